"""Issue 19, imports: PX4 ULog (pyulog) and ArduPilot DataFlash (pymavlink) logs, and Kalibr/EuRoC
IMU CSVs, into sessions whose samples equal the logged numbers bit for bit, which `station solve`
calibrates as other imports; and the awkward logs a lab produces (two IMUs, a cut log, repeated or
backward time stamps, an empty IMU topic, another vehicle's log without IMU messages).

The logs are written from the formats' public specifications (tests/flightlogs.py), and once
through pyulog's own writer (ULog.write_ulog); the readings are the hand-held free-static
simulation of tests/hand.py (known sensitivity and bias)."""

import json

import numpy as np
import pytest
from flightlogs import (
    IMU_FORMAT_MS,
    SENSOR_ACCEL,
    SENSOR_COMBINED,
    VEHICLE_IMU,
    batch_log,
    dataflash,
    df_fmt,
    df_message,
    records,
    ulog,
)
from hand import A_TRUE, B_TRUE, hand_session
from test_import_solve import station_with_errors as station

from station.calfiles.calfile import load
from station.session import Session

DEVICE_ID = 2490378  # an ICM-20602 on SPI bus 1, as PX4 encodes it
T0_US = 3_000_000


@pytest.fixture(scope="module")
def hand():
    """(time stamps us (K,), readings float32 (K, 6): acc m/s^2 then gyro rad/s) of the hand
    recording, and a second IMU's (another seed, same times)."""
    x, _ = hand_session(seed=3)
    other, _ = hand_session(seed=8)
    t = T0_US + 10_000 * np.arange(len(x), dtype=np.uint64) + np.uint64(37)
    return t, x.astype(np.float32), other[: len(x)].astype(np.float32)


def raw_topics(t, x, multi_id=0, temperature=41.5):
    """sensor_accel and sensor_gyro rows of instance `multi_id` (time stamps `t`, readings x)."""
    k = len(t)
    common = dict(timestamp=t + np.uint64(120), timestamp_sample=t,
                  device_id=np.full(k, DEVICE_ID + multi_id), temperature=np.full(k, temperature))
    return [("sensor_accel", SENSOR_ACCEL, multi_id,
             records(SENSOR_ACCEL, x=x[:, 0], y=x[:, 1], z=x[:, 2], **common)),
            ("sensor_gyro", SENSOR_ACCEL, multi_id,
             records(SENSOR_ACCEL, x=x[:, 3], y=x[:, 4], z=x[:, 5], **common))]


def samples(path) -> dict:
    """{stream: (time stamps s, SI values)} of a session, and its import metadata."""
    with Session.open(path) as s:
        out = {name: (s.stream(name).device_time, s.stream(name).to_si()) for name in s.specs}
        return out, s.metadata["import"]


def assert_equal_to_log(path, t, x):
    """The session's streams acc and gyro are the logged float32 numbers, bit for bit, at the
    logged time stamps."""
    got, _ = samples(path)
    for name, cols in (("acc", slice(0, 3)), ("gyro", slice(3, 6))):
        time, values = got[name]
        np.testing.assert_array_equal(values, x[:, cols].astype(np.float64))
        np.testing.assert_array_equal(time, t.astype(np.int64) * 1e-6)


# ---------------------------------------------------------------------------------------- ULog


def test_ulog_samples_equal_the_logged_ones_per_instance(hand, tmp_path, capsys):
    t, x, other = hand
    log = tmp_path / "two.ulg"
    log.write_bytes(ulog(raw_topics(t, x, 0) + raw_topics(t, other, 1, temperature=45.0)))
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "a.h5", log, "--json")
    assert code == 0
    assert json.loads(out)["streams"]["acc"]["samples"] == len(t)
    assert any(f"acc from topic sensor_accel instance 0, device id {DEVICE_ID} (read with "
               "pyulog " in note for note in json.loads(out)["notes"])
    assert_equal_to_log(tmp_path / "a.h5", t, x)
    _, meta = samples(tmp_path / "a.h5")
    assert meta["format"] == "ulog" and meta["reader"].startswith("pyulog ")
    assert meta["origin"]["acc"] == {"topic": "sensor_accel", "instance": 0,
                                     "time": "timestamp_sample", "device_id": DEVICE_ID,
                                     "temperature": {"first": 41.5, "min": 41.5, "mean": 41.5,
                                                     "max": 41.5}}
    assert meta["origin"]["gyro"]["topic"] == "sensor_gyro"

    code, _, _ = station(capsys, "import", "ulog", tmp_path / "b.h5", log, "--instance", "1")
    assert code == 0
    assert_equal_to_log(tmp_path / "b.h5", t, other)
    assert samples(tmp_path / "b.h5")[1]["origin"]["acc"]["device_id"] == DEVICE_ID + 1

    code, _, err = station(capsys, "import", "ulog", tmp_path / "c.h5", log, "--instance", "2")
    assert code == 2 and not (tmp_path / "c.h5").exists()
    assert "no IMU candidate with instance 2" in err
    assert f"sensor_accel instance 1: {len(t)} samples" in err and "--instance" in err


