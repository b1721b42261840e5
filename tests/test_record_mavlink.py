"""Issue 19's acceptance for the MAVLink link: the MAVLink twin (a flight controller streaming
SCALED_IMU, pymavlink on both sides) serves the hand bench's accelerometer triad over a real pty or
UDP on 127.0.0.1; `station record` runs a free-static session against it through the bench profile
`station twin` writes, and `station solve` calibrates it within its chi2 bounds, the recovered
sensitivities and biases within their sigmas of the twin's truth."""

import io

import numpy as np
import pytest
from scipy import stats

from station import cli
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.files.calfile import load
from station.files.session import Session
from station.twin.served import HandTwin

FALSE_ALARM = 1e-3
"""Two-sided false-alarm probability of each check (Bonferroni over the values it checks)."""


@pytest.fixture(scope="module", params=["pty", "udp"])
def solved(request, tmp_path_factory):
    """A free-static session of 12 poses recorded from the MAVLink twin, solved by `station
    solve --json`: (link, truth, session path, calibration, bench profile text)."""
    tmp = tmp_path_factory.mktemp(request.param)
    with HandTwin("static", seed=11, speed=40.0, poses=12, link="mavlink",
                  udp=request.param == "udp") as twin:
        text = twin.profile_text("SN-FC")
        (tmp / "b.toml").write_text(text)
        profile = BenchProfile.load(tmp / "b.toml")
        summary = record(profile, tmp / "s.h5", ConsoleOperator(io.StringIO("\n" * 50),
                                                                  io.StringIO()))
        truth = twin.truth()
    assert twin.error is None
    assert summary["positions_done"] == profile.positions == 12
    assert cli.main(["solve", str(tmp / "s.h5"), "--json"]) == 0
    return request.param, truth, tmp / "s.h5", load(tmp / "s.cal.json", unit_serial="SN-FC"), text


def test_the_bench_profile_names_the_mavlink_link(solved):
    link, _, _, _, text = solved
    assert 'link = "mavlink"' in text and 'profile = "acc3_mavlink"' in text
    assert ('port = "udpin:127.0.0.1:' in text) == (link == "udp")


def test_the_chi2_is_within_its_bounds(solved):
    _, _, _, cal, _ = solved
    chi2, dof = cal.fit["chi2"], cal.fit["dof"]
    low, high = stats.chi2.ppf(FALSE_ALARM / 2, dof), stats.chi2.isf(FALSE_ALARM / 2, dof)
    assert dof > 0 and low <= chi2 <= high, (chi2, dof, low, high)


def test_the_calibration_matches_the_truth(solved):
    _, truth, _, cal, _ = solved
    a = np.array(truth["a"])
    z = np.concatenate([(cal.bias - truth["bias"]) / cal.bias_sigma,
                        (cal.scale_factors - np.linalg.norm(a, axis=0)) / cal.scale_factors_sigma])
    assert np.all(np.abs(z) < stats.norm.isf(FALSE_ALARM / 2 / z.size)), z
    assert cal.units == ("m/s^2",) * 3


def test_the_session_holds_the_mavlink_stream(solved):
    """The stream's counts are mG (SCALED_IMU's fixed scale), every sample numbered in turn."""
    _, _, path, _, _ = solved
    with Session.open(path) as session:
        spec, stream = session.specs["imu"], session.stream("imu")
        assert session.metadata["profiles"]["imu"]["mavlink"]["message"] == "SCALED_IMU"
        seq = np.asarray(stream.seq)
    np.testing.assert_allclose(spec.counts_per_unit, 1000 / 9.80665, rtol=1e-12)
    assert np.all(np.diff(seq) == 1)
