"""The technician at a browser, as the protocols see them (`station.acquire.operator`'s three
calls): `prompt` adds to the messages every browser shows; `wait` and `confirm` put a question
up (`asked`) and block until a browser answers it (`answer`), or the session is stopped from a
browser (`cancel`: the blocked call raises the stop's error, e.g. OperatorAbort, so the protocol
stops the table and records the abort as it does for Ctrl-D at the terminal)."""

import itertools
import threading

MESSAGES = 20
"""Messages kept for a browser that attaches (or reloads) mid-session."""


class BrowserOperator:
    """Prompts, instructions and questions for the browsers; answers from any of them."""

    def __init__(self):
        self.messages = []
        self.asked = None  # {"id", "kind": "wait" | "confirm", "text", "orientation"}
        self._ids = itertools.count(1)
        self._answer = None
        self._stopped = None
        self._cond = threading.Condition()

    def prompt(self, text: str) -> None:
        with self._cond:
            self.messages = [*self.messages[-(MESSAGES - 1):], text]

    def wait(self, instruction) -> None:
        self._ask("wait", instruction.text, instruction.orientation)

    def confirm(self, question: str) -> bool:
        return self._ask("confirm", question) == "yes"

    def answer(self, ask_id: int, value: str) -> bool:
        """A browser's answer ("done", "yes", "no") to question `ask_id`; False when that question
        is no longer asked (answered by another browser, or never asked)."""
        with self._cond:
            if self.asked is None or self.asked["id"] != ask_id:
                return False
            if value not in (("done",) if self.asked["kind"] == "wait" else ("yes", "no")):
                return False
            self._answer, self.asked = value, None
            self._cond.notify_all()
        return True

    def cancel(self, error: BaseException) -> None:
        """Stop the session: a question asked now, or the next one, raises `error`."""
        with self._cond:
            self._stopped = error
            self._cond.notify_all()

    def _ask(self, kind: str, text: str, orientation=None) -> str:
        """Put a question up and wait for its answer."""
        with self._cond:
            self._raise_if_stopped()
            self._answer = None
            self.asked = {"id": next(self._ids), "kind": kind, "text": text,
                          "orientation": None if orientation is None else orientation.tolist()}
        self.prompt(text)
        with self._cond:
            while self._answer is None:
                self._raise_if_stopped()
                self._cond.wait()
            return self._answer

    def _raise_if_stopped(self) -> None:
        if self._stopped is not None:
            self.asked = None
            raise self._stopped