def test_a_ulog_written_by_pyulog_imports_the_same(hand, tmp_path, capsys):
    from pyulog import ULog

    t, x, _ = hand
    first = tmp_path / "spec.ulg"
    first.write_bytes(ulog(raw_topics(t[:2000], x[:2000])))
    ULog(str(first)).write_ulog(str(tmp_path / "pyulog.ulg"))  # the library's own writer
    # the writer from the specification writes what pyulog's writer does, byte for byte
    assert (tmp_path / "pyulog.ulg").read_bytes() == first.read_bytes()
    code, _, _ = station(capsys, "import", "ulog", tmp_path / "p.h5", tmp_path / "pyulog.ulg")
    assert code == 0
    assert_equal_to_log(tmp_path / "p.h5", t[:2000], x[:2000])


def test_sensor_combined_when_the_raw_topics_are_absent(hand, tmp_path, capsys):
    t, x, _ = hand
    k = 500
    relative = np.full(k, -1800, np.int32)
    relative[7] = 2**31 - 1  # a sample without an accelerometer part
    rows = records(SENSOR_COMBINED, timestamp=t[:k], gyro_rad=x[:k, 3:],
                   accelerometer_timestamp_relative=relative, accelerometer_m_s2=x[:k, :3])
    empty = records(SENSOR_ACCEL, timestamp=t[:0])
    log = tmp_path / "combined.ulg"
    log.write_bytes(ulog([("sensor_accel", SENSOR_ACCEL, 0, empty),  # subscribed, never logged
                          ("sensor_combined", SENSOR_COMBINED, 0, rows)]))
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "c.h5", log, "--json")
    assert code == 0
    got, meta = samples(tmp_path / "c.h5")
    keep = np.arange(k) != 7
    np.testing.assert_array_equal(got["gyro"][1], x[:k, 3:].astype(float))
    np.testing.assert_array_equal(got["gyro"][0], t[:k].astype(np.int64) * 1e-6)
    np.testing.assert_array_equal(got["acc"][1], x[:k, :3][keep].astype(float))
    np.testing.assert_array_equal(got["acc"][0], (t[:k].astype(np.int64) - 1800)[keep] * 1e-6)
    assert meta["origin"]["acc"]["topic"] == "sensor_combined"
    assert any("1 samples without an accelerometer part" in n for n in json.loads(out)["notes"])


def combined_rows(t, x):
    """sensor_combined rows at time stamps `t` of readings x (acc then gyro), the accelerometer
    sampled with the gyro."""
    return records(SENSOR_COMBINED, timestamp=t, gyro_rad=x[:, 3:],
                   accelerometer_timestamp_relative=np.zeros(len(t), np.int32),
                   accelerometer_m_s2=x[:, :3])


