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
from station.diagnose.effects import EXTENSIONS, OPEN_FAMILIES


@dataclass(frozen=True)
class Step:
    """One model of the sequence: its extensions, fit, gap and the evidence that led on."""

    model: model.Model
    gap: dict
    evidence: dict  # candidate -> {"lr", "dof", "p", "log10_p", "significant", "delta_aic"}
    chosen: str  # effect added next, or "none"


WHY = "with both in the model neither adds to the other"
"""Why candidates are ambiguous (`ambiguous`), unless their evidence says otherwise."""


@dataclass(frozen=True)
class Diagnosis:
    """The sequence of models; the final goodness-of-fit test (`fit_test`, station.diagnose.
    goodness) with the signature of each failed statistic (`unexplained`); the held-out check
    of the final model's correction (`correction`: applied or not); the share of its own gap
    each named effect closes (`closes`: {effect: `closed`}, `partial` True while one of its own
    statistics still fails) and the significant effects found but not named (`not_named`,
    `settle`), each with the reason and the share of its own gap it closed; `caveats`, what a
    named effect may be instead where this session cannot tell (a free-static drift or a
    walk)."""

    steps: list
    alpha: float
    fit_test: dict | None = None
    unexplained: list = field(default_factory=list)
    correction: dict | None = None
    spectrum: dict | None = None
    closes: dict = field(default_factory=dict)
    not_named: tuple = ()
    caveats: tuple = ()

    @property
    def resembles(self) -> list:
        """[{"effect", "reason", "log10_p", "step"}]: candidates significant at some step but not
        named because their fit was outside their physical range (last occurrence of each), then
        the `not_named` ones (with what they close)."""
        out = {}
        for i, step in enumerate(self.steps):
            for name, e in step.evidence.items():
                if e["significant"] and e.get("implausible"):
                    out[name] = {"effect": name, "reason": e["implausible"],
                                 "log10_p": e["log10_p"], "step": i}
        dropped = [p["effect"] for p in self.not_named]
        return [v for k, v in out.items() if k not in self.effects and k not in dropped] + list(
            self.not_named)

    @property
    def ambiguous(self) -> list:
        """[{"effects", "log10_p", "told_apart_by", "step"}]: candidates found indistinguishable
        at a step (`ambiguous`: the data say one of them is there, not which), named together and
        corrected with neither, with what to record to tell them apart. A member that is no
        candidate (a free-static gyro law's `pose_bias`: the loop's `noise` said it explains the
        law as well) has no p-value; the evidence then says why and how to tell (`why`,
        `told_apart_by`)."""
        out = []
        for i, step in enumerate(self.steps):
            seen = set()
            for name, e in step.evidence.items():
                if "ambiguous_with" in e and name not in seen:
                    group = sorted({name, *e["ambiguous_with"]})
                    seen |= set(group)
                    out.append({"effects": group, "step": i,
                                "told_apart_by": e.get("told_apart_by") or told_apart(group),
                                "why": e.get("why", WHY),
                                "log10_p": {k: step.evidence[k]["log10_p"] for k in group
                                            if k in step.evidence}})
        return out

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
    return likelihood_ratio(current.deviance - extended.deviance, extended.fitted[name], tests,
                            alpha)


