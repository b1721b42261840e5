"""Scale of the solver (issue 17): cost linear in the work, memory bounded.

Every figure stands beside a baseline measured in the same run; growths are exponents of a
least-squares line through log(figure) against log(size) over the range.

- calibrate : `station.calibrate` with uncertainties (sigma given), n = 100 positions of m random
              sensors, m = 12, 48, 192, 768. Each m runs in a fresh child process: wall time of
              calibrate (best of --repeat), and its peak memory as the tracemalloc peak of the
              Python and numpy allocations of one call (LAPACK's work space is not traced; the
              child's ru_maxrss, which includes the interpreter and the libraries, beside it).
              Baselines in the same child: the closed form + ML alone (`starts.closed_form` +
              `ml.refine`), and the closed form + `BaselineLM` below, the plain Schur-complement
              LM, for as many iterations as the ML takes (the same fit: checked). Targets: time
              exponent <= 3.0, memory exponent <= 2.0, m = 768 < 8 GB, calibrate <= 1.3 x the
              plain LM at m = 12 and m = 768 (issue 35; the uncertainties and the checks
              included).
- ml        : CPU seconds per iteration of the ML (`ml.refine`, m = 12 sensors, n = 10^2 .. 10^5
              positions) against `BaselineLM`, a minimal batched Schur-complement
              Levenberg-Marquardt written here, doing the same iterations from the same start
              (best of max(--repeat, 10^5 / n) runs). CPU time of this single process (one BLAS
              thread) is the work; the wall time beside it adds the waits for a core on a shared
              machine, longer the longer the run (it inflates the exponent under load).
              Targets: exponent <= 1.05, ratio <= 1.2.
- coverage  : coverage of the 95 % intervals (+-1.96 sigma) of the scale factors, axis angles and
              biases of accelerometer triads at 20-23 random poses, biases estimated, sigma
              estimated from the residuals (11-14 dof), over --trials trials; beside it the
              same intervals without the Student-t widening (the previous normal quantile).
              Target: 94-96 %.
- startup   : `station --help` CPU (bench/startup.py, run as a child) and the wall time of
              `station solve sessions/rotary-12gyro.h5` (and its CPU time: on a loaded machine
              the wall time mostly waits for a core) beside a bare `python -c pass`.
              Target: solve <= 1 s on an idle machine.
- replay    : the JSON object of bench/scale_replay.py --json when that file exists.

BLAS threads: set OPENBLAS_NUM_THREADS (reported) before running; on a loaded 2-core machine
OpenBLAS's threads spin against other work and small solves slow down 100x.

Prints a table, or one JSON object with --json.
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SIZES_M = (12, 48, 192, 768)
SIZES_N = (100, 1_000, 10_000, 100_000)
TARGETS = {"calibrate_time_exponent": 3.0, "calibrate_memory_exponent": 2.0,
           "calibrate_768_bytes": 8e9, "calibrate_over_plain_lm": 1.3, "ml_exponent": 1.05,
           "ml_ratio": 1.2,
           "coverage": (0.94, 0.96), "solve_s": 1.0}


def exponent(sizes, values) -> float:
    """Slope of the least-squares line through (log size, log value)."""
    return float(np.polyfit(np.log(sizes), np.log(values), 1)[0])


def array_problem(m: int, n: int, seed: int = 0):
    """(a (3, m), v (3, n), readings (m, n)): m sensors of random axes and scales ~1, n random
    unit stimuli, noise 0.01."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((3, m))
    a *= (1 + 0.01 * rng.standard_normal(m)) / np.linalg.norm(a, axis=0)
    v = rng.standard_normal((3, n))
    v /= np.linalg.norm(v, axis=0)
    return a, v, a.T @ v + 0.01 * rng.standard_normal((m, n))


# ---- calibrate: time and memory against m (one child process per m) ----

