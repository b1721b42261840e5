"""The PASS/FAIL verdict in the session report (station/report/session.py).

The verdict (`station.solve.verdict`: the unit against its type's `[tolerances]`) is written by
`station solve` and `station record --solve` into the calibration file beside the session,
`SESSION.cal.json` (a unit of several on one table: `SESSION.<unit serial>.cal.json`). The report
shows that file's verdict when the file was solved from this session and stream: in the summary
(overall, parameters tested, the file) and, for a unit that did not pass, a section listing every
parameter that did not, in the words `station solve` prints. A session whose bench profile gave
tolerances but has no such file yet gets a warning naming the command that judges it.
"""

from pathlib import Path

from station.calfiles.calfile import load
from station.errors import InputError
from station.report import html
from station.solve.verdict import words


def calibration_files(session_path, serial: str | None) -> list:
    """Where `station solve` writes the calibration of `session_path`: SESSION.cal.json, or for a
    unit of several on one table SESSION.<serial>.cal.json."""
    path = Path(session_path)
    name = path.name.removesuffix(path.suffix)
    unit = f"{name}.{serial}.cal.json"  # the serial is the file's text: a name, or nothing
    return [path.with_suffix(".cal.json"),
            *([path.with_name(unit)] if serial and Path(unit).name == unit else [])]


def add_to_report(report, session, stream: str | None, serial: str | None,
                  tolerances: bool) -> None:
    """The verdict of the calibration file beside `session` (solved from its `stream`, None: any;
    `serial`: the unit's) in `report`'s summary and sections; `tolerances`: the session's bench
    profile gave a [tolerances] table (a warning says how to judge the unit when no verdict is
    found)."""
    found = []
    for path in calibration_files(session.path, serial):
        try:
            found += [(path, cal) for cal in [_solved_from(path, session.path, stream)] if cal]
        except InputError as exc:
            report.warnings.append(f"The verdict could not be read: {exc}")
    judged = [(path, cal) for path, cal in found if cal.verdict is not None]
    if not judged:
        if tolerances:
            report.warnings.append(
                "The bench profile gives the unit type's tolerances, and no calibration file "
                f"beside the session holds a verdict: `station solve {session.path}` judges the "
                "unit (PASS/FAIL) and writes it there, then `station report` shows it.")
        return
    path, cal = judged[0]
    verdict = cal.verdict
    report.summary["verdict"] = (f"{verdict['overall']} ({len(verdict['parameters'])} "
                                 f"parameters tested, {path.name})")
    text = words(verdict)
    report.sections.append(html.section(
        "verdict", f"Verdict: {verdict['overall']}",
        f"<p>The unit against its type's tolerances (a parameter passes when its estimate "
        f"+- {verdict['margin_sigma']:g} sigma is inside the limit; docs/quality.md), from "
        f"{html.e(path.name)}:</p><pre>{html.e(text)}</pre>"))


def _solved_from(path: Path, session_path, stream: str | None):
    """The calibration file `path` if it exists, loads and was solved from `session_path`
    (and `stream`, unless None); else None. InputError: the file is there and unreadable."""
    try:
        if not path.is_file():
            return None
    except (OSError, ValueError):  # a name the file system cannot hold (the serial is data)
        return None
    cal = load(path)
    source = cal.session or {}
    if source.get("path") != str(Path(session_path).resolve()):
        return None
    return cal if stream is None or source.get("stream") == stream else None
