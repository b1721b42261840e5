"""A bench whose rotary table's rate error drifts across 30 sessions is flagged by the fleet
report's run rules before its units fail their tolerances.

Each session calibrates a new 12-gyro unit (Rupniewski's layout, scale factors 1 +- 0.2 %) on the
bench's table: the readings of 20 random orientations at the commanded rate, the table's true rate
distorted by the `rate_error` effect (station.model.effects.rate_error: true = commanded (1 +
scale + delta_j)), solved by the station's solver with the commanded rate as the magnitude (so
the rate error lands in every scale factor) and judged against a 1 % scale-factor tolerance. The
table's encoder shows the session's rate error (what `station.records.sources.table_rate_error`
reads from a session's table stream): the mean of its positions' factors minus 1. The scale of the
rate error is 0 for 10 sessions (the baseline), then creeps up 0.05 % a session.
"""

import dataclasses

import numpy as np
from recordmaker import when

from station import cli
from station.calfiles.calfile import Calibration
from station.model.effects.rate_error import RateError
from station.records.analysis import fleet
from station.records.query import Selection
from station.records.record import Record
from station.records.store import open_store
from station.report.fleet import fleet_page
from station.sim.layouts import A_MODEL
from station.solve.calibrate import calibrate
from station.solve.verdict import Tolerances, verdict

SESSIONS, STABLE, CREEP = 30, 10, 5e-4
RATE, NOISE, POSITIONS = 1.0, 2e-4, 20  # rad/s commanded, readings' sd (rad/s), per session
TOLERANCES = Tolerances(scale_factor=0.01)
NAMES = [f"g{i + 1}" for i in range(12)]


def session_calibration(k: int, rng: np.random.Generator, tmp_path):
    """(calibration file path, its Calibration, the table's rate error) of session k."""
    a = A_MODEL / np.linalg.norm(A_MODEL, axis=0) * (1 + rng.normal(0, 0.002, 12))
    scale = 0.0 if k < STABLE else CREEP * (k - STABLE + 1)
    factors = RateError(scale=scale, spread=1e-4).factors(POSITIONS, rng)
    u = rng.standard_normal((3, POSITIONS))
    u /= np.linalg.norm(u, axis=0)
    readings = a.T @ (RATE * factors * u) + rng.normal(0, NOISE, (12, POSITIONS))
    result = calibrate(readings, RATE, sigma=NOISE, names=NAMES)
    cal = Calibration.from_result(result, f"U{k:03d}", NAMES, "rad/s", bias=np.zeros(12),
                                  bias_sigma=np.full(12, 1e-5), bias_source="static windows")
    cal = dataclasses.replace(cal, verdict=verdict(cal, TOLERANCES, NAMES), created=when(k, 60))
    path = tmp_path / f"U{k:03d}.cal.json"
    cal.save(path)
    return path, cal, float(factors.mean() - 1)


def test_a_drifting_rate_table_is_flagged_before_its_units_fail(tmp_path):
    rng = np.random.default_rng(33)
    url = f"sqlite:///{tmp_path / 'station.db'}"
    verdicts = []
    with open_store(url) as store:
        for k in range(SESSIONS):
            path, cal, rate_error = session_calibration(k, rng, tmp_path)
            record = dataclasses.replace(Record.from_calibration(cal, path), bench="bench2",
                                         model="imu12", session_sha256=f"session-{k}",
                                         table_rate_error=rate_error)
            store.add(record)
            verdicts.append(cal.verdict["overall"])
        report = fleet(store, Selection(), baseline=STABLE)
    assert "FAIL" in verdicts, "the drift must end in failing units, or the test proves nothing"
    first_fail = verdicts.index("FAIL")
    health = report["benches"]["bench2"]["table_rate_error"]
    assert health["points"] == SESSIONS
    flag = health["first_flag"]
    assert flag is not None
    assert STABLE <= flag["index"] < first_fail, (flag, verdicts)
    assert all(v == "PASS" for v in verdicts[:flag["index"] + 1])
    assert health["flagged"][0] == flag["index"]
    assert 'id="bench-bench2-table_rate_error"' in fleet_page(report, url)


def test_station_fleet_exits_1_on_a_flagged_bench(tmp_path, capsys):
    """The command line says so too: the bench named FLAGGED in the text, exit code 1."""
    test_a_drifting_rate_table_is_flagged_before_its_units_fail(tmp_path)
    url = f"sqlite:///{tmp_path / 'station.db'}"
    assert cli.main(["fleet", "--db", url, "--baseline", str(STABLE)]) == 1
    assert "bench bench2: table rate error over 30 sessions: FLAGGED" in capsys.readouterr().out