def calibrate_child(m: int, repeat: int) -> dict:
    """In this process: best wall time of calibrate and of the closed form + ML, and calibrate's
    tracemalloc peak; printed as JSON by --child."""
    import station
    from station.solve import ml, starts

    _, _, readings = array_problem(m, 100)

    def full():
        return station.calibrate(readings, 1.0, sigma=0.01)

    def bare():
        a0, v0, _ = starts.closed_form("pca", readings, None, False, None, 1.0, 3)
        return ml.refine(readings, a0, v0, sigma=0.01)

    its = bare().iterations
    lm = BaselineLM(readings, np.full(readings.shape, 1e4))

    def plain():
        a0, v0, _ = starts.closed_form("pca", readings, None, False, None, 1.0, 3)
        return lm.run(a0, v0 / np.linalg.norm(v0, axis=0), its)  # on |v| = 1, as ml.refine

    assert np.isclose(plain()[2], bare().objective, rtol=1e-6), "not the same fit"
    full()  # imports and first-call costs out of the timing
    times = {}
    for name, fn in (("calibrate_s", full), ("closed_form_ml_s", bare),
                     ("closed_form_plain_lm_s", plain)):
        runs = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn()
            runs.append(time.perf_counter() - t0)
        times[name] = min(runs)
    tracemalloc.start()
    full()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"m": m, **times, "tracemalloc_peak_bytes": peak,
            "ru_maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def calibrate_scale(repeat: int) -> dict:
    """calibrate_child for each m in a fresh process, and the exponents over m."""
    rows = []
    for m in SIZES_M:
        out = subprocess.run([sys.executable, "-P", __file__, "--child", str(m), "--repeat",
                              str(repeat if m < 768 else 1)],
                             check=True, capture_output=True, text=True)
        rows.append(json.loads(out.stdout))
    col = {k: [r[k] for r in rows] for k in rows[0]}
    return {"n": 100, "rows": rows,
            "time_exponent": exponent(SIZES_M, col["calibrate_s"]),
            "baseline_time_exponent": exponent(SIZES_M, col["closed_form_ml_s"]),
            "memory_exponent": exponent(SIZES_M, col["tracemalloc_peak_bytes"]),
            "ratio_to_baseline": [f / b for f, b in zip(col["calibrate_s"],
                                                        col["closed_form_ml_s"], strict=True)],
            "ratio_to_plain_lm": [f / b for f, b in zip(col["calibrate_s"],
                                                        col["closed_form_plain_lm_s"],
                                                        strict=True)]}


# ---- ML per iteration against n, beside a minimal Schur-complement LM ----

class BaselineLM:
    """Minimal batched Levenberg-Marquardt for z_ij = a_i . v_j + noise, |v_j| = 1, weights w_ij:
    a (3, m) global, each v_j a direction (2 tangent coordinates), the local blocks eliminated by
    the Schur complement. Independent of the station's code."""

    def __init__(self, readings, weight):
        self.z, self.w = readings, weight

    @staticmethod
    def tangents(v):
        """(n, 3, 2) orthonormal bases of the planes perpendicular to the unit v_j."""
        helper = np.where(np.abs(v[0]) < 0.9, 1.0, 0.0)
        t1 = np.cross(v.T, np.stack([helper, 1.0 - helper, np.zeros_like(helper)], 1))
        t1 /= np.linalg.norm(t1, axis=1)[:, None]
        return np.stack([t1, np.cross(v.T, t1)], 2)

    def cost(self, a, v):
        return float(np.sum(self.w * (self.z - a.T @ v) ** 2))

    def step(self, a, v, lam):
        """One damped Gauss-Newton step (da, dt, tangent bases)."""
        m, n = self.z.shape
        basis = self.tangents(v)
        wr = self.w * (self.z - a.T @ v)
        local = a.T @ basis  # (n, m, 2): d z_ij / d t_j
        wl = local * self.w.T[:, :, None]
        h_ll = np.transpose(wl, (0, 2, 1)) @ local  # (n, 2, 2)
        h_ll += lam * np.einsum("nkk->nk", h_ll)[:, :, None] * np.eye(2)
        h_gg = (self.w @ np.einsum("pn,qn->npq", v, v).reshape(n, 9)).reshape(m, 3, 3)
        h_gg += lam * np.einsum("ipp->ip", h_gg)[:, :, None] * np.eye(3)
        cross = (v.T[:, None, :, None] * wl[:, :, None, :])  # (n, m, 3, 2): d2 / da_i dt_j
        inv = np.linalg.inv(h_ll)
        g_l = np.einsum("in,nik->nk", wr, local)
        cross_mat = cross.transpose(1, 2, 0, 3).reshape(3 * m, 2 * n)
        ci = (cross @ inv[:, None]).transpose(1, 2, 0, 3).reshape(3 * m, 2 * n)
        s = -(ci @ cross_mat.T)
        s4 = s.reshape(m, 3, m, 3)
        s4[np.arange(m), :, np.arange(m), :] += h_gg
        da = np.linalg.solve(s, (wr @ v.T).ravel() - ci @ g_l.ravel())
        rhs = g_l - (da @ cross_mat).reshape(n, 2)
        return da.reshape(m, 3).T, np.einsum("nkl,nl->nk", inv, rhs), basis

    def run(self, a, v, iterations: int):
        """`iterations` LM iterations from (a, v); the final (a, v, cost)."""
        lam, cost = 1e-6, self.cost(a, v)
        for _ in range(iterations):
            da, dt, basis = self.step(a, v, lam)
            a_t = a + da
            v_t = v + np.einsum("ndk,nk->dn", basis, dt)
            v_t /= np.linalg.norm(v_t, axis=0)
            cost_t = self.cost(a_t, v_t)
            if cost_t <= cost:
                a, v, cost, lam = a_t, v_t, cost_t, max(lam / 10, 1e-12)
            else:
                lam *= 10
        return a, v, cost


