"""A thermal campaign through the real drivers (issue 15): the virtual thermal bench
(`station.twin.thermal.ThermalTwin`: the 12-gyro unit streaming its temperature over a pty, the
rotary table with its motorised fixture and the thermal chamber behind pymodbus servers on
127.0.0.1) recorded by `station record`, solved by `station solve`, applied by `station apply`;
then every fault of a soak, each a specific error with the table stopped and the chamber at its
safe setpoint, and a campaign interrupted by Ctrl-C resumed and solved.

A fast clock (80x), a fast chamber and a small unit (time constants of 10 s and 30 s of clock
time), few positions and short windows keep each campaign to seconds of wall time.
"""

import csv
import json
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from scipy.stats import norm
from scipy.stats import t as student
from twinproc import STATION, TwinProcess

from drivers.errors import ChamberAlarm, ChamberDoorOpen, ChamberTimeout, DeviceLostError
from drivers.thermal_chamber import ChamberRegisterMap
from station.acquire.bench import BenchProfile
from station.acquire.operator import ConsoleOperator
from station.calfiles.calfile import load
from station.cli import main
from station.errors import RecordingError, SoakTimeout
from station.protocols.thermal import ROOM, run_campaign
from station.session import Session
from station.session.campaign import Campaign
from station.sim.thermal import unit_at
from station.twin.thermal import TRUTH, ThermalTwin

SPEED = None  # lockstep time (drivers.clock.SteppedClock)
ALPHA = 0.01
"""False-alarm probability of each statistical check, over all the values it checks."""


def _write_profile(twin, tmp_path):
    profile = tmp_path / "bench.toml"
    profile.write_text(twin.profile_text())
    return profile


