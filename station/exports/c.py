"""A C header with a calibration, for firmware that fuses the sensors itself.

For the m readings z of one instant (SI units) the firmware computes the calibrated d-vector

    v[k] = sum_i FUSION[k][i] * (z[i] - BIAS[i])        (v = (a a^T)^-1 a (z - b))

and, from raw counts, z[i] = counts[i] / COUNTS_PER_UNIT[i]. The header holds the fusion matrix,
the biases and the counts scale as `static const float` (or double) arrays with their units in
comments, plus the unit's serial, the sensor order, the frame and the calibration file's checksum
so the firmware image can be traced back to the calibration.

With a temperature model (calibration file version 6) the header adds T_REF, T_MIN, T_MAX (K),
the orders and the coefficients BIAS_TEMPCO[i][p-1] (u/K^p) and SCALE_TEMPCO[i][p-1] (1/K^p);
at the unit's temperature T (x = T - T_REF) the firmware computes

    r[i]  = 1 + sum_p SCALE_TEMPCO[i][p-1] x^p
    zc[i] = (z[i] - BIAS[i] - sum_p BIAS_TEMPCO[i][p-1] x^p) / r[i]
    v[k] = sum_i FUSION[k][i] * zc[i]

which is the model's fusion exactly for a triad (m = d) and, for m > d, the least squares with
each sensor's residual weighted by r[i]^2 (a weighting within a few 1e-3 of the station's).
"""

import re

import numpy as np

from station.calfiles.calfile import Calibration
from station.errors import InputError
from station.exports.imu import si_readings

CTYPES = ("float", "double")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,31}\Z")


def c_header(cal: Calibration, prefix: str = "IMU_CAL", ctype: str = "float") -> str:
    """The header text; `prefix` names the macros and arrays (a C identifier, e.g. IMU_CAL)."""
    if not _IDENT.match(prefix):
        raise InputError(f"prefix {prefix!r} is not a C identifier (letters, digits, '_', not "
                         "starting with a digit, at most 32 characters)")
    if ctype not in CTYPES:
        raise InputError(f"C type {ctype!r}: choose one of {CTYPES}")
    si_readings(cal, "the calibration")
    d, m = cal.d, cal.m
    unit = cal.units[0]
    guard = f"{prefix.upper()}_H"
    lines = [
        (f"/* Calibration of IMU unit {_comment(cal.unit_serial)}, written by imu-station "
         f"{_comment(cal.software_version)}."),
        (f" * Calibrated {_comment(cal.created)}; calibration file checksum "
         f"{_comment(_checksum(cal))}."),
        f" * Sensors (index i): {_comment(', '.join(cal.sensors))}.",
        f" * Frame of v: {cal.frame} (docs/conventions.md); "
        f"fit: {_comment(cal.fit.get('method'))}.",
        " *",
        f" *   z[i] = counts[i] / {prefix}_COUNTS_PER_UNIT[i]                 ({unit})",
        f" *   v[k] = sum_i {prefix}_FUSION[k][i] * (z[i] - {prefix}_BIAS[i])   ({unit})",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        f"#define {prefix}_D {d}  /* components of v */",
        f"#define {prefix}_M {m}  /* sensors */",
        "",
        f"/* least-squares fusion matrix (a a^T)^-1 a, {d} x {m}, {unit} per {unit} */",
        f"static const {ctype} {prefix}_FUSION[{d}][{m}] = {{",
        *(f"    {{{_row(row, ctype)}}}," for row in cal.fusion_matrix()),
        "};",
        "",
        f"/* bias of each sensor, {unit}, subtracted before fusion */",
        f"static const {ctype} {prefix}_BIAS[{m}] = {{{_row(cal.bias, ctype)}}};",
    ]
    if cal.counts_per_unit is not None:
        lines += ["", f"/* raw counts per {unit} of each sensor */",
                  (f"static const {ctype} {prefix}_COUNTS_PER_UNIT[{m}] = "
                   f"{{{_row(cal.counts_per_unit, ctype)}}};")]
    if cal.temperature is not None:
        lines += temperature_lines(cal.temperature, prefix, ctype, unit)
    lines += ["", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def temperature_lines(model, prefix: str, ctype: str, unit: str) -> list:
    """The header lines of a temperature model (module docstring); an order-0 quantity has its
    order macro only (C has no empty arrays)."""
    lines = ["", "/* temperature model (docs/conventions.md): x = T - T_REF, T in K, valid on "
                 "[T_MIN, T_MAX] */",
             f"#define {prefix}_T_REF {model.t_ref!r}",
             f"#define {prefix}_T_MIN {model.t_min!r}",
             f"#define {prefix}_T_MAX {model.t_max!r}"]
    for name, coef, words in (("BIAS", model.bias, f"{unit} per K^p"),
                              ("SCALE", model.scale, "relative, per K^p")):
        order = coef.shape[1]
        lines.append(f"#define {prefix}_{name}_ORDER {order}")
        if order:
            lines += [f"/* {name.lower()} tempco of degree p = 1..{order} of each sensor, "
                      f"{words} */",
                      f"static const {ctype} {prefix}_{name}_TEMPCO[{len(coef)}][{order}] = {{",
                      *(f"    {{{_row(row, ctype)}}}," for row in coef), "};"]
    return lines


def _row(values, ctype: str) -> str:
    """C literals: the shortest text that round-trips the float32 (with an f suffix) or the
    float64 value."""
    if ctype == "float":
        return ", ".join(f"{np.float32(x)!s}f" for x in values)
    return ", ".join(repr(float(x)) for x in values)


def _comment(text) -> str:
    """Text safe inside a C comment (untrusted strings cannot close it or start a directive)."""
    return re.sub(r"[^A-Za-z0-9 _.,:;=+\-/()^]", "?", str(text))


def _checksum(cal: Calibration) -> str:
    return cal.to_document()["checksum"]
