"""`station apply` (readings -> calibrated vectors) and `station export --c-header`, checked against
vectors made by hand: z_i = a_i . v + b_i, so the fusion must give back v (docs/conventions.md)."""

import csv
import re
import shutil
import subprocess

import h5py
import numpy as np
import pytest
from test_calfile import SENSORS, make

from drivers.samples import SampleBlock
from station import cli
from station.calfiles.calfile import load
from station.exports.c import c_header
from station.session import SessionWriter, StreamSpec

RATE = 100.0
CPU = 1e6  # counts per rad/s


@pytest.fixture
def cal_path(tmp_path):
    path = tmp_path / "SN42.cal.json"
    make().save(path)
    return path


def truth(k: int = 50, seed: int = 9):
    """(v (k, 3) rad/s, readings z (k, 4) rad/s) of the calibration of `make()`."""
    cal = make()
    v = np.random.default_rng(seed).uniform(-2, 2, (k, 3))
    return v, v @ cal.a + cal.bias


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], float)


def write_csv(path, header, columns):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(np.column_stack(columns).tolist())


def test_csv_of_si_readings_in_any_column_order(tmp_path, cal_path):
    v, z = truth()
    t = np.arange(len(v)) / RATE
    data = tmp_path / "z.csv"
    write_csv(data, ["g3 [rad/s]", "time", "g1", "g4", "g2 [rad/s]"],
              [z[:, 2], t, z[:, 0], z[:, 3], z[:, 1]])
    out = tmp_path / "v.csv"
    assert cli.main(["apply", str(cal_path), str(data), "--out", str(out)]) == 0
    header, values = read_csv(out)
    assert header == ["time [s]", "v_x [rad/s]", "v_y [rad/s]", "v_z [rad/s]"]
    assert np.array_equal(values[:, 0], t)
    assert np.allclose(values[:, 1:], v, atol=1e-12)


def test_sigma_columns_from_the_calibrations_covariance(tmp_path, capsys):
    v, z = truth(k=20)
    sigma = np.r_[np.full(12, 1e-4), np.full(4, 1e-5)]
    cal = make(covariance=np.diag(sigma**2))
    path = tmp_path / "cov.cal.json"
    cal.save(path)
    data, out = tmp_path / "z.csv", tmp_path / "v.csv"
    write_csv(data, list(SENSORS), [z[:, i] for i in range(4)])
    assert cli.main(["apply", str(path), str(data), "--out", str(out), "--sigma"]) == 0
    header, values = read_csv(out)
    assert header[3:] == ["sigma_v_x [rad/s]", "sigma_v_y [rad/s]", "sigma_v_z [rad/s]"]
    assert np.allclose(values[:, :3], v, atol=1e-12)
    expected = np.sqrt(np.diagonal(cal.vector_covariance(z.T), axis1=1, axis2=2))
    assert np.allclose(values[:, 3:], expected, rtol=1e-12)
    # b's own sigma alone: F diag(sb^2) F^T, a lower bound of each component's variance
    f = cal.fusion_matrix()
    assert np.all(values[:, 3:] ** 2 >= np.diag(f @ np.diag(sigma[12:] ** 2) @ f.T) * (1 - 1e-9))
    assert cli.main(["apply", str(cal_path_of(tmp_path)), str(data), "--sigma"]) == 2
    assert "no covariance" in capsys.readouterr().err


def cal_path_of(tmp_path):
    """A calibration file without covariance (as version-1 files)."""
    path = tmp_path / "nocov.cal.json"
    make().save(path)
    return path


