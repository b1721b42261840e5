"""The physical range of each named effect's parameters: a fit outside it is not named.

A candidate can explain part of a gap with values no physics allows (an "Earth rate" at 3x the
Earth's, a negative latency). Such a candidate is reported as "resembles X, parameters
implausible" (station.diagnose.select) and never named. Each range is declared here, per
effect, as a bound on the fitted value allowing for its 1-sigma (a value is out of range when
it lies more than Z_LIMIT sigma beyond the bound):

- earth_rate: horizontal N, vertical U = Omega_E (cos phi, sin phi) within EARTH_TOLERANCE
  (relative) at the site latitude phi when given; otherwise |(N, U)| = Omega_E within it and
  0 <= N <= Omega_E (rad/s gyros only);
- latency: 0 <= delay_i <= LATENCY_MAX;
- rate_error: spread <= RATE_SPREAD_MAX (what a table's own servo would not flag), and its
  per-position factors independent of the sensor axes (AXES_LOG10_P); an encoder's gain
  within GAIN_TOLERANCE of 1;
- scale_nonlinearity: |k2_i| x the largest |signal| <= NONLINEARITY_MAX (datasheets: 0.01-0.5
  % of full scale);
- scale_asymmetry: |k_i| <= NONLINEARITY_MAX (datasheets: an asymmetry 2 k of 0.01-0.5 %);
- polynomial: sum_q |c_q,i| x the largest |signal|^(q - 1) <= NONLINEARITY_MAX;
- axis_wobble: half-angle <= WOBBLE_MAX_DEG;
- g_sensitivity: |G| <= G_SENSITIVITY_MAX deg/s per g (rad/s gyros only);
- temperature: |bias tempco_i| <= TEMPCO_MAX deg/s per K (rad/s gyros only);
- bias_drift, saturation: any fitted value.
"""

from dataclasses import dataclass

import numpy as np

from station.model.earth import OMEGA_EARTH

Z_LIMIT = 4.0
"""Sigmas a fitted value may lie beyond its range (about a Bonferroni 1e-4 two-sided)."""
EARTH_TOLERANCE = 0.1
"""Relative error allowed on the Earth rate's parts: the gyros' scale factors, the site."""
LATENCY_MAX = 0.05
"""s: a delay beyond a few samples of any bus is a timestamp fault, not a sensor latency."""
RATE_SPREAD_MAX = 2e-3
"""Relative spread of a table's rate over positions that its own servo would not flag."""
AXES_LOG10_P = -3.0
"""A table rate spread whose factors follow the sensor axes at this log10 p is not the table's
(station.diagnose.effects.rate_error.axes_log10_p)."""
GAIN_TOLERANCE = 0.2
"""Encoder gain: 1 when the readings follow the table's encoder."""
NONLINEARITY_MAX = 0.01
"""Relative output error k2 s at the largest signal s (1 %: ten times a MEMS datasheet's)."""
WOBBLE_MAX_DEG = 0.1
"""Coning half-angle of a rate table's axis (bearing run-out), degrees."""
G_SENSITIVITY_MAX = 1.0
"""deg/s per g: ten times a MEMS gyro's datasheet g-sensitivity."""
TEMPCO_MAX = 0.1
"""deg/s per K: a MEMS gyro's bias tempco over its range (datasheets: 0.005-0.05 deg/s/K; the
unit's zero-rate output over -40..85 C stays within a few deg/s)."""


@dataclass(frozen=True)
class Site:
    """What the ranges need to know about the bench: its latitude (degrees, None: unknown) and
    whether the gyro readings are in rad/s (False for raw counts: rates cannot be judged)."""

    latitude_deg: float | None = None
    rad_per_s: bool = True


def _beyond(value, sigma, low=-np.inf, high=np.inf) -> bool:
    """True when value lies more than Z_LIMIT sigma outside [low, high] (any element)."""
    v, s = np.asarray(value, float), np.nan_to_num(np.asarray(sigma, float))
    return bool(np.any((v + Z_LIMIT * s < low) | (v - Z_LIMIT * s > high)))


def _value(fitted, *keys):
    """(value, sigma) of the first key the fitted extension has (rotary or free-static name)."""
    key = next(k for k in keys if k in fitted.values)
    return fitted.value(key), np.asarray(fitted.sigma.get(key, np.nan), float)


def earth_rate(fitted, site: Site) -> str:
    """See the module table."""
    if not site.rad_per_s:
        return ""
    n, sn = _value(fitted, "horizontal_rate", "horizontal")
    u, su = _value(fitted, "vertical_rate", "vertical")
    tol = EARTH_TOLERANCE * OMEGA_EARTH
    if site.latitude_deg is not None:
        lat = np.radians(site.latitude_deg)
        want = {"horizontal": (n, sn, OMEGA_EARTH * np.cos(lat)),
                "vertical": (u, su, OMEGA_EARTH * np.sin(lat))}
        for part, (x, s, w) in want.items():
            if np.isfinite(x) and _beyond(x, s, w - tol, w + tol):
                return (f"{part} rate {x:.3g} +- {s:.2g} rad/s where the Earth's at latitude "
                        f"{site.latitude_deg:g} deg is {w:.3g}")
        return ""
    if _beyond(n, sn, -tol, OMEGA_EARTH + tol):
        return f"horizontal rate {n:.3g} +- {sn:.2g} rad/s beyond the Earth's {OMEGA_EARTH:.4g}"
    if np.isfinite(u):
        rate = float(np.hypot(n, u))
        s = float(np.hypot(n * sn, u * su) / max(rate, 1e-300))
        if _beyond(rate, s, OMEGA_EARTH - tol, OMEGA_EARTH + tol):
            return (f"rate {rate:.3g} +- {s:.2g} rad/s ({rate / OMEGA_EARTH:.2f} x the Earth's; "
                    f"latitude {np.degrees(np.arctan2(u, n)):.1f} deg)")
    return ""


