"""PASS / FAIL / MARGINAL (station.solve.verdict) on simulated units inside and outside their
tolerances, borderline ones included; and the verdict on the command line.

200 simulated 12-gyro units (Section IV layout, 20 positions, noise 0.003 so that a scale
factor's 1-sigma is about 1e-3), 100 inside their tolerances (a third with one parameter at
90-100 % of its limit: borderline) and 100 outside (one scale factor or bias at 1-2 times its
tolerance). The rule judges with a 2-sigma margin, so a verdict contradicts the truth (PASS for a
parameter truly out of tolerance, FAIL for one truly inside) only when the estimate errs by more
than 2 sigma plus the truth's distance to the limit: for parameters more than 2 sigma from their
limit, more than 4 sigma (p = 6e-5 per parameter; fixed seed), so none may. Such a parameter is
MARGINAL when its estimate falls within 2 sigma of the limit, as often as normal errors predict;
within 2 sigma of the limit any verdict is excused, and there MARGINAL must be the common one."""

from types import SimpleNamespace

import numpy as np
import pytest
from layouts import random_directions
from scipy.stats import norm

import station
from station import cli
from station.sim.layouts import A_MODEL
from station.solve.verdict import MARGIN, Tolerances, judge, verdict

TOL = Tolerances(scale_factor=0.02, bias=0.01, axis_angle_deg=1.0)
UNITS = 200


def simulated_unit(rng, outside: bool):
    """(truth, calibration-like result with biases) of one unit measured at 20 positions. Inside
    units: every parameter within 70 % of its tolerance, and one in three with one scale factor
    or bias at 90-100 % of it (borderline); outside units: one scale factor or bias at 1-2 times
    its tolerance (borderline near 1)."""
    k = 1 + rng.choice([-1, 1], 12) * rng.uniform(0, 0.7, 12) * TOL.scale_factor
    bias = rng.choice([-1, 1], 12) * rng.uniform(0, 0.7, 12) * TOL.bias
    low, high = (1, 2) if outside else (0.9, 1.0)
    if outside or rng.random() < 1 / 3:
        i = rng.integers(12)
        if rng.random() < 0.5:
            k[i] = 1 + rng.choice([-1, 1]) * rng.uniform(low, high) * TOL.scale_factor
        else:
            bias[i] = rng.choice([-1, 1]) * rng.uniform(low, high) * TOL.bias
    tilt = np.radians(rng.uniform(0, 0.35 * TOL.axis_angle_deg, 12))  # pair angles within 0.7 T
    u = A_MODEL / np.linalg.norm(A_MODEL, axis=0)
    w = np.cross(u.T, rng.standard_normal((12, 3))).T
    w /= np.linalg.norm(w, axis=0)
    axes = np.cos(tilt) * u + np.sin(tilt) * w  # each axis tilted by `tilt` off nominal
    a = k * axes
    bias_sigma = np.full(12, 0.0005)
    v = random_directions(rng, 3, 20)
    result = station.calibrate(a.T @ v + 0.003 * rng.standard_normal((12, 20)), 1.0, sigma=0.003)
    cal = SimpleNamespace(**{f: getattr(result, f) for f in (
        "scale_factors", "scale_factors_sigma", "axis_angles", "axis_angles_sigma")},
        bias=bias + bias_sigma * rng.standard_normal(12), bias_sigma=bias_sigma)
    unit = u.T @ u
    truth_angles = np.degrees(np.arccos(np.clip(axes.T @ axes, -1, 1)))
    nominal_angles = np.degrees(np.arccos(np.clip(unit, -1, 1)))
    return {"scale factor": np.abs(k - 1), "bias": np.abs(bias),
            "angle": np.abs(truth_angles - nominal_angles)[np.triu_indices(12, 1)]}, cal


def test_the_rule():
    assert judge(0.0, 0.1, 1.0) == "pass" and judge(2.0, 0.1, 1.0) == "fail"
    assert judge(0.85, 0.1, 1.0) == "marginal" and judge(1.15, 0.1, 1.0) == "marginal"
    assert judge(1.0 - MARGIN * 0.1, 0.1, 1.0) == "pass"


