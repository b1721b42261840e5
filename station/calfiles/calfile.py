"""The calibration file: one unit's calibration as versioned, self-describing JSON.

    cal = Calibration.from_result(result, unit_serial="SN42", sensors=("g1", ..., "g12"),
                                  units="rad/s", bias=b, bias_sigma=sb, session={...})
    cal.save("SN42.cal.json")                 # refuses to overwrite unless overwrite=True
    cal = load("SN42.cal.json", unit_serial="SN42")   # refuses another unit's file
    v = cal.apply(z)                           # (m, k) SI readings -> (d, k) calibrated vectors

The file records everything needed to use the calibration without this software: the format name
and version, the software version, the conventions (docs/conventions.md: `a` is d x m, column i =
sensor i's sensitive vector; model z = a^T v + b with the bias after the projection; fusion
v = (a a^T)^-1 a (z - b)), the units (SI readings, raw counts per SI unit at the driver edge), the
unit's serial and each sensor's id, `a` and `b` with their 1-sigma values, their joint covariance
(version 2: order a row-major, then b; in the frame of `a`, whose gauge it removes; biases
measured apart from the fit are independent of `a`), the gauge-invariant scale factors and axis
angles with their 1-sigma values, the frame of `a`, the fit, the session it came from and the
date. Version 4 adds `uncertainty`: the sigmas above are the total figure (the readings' white
noise plus a per-pose error term estimated from the residuals, docs/solvers.md), `uncertainty`
holds that term and the white-noise figure beside them. Version 5 adds `noise`: each sensor's
white-noise density, bias instability and random walk from the static data by the Allan deviation
(`NoiseFigures`, docs/noise.md), null when not measured. Version 6 adds `temperature`: the
temperature model (biases and scale factors as polynomials in T - t_ref, the calibrated range,
the coefficients with their sigmas and covariance; station.model.temperature), null when there
is none; `a` and `b` are then the calibration at t_ref. Files of versions 1-5 still load.
Readings in raw counts whose scale was not known (`station import --unit NAME=counts:m/s^2`)
are said so: `units.readings` is "counts" and `units.stimulus` the SI unit of what they sense;
`a` is then in counts per stimulus unit, `b`, the noise and the temperature's bias terms in
counts (software before this refuses such a file by its readings' unit).
Floats are written as JSON numbers in Python's shortest round-trip form, so a load gives back
bit-identical arrays. A SHA-256 checksum over the canonical JSON of the content detects edits and
damage (it is not a signature).

Loading treats the file as untrusted: size limit, strict JSON (no NaN/Infinity, no duplicate keys),
format and version checked first, then the checksum, then every key, type, shape and unit; unknown
keys are refused. Errors are `CalibrationFileError` (a `ValueError`) naming the file, the problem
and what to do.
"""

import dataclasses
import errno
import hashlib
import json
import os
from dataclasses import dataclass, field

import numpy as np

from station.errors import CalibrationFileError, InputError
from station.files.provenance import software_version, utc_now
from station.limits import json_loads
from station.model import measurement
from station.model.temperature import MAX_ORDER, TemperatureModel, check_kelvin

FORMAT = "imu-station-calibration"
FORMAT_VERSION = 6
SUPPORTED_VERSIONS = (1, 2, 3, 4, 5, 6)  # 2 added `covariance`, 3 `verdict`, 4 `uncertainty`,
# 5 `noise`, 6 `temperature`
MAX_BYTES = 4 << 20
LIMITS = {"a": (1e-9, 1e12), "b": (0.0, 1e9), "magnitude": (1e-12, 1e9), "condition": (0.0, 1e8)}
"""Plausible ranges of finite numbers, wide enough for any unit in SI or raw counts: column norms
of a (scale factors: counts per SI unit of a magnetometer reach 1e7), |b| in SI units, the stimulus
magnitude, the condition number of a (sensitive axes nearly in one plane beyond it)."""
LIMIT_WORDS = {"a": "scale factor (a column norm)", "b": "bias", "magnitude": "magnitude",
               "condition": "condition number of a"}
SI_UNITS = ("rad/s", "m/s^2", "T")
COUNTS = "counts"
"""The readings' unit of raw counts whose scale was not known (the stimulus then in SI_UNITS)."""
FRAMES = ("canonical", "nominal")
CONVENTIONS_V1 = {
    "document": "docs/conventions.md",
    "model": "z_i = a_i . v + b_i + noise  (M = a^T v + b 1^T)",
    "sensitivity": "a is d x m (rows = frame axes, columns = sensors in the order of "
                   "unit.sensors); column i = sensor i's sensitive axis times its scale factor",
    "bias": "b has one entry per sensor, added after the projection, in the readings' units",
    "apply": "v = (a a^T)^-1 a (z - b), z = the m readings of one instant in SI units",
    "counts": "SI reading = raw counts / counts_per_unit",
    "matrices": "nested JSON lists, row-major",
}
CONVENTIONS = {**CONVENTIONS_V1,
               "covariance": "joint covariance of (a row-major, then b): (d m + m) x (d m + m), "
                             "in the frame of a; null when unknown"}
_KEYS_V1 = ("format", "format_version", "software_version", "created", "conventions", "unit",
            "units", "frame", "magnitude", "scale_known", "sensitivity", "bias", "invariants",
            "fit", "session", "checksum")
CONVENTIONS_V3 = {**CONVENTIONS,
                  "verdict": "the unit against its type's tolerances (station.solve.verdict): "
                             "overall PASS, FAIL or MARGINAL and each tested parameter; null "
                             "when no tolerances were given"}
CONVENTIONS_V4 = {**CONVENTIONS_V3,
                  "uncertainty": "every sigma (and the covariance) is the total figure: the "
                                 "readings' white noise plus pose_sigma, a per-pose error term "
                                 "estimated from the residuals (docs/solvers.md); white holds the "
                                 "white-noise figure of the same quantities; null when unknown"}
