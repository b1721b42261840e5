"""`station diagnose` on recorded HDF5 rotary sessions (issue 7): sessions recorded on the virtual
bench through the real drivers (serial pty twin, Modbus table twin on 127.0.0.1, 40x clock),
imported array files, and the refusals.

Gap bounds: each gap statistic is a mean of N squared N(0, 1) features when the model explains
the data, so it stays below chi2.ppf(1 - q, N) / N; q = 1e-3 shared by the statistics of a
session. N per statistic follows station/diagnose/gap.py: static (n - 1) m, trend 2 n m slopes,
harmonics 12 n m coefficients, transients 2 n m means; `averaged` has the calibration's dof; a
rail side held by construction contributes one chi2(1)-like deviance.
"""

import dataclasses
import json
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy import stats

from station.diagnose import data as session_data
from station.diagnose import diagnose
from station.diagnose.effects.rate_error import encoder_reads
from station.diagnose.gap import HARMONICS
from station.errors import CalibrationInputError
from station.imports.npz import write
from station.imports.recordings import import_npz
from station.model.earth import OMEGA_EARTH
from station.model.effects import parse
from station.protocols.rotary import RotarySettings, suggested_axes
from station.session import Session, SessionWriter, StreamSpec
from station.sim.layouts import A_MODEL, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary
from station.twin.rotary_bench import VirtualBench, record_rotary

POSITIONS = 8  # Eqs. (16)-(17) need n >= 6 for 12 sensors
FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
"""Short windows; `record_rotary` raises the margins to the bench's host-latency floor."""
RATE_SPREAD = 5e-4
"""Hidden per-position rate error: about 4 sigma of one reading of M (sigma_M ~ 1.2e-4 rad/s)."""
RATE_POSITIONS = 16
"""Of the n rate factors a calibration absorbs d(d+1)/2 = 6 combinations (the random-effects
model sees n - 6): 8 positions leave 2, too few to tell the spread from other effects."""
FALSE_ALARM = 1e-3


def gap_bounds(result, d) -> dict:
    """Upper bound of each gap statistic of the final model under the white-noise hypothesis."""
    n, _, m = d.shape
    features = {"static": (n - 1) * m, "trend": 2 * n * m, "harmonics": 2 * len(HARMONICS) * n * m,
                "transients": 2 * n * m, "averaged": result.final.calibration.dof, "rails": 1}
    q = FALSE_ALARM / len(features)
    return {k: stats.chi2.ppf(1 - q, dof) / dof for k, dof in features.items()}


def record(path, positions=POSITIONS, **bench):
    with VirtualBench(seed=3, remount_time=1.0, **bench) as b:
        record_rotary(b, path, FAST, suggested_axes(positions))
    return path


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return record(tmp_path_factory.mktemp("clean") / "clean.h5")


@pytest.fixture(scope="module")
def rate_error(tmp_path_factory):
    return record(tmp_path_factory.mktemp("rate") / "rate.h5", RATE_POSITIONS,
                  rate_error={"spread": RATE_SPREAD})


@pytest.fixture(scope="module")
def rate_error_encoder(tmp_path_factory):
    return record(tmp_path_factory.mktemp("encoder") / "encoder.h5", RATE_POSITIONS,
                  rate_error={"spread": RATE_SPREAD, "encoder": True})


def check_explained(result, d):
    gaps, bounds = result.steps[-1].gap, gap_bounds(result, d)
    assert all(gaps[k] < bounds[k] for k in bounds), (gaps, bounds)


def test_effect_free_bench_session_is_called_none(clean):
    d = session_data.from_session(clean)
    assert d.shape[0] == POSITIONS and d.times.shape == d.shape[:2]
    assert np.all(np.diff(d.times, axis=1) > 0)  # the stretches keep their session order
    result = diagnose(d)
    assert result.effects == []
    check_explained(result, d)


def test_hidden_table_rate_error_is_named(rate_error):
    d = session_data.from_session(rate_error)
    assert d.shape[0] == RATE_POSITIONS
    result = diagnose(d)
    assert result.effects[:1] == ["rate_error"]
    check_explained(result, d)


def test_a_table_that_reports_its_command_keeps_the_random_effect(rate_error):
    """Even when the encoder test is forced to fire on its noise (1-sigma understated 1000 x), the
    likelihood keeps the random-effects fit of an echo table's hidden rate error."""
    d = session_data.from_session(rate_error)
    forced = dataclasses.replace(d, rate_factors_sigma=d.rate_factors_sigma * 1e-3)
    assert encoder_reads(forced)
    result = diagnose(forced)
    assert result.effects[:1] == ["rate_error"]
    assert "gain" not in result.final.fitted["rate_error"].values  # the spread, not the encoder


