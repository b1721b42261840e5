"""A session corrupted on purpose is never written as a good calibration file.

One rotary session is recorded on the virtual bench through the real drivers; each corruption
below rewrites a copy of it the way a broken link, a host clock, a device, a disk or a wrong
edit would (samples recorded twice, stretches dropped, clocks that jump, counts that glitch,
windows moved onto the table's ramps). `station solve`'s path (`solve_session`) must refuse every
one, by the reduction's checks (window sample counts, CalibrationInputError) or by the quality
gate (chi2 and outliers, SuspectFitError), while the clean copy is written with status "good".
"""

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from station.commands.solve import solve_session
from station.errors import CalibrationInputError, StationError, SuspectFitError
from station.protocols.rotary import RotarySettings, suggested_axes
from station.reduce.rotary import position_windows
from station.reduce.timeline import sample_times
from station.session import Session, SessionWriter
from station.twin.rotary_bench import VirtualBench, record_rotary

POSITIONS = 8
P = 3  # the position most corruptions hit (0-based)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A recorded 8-position rotary session (12 gyros, 200 Hz, seed 11)."""
    path = tmp_path_factory.mktemp("corruption") / "clean.h5"
    with VirtualBench("serial", seed=11) as bench:
        record_rotary(bench, path, RotarySettings(), suggested_axes(POSITIONS))
    return path


def load(path) -> SimpleNamespace:
    """Everything of a session as arrays the corruptions edit."""
    with Session.open(path) as s:
        imu, table, events = s.stream("imu"), s.table(), s.events()
        spec = s.specs["imu"]
        metadata = s.metadata
    t = sample_times(imu.seq, imu.host_time, spec.rate_hz)
    return SimpleNamespace(
        metadata=metadata, spec=spec, counts=imu.counts.copy(), seq=imu.seq.copy(),
        device_time=imu.device_time.copy(), host_time=imu.host_time.copy(), t=t,
        table={k: getattr(table, k).copy() for k in ("time", "rate", "angle", "rate_setpoint",
                                                      "status")},
        events=[SimpleNamespace(time=e.time, kind=e.kind, position=e.position, detail=e.detail)
                for e in events],
        windows=position_windows(events))


def save(s: SimpleNamespace, path) -> None:
    """Write `s` as a new session file."""
    with SessionWriter.create(path, s.metadata, {"imu": s.spec}) as w:
        w.append("imu", SimpleNamespace(counts=s.counts, seq=s.seq, device_time=s.device_time,
                                        host_time=s.host_time, channels=s.spec.channels))
        tb = s.table
        w.append_table([SimpleNamespace(
            time=t, rate=r, angle=a, rate_setpoint=sp,
            **{bit: bool(st >> i & 1) for i, bit in enumerate(
                ("running", "ready", "moving", "at_rate", "fault"))})
            for t, r, a, sp, st in zip(tb["time"], tb["rate"], tb["angle"], tb["rate_setpoint"],
                                       tb["status"], strict=True)])
        for e in s.events:
            if e.kind != "session_start":
                w.event(e.kind, e.position, e.detail, time=e.time)


def inside(s, name: str, j: int = P, part=(0.0, 1.0)):
    """Boolean mask of the samples in a fraction `part` of window `name` of position j."""
    t0, t1 = s.windows[j][name]
    a, b = t0 + part[0] * (t1 - t0), t0 + part[1] * (t1 - t0)
    return (s.t >= a) & (s.t <= b)


def keep(s, mask) -> None:
    """Keep only the samples where `mask` holds."""
    for name in ("counts", "seq", "device_time", "host_time", "t"):
        setattr(s, name, getattr(s, name)[mask])


def insert_copy(s, mask) -> None:
    """The samples of `mask` recorded a second time, right after themselves."""
    order = np.argsort(np.concatenate([np.arange(len(s.seq)), np.flatnonzero(mask) + 0.5]),
                       kind="stable")
    for name in ("counts", "seq", "device_time", "host_time", "t"):
        x = getattr(s, name)
        setattr(s, name, np.concatenate([x, x[mask]])[order])


def shift_clock(s, after: float, dt: float) -> None:
    """The host clock jumps by dt at `after`: every later arrival, table state and event."""
    s.host_time[s.host_time > after] += dt
    s.table["time"][s.table["time"] > after] += dt
    for e in s.events:
        e.time += dt if e.time > after else 0.0


def move_event(s, kind: str, dt: float, j: int = P) -> None:
    for e in s.events:
        if e.kind == kind and e.position == j:
            e.time += dt


def scale_counts(s, mask, factor, channels=slice(None)) -> None:
    s.counts[np.ix_(mask, np.arange(s.counts.shape[1])[channels])] = np.round(
        s.counts[np.ix_(mask, np.arange(s.counts.shape[1])[channels])] * factor)


def rotating_mid(s, j: int = P) -> float:
    t0, t1 = s.windows[j]["rotating"]
    return 0.5 * (t0 + t1)


def _stuck(s):
    m = inside(s, "rotating")
    s.counts[m, 4] = s.counts[np.flatnonzero(m)[0], 4]