CONVENTIONS_V5 = {**CONVENTIONS_V4,
                  "noise": "each sensor's noise from static data by the overlapping Allan "
                           "variance, fitted as N^2/tau + (2 ln2/pi) B^2 + K^2 tau/3 (IEEE Std "
                           "952-1997 Annex C, docs/noise.md): white (N, white-noise density: "
                           "angle/velocity random walk), bias_instability (B), random_walk (K, "
                           "rate/acceleration random walk), each with its 1-sigma, in the units "
                           "given; a term null when the data did not resolve it for every "
                           "sensor; rate_hz and seconds of the static data; null when not "
                           "measured"}
CONVENTIONS_V6 = {**CONVENTIONS_V5,
                  "temperature": "the temperature model (docs/conventions.md, Temperature): at "
                                 "the unit's temperature T in K, x = T - t_ref, b_i(T) = b_i + "
                                 "sum_p bias[i][p-1] x^p and a_i(T) = a_i (1 + sum_p "
                                 "scale[i][p-1] x^p), a and b above being the calibration at "
                                 "t_ref; valid on range [t_min, t_max] K; covariance over (bias "
                                 "row-major, then scale row-major); null when none"}
_KEYS = {1: _KEYS_V1, 2: (*_KEYS_V1[:-1], "covariance", "checksum"),
         3: (*_KEYS_V1[:-1], "covariance", "verdict", "checksum"),
         4: (*_KEYS_V1[:-1], "covariance", "verdict", "uncertainty", "checksum"),
         5: (*_KEYS_V1[:-1], "covariance", "verdict", "uncertainty", "noise", "checksum"),
         6: (*_KEYS_V1[:-1], "covariance", "verdict", "uncertainty", "noise", "temperature",
             "checksum")}
_CONVENTIONS = {1: CONVENTIONS_V1, 2: CONVENTIONS, 3: CONVENTIONS_V3, 4: CONVENTIONS_V4,
                5: CONVENTIONS_V5, 6: CONVENTIONS_V6}
TEMPERATURE_KEYS = ("t_ref", "range", "orders", "bias", "bias_sigma", "scale", "scale_sigma",
                    "covariance", "units")
SCALE_RATIO = (0.1, 10.0)
"""a_i(T) / a_i(t_ref) must stay within these over the calibrated range: beyond, a temperature
model is no unit's (and applying it would divide by almost nothing)."""
NOISE_TERMS = ("white", "bias_instability", "random_walk")
NOISE_KEYS = ("white", "white_sigma", "bias_instability", "bias_instability_sigma", "random_walk",
              "random_walk_sigma", "rate_hz", "seconds", "units")
WHITE = ("a_sigma", "bias_sigma", "scale_factors_sigma", "axis_angles_sigma")
VERDICTS = ("PASS", "FAIL", "MARGINAL")


@dataclass(frozen=True, eq=False)
class NoiseFigures:
    """Each sensor's noise from its static data, by the Allan deviation (IEEE Std 952-1997 and
    1293-1998 terms); arrays (m,) in the order of `Calibration.sensors`, in the readings' units u
    (rad/s, m/s^2), each with its 1-sigma:

    white            : N, white-noise density (angle / velocity random walk), u sqrt(s) = u/sqrt(Hz)
    bias_instability : B, the flicker floor, u (Allan deviation minimum / sqrt(2 ln 2 / pi))
    random_walk      : K, rate / acceleration random walk, u/sqrt(s) (= u sqrt(Hz)/s)
    rate_hz          : sample rate of the static data; seconds: how much of it was analysed
    white and white_sigma are always arrays; bias_instability and random_walk (with their sigmas)
    are None when the static data did not resolve the term for every sensor (too short a rest,
    station.solve.noise), else arrays. Values and sigmas are finite and positive.
    """

    white: np.ndarray
    white_sigma: np.ndarray
    bias_instability: np.ndarray | None
    bias_instability_sigma: np.ndarray | None
    random_walk: np.ndarray | None
    random_walk_sigma: np.ndarray | None
    rate_hz: float
    seconds: float

    @classmethod
    def from_fit(cls, fit, rate_hz: float, seconds: float, channels=None) -> "NoiseFigures":
        """The figures of a `station.solve.noise.NoiseFit` (value, sigma (3, c), resolved) for
        its `channels` (indices, default all, in the order of the calibration's sensors): a
        term not resolved for every one of them is None."""
        pick = slice(None) if channels is None else np.asarray(channels, np.int64)
        value, sigma, resolved = fit.value[:, pick], fit.sigma[:, pick], fit.resolved[:, pick]
        terms = [(value[k], sigma[k]) if resolved[k].all() else (None, None) for k in range(3)]
        return cls(*terms[0], *terms[1], *terms[2], rate_hz=float(rate_hz),
                   seconds=float(seconds))

    def to_document(self, unit: str) -> dict:
        """The file's `noise` object for readings in `unit`."""
        doc = {key: _list(getattr(self, key)) for key in NOISE_KEYS[:6]}
        return {**doc, "rate_hz": self.rate_hz, "seconds": self.seconds,
                "units": noise_units(unit)}


