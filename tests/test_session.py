"""The HDF5 session file: round trips, live reading, refusal of foreign or damaged files and of
bad input."""

import dataclasses
import json
import threading
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from layouts import section4_gyros

from drivers.clock import ScaledClock
from drivers.profile import ImuSection, load_profile
from drivers.samples import SampleBlock
from station.replay import as_block
from station.session import (
    EVENT_KINDS,
    Session,
    SessionFormatError,
    SessionLockedError,
    SessionWriter,
    StreamSpec,
    write_results,
)
from station.session import writer as writer_module
from station.session.format import EVENT_COLUMNS, STREAM_COLUMNS, TABLE_COLUMNS
from station.solve.calibrate import calibrate

CHANNELS = tuple(f"g{i + 1}" for i in range(12))
SPEC = StreamSpec(CHANNELS, "rad/s", 1.0e6, 2000.0, device="imu12")
META = {"protocol": "rotary", "unit_serial": "SN-0042", "settings": {"positions": 20, "rate": 1.5},
        "profiles": {"imu": {"imu": {"name": "imu12", "scale": 1.0e6}}}, "notes": "bench 3, 21 C"}


def block(rng, start, k, m=12, low=-(2**31), high=2**31):
    """k samples from sequence number `start`, counts uniform over [low, high)."""
    seq = np.arange(start, start + k, dtype=np.int64)
    device_time = seq * 5e-4
    device_time[::7] = np.nan  # samples without a device timestamp
    return SampleBlock(rng.integers(low, high, size=(k, m)), seq, device_time,
                       100.0 + seq * 5e-4 + rng.uniform(0, 1e-4, k), CHANNELS[:m])


def table_reading(t, bits=()):
    flags = {b: b in bits for b in ("running", "ready", "moving", "at_rate", "fault")}
    return SimpleNamespace(time=t, rate=0.1 * t, angle=0.05 * t * t, rate_setpoint=1.5, **flags)


def new_session(path, **kw):
    return SessionWriter.create(path, META, {"imu": SPEC}, clock=ScaledClock(start=100.0), **kw)


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    path = tmp_path / "s.h5"
    blocks = [block(rng, 0, 700), block(rng, 700, 1), block(rng, 701, 4000)]
    states = [table_reading(0.5), table_reading(1.0, ("running", "moving")),
              table_reading(2.0, ("running", "ready", "moving", "at_rate", "fault"))]
    with new_session(path) as w:
        for b in blocks:
            w.append("imu", b)
        w.append_table(states[0])
        w.append_table(states[1:])
        w.event("static_start", 0, {"window_s": 10.0, "label": "face +z ü"}, time=101.0)
        w.event("position_done", np.int64(0), time=102.0)  # numpy integers are positions too
        w.event("fault", None, {"text": "table slipped"}, time=103.0)
    every = SampleBlock.concat(blocks)
    with Session.open(path) as s:
        d = s.stream("imu")
        assert d.counts.dtype == np.int32 and np.array_equal(d.counts, every.counts)
        assert np.array_equal(d.seq, every.seq)
        assert np.array_equal(d.device_time, every.device_time, equal_nan=True)
        assert np.array_equal(d.host_time, every.host_time)
        assert d.spec == SPEC and np.array_equal(d.to_si(), every.counts / 1.0e6)
        assert np.array_equal(as_block(d).counts, every.counts)
        t = s.table()
        assert np.array_equal(t.time, [0.5, 1.0, 2.0])
        assert np.array_equal(t.angle, [0.0125, 0.05, 0.2])
        assert np.array_equal(t.rate, [0.05, 0.1, 0.2])
        assert np.array_equal(t.rate_setpoint, [1.5] * 3)
        assert t.flag("running").tolist() == [False, True, True]
        assert t.flag("at_rate").tolist() == [False, False, True]
        assert t.status.tolist() == [0, 0b101, 0b11111]  # bit i = TABLE_STATUS_BITS[i]
        events = s.events()
        assert [(e.kind, e.position) for e in events] == [
            ("session_start", None), ("static_start", 0), ("position_done", 0), ("fault", None)]
        assert events[0].time == 100.0 or 100.0 <= events[0].time < 200.0  # the writer's clock
        assert [e.time for e in events[1:]] == [101.0, 102.0, 103.0]
        assert events[1].detail == {"window_s": 10.0, "label": "face +z ü"}
        assert events[3].detail == {"text": "table slipped"}
        assert s.last_completed_position() == 0
        assert s.metadata == META and s.protocol == "rotary" and s.unit_serial == "SN-0042"
        assert s.format_version == 1 and s.closed_cleanly
    with h5py.File(path, "r") as f:  # the documented layout, read without station.session
        assert f.attrs["format"] == "imu-station-session" and f.attrs["format_version"] == 1
        assert json.loads(f.attrs["units"])["imu"] == ["rad/s"] * 12
        assert f.attrs["created"].endswith("Z")
        assert list(f["streams/imu"].attrs["channels"]) == list(CHANNELS)
        assert np.array_equal(f["streams/imu"].attrs["counts_per_unit"], [1.0e6] * 12)
        assert f["streams/imu/counts"].maxshape == (None, 12)
        assert f["events/kind"][1] == b"static_start"


