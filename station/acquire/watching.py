"""Watching a running session: `Unwatched`, the observer interface of
`station.acquire.live_view.LiveView` that watches nothing.

A protocol's session runner asks its view to `follow` the protocol and to observe the three objects
the protocol talks through (the IMU driver, the operator, the recorder); each returns the object to
use, a proxy that tells the view or the object itself. The terminal's live view
(`station.acquire.live_view`), the demo's progress bar (`station.acquire.progress`) and the
browser's view (`station.serve.watch`) implement it; every protocol kind runs with any of them.
"""

import contextlib


class Unwatched:
    """No view: every observed object passes through unchanged."""

    def follow(self, protocol):
        return protocol

    def observe_imu(self, imu, name: str = ""):
        return imu

    def observe_operator(self, operator):
        return operator

    def observe_recorder(self, recorder):
        return recorder

    def show(self):
        return contextlib.nullcontext(self)
