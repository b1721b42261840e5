"""`station db`: the calibration record store itself (docs/records.md).

    station db import DIR   record every calibration file under DIR (and what its session says)
    station db check        the store's integrity: SQLite's integrity_check, every record whole
    station db info         where the store is, its schema version, how many records
    station db list [KEY=VALUE ...]   the records a selection picks (docs/records.md, "Selecting
                            records"): time, unit, model, lot, verdict, bench, devices, software,
                            operator, session and calibration files with their sha256

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
                "  station db check --db sessions/station.db\n"
                "  station db list lot=L7 --json   # every calibration of lot L7, for an audit\n"
                "  station db list chamber=192.168.0.60   # the sessions that used that chamber")
    p.add_argument("action", choices=tuple(ACTIONS), help="what to do")
    p.add_argument("words", nargs="*", metavar="DIR | KEY=VALUE",
                   help="import: the folder to record; list: which records (default all)")
    p.add_argument("--db", metavar="URL", help="the record store (default above)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.errors import InputError
    from station.records.store import open_store, store_url

    args.directory = None
    if args.action == "import":
        if len(args.words) != 1 or not Path(args.words[0]).is_dir():
            raise InputError("give one directory to `station db import DIR`: the folder of the "
                             "sessions and calibration files")
        args.directory = Path(args.words[0])
    elif args.words and args.action != "list":
        raise InputError(f"`station db {args.action}` takes no words ({' '.join(args.words)})")
    url = store_url(args.db, args.directory)[0]
    with open_store(url, create=args.action == "import") as store:
        result = {"store": store.where, **ACTIONS[args.action](store, args)}
    print(json.dumps(result, indent=2) if args.json else
          "\n".join(f"{k}: {v}" for k, v in result.items() if k not in ("refused", "calibrations"))
          + "".join(f"\nrefused {f}: {why}" for f, why in result.get("refused", ()))
          + "".join(f"\n{_line(r)}" for r in result.get("calibrations", ())))
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


def _list(store, args) -> dict:
    """`station db list WORDS`: the records the words pick, oldest first, without their
    parameters (`station history SERIAL` shows those)."""
    from dataclasses import asdict

    from station.records.query import Selection

    records = [{k: v for k, v in asdict(r).items() if k != "parameters"}
               for r in store.records(Selection.parse(" ".join(args.words)))]
    return {"count": len(records), "calibrations": records}


def _line(r: dict) -> str:
    """One record of `db list` in words."""
    return (f"{r['id']:>6} {r['created']} {r['unit_serial']} {r['model'] or '-'} "
            f"lot {r['lot'] or '-'} {r['verdict'] or '-'} bench {r['bench'] or '-'} "
            f"table {r['table_id'] or '-'} chamber {r['chamber_id'] or '-'} "
            f"station {r['station_version']} session {r['session_path'] or '-'} "
            f"({(r['session_sha256'] or '-')[:12]}) calibration {r['calibration_path']}")


ACTIONS = {"import": _import, "check": _check, "info": _info, "list": _list}
