"""Device faults the hard way: what the station does with each, class by class.

Per class, the inputs tried and how each ended: a clean error (a TableError naming the table), a
traceback (any other exception), a hang (no answer within 10 s), accepted with the right result (a
retry absorbed the fault, a duplicate dropped, a restart segmented), or accepted with a changed
result (a wrong reading, a forward jump in the numbering). Classes:

- table_reset: the table's TCP connection reset on every try of each call (1, 3 and 10 resets)
- table_short: replies one register short (reads) or cut (writes), same calls and counts
- controller_killed: the table controller dies while the table turns at 3 rad/s; each call after
- kill_resume: `station record` against `station twin`, SIGKILLed at random moments of a rotary
  session, then `station resume`: the delay from its start to the stop command in the twin's
  register log (`station twin --table-log`), and how often the table was left turning
- sequence: serial frames sent twice (pty twin), CAN samples sent twice (virtual bus), serial and
  CAN devices restarting their numbering
- can_restarts: 500 CAN streams whose device resets to a small counter value (0-3) after a
  random number of samples from a random counter, through the pure decoder
- corrupted_streams: 10^4 serial byte streams of 100 frames, each damaged one way (bits flipped,
  a stretch dropped, garbage inserted, a frame cut, 120 bytes repeated), parsed in random chunks:
  accepted right means every sample is one sent with its number
- files (with --files N): damaged inputs through the commands that read them, N per kind of
  damage (bench/file_faults.py, run as its own process: truncated killed session files, zeroed
  4 KB blocks, flipped bytes, killed flags on top, inflated size claims; deep or non-finite
  metadata and calibration files, NaN table rows, deep and wide profiles, deflate bombs)

    .venv/bin/python -P bench/faults.py [--json] [--kills 10] [--files 0]
"""

import argparse
import json
import logging
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

from drivers.can_imu import CanImu, CanProfile
from drivers.clock import ScaledClock
from drivers.errors import TableError
from drivers.profile import SerialImuProfile
from drivers.rotary_table import RotaryTable, TableRegisterMap
from drivers.samples import SampleBlock
from drivers.serial_imu import SerialImu
from drivers.twins.can import CanImuTwin
from drivers.twins.serial import SerialTwin
from drivers.twins.table import TableTwin
from station.session import Session
from station.sim.table import TablePhysics

MAP = TableRegisterMap.load("table_modbus")
CALLS = {"state": (), "set_rate": (1.0,), "start": (), "stop": ()}
HANG_S = 10.0
STATION = [sys.executable, "-m", "station"]
OUTCOMES = ("clean_error", "traceback", "hang", "accepted_right", "accepted_changed")


def tally(outcomes: list) -> dict:
    """Counts of each outcome, and the inputs tried."""
    return {"tried": len(outcomes), **{o: outcomes.count(o) for o in OUTCOMES}}


def bounded(call) -> tuple:
    """(result or exception, hung) of `call()` run in a thread for at most HANG_S seconds."""
    box = {}

    def run():
        try:
            box["value"] = call()
        except BaseException as exc:  # noqa: BLE001 - classified by the caller
            box["error"] = exc
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(HANG_S)
    return box, thread.is_alive()


def spinning_table():
    """(physics, twin, driver): a twin table turning at 3 rad/s and a connected driver."""
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock, max_accel=4.0, settle_time=0.5)
    twin = TableTwin(physics, MAP, lifetime=120.0).start()
    table = RotaryTable("127.0.0.1", twin.port, MAP, timeout=0.1, retries=2, stop_patience=0.5,
                        clock=clock)
    table.connect()
    table.set_rate(3.0)
    table.start()
    return physics, twin, table


def right(call: str, result, physics) -> bool:
    """Did an accepted call do what it should (the physics is the truth)?"""
    truth = physics.state()
    if call == "state":
        return result.rate_setpoint == truth.rate_setpoint and result.running == truth.running
    if call == "set_rate":
        return truth.rate_setpoint == 1.0
    return truth.running == (call == "start")


def classify(box: dict, hung: bool, check) -> str:
    if hung:
        return "hang"
    if "error" in box:
        return "clean_error" if isinstance(box["error"], TableError) else "traceback"
    return "accepted_right" if check(box["value"]) else "accepted_changed"


