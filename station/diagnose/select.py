"""The diagnose loop: fit, compare every candidate effect by its likelihood ratio, add the
strongest significant one, refit, repeat until no candidate is significant.

Evidence of a candidate = the decrease of the model deviance (binned chi2 + rail deviance,
station.diagnose.model) when it is added and everything is refitted jointly: a likelihood ratio.
Its p-value comes from the candidate's null law (chi2(dof) for linear parameters, moment-matched
for the tone fits, 1/2 chi2_0 + 1/2 chi2_1 for a random effect's variance); a candidate is
significant when p < alpha / (candidates tested in the step) (Bonferroni). Also reported: the AIC
change, LR - 2 dof.
"""

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln
from scipy.stats import chi2 as chi2_law

from station.diagnose import gap, model
from station.diagnose.effects import EXTENSIONS


@dataclass(frozen=True)
class Step:
    """One model of the sequence: its extensions, fit, gap and the evidence that led on."""

    model: model.Model
    gap: dict
    evidence: dict  # candidate -> {"lr", "dof", "p", "log10_p", "significant", "delta_aic"}
    chosen: str  # effect added next, or "none"


@dataclass(frozen=True)
class Diagnosis:
    steps: list
    alpha: float

    @property
    def effects(self) -> list:
        """Named effects in the order they were added."""
        return list(self.steps[-1].model.names)

    @property
    def final(self) -> model.Model:
        return self.steps[-1].model


def log_sf(x: float, nu: float) -> float:
    """log P(chi2(nu) > x); beyond double precision, the leading term of the incomplete gamma
    function's asymptotic series (so that overwhelming evidence still ranks)."""
    out = float(chi2_law.logsf(x, nu))
    if np.isfinite(out):
        return out
    return float((nu / 2 - 1) * np.log(x / 2) - x / 2 - gammaln(nu / 2))


def evidence(current: model.Model, extended: model.Model, name: str, tests: int, alpha):
    """The likelihood-ratio evidence for `name` (extended = current + name)."""
    lr = max(current.deviance - extended.deviance, 0.0)
    fitted = extended.fitted[name]
    scale, nu = fitted.null_law
    log_p = np.log(fitted.null_mass) + log_sf(lr / scale, nu) if lr > 0 else 0.0
    return {
        "lr": lr,
        "dof": fitted.dof,
        "null_scale": scale,
        "null_dof": nu,
        "null_mass": fitted.null_mass,
        "p": float(np.exp(log_p)),
        "log10_p": log_p / np.log(10),
        "significant": bool(log_p < np.log(alpha / tests)),
        "delta_aic": lr - 2 * fitted.dof,
    }


def diagnose(data, *, alpha: float = 0.01, max_effects: int = 3, iterations: int = 3,
             candidates=tuple(EXTENSIONS), progress=None) -> Diagnosis:
    """Run the workflow on a session (station.diagnose.data.RotaryData); `progress` as
    `greedy`'s."""
    return greedy(model.nominal(data), candidates,
                  lambda current, names: model.fit(data, list(names), current, iterations),
                  lambda m: gap.statistics(data, m), alpha=alpha, max_effects=max_effects,
                  progress=progress)


def greedy(start, candidates, extend, statistics, *, alpha: float, max_effects: int,
           progress=None) -> Diagnosis:
    """The evidence loop from the model `start`: every candidate not yet in the model is added
    (`extend(current, names)` -> the model fitted with those extensions) and its evidence
    measured; the strongest significant one is kept; repeated until none is significant or
    `max_effects` are in. `statistics(model)` gives each step's gap. `progress(done, total)`, if
    given, hears of each fit: done so far, and at most `total` (every step going on)."""
    current, steps = start, []
    n = len(candidates)
    tried, total = 0, sum(n - s for s in range(min(max_effects, n)))
    while True:
        remaining = [c for c in candidates if c not in current.fitted]
        fits, ev = {}, {}
        if len(current.fitted) < max_effects:
            for name in remaining:
                fits[name] = extend(current, (*current.fitted, name))
                ev[name] = evidence(current, fits[name], name, len(remaining), alpha)
                tried += 1
                if progress is not None:
                    progress(tried, total)
        best = min((n for n in ev if ev[n]["significant"]), key=lambda n: ev[n]["log10_p"],
                   default="none")
        steps.append(Step(current, statistics(current), ev, best))
        if best == "none":
            return Diagnosis(steps, alpha)
        current = fits[best]
