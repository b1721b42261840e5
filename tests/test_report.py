"""The session report (issue 6): rendered from a session recorded on the virtual bench through the
real drivers, opened in headless Chromium (every image loads, no page error, a screenshot), its
warnings triggered by sessions made to need them; `station report`. The live view that watched
that recording, and fed by hand."""

import base64
import contextlib
import html
import io
import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rich.console import Console

from drivers.samples import SampleBlock
from station import calibrate, cli
from station.acquire.live_view import LiveView
from station.acquire.recorder import Recorder
from station.protocols.rotary import RotaryProtocol, suggested_axes
from station.reduce.rotary import position_windows, rotary_readings
from station.report import session as report
from station.session import Session, SessionWriter, write_results
from station.twin.rotary_bench import VirtualBench

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars")
PROBE = ("""<script>
window.__errors = [];
window.addEventListener("error", e => window.__errors.push(
  e.message || ("failed to load " + String(e.target && e.target.src).slice(0, 60))), true);
const original = console.error;
console.error = (...a) => { window.__errors.push("console.error: " + a.join(" ")); """
         """original(...a); };
window.addEventListener("load", () => document.documentElement.setAttribute("data-probe",
  JSON.stringify({errors: window.__errors,
                  images: [...document.images].map(i => [i.complete, i.naturalWidth])})));
</script>""")
"""Injected first in <head> (before the report's Content-Security-Policy, which would block it):
records script errors, failed image loads and console errors into the DOM for --dump-dom."""
POSITIONS = 8


@pytest.fixture(scope="module")
def chromium():
    """Path of Chromium; installed with apt-get when absent and possible, else a skip."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    why = "needs root and apt-get"
    if found is None and os.geteuid() == 0 and shutil.which("apt-get"):
        for cmd in (["apt-get", "update"], ["apt-get", "install", "-y", "chromium"]):
            done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=900,
                                  env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
            why = f"{' '.join(cmd)} exited {done.returncode}: {done.stderr.strip()[-300:]}"
        found = shutil.which("chromium")
    if found is None:
        pytest.skip(f"chromium is absent and could not be installed ({why}); install it with "
                    "apt-get install -y chromium")
    return found


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A session of 8 positions recorded on the virtual bench (40x clock) under the live view,
    reduced and solved (results/rotary): (path, the view, what the view printed)."""
    path = tmp_path_factory.mktemp("bench") / "bench.h5"
    screen = Console(file=io.StringIO(), force_terminal=True, width=130, record=True)
    with VirtualBench("serial", seed=3) as bench, \
            bench.drivers() as (imu, table):
        view = LiveView(bench.clock)
        protocol = view.follow(RotaryProtocol(table, view.observe_operator(bench.technician),
                                              bench.clock, axes=suggested_axes(POSITIONS)))
        metadata = {**protocol.metadata(), "unit_serial": "SIM-3"}
        with SessionWriter.create(path, metadata, {"imu": bench.stream_spec},
                                  clock=bench.clock) as writer, \
                Recorder(writer, view.observe_imu(imu), clock=bench.clock) as recorder, \
                view.show(screen):
            protocol.run(view.observe_recorder(recorder))
        a_nominal = bench.truth().a_nominal
    with Session.open(path) as session:
        reduced = rotary_readings(session)
    result = calibrate(reduced.M, 1.0, sigma=reduced.sigma, nominal=a_nominal)
    write_results(path, "rotary", "imu", reduced.M, result, reduced.sigma)
    return path, view, screen.export_text()


@pytest.fixture(scope="module")
def clean(recorded, tmp_path_factory):
    """The report of the recorded session, built once and written: (Report, files written)."""
    built = report.build(recorded[0])
    return built, built.write(tmp_path_factory.mktemp("report") / "report.html")


def test_the_uncertainty_caption_promises_only_what_is_drawn(clean):
    built, _ = clean  # a rotary session: Eq. (18) readings are bias-free, no bias in the fit
    caption = next(p.caption for p in built.plots if p.name == "uncertainty")
    assert "biases were not estimated" in caption and "Scale factors" in caption


