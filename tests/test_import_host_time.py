"""Issue 31: a CSV whose time column is the receiving host's clock (lines stamped as they arrive,
in bunches) is imported at the device's rate, placed by the device's counter or the stated rate,
and the notes say so; a device's own regular stamps are kept as they are.

The host clock is simulated (fixed seed): a 100 Hz device whose lines reach the host after a
positive delay, in bunches (each line no earlier than the one before plus 0.2 ms), which gives
steps from 0.2 to 48 ms whose median (about 16 ms) is not the device's 10 ms."""

import json
import re

import numpy as np
import pytest

from station.cli import main
from station.session import Session

RATE = 100.0
K = 6000  # 60 s


def host_stamps(device_t: np.ndarray, seed: int = 4) -> np.ndarray:
    """Arrival times on the host of lines the device sent at `device_t`: a delay (2 ms plus an
    exponential of mean 4 ms, bursts of the USB poll), each line after the previous one."""
    rng = np.random.default_rng(seed)
    arrive = device_t + 0.002 + rng.exponential(0.004, len(device_t))
    arrive = np.ceil(arrive / 0.016) * 0.016  # a 16 ms poll delivers what has come
    out = np.empty_like(arrive)
    out[0] = arrive[0]
    for i in range(1, len(arrive)):
        out[i] = max(arrive[i], out[i - 1] + 0.0002)
    return 1_700_000_000.0 + out  # the host's epoch


@pytest.fixture(scope="module")
def recording():
    """(counter (K,), device times s (K,), host stamps s (K,), readings (K, 3) m/s^2); the counter
    skips 40 samples the link lost."""
    seq = np.r_[0:2000, 2040:K + 40]
    device_t = 12.5 + seq / RATE
    rng = np.random.default_rng(7)
    acc = np.array([0.1, -0.2, 9.8]) + 0.01 * rng.standard_normal((K, 3))
    return seq, device_t, host_stamps(device_t), acc


def write_csv(path, time, acc, seq=None) -> None:
    head = "host_t,seq,ax,ay,az" if seq is not None else "host_t,ax,ay,az"
    rows = [",".join([repr(float(time[i])), *([str(seq[i])] if seq is not None else []),
                      *(repr(float(v)) for v in acc[i])]) for i in range(len(time))]
    path.write_text("\n".join([head, *rows]) + "\n")


def imported(capsys, out, csv, *options) -> tuple:
    """(exit code, the --json report, stderr) of `station import csv`."""
    capsys.readouterr()
    code = main(["import", "csv", str(out), str(csv), "--time", "host_t", "--stream",
                 "acc=ax,ay,az", "--unit", "acc=m/s^2", "--json", *map(str, options)])
    captured = capsys.readouterr()
    return code, json.loads(captured.out) if code == 0 else None, captured.err


def stream(path) -> tuple:
    with Session.open(path) as s:
        data = s.stream("acc")
        return data.device_time, data.seq, s.specs["acc"].rate_hz


def test_the_simulated_stamps_are_a_hosts(recording):
    _, _, host, _ = recording
    steps = np.diff(host)
    assert steps.min() < 0.0005 and steps.max() > 0.03
    assert 1 / np.median(steps) < 0.95 * RATE  # the median step says a wrong rate