FLUSH_WRITES = len(STREAM_COLUMNS) + len(TABLE_COLUMNS) + len(EVENT_COLUMNS) + 1  # + detail


@pytest.mark.parametrize("cut", range(1, FLUSH_WRITES + 1))
def test_a_flush_cut_by_ctrl_c_is_written_again_whole(tmp_path, monkeypatch, cut):
    """Ctrl-C raises KeyboardInterrupt in the main thread between any two writes of a flush (here
    before write number `cut` of the flush of an event with samples and table states buffered);
    the protocol then records its abort and closes: every row is in the file once, the columns in
    step (a cut events flush once made a resumed session unreadable: 'not valid ASCII/JSON')."""
    rng = np.random.default_rng(cut)
    blocks = [block(rng, 0, 30), block(rng, 30, 20)]
    states = [table_reading(1.0), table_reading(2.0, ("running",))]
    path = tmp_path / "cut.h5"
    w = new_session(path, flush_interval=3600.0)
    for b, state in zip(blocks, states, strict=True):
        w.append("imu", b)
        w.append_table(state)
    real, writes = writer_module._extend, []

    def extend(ds, values):
        writes.append(ds.name)
        if len(writes) == cut:
            raise KeyboardInterrupt
        real(ds, values)
    monkeypatch.setattr(writer_module, "_extend", extend)
    with pytest.raises(KeyboardInterrupt):
        w.event("position_done", 0, {"up": [0.0, 0.0, 1.0]}, time=101.0)
    monkeypatch.setattr(writer_module, "_extend", real)
    w.event("abort", 0, {"error": "KeyboardInterrupt"}, time=102.0)
    w.close()
    every = SampleBlock.concat(blocks)
    with Session.open(path) as s:
        d = s.stream("imu")
        assert np.array_equal(d.seq, every.seq) and np.array_equal(d.counts, every.counts)
        assert np.array_equal(d.host_time, every.host_time)
        assert np.array_equal(s.table().time, [1.0, 2.0])
        events = s.events()
        assert [(e.kind, e.position, e.detail) for e in events[1:]] == [
            ("position_done", 0, {"up": [0.0, 0.0, 1.0]}),
            ("abort", 0, {"error": "KeyboardInterrupt"})]
        assert [e.time for e in events[1:]] == [101.0, 102.0]
    assert len(writes) == cut  # the flush had reached its write number `cut`


def test_int64_streams_keep_counts_beyond_32_bits(tmp_path):
    rng = np.random.default_rng(2)
    spec = dataclasses.replace(SPEC, dtype="int64")
    b = block(rng, 0, 50, low=-(2**62), high=2**62)
    with SessionWriter.create(tmp_path / "s.h5", META, {"imu": spec}) as w:
        w.append("imu", b)
    with Session.open(tmp_path / "s.h5") as s:
        assert np.array_equal(s.stream("imu").counts, b.counts)


def test_spec_from_a_device_profile():
    imu = load_profile("imu12_serial").section("imu", ImuSection.parse)
    spec = StreamSpec.from_profile(imu)
    assert spec.channels == tuple(imu.channels) and spec.counts_per_unit == tuple(imu.scale)
    assert spec.units == tuple(imu.units) and spec.rate_hz == imu.rate_hz


def test_samples_are_batched_until_the_flush_interval(tmp_path):
    rng = np.random.default_rng(3)
    w = new_session(tmp_path / "s.h5", flush_interval=3600.0)
    w.append("imu", block(rng, 0, 100))
    w.append_table(table_reading(1.0))
    assert w.flushed == {"imu": 0, "table": 0, "events": 1}  # only session_start
    w.event("rotate_start", 3)  # events flush at once, with everything buffered
    assert w.flushed == {"imu": 100, "table": 1, "events": 2}
    w.flush_interval = 0.0
    w.append("imu", block(rng, 100, 10))
    assert w.flushed["imu"] == 110
    w.close()