def test_the_fastest_imu_topics_are_chosen_and_the_candidates_said(hand, tmp_path, capsys):
    """PX4's default profile: sensor_accel/sensor_gyro at 1 Hz beside sensor_combined at 250 Hz
    in the same log. The 250 Hz family is imported; --topic takes the other; the notes list both
    with their rates."""
    _, x, _ = hand
    k = 7800  # 31.2 s at 250 Hz
    fast = T0_US + 4000 * np.arange(k, dtype=np.uint64)
    slow = np.arange(0, k, 250)  # PX4 logs the raw topics at 1 Hz by default: 32 samples
    log = tmp_path / "default.ulg"
    log.write_bytes(ulog(raw_topics(fast[slow], x[slow])
                         + [("sensor_combined", SENSOR_COMBINED, 0, combined_rows(fast, x[:k]))]))
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "d.h5", log, "--json")
    assert code == 0
    report = json.loads(out)
    assert report["streams"]["acc"]["samples"] == k and report["streams"]["acc"]["rate_hz"] == 250
    said = next(n for n in report["notes"] if "IMU candidates" in n)
    assert "sensor_accel+sensor_gyro instance 0: 32 samples at 1 Hz" in said
    assert "sensor_combined instance 0: 7800 samples at 250 Hz" in said
    assert "chosen sensor_combined instance 0 (the highest rate" in said
    np.testing.assert_array_equal(samples(tmp_path / "d.h5")[0]["gyro"][1], x[:k, 3:])

    code, out, _ = station(capsys, "import", "ulog", tmp_path / "s.h5", log, "--topic",
                           "sensor_gyro", "--json")
    assert code == 0
    assert json.loads(out)["streams"]["gyro"]["samples"] == len(slow)
    assert samples(tmp_path / "s.h5")[1]["origin"]["gyro"]["topic"] == "sensor_gyro"
    code, _, err = station(capsys, "solve", tmp_path / "s.h5")  # 1 Hz: no still detection
    assert code == 2 and "samples at 1 Hz" in err and "--topic sensor_combined" in err

    code, _, err = station(capsys, "import", "ulog", tmp_path / "v.h5", log, "--topic",
                           "vehicle_imu")
    assert code == 2 and "no IMU candidate with topic vehicle_imu (candidates: " in err
    code, _, err = station(capsys, "import", "ulog", tmp_path / "w.h5", log, "--topic", "gps")
    assert code == 2 and "Give one of sensor_accel, sensor_gyro" in err
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "x.h5", log, "--topic",
                           "sensor_gyro")
    assert code == 2 and "--topic is for PX4 ULog files" in err


def test_equal_rates_prefer_the_raw_sensors(hand, tmp_path, capsys):
    t, x, _ = hand
    k = 1000
    log = tmp_path / "both.ulg"
    log.write_bytes(ulog(raw_topics(t[:k], x[:k])
                         + [("sensor_combined", SENSOR_COMBINED, 0, combined_rows(t[:k], x[:k]))]))
    assert station(capsys, "import", "ulog", tmp_path / "b.h5", log)[0] == 0
    assert samples(tmp_path / "b.h5")[1]["origin"]["acc"]["topic"] == "sensor_accel"


def test_vehicle_imu_rates_from_the_integrated_deltas(hand, tmp_path, capsys):
    t, x, _ = hand
    k = 400
    dt = np.full(k, 4998, np.uint16)  # about 5 ms integration
    dt[3] = 0
    d_angle, d_velocity = (x[:k, 3:] * np.float32(0.004998)), (x[:k, :3] * np.float32(0.004998))
    rows = records(VEHICLE_IMU, timestamp=t[:k], timestamp_sample=t[:k],
                   accel_device_id=np.full(k, DEVICE_ID), gyro_device_id=np.full(k, 7),
                   delta_angle=d_angle, delta_velocity=d_velocity, delta_angle_dt=dt,
                   delta_velocity_dt=dt)
    log = tmp_path / "vimu.ulg"
    log.write_bytes(ulog([("vehicle_imu", VEHICLE_IMU, 0, rows)]))
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "v.h5", log, "--json")
    assert code == 0
    got, meta = samples(tmp_path / "v.h5")
    keep = np.arange(k) != 3
    rate = d_angle[keep].astype(float) / 0.004998
    # divided rates are not float32 numbers: rounded to 2^-k, k the largest keeping the counts
    # below 2^53 (|rate| < 2^-6 here: k = 59, half a count 2^-60)
    assert np.abs(rate).max() < 2.0**-6
    np.testing.assert_allclose(got["gyro"][1], rate, rtol=0, atol=2.0**-60)
    assert meta["origin"]["gyro"] == {"topic": "vehicle_imu", "instance": 0,
                                      "integrated": "delta_angle", "device_id": 7}
    assert any("rounded to 2^-" in n for n in json.loads(out)["notes"])


