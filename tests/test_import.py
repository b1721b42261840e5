"""`station import`: text, CSV and rotary .npz recordings into session files that the solver path
uses; untrusted files refused with clear errors; the real recordings of ../shared when present."""

from pathlib import Path

import numpy as np
import pytest

import station
from station.cli import main
from station.errors import CalibrationInputError
from station.imports import npz
from station.imports.recordings import (
    FIXED_POINT,
    Unit,
    import_csv,
    import_npz,
    import_text,
    read_npz,
)
from station.reduce.eq18 import reduce_arrays
from station.reduce.free_static import calibrate_free_static
from station.reduce.iron import iron_readings
from station.reduce.rotary import rotary_readings
from station.session import Session
from station.sim.layouts import A_MODEL, accelerometer_triad, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary
from station.sim.static import simulate_static
from station.solve.still import calibrate_still

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL.exists():
    REAL = Path("/work/shared/data/real")


@pytest.fixture(scope="module")
def rotary_npz(tmp_path_factory):
    """A 6-position rotary recording of the 12-gyro unit, as `station simulate` writes it."""
    unit = gyro_array(np.random.default_rng(5))
    sim = simulate_rotary(unit, 6, RotaryTiming(static=4, moving=20), a_nominal=A_MODEL)
    path = tmp_path_factory.mktemp("npz") / "rotary.npz"
    npz.write(path, sim)
    return path, sim


def test_npz_session_reduces_like_the_array_file(rotary_npz, tmp_path):
    path, sim = rotary_npz
    out = tmp_path / "rotary.h5"
    assert main(["import", "npz", str(out), str(path), "--unit-serial", "SN7"]) == 0
    with Session.open(out) as s:
        reduced = rotary_readings(s)
        assert s.metadata["unit_serial"] == "SN7"
        np.testing.assert_array_equal(s.stream("imu").counts.reshape(sim.arrays["y"].shape),
                                      sim.arrays["y"])
    direct = reduce_arrays(sim.arrays)
    np.testing.assert_array_equal(reduced.M, direct.M)
    np.testing.assert_array_equal(reduced.revolutions, direct.revolutions)
    result = station.calibrate(reduced.M, float(sim.arrays["c_cmd"]), sigma=reduced.sigma)
    # against the truth within the bound: eps^2 <= 16 trace(CRLB) (4 sigma of a chi-like norm)
    bound = station.crlb(np.asarray(sim.truth["a"]), np.asarray(sim.truth["v"]), reduced.sigma)
    assert station.eps(np.asarray(sim.truth["a"]), result.a) < 4 * np.sqrt(np.trace(bound))


def test_npz_refusals(rotary_npz, tmp_path):
    _, sim = rotary_npz
    good = dict(sim.arrays)

    def refused(arrays, match):
        path = tmp_path / "bad.npz"
        np.savez(path, **arrays)  # object arrays are pickled inside
        with pytest.raises(CalibrationInputError, match=match):
            import_npz(tmp_path / "bad.h5", path)
        assert not (tmp_path / "bad.h5").exists()

    refused({**good, "fs": np.array(["a", "b"], dtype=object)}, "type object")
    refused({k: v for k, v in good.items() if k != "t0"}, "lacks the arrays \\['t0'\\]")
    refused({**good, "t0": good["t0"][:-1]}, "t0 has shape")
    refused({**good, "seg_rotating": np.array([10, 10**7])}, "seg_rotating")
    refused({**good, "y": good["y"].astype(float)}, "y is a float64")
    refused({**good, "lsb": -good["lsb"]}, "positive")
    refused({**good, "t0": np.zeros(len(good["t0"]))}, "overlap")
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(CalibrationInputError, match="not a readable .npz"):
        read_npz(tmp_path / "junk.npz")
    with pytest.raises(CalibrationInputError, match="exceeds"):
        read_npz(rotary_npz[0], max_bytes=1000)


def test_text_tables_to_a_free_static_calibration(tmp_path):
    """imu_tk's layout (t x y z per file, raw counts) through the session to the solver."""
    unit = accelerometer_triad(np.random.default_rng(2), fs=100.0)
    sim = simulate_static(unit, 14)
    counts = sim.arrays["y"][0]
    t = 0.03 + np.arange(len(counts)) / 100.0
    acc = tmp_path / "acc.mat"
    np.savetxt(acc, np.column_stack([t, counts]), fmt="%.7e")
    scale = float(unit.counts_per_unit[0])
    out = tmp_path / "static.h5"
    assert main(["import", "text", str(out), "--stream", f"accel={acc}",
                 "--unit", f"accel=counts:m/s^2@{scale}"]) == 0
    with Session.open(out) as s:
        data = s.stream("accel")
    np.testing.assert_array_equal(data.counts, counts)
    assert data.spec.rate_hz == pytest.approx(100.0)
    np.testing.assert_allclose(data.host_time, t)
    fit = calibrate_free_static(data.to_si(), data.spec.rate_hz, sim.truth["gravity"])
    assert len(fit.still.intervals) >= 14
    z = (fit.accel.scale_factors - np.linalg.norm(unit.a, axis=0)) / fit.accel.scale_factors_sigma
    assert np.all(np.abs(z) < 4)