def table_faults(kind: str) -> dict:
    """Each call with the fault `kind` on its next 1, 3 (every try) and 10 requests."""
    outcomes = []
    for call, args in CALLS.items():
        for count in (1, 3, 10):
            physics, twin, table = spinning_table()
            try:
                twin.inject(kind, count=count)
                box, hung = bounded(lambda c=call, a=args, t=table: getattr(t, c)(*a))
                outcomes.append(classify(box, hung, lambda r, c=call, p=physics: right(c, r, p)))
            finally:
                table.close()
                twin.close()
    return tally(outcomes)


def controller_killed(trials: int = 3) -> dict:
    """The controller dies mid-rotation; each call afterwards. Also: was the operator told to stop
    the table by hand (it keeps turning)?"""
    outcomes, told = [], 0
    for _ in range(trials):
        for call, args in CALLS.items():
            physics, twin, table = spinning_table()
            try:
                twin.die()
                box, hung = bounded(lambda c=call, a=args, t=table: getattr(t, c)(*a))
                outcomes.append(classify(box, hung, lambda r: False))
                notes = getattr(box.get("error"), "__notes__", ())
                told += any("stop the table by hand" in n for n in notes) or call == "stop"
            finally:
                table.close()
                twin.close()
    return {**tally(outcomes), "told_to_stop_by_hand": told}


def _events(path: Path) -> list:
    try:
        with Session.open(path) as s:
            return [e.kind for e in s.events()]
    except Exception:  # noqa: BLE001 - not created yet
        return []


def _writes(log: Path) -> list:
    """(monotonic s, address, values) of the twin's accepted writes so far."""
    if not log.exists():
        return []
    rows = [line.split() for line in log.read_text().splitlines()]
    return [(float(r[0]), int(r[1]), [int(v) for v in r[2:]]) for r in rows if len(r) > 2]


