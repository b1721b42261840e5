"""Calibration protocols: what the station asks of the devices and the technician, step by step,
and `KINDS`, the one registry of protocol kinds.

- `rotary` (`station.protocols.rotary`): gyros on a rotary table, Rupniewski Section IV, Eq. 18;
- `iron` (`station.protocols.iron`): accelerometers in a right-angle iron, Hwangbo & Kanade;
- `static` (`station.protocols.static`): accelerometers in free still poses, no fixture;
- `import` (`station import`): a foreign recording, its accelerometer's still poses found in the
  data (the free-static path); it is solved, replayed and reported, never recorded.

A session file records its kind (`protocol` in its metadata); every command that depends on the
kind finds what to do in `KINDS` and nowhere else. A `Kind` names its parts as lazy references,
"module:attribute" strings imported only when a command uses them (python-can's BACKENDS style),
so importing this package costs nothing: no numpy, scipy, h5py or pymodbus. Adding a kind is one
entry here (docs/protocols.md, "Adding a protocol kind").
"""

import importlib
from dataclasses import dataclass

from station.errors import CalibrationInputError


@dataclass(frozen=True)
class Kind:
    """One protocol kind; each callable is a "module:attribute" reference (`entry`), None where the
    kind has no such part.

    title     : what the kind calibrates, one line for the help texts (`station simulate --help`)
    settings  : the settings dataclass of its state machine (the bench profile's [protocol] keys)
    acquire   : (bench, imu, table, out, operator, clock, spec, metadata, view) -> None: run the
                state machine with opened devices into the new session file `out` (`station
                record`; table None unless `table`; view: who watches, `station.acquire.watching`,
                or None; the terminal's LiveView only where `live_view`)
    table     : acquire needs the rotary table (the bench profile's [table]); else the bench
                profile gives the nominal `layout` of the accelerometers and `positions` come from
                the settings (`settings.poses`)
    live_view : acquire can show `station.acquire.live_view.LiveView` (the terminal's)
    resume    : (writer, metadata, imu, table, operator, clock, view=None) -> first position:
                continue a session after a kill, pause or abort (`station resume`; table None
                unless `table`; view as acquire's)
    reduce    : (session, stream, trim=seconds) -> readings with M, sigma (m, n), take(columns)
    still     : the reduction detects still poses and takes the user's detector settings
                (`still=station.reduce.stillness.StillOptions`: --rest, --threshold, ...)
    faces     : the reduction takes `faces=True` (--faces): the still poses are the faces of a
                right-angle block in one mounting, labelled from the data (Eq. 15 constraints)
    carry     : (session, gyro stream, accelerometer stream, still readings) -> (gyro, acc
                samples, still intervals): a stream in rad/s alone is a gyro triad calibrated
                by carrying gravity through the turns between the accelerometer's still poses
                (`station.replay.solve_carried`, docs/hand-turns.md); None: no such path
    stream    : session -> name of the stream calibrated by default; None: "imu"
    solve     : (readings, magnitude, nominal=, method=, refine=) -> CalibrationResult
    stimulus  : (words, metadata keys outermost first) of the recorded stimulus magnitude
    stimulus_default : (words, the magnitude's reference) used when the session records none
                (the commands say so); None: --magnitude is needed
    nominal_frame : the solution is given in the frame of the recorded nominal layout `a_nominal`
    channels  : (session, stream) -> indices of the calibrated channels; None: every channel
    bias      : readings -> the calibration file's bias terms; None: estimated by `solve`
    simulate  : (rng, effects, options) -> `station.sim` Simulation (`station simulate`; options:
                its arguments positions (None: the kind's default), fs, rate, turn_deg)
    twin      : options -> a virtual bench for `station twin` (a context manager with
                profile_text, addresses, truth, error; options: its arguments seed, speed,
                positions, mountings, rate_hz, lifetime); ValueError for options it cannot serve
    """

    title: str
    settings: str | None = None
    acquire: str | None = None
    table: bool = False
    live_view: bool = False
    resume: str | None = None
    reduce: str | None = None
    still: bool = False
    faces: bool = False
    carry: str | None = None
    stream: str | None = None
    solve: str | None = None
    stimulus: tuple = ("gravity", ("gravity",))
    stimulus_default: tuple | None = None
    nominal_frame: bool = False
    channels: str | None = None
    bias: str | None = None
    simulate: str | None = None
    twin: str | None = None

    def entry(self, role: str):
        """The object the `role` reference names, imported now (check `has(role)` first)."""
        return reference(getattr(self, role))

    def has(self, role: str) -> bool:
        """True when the kind has a `role` part."""
        return getattr(self, role) is not None


