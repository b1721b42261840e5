"""A new user's walk through the station by the command line alone (issue 36), step by step.

From a fresh checkout, in a scratch directory, every command run as a user types it
(`python -m station ...`, its own process) and its output checked:

1. `station demo`: the verdict and the legend that explains every figure;
2. `station twin` and `station record --solve` on it: a session judged against the twin's
   `[tolerances]` (VERDICT: PASS);
3. `station report`: the verdict in the HTML, as headless Chromium renders it (/usr/bin/chromium;
   the step is marked skipped without it);
4. `station noise SESSION --store CAL --plot`: the figures stored in the calibration file;
5. an accelerometer and gyro triad turned by hand between still poses, and a ten-minute rest of
   it (simulated recordings written as CSV: the twins' hand bench streams no separate gyro
   stream yet), imported with `station import csv`; the accelerometer solved, the gyro from the
   turns, the rest's noise stored in both files (`station noise REST --store`);
6. `station export` to every format (c-header from the recorded 12-gyro session; Kalibr,
   ArduPilot, PX4, ROS and imucal from the triads), and imucal's own loader applying the imucal
   file to the recording: its vectors against `station apply`'s.

Every command must exit 0 (or as the step expects) with no traceback, no Python warning and no
"nan" in its output. Prints one line per step, or with --json the steps' records.

    .venv/bin/python -P bench/walkthrough.py [--positions 8] [--keep DIR] [--json]
"""

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

STATION = [sys.executable, "-m", "station"]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync")
FS = 100.0
G = 9.80665
HAND_POSES = 24
REST_SECONDS = 600.0
GYRO_A = np.array([[1.004, 0.002, -0.001], [-0.001, 0.997, 0.002], [0.001, -0.002, 1.003]])
"""The simulated gyro triad's sensitivity (rows: z^T = w^T a + b^T), 0.4 % and 0.1 deg off."""
GYRO_BIAS = np.array([0.02, -0.01, 0.015])  # rad/s
FORBIDDEN = re.compile(r"Traceback|[A-Za-z]+Warning|\bnan\b")
"""What no command's output may hold: a traceback, a Python warning, a figure that is not one."""


class StepFailed(AssertionError):
    """A step's command or check failed; the message says which and why."""


def station(work: Path, *argv, expect: int = 0) -> subprocess.CompletedProcess:
    """`station ARGV` in `work`, its exit code and output checked."""
    done = subprocess.run([*STATION, *map(str, argv)], cwd=work, capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=1800)
    words = " ".join(map(str, argv))
    if done.returncode != expect:
        raise StepFailed(f"`station {words}` exited {done.returncode}, not {expect}: "
                         f"{done.stderr.strip()[-600:]}")
    found = FORBIDDEN.search(done.stdout + done.stderr)
    if found:
        raise StepFailed(f"`station {words}` printed {found.group(0)!r}: "
                         f"{(done.stdout + done.stderr)[max(0, found.start() - 300):][:600]}")
    return done


def need(condition: bool, what: str) -> None:
    if not condition:
        raise StepFailed(what)


def demo(work: Path, positions: int) -> dict:
    done = station(work, "demo", "--positions", positions, "--out", "demo.h5")
    need("VERDICT: PASS" in done.stdout, f"the demo's verdict: {done.stdout[-400:]}")
    need("what the figures mean:" in done.stdout and "tested against" in done.stdout,
         "the demo's legend and what its verdict tested")
    return {"verdict": "PASS"}