def ml_scale(repeat: int) -> dict:
    """CPU (and wall) seconds per iteration of ml.refine and of BaselineLM, m = 12, over n; same
    start (the truth perturbed by 1e-3), same number of iterations (the station's)."""
    from station.solve import ml

    rows = []
    for n in SIZES_N:
        a, v, readings = array_problem(12, n, seed=n)
        rng = np.random.default_rng(1)
        a0 = a + 1e-3 * rng.standard_normal(a.shape)
        v0 = v + 1e-3 * rng.standard_normal(v.shape)
        v0 /= np.linalg.norm(v0, axis=0)
        weight = np.full(readings.shape, 1e4)
        fit = ml.refine(readings, a0, v0, sigma=0.01)
        its = fit.iterations
        base = BaselineLM(readings, weight)
        assert np.isclose(base.run(a0, v0, its)[2], fit.objective, rtol=1e-6), "not the same fit"
        runs = {"station": [], "baseline": []}
        for _ in range(max(repeat, 10**5 // n)):  # a second or more of each at every n
            runs["station"].append(np.array(timed(ml.refine, readings, a0, v0, sigma=0.01)) / its)
            runs["baseline"].append(np.array(timed(base.run, a0, v0, its)) / its)
        best = {name: np.min(r, axis=0).tolist() for name, r in runs.items()}  # (CPU, wall) / it
        rows.append({"n": n, "iterations": its, "station_s_per_iteration": best["station"][0],
                     "baseline_s_per_iteration": best["baseline"][0],
                     "station_wall_s_per_iteration": best["station"][1],
                     "baseline_wall_s_per_iteration": best["baseline"][1],
                     "ratio": best["station"][0] / best["baseline"][0]})
    col = {k: [r[k] for r in rows] for k in rows[0]}
    return {"m": 12, "rows": rows,
            "exponent": exponent(SIZES_N, col["station_s_per_iteration"]),
            "baseline_exponent": exponent(SIZES_N, col["baseline_s_per_iteration"]),
            "wall_exponent": exponent(SIZES_N, col["station_wall_s_per_iteration"]),
            "baseline_wall_exponent": exponent(SIZES_N, col["baseline_wall_s_per_iteration"]),
            "max_ratio": max(col["ratio"])}


def timed(fn, *args, **kwargs) -> tuple[float, float]:
    """(CPU, wall) seconds of one call fn(*args, **kwargs) in this process."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn(*args, **kwargs)
    return time.process_time() - c0, time.perf_counter() - t0


# ---- coverage of the 95 % intervals at 11-14 dof ----

TRIAD = np.array([[9.7, 0.05, -0.1], [0.0, 9.9, 0.08], [0.0, 0.0, 9.8]])


def coverage(trials: int, seed: int = 17) -> dict:
    """Coverage of +-1.96 sigma of the scale factors, angles and biases of accelerometer triads
    (biases estimated, sigma from the residuals, 20-23 poses: 11-14 dof); the same with the
    normal quantile (the sigmas divided by the Student-t factor) beside it."""
    import station
    from station.solve.uncertainty import t_widening

    rng = np.random.default_rng(seed)
    i, k = np.triu_indices(3, 1)
    u = TRIAD / np.linalg.norm(TRIAD, axis=0)
    true = {"scale_factors": np.linalg.norm(TRIAD, axis=0),
            "axis_angles": np.arccos(np.clip(u.T @ u, -1, 1))[i, k]}
    hits = {"student_t": [], "normal": []}
    dofs = []
    for trial in range(trials):
        n = 20 + trial % 4
        b = rng.normal(0, 0.5, 3)
        v = rng.standard_normal((3, n))
        v /= np.linalg.norm(v, axis=0)
        res = station.calibrate(TRIAD.T @ v + b[:, None] + 0.01 * rng.standard_normal((3, n)),
                                1.0, bias="estimate")
        dofs.append(res.dof)
        err = np.r_[res.scale_factors - true["scale_factors"],
                    res.axis_angles[i, k] - true["axis_angles"], res.bias - b]
        sd = np.r_[res.scale_factors_sigma, res.axis_angles_sigma[i, k], res.bias_sigma]
        hits["student_t"].append(np.abs(err) < 1.96 * sd)
        hits["normal"].append(np.abs(err) < 1.96 * sd / np.sqrt(t_widening(res.dof)))
    out = {"trials": trials, "dof": sorted(set(dofs))}
    for name, h in hits.items():
        h = np.array(h)
        out[name] = {"scale_factors": float(h[:, :3].mean()),
                     "axis_angles": float(h[:, 3:6].mean()),
                     "biases": float(h[:, 6:].mean()), "all": float(h.mean()),
                     "binomial_se_one_per_trial": float(np.sqrt(0.95 * 0.05 / trials))}
    return out


# ---- start-up and a whole solve ----

def startup(repeat: int) -> dict:
    """bench/startup.py --json (station --help CPU) and the wall time of `station solve` on the
    example rotary session beside `python -c pass`."""
    out = subprocess.run([sys.executable, "-P", str(HERE / "startup.py"), "--json", "--repeat",
                          str(repeat)], check=True, capture_output=True, text=True)
    script = Path(sys.executable).with_name("station")
    session = HERE.parent / "sessions" / "rotary-12gyro.h5"

    def timed(cmd) -> tuple[float, float]:
        """(wall, user + system CPU) seconds of one run of cmd."""
        before, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        wall, after = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)

    with tempfile.TemporaryDirectory() as tmp:
        solve = [str(script), "solve", str(session), "--out", str(Path(tmp) / "x.cal.json"),
                 "--force", "--json"]
        solve_runs = [timed(solve) for _ in range(repeat)]
    bare_runs = [timed([sys.executable, "-c", "pass"]) for _ in range(repeat)]
    return {"startup": json.loads(out.stdout),
            "solve_rotary_12gyro_wall_s": statistics.median(w for w, _ in solve_runs),
            "solve_rotary_12gyro_cpu_s": statistics.median(c for _, c in solve_runs),
            "python_pass_wall_s": statistics.median(w for w, _ in bare_runs),
            "python_pass_cpu_s": statistics.median(c for _, c in bare_runs)}


def replay() -> dict | None:
    """The JSON object of bench/scale_replay.py --json, if another bench put it there."""
    path = HERE / "scale_replay.py"
    if not path.exists():
        return None
    out = subprocess.run([sys.executable, "-P", str(path), "--json"], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout)


def verdicts(r: dict) -> dict:
    """Each acceptance figure against its target."""
    cal, ml_ = r["calibrate"], r["ml"]
    lo, hi = TARGETS["coverage"]
    cover = r["coverage"]["student_t"]
    return {k: bool(v) for k, v in {
        "calibrate_time_exponent": cal["time_exponent"] <= TARGETS["calibrate_time_exponent"],
        "calibrate_memory_exponent":
            cal["memory_exponent"] <= TARGETS["calibrate_memory_exponent"],
        "calibrate_768_under_8GB": all(row["ru_maxrss_bytes"] < TARGETS["calibrate_768_bytes"]
                                       for row in cal["rows"] if row["m"] == 768),
        "calibrate_over_plain_lm_12_768": all(
            r_ <= TARGETS["calibrate_over_plain_lm"] for r_, row in
            zip(cal["ratio_to_plain_lm"], cal["rows"], strict=True) if row["m"] in (12, 768)),
        "ml_exponent": ml_["exponent"] <= TARGETS["ml_exponent"],
        "ml_ratio": ml_["max_ratio"] <= TARGETS["ml_ratio"],
        "coverage_94_96": all(lo <= cover[k] <= hi
                              for k in ("scale_factors", "axis_angles", "biases")),
        "solve_1s": r["startup"]["solve_rotary_12gyro_wall_s"] <= TARGETS["solve_s"],
    }.items()}


def report(r: dict) -> None:
    """The figures as a table."""
    print(f"OPENBLAS_NUM_THREADS={r['openblas_threads']}  load average {r['load_average']}")
    print("calibrate with uncertainties, n = 100 (best wall time; tracemalloc peak; ru_maxrss)")
    for row in r["calibrate"]["rows"]:
        print(f"  m {row['m']:4d}  {row['calibrate_s'] * 1e3:9.2f} ms  closed form + ML "
              f"{row['closed_form_ml_s'] * 1e3:9.2f} ms  + plain LM "
              f"{row['closed_form_plain_lm_s'] * 1e3:9.2f} ms (ratio "
              f"{row['calibrate_s'] / row['closed_form_plain_lm_s']:.2f})  peak "
              f"{row['tracemalloc_peak_bytes'] / 1e6:8.1f} MB  maxrss "
              f"{row['ru_maxrss_bytes'] / 1e6:7.0f} MB")
    cal = r["calibrate"]
    print(f"  exponents: time {cal['time_exponent']:.2f} (baseline "
          f"{cal['baseline_time_exponent']:.2f}), memory {cal['memory_exponent']:.2f}")
    print("ML per iteration, m = 12 (CPU; wall)")
    for row in r["ml"]["rows"]:
        print(f"  n {row['n']:6d}  {row['station_s_per_iteration'] * 1e3:9.3f} ms "
              f"({row['station_wall_s_per_iteration'] * 1e3:9.3f})  baseline LM "
              f"{row['baseline_s_per_iteration'] * 1e3:9.3f} ms "
              f"({row['baseline_wall_s_per_iteration'] * 1e3:9.3f})  ratio {row['ratio']:.2f}")
    print(f"  exponent {r['ml']['exponent']:.3f} (baseline {r['ml']['baseline_exponent']:.3f}); "
          f"wall {r['ml']['wall_exponent']:.3f} (baseline {r['ml']['baseline_wall_exponent']:.3f})")
    cov = r["coverage"]
    print(f"coverage of 95 % intervals, {cov['trials']} triads, dof {cov['dof']}")
    for name in ("student_t", "normal"):
        c = cov[name]
        print(f"  {name:9s}  scale {c['scale_factors']:.3f}  angles {c['axis_angles']:.3f}  "
              f"biases {c['biases']:.3f}")
    st = r["startup"]
    print(f"station --help CPU {st['startup']['cpu_s'].get('station --help', float('nan')):.3f} s"
          f" (python -c pass {st['startup']['cpu_s']['python -c pass']:.3f} s); station solve "
          f"rotary-12gyro {st['solve_rotary_12gyro_wall_s']:.3f} s wall, "
          f"{st['solve_rotary_12gyro_cpu_s']:.3f} s CPU (python -c pass "
          f"{st['python_pass_wall_s']:.3f} s wall, {st['python_pass_cpu_s']:.3f} s CPU)")
    if r["replay"] is not None:
        print("replay:", json.dumps(r["replay"]))
    print("verdicts:", ", ".join(f"{k} {'met' if v else 'MISSED'}"
                                 for k, v in r["verdicts"].items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object")
    parser.add_argument("--repeat", type=int, default=3, help="runs per timing (best or median)")
    parser.add_argument("--trials", type=int, default=1000, help="coverage trials")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(calibrate_child(args.child, args.repeat)))
        return
    r = {"openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
         "load_average": [round(x, 2) for x in os.getloadavg()],
         "calibrate": calibrate_scale(args.repeat), "ml": ml_scale(args.repeat),
         "coverage": coverage(args.trials), "startup": startup(max(args.repeat, 5)),
         "replay": replay(), "targets": TARGETS}
    r["verdicts"] = verdicts(r)
    r["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    if args.json:
        print(json.dumps(r, indent=1))
    else:
        report(r)


if __name__ == "__main__":
    main()
