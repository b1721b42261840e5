"""A magnetometer turned by hand, no still poses: block readings (station.reduce.blocks) and the
ellipsoid calibration with biases (hard iron) and the sensitivity (soft iron) within their sigma."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from station.errors import CalibrationInputError
from station.reduce.blocks import block_readings
from station.solve.calibrate import calibrate

FS = 100.0
FIELD = 48e-6  # T, a mid-latitude Earth field


def turning_magnetometer(seed: int, seconds: float = 60.0, noise: float = 0.3e-6,
                         fs: float = FS):
    """(samples (k, 3) in T, true a (3, 3), true bias (3,)): the unit turned smoothly through a
    random attitude every 1.5 s (about 80-120 deg/s), a fixed Earth field, sampled at fs Hz."""
    rng = np.random.default_rng(seed)
    keys = Rotation.random(int(seconds / 1.5) + 2, random_state=rng)
    t = np.arange(int(seconds * fs)) / fs
    att = Slerp(np.arange(len(keys)) * 1.5, keys)(t)
    field = FIELD * np.array([np.cos(np.radians(65)), 0.0, -np.sin(np.radians(65))])
    b_unit = att.apply(field)
    a = np.diag(1 + 0.05 * rng.standard_normal(3)) + 0.03 * rng.standard_normal((3, 3))
    bias = 15e-6 * rng.standard_normal(3)
    z = b_unit @ a + bias + noise * rng.standard_normal((len(t), 3))
    return z, a, bias


def invariants(a):
    """Scale factors and the three axis angles (deg), free of the frame."""
    k = np.linalg.norm(a, axis=0)
    u = a / k
    g = np.clip(u.T @ u, -1, 1)
    return k, np.degrees(np.arccos(g[np.triu_indices(3, 1)]))


@pytest.mark.parametrize("seed", [1, 2])
def test_hard_and_soft_iron_recovered_within_sigma(seed):
    z, a, bias = turning_magnetometer(seed)
    blocks = block_readings(z, FS)
    assert blocks.dropped < 0.05 * (blocks.M.shape[1] + blocks.dropped)
    fit = calibrate(blocks.M, FIELD, bias="estimate", sigma=blocks.sigma)
    assert np.all(np.abs(fit.bias - bias) < 4.5 * fit.bias_sigma)
    k, _ = invariants(a)
    assert np.all(np.abs(fit.scale_factors - k) < 4.5 * fit.scale_factors_sigma)
    chi2 = fit.chi2 / fit.dof
    assert abs(chi2 - 1) < 5 * np.sqrt(2 / fit.dof)  # the block sigma is the noise's


def test_the_block_sigma_is_the_noise_despite_the_motion():
    z, _, _ = turning_magnetometer(3, noise=0.5e-6)
    blocks = block_readings(z, FS)
    size = int(0.1 * FS)
    t = np.arange(size) - (size - 1) / 2
    q = t ** 2 - np.mean(t ** 2)
    gain = np.sqrt(1 / size + np.mean(t ** 2) ** 2 / (q @ q))  # sd of the centre per unit noise
    rms = np.sqrt(np.mean(blocks.sigma ** 2)) / gain
    assert abs(rms / 0.5e-6 - 1) < 0.05  # 3 x 600 blocks of 7 dof: the RMS is within ~1 %


def test_blocks_too_short_are_refused():
    z, _, _ = turning_magnetometer(4, seconds=5)
    with pytest.raises(CalibrationInputError, match="--block"):
        block_readings(z, FS, seconds=0.02)


def test_fast_turns_are_dropped_not_averaged():
    z, _, _ = turning_magnetometer(5)
    blocks = block_readings(z, FS, seconds=0.5, max_turn_deg=30)
    assert blocks.dropped > 0 and np.all(blocks.turned_deg <= 30)


def test_import_solve_apply_on_the_command_line(tmp_path, capsys):
    """import csv (uT) -> solve --magnitude -> apply: |B| back at the local field (without
    --magnitude: the local field's unit sphere, `test_raw_counts_at_50_hz_...`)."""
    import json

    from station.calfiles.calfile import load
    from station.cli import main

    z, a, bias = turning_magnetometer(6)
    t = np.arange(len(z)) / FS
    rows = "\n".join(",".join(f"{x:.6f}" for x in (ti, *zi * 1e6))
                      for ti, zi in zip(t, z, strict=True))
    (tmp_path / "mag.csv").write_text("time,mx,my,mz\n" + rows + "\n")
    session, cal = tmp_path / "mag.h5", tmp_path / "mag.cal.json"
    assert main(["import", "csv", str(session), str(tmp_path / "mag.csv"), "--time", "time",
                 "--stream", "mag=mx,my,mz", "--unit", "mag=uT"]) == 0
    capsys.readouterr()
    assert main(["solve", str(session), "--out", str(cal), "--magnitude", str(FIELD),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    fit = load(cal)
    assert fit.units[0] == "T" and summary["positions"] > 500
    assert np.all(np.abs(fit.bias - bias) < 4.5 * fit.bias_sigma)
    out = tmp_path / "mag.cal.csv"
    assert main(["apply", str(cal), str(session), "--out", str(out)]) == 0
    v = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:]
    assert abs(np.median(np.linalg.norm(v, axis=1)) / FIELD - 1) < 0.01


COUNTS = 1e7
"""Counts per T of the simulated chip (0.1 uT per count; its noise 0.3 uT is 3 counts)."""


def counts_csv(path, seed: int, fs: float = 50.0):
    """A 3-axis chip's raw counts turned by hand (`turning_magnetometer` at fs Hz, rounded to
    whole counts) written as CSV; (true a, true bias) in T."""
    z, a, bias = turning_magnetometer(seed, fs=fs)
    t = np.arange(len(z)) / fs
    rows = "\n".join(f"{ti:.4f},{x:.0f},{y:.0f},{w:.0f}"
                     for ti, (x, y, w) in zip(t, np.round(z * COUNTS), strict=True))
    path.write_text("time,mx,my,mz\n" + rows + "\n")
    return a, bias


def within_3_sigma(cal, scale_factors, bias) -> None:
    """Every scale factor and bias of the calibration file within 3 of its 1-sigma of the
    truth (6 normal errors: a false failure has probability 1.6 %)."""
    z = np.concatenate([(cal.scale_factors - scale_factors) / cal.scale_factors_sigma,
                        (cal.bias - bias) / cal.bias_sigma])
    assert np.all(np.abs(z) < 3), z


def test_raw_counts_at_50_hz_import_solve_apply_with_and_without_the_field(tmp_path, capsys):
    """Issue 31: raw counts (`counts:T`, 5-sample blocks at 50 Hz, whose own scatter is 0 now and
    then) solve from blocks; without --magnitude to the local field's unit sphere (scale factors
    in counts per local field, the field applied in its units), with a nominal scale and
    --magnitude in counts per T and T."""
    import json

    from station.calfiles.calfile import load
    from station.cli import main

    a, bias = counts_csv(tmp_path / "chip.csv", 7)
    k = np.linalg.norm(a, axis=0)
    for unit, magnitude, scale, offset in (
            ("counts:T", [], k * COUNTS * FIELD, bias * COUNTS),
            (f"counts:T@{COUNTS:g}", ["--magnitude", str(FIELD)], k, bias)):
        session, cal_path = tmp_path / f"{len(magnitude)}.h5", tmp_path / f"{len(magnitude)}.json"
        assert main(["import", "csv", str(session), str(tmp_path / "chip.csv"), "--time", "time",
                     "--stream", "mag=mx,my,mz", "--unit", f"mag={unit}"]) == 0
        capsys.readouterr()
        assert main(["solve", str(session), "--out", str(cal_path), "--json", *magnitude]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["positions"] > 500
        cal = load(cal_path)
        assert cal.scale_known == bool(magnitude)
        within_3_sigma(cal, scale, offset)
        out = tmp_path / f"{len(magnitude)}.csv"
        assert main(["apply", str(cal_path), str(session), "--out", str(out)]) == 0
        header = out.read_text().splitlines()[0]
        assert header.endswith("[T]" if magnitude else "[local magnitude]"), header
        v = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:]
        assert abs(np.median(np.linalg.norm(v, axis=1)) / (FIELD if magnitude else 1) - 1) < 0.01
