"""The walk-through of issue 36 (bench/walkthrough.py): from a scratch directory, by the command
line alone, demo, record on the twin with a verdict, the report's verdict rendered by headless
Chromium, noise figures stored, an export to every format and imucal's loader on the imucal file -
every command's output free of tracebacks, warnings and nan."""

import importlib.util
from pathlib import Path

WALKTHROUGH = Path(__file__).resolve().parents[1] / "bench" / "walkthrough.py"


def load_walkthrough():
    """bench/walkthrough.py as a module (not through sys.path: bench/serial.py would shadow
    pyserial there)."""
    spec = importlib.util.spec_from_file_location("walkthrough", WALKTHROUGH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_new_user_walks_from_the_demo_to_every_export(tmp_path):
    walkthrough = load_walkthrough()
    records = {r["step"]: r for r in walkthrough.walk(tmp_path, positions=8)}
    assert list(records) == ["demo", "record on the twin", "report", "noise --store",
                             "hand triads and rest", "export", "imucal round trip"]
    assert records["demo"]["verdict"] == records["record on the twin"]["verdict"] == "PASS"
    assert set(records["export"]) >= {"c-header", "kalibr", "ardupilot", "px4", "ros", "imucal"}
    assert records["imucal round trip"]["acc_max_m_s2"] < 1e-12
    if Path(walkthrough.CHROMIUM).exists():
        assert records["report"]["chromium"].startswith("the verdict rendered")