def test_verdicts_agree_with_the_truth_beyond_two_sigma_of_a_limit():
    rng = np.random.default_rng(2026)
    params = {"contradictions": 0, "far": 0, "far_marginal": 0, "far_marginal_expected": 0.0,
              "near": 0, "near_marginal": 0}
    units = {"PASS": [], "FAIL": [], "near": []}  # by the truth; lists of verdicts
    for n in range(UNITS):
        truth, cal = simulated_unit(rng, outside=n % 2 == 1)
        v = verdict(cal, TOL, nominal=A_MODEL)
        got = {"scale factor": [], "bias": [], "angle": []}
        for p in v["parameters"]:
            kind = "angle" if p["name"].startswith("angle") else (
                "bias" if p["name"].endswith("bias") else "scale factor")
            got[kind].append(p)
        near = outside = False
        for kind, judged in got.items():
            for true_dev, p in zip(truth[kind], judged, strict=True):
                inside = true_dev <= p["limit"]
                far = abs(true_dev - p["limit"]) > MARGIN * p["sigma"]
                outside |= far and not inside
                near |= not far
                wrong = (p["verdict"] == "pass" and not inside) or \
                    (p["verdict"] == "fail" and inside)
                params["far" if far else "near"] += 1
                params["far_marginal" if far else "near_marginal"] += p["verdict"] == "marginal"
                params["contradictions"] += far and wrong
                if far:  # P(estimate within MARGIN sigma of the limit), normal errors
                    d = abs(true_dev - p["limit"]) / p["sigma"]
                    params["far_marginal_expected"] += norm.cdf(d + MARGIN) - norm.cdf(d - MARGIN)
        units["FAIL" if outside else "near" if near else "PASS"].append(v["overall"])
    assert params["contradictions"] == 0, params
    assert params["near"] >= 50, params  # borderline parameters included
    # beyond 2 sigma of every limit the unit's verdict is the truth's, or MARGINAL where an
    # estimate fell within 2 sigma of its limit: as often as normal errors predict (3 s.e.)
    assert units["PASS"] and set(units["PASS"]) <= {"PASS", "MARGINAL"}, units
    assert units["FAIL"] and set(units["FAIL"]) <= {"FAIL", "MARGINAL"}, units
    assert units["PASS"].count("PASS") >= 0.8 * len(units["PASS"]), units
    assert units["FAIL"].count("FAIL") >= 0.8 * len(units["FAIL"]), units
    expected = params["far_marginal_expected"]
    assert params["far_marginal"] <= expected + 3 * np.sqrt(expected), params
    # within 2 sigma of a limit: mostly MARGINAL
    assert units["near"].count("MARGINAL") >= 0.5 * len(units["near"]), units
    assert params["near_marginal"] >= 0.4 * params["near"], params


def test_tolerances_are_checked():
    with pytest.raises(ValueError, match="unknown tolerance"):
        Tolerances.from_table({"scale": 0.1})
    with pytest.raises(ValueError, match="positive number"):
        Tolerances.from_table({"bias": -1})
    assert Tolerances().empty and not TOL.empty


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """An 8-position rotary session of the virtual bench through the real drivers."""
    from station.protocols.rotary import RotarySettings, suggested_axes
    from station.twin.rotary_bench import VirtualBench, record_rotary

    path = tmp_path_factory.mktemp("verdict") / "s.h5"
    with VirtualBench("serial", seed=5) as bench:
        record_rotary(bench, path, RotarySettings(), suggested_axes(8))
    return path


@pytest.mark.parametrize("limit, overall, code", [(0.5, "PASS", 0), (1e-6, "FAIL", 1)])
def test_solve_judges_the_unit_prints_the_verdict_and_exits_by_it(session, tmp_path, capsys,
                                                                  limit, overall, code):
    tolerances = tmp_path / "type.toml"
    tolerances.write_text(f"[tolerances]\nscale_factor = {limit}\nbias = 0.5\n")
    out = tmp_path / "s.cal.json"
    assert cli.main(["solve", str(session), "--out", str(out), "--tolerances",
                     str(tolerances)]) == code
    printed = capsys.readouterr().out
    assert f"VERDICT: {overall} (24 parameters tested)" in printed
    from station.calfiles.calfile import load

    stored = load(out).verdict
    assert stored["overall"] == overall and len(stored["parameters"]) == 24
    assert (overall == "FAIL") == ("FAIL: g1 scale factor" in printed)


def test_a_bad_tolerance_file_is_refused(session, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[tolerances]\nscale = 0.1\n")
    assert cli.main(["solve", str(session), "--out", str(tmp_path / "x.json"), "--tolerances",
                     str(bad)]) == 2
    assert "unknown tolerance" in capsys.readouterr().err