def record(work: Path, positions: int) -> dict:
    twin = subprocess.Popen([*STATION, "twin", "--positions", str(positions), "--profile-out",
                             "twin.toml", "--lifetime", "1800"], cwd=work,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        twin.stdout.readline()  # the twin is serving once it has printed its addresses
        need((work / "twin.toml").is_file(), "station twin wrote no profile")
        need("[tolerances]" in (work / "twin.toml").read_text(), "the twin's [tolerances]")
        done = station(work, "record", "--profile", "twin.toml", "--out", "rec.h5", "--solve")
    finally:
        twin.send_signal(signal.SIGINT)
        try:
            out, err = twin.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            twin.kill()
            out, err = twin.communicate()
    need(not FORBIDDEN.search(err), f"station twin printed: {err[-600:]}")
    need("VERDICT: PASS" in done.stdout, f"record --solve's verdict: {done.stdout[-400:]}")
    return {"verdict": "PASS", "calibration": "rec.cal.json"}


def report(work: Path) -> dict:
    station(work, "report", "rec.h5")
    page = (work / "rec.html").read_text(encoding="utf-8")
    need("<h2>Verdict: PASS</h2>" in page, "the report's HTML holds no verdict")
    if not os.access(CHROMIUM, os.X_OK):
        return {"html": "rec.html", "chromium": "skipped: /usr/bin/chromium is absent"}
    profile = work / "chromium-profile"
    dom = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--dump-dom",
                          (work / "rec.html").as_uri()], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    need(re.search(r"<h2>Verdict: PASS</h2>", dom) is not None
         and re.search(r"<td>verdict</td><td>PASS \(", dom) is not None,
         "Chromium's rendering of the report shows no verdict")
    return {"html": "rec.html", "chromium": "the verdict rendered (section and summary row)"}


def noise(work: Path) -> dict:
    done = station(work, "noise", "rec.h5", "--store", "rec.cal.json", "--plot",
                   "rec-allan.png")
    need("noise figures stored in rec.cal.json" in done.stdout, "noise --store said nothing")
    stored = json.loads((work / "rec.cal.json").read_text())["noise"]
    need(stored is not None and len(stored["white"]) == 12, "the stored figures")
    return {"stored": "rec.cal.json", "white_median": float(np.median(stored["white"]))}


def hand_recordings(work: Path, seed: int = 36) -> None:
    """hand.csv (the triads turned by hand between still poses) and rest.csv (ten minutes at
    rest, white noise and random walks): simulated, as a user's logger would write them."""
    from scipy.spatial.transform import Rotation

    from station.sim.noise import simulated_noise
    from station.sim.static import attitude_path

    rng = np.random.default_rng(seed)
    _, att, _ = attitude_path(Rotation.random(HAND_POSES, random_state=rng), 3.0, 2.0, FS)
    omega = (att[:-1] * att[1:].inv()).as_rotvec() * FS
    omega = np.vstack([omega, omega[-1:]])
    acc = G * att.apply([0.0, 0.0, 1.0]) + 0.01 * rng.standard_normal((len(att), 3))
    gyro = omega @ GYRO_A + GYRO_BIAS + 0.003 * rng.standard_normal((len(att), 3))
    head = "t,ax,ay,az,gx,gy,gz"
    np.savetxt(work / "hand.csv", np.column_stack([np.arange(len(att)) / FS, acc, gyro]),
               delimiter=",", header=head, comments="", fmt="%.10g")
    k = int(REST_SECONDS * FS)
    still = [simulated_noise(k, FS, white=w, random_walk=w, rng=rng)
             for w in (2e-3, 2e-3, 2e-3, 1e-3, 1e-3, 1e-3)]
    rest = np.column_stack([np.arange(k) / FS, *still])
    rest[:, 3] += G
    np.savetxt(work / "rest.csv", rest, delimiter=",", header=head, comments="", fmt="%.10g")


def triads(work: Path) -> dict:
    hand_recordings(work)
    streams = ["--time", "t", "--stream", "acc=ax,ay,az", "--unit", "acc=m/s^2", "--stream",
               "gyro=gx,gy,gz", "--unit", "gyro=rad/s", "--unit-serial", "SIM-HAND"]
    station(work, "import", "csv", "hand.h5", "hand.csv", *streams)
    station(work, "import", "csv", "rest.h5", "rest.csv", *streams)
    station(work, "solve", "hand.h5", "--out", "acc.cal.json")
    station(work, "solve", "hand.h5", "--stream", "gyro", "--out", "gyro.cal.json")
    for cal in ("acc.cal.json", "gyro.cal.json"):
        done = station(work, "noise", "rest.h5", "--store", cal)
        need("random walk" in done.stdout.split("stored in")[-1].split("not resolved")[0],
             f"the rest's random walk stored in {cal}: {done.stdout[-300:]}")
    return {"accelerometer": "acc.cal.json", "gyro": "gyro.cal.json"}


