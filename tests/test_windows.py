"""Windows as row ranges (station.reduce.windows) and the block-wise sample instants: the same
rows, readings and instants as masks over the whole stream (issue 17: cost linear in the work,
memory bounded)."""

import numpy as np
import pytest
from test_session_damage import ROWS_PER_POSITION, write_session, zero_chunk

from station.imports import npz
from station.imports.recordings import import_npz
from station.reduce import timeline, windows
from station.reduce.eq18 import Reduced, reduce_rotary
from station.reduce.rotary import position_windows, rotary_readings
from station.reduce.spikes import column_medians
from station.reduce.timeline import sample_times, segment_breaks
from station.reduce.windows import RowBlocks, StreamWindows, increasing_runs, window_ranges
from station.session import Session
from station.sim import rotary as rotary_sim
from station.sim.layouts import A_MODEL, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary


def resumed_stream(rng, k: int = 3000):
    """seq and host_time of a stream that restarts its numbering once and is resumed once (its
    first samples after the resume held back: NaN instants), and the break. The restarted
    segment overlaps the first in time."""
    seq = np.concatenate([np.arange(1000), np.arange(50, 1050), np.arange(2000, 2000 + k - 2000)])
    host = np.concatenate([np.arange(1000) / 100, 5 + np.arange(1000) / 100,
                           30 + np.arange(k - 2000) / 100])
    host = host + rng.exponential(0.003, k)
    host[2000:2100] = 31.0  # held back across the resume: one burst after it
    seq[2000:2100] = np.arange(1900, 2000)
    return seq, host, [30.5]


def test_window_rows_are_the_mask_rows_on_segments_and_nan():
    rng = np.random.default_rng(1)
    seq, host, breaks = resumed_stream(rng)
    t = sample_times(seq, host, 100.0, breaks)
    assert np.isnan(t).any() and len(increasing_runs(t)) >= 3
    runs = increasing_runs(t)
    for t0 in rng.uniform(-1, 45, 200):
        t1 = t0 + rng.uniform(0, 15)
        got = [i for a, b in window_ranges(t, runs, t0, t1) for i in range(a, b)]
        assert got == np.flatnonzero((t >= t0) & (t <= t1)).tolist()
        half = [i for a, b in window_ranges(t, runs, t0, t1, closed=False) for i in range(a, b)]
        assert half == np.flatnonzero((t >= t0) & (t < t1)).tolist()


def test_sample_times_do_not_depend_on_the_block_size(monkeypatch):
    seq, host, breaks = resumed_stream(np.random.default_rng(2))
    whole = sample_times(seq, host, 100.0, breaks)
    monkeypatch.setattr(timeline, "BLOCK", 7)
    np.testing.assert_array_equal(sample_times(seq, host, 100.0, breaks), whole)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """An imported 6-position simulated rotary session."""
    unit = gyro_array(np.random.default_rng(7), fs=50.0)
    sim = simulate_rotary(unit, 6, RotaryTiming(static=3, moving=12), a_nominal=A_MODEL)
    folder = tmp_path_factory.mktemp("windows")
    npz.write(folder / "rotary.npz", sim)
    return import_npz(folder / "rotary.h5", folder / "rotary.npz")


def whole_stream_readings(s) -> Reduced:
    """Eq. (18) readings from the whole stream held in memory, windows as masks over it: the
    reduction before the windows became row ranges."""
    data, table, events = s.stream("imu"), s.table(), s.events()
    t = sample_times(data.seq, data.host_time, data.spec.rate_hz, segment_breaks(events))
    parts = []
    for w in position_windows(events).values():
        static, rotating = ((t >= t0) & (t <= t1) for t0, t1 in w.values())
        ns, nr = int(static.sum()), int(rotating.sum())
        y = np.concatenate([data.counts[static], data.counts[rotating]])[None]
        angle = np.interp(np.concatenate([t[static], t[rotating]]), table.time, table.angle)
        parts.append(reduce_rotary(y, 1 / np.asarray(data.spec.counts_per_unit),
                                   {"static": np.array([0, ns]),
                                    "rotating": np.array([ns, ns + nr])}, angle=angle))
    return Reduced(**{name: np.concatenate([getattr(p, name) for p in parts], axis=-1)
                      for name in Reduced.__dataclass_fields__})