def test_a_four_setpoint_campaign_recovers_the_true_tempcos(tmp_path, capsys):
    """4 setpoints, 6 positions each: the 24 linear tempcos within their Bonferroni bound of the
    truth, both tempcos detected, a version-6 calibration file with the model, and `station
    apply` between two setpoints giving the true rate magnitudes within the calibration's own
    1-sigma bound."""
    with ThermalTwin(seed=2, speed=SPEED, positions=6) as twin:
        profile = _write_profile(twin, tmp_path)
        assert main(["record", "--profile", str(profile), "--out", str(tmp_path / "camp"),
                     "--solve", "--json"]) == 0
        unit = twin.bench.unit
        assert twin.error is None
    summary = json.loads(capsys.readouterr().out)
    assert [s["state"] for s in summary["soaks"]] == ["done"] * 4
    with Session.open(tmp_path / "camp" / "soak_1_263K.h5") as session:
        thermal = session.metadata["thermal"]
    assert thermal["setpoint"] == 263.15 and abs(thermal["unit_temperature"] - 263.15) < 0.5
    assert thermal["chamber_before"]["at_setpoint"] and len(thermal["trace"]["air"]) > 10

    path = tmp_path / "camp" / "campaign.cal.json"
    assert json.loads(path.read_text())["format_version"] == 6
    model = load(path).temperature
    # the true tempcos are 40 (bias) and 10 to 60 (scale) of their sigmas: both orders at least
    # linear. A needless quadratic is chosen now and then (nominally <= 1 % per step, more with
    # the bias sigmas estimated from 6 windows): the linear terms are then checked all the same
    assert model.orders["bias"] >= 1 and model.orders["scale"] >= 1, model.orders
    z_bias = (model.bias[:, 0] - TRUTH.bias) / model.bias_sigma[:, 0]
    z_scale = (model.scale[:, 0] - np.asarray(TRUTH.scale)) / model.scale_sigma[:, 0]
    # Bonferroni over the 24 values, ALPHA in all. A bias 1-sigma comes from the scatter of 6
    # static windows per soak pooled over the 4 soaks (`pooled_static_bias`): the z is Student's
    # t of 4 x 5 = 20 dof. A scale factor's 1-sigma comes from thousands of samples per window
    # (normal).
    assert np.all(np.abs(z_bias) < student.isf(ALPHA / 48, 20)), z_bias
    assert np.all(np.abs(z_scale) < norm.isf(ALPHA / 48)), z_scale

    rng = np.random.default_rng(7)
    v = rng.standard_normal((3, 20))
    v /= np.linalg.norm(v, axis=0)  # 1 rad/s, the table rate of the sessions
    between = 298.15
    at = unit_at(unit, between, True, TRUTH)
    z = at.a.T @ v + at.bias[:, None]
    readings = tmp_path / "rates.csv"
    with readings.open("w", newline="") as f:
        csv.writer(f).writerows([[f"g{i + 1} [rad/s]" for i in range(12)], *z.T.tolist()])
    out = tmp_path / "applied.csv"
    assert main(["apply", str(path), str(readings), "--temperature", str(between), "--sigma",
                 "--out", str(out)]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    names = [k for k in rows[0] if k.startswith("v_")]
    got = np.array([[float(r[k]) for k in names] for r in rows]).T
    sigma = np.array([[float(r["sigma_" + k]) for k in names] for r in rows]).T
    # the calibration's frame is its own (Eq. 19), so compare the magnitudes: within
    # |sigma| (a bound on the 1-sigma of the magnitude) times the Bonferroni quantile
    error = np.abs(np.linalg.norm(got, axis=0) - 1.0)
    assert np.all(error < norm.isf(ALPHA / 40) * np.linalg.norm(sigma, axis=0)), error


FAULTS = {
    "alarm": (lambda twin: setattr(twin.physics, "alarm", True), ChamberAlarm),
    "door": (lambda twin: setattr(twin.physics, "door_open", True), ChamberDoorOpen),
    "imu lost": (lambda twin: twin.toggle("imu"), DeviceLostError),
    "imu silent": (lambda twin: twin.bench.imu_twin.pause(1e4), RecordingError),
    "chamber silent": (lambda twin: twin.toggle("chamber"), ChamberTimeout),
    "soak timeout": (lambda twin: None, SoakTimeout),
}


@pytest.mark.parametrize("fault", FAULTS)
def test_a_fault_during_a_soak_stops_the_table_and_leaves_the_chamber_safe(fault, tmp_path):
    """The fault comes while the unit soaks at the first setpoint, with the table (left)
    turning: the campaign ends with that fault's error, the table stopped, the chamber at its
    safe setpoint (a silent chamber cannot be told anything: the error says to set it by hand),
    and the manifest still at the first soak."""
    make, error = FAULTS[fault]
    soak = {"soak_timeout": 60.0, "stability": 1e-4} if fault == "soak timeout" else None
    if fault == "chamber silent":  # each lost reply waits this (not lockstep's 30 s) per try
        soak = {"reply_timeout": 5.0, "retries": 1}
    with ThermalTwin(seed=3, speed=SPEED, positions=3, setpoints=(283.15, 313.15),
                     soak=soak) as twin:
        profile = _write_profile(twin, tmp_path)
        bench = BenchProfile.load(profile)
        campaign = Campaign.create(tmp_path / "camp", bench.unit_serial, profile,
                                   bench.chamber.setpoints)
        table = twin.bench.table

        def strike():
            while twin.physics.setpoint != 283.15:
                time.sleep(0.01)
            table.set_rate(1.0)
            table.start()
            twin.bench.clock.sleep(5.0)  # the soak is under way (lockstep time, not the host's)
            make(twin)

        striker = threading.Thread(target=strike, daemon=True)
        striker.start()
        with pytest.raises(error) as info:
            run_campaign(bench, campaign, ConsoleOperator(stdout=sys.stderr))
        striker.join(5.0)
        assert not table.state().running
        notes = " ".join(getattr(info.value, "__notes__", []))
        if fault == "chamber silent":  # nothing reaches it: its own watchdog takes it safe
            assert "set it by hand" in notes and "watchdog" in notes
            watchdog = ChamberRegisterMap.load("chamber_modbus").watchdog
            twin.bench.clock.sleep(2 * watchdog.period)  # this thread moves lockstep time now
            assert twin.physics.setpoint == watchdog.safe_setpoint == ROOM
        else:
            assert twin.physics.setpoint == ROOM and "safe setpoint" in notes
        assert "station resume" in notes
        if fault == "soak timeout":  # names the setpoint, the rate still seen, what to do
            assert all(w in str(info.value) for w in ("283.15 K", "K/min", "soak_timeout"))
    assert Campaign.load(tmp_path / "camp").next_soak() == 0


def test_ctrl_c_during_a_soak_then_resume_and_solve(tmp_path):
    """`station record` interrupted (SIGINT) while the unit soaks at the second setpoint: exit
    130, the table stopped, the chamber at its safe setpoint, the first soak done; `station
    resume DIR` records the second, and `station solve DIR` fits both."""
    with ThermalTwin(seed=4, speed=SPEED, positions=6, setpoints=(283.15, 313.15)) as twin:
        profile = _write_profile(twin, tmp_path)
        camp = tmp_path / "camp"
        record = subprocess.Popen([*STATION, "record", "--profile", str(profile), "--out",
                                   str(camp)], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True)
        while twin.physics.setpoint != 313.15:  # however long a busy host takes
            assert record.poll() is None, record.stderr.read()
            time.sleep(0.02)
        twin.bench.clock.sleep(5.0)  # soaking at 313.15 K (lockstep time, not the host's)
        twin.bench.clock.leave()  # a thread that waited takes part in lockstep time until it leaves
        twin.bench.table.set_rate(1.0)
        twin.bench.table.start()
        record.send_signal(signal.SIGINT)
        _, err = record.communicate(timeout=600)
        assert record.returncode == 130, err
        assert not twin.bench.table.state().running
        assert twin.physics.setpoint == ROOM and "safe setpoint" in err
        assert Campaign.load(camp).next_soak() == 1

        resumed = subprocess.run([*STATION, "resume", str(camp), "--json"], capture_output=True,
                                 text=True, timeout=600)
        assert resumed.returncode == 0, resumed.stderr
        assert twin.physics.setpoint == ROOM
    assert Campaign.load(camp).next_soak() is None
    solved = subprocess.run([*STATION, "solve", str(camp), "--json"], capture_output=True,
                            text=True, timeout=600)
    assert solved.returncode == 0, solved.stderr
    summary = json.loads(solved.stdout)
    assert len(summary["soaks_K"]) == 2 and summary["orders"]["bias"] == 1


def test_station_twin_chamber_serves_the_thermal_bench(tmp_path):
    """`station twin --chamber`: the chamber's address among the devices, and a bench profile
    whose [chamber] points at it, for a unit streaming its temperature."""
    profile = tmp_path / "thermal.toml"
    with TwinProcess("--chamber", "--speed", "20", "--positions", "6", "--profile-out",
                     str(profile), "--lifetime", "30") as twin:
        bench = BenchProfile.load(profile)
    assert bench.chamber.port == twin.started["chamber"]["port"]
    assert bench.chamber.host == "127.0.0.1" and bench.imu.imu.units[-1] == "K"
    truth = twin.truth
    assert truth["temperature"]["bias"] == TRUTH.bias and truth["chamber"]["air"] == ROOM


def test_an_alarm_during_a_session_stops_it_and_the_resume_completes_it(tmp_path):
    """The chamber's alarm while the first session records (the chamber is watched meanwhile):
    ChamberAlarm at once, the session stopped with its table stopped and the chamber safe, the
    positions done kept; after the alarm is cleared, the resumed campaign soaks that setpoint
    again and records the positions left into the same session."""
    with ThermalTwin(seed=5, speed=SPEED, positions=3, setpoints=(283.15, 313.15)) as twin:
        profile = _write_profile(twin, tmp_path)
        bench = BenchProfile.load(profile)
        camp = tmp_path / "camp"
        campaign = Campaign.create(camp, bench.unit_serial, profile, bench.chamber.setpoints)

        def strike():
            while not (camp / "soak_1_283K.h5").exists():
                time.sleep(0.01)
            twin.bench.clock.sleep(5.0)  # lockstep time, not the host's
            twin.physics.alarm = True

        threading.Thread(target=strike, daemon=True).start()
        with pytest.raises(ChamberAlarm, match="the session stopped"):
            run_campaign(bench, campaign, ConsoleOperator(stdout=sys.stderr))
        assert twin.physics.setpoint == ROOM and not twin.bench.table.state().running
        with Session.open(camp / "soak_1_283K.h5") as session:
            aborts = [e for e in session.events() if e.kind == "abort"]
            stopped_at = session.last_completed_position()
        assert len(aborts) == 1 and "ChamberAlarm" in aborts[0].detail["error"]
        assert stopped_at is None or stopped_at < 2  # stopped before its last position
        again = Campaign.load(camp)
        assert again.next_soak() == 0 and any(again.soaks[0]["chamber_during"]["alarm"])

        twin.physics.alarm = False
        run_campaign(bench, again, ConsoleOperator(stdout=sys.stderr))
    done = Campaign.load(camp)
    assert done.next_soak() is None and not any(done.soaks[0]["chamber_during"]["alarm"])
    with Session.open(camp / "soak_1_283K.h5") as session:
        assert [e.kind for e in session.events()].count("session_resumed") == 1
        assert session.last_completed_position() == 2