def likelihood_ratio(lr: float, fitted, tests: int, alpha) -> dict:
    """The evidence of a deviance decrease `lr` by the extension `fitted`, one of `tests`
    candidates: its p-value under the extension's null law, its significance at alpha / tests."""
    lr = max(lr, 0.0)
    scale, nu = fitted.null_law
    mass = fitted.null_mass * fitted.searched  # an open family's grid: Bonferroni over it
    log_p = min(np.log(mass) + goodness.log_sf(lr / scale, nu), 0.0) if lr > 0 else 0.0
    return {
        "lr": lr,
        "dof": fitted.dof,
        "null_scale": scale,
        "null_dof": nu,
        "null_mass": mass,
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
    start = model.nominal(data)

    def run(excluded=()):
        return greedy(start, tuple(c for c in candidates if c not in excluded),
                      lambda current, names: model.fit(data, list(names), current, iterations),
                      lambda m: gap.statistics(data, m), alpha=alpha, max_effects=max_effects,
                      check=lambda name, f: plausibility.check(name, f, site),
                      noise=lambda name, fit, current: within_walk(getattr(
                          EXTENSIONS[name], "beyond_walk", lambda *_: None)(
                          current, fit.fitted[name]), alpha / len(candidates)),
                      progress=progress)

    n = data.shape[0]

    def test_of(step):
        spec = signature.spectrum(data, step.model)
        extra = {"spectrum": signature.test(spec, n),
                 "table_rate_tone": signature.tone_test(spec, n)} if spec else None
        return goodness.test(step.gap, gap.dofs(data, step.model), alpha, extra), spec

    result, (test, spec) = settle(run(), test_of, alpha,
                                  {k: e.GAPS for k, e in EXTENSIONS.items()},
                                  {k: getattr(e, "UNREADABLE_WITH", ()) for k, e in
                                   EXTENSIONS.items()}, run)
    if spec:
        spec["peaks"] = signature.peaks(spec, n, alpha)
    return replace(result, fit_test=test, correction=correction(data, result), spectrum=spec,
                   unexplained=[{**test["statistics"][k], "statistic": k,
                                 "signature": _signature(data, result.final, spec, k)}
                                for k in test["failed"]])


def within_walk(log10_p: float | None, level: float) -> str:
    """"" or why a fitted drift is no effect: a bias random walk explains it (`log10_p` of the
    drift against a free walk, station.diagnose.walk, not below log10 `level`; None: the
    candidate is no drift)."""
    if log10_p is None or log10_p < np.log10(level):
        return ""
    return f"a bias random walk explains it (log10 p {log10_p:.1f} of the drift beside a free walk)"


def _signature(data, final: model.Model, spec: dict, statistic: str) -> dict:
    """The signature of a failed statistic (station.diagnose.signature): the spectrum's peaks,
    the once-per-revolution points, or the breakdown of a gap's features."""
    if statistic == "spectrum":
        return {"peaks": spec["peaks"]}
    if statistic == "table_rate_tone":
        return {"peaks": signature.tones(spec)}
    return signature.describe(data, final, statistic)


def settle(result: Diagnosis, test_of, alpha: float, own: dict, unreadable=None,
           rerun=None) -> tuple:
    """(diagnosis, test_of(its final step)), test_of(step) -> (goodness.test, anything): the
    final goodness-of-fit test, and every named effect judged against it (`withheld`; one
    whose own gap stays open is named as partial when it stands). An effect withheld is not
    named and is listed in `not_named` with the share of its own gap it closed; when effects
    were named after it, the loop is run again without it (`rerun(excluded candidates)` ->
    Diagnosis), so that an effect it stood in front of is still named (issue 32: a drift that
    soaked up coloured noise took the real effect with it); the last named one is cut off.
    Repeated until every named effect stands; each then gets `closed` of its own gap (`own`:
    {effect: statistics}) from the step it was added to the final model."""
    dropped = []
    while True:
        out = test_of(result.steps[-1])
        test = out[0]
        dof = {k: s["dof"] for k, s in test["statistics"].items() if "dof" in s}
        found = withheld(result, test, alpha, own, unreadable or {})
        if found is None:
            closes = {s.chosen: {**closed(s.gap, result.steps[-1].gap, dof, own.get(s.chosen, ()),
                                          alpha),
                                 "partial": any(k in test["failed"] for k in own.get(s.chosen, ()))}
                      for s in result.steps[:-1]}
            return replace(result, closes=closes, not_named=tuple(dropped)), out
        i, note = found
        step = result.steps[i]
        dropped.append({"effect": step.chosen, "reason": note, "not_named": True,
                        "log10_p": step.evidence[step.chosen]["log10_p"],
                        "closes": closed(step.gap, result.steps[i + 1].gap, dof,
                                         own.get(step.chosen, ()), alpha)})
        if rerun is not None and i < len(result.steps) - 2:
            result = rerun(tuple(p["effect"] for p in dropped))
        else:
            result = replace(result, steps=[*result.steps[:i], replace(step, chosen="none")])


def withheld(result: Diagnosis, test: dict, alpha: float, own: dict, unreadable: dict):
    """(step, why) of the first named effect that the final test `test` says is not to be
    named, or None: a statistic of `unreadable` ({effect: statistics}, e.g. `rails` for the
    effects read from the readings M) fails, which says the data its evidence rests on carry
    something the model does not explain; or its LR over the dispersion of the gap it sits in
    is no longer significant (a quasi-likelihood). That dispersion is the largest failed gap of
    its own statistics (`own`: {effect: statistics}: the noise its signature really shows, e.g.
    a bias random walk in `static`) when one of them fails (the effect is then named as partial,
    `closed` says how much), else the largest failed mean-square gap of many features (so not
    `rails`, about 1 dof, nor `spectrum`, a maximum over its grid; `table_rate_tone` is the mean
    of 2n squared features at fixed points)."""
    dispersion = max([test["statistics"][k]["gap"] for k in test["failed"]
                      if k not in ("spectrum", "rails")], default=1.0)
    for i, step in enumerate(result.steps[:-1]):
        e = step.evidence[step.chosen]
        left = [k for k in own.get(step.chosen, ()) if k in test["failed"]]
        blind = [k for k in unreadable.get(step.chosen, ()) if k in test["failed"]]
        if blind:
            return i, (f"its evidence rests on data that an unexplained gap says are corrupted "
                       f"({', '.join(blind)})")
        phi = max(test["statistics"][k]["gap"] for k in left) if left else dispersion
        quasi = (np.log(e["null_mass"]) + goodness.log_sf(
            e["lr"] / (e["null_scale"] * phi), e["null_dof"])) / np.log(10)
        if phi > 1 and quasi >= np.log10(alpha / len(step.evidence)):
            return i, (f"explains only part of a gap left unexplained (log10 p {quasi:.1f} with "
                       f"the LR over {'its own' if left else 'that'} gap's dispersion "
                       f"{phi:.2f})")
    return None


def closed(before: dict, after: dict, dof: dict, statistics, alpha: float = 0.01) -> dict:
    """The share of the gap an effect closes: over its own `statistics` that were open before it
    (gap x dof beyond its chi2(dof) law at level `alpha`), 1 - (the chi2 excess left after) /
    (the excess before), each excess dof x (gap - 1) and what is left never below the noise;
    per statistic too. `fraction` None when none of its statistics was open."""
    open_ = [k for k in statistics if k in before and k in after and k in dof
             and goodness.log_sf(before[k] * dof[k], dof[k]) < np.log(alpha)]
    by = {k: float(np.clip(1 - max(after[k] - 1, 0) / (before[k] - 1), 0, 1)) for k in open_}
    excess = sum(dof[k] * (before[k] - 1) for k in open_)
    left = sum(dof[k] * max(after[k] - 1, 0) for k in open_)
    return {"fraction": float(np.clip(1 - left / excess, 0, 1)) if open_ else None,
            "by_statistic": by}


CONVERGED = 0.1
"""A model refitted from itself that lowers its deviance by less than this (a tenth of a chi2
unit, far below any test's threshold) is converged."""
ROUNDS = 10
"""Refits at most, towards `CONVERGED`."""


def converged(fit, extend):
    """The model `fit` refitted from itself (`extend(fit, its names)`) until its deviance drops
    by less than CONVERGED: the joint fit's few iterations leave a strong effect unconverged
    (a warm-up or asymmetry far above its limit: 273 of deviance left after the first fit), and
    the next step would credit that remainder to whichever candidate it adds (every candidate
    then looks significant, equally)."""
    for _ in range(ROUNDS):
        again = extend(fit, tuple(fit.fitted))
        if fit.deviance - again.deviance < CONVERGED:
            return again if again.deviance < fit.deviance else fit
        fit = again
    return fit


def _eligible(e: dict) -> bool:
    """A candidate the loop may name: significant, plausible and more than the noise."""
    return e["significant"] and not e.get("implausible") and not e.get("within_noise")


def _strongest(ev: dict, excluded) -> str:
    """The eligible candidate of smallest p-value outside `excluded`, or "none"."""
    names = [k for k, e in ev.items() if k not in excluded and _eligible(e)]
    return min(names, key=lambda k: ev[k]["log10_p"], default="none")


def ambiguous(current, chosen, best: str, ev: dict, extend, alpha: float, taken=()) -> list:
    """The eligible candidates indistinguishable from `best` on this session (issue 32, pattern
    5): each is significant alone, and with both in the model neither adds significantly to the
    other (the likelihood ratio of each given the other, at alpha over the step's candidates):
    the data say one of them is there, not which. Open families are never ambiguous with the
    strongest named effect (`OPEN_FAMILIES`: they generalise them); once a group is ambiguous,
    `greedy` names the next candidate only if it adds significantly to the group's strongest,
    else it joins the group (an open family that explains what the pair explains is no answer
    either). `chosen` is the model with `best`; the model with both is fitted only where the
    difference of the two alone leaves it possible. Candidates `taken` (already said ambiguous
    in a group of this step) are not paired again."""
    tests = len(ev)
    out = []
    for other, e in ev.items():
        if other == best or other in taken or not _eligible(e) or {best, other} & set(
                OPEN_FAMILIES):
            continue
        # best given other decreases the deviance by at least LR(best) - LR(other)
        if likelihood_ratio(ev[best]["lr"] - e["lr"], chosen.fitted[best], tests,
                            alpha)["significant"]:
            continue
        both = extend(current, (*current.fitted, best, other))
        given_other = current.deviance - e["lr"] - both.deviance
        given_best = chosen.deviance - both.deviance
        if not (likelihood_ratio(given_other, both.fitted[best], tests, alpha)["significant"]
                or likelihood_ratio(given_best, both.fitted[other], tests, alpha)["significant"]):
            out.append(other)
    return out


def told_apart(names) -> str:
    """What to record to tell ambiguous candidates apart (their modules' `TOLD_APART`)."""
    ways = {EXTENSIONS[a].TOLD_APART[b] for a in names for b in names
            if b in getattr(EXTENSIONS[a], "TOLD_APART", {})}
    return "; ".join(sorted(ways)) or ("positions where their signatures differ (other "
                                       "orientations, rates or timings)")


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
           check=lambda name, fitted: "", noise=lambda name, fit, current: "",
           progress=None) -> Diagnosis:
    """The evidence loop from the model `start`: every candidate not yet in the model is added
    (`extend(current, names)` -> the model fitted with those extensions) and its evidence
    measured; the strongest significant one whose fit is plausible (`check(name, fitted)` ->
    "" or why not) and more than the noise (`noise(name, fit, current)` -> "" or why not, fit
    the model with it, `within_noise` in its evidence: a drift a bias random walk explains, a
    gyro law a bias moving from pose to pose explains) is kept; repeated until none is
    significant or `max_effects` are in. `statistics(model)` gives each step's gap.
    `progress(done, total)`, if given, hears of each fit: done so far, and at most `total`
    (every step going on)."""
    current, steps, excluded = start, [], set()
    n = len(candidates)
    tried, total = 0, sum(n - s for s in range(min(max_effects, n)))
    while True:
        remaining = [c for c in candidates if c not in current.fitted and c not in excluded]
        ev, best, chosen = {}, "none", None
        if len(current.fitted) < max_effects:
            for name in remaining:
                fit = extend(current, (*current.fitted, name))
                ev[name] = evidence(current, fit, name, len(remaining), alpha)
                ev[name]["implausible"] = check(name, fit.fitted[name])
                if ev[name]["significant"] and not ev[name]["implausible"]:
                    ev[name]["within_noise"] = noise(name, fit, current)
                if _eligible(ev[name]) and (
                        best == "none" or ev[name]["log10_p"] < ev[best]["log10_p"]):
                    best, chosen = name, fit  # only the strongest fit so far is kept (memory)
                tried += 1
                if progress is not None:
                    progress(tried, total)
        while best != "none" and (tied := ambiguous(current, chosen, best, ev, extend, alpha,
                                                    excluded)):
            group, leader = {best, *tied}, chosen
            best, chosen = _strongest(ev, excluded | group), None
            while best != "none":  # the next must explain more than the group does
                both = extend(leader, (*leader.fitted, best))
                if likelihood_ratio(leader.deviance - both.deviance, both.fitted[best], len(ev),
                                    alpha)["significant"]:
                    chosen = extend(current, (*current.fitted, best))
                    break
                group.add(best)  # it explains what the group does (an open family, too)
                best = _strongest(ev, excluded | group)
            for name in group:
                ev[name]["ambiguous_with"] = sorted(group - {name})
            excluded |= group
        steps.append(Step(current, statistics(current), ev, best))
        if best == "none":
            return Diagnosis(steps, alpha)
        current = converged(chosen, extend)