def test_reader_sees_flushed_rows_while_the_writer_is_live(tmp_path):
    rng = np.random.default_rng(4)
    path = tmp_path / "s.h5"
    w = new_session(path, flush_interval=3600.0)
    w.append("imu", block(rng, 0, 300))
    w.flush()
    with Session.open(path) as s:
        assert len(s.stream("imu").seq) == 300 and not s.closed_cleanly
        w.append("imu", block(rng, 300, 200))
        assert len(s.stream("imu").seq) == 300  # buffered, not yet in the file
        w.event("position_done", 0)
        assert len(s.stream("imu").seq) == 500  # refreshed on each call
        assert s.last_completed_position() == 0
    w.close()


def test_threads_may_share_a_writer(tmp_path):
    rng = np.random.default_rng(10)
    parts = [block(rng, 1000 * i, 1000) for i in range(4)]
    with new_session(tmp_path / "s.h5", flush_interval=0.0) as w:  # flush on every append
        def feed(b):
            for i in range(0, 1000, 10):
                w.append("imu", SampleBlock(b.counts[i:i + 10], b.seq[i:i + 10],
                                            b.device_time[i:i + 10], b.host_time[i:i + 10]))
        threads = [threading.Thread(target=feed, args=(b,)) for b in parts]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    with Session.open(tmp_path / "s.h5") as s:
        d = s.stream("imu")
    order = np.argsort(d.seq)
    assert np.array_equal(d.seq[order], np.arange(4000))
    assert np.array_equal(d.counts[order], SampleBlock.concat(parts).counts)


def readings_and_calibration():
    _, _, readings = section4_gyros(np.random.default_rng(5), 20, 0.01)
    return readings, calibrate(readings, 1.0, sigma=0.01)


def test_results_round_trip_and_are_never_overwritten(tmp_path):
    readings, cal = readings_and_calibration()
    sigma = np.full(readings.shape, 0.01)
    path = tmp_path / "s.h5"
    w = new_session(path)
    w.append("imu", block(np.random.default_rng(6), 0, 10))
    w.write_results("live", "imu", readings, cal, sigma)
    with pytest.raises(ValueError, match="closed"):
        w.append("imu", block(np.random.default_rng(6), 10, 10))
    write_results(path, "replay-1", "imu", readings[:, :5])  # replay adds a group
    with pytest.raises(ValueError, match="exists"):
        write_results(path, "live", "imu", readings)
    with Session.open(path) as s:
        assert s.result_names == ("live", "replay-1")
        r = s.results("live")
        assert np.array_equal(r.readings, readings) and np.array_equal(r.readings_sigma, sigma)
        assert r.stream == "imu" and r.units == ("rad/s",) * 12
        for field in dataclasses.fields(cal):
            ours, theirs = getattr(r.calibration, field.name), getattr(cal, field.name)
            if isinstance(theirs, np.ndarray):
                assert np.array_equal(ours, theirs), field.name
            else:
                assert ours == theirs and type(ours) is type(theirs), field.name
        assert np.allclose(r.calibration.apply(readings), cal.apply(readings))
        replay = s.results("replay-1")
        assert replay.calibration is None and replay.readings_sigma is None
        assert replay.readings.shape == (12, 5)
        assert len(s.stream("imu").seq) == 10


def test_results_refuse_a_file_left_open(tmp_path):
    readings, _ = readings_and_calibration()
    w = new_session(tmp_path / "s.h5")
    with pytest.raises(SessionLockedError, match="resume"):
        write_results(tmp_path / "s.h5", "r", "imu", readings)
    with pytest.raises(ValueError, match=r"shape \(11, 20\).*\(12, n\)"):
        w.write_results("r", "imu", readings[1:])
    w.close()


def test_resume_appends_after_a_clean_close(tmp_path):
    rng = np.random.default_rng(7)
    path = tmp_path / "s.h5"
    first, second = block(rng, 0, 300), block(rng, 300, 300)
    with new_session(path) as w:
        w.append("imu", first)
        w.event("position_done", 0)
        w.event("position_done", 1)
    with SessionWriter.resume(path) as w:
        assert w.last_completed_position == 1
        w.append("imu", second)
        w.event("position_done", 2)
    with Session.open(path) as s:
        assert np.array_equal(s.stream("imu").counts, np.concatenate([first.counts, second.counts]))
        kinds = [e.kind for e in s.events()]
        assert kinds == ["session_start", "position_done", "position_done", "session_resumed",
                         "position_done"]
        assert s.events()[3].position == 1 and s.last_completed_position() == 2