def render(chromium, page: Path, workdir: Path) -> tuple[dict, Path]:
    """Open `page` (with the probe injected) in headless Chromium: the probe's findings and a
    screenshot of the whole report."""
    probed = page.with_name(f"probed-{page.name}")
    probed.write_text(page.read_text(encoding="utf-8").replace("<head>", "<head>" + PROBE, 1),
                      encoding="utf-8")
    shot = workdir / f"{page.stem}-screenshot.png"
    base = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={workdir / 'chromium-profile'}"]
    dom = subprocess.run([*base, "--dump-dom", probed.as_uri()], capture_output=True, text=True,
                         timeout=600, check=True).stdout
    subprocess.run([*base, "--window-size=1200,7000", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, timeout=600, check=True)
    found = re.search(r'<html[^>]*data-probe="([^"]*)"', dom)
    assert found, "the probe did not run: the page never fired its load event"
    if os.environ.get("REPORT_SCREENSHOT_DIR"):
        keep = Path(os.environ["REPORT_SCREENSHOT_DIR"])
        keep.mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, keep / shot.name)
    return json.loads(html.unescape(found.group(1))), shot


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk (read independently of any image library)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def embedded_images(page: str) -> list[bytes]:
    return [base64.b64decode(b) for b in re.findall(r'src="data:image/png;base64,([^"]+)"', page)]


def test_report_renders_in_headless_chromium(clean, chromium, tmp_path):
    built, files = clean
    probe, shot = render(chromium, files[0], tmp_path)
    assert probe["errors"] == []
    images = embedded_images(files[0].read_text(encoding="utf-8"))
    names = {p.name for p in built.plots}
    assert {"residuals", "axes", "coverage", "table", "stream-imu", "uncertainty"} <= names
    assert len(probe["images"]) == len(images) == len(built.plots)
    # every image decoded at the width its PNG header states
    assert [w for _, w in probe["images"]] == [png_size(i)[0] for i in images]
    assert all(complete for complete, _ in probe["images"])
    assert png_size(shot.read_bytes()) == (1200, 7000)


def test_figures_next_to_the_report_are_the_embedded_ones(clean):
    files = clean[1]
    pngs = [f.read_bytes() for f in files[1:]]
    assert all(f.name.startswith("report-") and f.suffix == ".png" for f in files[1:])
    assert pngs == embedded_images(files[0].read_text(encoding="utf-8"))


def test_clean_session_report_states_the_recording_and_warns_of_nothing(recorded, clean):
    path = recorded[0]
    built = clean[0]
    s = built.summary
    with Session.open(path) as session:
        samples = len(session.stream("imu").seq)
        stored = session.results("rotary").calibration
    assert s["positions"] == s["positions_planned"] == POSITIONS
    assert s["samples"] == samples and s["sensors"] == 12 and s["rate_hz"] == 200
    assert s["chi2_per_dof"] == pytest.approx(stored.chi2 / stored.dof)
    assert s["noise_median"] == pytest.approx(np.median(stored.sigma))
    assert s["closed_cleanly"] and s["outliers"] == 0
    assert built.warnings == [], built.warnings
    page = built.html()
    assert "No warning" in page and "SIM-3" in page


def test_an_outlier_is_named_and_breaks_chi2(recorded, tmp_path):
    path = tmp_path / "tampered.h5"
    shutil.copy(recorded[0], path)
    with Session.open(path) as session:
        stored = session.results("rotary")
    readings, sigma = stored.readings.copy(), stored.readings_sigma
    readings[3, 5] += 40 * sigma[3, 5]  # sensor g4 at position 6: a bumped window
    write_results(path, "tampered", "imu", readings, calibrate(readings, 1.0, sigma=sigma), sigma)
    built = report.build(path)  # the newest result is the default
    assert built.summary["result"].startswith("results/tampered")
    text = " ".join(built.warnings)
    assert "outliers" in text and "g4 at position 6" in text
    # chi2 gains about (40 (1 - leverage))^2 >> dof = 47: the model does not explain the data
    assert "does not explain the data" in text