def test_a_ulog_cut_in_a_message_keeps_the_samples_before(hand, tmp_path, capsys):
    t, x, _ = hand
    whole = ulog(raw_topics(t[:1000], x[:1000]))
    log = tmp_path / "cut.ulg"
    log.write_bytes(whole[: len(whole) - 20])  # the last data message cut in its middle
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "cut.h5", log, "--json")
    assert code == 0
    assert any("ends inside a message (" in n for n in json.loads(out)["notes"])
    got, _ = samples(tmp_path / "cut.h5")
    # messages go in time order, gyro after accel: the last gyro sample is the one cut
    np.testing.assert_array_equal(got["acc"][1], x[:1000, :3].astype(float))
    np.testing.assert_array_equal(got["gyro"][1], x[:999, 3:].astype(float))
    (tmp_path / "whole.ulg").write_bytes(whole)
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "whole.h5",
                           tmp_path / "whole.ulg", "--json")
    assert code == 0 and not any("ends inside" in n for n in json.loads(out)["notes"])

    log.write_bytes(whole[:10])  # cut in the header
    code, _, err = station(capsys, "import", "ulog", tmp_path / "head.h5", log)
    assert code == 2 and "not a ULog file pyulog can read" in err and "cut.ulg" in err


def test_repeated_and_backward_time_stamps(hand, tmp_path, capsys):
    t, x, _ = hand
    k = 600
    twice = np.insert(np.arange(k), 100, 99)  # message 99 logged twice
    log = tmp_path / "twice.ulg"
    log.write_bytes(ulog(raw_topics(t[twice], x[twice])))
    code, out, _ = station(capsys, "import", "ulog", tmp_path / "twice.h5", log, "--json")
    assert code == 0
    assert_equal_to_log(tmp_path / "twice.h5", t[:k], x[:k])
    assert any("1 samples logged twice" in n for n in json.loads(out)["notes"])

    clash = x[twice].copy()
    clash[100, 0] += 1.0  # the same time stamp, another value
    log.write_bytes(ulog(raw_topics(t[twice], clash)))
    code, _, err = station(capsys, "import", "ulog", tmp_path / "clash.h5", log)
    assert code == 2 and not (tmp_path / "clash.h5").exists()
    assert "topic sensor_accel instance 0: the time stamp repeats with other values after " \
           "sample 100" in err and "ulog2csv" in err

    back = t[:k].copy()
    back[300:] -= np.uint64(5_000_000)  # the sensor restarted its clock
    log.write_bytes(ulog(raw_topics(back, x[:k]), in_time_order=False))
    code, _, err = station(capsys, "import", "ulog", tmp_path / "back.h5", log)
    assert code == 2 and "goes backwards after sample 300" in err


def test_nan_samples_are_refused(hand, tmp_path, capsys):
    t, x, _ = hand
    bad = x[:300].copy()
    bad[50:53, 4] = np.nan
    log = tmp_path / "nan.ulg"
    log.write_bytes(ulog(raw_topics(t[:300], bad)))
    code, _, err = station(capsys, "import", "ulog", tmp_path / "nan.h5", log)
    assert code == 2 and "sensor_gyro instance 0: 3 samples hold NaN" in err


def test_a_ulog_without_imu_topics_is_refused_listing_what_it_holds(tmp_path, capsys):
    gps = [("uint64_t", "timestamp"), ("int32_t", "lat"), ("int32_t", "lon")]
    t = np.arange(1, 51, dtype=np.uint64) * 100_000
    empty = records(SENSOR_ACCEL, timestamp=t[:0])
    log = tmp_path / "rover.ulg"
    log.write_bytes(ulog([("vehicle_gps_position", gps, 0, records(gps, timestamp=t)),
                          ("sensor_accel", SENSOR_ACCEL, 0, empty)]))
    code, _, err = station(capsys, "import", "ulog", tmp_path / "r.h5", log)
    assert code == 2
    assert "holds no IMU samples (sensor_accel: no samples)" in err
    assert "SDLOG_PROFILE" in err


def test_the_streams_of_a_log_are_not_spelled_out(hand, tmp_path, capsys):
    t, x, _ = hand
    log = tmp_path / "a.ulg"
    log.write_bytes(ulog(raw_topics(t[:100], x[:100])))
    code, _, err = station(capsys, "import", "ulog", tmp_path / "a.h5", log, "--stream", "acc=x")
    assert code == 2 and "takes the IMU's streams, units and time stamps from the log; leave " \
                         "out --stream" in err
    code, _, err = station(capsys, "import", "csv", tmp_path / "a.h5", log, "--instance", "1")
    assert code == 2 and "--instance is for flight-controller logs" in err
    assert not (tmp_path / "a.h5").exists()


