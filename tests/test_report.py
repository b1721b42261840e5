"""The session report (issue 6): rendered from a session recorded on the virtual bench through the
real drivers, opened in headless Chromium (every image loads, no page error, a screenshot), its
warnings triggered by sessions made to need them; `station report`."""

import base64
import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from station import calibrate, cli, report
from station.commands.demo import run_demo
from station.session import Session, SessionWriter, write_results

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars")
PROBE = """<script>
window.__errors = [];
window.addEventListener("error", e => window.__errors.push(
  e.message || ("failed to load " + String(e.target && e.target.src).slice(0, 60))), true);
const original = console.error;
console.error = (...a) => { window.__errors.push("console.error: " + a.join(" ")); original(...a); };
window.addEventListener("load", () => document.documentElement.setAttribute("data-probe",
  JSON.stringify({errors: window.__errors,
                  images: [...document.images].map(i => [i.complete, i.naturalWidth])})));
</script>"""
"""Injected first in <head> (before the report's Content-Security-Policy, which would block it):
records script errors, failed image loads and console errors into the DOM for --dump-dom."""
POSITIONS = 8


@pytest.fixture(scope="module")
def chromium():
    """Path of Chromium; installed with apt-get when absent and possible, else a skip."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None and os.geteuid() == 0 and shutil.which("apt-get"):
        for cmd in (["apt-get", "update"], ["apt-get", "install", "-y", "chromium"]):
            subprocess.run(cmd, capture_output=True, timeout=900,
                           env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
        found = shutil.which("chromium")
    if found is None:
        pytest.skip("chromium is absent and could not be installed (needs root and apt-get: "
                    "apt-get install -y chromium)")
    return found


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A session of 8 positions recorded on the virtual bench (80x clock), with its results."""
    path = tmp_path_factory.mktemp("bench") / "bench.h5"
    summary = run_demo(path, positions=POSITIONS, speed=80.0, seed=3)
    return path, summary


@pytest.fixture(scope="module")
def clean(recorded, tmp_path_factory):
    """The report of the recorded session, built once and written: (Report, files written)."""
    built = report.build(recorded[0])
    return built, built.write(tmp_path_factory.mktemp("report") / "report.html")