def latency(fitted, site: Site) -> str:
    """See the module table."""
    d, s = _value(fitted, "delay")
    if _beyond(d, s, 0.0, LATENCY_MAX):
        return f"delays {np.round(d * 1e3, 3).tolist()} ms outside 0..{LATENCY_MAX * 1e3:g} ms"
    return ""


def rate_error(fitted, site: Site) -> str:
    """See the module table."""
    if "gain" in fitted.values:
        g, s = _value(fitted, "gain")
        if _beyond(g, s, 1 - GAIN_TOLERANCE, 1 + GAIN_TOLERANCE):
            return f"encoder gain {float(g):.3g} +- {float(s):.2g}, not about 1"
        return ""
    spread = float(fitted.values["spread"])
    if spread > RATE_SPREAD_MAX:
        return f"rate spread {spread:.3g} above {RATE_SPREAD_MAX:g}"
    axes = float(fitted.values.get("axes_log10_p", 0.0))
    if axes < AXES_LOG10_P:
        return (f"the per-position rate factors follow the sensor axes (log10 p {axes:.1f}): a "
                "table's rate error cannot know how the unit is mounted")
    return ""


def scale_nonlinearity(fitted, site: Site) -> str:
    """See the module table."""
    k2, s = _value(fitted, "k2")
    peak = np.asarray(fitted.values.get("peak_signal", np.nan), float)
    if _beyond(np.abs(k2) * peak, s * peak, high=NONLINEARITY_MAX):
        return (f"relative nonlinearity up to {np.nanmax(np.abs(k2) * peak):.3g} at the "
                f"largest signal, above {NONLINEARITY_MAX:g}")
    return ""


def scale_asymmetry(fitted, site: Site) -> str:
    """See the module table."""
    k, s = _value(fitted, "k")
    if _beyond(np.abs(k), s, high=NONLINEARITY_MAX):
        return (f"scale asymmetry up to {np.max(np.abs(k)):.3g} relative, above "
                f"{NONLINEARITY_MAX:g}")
    return ""


def polynomial(fitted, site: Site) -> str:
    """See the module table."""
    peak = np.asarray(fitted.values["peak_signal"], float)
    keys = [k for k in fitted.values if k.startswith("c")]
    bend = sum(np.abs(fitted.value(k)) * peak ** (int(k[1:]) - 1) for k in keys)
    spread = np.sqrt(sum((np.asarray(fitted.sigma[k]) * peak ** (int(k[1:]) - 1)) ** 2
                         for k in keys))
    if _beyond(bend, spread, high=NONLINEARITY_MAX):
        return (f"relative nonlinearity up to {np.max(bend):.3g} at the largest signal, above "
                f"{NONLINEARITY_MAX:g}")
    return ""


def axis_wobble(fitted, site: Site) -> str:
    """See the module table."""
    b, s = _value(fitted, "angle_deg")
    if _beyond(np.abs(b), s, high=WOBBLE_MAX_DEG):
        return f"coning half-angle {float(b):.3g} deg above {WOBBLE_MAX_DEG:g} deg"
    return ""


def g_sensitivity(fitted, site: Site) -> str:
    """See the module table."""
    if not site.rad_per_s:
        return ""
    g, s = _value(fitted, "G_deg_s_per_g")
    if _beyond(np.abs(g), s, high=G_SENSITIVITY_MAX):
        return f"g-sensitivity up to {np.max(np.abs(g)):.3g} deg/s per g"
    return ""


def temperature(fitted, site: Site) -> str:
    """See the module table."""
    if not site.rad_per_s:
        return ""
    k, s = _value(fitted, "bias")
    high = np.radians(TEMPCO_MAX)
    if _beyond(np.abs(k), s, high=high):
        return (f"bias tempco up to {np.degrees(np.max(np.abs(k))):.3g} deg/s per K, above "
                f"{TEMPCO_MAX:g}")
    return ""


RANGES = {"earth_rate": earth_rate, "latency": latency, "rate_error": rate_error,
          "scale_nonlinearity": scale_nonlinearity, "scale_asymmetry": scale_asymmetry,
          "polynomial": polynomial,
          "axis_wobble": axis_wobble,
          "g_sensitivity": g_sensitivity, "temperature": temperature}
"""Effect -> its range check; effects not listed accept any fitted value."""


def check(name: str, fitted, site: Site) -> str:
    """Why the fitted parameters of effect `name` are outside its physical range ("" if not)."""
    rule = RANGES.get(name)
    return rule(fitted, site) if rule else ""
