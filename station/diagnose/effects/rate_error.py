"""Extension `rate_error`: the table's true rate is the command times 1 + delta_j per position.

Encoder. When the table's angle reads the shaft, the delta_j are measured (`RotaryData.
rate_factors`, which differ from 1 beyond their precision: `encoder_reads`). The extension then
has one parameter, the gain lambda of the signature delta_j s_j(t), a fixed effect (LR ~
chi2(1)); lambda = 1 says the readings follow the encoder's rates. The readings are corrected
like any fixed effect, the common part of the delta_j included: with the encoder it is no longer
a common scale factor of unknown size. The random-effects fit below is kept instead when it
explains more (a table that reports its command, whose factors are noise).

Random effect. Otherwise (the table reports the commanded angle) delta_j ~ N(0, spread^2) is a
random effect (one parameter, the spread s). Why random: nothing but the readings tells delta_j
then, and with one free factor per position the magnitudes |v_j| = c (1 + delta_j) leave a only
determined up to GL(3) (the magnitude constraint is what fixes g = a a^T). With the prior on
delta_j, a is identifiable again. The common part of the delta_j (the simulator's `scale`) is a
common scale factor of all sensors (Remark 2 of Rupniewski): the prior's mean is 0, and it is
not estimated.

Fit, given the twin without the extension:
1. per position, the least-squares factor delta_hat_j on the signature s_j(t) (the twin's sensed
   signal) and its variance w_j (`linear.fit`);
2. delta_hat = delta - X e + noise, where X e (X: (n, d(d+1)/2), the quadratic forms u_j^T E u_j
   over symmetric E) is the part of the delta_j a calibration absorbs by changing g = a a^T: a
   linear mixed model with fixed effects X and the random effect delta. s^2 maximises its
   restricted (REML) likelihood, which accounts for what the calibration absorbs (unbiased where
   a plain moment estimate over n positions is biased low by the d(d+1)/2 absorbed directions);
3. the twin's factors are the BLUPs 1 + s^2 / (s^2 + w_j) (delta_hat_j - (X e_gls)_j);
4. the calibration step (station.diagnose.model) calibrates the uncorrected Eq. (18) readings with
   magnitude_spread = s (`calibration_options`), i.e. the soft-magnitude maximum likelihood.

Likelihood ratio: the model's deviance gains the random-effect terms of -2 log marginal likelihood,
sum_j delta_j^2 / s^2 + log(1 + s^2 / w_j) (`Fitted.penalty`), so the LR against the nested s = 0
model is that of one variance on the boundary of its range: 1/2 chi2_0 + 1/2 chi2_1 (null mass 1/2).
"""

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import chi2
from scipy.stats import f as f_law

from station.diagnose import linear
from station.diagnose.effects import READ_FROM_M, Fitted
from station.model.effects import rate_error