def render(chromium, page: Path, workdir: Path) -> tuple[dict, Path]:
    """Open `page` (with the probe injected) in headless Chromium: the probe's findings and a
    screenshot of the whole report."""
    probed = page.with_name(f"probed-{page.name}")
    probed.write_text(page.read_text(encoding="utf-8").replace("<head>", "<head>" + PROBE, 1),
                      encoding="utf-8")
    shot = workdir / f"{page.stem}-screenshot.png"
    base = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={workdir / 'chromium-profile'}"]
    dom = subprocess.run([*base, "--dump-dom", probed.as_uri()], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    subprocess.run([*base, "--window-size=1200,7000", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, timeout=120, check=True)
    found = re.search(r'<html[^>]*data-probe="([^"]*)"', dom)
    assert found, "the probe did not run: the page never fired its load event"
    if os.environ.get("REPORT_SCREENSHOT_DIR"):
        keep = Path(os.environ["REPORT_SCREENSHOT_DIR"])
        keep.mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, keep / shot.name)
    return json.loads(html.unescape(found.group(1))), shot


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk (read independently of any image library)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def embedded_images(page: str) -> list[bytes]:
    return [base64.b64decode(b) for b in re.findall(r'src="data:image/png;base64,([^"]+)"', page)]


def test_report_renders_in_headless_chromium(clean, chromium, tmp_path):
    built, files = clean
    probe, shot = render(chromium, files[0], tmp_path)
    assert probe["errors"] == []
    images = embedded_images(files[0].read_text(encoding="utf-8"))
    names = {p.name for p in built.plots}
    assert {"residuals", "axes", "coverage", "table", "stream-imu", "uncertainty"} <= names
    assert len(probe["images"]) == len(images) == len(built.plots)
    # every image decoded at the width its PNG header states
    assert [w for _, w in probe["images"]] == [png_size(i)[0] for i in images]
    assert all(complete for complete, _ in probe["images"])
    assert png_size(shot.read_bytes()) == (1200, 7000)


def test_figures_next_to_the_report_are_the_embedded_ones(clean):
    files = clean[1]
    pngs = [f.read_bytes() for f in files[1:]]
    assert all(f.name.startswith("report-") and f.suffix == ".png" for f in files[1:])
    assert pngs == embedded_images(files[0].read_text(encoding="utf-8"))


def test_clean_session_report_states_the_recording_and_warns_of_nothing(recorded, clean):
    path, demo = recorded
    built = clean[0]
    s = built.summary
    with Session.open(path) as session:
        samples = len(session.stream("imu").seq)
        stored = session.results("rotary").calibration
    assert s["positions"] == s["positions_planned"] == POSITIONS
    assert s["samples"] == samples and s["sensors"] == 12 and s["rate_hz"] == 200
    assert s["chi2_per_dof"] == pytest.approx(demo["chi2_per_dof"])
    assert s["noise_median"] == pytest.approx(np.median(stored.sigma))
    assert s["closed_cleanly"] and s["outliers"] == 0
    assert built.warnings == [], built.warnings
    page = built.html()
    assert "No warning" in page and "SIM-3" in page


def test_an_outlier_is_named_and_breaks_chi2(recorded, tmp_path):
    path = tmp_path / "tampered.h5"
    shutil.copy(recorded[0], path)
    with Session.open(path) as session:
        stored = session.results("rotary")
    readings, sigma = stored.readings.copy(), stored.readings_sigma
    readings[3, 5] += 40 * sigma[3, 5]  # sensor g4 at position 6: a bumped window
    write_results(path, "tampered", "imu", readings, calibrate(readings, 1.0, sigma=sigma), sigma)
    built = report.build(path)  # the newest result is the default
    assert built.summary["result"].startswith("results/tampered")
    text = " ".join(built.warnings)
    assert "outliers" in text and "g4 at position 6" in text
    # chi2 gains about (40 (1 - leverage))^2 >> dof = 47: the model does not explain the data
    assert "does not explain the data" in text


def test_weak_geometry_is_warned(recorded, tmp_path):
    path = tmp_path / "cone.h5"
    shutil.copy(recorded[0], path)
    with Session.open(path) as session:
        a = session.results("rotary").calibration.a
    rng = np.random.default_rng(7)
    n, tilt = 12, np.radians(20)  # every stimulus within 20 deg of one axis
    azimuth = np.linspace(0, 2 * np.pi, n, endpoint=False)
    polar = tilt * np.sqrt(rng.uniform(0.2, 1, n))
    v = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    sigma = np.full((12, n), 1e-4)
    readings = a.T @ v + sigma * rng.standard_normal((12, n))
    write_results(path, "cone", "imu", readings, calibrate(readings, 1.0, sigma=sigma), sigma)
    built = report.build(path, "cone")
    # eigenvalues of sum v v^T: about n sin^2 / 2 across against n cos^2 along: ratio < 0.07
    assert built.summary["excitation_ratio"] < 0.07
    text = " ".join(built.warnings)
    assert "Weak geometry" in text and "No position within" in text


def copy_positions(source, target, keep: int, serial: str, extra_events=()) -> None:
    """A session holding the recording of `source` up to its position `keep` (not completed),
    no results; like a recording interrupted there."""
    with Session.open(source) as s:
        imu, table, events = s.stream("imu"), s.table(), s.events()
        metadata = {**s.metadata, "unit_serial": serial}
        spec = s.specs["imu"]
    with SessionWriter.create(target, metadata, {"imu": spec}) as w:
        w.append("imu", imu.to_block())
        w.append_table([SimpleNamespace(
            time=t, rate=r, angle=a, rate_setpoint=sp,
            **{bit: bool(st >> i & 1) for i, bit in enumerate(
                ("running", "ready", "moving", "at_rate", "fault"))})
            for t, r, a, sp, st in zip(table.time, table.rate, table.angle, table.rate_setpoint,
                                       table.status)])
        for e in events:
            if e.kind != "session_start" and (e.position is None or e.position < keep):
                w.event(e.kind, e.position, e.detail, time=e.time)
        for kind, detail in extra_events:
            w.event(kind, keep, detail, time=events[-1].time)


def test_interrupted_session_is_solved_for_the_report_and_escaped(recorded, chromium, tmp_path):
    path = tmp_path / "interrupted.h5"
    hostile = '<script>alert("x")</script><img src=x onerror=alert(1)>'
    copy_positions(recorded[0], path, 6, hostile, [
        ("note", {"text": "link statistics", "link": {"crc_failures": 3, "frames": 9}}),
        ("abort", {"state": "rotating", "error": "ProtocolError: <b>table</b> fault"})])
    built = report.build(path)
    s = built.summary
    assert s["result"].startswith("computed") and s["positions"] == 6
    # a fit of Eq. (18) readings with their own sigma: chi2/dof = 1 +- sqrt(2/dof), 5 sigma
    assert abs(s["chi2_per_dof"] - 1) < 5 * np.sqrt(2 / s["dof"])
    text = " ".join(built.warnings)
    assert "Only 6 of the 8 planned positions" in text
    assert "abort at position 7" in text and "3 crc failures" in text
    page = built.html()
    assert "<script>alert" not in page and "<b>table</b>" not in page and "onerror=alert" not in \
        page.replace("onerror=alert(1)&gt;", "")
    assert html.escape(hostile) in page
    files = built.write(tmp_path / "interrupted.html")
    probe, _ = render(chromium, files[0], tmp_path)
    assert probe["errors"] == [] and all(w > 0 for _, w in probe["images"])


def test_station_report_cli(recorded, tmp_path, capsys):
    out = tmp_path / "cli" / "r.html"
    assert cli.main(["report", str(recorded[0]), "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["files"][0] == str(out) and all(Path(f).is_file() for f in printed["files"])
    assert printed["positions"] == POSITIONS and printed["warnings"] == []


@pytest.mark.parametrize("args, message", [
    (["missing.h5"], "is not a file"),
    (["plain.txt"], "not an HDF5 file"),
    (["plain.txt", "--out", "plain.txt"], "would overwrite the session file"),
])
def test_station_report_refuses_bad_input(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    Path("plain.txt").write_text("not a session")
    assert cli.main(["report", *args]) == 1
    assert message in capsys.readouterr().err


def test_station_report_names_the_results_it_has(recorded, tmp_path, capsys):
    assert cli.main(["report", str(recorded[0]), "--out", str(tmp_path / "r.html"),
                     "--result", "nope"]) == 1
    assert "no results named 'nope'; it has rotary" in capsys.readouterr().err
