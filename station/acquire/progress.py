"""A progress bar of captured positions, for sessions that run without the live view
(`station demo`): the observer interface of `station.acquire.live_view.LiveView`, reduced to the
`position_done` events, drawn by the commands' one progress bar (`station.commands.progress`,
passed in: the acquisition room does not import the commands)."""

import contextlib

from station.acquire.watching import Unwatched


class PositionProgress(Unwatched):
    """Counts the positions the recorder reports done; shown while `show()` runs.

    bar : (what, unit) -> a context manager yielding `advance(done, total)`
    """

    def __init__(self, bar):
        self._bar = bar
        self._advance = None
        self.total = 0

    def follow(self, protocol):
        self.total = len(protocol.axes)
        return protocol

    def observe_recorder(self, recorder):
        return _Counted(recorder, self)

    @contextlib.contextmanager
    def show(self):
        with self._bar("positions captured", "positions") as advance:
            self._advance = advance
            advance(0, self.total)
            yield self

    def done(self, position: int) -> None:
        """Position `position` (0-based) was captured."""
        if self._advance is not None:
            self._advance(position + 1, self.total)


class _Counted:
    """The recorder, passing every call through; `position_done` also advances the bar."""

    def __init__(self, recorder, progress: PositionProgress):
        self._recorder, self._bar = recorder, progress

    def __getattr__(self, name):
        return getattr(self._recorder, name)

    def event(self, kind, position=None, detail=None, *at):
        time = self._recorder.event(kind, position, detail, *at)  # at: the bound's time, if any
        if kind == "position_done" and position is not None:
            self._bar.done(position)
        return time
