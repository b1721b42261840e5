"""The serial twin's device end knows when nobody reads its port (`drivers.twins.pty.PtyLink`):
a port the station closed (or a killed station's) loses the frames due, as a real device's bytes
are lost, from the moment no program holds it open, not after `unread_after` wall seconds; a
station that holds the port open but reads slowly (a loaded host) loses nothing.
"""

import threading
import time

import numpy as np
import serial

from drivers.clock import ScaledClock
from drivers.profile import SerialImuProfile
from drivers.twins.pty import PtyLink
from drivers.twins.serial import OVERFLOW, SENT, SerialTwin

PATIENCE = 30.0
"""unread_after of these tests (wall s): far longer than any of them waits, so what they see comes
from the reader test, not the timer."""


def _fill(link: PtyLink) -> None:
    """Write until the pty takes no more bytes (nobody reads)."""
    stop = threading.Event()
    threading.Timer(0.3, stop.set).start()
    link.write(b"\0" * (1 << 20), stop)


def _unread_within(link: PtyLink, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if link.unread():
            return True
        time.sleep(0.01)
    return False


def test_a_full_pty_that_nobody_holds_open_is_unread_at_once():
    link = PtyLink(unread_after=PATIENCE)
    try:
        _fill(link)
        assert _unread_within(link, 1.0)
    finally:
        link.close()


def test_a_reader_that_holds_the_port_open_is_waited_for_then_its_close_is_seen():
    link = PtyLink(unread_after=PATIENCE)
    try:
        with serial.Serial(link.port, timeout=0.1):  # opened, never read: a host that is busy
            _fill(link)
            assert not _unread_within(link, 0.5)
        assert _unread_within(link, 1.0)
    finally:
        link.close()


def test_frames_due_while_the_station_is_away_are_lost_not_sent_late():
    """Read, close the port for 1 wall s (40 clock s at 40x), reopen: the frames of the absence
    are OVERFLOW in the twin's log and the first frame read again is of the reopening's time, not
    a backlog from the close; with the port open throughout no frame is lost."""
    profile = SerialImuProfile.load("imu12_serial")
    clock = ScaledClock(speed=40.0)
    m = len(profile.imu.channels)
    twin = SerialTwin(profile, lambda t: np.zeros((len(t), m), np.int64), clock=clock,
                      max_lag=np.inf, unread_after=PATIENCE)
    with twin:
        with serial.Serial(twin.port, timeout=0.05) as port:
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                port.read(1 << 16)
        seq, fate = twin.log()
        assert len(seq) > 0 and np.all(fate == SENT)
        closed = clock.now()
        time.sleep(1.0)
        with serial.Serial(twin.port, timeout=0.05) as port:
            reopened = clock.now()
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                port.read(1 << 16)
        seq, fate = twin.log()
    lost = seq[fate == OVERFLOW]
    # at 40x and 200 Hz the second away is about 8000 frames; most of them must be lost
    away = (reopened - closed) * twin.rate_hz
    assert len(lost) > 0.5 * away, (len(lost), away)
    assert twin.time_of(lost.min()) < closed + 10.0 and twin.time_of(lost.max()) > reopened - 10.0
