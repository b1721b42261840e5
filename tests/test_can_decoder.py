"""The pure CAN sample assembler and the profile checks: hostile frames, counters, bad profiles."""

import tomllib
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can_imu import CanProfile, FrameLayout, SampleAssembler
from drivers.profile import Profile, ProfileError

PROFILE_PATH = Path(__file__).parents[1] / "drivers/profiles/imu12_can.toml"
PROFILE = CanProfile.load(PROFILE_PATH)
LAYOUT = FrameLayout(PROFILE)
IDS = [0x180, 0x181, 0x182]


def frame(index: int, counter: int, values=(0, 0, 0, 0)) -> can.Message:
    """Frame `index` (0..2) of a sample, packed by hand from the DBC layout: 8-bit counter, then
    four 14-bit two's-complement fields, little endian."""
    word = counter
    for j, v in enumerate(values):
        word |= (v & 0x3FFF) << (8 + 14 * j)
    return can.Message(arbitration_id=IDS[index], data=word.to_bytes(8, "little"),
                       is_extended_id=False)


def test_hand_packed_frames_decode_to_their_values():
    asm = SampleAssembler(LAYOUT)
    values = [(-8192, 8191, -1, 0), (1, 2, 3, 4), (-5, -6, 7000, -7000)]
    for i in range(3):
        asm.feed(frame(i, 42, values[i]), host_time=1.5)
    block = asm.take()
    np.testing.assert_array_equal(block.counts, [np.concatenate(values)])
    assert block.seq.tolist() == [42] and block.host_time.tolist() == [1.5]


def test_counter_wraps_into_a_monotonic_sequence():
    asm = SampleAssembler(LAYOUT)
    for k in range(250, 262):
        for i in range(3):
            asm.feed(frame(i, k % 256), host_time=0.0)
    assert asm.take().seq.tolist() == list(range(250, 262))
    assert (asm.stats.gaps, asm.stats.dropped) == (0, 0)


def test_a_lost_middle_frame_drops_only_its_sample():
    asm = SampleAssembler(LAYOUT)
    for counter, indices in [(1, [0, 1, 2]), (2, [0, 2]), (3, [0, 1, 2]), (4, [1, 2])]:
        for i in indices:
            asm.feed(frame(i, counter), host_time=0.0)
    asm.finish()
    assert asm.take().seq.tolist() == [1, 3]
    assert (asm.stats.incomplete, asm.stats.orphaned, asm.stats.gaps,
            asm.stats.dropped) == (2, 4, 1, 1)


garbage_frame = st.builds(
    lambda id_, ext, data, remote: [can.Message(
        arbitration_id=id_, is_extended_id=ext, data=None if remote else data,
        is_remote_frame=remote, dlc=len(data))],
    st.one_of(st.sampled_from(IDS), st.integers(0, 0x7FF)),
    st.booleans(),
    st.binary(min_size=0, max_size=8),
    st.booleans(),
)
sample_frames = st.builds(  # the three frames of one sample, some possibly lost
    lambda counter, values, lost: [frame(i, counter, values[4 * i:4 * i + 4])
                                   for i in range(3) if i not in lost],
    st.integers(0, 255),
    st.lists(st.integers(-8192, 8191), min_size=12, max_size=12),
    st.sets(st.integers(0, 2), max_size=3) | st.just(set()),
)
frames_strategy = st.lists(garbage_frame | sample_frames, max_size=40).map(
    lambda groups: [msg for group in groups for msg in group])


@settings(max_examples=300, deadline=None)
@given(frames_strategy)
def test_random_frames_never_raise_and_every_frame_is_accounted_for(msgs):
    asm = SampleAssembler(LAYOUT)
    for msg in msgs:
        asm.feed(msg, host_time=0.0)
    asm.finish()
    block = asm.take()
    s = asm.stats
    assert s.frames == len(msgs) == s.used + s.unknown + s.short + s.orphaned
    assert s.used == 3 * (s.samples + s.duplicates)  # a repeated sample's frames were used
    if block is not None:
        assert block.counts.shape == (s.samples, 12)
        assert np.count_nonzero(np.diff(block.seq) <= 0) == s.restarts  # else increasing
        assert block.counts.min() >= -8192 and block.counts.max() <= 8191


def profile_dict() -> dict:
    with PROFILE_PATH.open("rb") as f:
        return tomllib.load(f)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("can"), r"no \[can\] section"),
    (lambda d: d["can"].pop("counter"), r"\[can\] counter: missing"),
    (lambda d: d["can"]["signals"].pop("g12"), "must map exactly the channels"),
    (lambda d: d["can"].update(bitrate=500000), r"unknown keys \['bitrate'\]"),
    (lambda d: d["can"].update(dbc="missing.dbc"), "not found"),
    (lambda d: d["can"].update(frames=["IMU_GYRO_A", "NOPE"]), "'NOPE' .* is not in"),
    (lambda d: d["can"]["signals"].update(g1="IMU_GYRO_A.G9"), "'G9' is not in frame"),
    (lambda d: d["can"].update(counter="G1"), "not in frame 'IMU_GYRO_B'"),
    (lambda d: d["can"].update(id_offset=0x700), r"id_offset 1792 puts frame IMU_GYRO_A \(id "
                                                 r"0x180\) at 0x880, outside the 11-bit ids"),
    (lambda d: d["can"].update(id_offset=-0x181), "at -0x1, outside"),
])
def test_bad_profiles_are_refused_with_a_clear_message(edit, message):
    data = profile_dict()
    edit(data)
    with pytest.raises(ProfileError, match=message):
        FrameLayout(CanProfile.from_profile(Profile(str(PROFILE_PATH), data)))
