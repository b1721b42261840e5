"""Damaged session files are refused by name before anything is computed from them (issue 20):
every chunk carries a fletcher32 checksum, and claimed sizes are checked against the storage held
(a check that could not finish is no verdict: test_session_check.py)."""

import struct

import h5py
import numpy as np
import pytest

from drivers.samples import SampleBlock
from station.cli import main
from station.errors import SessionFormatError
from station.session import Session, SessionWriter, StreamSpec
from station.session._repair import _lookup3
from station.session.check import checked

FS = 100.0
ROWS_PER_POSITION = 3000  # a little over two 64 KB chunks of 3 x int32 counts (5461 rows each)
POSITIONS = 4


def write_session(path):
    """Four positions of 3-channel samples, each spanned by position_start / position_done."""
    spec = StreamSpec(["a", "b", "c"], "m/s^2", 1000.0, FS)
    with SessionWriter.create(path, {"protocol": "damage-test", "unit_serial": "D1"},
                              {"imu": spec}) as w:
        for p in range(POSITIONS):
            seq = np.arange(p * ROWS_PER_POSITION, (p + 1) * ROWS_PER_POSITION)
            t = seq / FS
            w.event("position_start", p, time=float(t[0]))
            w.append("imu", SampleBlock(np.stack([seq % 7, seq % 11, seq % 13], 1).astype(np.int32),
                                        seq, t, t))
            w.event("position_done", p, time=float(t[-1]))
    return path


def zero_chunk(path, dataset: str, index: int) -> tuple:
    """Zero 4 KB in the middle of one stored chunk (a whole chunk of zeros, its checksum
    included, would pass fletcher32: the checksum of zeros is zero); the chunk's row range."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        info = ds.id.get_chunk_info(index)
        rows = (info.chunk_offset[0], min(info.chunk_offset[0] + ds.chunks[0], ds.shape[0]))
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes(4096))
    return rows


def test_an_intact_session_passes(tmp_path):
    checked(write_session(tmp_path / "s.h5"))


def test_a_damaged_chunk_is_named_with_its_positions(tmp_path):
    path = write_session(tmp_path / "s.h5")
    first, end = zero_chunk(path, "streams/imu/counts", 1)
    hit = sorted({r // ROWS_PER_POSITION for r in range(first, end)})
    with pytest.raises(SessionFormatError) as err:
        checked(path)
    words = str(err.value)
    assert f"/streams/imu/counts rows {first}-{end - 1}" in words
    assert f"position(s) {hit[0] + 1}-{hit[-1] + 1}" in words
    others = [p for p in range(POSITIONS) if p not in hit]
    assert others, "the test needs an undamaged position"
    checked(path, positions=others)  # damage elsewhere is let through
    with pytest.raises(SessionFormatError):
        checked(path, positions=hit[:1])
    with Session.open(path) as s:
        data = s.stream("imu")
    kept = np.setdiff1d(np.arange(POSITIONS * ROWS_PER_POSITION), np.arange(first, end))
    np.testing.assert_array_equal(data.seq, kept)  # the damaged rows dropped, as lost samples
    np.testing.assert_array_equal(data.counts[:, 1], kept % 11)


def test_the_cli_refuses_a_damaged_file_in_one_line(tmp_path, capsys):
    path = write_session(tmp_path / "s.h5")
    zero_chunk(path, "streams/imu/host_time", 0)
    assert main(["solve", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "is damaged: /streams/imu/host_time rows 0-" in err


def test_a_claim_beyond_the_stored_data_is_refused(tmp_path):
    path = write_session(tmp_path / "s.h5")
    with h5py.File(path, "r+") as f:
        for column in ("counts", "seq", "device_time", "host_time"):
            f["streams/imu"][column].resize(50_000_000, axis=0)
    with pytest.raises(SessionFormatError, match="claims 50000000 rows"):
        checked(path)


def test_a_killed_truncated_file_is_refused(tmp_path):
    """A killed writer's flags on a truncated file: read as a closed file, its length is checked
    (HDF5's SWMR reader skips that check and retries each read past the end for hours)."""
    path = write_session(tmp_path / "s.h5")
    data = bytearray(path.read_bytes())
    data[11] = 0x05  # open for SWMR write, as a killed writer leaves it
    struct.pack_into("<I", data, 44, _lookup3(bytes(data[:44])))
    path.write_bytes(bytes(data[:len(data) // 4]))  # metadata cut: the SWMR reader would sleep
    with pytest.raises(SessionFormatError, match=f"is damaged: .*truncated file: eof = "
                                                 f"{len(data) // 4}, .* stored_eof = "
                                                 f"{len(data)}"):
        checked(path)


def test_changed_metadata_text_is_refused(tmp_path):
    """The metadata JSON lives in HDF5's global heap, which has no checksum of its own."""
    path = write_session(tmp_path / "s.h5")
    data = bytearray(path.read_bytes())
    at = data.index(b'"unit_serial": "D1"')
    data[at + len('"unit_serial": "D')] = ord("7")
    path.write_bytes(bytes(data))
    with pytest.raises(SessionFormatError, match="does not match its checksum"):
        Session.open(path)
