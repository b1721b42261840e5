"""Wire formats of serial IMUs: one module per format, one small decode contract (as pymodbus'
framer/).

    crc.py     CRCs and byte sums of the binary format (numpy, many frames at once)
    binary.py  binary frames: sync | seq | time | counts | CRC (BinaryFrameParser, encode_frames)
    ascii.py   one sample per text line (AsciiLineParser, encode_lines)

A decoder takes the bytes as they arrive and says how much of the stream it used and what it
decoded: `decode(data, host_time, final=False) -> Decoded(used, block)`. `used` counts the bytes
this call decided (decoded into samples or skipped as garbage); the others stay buffered in the
decoder until more bytes decide them, or until `final` (no more bytes will come) decides them all.
`reset()` forgets the buffered bytes (a new connection); the counters in `stats` go on.
"""

from dataclasses import dataclass
from typing import NamedTuple, Protocol

from drivers import LinkStats
from drivers.samples import SampleBlock


@dataclass
class SerialStats(LinkStats):
    """Counters of a serial link (LinkStats' samples, gaps, dropped, and):

    bytes         : bytes received
    crc_failures  : sync candidates outside accepted frames whose CRC (or length field) did not
                    match
    bad_lines     : complete ASCII lines that did not parse
    resyncs       : times alignment was lost and found again (bytes skipped between two frames)
    skipped_bytes : bytes that belong to no accepted frame (garbage, partial and corrupted frames)
    """

    bytes: int = 0
    crc_failures: int = 0
    bad_lines: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0


class Decoded(NamedTuple):
    """What one `decode` call did: `used` bytes decided, `block` the samples decoded."""

    used: int
    block: SampleBlock


class Decoder(Protocol):
    """The decode contract every wire format implements (see the module docstring)."""

    stats: SerialStats

    def reset(self) -> None: ...

    def decode(self, data: bytes, host_time: float, final: bool = False) -> Decoded: ...
