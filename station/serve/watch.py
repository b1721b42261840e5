"""What a running session shows in a browser: `BrowserView`, the terminal live view's state
(`station.acquire.live_view.LiveView`: phase, windows, table, links, stillness) kept for the page
instead of drawn, with what the page draws besides: the stream and the table's rate as plot
series, the positions done and the time left.

`snapshot(since)` is everything as JSON-ready values; its `series` and `rates` hold only the
points after `since` (the page's cursor), so an update costs what is new, whatever the session's
length. Every point carries its clock time and its index; `arrived` is the wall time the newest
sample reached the station, so the page can measure its own lag.
"""

import collections
import contextlib
import math
import time

import numpy as np
from rich.text import Text

from station.acquire.live_view import PHASES, LiveView, counter_words

STILL_PHASES = {
    "face": "asking for the next face of the iron",
    "pose": "asking for the next pose",
    "settle": "waiting for the unit to be put down and still",
    "hold": "recording the still pose",
}
"""The still-pose protocols' phases (`station.protocols.iron`, `static`) in words."""
KEPT = 4000
"""Plot points kept (at `plot_hz`, the last 80 s of the session's clock): a page that attaches
gets them all, a page that follows gets the new ones."""


class BrowserView(LiveView):
    """The live view of a session, kept for the browsers.

    clock    : the session clock
    counts_per_unit : the stream's (its counts -> SI units, for the plot and the stillness)
    channels : the stream's channel names
    watchdog : as `LiveView`'s
    plot_hz  : plot points per second of the session clock (block means)
    """

    def __init__(self, clock, counts_per_unit, channels, watchdog=None, plot_hz: float = 50.0):
        super().__init__(clock, watchdog=watchdog)
        self.counts_per_unit = np.asarray(counts_per_unit, float)
        self.channels = list(channels)
        self.plot_hz = plot_hz
        self.series = collections.deque(maxlen=KEPT)  # (index, clock t, values)
        self.rates = collections.deque(maxlen=KEPT)  # (index, clock t, table rate)
        self.done = []  # positions completed, in order
        self.arrived = math.nan  # wall time of the newest sample
        self._count = 0
        self._pending = []  # block means since the last plot point
        self._next_point = -math.inf
        self._first_start = None  # clock time of the first position started

    def follow(self, protocol):
        """Show `protocol`, on its clock (the view is made before the session's clock is)."""
        self.clock = getattr(protocol, "clock", self.clock)
        return super().follow(protocol)

    def show(self):
        """Nothing to draw here: the browsers ask for snapshots."""
        return contextlib.nullcontext(self)

    def observe_imu(self, imu, counts_per_unit=None, name: str = ""):
        """As `LiveView.observe_imu`, the stream's scale applied (the protocols give none)."""
        return super().observe_imu(imu, self.counts_per_unit, name)

    def on_samples(self, block, counts_per_unit=None, feed=None) -> None:
        super().on_samples(block, counts_per_unit, feed)
        if feed is not self.feeds[0]:
            return
        now = self.clock.now()
        values = np.asarray(block.counts, float) / self.counts_per_unit
        with self._lock:
            self.arrived = time.time()
            self._pending.append(values.mean(axis=0))
            if now >= self._next_point:
                self._next_point = now + 1.0 / self.plot_hz
                self.series.append((self._next(), now, np.mean(self._pending, axis=0)))
                self._pending = []

    def on_table(self, reading) -> None:
        super().on_table(reading)
        rate = self.protocol.motion(reading)[0] if hasattr(self.protocol, "motion") \
            else reading.rate
        with self._lock:
            self.rates.append((self._next(), self.clock.now(), float(rate)))

    def table_after(self, reading) -> None:
        """The table as read once the session ended (stopped, paused, failed): what the page
        shows then, not the last reading of the session."""
        with self._lock:
            self._table = reading

    def on_event(self, kind: str, position=None, detail=None, time=None) -> None:
        super().on_event(kind, position, detail, time)
        with self._lock:
            if kind == "position_start" and self._first_start is None:
                self._first_start = self.clock.now()
            elif kind == "position_done" and position not in self.done:
                self.done.append(position)

    def _next(self) -> int:
        self._count += 1
        return self._count

    # -- what the page gets ----------------------------------------------------------------------

    def snapshot(self, since: int = 0) -> dict:
        """The session's state now, with the plot points after index `since`."""
        p = self.protocol
        with self._lock:
            series = [(i, round(t, 3), np.round(v, 6).tolist()) for i, t, v in self.series
                      if i > since]
            rates = [(i, round(t, 3), round(r, 5)) for i, t, r in self.rates if i > since]
            table, done, arrived = self._table, list(self.done), self.arrived
            windows = dict(self._windows)
            feeds = [{"name": f.name, "rate": round(f.fps(), 1), "samples": f.samples,
                      "gaps": f.seq_gaps, "link": counter_words(f.imu)} for f in self.feeds]
        shown = {"series": series, "rates": rates, "channels": self.channels, "done": done,
                 "arrived": arrived, "cursor": self._count, "feeds": feeds,
                 "table": None if table is None else self.table_words(table),
                 "watchdog": None if self.watchdog is None else
                 Text.from_markup(self._watchdog_words(table)).plain,
                 "stillness": {"dispersion": None if math.isnan(self.dispersion)
                               else round(self.dispersion, 2), "still": self.still,
                               "enter": self.enter, "leave": self.leave}}
        if p is None:
            return shown
        total = positions(p)
        state = p.state
        shown.update(state=state, phase=PHASES.get(state) or STILL_PHASES.get(state, state),
                     position=min(p.position, total - 1), total=total,
                     time_left=self._time_left(len(done), total),
                     windows={name: {"fraction": round(f, 3), "words": w}
                              for name, (f, w) in self._windows_of(windows, table,
                                                                   state).items()})
        if hasattr(p, "instruction") and p.position < total:
            asked = p.instruction(p.position)
            shown["pose"] = {"text": asked.text, "orientation": asked.orientation.tolist()}
        return shown

    def _windows_of(self, windows, table, state: str) -> dict:
        """The rotary protocol's window progress (`LiveView`), none for the still-pose kinds."""
        return self._window_progress(windows, table, state) if hasattr(self.protocol, "axes") \
            else {}

    def _time_left(self, done: int, total: int) -> float | None:
        """Session clock seconds left, from the mean time of the positions done so far."""
        if not done or self._first_start is None:
            return None
        return round((self.clock.now() - self._first_start) / done * (total - done), 1)


def positions(protocol) -> int:
    """How many positions (rotary) or poses (still-pose kinds) the protocol records."""
    return len(protocol.axes) if hasattr(protocol, "axes") else protocol.settings.poses