@dataclass(frozen=True, eq=False)
class Calibration(measurement.Sensitivity):
    """One unit's calibration, as stored in a calibration file (shapes: d axes, m sensors).

    a, a_sigma          : (d, m) sensitivity matrix in `frame` and its 1-sigma
    bias, bias_sigma    : (m,) biases in the readings' units and their 1-sigma
    scale_factors(_sigma), axis_angles(_sigma) : (m,), (m, m) rad; frame-free invariants
    units               : unit of each sensor's readings (also the unit of b): SI, or COUNTS
                          for raw counts whose scale was not known
    counts_per_unit     : (m,) raw counts per SI unit at the driver edge, or None if unknown
    frame               : "canonical" (Eq. 19) or "nominal" (aligned to a nominal layout)
    magnitude           : |v_j| of the calibration positions; scale_known False: Remark 2
    fit                 : {"method", "chi2", "dof", "positions", "bias_source", "status" ("good"
                          or "suspect": station.solve.quality), "status_reasons"}; files written
                          before the quality gate have no status
    session             : where the readings came from (path, stream, ...) or None
    covariance          : (d m + m, d m + m) joint covariance of (a row-major, b) in `frame`, its
                          diagonal the squared sigmas; None when unknown (version-1 files)
    verdict             : station.solve.verdict's verdict against the unit type's tolerances, or
                          None (none given; files before version 3)
    pose_sigma          : the per-pose error term folded into every sigma (readings' units), or
                          None (estimated with the noise, or files before version 4)
    white               : the white-noise figure {name: array} of WHITE (a_sigma, bias_sigma,
                          scale_factors_sigma, axis_angles_sigma), or None (files before
                          version 4)
    noise               : each sensor's `NoiseFigures`, or None (not measured; files before
                          version 5)
    temperature         : the `TemperatureModel` (station.model.temperature), a and bias being
                          the calibration at its t_ref, or None (none; files before version 6)
    stimulus            : SI unit of v when the readings are COUNTS; None: that of the readings
                          (`quantity`)
    """

    unit_serial: str
    sensors: tuple
    units: tuple
    a: np.ndarray
    a_sigma: np.ndarray
    bias: np.ndarray
    bias_sigma: np.ndarray
    scale_factors: np.ndarray
    scale_factors_sigma: np.ndarray
    axis_angles: np.ndarray
    axis_angles_sigma: np.ndarray
    frame: str
    magnitude: float
    scale_known: bool
    fit: dict
    counts_per_unit: np.ndarray | None = None
    session: dict | None = None
    covariance: np.ndarray | None = None
    verdict: dict | None = None
    pose_sigma: float | None = None
    white: dict | None = None
    noise: NoiseFigures | None = None
    temperature: TemperatureModel | None = None
    stimulus: str | None = None
    created: str = field(default_factory=lambda: utc_now())
    software_version: str = field(default_factory=lambda: software_version())

    @property
    def quantity(self) -> str:
        """The SI unit of what the sensors sense (of v and the magnitude): the readings' unit,
        or the stimulus' for readings in COUNTS."""
        return self.stimulus or self.units[0]

    @classmethod
    def from_result(cls, result, unit_serial: str, sensors, units, *, bias=None, bias_sigma=None,
                    bias_source: str = "estimated with the calibration", counts_per_unit=None,
                    session: dict | None = None, status: str = "good",
                    status_reasons=(), stimulus: str | None = None) -> "Calibration":
        """A calibration file's content from a `station.solve.calibrate.CalibrationResult`.

        bias, bias_sigma : (m,) biases and 1-sigma measured apart from the fit (e.g. the static
                           windows of a rotary session, whose Eq. (18) readings are bias-free);
                           default: the result's own (it must then have estimated them).
        units            : one unit for all sensors, or one per sensor: SI, or COUNTS with the
                           `stimulus` unit (SI) of what they sense.
        status           : "good", or "suspect" (a fit that failed the quality gate,
                           station.solve.quality) with `status_reasons` in words.
        The parameters the poses determine only loosely (`result.weakly_determined`) are named
        in `fit.weakly_determined` (absent when there are none).
        """
        m = result.m
        own_bias = bias is None
        if own_bias:
            if result.bias is None or result.bias_sigma is None:
                raise CalibrationFileError(
                    "the calibration has no estimated bias (its readings were bias-free); give "
                    "the biases measured apart, e.g. from the static windows")
            bias, bias_sigma = result.bias, result.bias_sigma
        units = (units,) * m if isinstance(units, str) else tuple(units)
        bias_sigma = np.asarray(bias_sigma, float)
        cal = cls(
            unit_serial=str(unit_serial), sensors=tuple(str(s) for s in sensors), units=units,
            a=result.a, a_sigma=result.a_sigma, bias=np.asarray(bias, float),
            bias_sigma=bias_sigma, scale_factors=result.scale_factors,
            scale_factors_sigma=result.scale_factors_sigma, axis_angles=result.axis_angles,
            axis_angles_sigma=result.axis_angles_sigma, frame=result.frame,
            magnitude=float(result.magnitude), scale_known=bool(result.scale_known),
            fit={"method": result.method, "start": result.start, "chi2": float(result.chi2),
                 "dof": int(result.dof), "positions": int(result.v.shape[1]),
                 "bias_source": bias_source, "status": status,
                 "status_reasons": list(status_reasons),
                 **({"weakly_determined": list(result.weakly_determined)}
                    if result.weakly_determined else {})},
            counts_per_unit=None if counts_per_unit is None else np.asarray(counts_per_unit,
                                                                               float),
            session=session, covariance=_joint_covariance(result, own_bias, bias_sigma),
            pose_sigma=result.pose_sigma, white=_white(result, None if own_bias else bias_sigma),
            stimulus=stimulus)
        return cal.checked()

    @classmethod
    def from_carry(cls, carry, unit_serial: str, sensors, *, frame: str, magnitude: float,
                   counts_per_unit=None, session: dict | None = None, status: str = "good",
                   status_reasons=(), units: str = "rad/s") -> "Calibration":
        """A gyro triad's calibration file content from `station.solve.gyro_carry`'s
        `CarryCalibration` (gravity carried through the turns between still poses, Tedaldi et
        al.): a and b with their joint covariance, the invariants with their 1-sigma, in the
        frame of the accelerometer calibration it was carried by (`frame`, its name);
        `magnitude`: that accelerometer's gravity (the carry needs no rate magnitude); status:
        "good", or "suspect" with `status_reasons` (the accelerometer's fit, which the carry
        trusts); `units`: of the gyro's readings, rad/s or COUNTS (raw, the scale not known)."""
        cal = cls(
            unit_serial=str(unit_serial), sensors=tuple(str(s) for s in sensors),
            units=(units,) * 3, stimulus="rad/s" if units == COUNTS else None, a=carry.a,
            a_sigma=carry.a_sigma, bias=carry.bias, bias_sigma=carry.bias_sigma,
            scale_factors=carry.scale_factors,
            scale_factors_sigma=carry.scale_factors_sigma, axis_angles=carry.axis_angles,
            axis_angles_sigma=carry.axis_angles_sigma, frame=frame, magnitude=float(magnitude),
            scale_known=True,
            fit={"method": "gravity carry (Tedaldi et al. 2014)", "start": "common scale (k I)",
                 "chi2": float(carry.dof), "dof": int(carry.dof),
                 "positions": int(len(carry.turns)),
                 "bias_source": "mean of the still poses (the Earth's rate included)",
                 "status": status, "status_reasons": list(status_reasons),
                 "noise": "estimated from the residuals (chi2 = dof)",
                 "carry": {"turns": int(len(carry.turns)),
                           "residual_sigma": float(carry.residual_sigma),
                           "error_start_rms_deg": _rms(carry.errors_before_deg),
                           "error_rms_deg": _rms(carry.errors_after_deg),
                           "error_max_deg": float(np.max(carry.errors_after_deg))}},
            counts_per_unit=None if counts_per_unit is None else np.asarray(counts_per_unit,
                                                                               float),
            session=session, covariance=carry.covariance)
        return cal.checked()

    def with_noise(self, noise: NoiseFigures | None) -> "Calibration":
        """This calibration with its sensors' `NoiseFigures` (checked as a load checks them)."""
        cal = dataclasses.replace(self, noise=noise)
        return cal.checked()

    @classmethod
    def from_temperature_fit(cls, fit, unit_serial: str, sensors, units,
                             **kwargs) -> "Calibration":
        """A calibration file's content from `station.solve.temperature.TemperatureFit`: its
        reference calibration (at t_ref) with the temperature model; `fit.temperature` records
        the soaks' temperatures, the fit's chi2 and dof and the order selection's steps; a fit
        with problems (inconsistent with the soaks' uncertainty) is written "suspect" with them.
        kwargs: those of `from_result` (counts_per_unit, session, ...)."""
        if fit.problems:
            kwargs.update(status="suspect", status_reasons=fit.problems)
        cal = cls.from_result(fit.reference, unit_serial, sensors, units, **kwargs)
        record = {"soaks_K": [float(s.temperature) for s in fit.soak_data],
                  "chi2": float(fit.chi2), "dof": int(fit.dof),
                  "selection": [{"quantity": q, "order": o, "chi2_drop": drop,
                                 "threshold": limit, "accepted": ok}
                                for q, o, drop, limit, ok in fit.tests]}
        return dataclasses.replace(cal, fit={**cal.fit, "temperature": record}) \
            .with_temperature(fit.model)

    def with_temperature(self, model: TemperatureModel | None) -> "Calibration":
        """This calibration with a temperature model (checked as a load checks it); a and bias
        must be the calibration at the model's t_ref (station.solve.temperature's reference)."""
        cal = dataclasses.replace(self, temperature=model)
        return cal.checked()

    def apply_at(self, z, temperature) -> np.ndarray:
        """Calibrated vectors (d, k) from SI readings z (m, k) taken at the unit's temperatures
        (k,) K (or one for all), through the temperature model; refused without one. The caller
        checks the calibrated range (`temperature.outside`)."""
        if self.temperature is None:
            raise CalibrationFileError("this calibration has no temperature model; apply it "
                                       "without a temperature")
        return self.temperature.fuse(self.a, self.bias, self._readings(z).reshape(self.m, -1),
                                     temperature)

    @property
    def vector_unit(self) -> str:
        """The unit of the calibrated vectors: the SI unit of what the sensors sense (`quantity`),
        or "local magnitude" when the stimulus magnitude was unknown (`scale_known` false, Remark
        2: a magnetometer calibrated to the local field's unit sphere gives the field in units of
        the local one)."""
        return self.quantity if self.scale_known else "local magnitude"

    def fusion_matrix(self) -> np.ndarray:
        """(d, m) least-squares fusion matrix F = (a a^T)^-1 a: v = F (z - b)."""
        return measurement.fusion_matrix(self.a)

    def apply(self, z) -> np.ndarray:
        """Calibrated vectors (d,) or (d, k) from SI readings z (m,) or (m, k), one column per
        instant (station.model.measurement.fuse)."""
        return measurement.fuse(self.a, self._readings(z), self.bias)

    def _readings(self, z) -> np.ndarray:
        """z as floats, refused unless it holds m readings per instant (one column each)."""
        z = np.asarray(z, float)
        if z.ndim not in (1, 2) or z.shape[0] != self.m:
            raise CalibrationFileError(f"readings have shape {z.shape}; this calibration needs "
                                       f"{self.m} readings per instant (sensors {self.sensors}), "
                                       "one column per instant: (m,) or (m, k)")
        return z

    def vector_covariance(self, z, temperature=None) -> np.ndarray:
        """(k, d, d) covariance of each calibrated vector F (z - b) due to the calibration's own
        uncertainty (`covariance`), for SI readings z (m,) or (m, k), by first-order propagation
        through station.model.measurement.fusion_jacobian. The readings' own noise is not
        included. With `temperature` (K, (k,) or one for all): at those temperatures through the
        temperature model, its coefficients' uncertainty included (`apply_at`)."""
        if self.covariance is None:
            raise CalibrationFileError("this calibration file has no covariance (format version "
                                       "1); solve the session again for one")
        if temperature is not None:
            if self.temperature is None:
                raise CalibrationFileError("this calibration has no temperature model; give no "
                                           "temperature")
            return self.temperature.vector_covariance(
                self.a, self.bias, self.covariance,
                self._readings(z).reshape(self.m, -1), temperature)
        jac = measurement.fusion_jacobian(self.a, self._readings(z), self.bias)
        return np.einsum("kpi,ij,kqj->kpq", jac, self.covariance, jac)

    def check_unit(self, unit_serial: str | None = None, sensors=None, units=None,
                   where: str = "the data") -> None:
        """Raise CalibrationFileError unless this calibration is for that unit, sensors, units."""
        if unit_serial is not None and str(unit_serial) != self.unit_serial:
            raise CalibrationFileError(
                f"the calibration is for unit {self.unit_serial!r} but {where} comes from unit "
                f"{unit_serial!r}; use that unit's calibration file")
        if sensors is not None and tuple(sensors) != self.sensors:
            raise CalibrationFileError(
                f"{where} has sensors {list(sensors)} but the calibration's are "
                f"{list(self.sensors)}; give the readings of the calibrated sensors, in its order")
        if units is not None:
            units = (units,) * self.m if isinstance(units, str) else tuple(units)
            if units != self.units:
                raise CalibrationFileError(
                    f"{where} is in {sorted(set(units))} but the calibration expects "
                    f"{sorted(set(self.units))}; convert the readings to SI first")

    def checked(self) -> "Calibration":
        """This calibration, once it passes the checks a load makes (`loads`) but the checksum's
        (it has none yet); CalibrationFileError naming the problem."""
        _from_document(self._document(), "the calibration", checksummed=False)
        return self

    def to_document(self) -> dict:
        """The JSON document of the file (checksum included)."""
        doc = self._document()
        doc["checksum"] = checksum(doc)
        return doc

    def _document(self) -> dict:
        """The JSON document of the file without its checksum."""
        return {
            "format": FORMAT, "format_version": FORMAT_VERSION,
            "software_version": self.software_version, "created": self.created,
            "conventions": dict(CONVENTIONS_V6),
            "unit": {"serial": self.unit_serial, "sensors": list(self.sensors)},
            "units": {"readings": list(self.units), "stimulus": self.quantity,
                      "sensitivity": "1 (reading unit per stimulus unit)" if self.stimulus is None
                      else f"{self.units[0]} per {self.stimulus}",
                      "bias": "readings' unit", "axis_angles": "rad",
                      "counts_per_unit": _list(self.counts_per_unit)},
            "frame": self.frame, "magnitude": self.magnitude, "scale_known": self.scale_known,
            "sensitivity": {"a": _list(self.a), "sigma": _list(self.a_sigma)},
            "bias": {"b": _list(self.bias), "sigma": _list(self.bias_sigma)},
            "invariants": {"scale_factors": _list(self.scale_factors),
                           "scale_factors_sigma": _list(self.scale_factors_sigma),
                           "axis_angles": _list(self.axis_angles),
                           "axis_angles_sigma": _list(self.axis_angles_sigma)},
            "fit": dict(self.fit), "session": self.session,
            "covariance": _list(self.covariance), "verdict": self.verdict,
            "uncertainty": {"pose_sigma": self.pose_sigma,
                            "white": None if self.white is None else
                            {k: _list(self.white[k]) for k in WHITE}},
            "noise": None if self.noise is None else self.noise.to_document(self.units[0]),
            "temperature": None if self.temperature is None else
            temperature_document(self.temperature, self.units[0]),
        }

    def dumps(self) -> str:
        """The file's text."""
        return _pretty(self.to_document()) + "\n"

    def save(self, path, overwrite: bool = False) -> None:
        """Write the file atomically: a temporary file renamed into place, or without `overwrite`
        linked into place, which fails when the name exists - also when another command wrote
        it meanwhile (two commands with one --out): FileExistsError naming the file."""
        path = os.fspath(path)
        exists = FileExistsError(errno.EEXIST, "exists; choose another name or allow "
                                               "overwriting (--force)", path)
        if os.path.exists(path) and not overwrite:
            raise exists
        tmp = f"{path}.tmp{os.getpid()}"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(self.dumps())
        if overwrite:
            os.replace(tmp, path)
            return
        try:
            os.link(tmp, path)  # atomic and never replaces: the check above cannot be raced
        except FileExistsError:
            raise exists from None
        finally:
            os.unlink(tmp)


