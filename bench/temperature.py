"""The thermal fit (issue 15) on simulated 4-soak sets (tests/thermalsim.py: an accelerometer
triad at 233, 273, 318 and 358 K, 20 free-static poses of 2 s per soak, datasheet-sized tempcos):

- the z spread of the linear tempcos (bias and scale, 3 sensors) over the seeds, fitted at the
  true orders: (estimate - truth) / sigma, spread ~ 1, max |z| against the Bonferroni bound of
  false-alarm probability 0.01;
- the same for the rotary gyro path (a 12-gyro unit, Eq. 18 reduction, biases from the static
  windows; a quarter of the seeds);
- the order selection: how often a true linear and a true quadratic law are given their orders;
- the model applied at 6 temperatures between the soaks against a calibration made at that very
  temperature: ratio of the RMS magnitude errors on noise-free probe readings (<= 1.2 asked).

    bench/temperature.py [--seeds N] [--json] [--quick]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import norm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from thermalsim import (  # noqa: E402
    BETWEEN,
    GYRO_TRUTH,
    TRUE_LINEAR,
    TRUE_QUADRATIC,
    direct_calibration,
    magnitude_errors,
    probe,
    rotary_fit,
    thermal_fit,
    z_scores,
)

from station.calfiles.calfile import Calibration  # noqa: E402

ALPHA = 0.01


def z_spread(seeds: int) -> dict:
    """The z-scores of the linear tempcos over `seeds` sets."""
    z = np.ravel([z_scores(thermal_fit(s, orders={"bias": 1, "scale": 1})[1], TRUE_LINEAR)
                  for s in range(seeds)])
    return {"n": int(z.size), "spread": float(z.std()), "mean": float(z.mean()),
            "max_abs": float(np.abs(z).max()),
            "bonferroni_bound": float(norm.isf(ALPHA / (2 * z.size)))}


def gyro_spread(seeds: int) -> dict:
    """The z-scores of the rotary path's linear tempcos (12 gyros) over `seeds` sets."""
    z_bias, z_scale = (np.ravel(z) for z in zip(*(z_scores(rotary_fit(s), GYRO_TRUTH)
                                                  for s in range(seeds)), strict=True))
    return {"n": int(z_bias.size), "bias_spread": float(z_bias.std()),
            "scale_spread": float(z_scale.std()),
            "max_abs": float(max(np.abs(z_bias).max(), np.abs(z_scale).max()))}


def selection(seeds: int) -> dict:
    """Rate of the right orders for a true linear and a true quadratic law."""
    out = {}
    for name, truth, want in (("linear", TRUE_LINEAR, {"bias": 1, "scale": 1}),
                              ("quadratic", TRUE_QUADRATIC, {"bias": 2, "scale": 2})):
        chosen = [thermal_fit(1000 + s, truth)[1].model.orders for s in range(seeds)]
        out[name] = {"right": float(np.mean([c == want for c in chosen])),
                     "chosen": sorted({json.dumps(c, sort_keys=True) for c in chosen})}
    return out


def between(seeds: int) -> dict:
    """RMS magnitude errors of the model and of a calibration made at each temperature."""
    model_err, direct_err = [], []
    for s in range(seeds):
        unit, fit = thermal_fit(s)
        cal = Calibration.from_temperature_fit(fit, "SIM", ("ax", "ay", "az"), "m/s^2")
        rng = np.random.default_rng(100 + s)
        for temp in BETWEEN:
            z, _ = probe(unit, temp, TRUE_LINEAR, rng)
            model_err.append(magnitude_errors(cal.apply_at(z, temp)))
            direct_err.append(magnitude_errors(
                direct_calibration(unit, temp, TRUE_LINEAR).apply(z)))
    rms_model = float(np.sqrt(np.mean(np.square(model_err))))
    rms_direct = float(np.sqrt(np.mean(np.square(direct_err))))
    return {"temperatures_K": list(BETWEEN), "rms_model": rms_model, "rms_direct": rms_direct,
            "ratio": rms_model / rms_direct}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=200, help="simulated 4-soak sets per figure")
    p.add_argument("--quick", action="store_true", help="10 seeds (a check that it runs)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    seeds = 10 if args.quick else args.seeds
    start = time.perf_counter()
    out = {"seeds": seeds, "z": z_spread(seeds), "gyro_z": gyro_spread(max(seeds // 4, 2)),
           "selection": selection(seeds),
           "between": between(max(seeds // 4, 2))}
    out["seconds"] = round(time.perf_counter() - start, 1)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    z, sel, btw = out["z"], out["selection"], out["between"]
    print(f"tempco z-scores ({z['n']}): spread {z['spread']:.3f}, mean {z['mean']:+.3f}, "
          f"max |z| {z['max_abs']:.2f} (Bonferroni bound {z['bonferroni_bound']:.2f})")
    gz = out["gyro_z"]
    print(f"rotary gyro path z-scores ({gz['n']} each): spread bias {gz['bias_spread']:.3f}, "
          f"scale {gz['scale_spread']:.3f}, max |z| {gz['max_abs']:.2f}")
    for name, s in sel.items():
        print(f"order selection, true {name}: right in {s['right']:.1%} ({', '.join(s['chosen'])})")
    print(f"between the soaks: RMS |v| error {btw['rms_model']:.3g} m/s^2 with the model, "
          f"{btw['rms_direct']:.3g} calibrated there: ratio {btw['ratio']:.3f}")
    print(f"{out['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
