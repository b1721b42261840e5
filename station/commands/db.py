"""`station db`: the calibration record store itself (docs/records.md).

    station db import DIR   record every calibration file under DIR (and what its session says)
    station db check        the store's integrity: SQLite's integrity_check, every record whole
    station db info         where the store is, its schema version, how many records

The store: --db URL (sqlite:///PATH or postgresql://user@host/dbname), else $STATION_DB, else
station.db in the working directory (`db import`: in DIR).
"""

import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = ("examples:\n  station db import sessions/\n"
                "  station db import /data/line2 --db postgresql://station@db.line/calibrations\n"
                "  station db check --db sessions/station.db")
    p.add_argument("action", choices=("import", "check", "info"), help="what to do")
    p.add_argument("directory", type=Path, nargs="?", help="import: the folder to record")
    p.add_argument("--db", metavar="URL", help="the record store (default above)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.errors import InputError
    from station.records.store import open_store, store_url

    if (args.action == "import") != (args.directory is not None):
        raise InputError("give a directory to `station db import DIR`, and only to import")
    if args.directory is not None and not args.directory.is_dir():
        raise InputError(f"{args.directory} is not a directory; give the folder of the sessions "
                         "and calibration files")
    url = store_url(args.db, args.directory)[0]
    with open_store(url, create=args.action == "import") as store:
        result = {"store": store.where, **ACTIONS[args.action](store, args)}
    print(json.dumps(result, indent=2) if args.json else
          "\n".join(f"{k}: {v}" for k, v in result.items() if k != "refused")
          + "".join(f"\nrefused {f}: {why}" for f, why in result.get("refused", ())))
    return 1 if result.get("problems") else 0


def _import(store, args) -> dict:
    """`station db import DIR`: every calibration file under DIR recorded."""
    from station.records.importing import import_folder

    return import_folder(store, args.directory)


def _check(store, args) -> dict:
    """`station db check`: the backend's integrity check and every record whole; `problems`
    lists what is wrong (exit 1)."""
    incomplete = store.incomplete()
    integrity = store.integrity()
    problems = ([] if integrity in ("ok", None) else [integrity]) + (
        [f"records without all their parameters: {incomplete}"] if incomplete else [])
    return {"records": store.count(), "integrity": integrity, "problems": problems}


def _info(store, args) -> dict:
    """`station db info`: the schema version (migrated to this station's on opening) and the
    number of records."""
    from station.records.schema import LATEST

    return {"schema_version": LATEST, "records": store.count()}


ACTIONS = {"import": _import, "check": _check, "info": _info}