GAPS = ("averaged",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
UNREADABLE_WITH = READ_FROM_M
STAGE = "rate"
TOLD_APART = {
    name: "the table's angle from an encoder on its shaft (the rate each position really turned "
          "at), or positions at a second table rate"
    for name in ("scale_asymmetry", "scale_nonlinearity")}
"""Candidates whose signature can match this one's on a session -> what to record to tell them
apart (station.diagnose.select: an ambiguous pair): with one rate magnitude per position, a
factor per position can take the shape of a per-sensor term even in the signal."""
ENCODER_TOL = 1e-9
"""Precision of a rate factor read off an exact angle array (rounding only)."""
ENCODER_ALPHA = 1e-3
"""False-alarm rate of the test that the table's angle shows rates other than the command."""


def quadratic_design(u: np.ndarray) -> np.ndarray:
    """(n, d(d+1)/2) regressors u_j^T E u_j for the symmetric basis matrices E (u: (d, n) unit)."""
    i, k = np.triu_indices(u.shape[0])
    return np.where(i == k, 1.0, 2.0) * u[i].T * u[k].T


def _projector(t: float, w: np.ndarray, x: np.ndarray):
    """REML pieces at s^2 = t: V^-1 (diagonal), the projector P = V^-1 - V^-1 X (X^T V^-1 X)^-1
    X^T V^-1, and log det(X^T V^-1 X)."""
    vinv = 1.0 / (t + w)
    xtx = x.T @ (vinv[:, None] * x)
    h = (vinv[:, None] * x) @ np.linalg.solve(xtx, (vinv[:, None] * x).T)
    return vinv, np.diag(vinv) - h, np.linalg.slogdet(xtx)[1]


def reml_spread(delta: np.ndarray, w: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(s^2, its standard deviation) maximising the restricted likelihood of delta ~ N(X e,
    diag(s^2 + w)); s^2 >= 0, on the boundary when the data call for none."""
    def minus2_loglik(t):
        vinv, p, logdet_x = _projector(t, w, x)
        return float(-np.sum(np.log(vinv)) + logdet_x + delta @ p @ delta)

    hi = 10.0 * (np.var(delta) + w.max())
    best = minimize_scalar(minus2_loglik, bounds=(0.0, hi), method="bounded",
                           options={"xatol": 1e-6 * hi})
    t = float(best.x) if best.fun < minus2_loglik(0.0) else 0.0
    _, p, _ = _projector(t, w, x)
    return t, float(np.sqrt(2.0 / np.sum(p * p)))  # Fisher information of s^2: tr(P P) / 2


def fit(ctx, twin, r) -> Fitted:
    """The random-effects fit, or, when the table's angle shows rates other than the command
    (`encoder_reads`), the encoder's fit if it explains more (a larger chi2 decrease net of the
    random effect's penalty: the test of `encoder_reads` relies on the IMU timing's 1-sigma,
    which a busy virtual bench can understate); see the module docstring."""
    # per position: the least-squares factor of the signature s_j(t) and its variance w_j; the
    # quadratic forms of the axes that a calibration absorbs
    lf = linear.fit_binned(r, [linear.centred_signature(ctx.data, twin.sensed)],
                           linear.weights(ctx.data, ctx.sigma), "position")
    u = ctx.v / np.linalg.norm(ctx.v, axis=0)
    x = quadratic_design(u)
    random = _fit_random(lf, x, axes_design(ctx.a, u))
    if not encoder_reads(ctx.data):
        return random
    encoder = _fit_encoder(ctx, twin, r, ctx.data.rate_factors - 1.0, lf.cov[:, 0, 0], x)
    return encoder if encoder.reduction >= random.reduction - random.penalty else random


def axes_design(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(n, m) regressors (a_i . u_j / |a_i|)^3: the per-position magnitude change that a
    per-sensor output nonlinearity k2 s^2 makes (sum_i k2_i s_ij^2 (a_i . u_j) / c), which
    follows the sensor axes."""
    return ((a / np.linalg.norm(a, axis=0)).T @ u).T ** 3


def axes_log10_p(delta_hat: np.ndarray, v: np.ndarray, x: np.ndarray, z: np.ndarray) -> float:
    """log10 p of the F test that the per-position factors delta_hat (variances v = s^2 + w)
    follow the sensor axes (regressors z) beyond what a calibration absorbs (x): a table's rate
    error cannot know how the unit is mounted. 0 when too few positions remain."""
    n = delta_hat.size
    full = np.column_stack([x, z])
    rank_x, rank_full = np.linalg.matrix_rank(x), np.linalg.matrix_rank(full)
    q, rest = rank_full - rank_x, n - rank_full
    if q < 1 or rest < 3:
        return 0.0
    sw = 1.0 / np.sqrt(v)

    def rss(design):
        coef = np.linalg.lstsq(design * sw[:, None], delta_hat * sw, rcond=None)[0]
        return float(np.sum(((delta_hat - design @ coef) * sw) ** 2))

    small, big = rss(x), rss(full)
    f = (small - big) / q / max(big / rest, 1e-300)
    return float(f_law.logsf(f, q, rest) / np.log(10))


def _fit_random(lf, x, z) -> Fitted:
    """The spread s by REML, the factors 1 + delta_j (BLUP) and the deviance terms, from the
    per-position fit `lf`, the absorbed design x and the sensor-axes design z (`axes_log10_p`,
    a check of the physical range: station.diagnose.plausibility)."""
    delta_hat, w = lf.theta[:, 0], lf.cov[:, 0, 0]
    t, t_sigma = reml_spread(delta_hat, w, x)
    vinv, p, _ = _projector(t, w, x)
    shrink = t * vinv
    delta = t * (p @ delta_hat)  # s^2 V^-1 (delta_hat - X e_gls)
    penalty = float(np.sum(delta**2) / t + np.sum(np.log1p(t / w))) if t > 0 else 0.0
    spread = float(np.sqrt(t))
    return Fitted(
        "rate_error",
        {"factors": 1.0 + delta, "spread": spread,
         "axes_log10_p": axes_log10_p(delta_hat, t + w, x, z)},
        {"factors": np.sqrt(shrink * w), "spread": float(np.sqrt(t + t_sigma)) - spread,
         "axes_log10_p": np.nan},
        dof=1,
        reduction=lf.reduction(delta[:, None]),
        notes="random effect: factors are BLUPs; the common rate error (scale) is not separable "
        "from a common scale factor; the sigma of the spread is the 1-sigma step of s^2 (REML "
        "Fisher information) upward, expressed in s",
        null_mass=0.5,
        penalty=penalty,
    )


def encoder_reads(data) -> bool:
    """True when the table's angle shows rates other than the command: the chi2 of the rate
    factors' deviations from 1 over their 1-sigma (at least ENCODER_TOL) exceeds its 1 -
    ENCODER_ALPHA quantile. False for a table that reports its command."""
    z = (data.rate_factors - 1.0) / np.maximum(data.rate_factors_sigma, ENCODER_TOL)
    return bool(np.sum(z**2) > chi2.isf(ENCODER_ALPHA, z.size))


def _fit_encoder(ctx, twin, r, measured: np.ndarray, w: np.ndarray,
                 x: np.ndarray) -> Fitted:
    """The gain lambda of the encoder's relative rate errors `measured` (n,); factors
    1 + lambda measured_j.

    The calibration absorbs the part X e of the measured_j (common scale and quadratic forms of
    the axes, x = `quadratic_design`), so the residuals of the twin without this extension hold
    only the rest, measured - X e (weighted by the information w_j^-1 of each position's level):
    the gain is the least-squares coefficient of that rest times s_j(t), whatever the correction
    the calibration already saw."""
    info = 1.0 / w
    absorbed = x @ np.linalg.lstsq(x * np.sqrt(info)[:, None], np.sqrt(info) * measured,
                                   rcond=None)[0]
    rest = measured - absorbed
    signature = linear.centred_signature(  # made a few positions at a time (memory)
        ctx.data, lambda rows: twin.sensed(rows) * rest[rows, None, None])
    lf = linear.fit_binned(r, [signature],
                           linear.weights(ctx.data, ctx.sigma), "global")
    gain, sd = float(lf.theta[0, 0]), float(np.sqrt(lf.cov[0, 0, 0]))
    return Fitted(
        "rate_error",
        {"factors": 1.0 + gain * measured, "gain": gain, "scale": float(measured.mean()),
         "spread": float(measured.std(ddof=1))},
        {"factors": sd * np.abs(measured), "gain": sd, "scale": np.nan, "spread": np.nan},
        dof=1,
        reduction=lf.reduction(),
        notes="rates read by the table's encoder: scale and spread are the mean and sd of "
        "true/commanded - 1 over the positions (measured, no sigma); gain 1 means the readings "
        "follow the encoder; the gain is tested on what a calibration cannot absorb",
    )


def calibration_options(fitted: Fitted) -> dict | None:
    """Keyword arguments of station.calibrate for the uncorrected Eq. (18) readings: the
    soft-magnitude maximum likelihood at the fitted spread; None when the encoder measured the
    factors (the readings are corrected instead)."""
    if "gain" in fitted.values:
        return None
    return {"magnitude_spread": float(fitted.values["spread"])}


def apply(ctx, fitted: Fitted, rate: np.ndarray) -> np.ndarray:
    """Table rate (n, k) times each position's factor (station.model.effects.rate_error)."""
    return rate_error.apply(rate[..., None], fitted.value("factors"))[..., 0]
