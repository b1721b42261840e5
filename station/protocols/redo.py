"""Redo, do not warn: the one rule by which every protocol kind records a flagged window again.

A window is flagged when the live check of the captured window says the offline reduction would
refuse it or that the unit was not still (`station.reduce.window_quality`: samples missing or
timed twice, spikes, a stuck channel, noise beyond the stillness detector's `enter` against the
reference), or when the protocol saw the bench go wrong during it (`station.errors.FlaggedWindow`:
the table moved during a static window, its rate left the tolerance while rotating). An unattended
session cannot leave such a window for the end, where `station solve` would refuse it: the
position is recorded again at once (`Redo.attempt`), up to `redo_limit` times per position (the
bench profile's `[protocol] redo_limit`, default `REDO_LIMIT`); one more flagged attempt stops the
session with `RedoLimitError`, naming the position, the flag and what to do.

- rotary (and two-axis, plates, each soak of a thermal campaign): the table is stopped and the
  position recorded again from its rest, without re-mounting the unit
  (`station.protocols.rotary.RotaryProtocol._redo`);
- still poses held by hand (iron, static): the technician is asked to hold the unit still and the
  next `hold` seconds are taken (`station.protocols.still.PoseWatcher.hold`).

In the session file a redo is a `position_start` event of the same position whose detail carries
`{"again": true, "redo": n, "flags": [the flags of the attempt it supersedes]}`.
Nothing recorded is lost: the superseded attempt's samples and events stay in the file; every
reduction takes a position's last attempt (the windows after its last `position_start`:
`station.reduce.rotary.position_windows`, `station.reduce.still.pose_windows`), as it did for a
position recorded again after a fault. A flagged attempt never gets a `position_done`, so a session
killed during a redo, or stopped by `RedoLimitError`, resumes with that position
(docs/session-format.md). A resumed session counts its redos anew.
"""

import numpy as np

from station.errors import InputError, RedoLimitError
from station.reduce.window_quality import WindowQuality

REDO_LIMIT = 2
"""Redos of one position before the session stops, when the profile gives no `redo_limit`."""
MOST_REDOS = 10
"""The largest accepted `redo_limit`: a position flagged more often has a cause to be found."""


def check_redo_limit(value) -> None:
    """InputError unless `value` is a whole number from 0 to `MOST_REDOS`."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MOST_REDOS:
        raise InputError(f"redo_limit must be a whole number from 0 (stop at the first flagged "
                         f"window) to {MOST_REDOS}, got {value!r}; set [protocol] redo_limit in "
                         "the bench profile")


def window_flags(qualities: dict, against: str) -> list:
    """The flags of the windows `qualities` ({window name: WindowQuality}) in words, [] when
    every one is fine; `against`: what the noise was compared with ("the rest noise")."""
    flags = []
    for name, q in qualities.items():
        if q.problem is not None:
            flags.append(q.problem.rstrip("."))
        if q.noisy:
            flags.append(_not_still(name, q, against))
    return flags


def _not_still(name: str, q: WindowQuality, against: str) -> str:
    """"the static window was not still: its noise is 5.2x the rest noise (more than 2x)"."""
    return (f"the {name} window was not still: its noise is {np.sqrt(q.ratio):.1f}x {against} "
            f"(more than {np.sqrt(q.limit):.0f}x)")


class Redo:
    """Counts each position's redos against `limit` (see the module docstring); `what` names a
    position in messages ("position", "pose")."""

    def __init__(self, limit: int = REDO_LIMIT, what: str = "position"):
        check_redo_limit(limit)
        self.limit, self.what = limit, what
        self.counts = {}  # position -> redos recorded

    def attempt(self, position: int, flags: list) -> dict:
        """Position `position` (0-based) was flagged with `flags`: the detail of the
        `position_start` event that records it again; RedoLimitError once it was
        recorded again `limit` times."""
        n = self.counts.get(position, 0) + 1
        if n > self.limit:
            raise RedoLimitError(
                f"{self.what} {position + 1} was flagged on each of its {n} attempts (last: "
                f"{'; '.join(flags)}) and redo_limit is {self.limit}. Check the unit's mounting "
                "and the bench for vibration, a loose cable or a glitching sensor, or raise "
                "[protocol] redo_limit in the bench profile; then `station resume SESSION` "
                f"records the {self.what} again (everything recorded so far is kept)")
        self.counts[position] = n
        return {"again": True, "redo": n, "flags": list(flags)}

    def words(self, position: int, flags: list) -> str:
        """What the operator is told when `position` is recorded again."""
        n = self.counts[position]
        return (f"{self.what} {position + 1}: {'; '.join(flags)}: recording it again (redo {n} "
                f"of at most {self.limit})")