def test_host_stamps_with_a_counter_are_placed_on_the_device_clock(recording, tmp_path, capsys):
    seq, _, host, acc = recording
    csv = tmp_path / "host.csv"
    write_csv(csv, host, acc, seq)
    code, report, err = imported(capsys, tmp_path / "c.h5", csv, "--index", "seq")
    assert code == 0, err
    # the least-squares slope over 60 s of delays of sd ~5 ms: sd ~ 5e-3 / (60 sqrt(K / 12)),
    # 4e-6 relative; 1e-4 is 25 sd
    assert report["streams"]["acc"]["rate_hz"] == pytest.approx(RATE, rel=1e-4)
    note = report["notes"][-1]
    assert "the time stamps look like a host's clock, not the device's" in note
    assert "placed by the counter column at 100" in note and "40 samples missing" in note
    t, got_seq, rate = stream(tmp_path / "c.h5")
    np.testing.assert_array_equal(got_seq, seq)
    # float64 seconds since 1970 step by 2.4e-7 s: two of those per difference
    np.testing.assert_allclose(np.diff(t), np.diff(seq) / rate, rtol=0, atol=4.8e-7)

    write_csv(csv, host, acc, seq % 256)  # a uint8 counter: wraps 23 times
    code, report, err = imported(capsys, tmp_path / "w.h5", csv, "--index", "seq")
    assert code == 0, err
    assert any("the counter wraps at 256 (23 times): unwrapped" in n for n in report["notes"])
    np.testing.assert_array_equal(stream(tmp_path / "w.h5")[1], seq)

    restart = seq.copy()
    restart[3000:] -= restart[3000]  # the device restarted: not a wrap
    write_csv(csv, host, acc, restart)
    code, _, err = imported(capsys, tmp_path / "x.h5", csv, "--index", "seq")
    assert code == 2 and "the counter does not increase after sample 3000" in err

    write_csv(csv, host, acc, seq)
    code, report, _ = imported(capsys, tmp_path / "f.h5", csv, "--index", "seq", "--fs", 100)
    assert code == 0 and report["streams"]["acc"]["rate_hz"] == RATE
    assert "at 100 Hz (stated)" in report["notes"][-1]


def test_host_stamps_with_a_stated_rate(recording, tmp_path, capsys):
    _, _, host, acc = recording
    csv = tmp_path / "host.csv"
    write_csv(csv, host, acc)
    code, report, _ = imported(capsys, tmp_path / "r.h5", csv, "--fs", 100)
    assert code == 0 and report["streams"]["acc"]["rate_hz"] == RATE
    assert "the rows placed at the stated 100 Hz instead" in report["notes"][-1]
    # 40 lost; the host's delays at the two ends (up to ~30 ms) blur the count by a few
    lost = re.search(r"about (\d+) samples lost, or a wrong --fs", report["notes"][-1])
    assert lost and 37 <= int(lost[1]) <= 43
    t, _, _ = stream(tmp_path / "r.h5")
    np.testing.assert_allclose(np.diff(t), 1 / RATE, rtol=0, atol=4.8e-7)  # 2 ulp of 1.7e9 s


def test_host_stamps_alone_give_the_rate_of_their_mean_step(recording, tmp_path, capsys):
    _, device_t, host, acc = recording
    csv = tmp_path / "host.csv"
    write_csv(csv, host, acc)
    code, report, _ = imported(capsys, tmp_path / "h.h5", csv)
    assert code == 0
    # the 40 lost samples stretch the mean step: K - 1 steps over the device's span
    expected = (K - 1) / (device_t[-1] - device_t[0])
    assert report["streams"]["acc"]["rate_hz"] == pytest.approx(expected, rel=5e-4)
    assert "the rate" in report["notes"][-1] and "--index COLUMN" in report["notes"][-1]

    back = host.copy()
    back[3000:] -= 0.5  # the host's clock stepped back (NTP)
    write_csv(csv, back, acc)
    code, _, err = imported(capsys, tmp_path / "b.h5", csv)
    assert code == 2 and "1 not forward" in err and "--index COLUMN" in err


def test_device_stamps_are_kept_as_they_are(recording, tmp_path, capsys):
    seq, device_t, _, acc = recording
    jitter = np.random.default_rng(2).normal(0, 2e-5, K)  # 20 us on 10 ms: a device's clock
    csv = tmp_path / "device.csv"
    write_csv(csv, device_t + jitter, acc)
    code, report, _ = imported(capsys, tmp_path / "d.h5", csv)
    assert code == 0 and not any("clock" in n for n in report["notes"])
    t, _, rate = stream(tmp_path / "d.h5")
    np.testing.assert_array_equal(t, device_t + jitter)
    assert rate == 1 / np.median(np.diff(device_t + jitter))
