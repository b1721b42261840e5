"""The diagnose loop: fit, compare every candidate effect by its likelihood ratio, add the
strongest significant one, refit, repeat until no candidate is significant.

Evidence of a candidate = the decrease of the model deviance (binned chi2 + rail deviance,
station.diagnose.model) when it is added and everything is refitted jointly: a likelihood ratio.
Its p-value comes from the candidate's null law (chi2(dof) for linear parameters, moment-matched
for the tone fits, 1/2 chi2_0 + 1/2 chi2_1 for a random effect's variance); a candidate is
significant when p < alpha / (candidates tested in the step) (Bonferroni). Also reported: the AIC
change, LR - 2 dof. A significant candidate whose fit lies outside its physical range
(station.diagnose.plausibility) is not named: it "resembles" the effect.

Once no candidate is significant, the final model's gaps are read against their white-noise law
(station.diagnose.goodness): a failed statistic is `unexplained`, described by its signature
(station.diagnose.signature). The calibration of the final model is kept only when its readings
predict the held-out positions better than the uncorrected ones (station.diagnose.heldout).
"""

from dataclasses import dataclass, field, replace

import numpy as np

from station.diagnose import gap, goodness, heldout, model, plausibility, signature
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
    """The sequence of models; the final goodness-of-fit test (`fit_test`, station.diagnose.
    goodness) with the signature of each failed statistic (`unexplained`); the held-out check
    of the final model's correction (`correction`: applied or not)."""

    steps: list
    alpha: float
    fit_test: dict | None = None
    unexplained: list = field(default_factory=list)
    correction: dict | None = None
    spectrum: dict | None = None

    @property
    def resembles(self) -> list:
        """[{"effect", "reason", "log10_p", "step"}]: candidates significant at some step but not
        named: their fit was outside their physical range, or they explain only part of an
        unexplained gap (`settle`); last occurrence of each."""
        out = {}
        for i, step in enumerate(self.steps):
            for name, e in step.evidence.items():
                reason = e.get("implausible") or e.get("not_named")
                if e["significant"] and reason:
                    out[name] = {"effect": name, "reason": reason,
                                 "log10_p": e["log10_p"], "step": i}
        return [v for k, v in out.items() if k not in self.effects]

    @property
    def calibration(self):
        """The calibration to use: the final model's when its correction is applied (or was not
        checked), else the nominal one."""
        applied = self.correction is None or self.correction["applied"]
        return (self.final if applied else self.steps[0].model).calibration

    @property
    def effects(self) -> list:
        """Named effects in the order they were added."""
        return list(self.steps[-1].model.names)

    @property
    def final(self) -> model.Model:
        return self.steps[-1].model


def evidence(current: model.Model, extended: model.Model, name: str, tests: int, alpha):
    """The likelihood-ratio evidence for `name` (extended = current + name)."""
    lr = max(current.deviance - extended.deviance, 0.0)
    fitted = extended.fitted[name]
    scale, nu = fitted.null_law
    log_p = np.log(fitted.null_mass) + goodness.log_sf(lr / scale, nu) if lr > 0 else 0.0
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
             candidates=tuple(EXTENSIONS), site=None, progress=None) -> Diagnosis:
    """Run the workflow on a session (station.diagnose.data.RotaryData); candidates the session
    cannot show (an extension's `available(data)` False) are not offered; `site` gives what the
    physical ranges need (station.diagnose.plausibility.Site; default: latitude unknown);
    `progress` as `greedy`'s."""
    site = site or plausibility.Site()
    candidates = tuple(c for c in candidates
                       if getattr(EXTENSIONS[c], "available", lambda d: True)(data))
    result = greedy(model.nominal(data), candidates,
                    lambda current, names: model.fit(data, list(names), current, iterations),
                    lambda m: gap.statistics(data, m), alpha=alpha, max_effects=max_effects,
                    check=lambda name, f: plausibility.check(name, f, site), progress=progress)
    n = data.shape[0]

    def test_of(step):
        spec = signature.spectrum(data, step.model)
        extra = {"spectrum": signature.test(spec, n),
                 "table_rate_tone": signature.tone_test(spec, n)} if spec else None
        return goodness.test(step.gap, gap.dofs(data, step.model), alpha, extra), spec

    result, (test, spec) = settle(result, test_of, alpha,
                                  {k: e.GAPS for k, e in EXTENSIONS.items()},
                                  {k: getattr(e, "UNREADABLE_WITH", ()) for k, e in
                                   EXTENSIONS.items()})
    if spec:
        spec["peaks"] = signature.peaks(spec, n, alpha)
    return replace(result, fit_test=test, correction=correction(data, result), spectrum=spec,
                   unexplained=[{**test["statistics"][k], "statistic": k,
                                 "signature": _signature(data, result.final, spec, k)}
                                for k in test["failed"]])