def test_a_logger_gap_is_a_gap_in_the_sample_numbers(hand, tmp_path, capsys):
    t, x, _ = hand
    keep = np.r_[0:300, 340:600]  # 40 samples the logger dropped
    jitter = np.random.default_rng(5).integers(-900, 900, len(keep)).astype(np.int64)
    times = (t[keep].astype(np.int64) + jitter).astype(np.uint64)  # +-0.9 ms on 10 ms steps
    log = tmp_path / "gap.ulg"
    log.write_bytes(ulog(raw_topics(times, x[keep])))
    assert station(capsys, "import", "ulog", tmp_path / "gap.h5", log)[0] == 0
    with Session.open(tmp_path / "gap.h5") as s:
        seq = s.stream("acc").seq
    np.testing.assert_array_equal(seq, keep)  # the row numbers where no sample was dropped


def test_a_file_that_is_no_log_is_refused(tmp_path, capsys):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00\x01" * 5000)
    code, _, err = station(capsys, "import", "ulog", tmp_path / "j.h5", junk)
    assert code == 2 and "not a ULog file" in err
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "j.h5", junk)
    assert code == 2 and "holds no IMU messages" in err and "messages: none" in err


@pytest.mark.parametrize("fmt", ["ulog", "dataflash", "batch"])
def test_damaged_logs_import_or_are_refused_by_name(hand, tmp_path, fmt):
    """Flipped bytes, cuts and overwritten runs (90 damaged copies, a fixed seed): each log is
    imported or refused with a CalibrationInputError naming it; nothing else escapes."""
    from station.errors import CalibrationInputError
    from station.imports.dataflash import import_dataflash
    from station.imports.ulog import import_ulog

    t, x, _ = hand
    logs = {"ulog": ulog(raw_topics(t[:300], x[:300])),
            "dataflash": dataflash({0: imu_rows(t[:300], x[:300])}, params=[("INS_ACC_ID", 5)]),
            "batch": batch_log([(0, 0, 128, 1000, 1000.0, np.ones((40, 3), np.int16)),
                                (1, 0, 938, 50_000, 1000.0, np.ones((40, 3), np.int16))])}
    read = {"ulog": import_ulog, "dataflash": import_dataflash,
            "batch": lambda out, path: import_dataflash(out, path, batch=True)}[fmt]
    rng = np.random.default_rng(11)
    outcomes = set()
    for trial in range(90):
        data = bytearray(logs[fmt])
        if trial % 3 == 0:
            for at in rng.integers(0, len(data), rng.integers(1, 20)):
                data[at] = rng.integers(0, 256)
        elif trial % 3 == 1:
            data = data[:rng.integers(0, len(data))]
        else:
            at = rng.integers(0, min(len(data), 3000))
            data[at:at + 8] = rng.integers(0, 256, 8).astype(np.uint8).tobytes()
        path = tmp_path / f"damaged{trial}.log"
        path.write_bytes(bytes(data))
        try:
            read(tmp_path / f"damaged{trial}.h5", path)
            outcomes.add("imported")
        except CalibrationInputError as exc:
            assert path.name in str(exc)
            outcomes.add("refused")
    assert outcomes == {"imported", "refused"}


# ----------------------------------------------------------------------------------- DataFlash


def imu_rows(t, x, temperature=39.25):
    """One instance's IMU rows for tests/flightlogs.dataflash: time, gyro, acc, temperature."""
    return (t.astype(np.int64), x[:, 3:], x[:, :3], temperature)