def _joint_covariance(result, own_bias: bool, bias_sigma: np.ndarray) -> np.ndarray | None:
    """Covariance of (a row-major, b): the result's own when it estimated b, else its block of a
    beside independent biases of `bias_sigma` (measured apart, e.g. the static windows); None
    for a result without parameter_covariance (stored before it existed)."""
    cov = result.parameter_covariance
    if cov is None:
        return None
    k = result.a.size
    if own_bias:
        return cov
    joint = np.zeros((k + len(bias_sigma),) * 2)
    joint[:k, :k] = cov[:k, :k]
    joint[k:, k:] = np.diag(bias_sigma**2)
    return joint


def _white(result, bias_sigma) -> dict | None:
    """The white-noise figure of a result for the file; biases measured apart (`bias_sigma`) keep
    their own sigma. None for a result without one (stored before it existed)."""
    if result.scale_factors_sigma_white is None:
        return None
    bias = result.bias_sigma_white if bias_sigma is None else bias_sigma
    return {"a_sigma": result.a_sigma_white, "bias_sigma": np.asarray(bias, float),
            "scale_factors_sigma": result.scale_factors_sigma_white,
            "axis_angles_sigma": result.axis_angles_sigma_white}


def _uncertainty(doc, a_shape, fail):
    """(pose_sigma, white) of a version-4 document (None, None before), checked."""
    block = doc.get("uncertainty")
    if block is None:
        return None, None
    if not isinstance(block, dict) or set(block) != {"pose_sigma", "white"}:
        raise fail("uncertainty must be null or an object with pose_sigma and white")
    pose = block["pose_sigma"]
    if pose is not None and not (type(pose) in (int, float) and np.isfinite(pose) and pose >= 0):
        raise fail(f"uncertainty.pose_sigma {pose!r} must be null or a number >= 0")
    if block["white"] is None:
        return pose, None
    white = _dict(block, "white", fail)
    if set(white) != set(WHITE):
        raise fail(f"uncertainty.white must hold exactly {', '.join(WHITE)}")
    d, m = a_shape
    shapes = {"a_sigma": (d, m), "bias_sigma": (m,), "scale_factors_sigma": (m,),
              "axis_angles_sigma": (m, m)}
    return (None if pose is None else float(pose),
            {k: _array(white, k, fail, shape=shapes[k], sigma=True) for k in WHITE})


