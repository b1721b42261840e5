"""The live view while a rotary session records: what the station is doing, in one rich panel.

Shown: the protocol phase in words, position k of n, a progress bar per window (static: seconds of
the static window elapsed; rotating: table angle swept of the whole turns asked), the table's rate,
setpoint and state, each IMU's samples per second and its link's CRC and gap counters (every unit
of a plate, named), a stillness indicator (the first IMU's), and the instruction the technician
has to carry out now and the next one.

The view is fed through a small observer interface (`LiveView.on_event`, `on_table`, `on_samples`,
`on_message`). The recorder and the protocol have no observer hook, so the view wraps the three
objects the protocol talks through - the IMU driver, the operator and the recorder - in thin
proxies that forward every call unchanged and tell the view; the protocol's `state` and `position`
are read from the protocol itself:

    view = LiveView(clock)
    operator = view.observe_operator(operator)
    protocol = view.follow(RotaryProtocol(table, operator, clock, settings, axes))
    with Recorder(writer, view.observe_imu(imu), clock=clock) as recorder, view.show():
        protocol.run(view.observe_recorder(recorder))

Stillness: the dispersion s = mean over channels of var_w(x_k) / var_ref,k over the last
`window` s of samples, var_ref the quietest window seen so far (docs/stillness.md's statistic, with
the rest period found on line); still below `enter`, moving above `leave` (hysteresis). At a
constant table rate the gyro signals are steady, so "still" means a steady signal; the table's own
`moving` flag is shown beside it.
"""

import collections
import contextlib
import math
import threading

import numpy as np
from rich.console import Console, Group
from rich.live import Live
from rich.markup import escape
from rich.panel import Panel
from rich.progress_bar import ProgressBar
from rich.table import Table

PHASES = {
    "mount": "waiting for the technician to mount the unit",
    "still": "waiting for the table to stand still",
    "static": "recording the static window (biases)",
    "spin_up": "starting the table",
    "settle": "waiting for the table rate to settle",
    "rotating": "recording the rotating window",
    "stop": "stopping the table",
    "rest": "waiting for the table to come to rest",
    "restart": "recording the position again",
    "done": "all positions recorded",
}
COUNTERS = ("crc_failures", "resyncs", "gaps", "dropped", "incomplete", "errors")
"""Link counters shown when the IMU driver's `stats` has them (every link's `drivers.LinkStats`:
gaps, dropped; serial `SerialStats`, CAN `CanStats`)."""