def assert_scaled(f, rows: dict) -> None:
    """Every group's time column is the dimension scale of its other columns' rows, the stream's
    channel names that of the counts' columns, every column carries `units`; `rows` = expected
    lengths of the scales."""
    imu, table, events = f["streams/imu"], f["streams/table"], f["events"]
    for group, scale, columns in [(imu, "host_time", ("counts", "seq", "device_time")),
                                  (table, "time", ("rate", "angle", "rate_setpoint", "status")),
                                  (events, "time", ("position", "kind", "detail_end"))]:
        assert group[scale].is_scale and group[scale].attrs["units"] == "s"
        assert group[scale].shape == (rows[group.name],)
        for column in columns:
            attached = group[column].dims[0]
            assert len(attached) == 1 and attached[0] == group[scale], (group.name, column)
            assert attached[0].shape == (rows[group.name],) and "units" in group[column].attrs
    assert [c.decode() for c in imu["counts"].dims[1][0][()]] == list(CHANNELS)
    assert imu["counts"].attrs["units"] == "count" and table["rate"].attrs["units"] == "rad/s"
    assert events["detail"].is_scale


def test_time_columns_are_dimension_scales_through_swmr_appends_and_resume(tmp_path):
    rng = np.random.default_rng(8)
    path = tmp_path / "s.h5"
    w = new_session(path, flush_interval=0.0)  # every append is flushed in SWMR mode
    for start in range(0, 900, 300):
        w.append("imu", block(rng, start, 300))
    w.append_table([table_reading(0.5), table_reading(1.0)])
    w.event("position_done", 0)
    with h5py.File(path, "r", swmr=True, libver=("v110", "v110")) as f:  # while the writer is live
        assert_scaled(f, {"/streams/imu": 900, "/streams/table": 2, "/events": 2})
    w.close()
    with SessionWriter.resume(path) as w:
        w.append("imu", block(rng, 900, 100))
    with h5py.File(path, "r") as f:
        assert_scaled(f, {"/streams/imu": 1000, "/streams/table": 2, "/events": 3})
    with Session.open(path) as s:
        assert len(s.stream("imu").seq) == 1000


def test_results_readings_carry_the_stream_units(tmp_path):
    path = tmp_path / "s.h5"
    new_session(path).close()
    readings, cal = readings_and_calibration()
    write_results(path, "live", "imu", readings, cal, np.full(readings.shape, 0.01))
    with h5py.File(path, "r") as f:
        for name in ("readings", "readings_sigma"):
            assert list(f[f"results/live/{name}"].attrs["units"]) == ["rad/s"] * 12


def test_version_1_files_without_scales_still_read():
    """The committed example sessions were written before the dimension scales existed."""
    examples = sorted((Path(__file__).resolve().parent.parent / "sessions").glob("*.h5"))
    assert examples
    for path in examples:
        with h5py.File(path, "r") as f:
            assert not f["streams/imu/host_time"].is_scale
            assert "units" not in f["streams/imu/counts"].attrs
        with Session.open(path) as s:
            assert s.format_version == 1 and len(s.stream("imu").seq) > 0 and s.events()


def test_resume_refuses_a_live_session(tmp_path):
    w = new_session(tmp_path / "s.h5")
    with pytest.raises(SessionLockedError, match="live writer"):
        SessionWriter.resume(tmp_path / "s.h5")
    w.close()


def test_create_refuses_to_overwrite(tmp_path):
    new_session(tmp_path / "s.h5").close()
    with pytest.raises(FileExistsError, match="resume"):
        new_session(tmp_path / "s.h5")
    new_session(tmp_path / "s.h5", overwrite=True).close()


def finished_session(path):
    with new_session(path) as w:
        w.append("imu", block(np.random.default_rng(8), 0, 20))
        w.event("position_done", 0)


@pytest.mark.parametrize("version, found", [(2, "2"), (0, "0"), ("1", "'1'")])
def test_unknown_format_versions_are_refused(tmp_path, version, found):
    path = tmp_path / "s.h5"
    finished_session(path)
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = version
    with pytest.raises(SessionFormatError, match=f"format_version {found}; .*reads versions 1"):
        Session.open(path)
    with pytest.raises(SessionFormatError):
        SessionWriter.resume(path)