def noise_units(unit: str) -> dict:
    """The units of the `noise` terms for readings in `unit` (u sqrt(s), u, u/sqrt(s))."""
    return {"white": f"{unit} sqrt(s)", "bias_instability": unit,
            "random_walk": f"{unit} / sqrt(s)"}


def _noise(doc, m: int, unit: str, fail) -> NoiseFigures | None:
    """The `noise` object of a version-5 document (None before, or null), checked: exactly its
    keys, each term an (m,) array of finite positive numbers with a positive 1-sigma (the random
    walk and bias instability both null or both given with their sigma), the rate and seconds
    positive, the units those of the readings."""
    block = doc.get("noise")
    if block is None:
        return None

    def fail_noise(problem: str, *advice) -> CalibrationFileError:
        return fail(problem if problem.startswith("noise") else f"noise.{problem}", *advice)

    if not isinstance(block, dict) or set(block) != set(NOISE_KEYS):
        raise fail(f"noise must be null or an object with exactly {', '.join(NOISE_KEYS)}")
    if block["units"] != noise_units(unit):
        raise fail(f"noise.units {block['units']!r} are not {noise_units(unit)} (readings in "
                   f"{unit})")
    for key in ("rate_hz", "seconds"):
        value = block[key]
        if type(value) not in (int, float) or not 0 < value <= LIMITS["b"][1]:
            raise fail(f"noise.{key} {value!r} must be a positive number")
    terms = {}
    for name in NOISE_TERMS:
        pair = (name, f"{name}_sigma")
        if name != "white" and block[pair[0]] is None and block[pair[1]] is None:
            terms.update(dict.fromkeys(pair))
            continue
        for key in pair:
            terms[key] = _array(block, key, fail_noise, shape=(m,), positive=True,
                                bound=LIMITS["b"][1])
    return NoiseFigures(**terms, rate_hz=float(block["rate_hz"]),
                        seconds=float(block["seconds"]))