@pytest.mark.parametrize("old", [False, True], ids=["IMU-with-I", "IMU-IMU2"])
def test_dataflash_samples_equal_the_logged_ones_per_instance(hand, tmp_path, capsys, old):
    t, x, other = hand
    k = 3000
    log = tmp_path / "two.bin"
    log.write_bytes(dataflash({0: imu_rows(t[:k], x[:k]), 1: imu_rows(t[:k], other[:k], 44.0)},
                              old=old, params=[("INS_ACC_ID", DEVICE_ID),
                                               ("INS_GYR2_ID", DEVICE_ID + 1)]))
    code, _, _ = station(capsys, "import", "dataflash", tmp_path / "a.h5", log)
    assert code == 0
    assert_equal_to_log(tmp_path / "a.h5", t[:k], x[:k])
    _, meta = samples(tmp_path / "a.h5")
    assert meta["format"] == "dataflash" and meta["reader"].startswith("pymavlink ")
    assert meta["origin"]["acc"] == {"message": "IMU", "instance": 0, "time": "TimeUS",
                                     "device_id": DEVICE_ID,
                                     "temperature": {"first": 39.25, "min": 39.25,
                                                     "mean": 39.25, "max": 39.25}}
    code, _, _ = station(capsys, "import", "dataflash", tmp_path / "b.h5", log, "--instance", "1")
    assert code == 0
    assert_equal_to_log(tmp_path / "b.h5", t[:k], other[:k])
    origin = samples(tmp_path / "b.h5")[1]["origin"]
    assert origin["gyro"]["device_id"] == DEVICE_ID + 1 and "device_id" not in origin["acc"]
    assert origin["gyro"]["message"] == ("IMU2" if old else "IMU")

    code, _, err = station(capsys, "import", "dataflash", tmp_path / "c.h5", log,
                           "--instance", "3")
    assert code == 2
    assert f"no IMU instance 3 (instance 0: {k} messages, instance 1: {k} messages)" in err


def test_a_dataflash_log_before_3_3_with_milliseconds(hand, tmp_path, capsys):
    """ArduPilot before 3.3 logged IMU and IMU2 at TimeMS (uint32 milliseconds), 50 Hz."""
    _, x, other = hand
    k = 2000
    ms = 61_234 + 20 * np.arange(k)
    chars, columns = IMU_FORMAT_MS
    body = [dataflash(None), df_fmt(120, "IMU", chars, columns),
            df_fmt(121, "IMU2", chars, columns)]
    for i in range(k):
        for type_id, y in ((120, x), (121, other)):
            body.append(df_message(type_id, chars, (ms[i], *y[i, 3:], *y[i, :3], 0, 0)))
    log = tmp_path / "ac32.bin"
    log.write_bytes(b"".join(body))
    for instance, y in ((0, x), (1, other)):
        h5 = tmp_path / f"ac32-{instance}.h5"
        code, out, err = station(capsys, "import", "dataflash", h5, log, "--instance", instance,
                                 "--json")
        assert code == 0, err
        report = json.loads(out)
        assert report["streams"]["acc"]["rate_hz"] == 50
        assert any("time TimeMS: milliseconds" in n for n in report["notes"])
        assert_equal_to_log(h5, ms * 1000, y[:k])
        assert samples(h5)[1]["origin"]["gyro"] == {"message": ["IMU", "IMU2"][instance],
                                                    "instance": instance, "time": "TimeMS"}


def test_a_dataflash_log_cut_in_a_message_keeps_the_samples_before(hand, tmp_path, capsys):
    t, x, _ = hand
    whole = dataflash({0: imu_rows(t[:800], x[:800])})
    log = tmp_path / "cut.bin"
    log.write_bytes(whole[:-17])
    code, out, _ = station(capsys, "import", "dataflash", tmp_path / "cut.h5", log, "--json")
    assert code == 0
    assert_equal_to_log(tmp_path / "cut.h5", t[:799], x[:799])
    assert any("ends inside a message" in n for n in json.loads(out)["notes"])


def test_dataflash_repeated_messages_and_backward_time(hand, tmp_path, capsys):
    t, x, _ = hand
    k = 500
    twice = np.insert(np.arange(k), 200, 199)
    log = tmp_path / "twice.bin"
    log.write_bytes(dataflash({0: imu_rows(t[twice], x[twice])}))
    code, out, _ = station(capsys, "import", "dataflash", tmp_path / "twice.h5", log, "--json")
    assert code == 0
    assert_equal_to_log(tmp_path / "twice.h5", t[:k], x[:k])
    assert any("message IMU instance 0: 1 samples logged twice" in n
               for n in json.loads(out)["notes"])

    back = t[:k].astype(np.int64)
    back[250:] -= 2_000_000
    # written in file order (a board that rebooted mid-log), not sorted by time
    body = b"".join(df_message(120, "QBffffffIIfBBHH", (back[i], 0, *x[i, 3:], *x[i, :3],
                                                         0, 0, 40.0, 1, 1, 400, 400))
                    for i in range(k))
    log.write_bytes(dataflash({}) + body)
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "back.h5", log)
    assert code == 2 and "message IMU instance 0: the time stamp goes backwards after sample " \
                         "250" in err