def _bias_step(s, positions):
    for j in positions:
        m = inside(s, "rotating", j)
        s.counts[m, :3] += np.round(200 * np.abs(s.counts[m, :3]).mean()).astype(s.counts.dtype) \
            // 100 + 1


def _zero_block(s):
    rows = np.flatnonzero(inside(s, "rotating"))[100:100 + 4096 // (4 * s.counts.shape[1])]
    s.counts[rows] = 0


def _byte_flips(s):
    rows = np.flatnonzero(inside(s, "rotating"))[::97][:20]
    s.counts[rows, rows % s.counts.shape[1]] ^= 1 << 20


def _swap(s):
    m = inside(s, "rotating")
    s.counts[np.ix_(m, [1, 2])] = s.counts[np.ix_(m, [2, 1])]


def _clip(s):
    m = inside(s, "rotating")
    limit = np.abs(s.counts[m]).max(axis=0) // 2
    s.counts[m] = np.clip(s.counts[m], -limit, limit)


def _spliced(s):
    m = inside(s, "rotating", part=(0.3, 0.7))
    rng = np.random.default_rng(5)
    s.counts[m] = rng.permutation(s.counts[m], axis=1)  # another unit's channel order


def _stretch(s, factor):
    s.host_time *= factor
    s.table["time"] *= factor
    for e in s.events:
        e.time *= factor


def _rate_doubled(s):
    s.spec = type(s.spec)(s.spec.channels, s.spec.units, s.spec.counts_per_unit,
                          2 * s.spec.rate_hz, s.spec.dtype, s.spec.device)


CORRUPTIONS = {
    "window recorded twice": lambda s: insert_copy(s, inside(s, "rotating")),
    "session tail recorded twice": lambda s: insert_copy(s, s.t > s.windows[5]["static"][0]),
    "every tenth sample twice": lambda s: insert_copy(s, np.arange(len(s.seq)) % 10 == 0),
    "static window 30 % dropped": lambda s: keep(s, ~inside(s, "static", part=(0.2, 0.5))),
    "rotating window half dropped": lambda s: keep(s, ~inside(s, "rotating", part=(0.5, 1.0))),
    "static window dropped": lambda s: keep(s, ~inside(s, "static")),
    "host clock jumps forward": lambda s: shift_clock(s, rotating_mid(s), 20.0),
    "host clock jumps backward": lambda s: shift_clock(s, rotating_mid(s), -20.0),
    "sequence numbers jump": lambda s: s.seq.__setitem__(s.t > rotating_mid(s),
                                                         s.seq[s.t > rotating_mid(s)] + 5000),
    "gain glitch in a window": lambda s: scale_counts(s, inside(s, "rotating"), 1.05),
    "sign flip of one channel": lambda s: scale_counts(s, inside(s, "rotating"), -1, slice(7, 8)),
    "bias step in a window": lambda s: _bias_step(s, [P]),
    "bias step over two positions": lambda s: _bias_step(s, [P, P + 1]),
    "stuck channel": _stuck,
    "zeroed 4 KB block": _zero_block,
    "flipped bits": _byte_flips,
    "swapped channels": _swap,
    "clipped rotation": _clip,
    "foreign counts spliced in": _spliced,
    "static window moved onto the spin-up": lambda s: (move_event(s, "static_end", 6.0),
                                                        move_event(s, "static_start", 6.0)),
    "rotating window starts on the spin-up": lambda s: move_event(s, "rotate_start", -4.0),
    "host clock runs 20 % fast": lambda s: _stretch(s, 1.2),
    "sample rate recorded twice too high": _rate_doubled,
}


def test_the_clean_session_is_written_as_good(clean, tmp_path):
    copy = tmp_path / "copy.h5"
    save(load(clean), copy)  # the rewrite itself changes nothing the solver sees
    for path in (clean, copy):
        cal = solve_session(path)
        assert cal.fit["status"] == "good" and cal.fit["status_reasons"] == []


@pytest.mark.parametrize("name", sorted(CORRUPTIONS))
def test_a_corrupted_session_is_never_written_as_good(clean, tmp_path, name):
    s = load(clean)
    CORRUPTIONS[name](s)
    path = tmp_path / "corrupt.h5"
    save(s, path)
    with pytest.raises(StationError) as refused:
        solve_session(path)
    assert isinstance(refused.value, CalibrationInputError | SuspectFitError)
    assert "mounting" not in str(refused.value) or "not the cause" in str(refused.value)


def test_accept_suspect_writes_the_fit_marked_with_its_reasons(clean, tmp_path):
    s = load(clean)
    scale_counts(s, inside(s, "rotating"), 1.05)
    save(s, tmp_path / "glitch.h5")
    cal = solve_session(tmp_path / "glitch.h5", accept_suspect=True)
    assert cal.fit["status"] == "suspect" and cal.fit["status_reasons"]
    shutil.copy(tmp_path / "glitch.h5", tmp_path / "again.h5")
    with pytest.raises(SuspectFitError, match="accept-suspect"):
        solve_session(tmp_path / "again.h5")
