"""The technician at the bench, as the protocols see them.

A protocol talks to an operator through three calls:
- `prompt(text)`: tell them what is going on (no answer expected);
- `wait(instruction)`: ask them to do something with their hands (e.g. re-mount the unit) and
  block until they say it is done;
- `confirm(question) -> bool`: a yes/no question.

`ConsoleOperator` is the person at the keyboard of the `station` CLI. `SimulatedTechnician` is the
virtual bench's technician: it takes the re-mounting time on the shared clock, then turns the
simulated unit (`station.sim.live.MountedUnit.orientation`) as instructed, with a small placement
error, and remembers what it really did (the truth).
"""

import sys
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from station.errors import OperatorAbort


@dataclass(frozen=True)
class Instruction:
    """Something the technician must do before the protocol goes on.

    text        : what to do, in words
    orientation : for a mounting, the 3 x 3 rotation table frame -> unit frame asked for (its
                  third column is the unit-frame direction that must point up the table axis)
    """

    text: str
    orientation: np.ndarray | None = None


class ConsoleOperator:
    """A person at a terminal: instructions are printed, 'done' is the Enter key.

    End of input (Ctrl-D) raises OperatorAbort, so the protocol stops the table and closes the
    session cleanly.
    """

    def __init__(self, stdin=None, stdout=None):
        self.stdin = stdin or sys.stdin
        self.stdout = stdout or sys.stdout

    def prompt(self, text: str) -> None:
        print(text, file=self.stdout, flush=True)

    def wait(self, instruction: Instruction) -> None:
        self._ask(f"{instruction.text}\n  press Enter when done (Ctrl-D aborts) ")

    def confirm(self, question: str) -> bool:
        while True:
            answer = self._ask(f"{question} [y/n] ").strip().lower()
            if answer in ("y", "yes", "n", "no"):
                return answer.startswith("y")
            self.prompt("  please answer y or n")

    def _ask(self, text: str) -> str:
        print(text, end="", file=self.stdout, flush=True)
        line = self.stdin.readline()
        if not line:
            raise OperatorAbort("the operator closed the input; session aborted")
        return line


class SimulatedTechnician:
    """The virtual bench's technician: re-mounts `mounted` (a MountedUnit) when asked.

    clock         : shared clock; re-mounting takes `remount_time` seconds of it
    placement_deg : standard deviation of the placement error about each axis, degrees
    rng           : numpy Generator (or seed) of the placement errors

    `orientations` lists the orientations really set, one per mounting: the truth of the stimulus
    direction (third column) at each position.
    """

    def __init__(self, mounted, clock, remount_time: float = 20.0, placement_deg: float = 0.5,
                 rng=None):
        self.mounted = mounted
        self.clock = clock
        self.remount_time = float(remount_time)
        self.placement_deg = float(placement_deg)
        self.rng = np.random.default_rng(rng)
        self.messages = []
        self.orientations = []

    def prompt(self, text: str) -> None:
        self.messages.append(text)

    def wait(self, instruction: Instruction) -> None:
        """Take `remount_time`, then set the asked orientation times a small random rotation."""
        self.prompt(instruction.text)
        if instruction.orientation is None:
            return
        self.clock.sleep(self.remount_time)
        error = Rotation.from_rotvec(np.radians(self.placement_deg) * self.rng.standard_normal(3))
        actual = np.asarray(instruction.orientation, float) @ error.as_matrix()
        self.mounted.orientation = actual
        self.orientations.append(actual)

    def confirm(self, question: str) -> bool:
        self.prompt(question)
        return True
