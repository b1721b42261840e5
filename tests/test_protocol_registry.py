"""The one registry of protocol kinds (`station.protocols.KINDS`): a toy kind registered here, whose
parts all live in this module, is reachable from `station simulate`, `station solve`, `station
replay` and `station record` without touching those commands; unknown kinds and missing parts give
errors naming the kinds that have the part; importing the registry imports none of the parts."""

import json
import os
import subprocess
import sys
import tty
from dataclasses import dataclass

import numpy as np
import pytest

from drivers.samples import SampleBlock
from station import cli
from station.acquire.bench import BenchProfile, record
from station.calfiles.calfile import load
from station.protocols import KINDS, Kind, UnknownKind, kinds_with, lookup
from station.reduce.still import StillReadings
from station.session import Session, SessionWriter, StreamSpec
from station.sim.layouts import TRIAD, accelerometer_triad
from station.sim.static import simulate_static
from station.solve.still import calibrate_still

HERE = __name__
CALLS = []
"""The toy parts called, in order."""

G = 9.81
COUNTS_PER_UNIT = 1000.0
RATE_HZ = 50.0
TRUE_A = np.array([[1.02, 0.01, 0.0], [0.0, 0.98, -0.02], [0.01, 0.0, 1.01]])
TRUE_BIAS = np.array([0.05, -0.03, 0.02])


@dataclass(frozen=True)
class ToySettings:
    """The toy protocol's [protocol] keys."""

    poses: int = 12
    gravity: float = G


def toy_acquire(bench, imu, table, out, operator, clock, spec, metadata, view):
    """Record an empty toy session with the opened IMU driver."""
    CALLS.append(("acquire", type(imu).__name__, table, bench.settings))
    with SessionWriter.create(out, {**metadata, "protocol": "toy"}, {"imu": spec}, clock=clock):
        pass


def toy_readings(session, stream, trim=0.0):
    """The mean of each completed position's samples (between its start and done events)."""
    CALLS.append(("reduce", session.protocol))
    data, events = session.stream(stream), session.events()
    start = {e.position: e.time for e in events if e.kind == "position_start"}
    done = [(e.position, e.time) for e in events if e.kind == "position_done"]
    z = data.to_si()
    spans = [(data.host_time >= start[j] + trim) & (data.host_time <= t - trim) for j, t in done]
    M = np.array([z[s].mean(axis=0) for s in spans]).T
    sigma = np.array([z[s].std(axis=0, ddof=1) / np.sqrt(s.sum()) for s in spans]).T
    windows = np.array([(start[j], t) for j, t in done])
    return StillReadings(M, sigma, windows, np.zeros(len(done), np.int64))


def toy_solve(readings, magnitude, nominal=None, method="auto", refine=True):
    """The still-pose solver, noted."""
    CALLS.append(("solve", magnitude))
    return calibrate_still(readings, magnitude, nominal=nominal, method=method, refine=refine)


def toy_simulation(rng, effects, options):
    """A free-static simulation of a triad, noted."""
    CALLS.append(("simulate", options.positions))
    unit = accelerometer_triad(rng, fs=options.fs)
    return simulate_static(unit, options.positions or 12, effects=effects, a_nominal=TRIAD)


TOY = Kind(title="a toy: a triad in still poses",
           settings=f"{HERE}:ToySettings",
           acquire=f"{HERE}:toy_acquire",
           reduce=f"{HERE}:toy_readings",
           solve=f"{HERE}:toy_solve",
           nominal_frame=True,
           simulate=f"{HERE}:toy_simulation")


@pytest.fixture
def toy(monkeypatch):
    """KINDS with the toy kind registered (for this test only)."""
    monkeypatch.setitem(KINDS, "toy", TOY)
    CALLS.clear()
    return TOY


