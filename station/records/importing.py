"""`station db import DIR`: fill the store from existing folders of calibration files (and the
session files they name).

Every `*.cal.json` under DIR is loaded as any calibration file is (checked, checksum verified)
and recorded; its session, when the file it names still exists, gives the record's hash, devices
and health (`station.records.sources`). A file already recorded (same sha256) is skipped, so an
import can be run again over a growing folder.
"""

from pathlib import Path

from station.errors import CalibrationFileError
from station.records.record import Record


def kind_of(cal) -> str:
    """The record kind of a calibration file: combined, campaign or session."""
    if cal.fit.get("method") == "combined":
        return "combined"
    if (cal.session or {}).get("protocol") == "thermal campaign":
        return "campaign"
    return "session"


def import_folder(store, directory) -> dict:
    """Record every calibration file under `directory` into `store`: {"added", "present",
    "refused": [[file, why], ...]}."""
    from station.calfiles.calfile import load

    added, present, refused = 0, 0, []
    for path in sorted(Path(directory).rglob("*.cal.json")):
        try:
            cal = load(path)
        except CalibrationFileError as exc:
            refused.append([str(path), str(exc)])
            continue
        if store.add(Record.from_calibration(cal, path, kind_of(cal))) is None:
            present += 1
        else:
            added += 1
    return {"added": added, "present": present, "refused": refused}
