"""The technician at a browser (`station.serve.operator.BrowserOperator`): a question waits for
its answer from any browser, wrong or late answers change nothing, a stop from a browser raises in
the protocol's call, and the messages kept for a browser that attaches are the latest."""

import threading

import numpy as np
import pytest

from station.acquire.operator import Instruction
from station.errors import OperatorAbort
from station.serve.operator import MESSAGES, BrowserOperator


def asking(operator, call, *args):
    """Run operator.call(*args) in a thread (the protocol's); (thread, result list) once the
    question is up."""
    result = []
    thread = threading.Thread(target=lambda: result.append(_outcome(getattr(operator, call),
                                                                     *args)))
    thread.start()
    while operator.asked is None:
        assert thread.is_alive()
        thread.join(0.01)
    return thread, result


def _outcome(call, *args):
    try:
        return call(*args)
    except OperatorAbort as exc:
        return exc


def test_a_confirmation_takes_the_first_valid_answer():
    operator = BrowserOperator()
    thread, result = asking(operator, "confirm", "the table does not answer: go on?")
    asked = operator.asked
    assert asked["kind"] == "confirm" and asked["orientation"] is None
    assert not operator.answer(asked["id"], "done")  # not an answer to a yes/no question
    assert not operator.answer(asked["id"] + 1, "no")  # another question's
    assert operator.answer(asked["id"], "no")
    assert not operator.answer(asked["id"], "yes")  # a second browser, too late
    thread.join(10)
    assert result == [False] and operator.asked is None


def test_an_instruction_shows_its_pose_until_done():
    operator = BrowserOperator()
    pose = np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])
    thread, result = asking(operator, "wait", Instruction("turn the unit", pose))
    assert operator.asked["orientation"] == pose.tolist()
    assert operator.messages[-1] == "turn the unit"
    assert operator.answer(operator.asked["id"], "done")
    thread.join(10)
    assert result == [None]


@pytest.mark.parametrize("call, args", [("wait", (Instruction("mount it"),)),
                                        ("confirm", ("go on?",))])
def test_a_stop_from_a_browser_raises_in_the_protocol(call, args):
    operator = BrowserOperator()
    thread, result = asking(operator, call, *args)
    operator.cancel(OperatorAbort("aborted from the browser"))
    thread.join(10)
    assert isinstance(result[0], OperatorAbort) and operator.asked is None
    with pytest.raises(OperatorAbort):  # and every question after it
        operator.confirm("again?")


def test_the_latest_messages_are_kept():
    operator = BrowserOperator()
    for k in range(MESSAGES + 5):
        operator.prompt(f"message {k}")
    assert operator.messages == [f"message {k}" for k in range(5, MESSAGES + 5)]