class LiveView:
    """State of the live view and its rendering; the observer callbacks may come from any thread.

    clock    : the session clock (window progress and rates are in its seconds)
    rate_hz  : the IMU's sample rate (default: the observed recorder's)
    window   : seconds of samples in the stillness statistic
    enter, leave : hysteresis of the stillness statistic, multiples of the reference variance
    watchdog : the table's watchdog as the session feeds it (`drivers.heartbeat.Watchdog`; False:
               its register map has none; None: not shown)
    """

    def __init__(self, clock, rate_hz: float | None = None, window: float = 0.5,
                 enter: float = 4.0, leave: float = 8.0, watchdog=None):
        self.protocol = None
        self.watchdog = watchdog
        self.clock = clock
        self.rate_hz = rate_hz
        self.window = window
        self.enter, self.leave = enter, leave
        self.feeds = []  # one `_Feed` per observed IMU, the first's samples feed the stillness
        self._lock = threading.Lock()
        self._windows = {}  # "static"/"rotating" -> (start clock time or angle, end or None)
        self._table = None
        self._message = ""
        self._recent = collections.deque()  # SI sample blocks of the last `window` s
        self._recent_count = 0
        self._reference = None  # quietest per-channel variance so far
        self._next_stillness = -math.inf  # clock time of the next stillness update
        self.dispersion = math.nan
        self.still = None
        self.display_error = None  # the first exception of a callback (shown, never raised)
        self._live = None  # the rich display while `show` runs

    # -- observer interface ----------------------------------------------------------------------

    def on_event(self, kind: str, position=None, detail: dict | None = None,
                 time: float | None = None) -> None:
        """A protocol event was recorded (`station.session.EVENT_KINDS`) at clock `time`
        (default now)."""
        now = self.clock.now() if time is None else time
        detail = detail or {}
        with self._lock:
            if kind == "position_start":
                self._windows = {}
            elif kind == "static_start":
                self._windows["static"] = (now, None)
            elif kind == "static_end" and "static" in self._windows:
                self._windows["static"] = (self._windows["static"][0], now)
            elif kind == "rotate_start":
                self._windows["rotating"] = (float(detail.get("angle", math.nan)), None)
            elif kind == "rotate_end" and "rotating" in self._windows:
                self._windows["rotating"] = (self._windows["rotating"][0],
                                             float(detail.get("angle", math.nan)))

    def on_table(self, reading) -> None:
        """A table state was read (`drivers.rotary_table.TableReading`)."""
        with self._lock:
            self._table = reading

    def on_message(self, text: str) -> None:
        """The technician was told something (a prompt or an instruction)."""
        with self._lock:
            self._message = text

    @property
    def samples(self) -> int:
        """Samples received from the first IMU."""
        return self.feeds[0].samples if self.feeds else 0

    @property
    def seq_gaps(self) -> int:
        """Sequence gaps of the first IMU."""
        return self.feeds[0].seq_gaps if self.feeds else 0

    def on_samples(self, block, counts_per_unit=None, feed=None) -> None:
        """A block of samples arrived (`drivers.samples.SampleBlock`) from the IMU of `feed`
        (default the first); `counts_per_unit` converts its counts to SI (only the stillness
        statistic uses them, so any scale works)."""
        now = self.clock.now()
        with self._lock:
            if feed is None:
                feed = self.feeds[0] if self.feeds else self._add_feed(None, "")
            feed.arrived(block, now)
            if feed is not self.feeds[0]:
                return
        x = np.asarray(block.counts, float)
        if counts_per_unit is not None:
            x = x / np.asarray(counts_per_unit, float)
        with self._lock:
            self._recent.append(x)
            self._recent_count += len(x)
            keep = max(2, int(self.window * self.rate_hz)) if self.rate_hz else math.inf
            while self._recent and self._recent_count - len(self._recent[0]) >= keep:
                self._recent_count -= len(self._recent.popleft())
            if self._recent_count >= keep and now >= self._next_stillness:
                self._next_stillness = now + self.window / 4
                self._update_stillness(np.concatenate(self._recent))

    # -- wiring ----------------------------------------------------------------------------------

    def follow(self, protocol):
        """Show `protocol` (`station.protocols.rotary.RotaryProtocol`: its state, position, axes
        and settings); returns it."""
        self.protocol = protocol
        return protocol

    def observe_imu(self, imu, counts_per_unit=None, name: str = ""):
        """A proxy of the IMU driver for the recorder: every block read also feeds the view
        (`name`: the unit's, shown when there are several)."""
        with self._lock:
            feed = self._add_feed(imu, name)
        return _ObservedImu(imu, self, counts_per_unit, feed)

    def _add_feed(self, imu, name: str) -> "_Feed":
        self.feeds.append(_Feed(imu, name))
        return self.feeds[-1]

    def observe_operator(self, operator):
        """A proxy of the operator for the protocol: what the technician is told feeds the view,
        and is printed or asked with the display off the screen (`aside`)."""
        return _Observed(operator, self, {"prompt": self.on_message,
                                          "wait": lambda i: self.on_message(i.text),
                                          "confirm": self.on_message}, around=self.aside)

    def observe_recorder(self, recorder):
        """A proxy of the recorder for the protocol: events and table states feed the view."""
        if self.rate_hz is None:
            self.rate_hz = getattr(recorder, "rate_hz", None)
        return _ObservedRecorder(recorder, self)

    @contextlib.contextmanager
    def show(self, console: Console | None = None, refresh_per_second: float = 4):
        """Display the view (rich.live) while the block runs, then leave its last state on the
        screen once. The display is transient: taken off (`aside`) it leaves no copy behind."""
        self._live = self._display(console, refresh_per_second)
        try:
            yield self
        finally:
            live, self._live = self._live, None
            live.stop()
            live.console.print(self.render())

    def _display(self, console, refresh_per_second: float) -> Live:
        """A transient rich display of the view, started."""
        live = Live(console=console, get_renderable=self.render,
                    refresh_per_second=refresh_per_second, transient=True)
        live.start()
        return live

    @contextlib.contextmanager
    def aside(self):
        """The display off the screen while the block runs (the technician is told or asked
        something on the terminal), then a new one below it: a prompt is never overdrawn, and no
        stale copy of the panel stays above it (a restarted display would first move up over
        the prompt by its last height)."""
        live = self._live
        if live is None:
            yield
            return
        live.stop()
        try:
            yield
        finally:
            if self._live is live:
                self._live = self._display(live.console, live.refresh_per_second)

    def guarded(self, callback, *args, **kwargs) -> None:
        """Call an observer callback; a failure is kept in `display_error`, never raised: a
        display problem must not stop a recording."""
        try:
            callback(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - shown in the view instead
            if self.display_error is None:
                self.display_error = exc

    # -- rendering -------------------------------------------------------------------------------

    def render(self) -> Panel:
        """The view as one rich renderable."""
        p = self.protocol
        if p is None:
            return Panel("waiting for the protocol to start", title="calibration session")
        n, j, state = len(p.axes), p.position, p.state
        with self._lock:
            windows, table, message = dict(self._windows), self._table, self._message
            feeds = [(f.name, f.fps(), f.samples, f.seq_gaps, f.imu) for f in self.feeds]
        grid = Table.grid(padding=(0, 2))
        grid.add_column(style="bold", no_wrap=True)
        grid.add_column()
        grid.add_row("phase", f"{PHASES.get(state, state)} [dim]({state})[/]")
        done = min(j, n) if state != "done" else n
        grid.add_row("position", Group(f"{min(j + 1, n)} of {n}", ProgressBar(n, done, 40)))
        for name, (fraction, words) in self._window_progress(windows, table, state).items():
            grid.add_row(f"{name} window", Group(words, ProgressBar(1.0, fraction, 40)))
        grid.add_row("table", self.table_words(table))
        if self.watchdog is not None:
            grid.add_row("watchdog", self._watchdog_words(table))
        for name, fps, samples, gaps, imu in feeds:
            named = f" {escape(name)}" if len(feeds) > 1 else ""
            grid.add_row(f"IMU{named}", f"{fps:.0f} samples/s, {samples} received, "
                                        f"{gaps} sequence gap(s)")
            grid.add_row(f"link{named}", counter_words(imu))
        grid.add_row("stillness", self._stillness_words())
        if state == "mount" and j < n:  # the station waits for this mounting: say it, and only it
            grid.add_row("[bold yellow]do now[/]",
                         f"[bold yellow]{escape(p.instruction(j).text)}[/], then "
                         "press Enter")
        else:
            grid.add_row("technician", escape(message) if message else "-")
            if j + 1 < n:
                grid.add_row("next", escape(p.instruction(j + 1).text))
        if self.display_error is not None:
            grid.add_row("[red]view error[/]", f"{self.display_error!r} (recording unaffected)")
        return Panel(grid, title="calibration session", border_style="blue")

    def _window_progress(self, windows, table, state: str) -> dict:
        """{"static" / "rotating": (fraction done, words)} of the current position; none while
        the next position is mounted (the windows shown are the last position's until its
        `position_start`)."""
        s, now, shown = self.protocol.settings, self.clock.now(), {}
        if state == "mount":
            return shown
        if "static" in windows:
            start, end = windows["static"]
            elapsed = (end if end is not None else now) - start
            shown["static"] = (min(1.0, elapsed / s.static), f"{elapsed:.1f} of {s.static:g} s")
        if "rotating" in windows:
            start, end = windows["rotating"]
            angle = end if end is not None else (self.protocol.motion(table)[1]
                                                 if table is not None else start)
            turns = abs(angle - start) / (2 * math.pi) if math.isfinite(start) else 0.0
            shown["rotating"] = (min(1.0, turns / s.revolutions),
                                 f"{turns:.2f} of {s.revolutions} turns")
        return shown

    @staticmethod
    def table_words(table) -> str:
        if table is None:
            return "no state read yet"
        flags = [name for name in ("running", "moving", "at_rate", "fault")
                 if getattr(table, name, False)]
        still = "turning" if getattr(table, "moving", False) else "standing still"
        inner = ""
        if getattr(table, "position_rate", None) is not None:  # a two-axis table's rate mode
            inner = (f"; position axis {table.position_rate:+.4f} rad/s at "
                     f"{table.position:.3f} rad")
        return (f"{table.rate:+.4f} rad/s (setpoint {table.rate_setpoint:+.4f}), {still}{inner}; "
                f"flags: {', '.join(flags) or 'none'}")

    def _watchdog_words(self, table) -> str:
        """The table's watchdog: none, armed (its period, the heartbeat's) or tripped."""
        w = self.watchdog
        if not w:
            return "[yellow]none[/] in the table's register map: a killed station leaves it turning"
        if getattr(table, "watchdog_tripped", False):
            return (f"[red]tripped[/]: no heartbeat for {w.period:g} s (between sessions, or "
                    "a stalled host), the table stopped itself; the next run clears it")
        return f"armed, {w.words()}; heartbeat every {w.beat:.2f} s"

    def _stillness_words(self) -> str:
        if self.still is None:
            return "measuring..."
        word = "[green]still[/]" if self.still else "[yellow]moving[/]"
        return f"{word} (dispersion {self.dispersion:.1f}; still below {self.enter:g})"

    # -- statistics ------------------------------------------------------------------------------

    def _update_stillness(self, x) -> None:
        """Dispersion of the latest window against the quietest one seen, with hysteresis."""
        var = np.var(x, axis=0)
        floor = np.finfo(float).tiny
        self._reference = var if self._reference is None else np.minimum(self._reference, var)
        self.dispersion = float(np.mean(var / np.maximum(self._reference, floor)))
        if self.still is None:
            self.still = self.dispersion < self.enter
        elif self.still and self.dispersion > self.leave:
            self.still = False
        elif not self.still and self.dispersion < self.enter:
            self.still = True


def counter_words(imu) -> str:
    """The link counters of an IMU driver's `stats` (COUNTERS)."""
    stats = getattr(imu, "stats", None)
    shown = [f"{name.replace('_', ' ')} {getattr(stats, name)}" for name in COUNTERS
             if isinstance(getattr(stats, name, None), int)]
    return ", ".join(shown) or "the driver keeps no counters"


class _Feed:
    """What the view keeps of one IMU's stream: the driver (for its counters), the unit's name,
    the samples and sequence gaps received, the arrivals of the last second."""

    def __init__(self, imu, name: str):
        self.imu, self.name = imu, name
        self.samples = self.seq_gaps = 0
        self._last_seq = None
        self._arrivals = collections.deque()  # (clock time, samples)

    def arrived(self, block, now: float) -> None:
        """Count a block received at clock time `now`."""
        seq = np.asarray(block.seq)
        if self._last_seq is not None:
            self.seq_gaps += int(np.sum(np.diff(np.concatenate([[self._last_seq], seq])) > 1))
        self._last_seq = int(seq[-1])
        self.samples += len(seq)
        self._arrivals.append((now, len(seq)))
        while self._arrivals and self._arrivals[0][0] < now - 1.0:
            self._arrivals.popleft()

    def fps(self) -> float:
        """Samples per second of the session clock over the last second of arrivals."""
        if len(self._arrivals) < 2:
            return 0.0
        span = self._arrivals[-1][0] - self._arrivals[0][0]
        return sum(k for _, k in list(self._arrivals)[1:]) / span if span > 0 else 0.0


class _Observed:
    """Forwards every attribute to `target`; the methods in `hooks` also call hook(*args), and
    run inside `around()` (a context manager) when one is given."""

    def __init__(self, target, view, hooks: dict, around=contextlib.nullcontext):
        self._target, self._view, self._hooks, self._around = target, view, hooks, around

    def __getattr__(self, name):
        value = getattr(self._target, name)
        hook = self._hooks.get(name)
        if hook is None:
            return value

        def observed(*args, **kwargs):
            self._view.guarded(hook, *args, **kwargs)
            with self._around():
                return value(*args, **kwargs)
        return observed


class _ObservedImu(_Observed):
    """The IMU driver: `read_block` also hands the block to the view."""

    def __init__(self, imu, view, counts_per_unit, feed):
        super().__init__(imu, view, {})
        self._counts_per_unit, self._feed = counts_per_unit, feed

    def read_block(self, *args, **kwargs):
        block = self._target.read_block(*args, **kwargs)
        if block is not None and len(block):
            self._view.guarded(self._view.on_samples, block, self._counts_per_unit, self._feed)
        return block


class _ObservedRecorder(_Observed):
    """The recorder: each event reaches the view with the clock time the session stored for it."""

    def __init__(self, recorder, view):
        super().__init__(recorder, view, {"table": view.on_table})

    def event(self, kind, position=None, detail=None, *at):
        time = self._target.event(kind, position, detail, *at)  # at: the bound's time, if any
        self._view.guarded(self._view.on_event, kind, position, detail, time=time)
        return time