def test_a_dataflash_log_without_imu_messages_is_refused(tmp_path, capsys):
    gps = [(i * 200_000, 3, 12, 515000000 + i, -1000000 - i) for i in range(40)]
    extra = [(130, "GPS", "QBBii", "TimeUS,Status,NSats,Lat,Lng", gps)]
    log = tmp_path / "tracker.bin"
    log.write_bytes(dataflash(None, extra=extra))  # another vehicle's log: no IMU at all
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "t.h5", log)
    assert code == 2 and "holds no IMU messages (messages: GPS 40" in err and "LOG_BITMASK" in err

    log.write_bytes(dataflash({}, extra=extra))  # IMU defined, never logged
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "e.h5", log)
    assert code == 2 and "defined but empty: IMU" in err


def test_a_foreign_imu_message_is_refused_by_field(tmp_path, capsys):
    log = tmp_path / "odd.bin"
    log.write_bytes(dataflash(None) + df_fmt(120, "IMU", "QBfff", "TimeUS,I,GyrX,GyrY,GyrZ")
                    + b"".join(df_message(120, "QBfff", (i * 2500, 0, 0.1, 0.2, 0.3))
                               for i in range(10)))
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "o.h5", log)
    assert code == 2 and "message IMU has no numeric AccX, AccY, AccZ" in err


def test_the_batch_sampler_counts_at_their_own_rate(hand, tmp_path, capsys):
    t, x, other = hand
    mul = {0: 128, 1: 938}  # ArduPilot's int16 multipliers: 32767 / 26 g, 32767 / 2000 deg/s
    batches, expected = [], {0: [], 1: []}
    for b in range(3):
        for kind, cols in ((0, slice(0, 3)), (1, slice(3, 6))):
            counts = np.round(x[100 * b:100 * b + 80, cols] * mul[kind]).astype(np.int16)
            start = 2_000_000 + 1_000_000 * b + 200_000 * kind
            batches.append((kind, 0, mul[kind], start, 1000.0, counts))
            expected[kind].append((start, counts))
    batches.append((0, 1, 128, 9_000_000, 1000.0, np.ones((40, 3), np.int16)))  # instance 1
    log = tmp_path / "isb.bin"
    # the second gyro batch (batch number 3) lost its middle block: left out
    log.write_bytes(batch_log(batches, drop={(3, 1)}))
    code, out, _ = station(capsys, "import", "dataflash", tmp_path / "isb.h5", log, "--batch",
                           "--json")
    assert code == 0
    notes = json.loads(out)["notes"]
    assert any("batch sampler gyro instance 0: 1 of 3 batches left out" in n for n in notes)
    got, meta = samples(tmp_path / "isb.h5")
    for kind, name in ((0, "acc"), (1, "gyro")):
        kept = [e for i, e in enumerate(expected[kind]) if (kind, i) != (1, 1)]
        counts = np.concatenate([c for _, c in kept])
        time = np.concatenate([(s + np.arange(80) * 1e6 / 1000.0) * 1e-6 for s, _ in kept])
        np.testing.assert_array_equal(got[name][1], counts / mul[kind])  # counts / multiplier
        np.testing.assert_allclose(got[name][0], time, rtol=0, atol=1e-9)
        assert meta["origin"][name]["batches"] == len(kept)

    code, _, err = station(capsys, "import", "dataflash", tmp_path / "i3.h5", log, "--batch",
                           "--instance", "3")
    assert code == 2 and "no batch sampler instance 3 (instances: 0, 1)" in err
    code, _, err = station(capsys, "import", "dataflash", tmp_path / "no.h5", tmp_path / "isb.bin")
    assert code == 2 and "holds no IMU messages" in err  # without --batch: the IMU messages


# ------------------------------------------------------------------------- calibrating the logs


@pytest.mark.parametrize("fmt", ["ulog", "dataflash"])
def test_station_solve_calibrates_a_logged_static_recording(hand, tmp_path, capsys, fmt):
    t, x, _ = hand
    log = tmp_path / f"hand.{fmt}"
    log.write_bytes(ulog(raw_topics(t, x)) if fmt == "ulog" else
                    dataflash({0: imu_rows(t, x)}))
    h5 = tmp_path / "hand.h5"
    assert station(capsys, "import", fmt, h5, log)[0] == 0
    code, out, err = station(capsys, "solve", h5, "--json")
    assert code == 0, err  # 0: the fit passed the quality gate (chi2, outliers)
    summary = json.loads(out)
    assert summary["poses"] == 15 and summary["rejected"] == []
    assert summary["status"] == "good" and summary["status_reasons"] == []  # chi2 within bounds
    cal = load(summary["calibration"])
    # within 4 sigma of the simulator's truth (6 values, normal errors)
    scale_err = (cal.scale_factors - np.linalg.norm(A_TRUE, axis=1)) / cal.scale_factors_sigma
    bias_err = (cal.bias - B_TRUE) / cal.bias_sigma
    assert np.all(np.abs(scale_err) < 4) and np.all(np.abs(bias_err) < 4), (scale_err, bias_err)


