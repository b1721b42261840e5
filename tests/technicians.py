"""Technicians at the console for the tests of `station record` on `station twin`'s bench."""

import io

from station.acquire.operator import ConsoleOperator


class QuitsAt:
    """A technician at the console who walks away (end of input, as Ctrl-D) when the station
    announces `words`: on a table with a motorised fixture the station needs no key press to
    mount, so the input ends at the next thing it says, not at the next question."""

    def __init__(self, words: str):
        self.words, self.console = words, ConsoleOperator(io.StringIO(""), io.StringIO())

    def prompt(self, text: str) -> None:
        if text.startswith(self.words):
            self.console.confirm("go on?")  # the input has ended: OperatorAbort
        self.console.prompt(text)

    def __getattr__(self, name):
        return getattr(self.console, name)