def kill_resume(kills: int, seed: int = 20) -> dict:
    """SIGKILL a rotary `station record` at random moments, then time `station resume`'s stop."""
    rng = random.Random(seed)
    command = MAP.registers["command"]
    delays, turning, outcomes = [], 0, []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        log, profile = tmp / "writes.log", tmp / "twin.toml"
        twin = subprocess.Popen([*STATION, "twin", "--speed", "40", "--positions", "6",
                                 "--profile-out", str(profile), "--table-log", str(log),
                                 "--lifetime", "900", "--json"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        json.loads(twin.stdout.readline())
        try:
            for k in range(kills):
                session = tmp / f"s{k}.h5"
                enters = tmp / "enter.txt"
                enters.write_text("\n" * 6)
                with enters.open() as stdin:
                    rec = subprocess.Popen([*STATION, "record", "--profile", str(profile), "--out",
                                            str(session), "--json"], stdin=stdin,
                                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                deadline = time.monotonic() + 60
                while "position_start" not in _events(session) and time.monotonic() < deadline:
                    time.sleep(0.01)
                time.sleep(rng.uniform(0.0, 3.0))  # a position is about 0.7 s of wall time
                rec.send_signal(signal.SIGKILL)
                rec.wait()
                commands = [w for w in _writes(log) if w[1] == command]
                turning += bool(commands) and commands[-1][2] == [MAP.run]
                started = time.monotonic()
                res = subprocess.Popen([*STATION, "resume", str(session), "--json"],
                                       stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.PIPE, text=True)
                stop = None
                while stop is None and time.monotonic() - started < HANG_S:
                    stop = next((t for t, a, v in _writes(log)
                                 if t >= started and a == command and v == [MAP.stop]), None)
                    time.sleep(0.05)  # the instant is the log's: polling only finds it
                res.send_signal(signal.SIGTERM)
                try:
                    _, err = res.communicate(timeout=30)
                except subprocess.TimeoutExpired:
                    res.kill()
                    _, err = res.communicate()
                if stop is None:
                    outcomes.append("hang")
                    continue
                delays.append(stop - started)
                outcomes.append("traceback" if "Traceback" in err else
                                "accepted_right" if stop - started <= 1.0 else "accepted_changed")
        finally:
            twin.send_signal(signal.SIGINT)
            try:
                twin.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                twin.kill()
    d = np.array(delays) if delays else np.full(1, np.nan)
    return {**tally(outcomes), "left_turning_at_kill": turning,
            "stop_delay_s": {"min": float(d.min()), "median": float(np.median(d)),
                             "max": float(d.max())}}


def serial_sequence(duplicate: float, restart: bool, seed: int) -> tuple:
    """One pty stream of the 12-gyro unit at 2 kHz; (block, stats, twin)."""
    profile = SerialImuProfile.load("imu12_serial")

    def source(times):
        n = np.round(np.asarray(times) * 1e6).astype(np.int64)
        return (n[:, None] * 2654435761 + np.arange(12) * 40503) % 2**32 - 2**31
    clock = ScaledClock(speed=10)
    twin = SerialTwin(profile, source, clock=clock, seed=seed, duplicate=duplicate,
                      max_lag=np.inf)  # flow control only: no frame skipped when behind
    blocks = []
    with twin, SerialImu(twin.port, profile, clock=clock) as imu:
        while sum(map(len, blocks)) < 4000:
            if restart and sum(map(len, blocks)) > 2000 and not twin.restarts:
                twin.restart()
            block = imu.read_block(timeout=5.0)
            if block is None:
                break
            blocks.append(block)
    return SampleBlock.concat(blocks), imu.stats, twin


def sequence(seed: int = 3) -> dict:
    """Duplicates and restarts on the serial and CAN links."""
    out = {}
    got, stats, twin = serial_sequence(0.08, False, seed)
    dup = int(np.count_nonzero(np.array(twin.duplicated) < got.seq[-1]))
    jumps = int(np.count_nonzero(np.diff(got.seq) != 1))
    out["serial_duplicate_frame"] = {"tried": dup, "dropped_and_counted": stats.duplicates,
                                     "forward_jumps": jumps, "restarts_seen": stats.restarts}
    restarts = []
    for trial in range(10):
        got, stats, twin = serial_sequence(0.0, True, seed + trial)
        steps = np.diff(got.seq)
        restarts.append("accepted_right" if (stats.restarts, stats.gaps) == (1, 0)
                        and np.count_nonzero(steps != 1) == 1 and np.all(steps[steps != 1] <= 0)
                        else "accepted_changed")
    out["serial_restart"] = tally(restarts)
    profile = CanProfile.load("imu12_can")
    n = 2000
    twice = set(np.random.default_rng(seed).choice(n - 1, size=500, replace=False).tolist())
    name = f"faults-{uuid.uuid4().hex}-bus"
    with CanImu({"interface": "virtual", "channel": name}, profile) as imu:
        twin = CanImuTwin(name, profile, lambda t: np.zeros((len(t), len(profile.imu.channels)),
                                                            np.int64) + np.arange(len(t))[:, None],
                          samples=n, duplicate=twice)
        with twin:
            twin.wait(30)
        seq = []
        deadline = time.monotonic() + 10
        while len(seq) < n and time.monotonic() < deadline:
            block = imu.read_block(timeout=0.05)
            if block is not None:
                seq.extend(block.seq.tolist())
    out["can_duplicate_sample"] = {
        "tried": len(twice), "dropped_and_counted": imu.stats.duplicates,
        "forward_jumps": int(np.count_nonzero(np.diff(seq) != 1))}
    return out


def can_restarts(n: int = 500, seed: int = 11) -> dict:
    """`n` CAN streams of the imu12_can profile (8-bit counter) through the drivers' pure
    decoder (`SampleAssembler`): a random number of samples from a random counter, then the
    device resets and counts again from a small value (0-3). Accepted right: one restart, the
    numbering not going forward there, every other step 1; changed: a forward jump instead (the
    reset read as samples lost), which no decoder without a device time can avoid when the reset
    lands within `max_gap` after the last counter."""
    import can

    from drivers.can_imu import FrameLayout, SampleAssembler

    layout = FrameLayout(CanProfile.load("imu12_can"))
    rng = np.random.default_rng(seed)
    outcomes = []
    for _ in range(n):
        first, before, after = int(rng.integers(0, 256)), int(rng.integers(1, 600)), 50
        counters = np.r_[first + np.arange(before), int(rng.integers(0, 4)) + np.arange(after)]
        asm = SampleAssembler(layout)
        for k, counter in enumerate(counters):
            for slot in layout.slots:
                values = {layout.counter: int(counter) % layout.counter_modulus,
                          **{name: (k * 31 + col) % 1000 for name, col in slot.columns}}
                asm.feed(can.Message(arbitration_id=slot.frame_id,
                                     is_extended_id=slot.message.is_extended_frame,
                                     data=slot.message.encode(values, scaling=False,
                                                              padding=True)), float(k))
        steps = np.diff(asm.take().seq)
        right = asm.stats.restarts == 1 and steps[before - 1] <= 0 and \
            np.all(np.delete(steps, before - 1) == 1)
        outcomes.append("accepted_right" if right else "accepted_changed")
    return tally(outcomes)


def corrupted_streams(n: int, seed: int = 5, frames: int = 100) -> dict:
    """`n` serial streams of `frames` imu12_serial frames, each damaged one way (bytes flipped,
    a stretch dropped, garbage inserted, a frame cut, frames repeated), parsed in random chunks
    through the drivers' BinaryFrameParser. A stream ends as a traceback, or accepted right
    (every sample's counts are those sent with its number, numbers increasing), or accepted with
    a changed result (a sample never sent, or numbers going back)."""
    from drivers.wire.binary import BinaryFrameParser, encode_frames

    profile = SerialImuProfile.load("imu12_serial")
    fmt, channels = profile.serial.frame, profile.imu.channels
    rng = np.random.default_rng(seed)
    outcomes = []
    for _ in range(n):
        seq = np.arange(frames) + int(rng.integers(0, 60000))
        counts = rng.integers(-2**31, 2**31, (frames, len(channels)))
        data = bytearray(encode_frames(fmt, seq % 65536, seq * 500, counts))
        _damage(data, rng)
        parser = BinaryFrameParser(fmt, channels)
        try:
            blocks, at = [], 0
            while at < len(data):
                step = int(rng.integers(1, 300))
                blocks.append(parser.decode(bytes(data[at:at + step]), float(at)).block)
                at += step
            blocks.append(parser.decode(b"", float(at), final=True).block)
            got = SampleBlock.concat(blocks)
        except Exception:  # noqa: BLE001 - counted: the bench's purpose
            outcomes.append("traceback")
            continue
        sent = dict(zip((seq % 65536).tolist(), map(tuple, counts.tolist()), strict=True))
        right = all(sent.get(int(q) % 65536) == tuple(c)
                    for q, c in zip(got.seq.tolist(), got.counts.tolist(), strict=True))
        outcomes.append("accepted_right" if right and np.all(np.diff(got.seq) > 0)
                        else "accepted_changed")
    return tally(outcomes)


def _damage(data: bytearray, rng) -> None:
    """One kind of damage, at random places of a serial byte stream (in place)."""
    kind = rng.integers(0, 5)
    if kind == 0:
        for at in rng.integers(0, len(data), int(rng.integers(1, 20))):
            data[at] ^= 1 << int(rng.integers(0, 8))
    elif kind == 1:
        at = int(rng.integers(0, len(data) - 100))
        del data[at:at + int(rng.integers(1, 100))]
    elif kind == 2:
        at = int(rng.integers(0, len(data)))
        data[at:at] = rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8).tobytes()
    elif kind == 3:
        at = int(rng.integers(0, len(data) - 60))
        del data[at + 10:at + 30]
    else:
        at = int(rng.integers(0, len(data) - 120))
        data[at:at] = data[at:at + 120]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--streams", type=int, default=10_000,
                        help="corrupted serial streams of 100 frames")
    parser.add_argument("--files", type=int, default=0,
                        help="damaged session files per kind (bench/file_faults.py); 0: none")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    logging.getLogger("drivers").setLevel(logging.CRITICAL)
    start = time.perf_counter()
    result = {"table_reset": table_faults("reset"), "table_short": table_faults("short"),
              "controller_killed": controller_killed(), "kill_resume": kill_resume(args.kills),
              "sequence": sequence(), "can_restarts": can_restarts(),
              "corrupted_streams": corrupted_streams(args.streams)}
    if args.files:
        done = subprocess.run([sys.executable, "-P", str(Path(__file__).with_name(
            "file_faults.py")), "--files", str(args.files), "--json"], capture_output=True,
            text=True, check=False)
        result["files"] = json.loads(done.stdout)["classes"]
    result["seconds"] = time.perf_counter() - start
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for name, row in result.items():
            print(f"{name:20s} {row}")


if __name__ == "__main__":
    main()