def test_foreign_files_are_refused(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "someone-else"
        f["x"] = np.arange(3)
    with pytest.raises(SessionFormatError, match="'someone-else'.*expected 'imu-station-session'"):
        Session.open(other)
    h5py.File(tmp_path / "bare.h5", "w").close()
    with pytest.raises(SessionFormatError, match="format attribute None"):
        Session.open(tmp_path / "bare.h5")
    (tmp_path / "text.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(SessionFormatError, match="not an HDF5 file"):
        Session.open(tmp_path / "text.h5")
    with pytest.raises(SessionFormatError):
        write_results(other, "r", "imu", np.zeros((12, 3)))
    with pytest.raises(FileNotFoundError):
        Session.open(tmp_path / "missing.h5")


def tamper(path, edit):
    finished_session(path)
    with h5py.File(path, "r+") as f:
        edit(f)


@pytest.mark.parametrize("edit, message", [
    (lambda f: f.__delitem__("streams/imu/seq"), "seq is missing"),
    (lambda f: (f.__delitem__("streams/imu/seq"),
                f.__setitem__("streams/imu/seq", h5py.ExternalLink("/etc/passwd", "/x"))),
     "seq is missing or an external link"),
    (lambda f: (f.__delitem__("streams/imu/seq"), f.create_dataset("streams/imu/seq", (20,), "f8")),
     "seq has dtype float64"),
    (lambda f: (f.__delitem__("streams/imu/counts"),
                f.create_dataset("streams/imu/counts", (20, 11), "i4")), r"rows x \(12,\)"),
    (lambda f: f["events/detail_end"].__setitem__(1, 0), "detail_end is not increasing"),
    (lambda f: f["events/detail"].__setitem__(0, ord("x")), "an event.s detail is not valid JSON"),
    (lambda f: f["metadata"][...], None),
    (lambda f: (f.__delitem__("metadata"), f.create_dataset("metadata", data="[1, 2]")),
     "JSON object"),
    (lambda f: f["streams/imu"].attrs.__setitem__("counts_per_unit", -1.0), "malformed"),
    (lambda f: f["streams/imu"].attrs.__setitem__("channels", 7), "'channels'"),
])
def test_damaged_or_hostile_files_are_refused_with_the_reason(tmp_path, edit, message):
    path = tmp_path / "s.h5"
    tamper(path, edit)
    if message is None:  # the untouched file reads: the refusals below are due to the edits
        with Session.open(path) as s:
            assert len(s.stream("imu").seq) == 20 and len(s.events()) == 2
        return
    with pytest.raises(SessionFormatError, match=message), Session.open(path) as s:
        s.stream("imu"), s.events()


def test_hostile_results_are_refused(tmp_path):
    readings, cal = readings_and_calibration()
    path = tmp_path / "s.h5"
    finished_session(path)
    write_results(path, "r", "imu", readings, cal)
    with h5py.File(path, "r+") as f:
        del f["results/r/calibration/v"]
        f["results/r/calibration/v"] = np.zeros((3, 19))
    with Session.open(path) as s, pytest.raises(SessionFormatError, match=r"v has shape \(3, 19\)"):
        s.results("r")


@pytest.mark.parametrize("call, message", [
    (lambda w, b: w.append("gyro", b), "unknown stream 'gyro'"),
    (lambda w, b: w.append("imu", dataclasses.replace(b, counts=b.counts[:, :11])),
     r"\(10, 11\) do not match 10 samples x 12 channels"),
    (lambda w, b: w.append("imu", dataclasses.replace(b, counts=b.counts * 1.0)), "integers"),
    (lambda w, b: w.append("imu", dataclasses.replace(b, counts=b.counts + 2**31)),
     "exceed int32.*dtype='int64'"),
    (lambda w, b: w.append("imu", dataclasses.replace(b, channels=CHANNELS[::-1])), "channels"),
    (lambda w, b: w.append("imu", dataclasses.replace(b, host_time=b.host_time[:3])), "10 entries"),
    (lambda w, b: w.event("position_dnoe", 1), "unknown event kind 'position_dnoe'"),
    (lambda w, b: w.event("note", -1), "non-negative int"),
    (lambda w, b: w.event("note", None, {"t": np.float64(np.nan)}), "JSON"),
])
def test_bad_writer_input_is_refused_clearly(tmp_path, call, message):
    rng = np.random.default_rng(9)
    b = block(rng, 0, 10, low=0, high=2**31 - 1)
    with new_session(tmp_path / "s.h5") as w:
        with pytest.raises(ValueError, match=message):
            call(w, b)
        w.append("imu", b)  # the writer is still usable
    with Session.open(tmp_path / "s.h5") as s:
        assert np.array_equal(s.stream("imu").counts, b.counts)
        assert "note" in EVENT_KINDS


@pytest.mark.parametrize("metadata, streams, message", [
    ({"unit_serial": "x"}, {"imu": SPEC}, "metadata\\['protocol'\\]"),
    ({**META, "when": object()}, {"imu": SPEC}, "not JSON-serialisable"),
    (META, {"table": SPEC}, "not 'table'"),
    (META, {"IMU 1": SPEC}, "lower-case identifier"),
    (META, {}, "at least one"),
])
def test_bad_create_arguments_are_refused_and_leave_no_file(tmp_path, metadata, streams, message):
    with pytest.raises(ValueError, match=message):
        SessionWriter.create(tmp_path / "s.h5", metadata, streams)
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.parametrize("kwargs, message", [
    ({"channels": ()}, "distinct"), ({"channels": ("a", "a")}, "distinct"),
    ({"units": ("rad/s",)}, "units"), ({"counts_per_unit": 0.0}, "positive"),
    ({"rate_hz": float("nan")}, "rate_hz"), ({"dtype": "float32"}, "int32"),
])
def test_bad_stream_specs_are_refused(kwargs, message):
    fields = {"channels": ("a", "b"), "units": "rad/s", "counts_per_unit": 1.0, "rate_hz": 100.0}
    with pytest.raises(ValueError, match=message):
        StreamSpec(**{**fields, **kwargs})


def test_rows_of_a_cut_flush_are_ignored_and_dropped_on_resume(tmp_path):
    path = tmp_path / "s.h5"
    finished_session(path)  # 20 samples, events session_start and position_done
    with h5py.File(path, "r+") as f:  # what a flush cut by a kill can leave
        f["streams/imu/counts"].resize(25, axis=0)
        f["streams/imu/seq"].resize(23, axis=0)
        for column in ("time", "position", "kind", "detail_end"):
            f["events"][column].resize(3, axis=0)
        f["events/detail_end"][2] = f["events/detail"].shape[0] + 10  # text not written
    with Session.open(path) as s:
        assert len(s.stream("imu").counts) == 20 and len(s.events()) == 2
    with SessionWriter.resume(path) as w:
        assert w.flushed["imu"] == 20 and w.last_completed_position == 0
    with Session.open(path) as s:
        resumed = s.events()[-1]
        assert resumed.kind == "session_resumed"
        assert resumed.detail == {"dropped_rows": {"imu": 5, "events": 1}}
        with h5py.File(path, "r") as f:
            assert f["streams/imu/counts"].shape == (20, 12)


@pytest.mark.parametrize("offset, data", [(44, b"\0\0\0\0"), (11, b"\5")])
def test_a_damaged_superblock_is_refused(tmp_path, offset, data):
    path = tmp_path / "s.h5"
    finished_session(path)
    with open(path, "r+b") as fh:  # a wrong checksum; flags of a live writer without a checksum
        fh.seek(offset)
        fh.write(data)
    for call in (Session.open, SessionWriter.resume):  # at once, not after HDF5's SWMR retries
        with pytest.raises(SessionFormatError, match="checksum is wrong"):
            call(path)


def test_results_with_no_empty_field_read_back(tmp_path):
    """A calibration with every field set (biases estimated, the noise given: a per-pose term and
    the white-noise figure) stores an empty `none_fields` list."""
    rng = np.random.default_rng(11)
    _, _, readings = section4_gyros(rng, 30, 1e-3)
    readings = readings + rng.normal(0, 0.1, (12, 1))
    cal = calibrate(readings, 1.0, bias="estimate", sigma=1e-3)
    assert all(getattr(cal, f.name) is not None for f in dataclasses.fields(cal))
    path = tmp_path / "s.h5"
    w = new_session(path)
    w.append("imu", block(rng, 0, 10))
    w.write_results("live", "imu", readings, cal)
    with Session.open(path) as s:
        back = s.results("live").calibration
    assert np.array_equal(back.bias, cal.bias) and np.array_equal(back.a, cal.a)