def _signature(data, final: model.Model, spec: dict, statistic: str) -> dict:
    """The signature of a failed statistic (station.diagnose.signature): the spectrum's peaks,
    the once-per-revolution points, or the breakdown of a gap's features."""
    if statistic == "spectrum":
        return {"peaks": spec["peaks"]}
    if statistic == "table_rate_tone":
        return {"peaks": signature.tones(spec)}
    return signature.describe(data, final, statistic)


def settle(result: Diagnosis, test_of, alpha: float, own: dict, unreadable=None) -> tuple:
    """(diagnosis, test_of(its final step)), test_of(step) -> (goodness.test, anything): the
    final goodness-of-fit test; when it fails, every
    named effect's evidence is read again with the LR divided by the dispersion the gap leaves
    (the largest failed mean-square gap of many features, so not `rails`, about 1 dof, nor
    `spectrum`, a maximum over its grid; `table_rate_tone` is the mean of 2n squared features
    at fixed points: a quasi-likelihood); the first effect no longer
    significant then, or whose own gap statistics (`own`: {effect: statistics}) still fail,
    and those after it, are not named (`not_named` in its evidence): they explain only part of a
    gap the library does not. Likewise an effect while a statistic of `unreadable` ({effect:
    statistics}, e.g. `rails` for the effects read from the readings M) fails: that gap says
    the data its evidence rests on carry something the model does not explain."""
    out = test_of(result.steps[-1])
    test = out[0]
    dispersion = max([test["statistics"][k]["gap"] for k in test["failed"]
                      if k not in ("spectrum", "rails")], default=1.0)
    for i, step in enumerate(result.steps[:-1]):
        e = step.evidence[step.chosen]
        quasi = (np.log(e["null_mass"]) + goodness.log_sf(
            e["lr"] / (e["null_scale"] * dispersion), e["null_dof"])) / np.log(10)
        left = [k for k in own.get(step.chosen, ()) if k in test["failed"]]
        blind = [k for k in (unreadable or {}).get(step.chosen, ()) if k in test["failed"]]
        weak = dispersion > 1 and quasi >= np.log10(alpha / len(step.evidence))
        if left or blind or weak:
            note = (f"leaves its own signature's gap unexplained ({', '.join(left)})" if left
                    else f"its evidence rests on data that an unexplained gap says are "
                    f"corrupted ({', '.join(blind)})" if blind
                    else f"explains only part of a gap left unexplained (log10 p {quasi:.1f} "
                    f"with the LR over that gap's dispersion {dispersion:.2f})")
            evidence = {**step.evidence, step.chosen: {**e, "not_named": note}}
            last = replace(step, evidence=evidence, chosen="none")
            result = replace(result, steps=[*result.steps[:i], last])
            return result, test_of(last)
    return result, out


def correction(data, result: Diagnosis) -> dict | None:
    """The held-out check of the final model's correction (station.diagnose.heldout): its
    score and the uncorrected readings', and whether it is applied; None without extensions."""
    final = result.final
    if not final.fitted:
        return None
    before = heldout.score(data.reduced.M, data.c, model.noise(data), {})
    corrected, sigma, options = model.readings(data, final.ctx, final.fitted)
    after = heldout.score(corrected, data.c, sigma, options)
    return {"held_out_chi2_before": before, "held_out_chi2_after": after,
            "positions": data.shape[0], "applied": bool(after < before)}


def greedy(start, candidates, extend, statistics, *, alpha: float, max_effects: int,
           check=lambda name, fitted: "", progress=None) -> Diagnosis:
    """The evidence loop from the model `start`: every candidate not yet in the model is added
    (`extend(current, names)` -> the model fitted with those extensions) and its evidence
    measured; the strongest significant one whose fit is plausible (`check(name, fitted)` ->
    "" or why not) is kept; repeated until none is significant or `max_effects` are in.
    `statistics(model)` gives each step's gap. `progress(done, total)`, if given, hears of each
    fit: done so far, and at most `total` (every step going on)."""
    current, steps = start, []
    n = len(candidates)
    tried, total = 0, sum(n - s for s in range(min(max_effects, n)))
    while True:
        remaining = [c for c in candidates if c not in current.fitted]
        ev, best, chosen = {}, "none", None
        if len(current.fitted) < max_effects:
            for name in remaining:
                fit = extend(current, (*current.fitted, name))
                ev[name] = evidence(current, fit, name, len(remaining), alpha)
                ev[name]["implausible"] = check(name, fit.fitted[name])
                if ev[name]["significant"] and not ev[name]["implausible"] and (
                        best == "none" or ev[name]["log10_p"] < ev[best]["log10_p"]):
                    best, chosen = name, fit  # only the strongest fit so far is kept (memory)
                tried += 1
                if progress is not None:
                    progress(tried, total)
        steps.append(Step(current, statistics(current), ev, best))
        if best == "none":
            return Diagnosis(steps, alpha)
        current = chosen