def test_rate_error_read_by_the_tables_encoder_is_corrected(rate_error_encoder):
    """The table's angle reads the shaft: each position's rate factor is measured from rest to
    rest, the extension's gain is 1 within its sigma, and the model explains the session."""
    d = session_data.from_session(rate_error_encoder)
    assert encoder_reads(d)
    # measured spread of the factors within 5 x its standard error (16 draws: sd / sqrt(30))
    assert abs(np.std(d.rate_factors - 1, ddof=1) - RATE_SPREAD) < 5 * RATE_SPREAD / np.sqrt(30)
    result = diagnose(d)
    assert result.effects[:1] == ["rate_error"]
    fitted = result.final.fitted["rate_error"]
    assert abs(fitted.values["gain"] - 1) < 3.29 * fitted.sigma["gain"], fitted.values["gain"]
    check_explained(result, d)


def test_cli_diagnoses_an_h5_session(clean):
    out = subprocess.run([sys.executable, "-m", "station", "diagnose", str(clean), "--json"],
                         check=False, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    doc = json.loads(out.stdout)
    assert doc["effects"] == [] and doc["positions"] == POSITIONS


@pytest.mark.parametrize("effect", ["none", "earth_rate", "latency=delay=1e-4"])
def test_imported_npz_gives_the_same_effects(tmp_path, effect):
    """The Earth's own rate (2.7 x it would be implausible), on a gyro 2.7 x quieter (and finer);
    a delay common to all sensors, which the IMU's own timing of the ramps would absorb: the
    imported session's table states are stamped at the sample instants, so they time the ramps
    (metadata table_timing)."""
    name, params = parse(effect)
    quiet = 2e-4 / OMEGA_EARTH
    unit = gyro_array(np.random.default_rng(7), A_MODEL[:, :6], fs=100.0,
                      noise_density=np.radians(0.01) / quiet,
                      counts_per_unit=quiet * 16.4 / np.radians(1.0))
    sim = simulate_rotary(unit, 20, RotaryTiming(static=4.0, moving=10.0),
                          effects={} if params is None else {name: params},
                          a_nominal=A_MODEL[:, :6])
    path, _ = write(tmp_path / "s.npz", sim)
    direct = diagnose(session_data.load(path)).effects
    imported = diagnose(session_data.from_session(import_npz(tmp_path / "s.h5", path))).effects
    assert imported == direct == ([] if params is None else [name])


# ------------------------------------------------------------------------------------ refusals


def copy_without(src, dst, drop) -> None:
    """A copy of a closed session whose IMU rows `drop` (boolean mask) are removed."""
    with h5py.File(src, "r") as f, h5py.File(dst, "w", libver=("v110", "v110")) as g:
        for key, value in f.attrs.items():
            g.attrs[key] = value
        for name in f:
            f.copy(name, g)
        imu = g["streams/imu"]
        for column in ("counts", "seq", "device_time", "host_time"):
            keep = imu[column][...][~drop]
            imu[column].resize(len(keep), axis=0)
            imu[column][...] = keep


@pytest.mark.parametrize("position, cut", [(2, "gap"), (POSITIONS - 1, "truncated")])
def test_lost_samples_inside_a_window_are_refused(clean, tmp_path, position, cut):
    with Session.open(clean) as s:
        t = s.stream("imu").host_time
        start = [e.time for e in s.events() if e.kind == "rotate_start" and e.position == position]
    i = int(np.searchsorted(t, start[0] + 1.5))
    drop = np.zeros(t.shape, bool)
    drop[i:i + 20 if cut == "gap" else None] = True
    copy_without(clean, tmp_path / "lossy.h5", drop)
    with pytest.raises(CalibrationInputError,
                       match=rf"position {position + 1}: the IMU link lost \d+ samples"):
        session_data.from_session(tmp_path / "lossy.h5")


def test_a_session_without_a_completed_position_is_refused(tmp_path):
    path = tmp_path / "empty.h5"
    spec = StreamSpec(["g1", "g2", "g3"], "rad/s", 1000.0, 200.0)
    with SessionWriter.create(path, {"protocol": "rotary", "unit_serial": "X"}, {"imu": spec}) as w:
        w.event("position_start", 0)
        w.event("static_start", 0)
        w.event("rotate_start", 0, {"angle": 0.0})
    with pytest.raises(CalibrationInputError, match="no completed position"):
        session_data.from_session(path)


def test_cli_sends_a_session_that_is_not_rotary_to_the_free_static_path(tmp_path):
    # a gyro-only session without rotary events: the free-static path says what it needs
    path = tmp_path / "static.h5"
    spec = StreamSpec(["g1", "g2", "g3"], "rad/s", 1000.0, 200.0)
    with SessionWriter.create(path, {"protocol": "static", "unit_serial": "X"}, {"imu": spec}):
        pass
    out = subprocess.run([sys.executable, "-m", "station", "diagnose", str(path)],
                         check=False, capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "one accelerometer stream (m/s^2)" in out.stderr
