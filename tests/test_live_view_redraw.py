"""The terminal live view on a real terminal screen (pyte, a VT100 emulator, fed every byte the
view and the console operator wrote): one panel on the screen whatever was printed or asked
meanwhile, every prompt whole (none overdrawn), and no window bars of the previous position while
the next one is mounted."""

import io
import time

import pyte
from rich.console import Console

from station.acquire.live_view import LiveView
from station.acquire.operator import ConsoleOperator
from station.protocols.rotary import RotaryProtocol, suggested_axes

WIDTH, HEIGHT = 110, 400  # tall enough that nothing scrolls off: every line stays countable


class Terminal(io.StringIO):
    """A terminal: what is written is kept, and its screen is that text through pyte."""

    def isatty(self) -> bool:
        return True

    def screen(self) -> list:
        screen = pyte.Screen(WIDTH, HEIGHT)
        stream = pyte.Stream(screen)
        stream.feed(self.getvalue().replace("\n", "\r\n"))
        return [line.rstrip() for line in screen.display]


class Keyboard:
    """The technician pressing Enter at every question: the terminal echoes it."""

    def __init__(self, term: Terminal):
        self.term = term

    def readline(self) -> str:
        self.term.write("\n")
        return "\n"


class Clock:
    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t


def render_text(view) -> str:
    console = Console(file=io.StringIO(), width=WIDTH, record=True)
    console.print(view.render())
    return console.export_text()


def test_prompts_and_questions_leave_one_panel_and_whole_lines():
    term, clock = Terminal(), Clock()
    console = Console(file=term, force_terminal=True, width=WIDTH, height=40)
    view = LiveView(clock, rate_hz=200.0)
    protocol = view.follow(RotaryProtocol(table=None, operator=None, clock=clock,
                                          axes=suggested_axes(8)))
    operator = view.observe_operator(ConsoleOperator(Keyboard(term), term))
    asked = []
    with view.show(console, refresh_per_second=50):
        for j in range(3):
            protocol.position, protocol.state = j, "mount"
            time.sleep(0.05)  # the display refreshes meanwhile
            asked.append(protocol.instruction(j).text)
            operator.wait(protocol.instruction(j))
            view.on_event("position_start", j, {})
            protocol.state = "static"
            for words in (f"position {j + 1}: static window (10 s)",
                          f"position {j + 1}: rotating window (2 turns)"):
                operator.prompt(words)
                time.sleep(0.05)
            view.on_event("position_done", j, {})
        protocol.position, protocol.state = 3, "done"
    lines = term.screen()
    panels = [k for k, line in enumerate(lines) if "calibration session" in line]
    assert len(panels) == 1, "\n".join(lines)  # the final panel only, no stale copy
    for words in asked:  # each instruction whole, on its own line, never overdrawn
        assert any(line.startswith(words) for line in lines), (words, "\n".join(lines))
    assert sum("press Enter when done" in line for line in lines) == 3
    assert any(line == "position 3: rotating window (2 turns)" for line in lines)
    assert panels[0] > max(k for k, line in enumerate(lines) if "press Enter" in line)


def test_no_window_bars_of_the_previous_position_while_the_next_is_mounted():
    clock = Clock()
    view = LiveView(clock, rate_hz=200.0)
    protocol = view.follow(RotaryProtocol(table=None, operator=None, clock=clock,
                                          axes=suggested_axes(8)))
    protocol.position, protocol.state = 0, "static"
    view.on_event("position_start", 0, {})
    view.on_event("static_start", 0)
    clock.t = 10.0
    view.on_event("static_end", 0)
    assert "static window" in render_text(view)
    view.on_event("position_done", 0, {})
    protocol.position, protocol.state = 1, "mount"
    text = render_text(view)
    assert "static window" not in text and "do now" in text