def test_weak_geometry_is_warned(recorded, tmp_path):
    path = tmp_path / "cone.h5"
    shutil.copy(recorded[0], path)
    with Session.open(path) as session:
        a = session.results("rotary").calibration.a
    rng = np.random.default_rng(7)
    n, tilt = 12, np.radians(20)  # every stimulus within 20 deg of one axis
    azimuth = np.linspace(0, 2 * np.pi, n, endpoint=False)
    polar = tilt * np.sqrt(rng.uniform(0.2, 1, n))
    v = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    sigma = np.full((12, n), 1e-4)
    readings = a.T @ v + sigma * rng.standard_normal((12, n))
    write_results(path, "cone", "imu", readings, calibrate(readings, 1.0, sigma=sigma), sigma)
    built = report.build(path, "cone")
    # eigenvalues of sum v v^T: about n sin^2 / 2 across against n cos^2 along: ratio < 0.07
    assert built.summary["excitation_ratio"] < 0.07
    text = " ".join(built.warnings)
    assert "Weak geometry" in text and "No position within" in text


def copy_positions(source, target, keep: int, serial: str, extra_events=()) -> None:
    """A session holding the recording of `source` up to its position `keep` (not completed),
    no results; like a recording interrupted there."""
    with Session.open(source) as s:
        imu, table, events = s.stream("imu"), s.table(), s.events()
        metadata = {**s.metadata, "unit_serial": serial}
        spec = s.specs["imu"]
    with SessionWriter.create(target, metadata, {"imu": spec}) as w:
        w.append("imu", imu)
        w.append_table([SimpleNamespace(
            time=t, rate=r, angle=a, rate_setpoint=sp,
            **{bit: bool(st >> i & 1) for i, bit in enumerate(
                ("running", "ready", "moving", "at_rate", "fault"))})
            for t, r, a, sp, st in zip(table.time, table.rate, table.angle, table.rate_setpoint,
                                       table.status, strict=True)])
        for e in events:
            if e.kind != "session_start" and (e.position is None or e.position < keep):
                w.event(e.kind, e.position, e.detail, time=e.time)
        for kind, detail in extra_events:
            w.event(kind, keep, detail, time=events[-1].time)


def test_interrupted_session_is_solved_for_the_report_and_escaped(recorded, chromium, tmp_path):
    path = tmp_path / "interrupted.h5"
    hostile = '<script>alert("x")</script><img src=x onerror=alert(1)>'
    copy_positions(recorded[0], path, 6, hostile, [
        ("note", {"text": "link statistics", "link": {"crc_failures": 3, "frames": 9}}),
        ("abort", {"state": "rotating", "error": "ProtocolError: <b>table</b> fault"})])
    built = report.build(path)
    s = built.summary
    assert s["result"].startswith("computed") and s["positions"] == 6
    # a fit of Eq. (18) readings with their own sigma: chi2/dof = 1 +- sqrt(2/dof), 5 sigma
    assert abs(s["chi2_per_dof"] - 1) < 5 * np.sqrt(2 / s["dof"])
    text = " ".join(built.warnings)
    assert "Only 6 of the 8 planned positions" in text
    assert "abort at position 7" in text and "3 crc failures" in text
    page = built.html()
    assert "<script>alert" not in page and "<b>table</b>" not in page and "onerror=alert" not in \
        page.replace("onerror=alert(1)&gt;", "")
    assert html.escape(hostile) in page
    files = built.write(tmp_path / "interrupted.html")
    probe, _ = render(chromium, files[0], tmp_path)
    assert probe["errors"] == [] and all(w > 0 for _, w in probe["images"])


