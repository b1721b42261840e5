"""`station.acquire.interrupts.Wake`, what `station twin`'s main thread waits on until it is told
to end: a Ctrl-C at any place of the wait leaves `set()` usable for the twin thread whose failure
ends the twin and for the SIGTERM handler; `threading.Event` is not (the same sweep finds where
its lock stays taken). A SIGTERM wakes the wait."""

import functools
import os
import signal
import threading

from signal_places import ends, interrupted_at

from station.acquire import interrupts


def blocked_after_a_ctrl_c(waker, code) -> list[str]:
    """The places where a Ctrl-C in the main thread's `wait(0.01)` leaves another thread's
    `set()` blocked; `waker()` makes a fresh waker for each place."""
    blocked, k = [], 1
    while True:
        fresh = waker()
        landed = interrupted_at(k, functools.partial(fresh.wait, 0.01), code)
        if landed is None:
            return blocked
        if not ends(fresh.set, 2):
            blocked.append(landed)
        k += 1


def test_a_ctrl_c_anywhere_in_the_wait_leaves_it_wakeable():
    wakes = []

    def waker():
        wakes.append(interrupts.Wake())
        return wakes[-1]

    try:
        code = (interrupts.__file__, threading.__file__)
        assert blocked_after_a_ctrl_c(waker, code) == []
        assert len(wakes) > 2 and all(wake.wait(5) for wake in wakes[:-1])  # woken by set()
    finally:
        for wake in wakes:
            wake.close()


def test_an_event_can_be_left_unwakeable_by_a_ctrl_c():
    """Why not `threading.Event`: its `wait` holds its lock inside a `with`."""
    assert blocked_after_a_ctrl_c(threading.Event, (threading.__file__,))


def test_a_sigterm_wakes_the_wait():
    wake = interrupts.Wake()
    previous = signal.signal(signal.SIGTERM, wake.set)
    try:
        threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGTERM)).start()
        assert wake.wait(30)
    finally:
        signal.signal(signal.SIGTERM, previous)
        wake.close()