def reference(ref: str):
    """The object a "module:attribute" reference names, imported now."""
    module, _, attribute = ref.partition(":")
    return getattr(importlib.import_module(module), attribute)


KINDS = {
    "rotary": Kind(
        title="gyros on a rotary table (Rupniewski, Eq. 18)",
        settings="station.protocols.rotary:RotarySettings",
        acquire="station.protocols.rotary:record_session",
        table=True,
        live_view=True,
        resume="station.protocols.rotary:continue_session",
        reduce="station.reduce.rotary:rotary_readings",
        solve="station.solve.rotary:calibrate_rotary",
        stimulus=("table rate", ("settings", "rate")),
        channels="station.reduce.rotary:rotary_channels",
        bias="station.reduce.rotary:static_bias",
        simulate="station.sim.rotary:simulated_session",
        twin="station.twin.served:rotary_twin",
    ),
    "iron": Kind(
        title="accelerometers in a right-angle iron (Hwangbo & Kanade)",
        settings="station.protocols.iron:IronSettings",
        acquire="station.protocols.iron:record_session",
        resume="station.protocols.iron:continue_session",
        reduce="station.reduce.iron:iron_readings",
        still=True,
        solve="station.solve.still:calibrate_still",
        nominal_frame=True,
        simulate="station.sim.iron:simulated_session",
        twin="station.twin.served:iron_twin",
    ),
    "static": Kind(
        title="accelerometers in free still poses",
        settings="station.protocols.static:StaticSettings",
        acquire="station.protocols.static:record_session",
        resume="station.protocols.static:continue_session",
        reduce="station.reduce.static:static_readings",
        still=True,
        solve="station.solve.still:calibrate_still",
        nominal_frame=True,
        channels="station.reduce.static:session_channels",
        simulate="station.sim.static:simulated_session",
        twin="station.twin.served:static_twin",
    ),
    "import": Kind(
        title="an imported recording: accelerometer still poses found in the data, or a "
              "magnetometer turned by hand",
        reduce="station.reduce.imported:imported_readings",
        still=True,
        faces=True,
        carry="station.reduce.imported:carry_samples",
        stream="station.reduce.imported:default_stream",
        solve="station.solve.still:calibrate_still",
        stimulus_default=("standard gravity", "station.model.constants:STANDARD_GRAVITY"),
        channels="station.reduce.imported:imported_channels",
    ),
}
"""The protocol kinds, by the name a session file records as its `protocol`."""

VERBS = {"acquire": "records", "resume": "resumes", "reduce": "reduces", "solve": "solves",
         "simulate": "simulates", "twin": "serves virtual benches of"}
"""How an unknown-kind error says what a role does."""


class UnknownKind(CalibrationInputError):
    """A protocol kind that is not registered, or has no part for what was asked."""


def kinds_with(role: str) -> list:
    """Names of the registered kinds that have a `role` part, in registry order."""
    return [name for name, kind in KINDS.items() if kind.has(role)]


def lookup(name: str, role: str, subject: str | None = None, command: str = "the station") -> Kind:
    """The kind `name`, which must have a `role` part; else UnknownKind naming the kinds that have
    one. subject: what names the kind (default "protocol kind 'x'"), command: who asks."""
    kind = KINDS.get(name)
    if kind is not None and kind.has(role):
        return kind
    subject = subject or f"protocol kind {name!r}"
    unknown = "" if kind is not None else \
        f" ({name!r} is no registered protocol kind; the kinds are {', '.join(KINDS)})"
    raise UnknownKind(f"{subject}; {command} {VERBS[role]} "
                      f"{', '.join(kinds_with(role)) or 'no'} sessions{unknown}.",
                      "Import a foreign recording with `station import` (solved as an 'import' "
                      "session), or register the kind's part in station.protocols.KINDS.")
