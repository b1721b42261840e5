"""Every input checked where it enters (issue 30): finite numbers in their ranges, nesting and
sizes bounded, before any work; each refusal one line naming the field and the allowed range.

Calibration files, session metadata and event details, recorded table columns, the metadata
`station resume` rebuilds a virtual bench from, device and bench profiles (TOML), .npz arrays;
and the messages of `station record` when it ends early."""

import hashlib
import json
import math
import subprocess
import zipfile

import h5py
import numpy as np
import pytest
from test_calfile import edited, make
from test_session import finished_session
from twinproc import ENV, STATION

from drivers.profile import BUNDLED, MAX_CHANNELS, ProfileError, SerialImuProfile, load_profile
from station import limits
from station.acquire.bench import BenchProfile
from station.calfiles.calfile import loads
from station.commands.record import how_to_go_on
from station.errors import CalibrationFileError, InputError, SessionFormatError
from station.imports import npz
from station.protocols.iron import IronSettings
from station.protocols.rotary import RotarySettings, suggested_axes
from station.protocols.still import StillSettings
from station.session import Session
from station.twin.rotary_bench import VirtualBench, checked_bench, record_rotary

DEEP = "[" * 100_000 + "]" * 100_000


# -- the limits themselves -------------------------------------------------------------------------

@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, -1.0, 1e300, 10**400, "1", True,
                                   None, [1.0]])
def test_a_number_out_of_range_or_of_another_type_is_refused_naming_field_and_range(value):
    with pytest.raises(InputError, match=r"^speed = .*: give a finite number in \[0, 100\]$"):
        limits.number(value, "speed", 0.0, 100.0)


@pytest.mark.parametrize("value", [-1, 2**32, 1.0, True, "3", math.nan])
def test_a_whole_number_out_of_range_or_not_an_int_is_refused(value):
    with pytest.raises(InputError, match=r"^seed = .*: give a whole number in \[0, 4294967295\]$"):
        limits.whole(value, "seed", 0, 2**32 - 1)


def test_numbers_in_range_pass_unchanged():
    assert limits.number(3, "x", 0, 5) == 3.0 and limits.whole(7, "n", 0, 9) == 7
    assert limits.choice(False, "two_axis", (True, False)) is False
    with pytest.raises(InputError, match="give one of True, False"):
        limits.choice(0, "two_axis", (True, False))  # 0 is not False here


def test_json_nested_100000_deep_is_refused_from_its_text():
    with pytest.raises(InputError, match="nested more than 64 deep"):
        limits.json_loads(DEEP, "doc")
    brackets_in_strings = json.dumps({"s": "[" * 1000, "t": ["{" * 70]})
    assert limits.json_loads(brackets_in_strings, "doc")["s"] == "[" * 1000


@pytest.mark.parametrize("text, where", [
    ('{"a": [[1, 1e999]]}', r"a\[0\]\[1\] = inf"),
    ('{"a": {"b": NaN}}', r"a\.b = nan"),
    ('{"m": -Infinity}', r"m = -inf"),
    ('{"m": ' + "1" + "0" * 400 + "}", r"m = an integer of 401 digits"),
])
def test_json_numbers_beyond_float_range_are_refused_naming_where(text, where):
    with pytest.raises(InputError, match=f"^doc: {where}: give a finite number"):
        limits.json_loads(text, "doc")


# -- calibration files -----------------------------------------------------------------------------

def test_a_calibration_file_with_1e999_in_a_is_refused_naming_the_entry():
    text = edited(make(), lambda d: d["sensitivity"].update(a=[[7.5] + r[1:] for r in
                                                                  d["sensitivity"]["a"]]))
    with pytest.raises(CalibrationFileError, match=r"sensitivity\.a\[\d\]\[0\] = inf"):
        loads(text.replace("7.5", "1e999", 1), "c.json")


def test_a_calibration_file_magnitude_of_10_to_400_is_refused():
    text = edited(make(), lambda d: d.update(magnitude=12345.0)).replace("12345.0", "1" + "0" * 400)
    with pytest.raises(CalibrationFileError, match="magnitude = an integer of 401 digits"):
        loads(text, "c.json")


