"""The `station` command. Each subcommand lives in its own module exposing `register(subparsers)`;
this file only lists them."""

import argparse
import importlib
import sys

# module names under station/commands/, one per subcommand
COMMANDS = ["demo", "simulate", "report", "solve", "apply", "export", "devices", "twin", "record", "resume", "replay", "import_", "diagnose"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="station", description="IMU calibration station: record, solve, replay, diagnose."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"station.commands.{name}").register(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
