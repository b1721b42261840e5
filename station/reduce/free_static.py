"""The free-static calibration path (multi-position method of Tedaldi et al.; DESIGN.md section 5).

A continuous raw recording -> automatically detected still intervals (station.reduce.stillness) ->
the accelerometer's averaged readings M (3 x P, one column per pose) -> `station.calibrate(M,
magnitude=g_local, bias="estimate", sigma=stderr)` (ellipsoid closed form or a fallback start +
maximum likelihood; the 1-sigma figures hold the per-pose error term, docs/solvers.md); the gyro
biases are the gyro means over the still interval that holds the rest period. `leave_one_out`
predicts each pose from the others and reports the folds the solver refuses instead of stopping.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.stillness import StillIntervals, detect_still
from station.solve.calibrate import CalibrationResult, calibrate


@dataclass(frozen=True)
class FreeStaticCalibration:
    """Result of the free-static path; units are those of the input (e.g. raw counts).

    still : the detected still intervals over the accelerometer (and gyro) channels.
    readings, readings_stderr : (m, P) accelerometer means per interval and their standard errors.
    accel : the accelerometer calibration (a in input units per m/s^2, canonical frame).
    rest_index : index of the still interval holding the rest period.
    gyro_bias, gyro_bias_sigma : gyro means over that interval and their standard errors,
                                 or None without a gyro.
    """

    still: StillIntervals
    readings: np.ndarray
    readings_stderr: np.ndarray
    accel: CalibrationResult
    rest_index: int
    gyro_bias: np.ndarray | None
    gyro_bias_sigma: np.ndarray | None


def calibrate_free_static(accel, fs: float, g_local: float, *, gyro=None, **detector):
    """Calibrate m >= 3 accelerometers from a free-static recording accel (K, m), fs in Hz.

    A triad goes through the ellipsoid closed form, more sensors through the joint-bias
    factorization (Hwangbo & Kanade p = 4); both are refined by maximum likelihood.
    gyro     optional (K, k) gyro samples: used for stillness detection too, biases from the rest.
    detector options of `station.reduce.stillness.detect_still` (rest, window, enter, leave, ...).
    """
    acc = np.asarray(accel, dtype=float)
    if acc.ndim != 2 or acc.shape[1] < 3:
        raise CalibrationInputError(
            f"accelerometer samples have shape {acc.shape}.",
            "Give a (samples, m) array with m >= 3 accelerometer channels.",
        )
    m = acc.shape[1]
    channels = acc
    if gyro is not None:
        gyro = np.asarray(gyro, dtype=float)
        if gyro.ndim != 2 or gyro.shape[0] != acc.shape[0]:
            raise CalibrationInputError(
                f"gyro samples have shape {gyro.shape}, accelerometer {acc.shape}.",
                "Give both streams on the same time base, one row per sample.",
            )
        channels = np.hstack([acc, gyro])
    still = detect_still(channels, fs, **detector)
    readings, stderr = still.mean[:, :m].T, still.stderr[:, :m].T
    # refuses too few or degenerate poses, naming what they leave undetermined
    fit = calibrate(readings, g_local, d=3, bias="estimate", sigma=stderr, names=_names(m))
    rest_index = _interval_holding(still.intervals, still.rest)
    return FreeStaticCalibration(
        still=still,
        readings=readings,
        readings_stderr=stderr,
        accel=fit,
        rest_index=rest_index,
        gyro_bias=None if gyro is None else still.mean[rest_index, m:],
        gyro_bias_sigma=None if gyro is None else still.stderr[rest_index, m:],
    )


class HeldOut(np.ndarray):
    """(P,) |a_j| - g_local for each held-out pose j (an ndarray), NaN where the fit on the other
    poses was refused; `refused` maps each such pose index to the solver's reason, `starts` names
    the start of each fold's fit (station.solve.starts; None where refused)."""

    def __new__(cls, errors, refused: dict, starts):
        obj = np.asarray(errors, dtype=float).view(cls)
        obj.refused, obj.starts = dict(refused), tuple(starts)
        return obj

    def __array_finalize__(self, obj):
        self.refused = getattr(obj, "refused", {})
        self.starts = getattr(obj, "starts", ())


def leave_one_out(readings, g_local: float, *, sigma=None) -> HeldOut:
    """|a_j| - g_local for each pose j calibrated by the fit on the other P - 1 poses (`HeldOut`).

    sigma: (m, P) standard errors of the readings (e.g. `readings_stderr`), or None: estimated from
    each fold's residuals. A fold the solver refuses (too few or degenerate poses left) is reported
    in `refused` with the reason, and the others go on."""
    readings = np.asarray(readings, dtype=float)
    p = readings.shape[1]
    errors, refused, starts = np.full(p, np.nan), {}, []
    for j in range(p):
        rest = np.delete(readings, j, axis=1)
        noise = None if sigma is None else np.delete(np.asarray(sigma, float), j, axis=1)
        try:
            fit = calibrate(rest, g_local, d=3, bias="estimate", sigma=noise,
                            names=_names(readings.shape[0]))
        except CalibrationInputError as exc:
            refused[j] = str(exc)
            starts.append(None)
            continue
        errors[j] = np.linalg.norm(fit.apply(readings[:, j])) - g_local
        starts.append(fit.start)
    return HeldOut(errors, refused, starts)


def _names(m: int) -> list:
    """Channel names for the solver's messages: acc_x, acc_y, acc_z for a triad, else acc_1.."""
    return ["acc_x", "acc_y", "acc_z"] if m == 3 else [f"acc_{i + 1}" for i in range(m)]


def _interval_holding(intervals: np.ndarray, rest: np.ndarray) -> int:
    """Index of the interval overlapping the rest period most."""
    overlap = np.minimum(intervals[:, 1], rest[1]) - np.maximum(intervals[:, 0], rest[0])
    if overlap.max() <= 0:
        raise CalibrationInputError(
            f"no still interval covers the rest period [{rest[0]}, {rest[1]}).",
            "Check that the rest period is really at rest (or let the detector choose it).",
        )
    return int(np.argmax(overlap))
