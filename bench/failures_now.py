"""A pytest plugin for long runs: each failing test's report (traceback and captured output)
appended to a file the moment the test ends, not only in the summary at the end of the run, so a
run stopped before its end (a loaded whole-suite run cut at its timeout) still says why its
failures failed. `bench/under_load.py --log DIR` loads it for every suite run:

    python -m pytest -p bench.failures_now --failures-log DIR/suite1.failures   (from the root)

With pytest-xdist the controller writes (the workers' reports reach it); a worker writes nothing.
"""

from pathlib import Path

_path = None


def pytest_addoption(parser):
    parser.addoption("--failures-log", type=Path, default=None,
                     help="append each failing test's report to this file as it ends")


def pytest_configure(config):
    global _path
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist)
        _path = config.getoption("failures_log")


def pytest_runtest_logreport(report):
    if _path is None or not report.failed:
        return
    with open(_path, "a", encoding="utf-8", errors="replace") as f:
        f.write(f"===== {report.nodeid} ({report.when}) =====\n{report.longreprtext}\n")
        for name, text in report.sections:
            f.write(f"----- {name} -----\n{text[-4000:]}\n")
