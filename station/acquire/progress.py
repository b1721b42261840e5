"""A progress bar of captured positions on stderr, for sessions that run without the live view
(`station demo`): the observer interface of `station.acquire.live_view.LiveView`, reduced to the
`position_done` events."""

import contextlib

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from station.protocols.rotary import Unwatched


class PositionProgress(Unwatched):
    """Counts the positions the recorder reports done; shown while `show()` runs."""

    def __init__(self, console: Console | None = None):
        self.console = console or Console(stderr=True)
        self._progress = None
        self._task = None
        self.total = 0

    def follow(self, protocol):
        self.total = len(protocol.axes)
        return protocol

    def observe_recorder(self, recorder):
        return _Counted(recorder, self)

    @contextlib.contextmanager
    def show(self):
        columns = (TextColumn("positions captured"), BarColumn(), MofNCompleteColumn(),
                   TimeElapsedColumn())
        with Progress(*columns, console=self.console, transient=True) as progress:
            self._progress = progress
            self._task = progress.add_task("positions", total=self.total)
            yield self

    def done(self, position: int) -> None:
        """Position `position` (0-based) was captured."""
        if self._progress is not None:
            self._progress.update(self._task, completed=position + 1)


class _Counted:
    """The recorder, passing every call through; `position_done` also advances the bar."""

    def __init__(self, recorder, progress: PositionProgress):
        self._recorder, self._bar = recorder, progress

    def __getattr__(self, name):
        return getattr(self._recorder, name)

    def event(self, kind, position=None, detail=None):
        time = self._recorder.event(kind, position, detail)
        if kind == "position_done" and position is not None:
            self._bar.done(position)
        return time