def test_windowed_reads_give_the_whole_stream_readings(session):
    with Session.open(session) as s:
        got, want = rotary_readings(s), whole_stream_readings(s)
    for name in Reduced.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@pytest.mark.parametrize("block_bytes", [1, 200, 1 << 23])
def test_readings_do_not_depend_on_the_block_size(session, monkeypatch, block_bytes):
    """Windows cut from blocks of one row, of a few samples (a window spans several blocks and a
    block several windows) and of the whole stream: the whole-stream readings, bit for bit."""
    monkeypatch.setattr(windows, "BLOCK_BYTES", block_bytes)
    with Session.open(session) as s:
        got, want = rotary_readings(s), whole_stream_readings(s)
    for name in Reduced.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def test_a_cut_of_a_block_is_what_a_read_of_its_rows_gives(tmp_path):
    """Blocks over a damaged counts chunk: each cut leaves out the rows a read of its own range
    leaves out, whether the block starts before, inside or after the damage."""
    path = write_session(tmp_path / "s.h5")
    first, end = zero_chunk(path, "streams/imu/counts", 1)
    rng = np.random.default_rng(5)
    with Session.open(path) as s:
        def read(a, b):
            part = s.stream("imu", a, b, columns=("counts",))
            return [part.counts], part.rows

        blocks = RowBlocks(read, 4000)
        starts = np.sort(rng.integers(0, 4 * ROWS_PER_POSITION - 50, 40))
        for a in [first - 10, first + 5, end - 3, *starts]:
            b = min(a + int(rng.integers(1, 2500)), 4 * ROWS_PER_POSITION)  # rows of the file
            (counts,), rows = blocks(a, b)
            (want,), want_rows = read(a, b)
            np.testing.assert_array_equal(counts, want)
            assert (rows is None) == (want_rows is None)
            if rows is not None:
                np.testing.assert_array_equal(rows, want_rows)


@pytest.mark.parametrize("k", [1, 2, 7, 200, 201])
def test_column_medians_are_numpys(k):
    rng = np.random.default_rng(k)
    for x in (rng.integers(-40, 40, (k, 5)).astype(np.int32), rng.normal(size=(k, 5))):
        np.testing.assert_array_equal(column_medians(x), np.median(x, axis=0))
    x = rng.normal(size=(k, 3))
    x[k // 2, 1] = np.nan
    np.testing.assert_array_equal(column_medians(x), np.median(x, axis=0))


def test_a_window_read_by_rows_is_the_masked_whole_stream(session):
    rng = np.random.default_rng(3)
    with Session.open(session) as s:
        whole, events = s.stream("imu"), s.events()
        windows = StreamWindows(s, "imu", events)
        t = sample_times(whole.seq, whole.host_time, whole.spec.rate_hz)
        np.testing.assert_array_equal(windows.t, t)
        for t0 in rng.uniform(t[0] - 1, t[-1], 20):
            t1 = t0 + rng.uniform(0, 30)
            index, counts = windows.read(t0, t1)
            inside = np.flatnonzero((t >= t0) & (t <= t1))
            np.testing.assert_array_equal(index, inside)
            np.testing.assert_array_equal(counts, whole.counts[inside])


def test_simulation_in_blocks_gives_the_whole_session_numbers(monkeypatch, tmp_path):
    def simulated(lazy):
        unit = gyro_array(np.random.default_rng(11), fs=20.0)
        return simulate_rotary(unit, 7, RotaryTiming(static=3, moving=12), a_nominal=A_MODEL,
                               lazy=lazy)

    monkeypatch.setattr(rotary_sim, "BLOCK_POSITIONS", 3)
    blocks = simulated(True)
    path, _ = npz.write(tmp_path / "blocks.npz", blocks)
    monkeypatch.setattr(rotary_sim, "BLOCK_POSITIONS", 7)
    whole = simulated(False)
    written = npz.read(path)
    assert set(written) == set(whole.arrays)
    for name, value in whole.arrays.items():
        np.testing.assert_array_equal(written[name], value, err_msg=name)
        assert written[name].dtype == np.asarray(value).dtype