def test_csv_with_named_columns_and_units(tmp_path):
    rng = np.random.default_rng(0)
    acc, gyr = rng.normal(0, 9, (500, 3)), rng.normal(0, 100, (500, 3))
    path = tmp_path / "rec.csv"
    rows = np.column_stack([np.arange(500) + 40, gyr, acc])
    header = "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.12g")
    out = import_csv(tmp_path / "rec.h5", path, {"acc": ["acc_x", "acc_y", "acc_z"],
                                                 "gyr": ["gyr_x", "gyr_y", "gyr_z"]},
                     {"acc": "m/s^2", "gyr": "deg/s"}, index_column="n_samples", fs=102.4)
    with Session.open(out) as s:
        a, g = s.stream("acc"), s.stream("gyr")
    assert g.spec.units == ("rad/s",) * 3 and a.spec.rate_hz == 102.4
    np.testing.assert_allclose(a.to_si(), acc, atol=0.5 / FIXED_POINT)
    np.testing.assert_allclose(g.to_si(), np.radians(gyr), atol=0.5 / FIXED_POINT * np.pi / 180)
    np.testing.assert_array_equal(a.seq, np.arange(500) + 40)

    def refused(match, **kw):
        args = {"streams": {"acc": ["acc_x"]}, "units": {"acc": "m/s^2"}, "fs": 100.0, **kw}
        with pytest.raises(CalibrationInputError, match=match):
            import_csv(tmp_path / "no.h5", args.pop("path", path), **args)

    refused("missing or named twice", streams={"acc": ["acc_q"]})
    refused("no unit given", units={})
    refused("unknown unit", units={"acc": "furlongs"})
    refused("give a time column or a sample rate", fs=None)
    refused("not forward", time_column="acc_y", fs=None)
    text = tmp_path / "text.csv"
    text.write_text("part,acc_x\nx_a,1.0\n")
    refused("not all numbers", path=text, streams={"acc": ["part"]})


def test_unit_specs():
    assert Unit.parse("counts:m/s^2@415") == Unit("m/s^2", True, 415.0)
    assert Unit.parse("g").counts_per_unit == pytest.approx(FIXED_POINT / 9.80665)
    for bad in ("counts:furlong", "counts:m/s^2@-1", "counts:m/s^2@x"):
        with pytest.raises(CalibrationInputError):
            Unit.parse(bad)


@pytest.mark.skipif(not REAL.exists(), reason="needs ../shared/data/real")
def test_real_imutk_xsens_text(tmp_path):
    """The Xsens recording of imu_tk through import: the scale factors of docs/stillness.md
    (414.44, 412.13, 414.62 counts per m/s^2, from the tables read directly) and within 0.3 % of
    the manufacturer's 415, 413, 415."""
    d = REAL / "imutk-xsens"
    out = import_text(tmp_path / "xsens.h5", {"accel": d / "xsens_acc.mat",
                                              "gyro": d / "xsens_gyro.mat"},
                      {"accel": "counts:m/s^2", "gyro": "counts:rad/s"})
    with Session.open(out) as s:
        acc, gyr = s.stream("accel"), s.stream("gyro")
    fit = calibrate_free_static(acc.to_si(), acc.spec.rate_hz, 9.81744, gyro=gyr.to_si(),
                                rest=(0, 5000))
    assert len(fit.still.intervals) == 38
    np.testing.assert_allclose(fit.accel.scale_factors, [414.44, 412.13, 414.62], atol=0.05)
    np.testing.assert_allclose(fit.accel.scale_factors, [415, 413, 415], rtol=3e-3)


@pytest.mark.skipif(not REAL.exists(), reason="needs ../shared/data/real")
def test_real_imucal_ferraris_csv_through_the_iron_path(tmp_path):
    """imucal's Ferraris session (six faces, then turns about each axis): the still poses found,
    faces recognised, calibrated by the iron path: |a| of every pose within 0.03 m/s^2 of g where
    the raw readings are off by up to 0.5 m/s^2."""
    out = import_csv(tmp_path / "ferraris.h5", REAL / "imucal-ferraris" /
                     "example_ferraris_session.csv",
                     {"acc": ["acc_x", "acc_y", "acc_z"], "gyr": ["gyr_x", "gyr_y", "gyr_z"]},
                     {"acc": "m/s^2", "gyr": "deg/s"}, index_column="n_samples", fs=102.4)
    with Session.open(out) as s:
        readings = iron_readings(s, stream="acc")
    assert {"+x", "-x", "+y", "-y", "+z", "-z"} <= set(readings.faces)
    raw = np.abs(np.linalg.norm(readings.M, axis=0) - 9.81)
    result = calibrate_still(readings, 9.81)
    fitted = np.abs(np.linalg.norm(result.apply(readings.M), axis=0) - 9.81)
    assert raw.max() > 0.4 and fitted.max() < 0.03
