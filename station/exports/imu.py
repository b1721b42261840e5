"""One IMU's calibration files as the other tools see them: what every export shares.

Other tools (Kalibr, ArduPilot, PX4, ROS, imucal) describe an IMU as an accelerometer triad and a
gyro triad with x, y, z axes. The station stores one calibration file per sensor type, each in its
own model (docs/conventions.md):

    z = a^T v + b        (a: d x m, column i = sensor i's sensitive vector; b after the projection)
    v = F (z - b),  F = (a a^T)^-1 a     (least-squares fusion; F = a^-T for a triad)

This module holds what the format modules (autopilot, kalibr, ros, imucal) share, written once:

- `Imu`: the accelerometer and/or gyro calibration given, each recognised by its units (m/s^2,
  rad/s), checked to be of one unit, and `Imu.common_frame` for the formats that put both triads
  in one frame;
- `triad`: a calibration refused unless it has m = 3 sensors (a redundant array or a single axis
  is not what these tools describe);
- `axis_noise`: the sensors' noise figures (`NoiseFigures`, per sensor) carried to the 3 axes of
  the calibrated vector through F;
- `per_axis`, `check_dropped`, `dropped_words`: the per-axis model of the autopilots, its
  parameters, the size of what it drops, the limit and the summary's sentence;
- `number`: float text that round-trips and that YAML 1.1 readers (PyYAML) take as a float;
  `safe_comment`: untrusted text made safe inside a comment line;
- `Written`: an export's text and the notes for the command's summary.
"""

from dataclasses import dataclass

import numpy as np

from station.calfiles.calfile import COUNTS, Calibration
from station.errors import InputError

KINDS = {"m/s^2": "accelerometer", "rad/s": "gyroscope"}
REFERENCE = {"accelerometer": (9.80665, "1 g"), "gyroscope": (1.0, "1 rad/s")}
"""The reading at which a dropped part is stated: standard gravity, 1 rad/s."""
NOISE_ADVICE = ("record the unit at rest (an hour or more for the random walks), then `station "
                "noise REST.h5 --store CAL.cal.json` stores its noise figures in the calibration "
                "file")


@dataclass(frozen=True)
class Imu:
    """The calibrations of one IMU: `acc` (m/s^2) and `gyro` (rad/s), either may be None."""

    acc: Calibration | None
    gyro: Calibration | None

    @classmethod
    def of(cls, first: Calibration, gyro: Calibration | None = None) -> "Imu":
        """The IMU of a calibration file (either kind, by its units) and an optional gyro file
        (`--gyro`); refused: magnetometers, two files of one kind, files of two units."""
        kind = kind_of(first, "the calibration file")
        if gyro is None:
            return cls(first, None) if kind == "accelerometer" else cls(None, first)
        if kind != "accelerometer":
            raise InputError(f"the first calibration file is a {kind} calibration ("
                             f"{first.units[0]}) and a gyro file was given too; give the "
                             "accelerometer calibration first and the gyro one after --gyro")
        if kind_of(gyro, "the --gyro file") != "gyroscope":
            raise InputError(f"the --gyro file holds an accelerometer calibration "
                             f"({gyro.units[0]}), not a gyro one (rad/s); give the gyro "
                             "calibration after --gyro")
        if gyro.unit_serial != first.unit_serial:
            raise InputError(f"the accelerometer calibration is for unit {first.unit_serial!r} "
                             f"and the gyro one for unit {gyro.unit_serial!r}; give two "
                             "calibrations of one unit")
        return cls(first, gyro)

    def need(self, format_name: str, *kinds: str) -> None:
        """Refuse unless the calibrations of `kinds` ("accelerometer", "gyroscope") were given."""
        given = {"accelerometer": self.acc, "gyroscope": self.gyro}
        missing = [k for k in kinds if given[k] is None]
        if missing:
            raise InputError(f"{format_name} needs an accelerometer and a gyro calibration; "
                             f"the {' and '.join(missing)} one is missing: give the "
                             "accelerometer file first and the gyro file after --gyro")

    def common_frame(self, format_name: str) -> None:
        """Refuse an accelerometer and a gyro calibration whose frames are not one frame: both
        `nominal` (each aligned to the unit's nominal axes), or the gyro carried by gravity
        through this accelerometer calibration's frame (station.solve.gyro_carry). Two
        `canonical` frames of Eq. (19) are each tied to their own sensors' axes, which differ by
        the unit's (unknown) misalignment between the triads."""
        acc, gyro = self.acc, self.gyro
        carried = str(gyro.fit.get("method", "")).startswith("gravity carry")
        if carried and gyro.frame == acc.frame:
            _carried_by(gyro, acc)
            return
        if acc.frame == gyro.frame == "nominal":
            return
        raise InputError(
            f"{format_name} puts both triads in one frame, but the accelerometer's is "
            f"{acc.frame!r} and the gyro's {gyro.frame!r} (each canonical frame is tied to its "
            "own sensors' axes); solve both against the unit's nominal layout (`station solve "
            "--nominal`), or calibrate the gyro from the turns between the accelerometer's "
            "poses (`station solve --stream GYRO`), which puts it in the accelerometer's frame")