def test_a_calibration_file_nested_deep_is_refused():
    with pytest.raises(CalibrationFileError, match="nested more than"):
        loads('{"format": ' + DEEP + "}", "c.json")


# -- session files ---------------------------------------------------------------------------------

def rewrite_metadata(path, text: str) -> None:
    """Replace a session's metadata with `text`, its checksum written again (crafted, not
    damaged: the checksum does not refuse it)."""
    with h5py.File(path, "r+") as f:
        del f["metadata"]
        ds = f.create_dataset("metadata", data=text, dtype=h5py.string_dtype())
        ds.attrs["sha256"] = np.bytes_(hashlib.sha256(text.encode()).hexdigest())


def test_session_metadata_nested_100000_deep_is_refused(tmp_path):
    path = tmp_path / "s.h5"
    finished_session(path)
    rewrite_metadata(path, '{"protocol": "rotary", "unit_serial": "X", "x": ' + DEEP + "}")
    with pytest.raises(SessionFormatError, match="/metadata is nested more than 64 deep"):
        Session.open(path)


def test_session_metadata_with_a_nan_is_refused_naming_the_field(tmp_path):
    path = tmp_path / "s.h5"
    finished_session(path)
    rewrite_metadata(path, '{"protocol": "rotary", "unit_serial": "X", "virtual_bench": '
                           '{"placement_deg": NaN}}')
    with pytest.raises(SessionFormatError, match=r"virtual_bench\.placement_deg = nan"):
        Session.open(path)


@pytest.fixture(scope="module")
def rotary(tmp_path_factory):
    """A 2-position rotary session recorded on the virtual bench in lockstep time."""
    path = tmp_path_factory.mktemp("rotary") / "r.h5"
    settings = RotarySettings(rate=1.0, revolutions=1, static=2.0, rest=0.5, guard=0.5,
                              steady=0.5)
    with VirtualBench(seed=7, rate_hz=25.0, remount_time=1.0) as bench:
        record_rotary(bench, path, settings, suggested_axes(2))
    return path


@pytest.mark.parametrize("column, row", [("time", 5), ("angle", 0), ("rate", -1)])
def test_a_nan_table_time_or_angle_refuses_the_session_as_damage_of_that_dataset(rotary, tmp_path,
                                                                                  column, row):
    path = tmp_path / "n.h5"
    path.write_bytes(rotary.read_bytes())
    with h5py.File(path, "r+") as f:
        ds = f["streams/table"][column]
        ds[row] = np.nan
        at = row % ds.shape[0]
    with Session.open(path) as s, pytest.raises(
            SessionFormatError, match=f"/streams/table/{column} holds nan at row {at} .*damaged"):
        s.table()
    done = subprocess.run([*STATION, "solve", str(path), "--out", str(tmp_path / "c.json")],
                          env=ENV, capture_output=True, text=True, timeout=300)
    # refused (or, when no window reads the row, refused for too few positions): one line
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr


# -- what `station resume` rebuilds the bench and protocol from ------------------------------------

@pytest.mark.parametrize("key, value, allowed", [
    ("speed", 1e-6, r"\[0.1, 10000\]"), ("remount_time", 1e9, r"\[0, 600\]"),
    ("seed", -1, r"\[0, 4294967295\]"), ("placement_deg", math.nan, r"\[0, 45\]"),
    ("rate_hz", "fast", r"\[1, 10000\]"), ("seed", 1.5, "whole number"),
    ("imu", 3, "one of 'serial', 'can'"), ("two_axis", "yes", "one of True, False"),
    ("rate_error", {"scale": math.inf}, r"scale = inf: give a finite number in \[-0.5, 0.5\]"),
    ("effects", -1, r"give an object \{effect: \{parameter: value\}\}$"),
    ("effects", {"bogus": {}}, "unknown effect"),
])
def test_each_virtual_bench_field_is_checked_before_a_bench_is_built(key, value, allowed):
    good = {"imu": "serial", "seed": 7, "speed": None, "rate_hz": 25.0, "remount_time": 1.0,
            "placement_deg": 0.5}
    with pytest.raises(InputError, match=f"virtual_bench.{key}.*{allowed}"):
        checked_bench({**good, key: value})
    assert checked_bench(good) == good


