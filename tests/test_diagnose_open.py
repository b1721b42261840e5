"""Issue 32: the open families name effects no list foresaw, add them to the model and show the
gap shrink: `tone` (a coning at any frequency, pattern 6) and `jump` (a step of the biases at
one instant). Both search a grid (frequencies, instants) and Bonferroni their p-value over it.
`polynomial` (a bend of the output in the signal, its order searched) likewise. The acceptance
figures (10 seeds a case) are bench/diagnose.py --open's; these are three seeds and the
algebra."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from station.diagnose import diagnose, linear, model
from station.diagnose.effects import Fitted, jump

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

SEEDS = (3600, 3601, 3602)


def named_alone(case: str, seed: int, family: str, gap: str) -> tuple:
    """(fitted family, truth) of a bench session hiding `case`: the family is named alone,
    nothing is left unexplained and its own `gap` shrinks."""
    data, truth = bench.session(case, 3, seed)
    result = diagnose(data)
    assert result.effects == [family] and not result.unexplained
    assert result.steps[-1].gap[gap] < result.steps[0].gap[gap]
    return result.final.fitted[family], truth


@pytest.mark.parametrize("seed", SEEDS)
def test_a_coning_off_the_table_rate_is_named_a_tone_at_its_frequency(seed):
    tone, _ = named_alone("tone_1.7x", seed, "tone", "harmonics")
    z = (tone.values["table_rate_multiple"] - 1.7) / tone.sigma["table_rate_multiple"]
    assert abs(z) < 3


@pytest.mark.parametrize("seed", SEEDS)
def test_a_step_of_the_biases_is_named_a_jump_at_its_instant(seed):
    fitted, truth = named_alone("jump", seed, "jump", "static")
    lo, hi = fitted.values["t0_span"]
    assert lo <= truth["jump"]["t0"] <= hi
    z = (fitted.value("delta") - truth["jump"]["delta"]) / fitted.sigma["delta"]
    assert np.all(np.abs(z) < 4)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_cubic_bend_of_the_output_is_named_a_polynomial(seed):
    """A cubic term no named effect has (c3 s^3, 3-4 x its limit): the open family `polynomial`
    is named alone, as a cubic, and the `averaged` gap shrinks."""
    fitted, _ = named_alone("polynomial_cubic", seed, "polynomial", "averaged")
    assert fitted.values["order"] == 3
    assert {k for k in fitted.values if k.startswith("c")} == {
        f"c{q}" for q in range(2, fitted.values["order"] + 1)}


def test_the_scan_is_the_least_squares_fit_at_each_instant():
    """The closed-form scan's chi2 decrease at an instant is the weighted least squares of the
    step's own signature (made sample by sample, centred as the residuals are) at that instant."""
    data, _ = bench.session("jump", 3, 3600)
    nominal = model.nominal(data)
    r = linear.centred_signature(data, nominal.twin.residual)
    w = linear.weights(data, nominal.ctx.sigma)
    lr, _, _ = jump.scan(data, r, w)
    rng = np.random.default_rng(1)
    for j, e in [(0, 5), (3, 0), (7, 40), (19, lr.shape[1] - 1),
                 *zip(rng.integers(0, 20, 4), rng.integers(0, lr.shape[1], 4), strict=True)]:
        t0 = jump._instant(data, int(j), int(e))[1]
        step = linear.centred(data, jump._step(data, t0, slice(None))[..., None])
        direct = linear.fit_binned(r, [step], w, "sensor").reduction()
        assert lr[j, e] == pytest.approx(direct, rel=1e-9, abs=1e-9)


def test_effect_free_sessions_name_no_open_family():
    """The families' best point over their grid is Bonferroni'd: in white noise neither is
    significant (a false name at most alpha = 1 % a session over all candidates)."""
    named = [diagnose(bench.session("none", m, 1000 * m + s)[0]).effects
             for m in (3, 12) for s in range(3)]
    assert not any({"tone", "jump"} & set(n) for n in named)


def test_a_jump_after_the_last_static_window_is_not_judged_against_a_walk():
    """Its static means do not step, so the walk's test has no column to judge (it returned a
    deviance of -inf from a singular design before); one inside the session is judged."""
    data, _ = bench.session("none", 3, 3000)
    nominal = model.nominal(data)
    s1 = data.windows["static"][1]
    times = data.session_times(slice(data.shape[0] - 1, None))[0]
    late = Fitted("jump", {"t0": float(times[s1 + 10]), "delta": np.zeros(3)}, {}, dof=4)
    assert jump.beyond_walk(nominal, late) is None
    middle = Fitted("jump", {"t0": float(data.session_times(slice(10, 11))[0][0]),
                             "delta": np.zeros(3)}, {}, dof=4)
    assert jump.beyond_walk(nominal, middle) is not None
