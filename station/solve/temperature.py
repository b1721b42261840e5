"""The thermal fit: per-soak calibrations -> the temperature model (station.model.temperature).

Each soak (the unit held at one temperature) is calibrated by the existing solver (`calibrate`:
closed form + maximum likelihood, the per-pose term included; docs/solvers.md). A soak's fit is
reduced to its scale factors s_i = |a_i| and biases b_i with their joint covariance C_k (from the
fit's covariance of (a, b), the poses eliminated): in the Gaussian limit these carry all the soak
says about the temperature model, whose polynomials are linear in their coefficients

    s_i(T) = s_i0 + sum_p q_ip x^p,   b_i(T) = b_i0 + sum_p beta_ip x^p,   x = T - T_ref.

The joint likelihood over all soaks is therefore Gaussian and maximised in closed form by
generalised least squares (weights C_k^-1), with the exact covariance (X^T W X)^-1 and
chi2 = r^T W r (Kariya & Kurata, "Generalized Least Squares", 2004, ch. 2). The relative scale
tempcos gamma_ip = q_ip / s_i0 and their covariance follow by first-order propagation.

The orders (one for the biases, one for the scale factors, shared by the m sensors: a datasheet
gives one tempco law per quantity, and sharing keeps each test's m extra coefficients together) are
chosen by nested likelihood-ratio tests: from (0, 0), the order of a quantity is raised while the
drop in chi2 exceeds the chi2(m) quantile of false-alarm probability FALSE_ALARM / 2 (Bonferroni
over the two candidates of a step); under a true lower order the drop is exactly chi2(m)
(Wilks; exact here, the model being linear and Gaussian), so each step adds a needless order with
probability at most FALSE_ALARM.
"""

from dataclasses import dataclass, replace

import numpy as np

from station.errors import CalibrationInputError
from station.model.temperature import MAX_ORDER, Soak, TemperatureModel, check_kelvin, powers
from station.solve.calibrate import CalibrationResult, calibrate
from station.solve.quality import CHI2_P
from station.solve.tails import chi2_isf, chi2_sf

FALSE_ALARM = 0.01
"""Probability that the order selection raises an order the data do not need, per step."""
MIN_SPAN = 5.0
"""Soak temperatures spanning less than this (K) cannot resolve a slope against the noise of
any MEMS unit: refused."""
DISTINCT = 1.0
"""Soaks closer than this (K) count as one temperature for the orders they can resolve."""


@dataclass(frozen=True)
class TemperatureFit:
    """The thermal fit.

    model     : the TemperatureModel at the selected orders
    reference : the calibration at T_ref (a CalibrationResult): a's axis directions from the soak
                nearest T_ref, the scale factors and biases the fit's s_i0, b_i0 with their
                covariance
    soaks     : the per-soak CalibrationResults, in the order given; soak_data the Soaks
    chi2, dof : of the fit at the selected orders; tests : [(quantity, order, drop in chi2,
                threshold, accepted)] of the order selection
    problems  : why the fit is suspect, in words (the soaks scatter about the model by more than
                their calibrations' uncertainty: chi2 beyond its upper CHI2_P / 2 tail, the
                quality gate's level, station.solve.quality); empty when it is consistent
    """

    model: TemperatureModel
    reference: CalibrationResult
    soaks: tuple
    soak_data: tuple
    chi2: float
    dof: int
    tests: tuple
    problems: tuple = ()


def fit_temperature(soaks, magnitude: float, *, orders=None, nominal=None, names=None,
                    false_alarm: float = FALSE_ALARM) -> TemperatureFit:
    """Fit the temperature model to `soaks` (a list of station.model.temperature.Soak) of
    stimulus magnitude `magnitude` (local gravity in m/s^2, the table rate in rad/s). orders:
    {"bias": P_b, "scale": P_s} to fix them, or None to select them (module docstring). names:
    the sensors' names for messages."""
    soaks = list(soaks)
    temps = _temperatures(soaks)
    results = tuple(_calibrate_soak(s, magnitude, nominal, names) for s in soaks)
    y, cov = zip(*(_invariants(r, s) for r, s in zip(results, soaks, strict=True)), strict=True)
    t_ref = 0.5 * (temps.min() + temps.max())
    x = temps - t_ref
    most = min(MAX_ORDER, _distinct(temps) - 1)
    if orders is None:
        chosen, tests = select_orders(x, y, cov, most, false_alarm)
    else:
        chosen, tests = _given(orders, most), ()
    g = gls(x, y, cov, chosen)
    model = _model(g, chosen, t_ref, temps)
    nearest = results[int(np.argmin(np.abs(x)))]
    return TemperatureFit(model, _reference(nearest, g), results, tuple(soaks), g["chi2"],
                          g["dof"], tests, _problems(g["chi2"], g["dof"]))


