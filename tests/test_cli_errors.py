"""The one error handler of `station`: every command, given a missing file, a file of the wrong
type or a bad option, prints one line on stderr (no traceback) and exits with the documented code
(station/cli.py: 2 bad input, 130 interrupted), in process and through `python -m station`."""

import subprocess
import sys

import pytest

from drivers.errors import DeviceError, ProfileError, SerialPortError, TableError
from station import cli, errors

BAD_INPUT = 2


@pytest.fixture
def files(tmp_path):
    """A missing path, files of the wrong type under each suffix the commands read, a text file."""
    junk = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4  # binary, not UTF-8, not HDF5
    made = {"missing": tmp_path / "absent.h5"}
    for suffix in (".h5", ".cal.json", ".toml", ".csv", ".npz", ".txt"):
        path = tmp_path / f"junk{suffix}"
        path.write_bytes(junk)
        made[suffix] = path
    return made


def calls(f, out):
    """(name, argv) of each command with a missing file, a wrong file and a bad option."""
    return [
        ("solve missing", ["solve", f["missing"]]),
        ("solve wrong", ["solve", f[".h5"], "--out", out / "x.cal.json"]),
        ("solve option", ["solve", f[".h5"], "--bogus"]),
        ("report missing", ["report", f["missing"]]),
        ("report wrong", ["report", f[".h5"], "--out", out / "r.html"]),
        ("report option", ["report"]),
        ("replay missing", ["replay", f["missing"]]),
        ("replay wrong", ["replay", f[".h5"]]),
        ("replay option", ["replay", f[".h5"], "--positions", "x-y"]),
        ("resume missing", ["resume", f["missing"]]),
        ("resume wrong", ["resume", f[".h5"]]),
        ("resume option", ["resume", f[".h5"], "--speed", "fast"]),
        ("diagnose missing", ["diagnose", f["missing"]]),
        ("diagnose wrong", ["diagnose", f[".h5"]]),
        ("diagnose wrong type", ["diagnose", f[".txt"]]),
        ("diagnose option", ["diagnose", f[".h5"], "--alpha", "2"]),
        ("apply missing", ["apply", f["missing"], f[".csv"]]),
        ("apply wrong", ["apply", f[".cal.json"], f[".csv"]]),
        ("apply option", ["apply", f[".cal.json"]]),
        ("export missing", ["export", f["missing"], "--c-header", out / "c.h"]),
        ("export wrong", ["export", f[".cal.json"], "--c-header", out / "c.h"]),
        ("export option", ["export", f[".cal.json"]]),
        ("record missing", ["record", "--profile", f["missing"], "--out", out / "s.h5"]),
        ("record wrong", ["record", "--profile", f[".toml"], "--out", out / "s.h5"]),
        ("record option", ["record", "--profile"]),
        ("import missing", ["import", "csv", out / "i.h5", f["missing"], "--stream", "a=x"]),
        ("import wrong csv", ["import", "csv", out / "i.h5", f[".csv"], "--stream", "a=x",
                              "--unit", "a=g", "--fs", "100"]),
        ("import wrong npz", ["import", "npz", out / "i.h5", f[".npz"]]),
        ("import wrong text", ["import", "text", out / "i.h5", "--stream", f"acc={f['.txt']}",
                               "--unit", "acc=g", "--fs", "100"]),
        ("import wrong binary", ["import", "binary", out / "i.h5", f[".npz"], "--profile",
                                 "mimu4444"]),
        ("import wrong profile", ["import", "binary", out / "i.h5", f[".npz"], "--profile",
                                  f[".toml"]]),
        ("import option", ["import", "xml", out / "i.h5"]),
        ("simulate option", ["simulate", "--effect", "no_such_effect", "--out", out / "s.npz"]),
        ("demo option", ["demo", "--speed", "-1"]),
        ("twin option", ["twin", "--positions", "0"]),
        ("devices option", ["devices", "--bogus"]),
        ("no command", ["frobnicate"]),
    ]