def temperature_units(unit: str, orders: dict) -> dict:
    """The units of the temperature model's coefficients for readings in `unit`."""
    return {"temperature": "K",
            "bias": [f"{unit} / K^{p}" for p in range(1, orders["bias"] + 1)],
            "scale": [f"1 / K^{p}" for p in range(1, orders["scale"] + 1)]}


def temperature_document(model: TemperatureModel, unit: str) -> dict:
    """The file's `temperature` object of a model, for readings in `unit`."""
    return {"t_ref": model.t_ref, "range": [model.t_min, model.t_max],
            "orders": dict(model.orders), "bias": _list(model.bias),
            "bias_sigma": _list(model.bias_sigma), "scale": _list(model.scale),
            "scale_sigma": _list(model.scale_sigma), "covariance": _list(model.covariance),
            "units": temperature_units(unit, model.orders)}


def _temperature(doc, m: int, unit: str, fail) -> TemperatureModel | None:
    """The `temperature` object of a version-6 document (None before, or null), checked: exactly
    its keys; t_ref and the range in kelvin, t_min < t_max, t_ref inside; orders integers in
    0..MAX_ORDER; coefficients (m, order) finite, sigmas the square roots of the covariance's
    diagonal (symmetric, positive semi-definite); the units those of the readings and orders; the
    scale ratio within SCALE_RATIO over the range."""
    block = doc.get("temperature")
    if block is None:
        return None

    def fail_t(problem: str, *advice) -> CalibrationFileError:
        return fail(f"temperature: {problem}", *advice)

    if not isinstance(block, dict) or set(block) != set(TEMPERATURE_KEYS):
        raise fail(f"temperature must be null or an object with exactly "
                   f"{', '.join(TEMPERATURE_KEYS)}")
    orders = block["orders"]
    if not (isinstance(orders, dict) and set(orders) == {"bias", "scale"}
            and all(type(v) is int and 0 <= v <= MAX_ORDER for v in orders.values())):
        raise fail_t(f"orders {orders!r} must be {{bias, scale}}, each an integer 0..{MAX_ORDER}")
    if block["units"] != temperature_units(unit, orders):
        raise fail_t(f"units {block['units']!r} are not {temperature_units(unit, orders)}")
    span = _array(block, "range", fail_t, shape=(2,))
    t_ref = block["t_ref"]
    if type(t_ref) not in (int, float):
        raise fail_t(f"t_ref {t_ref!r} must be a number (K)")
    try:
        check_kelvin([t_ref, *span], "temperature.t_ref and range")
    except InputError as exc:
        raise fail(str(exc)) from None
    if not span[0] < span[1] or not span[0] <= t_ref <= span[1]:
        raise fail_t(f"range {span.tolist()} must be [t_min, t_max] with t_min < t_max and "
                     f"t_ref {t_ref} inside")
    shapes = {"bias": (m, orders["bias"]), "scale": (m, orders["scale"])}
    coef = {k: _array(block, k, fail_t, shape=shapes[k], bound=LIMITS["b"][1]) for k in shapes}
    sigma = {k: _array(block, f"{k}_sigma", fail_t, shape=shapes[k], sigma=True)
             for k in shapes}
    k = m * (orders["bias"] + orders["scale"])
    if not k and block["covariance"] != []:
        raise fail_t("covariance must be [] when both orders are 0")
    cov = _covariance(block, np.r_[sigma["bias"].ravel(), sigma["scale"].ravel()], fail_t) \
        if k else np.zeros((0, 0))
    model = TemperatureModel(t_ref=float(t_ref), t_min=float(span[0]), t_max=float(span[1]),
                             bias=coef["bias"].reshape(shapes["bias"]),
                             scale=coef["scale"].reshape(shapes["scale"]), covariance=cov)
    ratio = model.scale_ratio(np.linspace(span[0], span[1], 101))
    if not (SCALE_RATIO[0] <= ratio.min() and ratio.max() <= SCALE_RATIO[1]):
        raise fail_t(f"scale makes a scale factor change by a ratio {ratio.min():.3g} .. "
                     f"{ratio.max():.3g} over the range; no unit does (allowed {SCALE_RATIO})")
    return model


