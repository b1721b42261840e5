"""A Ctrl-C or `kill` whose KeyboardInterrupt Python drops (the handler ran inside a finaliser or
a weakref callback: "Exception ignored in ...") is raised again where a protocol polls its devices
(station.acquire.interrupts); once handled it is not raised again. Seen on CI: `station record`
went on to the end of the session after a SIGTERM at a position's end."""

import os
import signal
from types import SimpleNamespace

import pytest

from station.acquire import interrupts
from station.protocols.still import run_states


class Finalised:
    """Sends itself `number` from its finaliser and runs on: the handler raises in there."""

    def __init__(self, number):
        self.number = number

    def __del__(self):
        os.kill(os.getpid(), self.number)
        for _ in range(10_000):  # the eval loop runs the Python handler here
            pass


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the dropped one
@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_dropped_interrupt_is_raised_again_until_handled(number):
    previous = interrupts.install()
    try:
        Finalised(number)  # its KeyboardInterrupt is printed and dropped, nothing raises here
        with pytest.raises(KeyboardInterrupt, match="SIGTERM|Ctrl-C"):  # the next one raises:
            os.kill(os.getpid(), signal.SIGTERM)  # the dropped one is not being handled
            for _ in range(10_000):
                pass
        with pytest.raises(KeyboardInterrupt, match="dropped"):
            interrupts.raise_dropped()
        interrupts.handled()
        interrupts.raise_dropped()  # handled: nothing more
    finally:
        interrupts.restore(previous)
    assert signal.getsignal(number) is previous[number]


def test_an_interrupt_that_propagates_is_handled_once():
    previous = interrupts.install()
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10_000):
                pass
        interrupts.handled()  # what the protocol does before stopping the table
        interrupts.raise_dropped()
    finally:
        interrupts.restore(previous)


def test_an_interrupt_a_library_turns_into_another_error_still_ends_as_the_interrupt():
    """Seen on CI: a Ctrl-C at a position's start landed inside a lock's handling, which raised
    `RuntimeError: cannot release un-acquired lock` instead: the table was stopped, but the
    station exited 1 with a traceback. The protocol now ends as interrupted (exit 130)."""

    def state():
        try:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10_000):  # the handler raises here
                pass
        except KeyboardInterrupt:
            raise RuntimeError("cannot release un-acquired lock") from None  # as threading did
        return "done"

    protocol = SimpleNamespace(state=None, position=2, handlers={"start": state})
    events = []
    recorder = SimpleNamespace(event=lambda *args: events.append(args))
    previous = interrupts.install()
    try:
        with pytest.raises(KeyboardInterrupt, match="Ctrl-C") as raised:
            run_states(protocol, recorder, "start")
        interrupts.raise_dropped()  # handled: nothing more
    finally:
        interrupts.restore(previous)
    assert isinstance(raised.value.__cause__, RuntimeError)
    assert events == [("abort", 2, {"state": "start",
                                    "error": "KeyboardInterrupt: interrupted (Ctrl-C)"})]