def test_csv_of_raw_counts(tmp_path, cal_path, capsys):
    v, z = truth()
    data = tmp_path / "counts.csv"
    write_csv(data, [f"{s} [counts]" for s in SENSORS], [np.round(z * CPU)])
    assert cli.main(["apply", str(cal_path), str(data), "--counts"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "v_x [rad/s],v_y [rad/s],v_z [rad/s]"
    got = np.array([line.split(",") for line in lines[1:]], float)
    # rounding: at most 0.5 count = 0.5e-6 rad/s per reading, through the fusion matrix
    assert np.max(np.abs(got - v)) < 0.5e-6 * np.abs(np.linalg.pinv(make().a.T)).sum(axis=1).max()


@pytest.mark.parametrize("header, rows, message", [
    (["g1", "g2", "g3"], [[1, 2, 3]], r"lack columns \['g4'\]"),
    (["g1", "g2", "g3", "g4", "g5"], [[1, 2, 3, 4, 5]], r"columns \['g5'\] are unknown"),
    (["g1 [deg/s]", "g2", "g3", "g4"], [[1, 2, 3, 4]], "not in rad/s"),
    (["g1", "g2", "g3", "g4"], [[1, 2, "nan", 4]], "finite"),
    (["g1", "g2", "g3", "g4"], [[1, 2, 3]], "4 finite numbers|not a table"),
    (["g1", "g1", "g3", "g4"], [[1, 2, 3, 4]], "repeats"),
    (["g1", "g2", "g3", "g4"], [[1, 2, "x", 4]], "not a table of numbers"),
])
def test_bad_csv_is_refused_with_the_reason(tmp_path, cal_path, capsys, header, rows, message):
    data = tmp_path / "bad.csv"
    with open(data, "w", newline="") as f:
        csv.writer(f).writerows([header, *rows])
    assert cli.main(["apply", str(cal_path), str(data)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("station apply: ")
    assert re.search(message, err), err


def session_file(path, serial="SN42", channels=SENSORS, units="rad/s"):
    """A closed session file holding the readings of `truth()` as counts."""
    v, z = truth()
    spec = StreamSpec(channels, units, CPU, RATE)
    seq = np.arange(len(z))
    with SessionWriter.create(path, {"protocol": "rotary", "unit_serial": serial},
                              {"imu": spec}) as w:
        w.append("imu", SampleBlock(np.round(z * CPU).astype(np.int64), seq,
                                    np.full(len(z), np.nan), 10.0 + seq / RATE, channels))
    return v


def test_session_to_hdf5(tmp_path, cal_path, capsys):
    v = session_file(tmp_path / "s.h5")
    out = tmp_path / "v.h5"
    assert cli.main(["apply", str(cal_path), str(tmp_path / "s.h5"), "--out", str(out),
                     "--json"]) == 0
    assert '"rows": 50' in capsys.readouterr().out
    with h5py.File(out, "r") as f:
        assert f["v"].attrs["units"] == "rad/s" and f["time"].attrs["units"] == "s"
        assert f.attrs["unit_serial"] == "SN42"
        assert f.attrs["calibration_checksum"] == make().to_document()["checksum"]
        assert (np.max(np.abs(f["v"][()] - v))
                < 0.5e-6 * np.abs(np.linalg.pinv(make().a.T)).sum(1).max())
        # sampling instants: seq / rate + host time of the least delayed sample
        assert np.allclose(np.diff(f["time"][()]), 1 / RATE)


@pytest.mark.parametrize("kwargs, message", [
    ({"serial": "SN7"}, "for unit 'SN42' but .* comes from unit 'SN7'"),
    ({"channels": ("a", "b", "c", "d")}, "lacks the calibration.s sensors"),
    ({"units": "m/s^2"}, "convert the readings to SI"),
])
def test_a_session_of_another_unit_is_refused(tmp_path, cal_path, capsys, kwargs, message):
    session_file(tmp_path / "s.h5", **kwargs)
    assert cli.main(["apply", str(cal_path), str(tmp_path / "s.h5")]) == 2
    assert re.search(message, capsys.readouterr().err)


def test_apply_never_overwrites(tmp_path, cal_path, capsys):
    out = tmp_path / "v.csv"
    out.write_text("precious")
    _, z = truth()
    data = tmp_path / "z.csv"
    write_csv(data, list(SENSORS), [z])
    assert cli.main(["apply", str(cal_path), str(data), "--out", str(out)]) == 2
    assert out.read_text() == "precious" and "exists" in capsys.readouterr().err


C_PROGRAM = r"""
#include <stdio.h>
#include "cal.h"
int main(void) {
    double z[IMU_CAL_M];
    while (1) {
        for (int i = 0; i < IMU_CAL_M; i++)
            if (scanf("%lf", &z[i]) != 1) return 0;
        for (int k = 0; k < IMU_CAL_D; k++) {
            double v = 0;
            for (int i = 0; i < IMU_CAL_M; i++)
                v += IMU_CAL_FUSION[k][i] * (z[i] / IMU_CAL_COUNTS_PER_UNIT[i] - IMU_CAL_BIAS[i]);
            printf("%.17g%c", v, k + 1 < IMU_CAL_D ? ' ' : '\n');
        }
    }
}
"""


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")
@pytest.mark.parametrize("ctype, tolerance", [("double", 1e-12), ("float", 1e-6)])
def test_the_c_header_computes_the_calibrated_vectors(tmp_path, cal_path, ctype, tolerance):
    v, z = truth(k=20)
    assert cli.main(["export", str(cal_path), "--c-header", str(tmp_path / "cal.h"),
                     "--type", ctype]) == 0
    (tmp_path / "main.c").write_text(C_PROGRAM)
    exe = tmp_path / "fuse"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(exe),
                    str(tmp_path / "main.c")], check=True, cwd=tmp_path)
    counts = z * CPU  # exact inputs: the header's arithmetic is what is checked
    run = subprocess.run([str(exe)], input="\n".join(" ".join(repr(float(x)) for x in row)
                                                     for row in counts),
                         capture_output=True, text=True, check=True, timeout=600)
    got = np.array([line.split() for line in run.stdout.splitlines()], float)
    # float: coefficients rounded to 2^-24 relative, |v| <= 3.5, sums of 4 terms
    assert np.max(np.abs(got - v)) < tolerance * 10


def test_export_refuses_another_unit_and_bad_names(tmp_path, cal_path, capsys):
    out = tmp_path / "cal.h"
    assert cli.main(["export", str(cal_path), "--c-header", str(out), "--unit-serial",
                     "SN7"]) == 2
    assert "for unit 'SN42'" in capsys.readouterr().err and not out.exists()
    with pytest.raises(ValueError, match="not a C identifier"):
        c_header(load(cal_path), prefix="1BAD")


def test_untrusted_strings_cannot_escape_the_header_comment(tmp_path):
    cal = make(unit_serial="x */ #include <evil.h> /*")
    text = c_header(cal)
    assert "*/ #include" not in text and "<evil.h>" not in text