def checksum(doc: dict) -> str:
    """"sha256:<hex>" of the canonical JSON (sorted keys, no spaces) of doc without "checksum"."""
    body = {k: v for k, v in doc.items() if k != "checksum"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def load(path, unit_serial: str | None = None, sensors=None, units=None) -> Calibration:
    """Read a calibration file; refuse it unless it is for `unit_serial` / `sensors` / `units`
    (each checked when given)."""
    path = os.fspath(path)
    cal = loads(read_text(path)[0], path)
    cal.check_unit(unit_serial, sensors, units, where="the data")
    return cal


def read_text(path) -> tuple[str, bytes]:
    """(text, bytes) of a calibration file, read once: at most MAX_BYTES, UTF-8 (the bytes for a
    digest of exactly what was read)."""
    path = os.fspath(path)
    try:
        size = os.path.getsize(path)
        if size > MAX_BYTES:
            raise CalibrationFileError(f"{path} holds {size} bytes; a calibration file is at most "
                                       f"{MAX_BYTES} bytes: is it the right file?")
        with open(path, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
        return raw.decode("utf-8"), raw
    except OSError as exc:
        raise CalibrationFileError(f"cannot read calibration file {path}: {exc.strerror}") \
            from None
    except UnicodeDecodeError:
        raise CalibrationFileError(f"{path} is not UTF-8 text; a calibration file is JSON") \
            from None


def loads(text: str, where: str = "calibration") -> Calibration:
    """Parse a calibration file's text (see `load`)."""
    doc = json_loads(text, where, error=CalibrationFileError, object_pairs_hook=_no_duplicates)
    return _from_document(doc, where)


def _no_duplicates(pairs):
    """An object's pairs as a dict; ValueError naming repeated keys (linear time)."""
    doc = dict(pairs)
    if len(doc) != len(pairs):
        seen, repeated = set(), set()
        for k, _ in pairs:
            (repeated if k in seen else seen).add(k)
        raise ValueError(f"duplicate keys {sorted(repeated)[:10]}")
    return doc


def _from_document(doc, where: str, checksummed: bool = True) -> Calibration:
    """Check a parsed document, in order: format, version, checksum (a file's; `checksummed`
    False: a document made here, `Calibration.checked`), content."""
    def fail(problem: str, advice: str = "the file is damaged or was edited; solve the session "
                                         "again or use an intact copy") -> CalibrationFileError:
        return CalibrationFileError(f"{where}: {problem}; {advice}")

    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise fail(f"not an IMU station calibration file (format {found!r}, expected {FORMAT!r})",
                   "give a file written by `station solve`")
    version = doc.get("format_version")
    if type(version) is not int or version not in SUPPORTED_VERSIONS:
        raise fail(f"format_version {version!r} is not one this software reads "
                   f"({', '.join(map(str, SUPPORTED_VERSIONS))})",
                   "files of a newer version need newer station software")
    unknown = sorted(set(doc) - set(_KEYS[version]))
    missing = [k for k in _KEYS[version] if k not in doc and (checksummed or k != "checksum")]
    if unknown or missing:
        raise fail(f"unknown keys {unknown} / missing keys {missing} for format version {version}")
    if checksummed and doc["checksum"] != checksum(doc):
        raise fail("the checksum does not match the content (it was changed after it was "
                   "written)")
    if doc["conventions"] != _CONVENTIONS[version]:
        raise fail("its conventions differ from this software's (docs/conventions.md)")
    unit, units = _dict(doc, "unit", fail), _dict(doc, "units", fail)
    serial = _str(unit, "serial", fail)
    sensors = _strings(unit, "sensors", fail)
    m = len(sensors)
    if m == 0 or len(set(sensors)) != m:
        raise fail(f"unit.sensors {sensors} must be distinct sensor ids")
    readings_units = _strings(units, "readings", fail)
    bad = sorted(set(readings_units) - {*SI_UNITS, COUNTS})
    if bad or len(readings_units) != m or len(set(readings_units)) != 1:
        raise fail(f"units.readings {readings_units} must be one SI unit ({', '.join(SI_UNITS)}) "
                   f"or {COUNTS} for all {m} sensors")
    stimulus = units.get("stimulus")
    if readings_units[0] == COUNTS and stimulus not in SI_UNITS:
        raise fail(f"units.stimulus {stimulus!r} of readings in {COUNTS} must be one of "
                   f"{', '.join(SI_UNITS)}")
    if readings_units[0] != COUNTS and stimulus != readings_units[0]:
        raise fail(f"units.stimulus {stimulus!r} differs from the readings' unit")
    sens, bias, inv = (_dict(doc, k, fail) for k in ("sensitivity", "bias", "invariants"))
    a = _array(sens, "a", fail, ndim=2, cols=m, bound=LIMITS["a"][1])
    d = a.shape[0]
    if not 1 <= d <= m or np.linalg.matrix_rank(a) < d:
        raise fail(f"sensitivity.a of shape {a.shape} must be d x m with rank d <= m")
    frame, magnitude = doc["frame"], doc["magnitude"]
    if frame not in FRAMES:
        raise fail(f"frame {frame!r} is not one of {FRAMES}")
    if type(magnitude) not in (int, float) or not magnitude > 0:
        raise fail(f"magnitude {magnitude!r} must be a positive number")
    _plausible(a, _array(bias, "b", fail, shape=(m,), bound=LIMITS["b"][1]), magnitude, fail)
    if type(doc["scale_known"]) is not bool:
        raise fail("scale_known must be true or false")
    fit, session = _dict(doc, "fit", fail), doc["session"]
    if session is not None and not isinstance(session, dict):
        raise fail("session must be an object or null")
    for key in ("software_version", "created"):
        if not isinstance(doc[key], str):
            raise fail(f"{key} must be a string")
    cpu = units.get("counts_per_unit")
    cpu = None if cpu is None else _array(units, "counts_per_unit", fail, shape=(m,),
                                          positive=True)
    a_sigma = _array(sens, "sigma", fail, shape=(d, m), sigma=True)
    bias_sigma = _array(bias, "sigma", fail, shape=(m,), sigma=True)
    covariance = None if doc.get("covariance") is None else \
        _covariance(doc, np.r_[a_sigma.ravel(), bias_sigma], fail)
    pose_sigma, white = _uncertainty(doc, a_sigma.shape, fail)
    verdict = doc.get("verdict")
    if verdict is not None and not (isinstance(verdict, dict)
                                    and verdict.get("overall") in VERDICTS
                                    and isinstance(verdict.get("parameters"), list)):
        raise fail(f"verdict must be null or an object with overall in {VERDICTS} and a list of "
                   "parameters")
    return Calibration(
        unit_serial=serial, sensors=tuple(sensors), units=tuple(readings_units), a=a,
        a_sigma=a_sigma, bias=_array(bias, "b", fail, shape=(m,)), bias_sigma=bias_sigma,
        scale_factors=_array(inv, "scale_factors", fail, shape=(m,), positive=True),
        scale_factors_sigma=_array(inv, "scale_factors_sigma", fail, shape=(m,), sigma=True),
        axis_angles=_array(inv, "axis_angles", fail, shape=(m, m)),
        axis_angles_sigma=_array(inv, "axis_angles_sigma", fail, shape=(m, m), sigma=True),
        frame=frame, magnitude=float(magnitude), scale_known=doc["scale_known"], fit=fit,
        counts_per_unit=cpu, session=session, covariance=covariance, verdict=verdict,
        pose_sigma=pose_sigma, white=white,
        noise=_noise(doc, m, readings_units[0], fail),
        temperature=_temperature(doc, m, readings_units[0], fail),
        stimulus=stimulus if readings_units[0] == COUNTS else None, created=doc["created"],
        software_version=doc["software_version"])


def _covariance(doc, sigma: np.ndarray, fail) -> np.ndarray:
    """The joint covariance, checked: square over (a, b), symmetric, positive semi-definite, its
    diagonal the squares of the sigmas the file states."""
    k = sigma.size
    cov = _array(doc, "covariance", fail, shape=(k, k))
    scale = max(float(np.abs(cov).max()), 1e-300)
    if np.abs(cov - cov.T).max() > 1e-12 * scale:
        raise fail("covariance is not symmetric")
    if np.linalg.eigvalsh(cov).min() < -1e-9 * scale:
        raise fail("covariance is not positive semi-definite")
    if not np.allclose(np.diag(cov), sigma**2, rtol=1e-9, atol=1e-12 * scale):
        raise fail("the covariance's diagonal differs from the squared sigmas of a and b")
    return cov


def _dict(doc, key, fail) -> dict:
    value = doc.get(key)
    if not isinstance(value, dict):
        raise fail(f"{key} must be an object")
    return value


def _str(doc, key, fail) -> str:
    value = doc.get(key)
    if not isinstance(value, str) or not value:
        raise fail(f"{key} must be a non-empty string")
    return value


def _strings(doc, key, fail) -> list:
    value = doc.get(key)
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise fail(f"{key} must be a list of non-empty strings")
    return value


def _plausible(a, b, magnitude, fail) -> None:
    """Refuse finite numbers no sensor unit has (`LIMITS`): a file crafted or damaged so that
    applying it overflows or divides by almost nothing (the fusion (a a^T)^-1 a of Eq. 7)."""
    scale = np.linalg.norm(a, axis=0)
    singular = np.linalg.svd(a, compute_uv=False)
    checks = {"a": scale, "b": np.abs(b), "magnitude": np.array([magnitude]),
              "condition": np.array([singular[0] / singular[-1]])}
    for name, values in checks.items():
        low, high = LIMITS[name]
        worst = values.max() if np.any(values > high) else values.min()
        if not low <= worst <= high:
            raise fail(f"its {LIMIT_WORDS[name]} {worst:.3g} lies outside [{low:g}, {high:g}]; "
                       "no sensor unit has that")


def _array(doc, key, fail, ndim=None, cols=None, shape=None, sigma=False, positive=False,
           bound=1e100):
    """A float64 array from nested lists of JSON numbers (bool refused), checked; every
    |value| <= bound (no overflow when squared or multiplied)."""
    value = doc.get(key)
    if not isinstance(value, list) or not _numbers(value):
        raise fail(f"{key} must be a (nested) list of numbers")
    try:
        arr = np.array(value, dtype=np.float64)
    except ValueError:
        raise fail(f"{key} is a ragged list; give a full matrix") from None
    except OverflowError:
        raise fail(f"{key} holds an integer too large for a float") from None
    if (ndim is not None and arr.ndim != ndim) or (cols is not None and arr.shape[-1:] != (cols,)) \
            or (shape is not None and arr.shape != shape):
        want = shape if shape is not None else f"{ndim}-D with {cols} columns"
        raise fail(f"{key} has shape {arr.shape}, expected {want}")
    if not np.all(np.abs(arr) <= bound) or (sigma and np.any(arr < 0)) \
            or (positive and np.any(arr <= 0)):
        raise fail(f"{key} must be finite (|x| <= {bound:g}){' and non-negative' if sigma else ''}"
                   f"{' and positive' if positive else ''}")
    return arr


def _numbers(value: list) -> bool:
    """Are the leaves of the nested list `value` all JSON numbers (int or float, not bool)? One
    look at the types of each list's items (no recursion)."""
    todo = [value]
    while todo:
        items = todo.pop()
        kinds = set(map(type, items))
        if not kinds <= {int, float, list}:
            return False
        if list in kinds:
            todo.extend(x for x in items if type(x) is list)
    return True


def _pretty(value, indent: str = "") -> str:
    """JSON with one key per line and each vector (matrix row) on one line."""
    inner = indent + "  "
    if isinstance(value, dict) and value:
        items = (f"{inner}{json.dumps(k)}: {_pretty(v, inner)}" for k, v in value.items())
        return "{\n" + ",\n".join(items) + f"\n{indent}}}"
    if isinstance(value, list) and value and isinstance(value[0], list):
        return "[\n" + ",\n".join(inner + _pretty(v, inner) for v in value) + f"\n{indent}]"
    return json.dumps(value, allow_nan=False)


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _list(x):
    """Nested lists of Python floats (repr round-trips exactly), None for None."""
    return None if x is None else np.asarray(x, dtype=np.float64).tolist()


