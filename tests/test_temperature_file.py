"""The temperature model in the calibration file (version 6), `station apply` at the unit's
temperature and the C header's coefficients. The model is hand-made (not fitted), readings are
made from it by its definition (docs/conventions.md, "Temperature"), not by the code under test."""

import csv
import re
import shutil
import subprocess

import h5py
import numpy as np
import pytest
from test_calfile import edited, make

from drivers.samples import SampleBlock
from station import cli
from station.calfiles.calfile import CONVENTIONS_V5, load, loads
from station.errors import CalibrationFileError
from station.model.temperature import TemperatureModel
from station.session import SessionWriter, StreamSpec

A = np.array([[1.01, 0.002, -0.003], [0.0, 0.98, 0.004], [0.0, 0.0, 1.02]])
B = np.array([0.05, -0.03, 0.02])
SENSORS = ("g1", "g2", "g3")
T_REF, T_MIN, T_MAX = 300.0, 260.0, 340.0
BETA = np.array([[2e-3, 1e-6], [-1e-3, 0.0], [5e-4, -2e-6]])  # u/K, u/K^2
GAMMA = np.array([[1e-4], [-2e-4], [3e-4]])  # 1/K


def model(bias=BETA, scale=GAMMA) -> TemperatureModel:
    k = bias.size + scale.size
    sigma = np.linspace(1e-6, 2e-6, k)
    return TemperatureModel(T_REF, T_MIN, T_MAX, bias, scale, np.diag(sigma**2))


COV0 = np.diag(np.r_[np.full(9, 1e-4), np.full(3, 1e-5)] ** 2)  # make()'s sigmas of a and b


def thermal_cal():
    return make(a=A, bias=B, covariance=COV0).with_temperature(model())


def readings(temps, seed=3):
    """(true v (k, 3), readings z (k, 3)) at the temperatures (k,), from the model's definition:
    a_i(T) = a_i (1 + gamma_i x), b_i(T) = b_i + beta_i1 x + beta_i2 x^2, x = T - T_REF."""
    x = np.asarray(temps, float) - T_REF
    v = np.random.default_rng(seed).uniform(-2, 2, (len(x), 3))
    z = np.array([vk @ (A * (1 + GAMMA[:, 0] * xk)) + B + BETA[:, 0] * xk + BETA[:, 1] * xk**2
                  for vk, xk in zip(v, x, strict=True)])
    return v, z


def write_csv(path, header, columns):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(np.column_stack(columns).tolist())