def _carried_by(gyro: Calibration, acc: Calibration) -> None:
    """Refuse a carried gyro unless the accelerometer calibration it was carried with (the
    record `station solve --stream GYRO` keeps in its session) is `acc`: same stream's scale
    factors and biases (to 1e-9, the same solve)."""
    record = (gyro.session or {}).get("accelerometer")
    same = isinstance(record, dict) and all(
        np.shape(record.get(key)) == (acc.m,)
        and np.allclose(np.asarray(record[key], float), ours, rtol=1e-9, atol=1e-12)
        for key, ours in (("scale_factors", acc.scale_factors), ("bias", acc.bias)))
    if not same:
        raise InputError(
            "the gyro calibration was carried through the frame of another accelerometer "
            "calibration than the one given (its record of that accelerometer's scale factors "
            "and biases differs); give the accelerometer calibration of the same session and "
            "settings, or solve the gyro again against this one")


def si_readings(cal: Calibration, where: str) -> None:
    """Refuse a calibration of raw counts whose scale was not known (`units.readings` "counts"):
    the formats take readings in SI units, with biases and noise in them."""
    if cal.units[0] == COUNTS:
        raise InputError(
            f"{where} calibrates raw counts whose scale was not known (biases and noise in "
            f"counts, not {cal.quantity}); the export formats need readings in SI units: import "
            f"the recording again with the scale, `--unit NAME=counts:{cal.quantity}@SCALE` "
            f"(SCALE: counts per {cal.quantity}, from the sensor's data sheet), and solve it "
            "again")


def kind_of(cal: Calibration, where: str) -> str:
    """"accelerometer" or "gyroscope" from the calibration's units; magnetometers and raw counts
    (`si_readings`) refused."""
    si_readings(cal, where)
    kind = KINDS.get(cal.units[0])
    if kind is None:
        raise InputError(f"{where} is a calibration in {cal.units[0]} (a magnetometer); the "
                         "export formats describe accelerometers (m/s^2) and gyros (rad/s)")
    return kind


def triad(cal: Calibration, format_name: str) -> Calibration:
    """The calibration, refused unless it has 3 sensors in 3 dimensions."""
    if (cal.d, cal.m) != (3, 3):
        raise InputError(
            f"{format_name} describes a triad (3 sensors on x, y, z) but the "
            f"{kind_of(cal, 'calibration')} calibration of unit {cal.unit_serial!r} has "
            f"{cal.m} sensors in {cal.d} dimensions; export it with `--to c-header` (the full "
            "fusion matrix), or calibrate 3 of its sensors apart")
    return cal


def axis_noise(cal: Calibration, name: str, format_name: str) -> np.ndarray:
    """(3,) noise figure `name` ("white" or "random_walk") of each axis of the calibrated
    vector: the sensors' figures n_i (independent) carried through the fusion, the square
    roots of diag(F diag(n^2) F^T), in the vector's units (the readings' units times u/sqrt(s)
    or u/sqrt(Hz), as the figure). Refused when the calibration has no noise figures or this one
    could not be fitted (data too short)."""
    values = None if cal.noise is None else getattr(cal.noise, name)
    if values is None:
        what = "no noise figures" if cal.noise is None else f"no {name.replace('_', ' ')} figure"
        raise InputError(f"{format_name} needs the {kind_of(cal, 'calibration')}'s noise, but "
                         f"the calibration of unit {cal.unit_serial!r} has {what}; "
                         f"{NOISE_ADVICE}")
    values = np.asarray(values, float)
    if values.shape != (cal.m,) or not np.all(np.isfinite(values) & (values >= 0)):
        raise InputError(f"the {name.replace('_', ' ')} figures {values.tolist()} are not "
                         f"{cal.m} finite numbers >= 0, one per sensor; {NOISE_ADVICE}")
    return np.sqrt(np.diag(noise_covariance(cal, np.square(values))))


def noise_covariance(cal: Calibration, variances) -> np.ndarray:
    """(d, d) covariance F diag(variances) F^T of the calibrated vector from independent
    sensors' variances (m,), exactly symmetric (a covariance a reader may check)."""
    f = cal.fusion_matrix()
    cov = (f * np.asarray(variances, float)) @ f.T
    return (cov + cov.T) / 2


