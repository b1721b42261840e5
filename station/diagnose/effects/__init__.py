"""Model extensions, one module per named effect, mirroring `station/model/effects/<name>.py`.

Each module exposes
- `GAPS`: the gap statistics that hold its signature (not named while one stays unexplained);
- optionally `UNREADABLE_WITH`: gap statistics whose failure says the data its evidence rests
  on are corrupted (not named while one stays unexplained: rate_error and scale_nonlinearity,
  read from the readings M, while `rails` fails);
- `STAGE`: where the twin applies it ("rate", "motion", "sensed", "offset", "output");
- `fit(ctx, twin, r) -> Fitted`: its parameters from the residuals of the twin without it
  (`twin`, station.diagnose.prediction.Twin: its rate (n, k) and its sensed rate a chunk of
  positions at a time), given as their centred bins and static means r (station.diagnose.linear),
  by weighted least squares;
- at the sensor stages ("sensed", "offset"): `params(fitted)`, the simulator's own parameters
  (station.model.effects), which the twin runs through the one sensor output chain
  (station.model.sensing); at the other stages: `apply(ctx, fitted, x, ...)`, its distortion at
  its stage, through the simulator's own effect function (imported, never copied): at the
  "rate" stage on the rate (n, k), at the "motion" stage `apply(ctx, fitted, omega, rate, rows)`
  on the positions `rows` (a slice), at the "output" stage on a chunk's output (p, k, m);
- at the stage "added": `apply(ctx, fitted, rows)`, the (p, k, m) offsets at the positions `rows`
  (temperature: at the session's recorded temperature; jump: after its instant), added beside the
  sensor chain's offsets;
- optionally `available(data) -> bool`: False when the session cannot show the effect (temperature:
  no recorded temperature); the candidate is then not offered (station.diagnose.select.diagnose);
- optionally `TOLD_APART`: {other candidate: what to record to tell the two apart} for the
  candidates whose signature can match this one's on a session (station.diagnose.select: an
  ambiguous pair is named together, corrected with neither);
- optionally `calibration_options(fitted) -> dict | None`: keyword arguments of
  `station.calibrate` when the extension enters the calibration's own model (rate_error: the
  magnitudes' spread) instead of a correction of the readings M; None: corrected for.
"""

from dataclasses import dataclass, field

import numpy as np

READ_FROM_M = ("rails",)
"""`UNREADABLE_WITH` of the effects read from the Eq. (18) readings M (rate_error,
scale_nonlinearity): a pile-up at the output rails that the model does not explain means some
readings were cut by a clip, which lowers those sensors' M_ij at the positions where they reach
the rail. Per-position factors (a table rate error: |v_j| through M_j) or a per-sensor
quadratic fitted to M absorb that cut, so they are not named while `rails` stays unexplained (a
clip left out of the candidates, m = 3, was named `rate_error` 3 of 3 times)."""


@dataclass(frozen=True)
class Fitted:
    """A fitted extension.

    values : parameter name -> estimate (what the twin applies and the report shows).
    sigma : parameter name -> 1-sigma uncertainty (same shapes; NaN where none is defined).
    dof : number of free parameters (for the likelihood-ratio test).
    reduction : decrease of the residual chi2 when this extension was fitted (a diagnostic).
    notes : what the estimate can and cannot say.
    null : (scale, nu): without the effect the likelihood ratio is about scale * chi2(nu);
        (1, dof) for parameters entering linearly, moment-matched otherwise (`tone_null`).
    null_mass : probability that the likelihood ratio is positive without the effect: 1, or 1/2
        for a variance on the boundary s = 0 of its range (law 1/2 chi2_0 + 1/2 chi2_1).
    searched : the points of a grid the fit took the best of (an open family's frequency): the
        p-value of its likelihood ratio is that many times the one point's (Bonferroni).
    penalty : random-effect terms of the model deviance (-2 log marginal likelihood) beyond the
        residual chi2; 0 for fixed effects.
    units : parameter name -> unit of its value, for the reports ("" dimensionless; a parameter
        without an entry is shown without a unit).
    """

    name: str
    values: dict
    sigma: dict
    dof: int
    reduction: float = 0.0
    notes: str = ""
    null: tuple = ()
    null_mass: float = 1.0
    penalty: float = 0.0
    units: dict = field(default_factory=dict)
    searched: int = 1

    def value(self, key):
        return np.asarray(self.values[key], float)

    @property
    def null_law(self) -> tuple:
        return self.null or (1.0, float(self.dof))


def sensed_fit(name: str, key: str, lf, peak: np.ndarray, units=None) -> Fitted:
    """The Fitted of a per-sensor term of the sensed signal (`linear.sensed_term`'s fit `lf` and
    peak |s|): its coefficient `key` per sensor with sigma, and the peak signal (the plausibility
    range's scale)."""
    return Fitted(
        name,
        {key: lf.theta[:, 0], "peak_signal": peak},
        {key: np.sqrt(lf.cov[:, 0, 0]), "peak_signal": np.full(peak.shape, np.nan)},
        dof=lf.theta.shape[0],
        reduction=lf.reduction(),
        units=units or {},
    )


def tone_null(h: np.ndarray, draws: int = 4000, seed: int = 0) -> tuple:
    """(scale, nu) of the null law of the chi2 decrease of a tone fit with one free phase per
    position and one common amplitude (earth_rate, axis_wobble).

    h (n, 2, 2) are the per-position normal matrices of the two quadratures. Without the effect
    the gradients g_j ~ N(0, h_j); the fit takes each phase from its free 2-D estimate and then
    the common amplitude, decreasing chi2 by (sum_j e_j . g_j)^2 / sum_j e_j . h_j e_j. That law
    is simulated (fixed seed) and matched to scale * chi2(nu) by its mean and variance.
    """
    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(h + 1e-12 * np.trace(h, axis1=1, axis2=2)[:, None, None] * np.eye(2))
    g = np.einsum("npq,dnq->dnp", chol, rng.standard_normal((draws, h.shape[0], 2)))
    theta = np.linalg.solve(h[None], g[..., None])[..., 0]
    e = theta / np.linalg.norm(theta, axis=2, keepdims=True)
    num = np.einsum("dnp,dnp->d", e, g) ** 2
    den = np.einsum("dnp,npq,dnq->d", e, h, e)
    t = num / den
    mean, var = t.mean(), t.var()
    return var / (2 * mean), 2 * mean**2 / var


def _registry() -> dict:
    from station.diagnose.effects import (
        axis_wobble,
        bias_drift,
        earth_rate,
        jump,
        latency,
        polynomial,
        rate_error,
        saturation,
        scale_asymmetry,
        scale_nonlinearity,
        temperature,
        tone,
    )

    return {
        "bias_drift": bias_drift,
        "scale_nonlinearity": scale_nonlinearity,
        "scale_asymmetry": scale_asymmetry,
        "rate_error": rate_error,
        "earth_rate": earth_rate,
        "saturation": saturation,
        "axis_wobble": axis_wobble,
        "latency": latency,
        "temperature": temperature,
        "tone": tone,
        "jump": jump,
        "polynomial": polynomial,
    }


EXTENSIONS = _registry()
"""Effect name -> model extension module (the simulator's EFFECTS names, and the open families:
`tone`, `jump`, `polynomial`)."""
OPEN_FAMILIES = ("tone", "jump", "polynomial")
"""The open families: they generalise named effects (a tone at the table rate is axis_wobble's
coning), so a named effect they match is the specific answer, never an ambiguity with them."""