def _directions(n: int) -> np.ndarray:
    """(n, 3) well-spread unit directions (Fibonacci sphere)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + np.sqrt(5)) * i
    r = np.sqrt(1 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _toy_session(path, protocol: str = "toy", poses: int = 12, samples: int = 100) -> None:
    """A session of `protocol` holding `poses` still poses of the true triad, noisy counts."""
    rng = np.random.default_rng(3)
    spec = StreamSpec(("ax", "ay", "az"), "m/s^2", COUNTS_PER_UNIT, RATE_HZ)
    metadata = {"protocol": protocol, "unit_serial": "TOY-1", "gravity": G,
                "a_nominal": np.eye(3).tolist()}
    with SessionWriter.create(path, metadata, {"imu": spec}) as writer:
        for j, u in enumerate(_directions(poses)):
            t0 = j * (samples + 10) / RATE_HZ
            z = TRUE_A.T @ (G * u) + TRUE_BIAS + rng.normal(0, 0.002, (samples, 3))
            seq = np.arange(samples) + j * samples
            writer.event("position_start", j, time=t0)
            writer.append("imu", SampleBlock(
                counts=np.round(z * COUNTS_PER_UNIT).astype(np.int64), seq=seq,
                device_time=np.full(samples, np.nan),
                host_time=t0 + 0.1 + np.arange(samples) / RATE_HZ))
            writer.event("position_done", j, time=t0 + 0.2 + samples / RATE_HZ)


def test_station_simulate_reaches_the_toy_kind(toy, tmp_path, capsys):
    assert cli.main(["simulate", "--protocol", "toy", "--positions", "14",
                     "--out", str(tmp_path / "toy.npz")]) == 0
    assert CALLS == [("simulate", 14)]
    assert (tmp_path / "toy.npz").is_file() and (tmp_path / "toy.truth.json").is_file()
    assert "wrote" in capsys.readouterr().out


def test_station_solve_reaches_the_toy_kind(toy, tmp_path, capsys):
    _toy_session(tmp_path / "toy.h5")
    assert cli.main(["solve", str(tmp_path / "toy.h5"), "--json"]) == 0
    assert [c[0] for c in CALLS] == ["reduce", "solve"] and CALLS[1][1] == G
    cal = load(tmp_path / "toy.cal.json")
    assert cal.frame == "nominal" and cal.fit["positions"] == 12
    np.testing.assert_allclose(cal.scale_factors, np.linalg.norm(TRUE_A, axis=0), atol=2e-3)
    np.testing.assert_allclose(cal.bias, TRUE_BIAS, atol=5e-3)
    assert "toy" in cal.fit["bias_source"]
    assert json.loads(capsys.readouterr().out)["positions"] == 12


def test_station_replay_reaches_the_toy_kind(toy, tmp_path, capsys):
    _toy_session(tmp_path / "toy.h5")
    assert cli.main(["replay", str(tmp_path / "toy.h5"), "--positions", "1-10", "--name", "ten",
                     "--json"]) == 0
    assert [c[0] for c in CALLS] == ["reduce", "solve"]
    summary = json.loads(capsys.readouterr().out)
    assert summary["positions"] == 10 and summary["results"] == "ten"
    with Session.open(tmp_path / "toy.h5") as session:
        assert session.results("ten").readings.shape == (3, 10)


def test_station_record_reaches_the_toy_kind(toy, tmp_path):
    """The profile's kind resolves through KINDS (its settings, no [table]) and `record` runs the
    toy's acquire with the opened serial driver (on a pseudo-terminal no bytes flow through)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        (tmp_path / "bench.toml").write_text(
            '[bench]\nunit_serial = "TOY-1"\n\n'
            f'[imu]\nlink = "serial"\nprofile = "acc3_serial"\nport = "{os.ttyname(slave)}"\n\n'
            '[protocol]\nkind = "toy"\nposes = 9\n')
        bench = BenchProfile.load(tmp_path / "bench.toml")
        assert bench.protocol == "toy" and bench.settings == ToySettings(poses=9)
        assert bench.positions == 9 and bench.table_host is None
        np.testing.assert_array_equal(bench.layout, np.eye(3))
        summary = record(bench, tmp_path / "toy.h5", operator=None)
    finally:
        os.close(master)
        os.close(slave)
    assert [("acquire", "SerialImu", None, ToySettings(poses=9))] == CALLS
    assert summary["protocol"] == "toy" and summary["positions_done"] == 0


def test_an_unknown_kind_is_refused_naming_the_registered_kinds(tmp_path, capsys):
    with pytest.raises(UnknownKind, match="'nope' is no registered protocol kind; the kinds are "
                                          "rotary, iron, static, import"):
        lookup("nope", "reduce")
    _toy_session(tmp_path / "nope.h5", protocol="nope")
    assert cli.main(["solve", str(tmp_path / "nope.h5")]) == 2
    err = capsys.readouterr().err
    assert ("records a 'nope' session; station solve reduces rotary, iron, static, import "
            "sessions") in err
    assert cli.main(["replay", str(tmp_path / "nope.h5")]) == 2
    assert "replay reduces rotary, iron, static, import sessions" in capsys.readouterr().err


def test_a_kind_without_a_part_is_refused_naming_the_kinds_that_have_it(toy, tmp_path):
    assert "toy" not in kinds_with("resume") and kinds_with("resume") == ["rotary", "iron",
                                                                          "static"]
    with pytest.raises(UnknownKind,
                       match="'toy' session; station resume resumes rotary, iron, static sessions"):
        lookup("toy", "resume", "x.h5 holds a 'toy' session", "station resume")
    with pytest.raises(SystemExit):  # argparse: the toy has no twin
        cli.main(["twin", "--protocol", "toy"])


def test_importing_the_registry_imports_none_of_the_parts():
    parts = sorted({getattr(kind, role).partition(":")[0] for kind in KINDS.values()
                    for role in ("settings", "acquire", "resume", "reduce", "solve", "channels",
                                 "bias", "simulate", "twin") if kind.has(role)})
    code = ("import sys, json, station; before = set(sys.modules); import station.protocols; "
            "print(json.dumps(sorted(set(sys.modules) - before)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout)
    assert [m for m in loaded if m.startswith(("station", "drivers"))] == [
        "station.errors", "station.protocols"]
    heavy = {"numpy", "scipy", "h5py", "pymodbus", "serial", "can", "matplotlib"}
    assert not [m for m in loaded if m.partition(".")[0] in heavy]
    code = (f"import sys, station.protocols; print([p for p in {parts!r} if p in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert len(parts) > 10 and out.stdout.strip() == "[]"
