"""The MIMU4444 8-IMU array's raw packet dump on the command line: import binary -> solve ->
apply -> report (docs/realdata.md). Skipped without ../shared."""

import json
from pathlib import Path

import numpy as np
import pytest

from station.cli import main
from station.files.calfile import load

DUMP = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mimu4444-array"
pytestmark = pytest.mark.skipif(not (DUMP / "exp_2.bin").is_file(),
                                reason="real data (../shared) not available")
G = 9.81  # the authors' local gravity (PROVENANCE.md)


def test_the_array_goes_from_the_dump_to_a_report(tmp_path, capsys):
    session, cal = tmp_path / "exp_2.h5", tmp_path / "exp_2.cal.json"
    assert main(["import", "binary", str(session), str(DUMP / "exp_2.bin"),
                 "--profile", "mimu4444"]) == 0
    assert main(["solve", str(session), "--magnitude", str(G), "--store", "--accept-suspect",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.split("\n", 2)[-1])
    assert summary["pose_sigma"] is not None and summary["pose_sigma"] < 0.01  # m/s^2
    fit = load(cal)
    assert len(fit.sensors) == 24 and fit.units[0] == "m/s^2"
    assert 19 <= fit.fit["positions"] <= 22  # 20-21 poses held in each recording
    out = tmp_path / "acc.csv"
    assert main(["apply", str(cal), str(session), "--out", str(out)]) == 0
    v = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:4]
    norm = np.linalg.norm(v, axis=1)
    assert abs(np.median(norm) - G) < 0.01  # most samples are still: |a| at g once calibrated
    assert main(["report", str(session)]) == 0
    assert (tmp_path / "exp_2.html").is_file()