@pytest.mark.parametrize("key, value, message", [
    ("static", math.inf, r"rotary setting static = inf: must be positive and at most 3600"),
    ("timeout", 1e300, r"rotary setting timeout = 1e\+300: must be positive and at most 3600"),
    ("poll", "x", r"rotary setting poll = 'x': must be positive and at most 60"),
    ("revolutions", True, r"rotary setting revolutions = True: give a whole number in \[1, 1000\]"),
    ("rate", math.nan, "rotary setting rate = nan"),
    ("rate", 0.0, "rate must be a non-zero number"),
    ("rest", -1.0, r"rotary setting rest = -1.0: must be positive"),
])
def test_rotary_settings_are_bounded(key, value, message):
    with pytest.raises(InputError, match=message):
        RotarySettings(**{key: value})
    RotarySettings(rate=-1.0)  # the other direction is a valid rate


@pytest.mark.parametrize("settings, message", [
    (lambda: StillSettings(hold="5"), r"setting hold = '5': must be positive and at most 3600"),
    (lambda: StillSettings(gravity=math.inf), r"setting gravity = inf: must be positive"),
    (lambda: StillSettings(enter=math.nan), r"setting enter = nan: give a finite number"),
    (lambda: IronSettings(mountings=True), r"mountings = True: give a whole number in \[1, 100\]"),
    (lambda: IronSettings(tolerance_deg=None), r"tolerance_deg = None: must be positive"),
])
def test_still_and_iron_settings_are_bounded(settings, message):
    """The settings an iron or free-static session records and `station resume` reads back."""
    with pytest.raises(InputError, match=message):
        settings()