@pytest.mark.parametrize("fmt", ["ulog", "dataflash"])
def test_station_solve_calibrates_a_logged_gyro_from_the_turns(tmp_path, capsys, fmt):
    from test_gyro_carry import G, hand_recording, true_sensitivity

    a_true = true_sensitivity(7)
    gyro, acc, _ = hand_recording(11, a_true)
    t = T0_US + 10_000 * np.arange(len(acc), dtype=np.uint64)
    x = np.hstack([acc, gyro]).astype(np.float32)
    log = tmp_path / f"turned.{fmt}"
    log.write_bytes(ulog(raw_topics(t, x)) if fmt == "ulog" else
                    dataflash({0: imu_rows(t, x)}))
    h5 = tmp_path / "turned.h5"
    assert station(capsys, "import", fmt, h5, log)[0] == 0
    # acc and gyro on the same samples (one DataFlash message; ULog topics sampled together):
    # the gyro from the turns between the poses
    code, out, err = station(capsys, "solve", h5, "--stream", "gyro", "--magnitude", G,
                             "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["poses"] == 24 and summary["status"] == "good"
    cal = load(summary["calibration"])
    assert cal.sensors == ("gyro1", "gyro2", "gyro3") and cal.units == ("rad/s",) * 3
    z = (cal.scale_factors - np.linalg.norm(a_true, axis=0)) / cal.scale_factors_sigma
    assert np.all(np.abs(z) < 4.5), z  # 3 normal errors: fails with p ~ 2e-5


# ---------------------------------------------------------------------------------- Kalibr CSV


EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
KALIBR_HEADER = "timestamp,omega_x,omega_y,omega_z,alpha_x,alpha_y,alpha_z"


@pytest.mark.parametrize("header", [EUROC_HEADER, KALIBR_HEADER], ids=["euroc", "kalibr"])
def test_a_kalibr_imu_csv_is_recognised(hand, tmp_path, capsys, header):
    t, x, _ = hand
    k = 400
    ns = 1403636579758555392 + 5_000_000 * np.arange(k, dtype=np.int64)  # 200 Hz, EuRoC's epoch
    lines = [header] + [",".join([str(ns[i]), *(repr(float(v)) for v in x[i, [3, 4, 5, 0, 1, 2]])])
                        for i in range(k)]
    csv = tmp_path / "data.csv"
    csv.write_text("\n".join(lines) + "\n")
    code, out, _ = station(capsys, "import", "csv", tmp_path / "k.h5", csv, "--json")
    assert code == 0
    report = json.loads(out)
    assert "recognised as a Kalibr/EuRoC IMU CSV" in report["notes"][0]
    assert report["streams"]["gyro"]["units"] == ["rad/s"] * 3
    # nanoseconds since 1970 read as float64 are multiples of 256 ns: the median step is
    # within 256 ns of 5 ms
    assert abs(report["streams"]["acc"]["rate_hz"] - 200) / 200 < 256e-9 / 5e-3
    got, _ = samples(tmp_path / "k.h5")
    # fixed point, 10^6 counts per unit (docs/session-format.md)
    np.testing.assert_allclose(got["acc"][1], x[:k, :3], rtol=0, atol=5.1e-7)
    np.testing.assert_allclose(got["gyro"][1], x[:k, 3:], rtol=0, atol=5.1e-7)


def test_an_unknown_header_without_streams_is_refused(tmp_path, capsys):
    csv = tmp_path / "other.csv"
    csv.write_text("t,ax,ay,az\n0,1,2,3\n0.01,1,2,3\n")
    code, _, err = station(capsys, "import", "csv", tmp_path / "o.h5", csv)
    assert code == 2 and "not a Kalibr/EuRoC IMU header" in err and "--stream acc=" in err