def _problems(chi2: float, dof: int) -> tuple:
    """The fit's inconsistency with the soaks' uncertainties, in words (none: ())."""
    if dof <= 0 or chi2_sf(dof, chi2) >= CHI2_P / 2:
        return ()
    return (f"the soaks scatter about the temperature model by more than their calibrations' "
            f"uncertainty (chi2 {chi2:.1f} for {dof} degrees of freedom): hysteresis between "
            "heating and cooling, a soak not settled, or a dependence the polynomials lack; the "
            "orders and sigmas are not to be trusted",)


def still_soak(temperature: float, readings) -> Soak:
    """The Soak of a still-pose soak's reduced readings (station.reduce.still.StillReadings or
    an iron's: M, sigma and constraints(), the inputs of `station.solve.still.calibrate_still`)
    at the unit's mean temperature (K) over it."""
    return Soak(float(temperature), readings.M, readings.sigma,
                constraints=readings.constraints())


def _temperatures(soaks) -> np.ndarray:
    """(K,) soak temperatures, checked: kelvin, finite, at least two, spanning MIN_SPAN."""
    if len(soaks) < 2:
        raise CalibrationInputError(f"{len(soaks)} soak(s) given; a temperature model needs at "
                                    "least 2 (3 for a quadratic).",
                                    "Soak the unit at more setpoints.")
    temps = check_kelvin([s.temperature for s in soaks], "soak temperature")
    span = temps.max() - temps.min()
    if span < MIN_SPAN:
        raise CalibrationInputError(
            f"the soaks span {span:.3g} K ({temps.min():.2f} .. {temps.max():.2f} K), too close "
            f"to resolve a slope (at least {MIN_SPAN:g} K).",
            "Spread the setpoints over the unit's operating range.")
    return temps


def _distinct(temps: np.ndarray) -> int:
    """Number of distinct temperatures (closer than DISTINCT count as one)."""
    t = np.sort(temps)
    return 1 + int(np.sum(np.diff(t) >= DISTINCT))


def _given(orders, most: int) -> dict:
    """The orders given, checked against what the soaks resolve."""
    chosen = {q: int(orders[q]) for q in ("bias", "scale")}
    for q, p in chosen.items():
        if not 0 <= p <= MAX_ORDER:
            raise CalibrationInputError(f"{q} order {p} is not in 0..{MAX_ORDER}.",
                                        "Choose 0, 1 or 2, or let the data select it.")
        if p > most:
            raise CalibrationInputError(
                f"a {q} polynomial of order {p} needs {p + 1} distinct soak temperatures "
                f"(at least {DISTINCT:g} K apart); the soaks give {most + 1}.",
                "Soak at more setpoints or lower the order.")
    return chosen


def _calibrate_soak(soak: Soak, magnitude: float, nominal, names) -> CalibrationResult:
    """The soak's calibration by the existing solver (biases estimated, or measured apart)."""
    bias = "estimate" if soak.bias is None else None
    try:
        return calibrate(soak.readings, magnitude, d=3, bias=bias, sigma=soak.sigma,
                         constraints=soak.constraints, nominal=nominal, names=names)
    except CalibrationInputError as exc:
        raise CalibrationInputError(f"the soak at {soak.temperature:.2f} K: {exc.problem}",
                                    exc.advice) from None


def _invariants(result: CalibrationResult, soak: Soak) -> tuple:
    """((2m,) scale factors then biases, their (2m, 2m) covariance) of a soak's calibration: by
    first-order propagation of the covariance of (a row-major, b) in the result's frame; biases
    measured apart are independent of a."""
    a = result.a
    d, m = a.shape
    s = np.linalg.norm(a, axis=0)
    jac = np.zeros((m, d * m))
    for i in range(m):
        jac[i, i::m] = a[:, i] / s[i]  # d|a_i| / d a_ri, a row-major
    cov = result.parameter_covariance
    if soak.bias is None:
        full = np.zeros((2 * m, d * m + m))
        full[:m, : d * m], full[m:, d * m:] = jac, np.eye(m)
        return np.r_[s, result.bias], full @ cov @ full.T
    joint = np.zeros((2 * m, 2 * m))
    joint[:m, :m] = jac @ cov[: d * m, : d * m] @ jac.T
    joint[m:, m:] = np.diag(np.asarray(soak.bias_sigma, float) ** 2)
    return np.r_[s, np.asarray(soak.bias, float)], joint


def select_orders(x, y, cov, most: int, false_alarm: float = FALSE_ALARM) -> tuple:
    """(orders, tests) by nested likelihood-ratio tests (module docstring) up to order `most`."""
    m = len(y[0]) // 2
    chosen = {"bias": 0, "scale": 0}
    threshold = chi2_isf(m, false_alarm / 2)
    tests = []
    current = gls(x, y, cov, chosen)["chi2"]
    while True:
        steps = {q: {**chosen, q: chosen[q] + 1} for q in chosen if chosen[q] < most}
        if not steps:
            break
        drops = {q: current - gls(x, y, cov, o)["chi2"] for q, o in steps.items()}
        q = max(drops, key=drops.get)
        accepted = drops[q] > threshold
        tests.append((q, steps[q][q], float(drops[q]), threshold, bool(accepted)))
        if not accepted:
            break
        chosen = steps[q]
        current -= drops[q]
    return chosen, tuple(tests)