@pytest.mark.parametrize("field, value, said", [
    (("virtual_bench", "speed"), 1e-6, "virtual_bench.speed = 1e-06"),
    (("virtual_bench", "remount_time"), 1e9, "virtual_bench.remount_time = 1000000000.0"),
    (("settings", "static"), 1e300, "rotary setting static = 1e+300"),
    (("axes",), [[0, 0, 0]], "axes: give 1 to 10000 non-zero directions"),
])
def test_station_resume_refuses_crafted_metadata_in_one_line(rotary, tmp_path, field, value, said):
    """What hung resume for more than 90 s (speed 1e-6, remount_time 1e9) or gave a traceback is
    refused before the bench starts: exit 2, one line naming the field."""
    path = tmp_path / "r.h5"
    path.write_bytes(rotary.read_bytes())
    with h5py.File(path) as f:
        metadata = json.loads(f["metadata"][()])
    target = metadata
    for key in field[:-1]:
        target = target[key]
    target[field[-1]] = value
    rewrite_metadata(path, json.dumps(metadata))
    done = subprocess.run([*STATION, "resume", str(path)], env=ENV, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_resume_speed_option_is_checked(rotary, tmp_path):
    path = tmp_path / "r.h5"
    path.write_bytes(rotary.read_bytes())
    done = subprocess.run([*STATION, "resume", str(path), "--speed", "1e-9"], env=ENV,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and r"--speed = 1e-09: give a finite number" in done.stderr


# -- profiles --------------------------------------------------------------------------------------

def test_a_profile_of_deeply_nested_arrays_is_refused_naming_the_line(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text('[bench]\nunit_serial = "A"\nx = ' + DEEP + "\n")
    with pytest.raises(ProfileError, match=r"line 3: arrays or inline tables nested more than 16"):
        load_profile(path)
    with pytest.raises(ProfileError, match="nested more than 16"):
        BenchProfile.load(path)


def test_brackets_in_toml_strings_and_comments_do_not_count(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text('a = "' + "[" * 40 + '"  # ' + "{" * 40 + "\nb = '''\n" + "[" * 40
                    + "\n'''\nc = [[1, 2], [3]]\n")
    assert load_profile(path).tables["c"] == [[1, 2], [3]]


def test_a_profile_file_over_a_megabyte_is_refused(tmp_path):
    path = tmp_path / "big.toml"
    path.write_text("# " + "x" * (1 << 20) + "\n")
    with pytest.raises(ProfileError, match="a device profile is at most 1048576 bytes"):
        load_profile(path)


def test_a_device_profile_of_100000_channels_is_refused_by_count(tmp_path):
    text = (BUNDLED / "imu12_serial.toml").read_text()
    names = ", ".join(f'"g{i}"' for i in range(100_000))
    path = tmp_path / "wide.toml"
    path.write_text("\n".join(f"channels = [{names}]" if line.startswith("channels") else line
                              for line in text.splitlines()))
    with pytest.raises(ProfileError, match=f"channels: must be a list of 1 to {MAX_CHANNELS} "
                                           r"distinct, non-empty names \(got 100000 names\)"):
        SerialImuProfile.load(path)


# -- .npz arrays -----------------------------------------------------------------------------------

def bomb(path, shape=(4, 2_000_000, 12), dtype="<i4", claim=None) -> None:
    """An .npz whose `y` is all zeros (deflated about 1000 times); `claim`: the .npy header's
    shape, when it lies about the data."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as z, \
            z.open("y.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": dtype, "fortran_order": False, "shape": claim or shape})
        left = math.prod(shape) * np.dtype(dtype).itemsize
        while left > 0:
            f.write(bytes(min(left, 1 << 22)))
            left -= 1 << 22


def test_a_deflate_bomb_is_refused_from_the_zip_headers_before_inflating(tmp_path):
    path = tmp_path / "bomb.npz"
    bomb(path)  # 384 MB of zeros in 0.4 MB
    with pytest.raises(InputError, match=r"y\.npy inflates 10\d\d times .*refused before "
                                         "inflating"):
        npz.headers(path)
    done = subprocess.run([*STATION, "import", "npz", str(tmp_path / "b.h5"), str(path)],
                          env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "refused before inflating" in done.stderr


def test_an_npy_header_that_disagrees_with_the_zip_size_is_damage(tmp_path):
    path = tmp_path / "lie.npz"
    bomb(path, shape=(10, 10), claim=(10, 1000))
    with pytest.raises(InputError, match=r"y\.npy inflates to \d+ bytes, its header's shape "
                                         r"\(10, 1000\) needs \d+: the file is damaged"):
        npz.read(path)


# -- messages --------------------------------------------------------------------------------------

def test_record_says_no_file_was_written_when_the_table_fails_before_the_first_sample(tmp_path):
    text = (BUNDLED / "bench_serial.toml").read_text()
    profile = tmp_path / "bench.toml"
    profile.write_text(text.replace("192.168.0.50", "127.0.0.1").replace("port = 502", "port = 9")
                       .replace("/dev/ttyUSB0", "/dev/null"))
    out = tmp_path / "s.h5"
    done = subprocess.run([*STATION, "record", "--profile", str(profile), "--out", str(out)],
                          env=ENV, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 3 and not out.exists()
    assert f"no session file was written ({out} does not exist)" in done.stderr
    assert "keeps the completed positions" not in done.stderr


def test_an_interrupted_record_says_how_to_go_on(tmp_path):
    out = tmp_path / "s.h5"
    out.write_bytes(b"")
    interrupted = KeyboardInterrupt()
    interrupted.table_stopped = True
    assert how_to_go_on(interrupted, out) == (f"the table was stopped; {out} keeps the completed "
                                              f"positions; go on with `station resume {out}`")


def test_a_bad_unit_serial_is_refused_alone(tmp_path):
    text = (BUNDLED / "bench_serial.toml").read_text()
    profile = tmp_path / "bench.toml"
    profile.write_text(text.replace('"SN0001"', '"../x"'))
    with pytest.raises(ProfileError) as refused:
        BenchProfile.load(profile)
    assert "unit_serial" in str(refused.value) and "clock_speed" not in str(refused.value)
    profile.write_text(text.replace("[bench]", "[bench]\nclock_speed = inf"))
    with pytest.raises(ProfileError, match=r"clock_speed: inf: give a number between 0 and 1e4"):
        BenchProfile.load(profile)