def read_vectors(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return np.array(rows[1:], float)


def test_a_version_6_file_round_trips_bit_for_bit(tmp_path):
    cal = thermal_cal()
    path = tmp_path / "t.cal.json"
    cal.save(path)
    back = load(path)
    assert back.dumps() == path.read_text()
    for name in ("bias", "scale", "covariance"):
        assert getattr(back.temperature, name).tobytes() == \
            getattr(cal.temperature, name).tobytes()
    assert (back.temperature.t_ref, back.temperature.t_min, back.temperature.t_max) == \
        (T_REF, T_MIN, T_MAX)
    doc = back.to_document()
    assert doc["format_version"] == 6
    assert doc["temperature"]["units"] == {"temperature": "K",
                                           "bias": ["rad/s / K^1", "rad/s / K^2"],
                                           "scale": ["1 / K^1"]}
    assert doc["temperature"]["orders"] == {"bias": 2, "scale": 1}
    assert loads(make().dumps()).temperature is None  # none: null


def test_older_files_load_with_no_temperature_model():
    def to_v5(doc):
        del doc["temperature"]
        doc.update(format_version=5, conventions=CONVENTIONS_V5)

    assert loads(edited(thermal_cal(), to_v5, True)).temperature is None
    with pytest.raises(CalibrationFileError, match="unknown keys \\['temperature'\\]"):
        loads(edited(thermal_cal(), lambda d: d.update(format_version=5,
                                                       conventions=CONVENTIONS_V5), True))


def test_the_checksum_covers_the_temperature_model():
    with pytest.raises(CalibrationFileError, match="checksum"):
        loads(edited(thermal_cal(), lambda d: d["temperature"]["bias"][0].__setitem__(0, 3e-3)))


@pytest.mark.parametrize("change, problem", [
    (lambda t: t.update(range=[340.0, 260.0]), "t_min < t_max"),
    (lambda t: t.update(t_ref=350.0), "t_ref 350.0 inside"),
    (lambda t: t.update(t_ref=27.0, range=[-13.0, 67.0]), "looks like degC"),
    (lambda t: t.update(range=[260.0, 1e200]), "range must be finite"),
    (lambda t: t["orders"].update(bias=3), "orders .* integer 0..2"),
    (lambda t: t["orders"].update(scale=True), "orders .* integer 0..2"),
    (lambda t: t.update(extra=1), "exactly t_ref, range"),
    (lambda t: t.update(bias=t["bias"][:2]), "bias has shape \\(2, 2\\)"),
    (lambda t: t.update(scale=[["1e-4"], [0.0], [0.0]]), "list of numbers"),
    (lambda t: t["scale_sigma"].__setitem__(0, [9e-6]), "diagonal differs"),
    (lambda t: t["units"].update(temperature="degC"), "units"),
    (lambda t: t.update(scale=[[0.1], [0.0], [0.0]]), "ratio"),
    (lambda t: t.update(covariance=[[1.0]]), "covariance has shape"),
    (lambda t: t.update(t_ref="300"), "t_ref '300' must be a number"),
])
def test_a_hostile_temperature_section_is_refused(change, problem):
    with pytest.raises(CalibrationFileError, match=problem):
        loads(edited(thermal_cal(), lambda d: change(d["temperature"]), True))


@pytest.fixture
def cal_path(tmp_path):
    path = tmp_path / "SN42.cal.json"
    thermal_cal().save(path)
    return path


def test_apply_uses_each_samples_temperature(tmp_path, cal_path, capsys):
    temps = np.linspace(T_MIN, T_MAX, 40)
    v, z = readings(temps)
    data = tmp_path / "z.csv"
    write_csv(data, ["temp [K]", *SENSORS], [temps, z])
    out = tmp_path / "v.csv"
    assert cli.main(["apply", str(cal_path), str(data), "--temperature-column", "temp",
                     "--out", str(out), "--json"]) == 0
    assert '"extrapolated": 0' in capsys.readouterr().out
    assert np.max(np.abs(read_vectors(out) - v)) < 1e-12
    # the reference calibration alone (no temperature) misses by the tempcos' size
    assert np.max(np.abs(make(a=A, bias=B).apply(z.T).T - v)) > 1e-2


def test_a_csv_column_in_kelvin_is_used_by_default(tmp_path, cal_path):
    temps = np.linspace(T_MIN, T_MAX, 7)
    v, z = readings(temps)
    data, out = tmp_path / "z.csv", tmp_path / "v.csv"
    write_csv(data, [*SENSORS, "unit temperature [K]"], [z, temps])
    assert cli.main(["apply", str(cal_path), str(data), "--out", str(out)]) == 0
    assert np.max(np.abs(read_vectors(out) - v)) < 1e-12


def test_a_fixed_temperature(tmp_path, cal_path):
    v, z = readings(np.full(10, 321.5))
    data, out = tmp_path / "z.csv", tmp_path / "v.csv"
    write_csv(data, list(SENSORS), [z])
    assert cli.main(["apply", str(cal_path), str(data), "--temperature", "321.5",
                     "--out", str(out), "--sigma"]) == 0
    got = read_vectors(out)
    assert got.shape == (10, 6) and np.max(np.abs(got[:, :3] - v)) < 1e-12
    # 21.5 K from t_ref the model's coefficients add to the sigma of every component
    assert cli.main(["apply", str(cal_path), str(data), "--temperature", str(T_REF),
                     "--out", str(out), "--sigma", "--force"]) == 0
    assert np.all(got[:, 3:] > read_vectors(out)[:, 3:])


def test_outside_the_range_it_refuses_unless_extrapolate(tmp_path, cal_path, capsys):
    temps = np.r_[np.linspace(280.0, 300.0, 5), 350.0]
    v, z = readings(temps)
    data, out = tmp_path / "z.csv", tmp_path / "v.csv"
    write_csv(data, ["temp", *SENSORS], [temps, z])
    args = ["apply", str(cal_path), str(data), "--temperature-column", "temp", "--out", str(out)]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "1 of 6 samples (e.g. 350.00 K) lie outside the calibrated range 260.00 .. 340.00 K" \
        in err and "--extrapolate" in err and not out.exists()
    assert cli.main([*args, "--extrapolate"]) == 0
    assert "warning: " in capsys.readouterr().err
    assert np.max(np.abs(read_vectors(out) - v)) < 1e-12  # the polynomial, carried on
    write_csv(data, list(SENSORS), [z])
    assert cli.main(["apply", str(cal_path), str(data), "--temperature", "250"]) == 2
    assert "250.00 K" in capsys.readouterr().err


@pytest.mark.parametrize("extra, columns, message", [
    ([], list(SENSORS), "has no channel in K; give the unit's temperature"),
    (["--temperature", "25"], list(SENSORS), "looks like degC"),
    (["--temperature-column", "temp"], ["temp", *SENSORS], "looks like degC"),
    (["--temperature-column", "temp"], ["temp [degC]", *SENSORS], "are not in"),
    (["--temperature-column", "t"], ["temp", *SENSORS], "no column 't'"),
    (["--temperature", "300", "--temperature-column", "temp"], ["temp", *SENSORS],
     "either --temperature or --temperature-column"),
])
def test_bad_temperature_input_is_refused(tmp_path, cal_path, capsys, extra, columns, message):
    _, z = readings(np.full(4, 300.0))
    data = tmp_path / "z.csv"
    write_csv(data, columns, [np.full(4, 25.0), z] if len(columns) == 4 else [z])
    assert cli.main(["apply", str(cal_path), str(data), *extra]) == 2
    assert re.search(message, capsys.readouterr().err)


def test_sigma_at_a_temperature_is_the_first_order_propagation():
    """Against central differences of apply_at over each parameter of (a, b) and of the model,
    with the two covariances given (independent)."""
    cov0, cal = COV0, thermal_cal()
    temps = np.array([265.0, 300.0, 335.0, 335.0])
    _, z = readings(temps)
    got = cal.vector_covariance(z.T, temps)
    theta0 = np.r_[A.ravel(), B]
    coef0 = np.r_[BETA.ravel(), GAMMA.ravel()]

    def apply(theta, coef):
        m = TemperatureModel(T_REF, T_MIN, T_MAX, coef[:6].reshape(3, 2),
                             coef[6:].reshape(3, 1), np.eye(9))
        return m.fuse(theta[:9].reshape(3, 3), theta[9:], z.T, temps)

    def jacobian(f, x0, h=1e-7):
        cols = []
        for i in range(len(x0)):
            e = np.zeros(len(x0))
            e[i] = h * max(abs(x0[i]), 1e-3)
            cols.append((f(x0 + e) - f(x0 - e)) / (2 * e[i]))
        return np.stack(cols, axis=-1)  # (d, k, p)

    j0 = jacobian(lambda t: apply(t, coef0), theta0)
    jt = jacobian(lambda c: apply(theta0, c), coef0)
    want = np.einsum("dkp,pq,ekq->kde", j0, cov0, j0) + \
        np.einsum("dkp,pq,ekq->kde", jt, cal.temperature.covariance, jt)
    assert np.allclose(got, want, rtol=1e-5, atol=1e-6 * np.abs(got).max())
    assert not np.allclose(got[0], got[1], rtol=1e-2)  # the model's uncertainty grows off t_ref
    assert np.allclose(cal.vector_covariance(z.T[:, 1], 300.0)[0], got[1], rtol=1e-12)


def test_temperature_options_need_a_temperature_model(tmp_path, capsys):
    path = tmp_path / "plain.cal.json"
    make(a=A, bias=B).save(path)
    _, z = readings(np.full(4, 300.0))
    data = tmp_path / "z.csv"
    write_csv(data, list(SENSORS), [z])
    assert cli.main(["apply", str(path), str(data), "--temperature", "300"]) == 2
    assert "has no temperature model" in capsys.readouterr().err


def test_a_sessions_channel_in_kelvin_is_used(tmp_path, cal_path):
    temps = np.linspace(270.0, 330.0, 30)
    v, z = readings(temps)
    cpu = np.array([1e6, 1e6, 1e6, 100.0])  # counts per rad/s, per K
    spec = StreamSpec((*SENSORS, "temp"), ("rad/s",) * 3 + ("K",), cpu, 100.0)
    seq = np.arange(len(z))
    with SessionWriter.create(tmp_path / "s.h5", {"protocol": "rotary", "unit_serial": "SN42"},
                              {"imu": spec}) as w:
        w.append("imu", SampleBlock(np.round(np.c_[z, temps] * cpu).astype(np.int64), seq,
                                    np.full(len(z), np.nan), 10.0 + seq / 100.0, spec.channels))
    out = tmp_path / "v.h5"
    assert cli.main(["apply", str(cal_path), str(tmp_path / "s.h5"), "--out", str(out)]) == 0
    with h5py.File(out, "r") as f:
        got, used = f["v"][()], f["temperature"][()]
        assert f["temperature"].attrs["units"] == "K"
    # counts rounded to 1e-6 rad/s and 0.01 K (the tempcos move a reading < 1e-5 per 0.01 K)
    assert np.max(np.abs(got - v)) < 2e-5 and np.max(np.abs(used - temps)) <= 0.005


C_PROGRAM = r"""
#include <stdio.h>
#include "cal.h"
int main(void) {
    double z[IMU_CAL_M], t;
    while (scanf("%lf", &t) == 1) {
        double x = t - IMU_CAL_T_REF, zc[IMU_CAL_M];
        for (int i = 0; i < IMU_CAL_M; i++) {
            if (scanf("%lf", &z[i]) != 1) return 1;
            double b = IMU_CAL_BIAS[i], r = 1, xp = 1;
            for (int p = 0; p < IMU_CAL_BIAS_ORDER; p++) {
                xp *= x;
                b += IMU_CAL_BIAS_TEMPCO[i][p] * xp;
            }
            xp = 1;
            for (int p = 0; p < IMU_CAL_SCALE_ORDER; p++) {
                xp *= x;
                r += IMU_CAL_SCALE_TEMPCO[i][p] * xp;
            }
            zc[i] = (z[i] - b) / r;
        }
        for (int k = 0; k < IMU_CAL_D; k++) {
            double v = 0;
            for (int i = 0; i < IMU_CAL_M; i++) v += IMU_CAL_FUSION[k][i] * zc[i];
            printf("%.17g%c", v, k + 1 < IMU_CAL_D ? ' ' : '\n');
        }
    }
    return 0;
}
"""


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")
def test_the_c_header_carries_the_temperature_model(tmp_path, cal_path, capsys):
    header = tmp_path / "cal.h"
    assert cli.main(["export", str(cal_path), "--c-header", str(header), "--type",
                     "double"]) == 0
    assert "temperature model: IMU_CAL_T_REF, _T_MIN, _T_MAX (260.00 .. 340.00 K), bias order 2" \
        in capsys.readouterr().out
    text = header.read_text()
    assert "#define IMU_CAL_T_MIN 260.0" in text and "#define IMU_CAL_BIAS_ORDER 2" in text
    (tmp_path / "main.c").write_text(C_PROGRAM)
    exe = tmp_path / "fuse"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(exe),
                    str(tmp_path / "main.c")], check=True, cwd=tmp_path)
    temps = np.linspace(T_MIN, T_MAX, 9)
    v, z = readings(temps)
    run = subprocess.run([str(exe)], input="\n".join(" ".join(repr(float(x)) for x in row)
                                                     for row in np.c_[temps, z]),
                         capture_output=True, text=True, check=True, timeout=600)
    got = np.array([line.split() for line in run.stdout.splitlines()], float)
    assert np.max(np.abs(got - v)) < 1e-12  # a triad: the firmware's formula is exact