def gls(x, y, cov, orders: dict) -> dict:
    """The generalised least-squares fit of the polynomials (module docstring) to the soaks'
    invariants y[k] (2m,) with covariances cov[k] at x[k] = T_k - T_ref: {"theta": (s0, q
    (m, P_s) row-major, b0, beta (m, P_b) row-major), "covariance", "chi2", "dof"}."""
    m = len(y[0]) // 2
    ps, pb = orders["scale"], orders["bias"]
    blocks = [_design(xk, m, ps, pb) for xk in x]
    weights = [np.linalg.pinv(c, hermitian=True) for c in cov]
    info = sum(xk.T @ w @ xk for xk, w in zip(blocks, weights, strict=True))
    score = sum(xk.T @ w @ yk for xk, w, yk in zip(blocks, weights, y, strict=True))
    covariance = np.linalg.inv(info)
    theta = covariance @ score
    chi2 = sum(float((yk - xk @ theta) @ w @ (yk - xk @ theta))
               for xk, w, yk in zip(blocks, weights, y, strict=True))
    return {"theta": theta, "covariance": covariance, "chi2": chi2,
            "dof": 2 * m * len(x) - theta.size, "m": m, "orders": dict(orders)}


def _design(x: float, m: int, ps: int, pb: int) -> np.ndarray:
    """(2m, m (2 + P_s + P_b)) design of one soak: rows (s_1..s_m, b_1..b_m)."""
    row = np.r_[1.0, powers(x, max(ps, pb))[0]]
    eye = np.eye(m)
    out = np.zeros((2 * m, m * (2 + ps + pb)))
    out[:m, : m * (1 + ps)] = np.kron(eye, row[: 1 + ps])
    out[m:, m * (1 + ps):] = np.kron(eye, row[: 1 + pb])
    return out


def _model(g: dict, orders: dict, t_ref: float, temps) -> TemperatureModel:
    """The TemperatureModel of a GLS fit: gamma = q / s0 with its covariance by propagation."""
    m, ps, pb = g["m"], orders["scale"], orders["bias"]
    theta, cov = g["theta"], g["covariance"]
    scale_block = theta[: m * (1 + ps)].reshape(m, 1 + ps)
    s0, q = scale_block[:, 0], scale_block[:, 1:]
    gamma = q / s0[:, None]
    # theta -> (beta row-major, gamma row-major); theta = (s0, q per sensor ..., b0, beta ...)
    jac = np.zeros((m * (pb + ps), theta.size))
    for i in range(m):
        for p in range(pb):
            jac[i * pb + p, m * (1 + ps) + i * (1 + pb) + 1 + p] = 1.0
        for p in range(ps):
            row = m * pb + i * ps + p
            jac[row, i * (1 + ps) + 1 + p] = 1.0 / s0[i]
            jac[row, i * (1 + ps)] = -q[i, p] / s0[i] ** 2
    bias = theta[m * (1 + ps):].reshape(m, 1 + pb)[:, 1:]
    return TemperatureModel(t_ref=float(t_ref), t_min=float(np.min(temps)),
                            t_max=float(np.max(temps)), bias=bias, scale=gamma,
                            covariance=_symmetric(jac @ cov @ jac.T))


def _symmetric(c: np.ndarray) -> np.ndarray:
    """c made exactly symmetric (rounding of a propagation leaves it a few ulp off)."""
    return 0.5 * (c + c.T)


def _reference(nearest: CalibrationResult, g: dict) -> CalibrationResult:
    """The calibration at T_ref: the nearest soak's axis directions scaled to the fit's s_i0,
    the fit's b_i0; the covariance of (a, b) that soak's a block rescaled beside the fit's b0
    block (the white-noise figures dropped: the reference is a fit over all soaks)."""
    m, ps, pb = g["m"], g["orders"]["scale"], g["orders"]["bias"]
    theta, cov = g["theta"], g["covariance"]
    i_s = np.arange(m) * (1 + ps)
    i_b = m * (1 + ps) + np.arange(m) * (1 + pb)
    s0, b0 = theta[i_s], theta[i_b]
    ratio = s0 / nearest.scale_factors
    d = nearest.a.shape[0]
    scale = np.tile(ratio, d)  # a row-major: entry (r, i) scaled by ratio_i
    k = d * m
    joint = np.zeros((k + m, k + m))
    joint[:k, :k] = nearest.parameter_covariance[:k, :k] * np.outer(scale, scale)
    joint[k:, k:] = cov[np.ix_(i_b, i_b)]
    return replace(nearest, a=nearest.a * ratio, a_sigma=nearest.a_sigma * ratio, bias=b0,
                   bias_estimated=True, bias_sigma=np.sqrt(np.diag(cov)[i_b]),
                   scale_factors=s0, scale_factors_sigma=np.sqrt(np.diag(cov)[i_s]),
                   parameter_covariance=joint, a_sigma_white=None,
                   scale_factors_sigma_white=None, axis_angles_sigma_white=None,
                   bias_sigma_white=None)