@dataclass(frozen=True)
class PerAxis:
    """A triad as an autopilot corrects it: v_k = (z_k - offset_k) * scale_k, axis by axis.

    offset  : (3,) the biases b, in the readings' units
    scale   : (3,) 1 / a_kk when the format has a scale, else ones
    dropped : worst case over directions of |v_per_axis - v| at the reference reading
              (REFERENCE: 1 g, 1 rad/s), in the readings' units: the largest singular value of
              (diag(scale) a^T - I) times the reference
    reference_text : "1 g" or "1 rad/s"
    """

    offset: np.ndarray
    scale: np.ndarray
    dropped: float
    reference_text: str


MAX_AXIS_ANGLE_DEG = 30.0
"""A sensor further than this from its frame axis is not that axis' sensor: a per-axis model
cannot use it."""


def per_axis(cal: Calibration, format_name: str, with_scale: bool) -> PerAxis:
    """The per-axis model of a triad (`with_scale` False: offsets only, as the autopilots
    correct a gyro).

    From z = a^T v + b, an autopilot computes v_k = (z_k - o_k) s_k. With o = b and s_k = 1 / a_kk
    (1 without a scale) it gives v' = S a^T v, S = diag(s): exact when a is diagonal; the part
    it drops is (S a^T - I) v, at most sigma_max(S a^T - I) |v| (the cross-axis terms, and the
    scale error when there is no scale). Refused when a sensor is more than MAX_AXIS_ANGLE_DEG
    from its frame axis (a frame not tied to the unit's axes, a sensor order other than x, y, z,
    or a sensor mounted reversed)."""
    triad(cal, format_name)
    kind = kind_of(cal, "calibration")
    cosines = np.diag(cal.a) / np.linalg.norm(cal.a, axis=0)
    angles = np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))
    worst = int(np.argmax(angles))
    if angles[worst] > MAX_AXIS_ANGLE_DEG:
        raise InputError(
            f"{format_name} corrects each axis with its own sensor, but {kind} sensor "
            f"{cal.sensors[worst]!r} points {angles[worst]:.0f} deg away from the {'xyz'[worst]} "
            f"axis of the calibration's {cal.frame} frame; solve the session against the unit's "
            "nominal layout (`station solve --nominal`, sensors in x, y, z order) so that the "
            "frame is the unit's axes")
    scale = 1.0 / np.diag(cal.a) if with_scale else np.ones(3)
    residual = scale[:, None] * cal.a.T - np.eye(3)
    value, text = REFERENCE[kind]
    dropped = float(np.linalg.norm(residual, 2) * value)
    return PerAxis(offset=np.array(cal.bias, float), scale=scale, dropped=dropped,
                   reference_text=text)


MAX_DROPPED = 0.01
"""The part of a reading a per-axis model may drop without --force: 1 % of the reference
reading (0.098 m/s^2 at 1 g, 0.01 rad/s at 1 rad/s), about a MEMS unit's uncalibrated
cross-axis sensitivity."""


def check_dropped(model: PerAxis, kind: str, format_name: str, force: bool) -> None:
    """Refuse a per-axis model that drops more than MAX_DROPPED of the reference reading,
    unless `force`."""
    value, text = REFERENCE[kind]
    if model.dropped > MAX_DROPPED * value and not force:
        raise InputError(
            f"{format_name}'s per-axis model of the {kind} drops up to {model.dropped:.3g} "
            f"{'m/s^2' if kind == 'accelerometer' else 'rad/s'} at {text} (cross-axis terms"
            f"{'' if kind == 'accelerometer' else ' and scale errors'} it cannot represent), "
            f"more than the limit of {MAX_DROPPED:.0%}; use a format with the full matrix "
            "(--to kalibr, imucal or c-header), or add --force to write it anyway")


def dropped_words(model: PerAxis, kind: str) -> str:
    """The summary's sentence on what a per-axis model drops."""
    unit = "m/s^2" if kind == "accelerometer" else "rad/s"
    return (f"{kind}: the per-axis model drops at most {model.dropped:.3g} {unit} at "
            f"{model.reference_text}")


def number(x) -> str:
    """A float as text that round-trips (Python's shortest repr) and that YAML 1.1 readers
    (PyYAML, which needs a '.' in a float) read as a float: 1e-05 -> 1.0e-05."""
    text = repr(float(x))
    if not np.isfinite(float(x)):
        raise InputError(f"{x!r} is not a finite number; the calibration cannot be exported")
    mantissa, sep, exponent = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + sep + exponent


@dataclass(frozen=True)
class Written:
    """An export: the file's text and the notes for the summary (dropped parts, what to set on
    the target, where the figures came from)."""

    text: str
    notes: tuple = ()


def safe_comment(text) -> str:
    """Untrusted text (a serial, a date) safe inside a one-line comment of any of the formats:
    letters, digits and a few marks; anything else becomes '?'."""
    return "".join(c if c.isalnum() or c in " _.:-/^+" else "?" for c in str(text))