def test_station_report_cli(recorded, tmp_path, capsys):
    out = tmp_path / "cli" / "r.html"
    assert cli.main(["report", str(recorded[0]), "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["files"][0] == str(out) and all(Path(f).is_file() for f in printed["files"])
    assert printed["positions"] == POSITIONS and printed["warnings"] == []


@pytest.mark.parametrize("args, message", [
    (["missing.h5"], "is not a file"),
    (["plain.txt"], "not an HDF5 file"),
    (["plain.txt", "--out", "plain.txt"], "would overwrite the session file"),
])
def test_station_report_refuses_bad_input(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    Path("plain.txt").write_text("not a session")
    assert cli.main(["report", *args]) == 2
    assert message in capsys.readouterr().err


def test_station_report_names_the_results_it_has(recorded, tmp_path, capsys):
    assert cli.main(["report", str(recorded[0]), "--out", str(tmp_path / "r.html"),
                     "--result", "nope"]) == 2
    assert "no results named 'nope'; it has rotary" in capsys.readouterr().err


# ---------------------------------------------------------------------------------- live view


def test_live_view_followed_the_whole_recording(recorded):
    path, view, printed = recorded
    with Session.open(path) as session:
        samples = len(session.stream("imu").seq)
    # the view saw every block the recorder stored, and no sequence gap
    assert view.samples == samples and view.seq_gaps == 0
    final = printed[printed.rindex("calibration session"):]
    assert "all positions recorded" in final and f"{POSITIONS} of {POSITIONS}" in final
    assert "crc failures 0" in final and "standing still" in final
    # the last windows: the whole static window and at least the 2 turns asked. The static window
    # shown is the one the session recorded (its length beyond 10 s depends on the host: a poll,
    # a Modbus request, an event flush); the view gets each event with the time the session
    # stored, so the two agree to the display rounding of 0.05 s
    static = float(re.search(r"static window\s+(\d+\.\d) of 10 s", final).group(1))
    turns = float(re.search(r"rotating window\s+(\d+\.\d+) of 2 turns", final).group(1))
    with Session.open(path) as session:
        t0, t1 = position_windows(session.events())[POSITIONS - 1]["static"]
    assert static >= 10.0 and abs(static - (t1 - t0)) <= 0.05 + 1e-9
    assert 2.0 <= turns < 2.5
    assert view.display_error is None
    # the signal was seen still (most of the time: static windows, steady rotation); the brief
    # motions (spin-up, stop) may fall between two refreshes: see the test fed by hand
    assert "still (dispersion" in printed
    assert "position 2/8: mount the unit" in printed  # the next instruction, while at 1
    assert "position 8/8 captured" in final  # the last prompt


class StepClock:
    """A session clock moved by hand."""

    def __init__(self):
        self.t = 100.0

    def now(self) -> float:
        return self.t


def test_live_view_windows_stillness_and_instructions():
    clock = StepClock()
    view = LiveView(clock, rate_hz=200.0)
    protocol = view.follow(RotaryProtocol(table=None, operator=None, clock=clock,
                                          axes=suggested_axes(8)))
    protocol.position, protocol.state = 2, "static"
    view.on_event("position_start", 2, {})
    view.on_event("static_start", 2)
    rng = np.random.default_rng(4)

    def feed(seconds, signal):
        for _ in range(int(seconds * 10)):  # blocks of 20 samples at 200 Hz
            start = view.samples
            x = signal(np.arange(start, start + 20) / 200.0)
            counts = np.round(1000 * (x[:, None] + rng.standard_normal((20, 3)))).astype(int)
            view.on_samples(SampleBlock(counts, np.arange(start, start + 20),
                                        np.full(20, np.nan), np.full(20, clock.t), ("x", "y", "z")),
                            counts_per_unit=1000.0)
            clock.t += 0.1

    feed(2.5, lambda t: 0 * t)  # noise only: the quietest window is the reference
    assert view.still and view.dispersion < 4
    text = render_text(view)
    assert "recording the static window" in text and "3 of 8" in text
    assert "2.5 of 10 s" in text  # the static window started 2.5 s of clock ago
    assert "position 4/8: mount the unit" in text  # the next instruction
    feed(1.0, lambda t: 10 * np.sin(2 * np.pi * 2 * t))  # variance 50 x the noise: moving
    assert not view.still and view.dispersion > 8
    assert "moving" in render_text(view)
    feed(1.0, lambda t: 0 * t)
    assert view.still
    view.on_event("static_end", 2)
    clock.t += 30.0  # the static window stays as it ended
    protocol.state = "rotating"
    view.on_event("rotate_start", 2, {"angle": 1.0})
    view.on_table(SimpleNamespace(time=clock.t, rate=1.0, angle=1.0 + 1.5 * np.pi,
                                  rate_setpoint=1.0, running=True, moving=True, at_rate=True,
                                  fault=False))
    view.on_message("position 3: rotating window (2 turns)")
    text = render_text(view)
    assert "4.5 of 10 s" in text and "0.75 of 2 turns" in text and "turning" in text
    assert "position 3: rotating window" in text and "recording the rotating window" in text
    # waiting for the next mounting: the view says what to do now, not what comes after it
    protocol.position, protocol.state = 3, "mount"
    view.on_message("position 3: rotating window (2 turns)")  # the last thing printed
    text = render_text(view)
    assert "do now" in text and "position 4/8: mount the unit" in text
    assert "position 5/8" not in text and "rotating window (2 turns)" not in text


def test_live_view_shows_every_unit_of_a_plate():
    """Two units observed (a plate): each its own named IMU and link rows with its own samples
    and sequence gaps; the stillness follows the first unit only (the second's motion does not
    make the view say moving)."""
    clock = StepClock()
    view = LiveView(clock, rate_hz=200.0)
    view.follow(RotaryProtocol(table=None, operator=None, clock=clock, axes=suggested_axes(8)))
    first, second = (view.observe_imu(None, name=f"unit SN-{k} (stream {s})")
                     for k, s in ((1, "imu"), (2, "imu2")))
    rng = np.random.default_rng(5)
    for block in range(30):
        seq = np.arange(20 * block, 20 * block + 20)
        for proxy, scale, skip in ((first, 1, 0), (second, 100, 5 * (block == 10))):
            counts = np.round(scale * 1000 * rng.standard_normal((20, 3))).astype(int)
            view.on_samples(SampleBlock(counts, seq + skip, np.full(20, np.nan),
                                        np.full(20, clock.t), ("x", "y", "z")),
                            1000.0, proxy._feed)
        clock.t += 0.1
    text = render_text(view)
    for name, gaps in (("SN-1 \\(stream imu\\)", 0), ("SN-2 \\(stream imu2\\)", 1)):
        assert re.search(rf"IMU unit {name}\s+\d+ samples/s, 600 received, {gaps} sequence", text)
    assert text.count("the driver keeps no counters") == 2 and view.still


def test_position_progress_counts_the_captured_positions():
    from station.acquire.progress import PositionProgress

    drawn = []

    @contextlib.contextmanager
    def bar_of(what, unit):  # station.commands.progress's interface, recorded
        yield lambda done, total: drawn.append((what, unit, done, total))

    bar = PositionProgress(bar_of)
    bar.follow(SimpleNamespace(axes=np.zeros((5, 3))))
    events = []
    recorder = bar.observe_recorder(SimpleNamespace(samples=7,
                                                    event=lambda *e: events.append(e) or 1.0))
    with bar.show():
        for j in range(3):
            recorder.event("position_done", j)
        recorder.event("static_start", 3)
    assert [d[2:] for d in drawn] == [(0, 5), (1, 5), (2, 5), (3, 5)]
    assert drawn[0][:2] == ("positions captured", "positions")
    assert recorder.samples == 7 and len(events) == 4  # everything passed through


def test_live_view_survives_a_failing_callback():
    clock = StepClock()
    view = LiveView(clock, rate_hz=200.0)
    events = []
    recorder = view.observe_recorder(SimpleNamespace(event=lambda *a: events.append(a),
                                                     rate_hz=200.0))
    recorder.event("rotate_start", 0, {"angle": "not a number"})  # the view cannot parse it
    assert events == [("rotate_start", 0, {"angle": "not a number"})]  # still recorded
    assert isinstance(view.display_error, ValueError)


def render_text(view) -> str:
    console = Console(file=io.StringIO(), width=130, record=True)
    console.print(view.render())
    return console.export_text()
