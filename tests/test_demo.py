"""Acceptance of the demo (issues 5 and 6): 20 positions of a 12-gyro unit recorded through the real
drivers on the virtual bench, eps within 1.5 sqrt(trace(CRLB)), over the serial and the CAN link."""

import json
import re

import numpy as np
import pytest

from station import cli
from station.commands.demo import run_demo
from station.session import Session


def check_summary(s: dict, positions: int) -> None:
    """What any demo run must show, with bounds from theory, not from the code."""
    assert s["positions"] == positions
    # the acceptance of issues 5 and 6 is eps <= 1.5 sqrt(trace CRLB) (bench/demo.py prints it over
    # runs). For an efficient solver eps^2 is sum_i lambda_i chi2_1 over the CRLB's eigenvalues
    # (effective dof ~12 on this layout), so even a perfect run exceeds 1.5 with probability 0.012:
    # one run is tested against that distribution at a 1e-4 false-alarm level instead
    assert s["eps_p_value"] > 1e-4, s["eps_over_sqrt_crlb"]
    # the model explains the data: chi2/dof = 1 +- sqrt(2/dof), 5 standard deviations allowed
    assert abs(s["chi2_per_dof"] - 1) < 5 * np.sqrt(2 / s["dof"])
    k, sd, true = (np.array(s[key]) for key in
                   ("scale_factors", "scale_factors_sigma", "scale_factors_true"))
    assert np.all(np.abs(k - true) < 5 * sd)
    # Eq. (18) noise: per-sample sigma N sqrt(fs), ~10 s static and >= 2 turns of 2 pi / 1 rad/s
    n_sigma = np.radians(0.01) * np.sqrt(200)
    theory = n_sigma * np.sqrt(1 / (10 * 200) + 1 / (4 * np.pi * 200))
    assert s["readings_sigma_median"] == pytest.approx(theory, rel=0.15)
    for pair in s["axis_angles_deg"]:
        assert abs(pair["angle"] - pair["true"]) < 5 * pair["sigma"]


def test_station_demo_json_meets_the_acceptance(tmp_path, capsys):
    out = tmp_path / "demo.h5"
    assert cli.main(["demo", "--json", "--out", str(out)]) == 0
    s = json.loads(capsys.readouterr().out)
    check_summary(s, 20)
    assert s["imu"] == "serial" and s["wall_seconds"] > 0  # its target: bench/demo.py
    assert s["link"]["crc_failures"] == 0
    with Session.open(out) as f:
        assert f.protocol == "rotary" and f.closed_cleanly
        results = f.results("rotary")
        assert results.readings.shape == (12, 20) and results.calibration is not None
        assert np.allclose(results.calibration.scale_factors, s["scale_factors"])


def test_demo_over_the_can_link_meets_the_acceptance(tmp_path):
    # lockstep time: the CAN link keeps up however busy the host (at 20x of a real-time clock it
    # failed in bench/under_load.py beside two CPU hogs and the other test worker)
    s = run_demo(tmp_path / "can.h5", imu="can", seed=2, positions=20)
    check_summary(s, 20)
    assert s["link"]["incomplete"] == 0 and s["link"]["errors"] == 0


def test_demo_refuses_to_overwrite_a_session(tmp_path, capsys):
    out = tmp_path / "kept.h5"
    out.write_bytes(b"precious")
    assert cli.main(["demo", "--out", str(out)]) == 2
    assert "exists; choose another --out" in capsys.readouterr().err
    assert out.read_bytes() == b"precious"


def test_demo_refuses_too_few_positions_before_recording(capsys):
    assert cli.main(["demo", "--positions", "4"]) == 2
    err = capsys.readouterr().err
    assert "4 position(s) are too few" in err and "Record 2 more position(s)" in err


def test_station_demo_prints_a_readable_summary(capsys):
    assert cli.main(["demo", "--positions", "8", "--seed", "5"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "serial IMU" in out and "scale factor" in out and "1-2" in out  # both tables
    factor = re.search(r"recorded in [0-9.]+ s \(([0-9]+)x real time, lockstep\)", out)
    assert factor  # its value depends on the host; the session does not
    p_value = float(re.search(r"\(p\s+=\s+([0-9.e+-]+)\s+for\s+an\s+efficient", out).group(1))
    assert p_value > 1e-4  # as in check_summary
