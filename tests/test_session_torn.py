"""A kill inside the in-place rewrite of a column's last chunk (`station.session.torn`):
the chunk holds some of the interrupted flush's rows beside the OLD fletcher32 checksum, so it
no longer reads back. Seen under load in 1 of about 40 kills (test_session_kill): the table's
210 durable rows all read as lost, and `SessionWriter.resume` failed ("filter returned failure
during read"). The rows the old checksum vouches for must be read, and the session resumed.

The torn chunk is made here as the kill leaves it: new rows written into the chunk's data, the
checksum trailer not yet rewritten (h5py's direct chunk write stores the bytes as given).
"""

import h5py
import numpy as np
import pytest

from drivers.samples import SampleBlock
from station.errors import SessionFormatError
from station.session import Session, SessionWriter, StreamSpec
from station.session.check import checked
from station.session.torn import verified_rows
from station.session.writer import CHUNK_BYTES

DURABLE = 210


class State:
    """A table state as the writer takes it."""

    def __init__(self, t: float):
        self.time, self.rate, self.angle, self.rate_setpoint = t, 1.0, 0.25 * t, 1.0
        self.running = self.ready = self.moving = self.at_rate = True
        self.fault = False


def times(rows):
    return 20.0 * np.arange(rows) + 7.0


@pytest.fixture
def session(tmp_path):
    """A closed session: DURABLE table states, 12-channel IMU rows and a position_done event."""
    path = tmp_path / "s.h5"
    spec = StreamSpec([f"g{i}" for i in range(12)], "rad/s", 1e6, 2000.0)
    with SessionWriter.create(path, {"protocol": "torn-test", "unit_serial": "T1"},
                              {"imu": spec}) as w:
        for t in times(DURABLE):
            w.append_table(State(float(t)))
        w.event("position_done", 0)
    return path


def tear(path, column="streams/table/time", new_rows=5, damage=None, durable=DURABLE):
    """Write `new_rows` more rows into the column's first chunk after its `durable` ones, keeping
    its old checksum (a kill before the trailer); or with `damage` (a slice of rows) zero those
    durable rows instead."""
    with h5py.File(path, "r+", libver=("v110", "v110")) as f:
        ds = f[column]
        mask, raw = ds.id.read_direct_chunk((0,))
        data = bytearray(raw)
        item = ds.dtype.itemsize
        if damage is None:
            extra = times(durable + new_rows)[durable:].astype(ds.dtype).tobytes()
            data[durable * item:(durable + new_rows) * item] = extra
        else:
            data[damage.start * item:damage.stop * item] = bytes((damage.stop - damage.start)
                                                                 * item)
        ds.id.write_direct_chunk((0,), bytes(data), mask)
        with pytest.raises(OSError):
            ds[:]


def test_a_torn_chunk_keeps_every_durable_row(session):
    tear(session)
    with Session.open(session) as s:
        assert np.array_equal(s.table().time, times(DURABLE))
    checked(session)  # the check every command runs first passes it: not damage


def test_a_torn_event_column_keeps_the_durable_events(session):
    """A kill inside the rewrite of an event column's last chunk (seen in test_session_kill under
    load: "/events/time does not read back intact"): the events before it are read, the
    interrupted flush's are not, and the session resumes."""
    with Session.open(session) as s:
        durable = [(e.kind, e.position) for e in s.events()]
    tear(session, "events/time", new_rows=3, durable=len(durable))
    with Session.open(session) as s:
        assert [(e.kind, e.position) for e in s.events()] == durable
    checked(session)
    with SessionWriter.resume(session) as w:
        w.event("position_done", 1)
    with Session.open(session) as s:
        after = [(e.kind, e.position) for e in s.events()]
    assert after[:len(durable)] == durable and after[-1] == ("position_done", 1)


def test_the_check_still_refuses_damaged_rows(session):
    tear(session, damage=slice(50, 60))
    with pytest.raises(SessionFormatError, match="streams/table/time rows 0-"):
        checked(session)


def test_a_torn_chunk_is_repaired_on_resume_and_the_session_continues(session):
    tear(session)
    with SessionWriter.resume(session) as w:
        w.append_table(State(1e4))
    with Session.open(session) as s:
        assert np.array_equal(s.table().time, [*times(DURABLE), 1e4])
        assert s.closed_cleanly
        with h5py.File(session, "r") as f:
            f["streams/table/time"][:]  # the chunk reads back: its checksum was rewritten


def test_a_torn_chunk_whose_flush_had_grown_the_column_keeps_the_durable_rows(session):
    with h5py.File(session, "r+", libver=("v110", "v110")) as f:
        f["streams/table/time"].resize(DURABLE + 5, axis=0)  # the flush's resize went through
    tear(session)
    with Session.open(session) as s:
        assert np.array_equal(s.table().time, times(DURABLE))  # cut to the columns' common rows
    with SessionWriter.resume(session) as w:
        w.append_table(State(1e4))
    with Session.open(session) as s:
        assert np.array_equal(s.table().time, [*times(DURABLE), 1e4])


@pytest.mark.parametrize("rows", [slice(50, 60), slice(DURABLE - 3, DURABLE)])
def test_damaged_durable_rows_are_not_vouched_for(session, rows):
    """Zeroed durable rows (damage, not a torn rewrite) match no prefix's checksum: the chunk's
    rows stay left out, as before, rather than read with the damage in them."""
    tear(session, damage=rows)
    with h5py.File(session, "r") as f:
        assert verified_rows(f["streams/table/time"], 0) is None
    with Session.open(session) as s:
        assert len(s.table().time) == 0


@pytest.mark.parametrize("column, dtype", [("streams/table/time", "f8"),
                                           ("streams/table/status", "u1"),
                                           ("streams/imu/counts", "i4"),
                                           ("events/kind", "S24")])
@pytest.mark.parametrize("rows", [1, 2, 63, 333])
def test_the_checksum_of_intact_chunks_is_hdf5s(tmp_path, column, dtype, rows):
    """On intact chunks of every column type and odd byte counts, the prefix of all the rows
    matches HDF5's own stored checksum: the recomputed fletcher32 is the library's."""
    path = tmp_path / "s.h5"
    spec = StreamSpec([f"g{i}" for i in range(12)], "rad/s", 1e6, 2000.0)
    rng = np.random.default_rng(rows)
    with SessionWriter.create(path, {"protocol": "torn-test", "unit_serial": "T1"},
                              {"imu": spec}) as w:
        for i in range(rows):
            w.append_table(State(float(rng.normal())))
            w.event("note", i)
        seq = np.arange(rows)
        w.append("imu", SampleBlock(rng.integers(-2**31, 2**31 - 1, (rows, 12)), seq,
                                    seq * 5e-4, seq * 5e-4))
    with h5py.File(path, "r") as f:
        ds = f[column]
        assert ds.dtype == np.dtype(dtype) and ds.chunks[0] * ds.dtype.itemsize <= 2 * CHUNK_BYTES
        got = verified_rows(ds, 0)
        assert got is not None and np.array_equal(got, ds[:ds.chunks[0]])
