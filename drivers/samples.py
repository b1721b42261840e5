"""The unit of data every IMU driver produces: a block of timestamped samples."""

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class SampleBlock:
    """k consecutive samples of m channels, as decoded from the wire.

    counts      : (k, m) int64   raw integer counts, exactly as sent by the device
    seq         : (k,)   int64   device sequence number, unwrapped: increasing within a segment
                                 (steps > 1 = dropped samples); it does not increase where the
                                 device restarted its numbering (`restart_seq`), the start of a
                                 new segment (`station.reduce.timeline.sample_times`)
    device_time : (k,)   float64 device timestamp in seconds (NaN where the device sends none)
    host_time   : (k,)   float64 host clock (drivers.clock) when the bytes were read, seconds
    """

    counts: np.ndarray
    seq: np.ndarray
    device_time: np.ndarray
    host_time: np.ndarray
    channels: tuple = field(default=())

    def __len__(self) -> int:
        return len(self.seq)

    @staticmethod
    def concat(blocks: list["SampleBlock"]) -> "SampleBlock":
        """One block holding all samples of `blocks` in order."""
        if not blocks:
            raise ValueError("no sample blocks to concatenate")
        return SampleBlock(
            counts=np.concatenate([b.counts for b in blocks]),
            seq=np.concatenate([b.seq for b in blocks]),
            device_time=np.concatenate([b.device_time for b in blocks]),
            host_time=np.concatenate([b.host_time for b in blocks]),
            channels=blocks[0].channels,
        )


def restart_seq(raw: int, last: int, modulus: int) -> int:
    """Unwrapped number of the first sample after a device restarted its counter at `raw`, the
    last sample before having had `last`: `raw` moved down by whole counter turns until it is at
    most `last`, so that the stream's numbering does not increase there (a new segment) and the
    samples before keep their numbers (and instants)."""
    return raw - modulus * max(0, -(-(raw - last) // modulus))
