"""Solver benchmark: every figure of the calibration core's acceptance, printed (or --json).

- noiseless exactness (PCA for d = 2, 3, 4; Hwangbo & Kanade p = 3, p = 4, p = 4 quartic)
- Monte Carlo on Rupniewski's Section IV setup: median eps, efficiency eps^2 / trace(CRLB) per n
  (the bound is conditional on the trial's directions, so the ratio is taken per trial and then
  averaged; the ratio of the means is printed too: at n = 8 a few near-degenerate designs with a
  bound 40-160x the median dominate it, and there the estimator is far from its asymptotic regime),
  log-log slopes of the median eps against sigma and n; Figs. 2-4 of the paper as PNG files
- triad with scale factors (1, 0.3, 3): closed form against ML, relative to the bound
- coverage of the nominal 95 % intervals of scale factors and axis angles
- Hwangbo & Kanade Table I (bench/factorization.py)
- speed: closed form m = 12, n = 20; ML m = 12, n = 200; baseline: dense scipy least_squares
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from factorization import table1  # noqa: E402
from layouts import random_directions, section4_gyros  # noqa: E402

import station  # noqa: E402
from station.solve.constraints import from_faces  # noqa: E402
from station.solve.factorization import factorize  # noqa: E402
from station.solve.ml import refine  # noqa: E402
from station.solve.pca import pca_calibration  # noqa: E402

N_VALUES = (8, 12, 20, 50, 100, 200)
SIGMAS = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2)
N_SLOPE = (50, 100, 200, 400)


def exactness(seed: int) -> dict:
    """Largest eps over random noiseless problems, per solver."""
    rng = np.random.default_rng(seed)
    out = {}
    for d in (2, 3, 4):
        worst = 0.0
        for _ in range(200):
            m = int(rng.integers(d, d + 8))
            n = int(rng.integers(d * (d + 1) // 2 + 1, 40))
            a = rng.standard_normal((d, m))
            v = random_directions(rng, d, n, rng.uniform(0.5, 5))
            worst = max(worst, station.eps(
                a, pca_calibration(a.T @ v, np.linalg.norm(v[:, 0]), d)[0]))
        out[f"pca_d{d}"] = worst
    faces = ["+x", "-x", "+y", "-y", "+z", "-z"]
    base = np.array([[1, -1, 0, 0, 0, 0], [0, 0, 1, -1, 0, 0], [0, 0, 0, 0, 1, -1]], float)
    worst = {"hk_p3_opposite_pairs": 0.0, "hk_p4_faces": 0.0, "hk_p4_quartic": 0.0}
    for _ in range(100):
        rot = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        a3, b3 = np.eye(3) + 0.05 * rng.standard_normal((3, 3)), rng.normal(0, 0.3, 3)
        fit = factorize(a3.T @ rot @ base + b3[:, None], from_faces(faces), estimate_bias=False)
        worst["hk_p3_opposite_pairs"] = max(worst["hk_p3_opposite_pairs"], station.eps(a3, fit.a))
        a4, b4 = rng.standard_normal((3, 5)), rng.normal(0, 0.3, 5)
        fit = factorize(a4.T @ rot @ base + b4[:, None], from_faces(faces), estimate_bias=True)
        worst["hk_p4_faces"] = max(worst["hk_p4_faces"], station.eps(a4, fit.a))
        v = random_directions(rng, 3, 20)
        fit = factorize(a4.T @ v + b4[:, None], magnitude=1.0, estimate_bias=True)
        worst["hk_p4_quartic"] = max(worst["hk_p4_quartic"], station.eps(a4, fit.a))
    out.update(worst)
    return out


def section4(trials: int, seed: int) -> dict:
    """Rupniewski Section IV Monte Carlo: efficiency per n, slopes against sigma and n."""
    rng = np.random.default_rng(seed)
    per_n, eps_by_n = {}, {}
    for n in N_VALUES:
        e_cf, e_ml, bound = np.empty(trials), np.empty(trials), np.empty(trials)
        for t in range(trials):
            a, v, readings = section4_gyros(rng, n, 0.01)
            a_cf, v_cf = pca_calibration(readings, 1.0, 3)
            e_cf[t] = station.eps(a, a_cf)
            e_ml[t] = station.eps(a, refine(readings, a_cf, v_cf, sigma=0.01).a)
            bound[t] = np.trace(station.crlb(a, v, 0.01))
        eps_by_n[n] = e_cf
        per_n[n] = {"median_eps_closed_form": float(np.median(e_cf)),
                    **efficiency(e_cf**2, e_ml**2, bound),
                    "sqrt_mean_crlb": float(np.sqrt(bound.mean()))}
    eps_by_sigma = {}
    for sigma in SIGMAS:
        eps_by_sigma[sigma] = np.array([
            station.eps(a, pca_calibration(readings, 1.0, 3)[0])
            for a, _, readings in (section4_gyros(rng, 20, sigma) for _ in range(trials))])
    eps_slope_n = {}
    for n in N_SLOPE:
        eps_slope_n[n] = np.array([
            station.eps(a, pca_calibration(readings, 1.0, 3)[0])
            for a, _, readings in (section4_gyros(rng, n, 0.01) for _ in range(trials))])
    slope_sigma = np.polyfit(
        np.log(SIGMAS), np.log([np.median(eps_by_sigma[s]) for s in SIGMAS]), 1)[0]
    slope_n = np.polyfit(
        np.log(N_SLOPE), np.log([np.median(eps_slope_n[n]) for n in N_SLOPE]), 1)[0]
    return {
        "trials": trials, "per_n": per_n,
        "median_eps_n20_sigma001": per_n[20]["median_eps_closed_form"],
        "slope_vs_sigma": float(slope_sigma), "slope_vs_n": float(slope_n),
        "_eps_by_n": eps_by_n, "_eps_by_sigma": eps_by_sigma, "_eps_slope_n": eps_slope_n,
    }


def figures(mc: dict, out: Path) -> list[str]:
    """Figs. 2-4 of Rupniewski: boxplot of eps per n; median and IQR against sigma and against n."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    fig, ax = plt.subplots(figsize=(6, 4))
    ns = list(mc["_eps_by_n"])
    ax.boxplot([mc["_eps_by_n"][n] for n in ns], tick_labels=[str(n) for n in ns])
    ax.set(xlabel="number of positions n", ylabel="calibration error eps (Eq. 19)",
           title="Fig. 2: four gyro triads, sigma = 0.01")
    paths.append(_save(fig, out / "fig2_eps_boxplot.png"))
    for key, xlabel, name, title in (
        ("_eps_by_sigma", "noise standard deviation sigma", "fig3_eps_vs_sigma.png",
         "Fig. 3: n = 20"),
        ("_eps_slope_n", "number of positions n", "fig4_eps_vs_n.png", "Fig. 4: sigma = 0.01"),
    ):
        xs = np.array(list(mc[key]))
        q = np.array([np.percentile(mc[key][x], [25, 50, 75]) for x in xs])
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.loglog(xs, q[:, 1], "o-", label="median eps")
        ax.loglog(xs, q[:, 2] - q[:, 0], "s--", label="interquartile range")
        ax.set(xlabel=xlabel, ylabel="calibration error", title=title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        paths.append(_save(fig, out / name))
    return paths


def _save(fig, path: Path) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return str(path)


def unequal_triad(trials: int, seed: int) -> dict:
    """Triad with scale factors (1, 0.3, 3), n = 20, sigma = 0.01: closed form vs ML vs the
    bound."""
    rng = np.random.default_rng(seed)
    a = np.diag([1.0, 0.3, 3.0])
    e_cf, e_ml, bound = np.empty(trials), np.empty(trials), np.empty(trials)
    for t in range(trials):
        v = random_directions(rng, 3, 20)
        readings = a.T @ v + 0.01 * rng.standard_normal((3, 20))
        a_cf, v_cf = pca_calibration(readings, 1.0, 3)
        e_cf[t] = station.eps(a, a_cf) ** 2
        e_ml[t] = station.eps(a, refine(readings, a_cf, v_cf, sigma=0.01).a) ** 2
        bound[t] = np.trace(station.crlb(a, v, 0.01))
    return efficiency(e_cf, e_ml, bound)


def efficiency(eps2_cf: np.ndarray, eps2_ml: np.ndarray, bound: np.ndarray) -> dict:
    """eps^2 / trace(CRLB) of the closed form and of ML, per trial (each against the bound of its
    own directions) averaged, with its standard error; and the ratio of the means."""
    out = {}
    for name, e2 in (("closed_form", eps2_cf), ("ml", eps2_ml)):
        out[f"ratio_{name}"] = float(np.mean(e2 / bound))
        out[f"ratio_{name}_se"] = float(np.std(e2 / bound) / np.sqrt(len(bound)))
        out[f"ratio_of_means_{name}"] = float(e2.mean() / bound.mean())
    return out


def coverage(trials: int, seed: int) -> dict:
    """Fraction of nominal 95 % intervals (sigma estimated from residuals) that cover the truth."""
    rng = np.random.default_rng(seed)
    i, k = np.triu_indices(12, 1)
    cs, ca = [], []
    for _ in range(trials):
        a, _, readings = section4_gyros(rng, 20, 0.01)
        res = station.calibrate(readings, 1.0)
        s = np.linalg.norm(a, axis=0)
        ang = np.arccos(np.clip((a / s).T @ (a / s), -1, 1))
        cs.append(np.abs(res.scale_factors - s) < 1.96 * res.scale_factors_sigma)
        ca.append((np.abs(res.axis_angles - ang) < 1.96 * res.axis_angles_sigma)[i, k])
    return {"scale_factors": float(np.mean(cs)), "axis_angles": float(np.mean(ca))}


def speed(seed: int) -> dict:
    """Median solve times; the dense scipy least_squares ML is the baseline in the same run."""
    rng = np.random.default_rng(seed)
    _, _, r20 = section4_gyros(rng, 20, 0.01)
    _, _, r200 = section4_gyros(rng, 200, 0.01)
    a0, v0 = pca_calibration(r200, 1.0, 3)

    def median_time(fn, repeats):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return float(np.median(times))

    def dense_ml():
        # the same likelihood with scipy's dense trust-region solver, v as free 3-vectors + |v|=c
        # rows
        def resid(x):
            aa, vv = x[:36].reshape(3, 12), x[36:].reshape(3, 200)
            return np.concatenate([(r200 - aa.T @ vv).ravel(), 100 * (np.sum(vv**2, 0) - 1)])
        least_squares(resid, np.concatenate([a0.ravel(), v0.ravel()]), method="trf")

    return {
        "closed_form_m12_n20_us": 1e6 * median_time(lambda: pca_calibration(r20, 1.0, 3), 2000),
        "ml_m12_n200_ms": 1e3 * median_time(lambda: refine(r200, a0, v0, sigma=0.01), 100),
        "baseline_dense_least_squares_m12_n200_ms": 1e3 * median_time(dense_ml, 2),
    }


def run(trials: int, seed: int, figure_dir: Path) -> dict:
    t0 = time.perf_counter()
    mc = section4(trials, seed)
    result = {
        "exactness_max_eps": exactness(seed),
        "section4": {k: val for k, val in mc.items() if not k.startswith("_")},
        "figures": figures(mc, figure_dir),
        "unequal_triad": unequal_triad(trials, seed + 1),
        "coverage_95": coverage(trials, seed + 2),
        "hwangbo_table1": table1(trials, seed + 3),
        "speed": speed(seed + 4),
    }
    s4 = result["section4"]
    result["acceptance"] = {
        "noiseless_eps_below_1e-9": max(result["exactness_max_eps"].values()) < 1e-9,
        "median_eps_n20_within_5pct_of_0.032":
            abs(s4["median_eps_n20_sigma001"] / 0.032 - 1) <= 0.05,
        "ratio_in_0.95_1.05_every_n_ml": all(
            0.95 <= p["ratio_ml"] <= 1.05 for p in s4["per_n"].values()),
        "ratio_in_0.95_1.05_every_n_closed_form": all(
            0.95 <= p["ratio_closed_form"] <= 1.05 for p in s4["per_n"].values()),
        "slope_sigma_1.00+-0.02": abs(s4["slope_vs_sigma"] - 1) <= 0.02,
        "slope_n_-0.50+-0.05": abs(s4["slope_vs_n"] + 0.5) <= 0.05,
        "unequal_triad_ml_ratio_le_1.05": result["unequal_triad"]["ratio_ml"] <= 1.05,
        "coverage_93_97": all(0.93 <= c <= 0.97 for c in result["coverage_95"].values()),
        **{f"table1_{k}": v for k, v in result["hwangbo_table1"]["acceptance"].items()},
        "closed_form_under_300us": result["speed"]["closed_form_m12_n20_us"] < 300,
        "ml_under_10ms": result["speed"]["ml_m12_n200_ms"] < 10,
    }
    result["wall_seconds"] = time.perf_counter() - t0
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Calibration-core benchmark (issue 2 acceptance).")
    parser.add_argument("--trials", type=int, default=1000, help="Monte Carlo trials per setting")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--figures", type=Path, default=Path("docs/figures"))
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args(argv)
    result = run(args.trials, args.seed, args.figures)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print(result)
    return 0


def _print(result: dict, indent: str = "") -> None:
    """Nested figures as indented lines."""
    for key, value in result.items():
        if isinstance(value, dict):
            print(f"{indent}{key}:")
            _print(value, indent + "  ")
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            print(f"{indent}{key}: {len(value)} rows (see --json)")
        elif isinstance(value, float):
            print(f"{indent}{key}: {value:.6g}")
        else:
            print(f"{indent}{key}: {value}")


if __name__ == "__main__":
    sys.exit(main())