def run_in_process(argv, capsys) -> tuple[int, str]:
    """Exit code and stderr of `station argv` run in this process (argparse exits, too)."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as done:
        code = done.code
    return code, capsys.readouterr().err


def test_every_command_fails_in_one_line_with_the_documented_code(files, tmp_path, capsys):
    failures = []
    for name, argv in calls(files, tmp_path):
        code, err = run_in_process(argv, capsys)
        lines = err.strip().splitlines()
        if code != BAD_INPUT or len(lines) != 1 or "Traceback" in err \
                or not lines[0].startswith("station"):
            failures.append(f"{name}: exit {code}, stderr {err!r}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("argv", [["solve", "@missing"], ["diagnose", "@.h5"],
                                  ["record", "--profile", "@.toml"], ["solve", "--bogus"]])
def test_python_m_station_fails_in_one_line(argv, files):
    argv = [str(files[a[1:]]) if a.startswith("@") else a for a in argv]
    done = subprocess.run([sys.executable, "-m", "station", *argv], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == BAD_INPUT and len(done.stderr.strip().splitlines()) == 1
    assert "Traceback" not in done.stderr and done.stdout == ""


def test_verbose_adds_the_traceback(files, capsys):
    code, err = run_in_process(["--verbose", "solve", files[".h5"]], capsys)
    assert code == BAD_INPUT and "Traceback" in err and err.strip().splitlines()[-1].startswith(
        "station solve:")


def test_python_m_station_help_and_version():
    done = subprocess.run([sys.executable, "-m", "station", "--help"], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0 and "diagnose" in done.stdout and "exit codes" in done.stdout
    version = subprocess.run([sys.executable, "-m", "station", "--version"], capture_output=True,
                             text=True, timeout=600)
    assert version.returncode == 0 and version.stdout.startswith("station ")


def test_every_error_has_one_of_two_roots_and_an_exit_code():
    """Each error class the station or its drivers define sits under StationError or DeviceError,
    keeps the built-in base callers catch, and carries a documented exit code."""
    station_errors = [c for c in vars(errors).values()
                      if isinstance(c, type) and issubclass(c, BaseException)]
    assert len(station_errors) >= 10
    assert all(issubclass(c, errors.StationError) for c in station_errors)
    for cls in (*station_errors, DeviceError, ProfileError, SerialPortError, TableError):
        assert cls.exit_code in (1, 2, 3), cls
    assert issubclass(errors.CalibrationInputError, ValueError)
    assert issubclass(ProfileError, ValueError) and issubclass(SerialPortError, ConnectionError)
    assert issubclass(TableError, RuntimeError) and issubclass(errors.ProtocolError, RuntimeError)


def test_notes_added_on_the_way_out_are_printed_on_the_same_line(capsys, monkeypatch):
    """A command's note (e.g. 'the table was stopped') reaches the one line; Ctrl-C gives 130."""
    def interrupted(args):
        err = KeyboardInterrupt()
        err.add_note("the table was stopped")
        raise err

    parser = cli.build_parser(["devices"])
    args = parser.parse_args(["devices"])
    monkeypatch.setattr(args, "run", interrupted)
    monkeypatch.setattr(cli, "parse", lambda argv: args)
    assert cli.main(["devices"]) == 130
    assert capsys.readouterr().err == "station devices: interrupted; the table was stopped\n"


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_command_has_examples_one_per_line_and_json(name, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main([name, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    examples = text.split("examples:")[1].split("\n\n")[0].strip().splitlines()
    continued = [False] + [line.rstrip().endswith("\\") for line in examples[:-1]]
    assert examples and all(line.lstrip().startswith("station ") or more
                            for line, more in zip(examples, continued, strict=True)), examples
    assert "--json" in text


def test_simulate_and_import_print_json(tmp_path, capsys):
    import json

    assert cli.main(["simulate", "--protocol", "rotary", "--out", str(tmp_path / "s.npz"),
                     "--json"]) == 0
    written = json.loads(capsys.readouterr().out)
    assert written["data"].endswith("s.npz") and written["shape"][0] > 0
    assert cli.main(["import", "npz", str(tmp_path / "s.h5"), str(tmp_path / "s.npz"),
                     "--json"]) == 0
    imported = json.loads(capsys.readouterr().out)
    assert imported["session"].endswith("s.h5") and imported["streams"]