def exports(work: Path) -> dict:
    formats = {"c-header": ["rec.cal.json", "--c-header", "rec.h"],
               "kalibr": ["acc.cal.json", "--gyro", "gyro.cal.json", "--to", "kalibr"],
               "ardupilot": ["acc.cal.json", "--gyro", "gyro.cal.json", "--to", "ardupilot"],
               "px4": ["acc.cal.json", "--gyro", "gyro.cal.json", "--to", "px4", "--acc-id",
                       "2818058", "--gyro-id", "2818066"],
               "ros": ["acc.cal.json", "--gyro", "gyro.cal.json", "--to", "ros"],
               "imucal": ["acc.cal.json", "--gyro", "gyro.cal.json", "--to", "imucal", "--out",
                          "imucal.json"]}
    written = {}
    for fmt, argv in formats.items():
        summary = json.loads(station(work, "export", *argv, "--json").stdout)
        written[fmt] = summary["out"]
    kalibr = (work / written["kalibr"]).read_text()
    need("update_rate: 100.0\n" in kalibr, "Kalibr's update_rate is not the 100 Hz recorded")
    return written


def imucal_round_trip(work: Path) -> dict:
    """imucal's own loader and calibrate on the hand recording's readings, against `station
    apply` on the same readings (a CSV with one column per calibrated sensor)."""
    from imucal.management import load_calibration_info

    raw = np.loadtxt(work / "hand.csv", delimiter=",", skiprows=1)
    ours = []
    for cal, columns in (("acc.cal.json", raw[:, 1:4]), ("gyro.cal.json", raw[:, 4:7])):
        sensors = json.loads((work / cal).read_text())["unit"]["sensors"]
        readings = work / cal.replace(".cal.json", "-readings.csv")
        np.savetxt(readings, columns, delimiter=",", header=",".join(sensors), comments="",
                   fmt="%.17g")
        out = work / cal.replace(".cal.json", "-vectors.csv")
        station(work, "apply", cal, readings.name, "--out", out.name)
        ours.append(np.loadtxt(out, delimiter=",", skiprows=1))
    got_acc, got_gyr = load_calibration_info(work / "imucal.json").calibrate(
        raw[:, 1:4], raw[:, 4:7], "m/s^2", "rad/s")
    diff = {"acc_max_m_s2": float(np.max(np.abs(got_acc - ours[0]))),
            "gyro_max_rad_s": float(np.max(np.abs(got_gyr - ours[1])))}
    # one calibration in two tools' arithmetic: agreement to float64 rounding of ~10 m/s^2
    need(diff["acc_max_m_s2"] < 1e-12 and diff["gyro_max_rad_s"] < 1e-12,
         f"imucal's vectors differ from station apply's: {diff}")
    return {"samples": len(raw), **diff}


def walk(work: Path, positions: int = 8, say=None) -> list:
    """Run every step in `work`; one record per step (name, seconds, what it found). A failing
    step raises StepFailed naming it."""
    steps = [("demo", lambda: demo(work, positions)),
             ("record on the twin", lambda: record(work, positions)),
             ("report", lambda: report(work)), ("noise --store", lambda: noise(work)),
             ("hand triads and rest", lambda: triads(work)), ("export", lambda: exports(work)),
             ("imucal round trip", lambda: imucal_round_trip(work))]
    records = []
    for name, step in steps:
        start = time.perf_counter()
        try:
            found = step()
        except StepFailed as exc:
            raise StepFailed(f"step {name!r}: {exc}") from None
        records.append({"step": name, "seconds": round(time.perf_counter() - start, 1),
                        **found})
        if say is not None:
            say(records[-1])
    return records


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--positions", type=int, default=8,
                        help="positions of the demo and the twin's session (default 8)")
    parser.add_argument("--keep", type=Path, help="work in this directory and keep it")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="walkthrough-"))
    work.mkdir(parents=True, exist_ok=True)
    say = None if args.json else (lambda r: print(json.dumps(r)))
    try:
        records = walk(work.resolve(), args.positions, say)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.json:
        print(json.dumps(records, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
