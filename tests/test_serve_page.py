"""`station serve` in a real browser (Debian's chromium through chromedriver, Selenium): sessions
on the digital twin in lockstep time, started, watched and finished from the page as a technician
would; the page's verdict against the calibration file and the twin's truth; a reload and a second
browser mid-session; Abort mid-rotation stopping the twin's table, then the session resumed; an
iron session whose poses are drawn as asked. Waits are generous (a busy neighbour); no verdict
depends on the wall clock.

STATION_SCREENSHOTS=DIR keeps the screenshots of each step there (docs/figures/serve-*.png were
taken so); otherwise they go to a temporary folder and are only checked to be images."""

import json
import os
import urllib.request

import numpy as np
import pytest
from selenium.common.exceptions import StaleElementReferenceException, TimeoutException
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait
from servedstation import ServedStation, chromium

from station.acquire.bench import BenchProfile
from station.session import Session
from station.twin.served import BenchTwin, HandTwin

POSITIONS = 7  # Eqs. (16)-(17) need n >= 6 for 12 sensors
LONG = 600  # seconds a whole session may take on a loaded host (a guard, not a verdict)


@pytest.fixture(scope="module")
def browsers():
    """Two headless chromium browsers (a second technician's screen), quit at the end."""
    first = chromium()
    try:
        second = chromium()
    except BaseException:
        first.quit()
        raise
    yield first, second
    first.quit()
    second.quit()


@pytest.fixture
def shots(tmp_path):
    """shot(browser, name): a PNG screenshot of the page (STATION_SCREENSHOTS or tmp_path)."""
    folder = os.environ.get("STATION_SCREENSHOTS") or tmp_path

    def shot(browser, name: str) -> None:
        path = os.path.join(folder, f"serve-{name}.png")
        assert browser.save_screenshot(path)
        with open(path, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    return shot


def until(browser, condition, timeout: float = LONG):
    """Wait (a guard against a hang, not a measure) until condition(browser) is true-ish."""
    return WebDriverWait(browser, timeout, poll_frequency=0.1,
                         ignored_exceptions=(StaleElementReferenceException,)).until(condition)


def text(browser, element_id: str) -> str:
    return browser.find_element(By.ID, element_id).text


def done_positions(browser) -> int:
    return len(browser.find_elements(By.CSS_SELECTOR, "#positions span.done"))


def start_session(browser, url: str, serial: str) -> None:
    """Open the page, scan the serial (typed, then Enter as a barcode scanner sends) and wait
    until the session runs."""
    browser.get(url)
    until(browser, lambda b: b.find_elements(By.CSS_SELECTOR, "#profile option"), 60)
    field = browser.find_element(By.ID, "serial")
    field.clear()
    field.send_keys(serial + Keys.ENTER)
    until(browser, lambda b: text(b, "state").startswith("running"), 120)


def served_file(url: str, name: str) -> bytes:
    with urllib.request.urlopen(f"{url}/files/{name}") as reply:
        return reply.read()


def no_script_errors(browser) -> None:
    """The page's script ran without an error (the browser's console)."""
    errors = [e["message"] for e in browser.get_log("browser") if e["source"] == "javascript"]
    assert not errors, errors


def verdict_shown(browser) -> str:
    """The verdict the page shows once the session is concluded (the page's state and error
    told if it never is)."""
    try:
        until(browser, lambda b: b.find_element(By.ID, "verdict").is_displayed()
              and text(b, "verdict").split()[:1])
    except TimeoutException:
        raise AssertionError(f"no verdict shown; the page says {text(browser, 'state')!r}, "
                             f"{text(browser, 'session-error')!r}") from None
    return text(browser, "verdict").split()[0]


def test_a_rotary_session_started_watched_and_finished_from_the_page(browsers, shots, tmp_path):
    """Start from the page, reload it mid-session, watch it from a second browser, end at the
    verdict: the page's verdict is the calibration file's, and the calibration the twin's truth."""
    first, second = browsers
    with BenchTwin(seed=4, positions=POSITIONS) as twin:
        (tmp_path / "rotary.toml").write_text(twin.profile_text("SIM-4"))
        with ServedStation([tmp_path / "rotary.toml"], tmp_path / "sessions",
                           db=f"sqlite:///{tmp_path / 'station.db'}") as station:
            first.get(station.url)
            until(first, lambda b: b.find_elements(By.CSS_SELECTOR, "#profile option"), 60)
            first.find_element(By.ID, "check").click()
            until(first, lambda b: "rotary table" in text(b, "devices"), 60)
            assert "standing still" in text(first, "devices")
            first.find_element(By.ID, "serial").send_keys("SN-WEB-1")
            shots(first, "1-setup")
            start_session(first, station.url, "SN-WEB-1")
            until(first, lambda b: done_positions(b) >= 2)
            until(first, lambda b: "rotating window" in text(b, "windows"))
            shots(first, "2-rotary-running")
            session_name = text(first, "file")
            assert session_name.startswith("SN-WEB-1-") and session_name.endswith(".h5")
            # a second browser attaches to the same session
            second.get(station.url)
            until(second, lambda b: text(b, "file") == session_name, 60)
            assert text(second, "unit") == "unit SN-WEB-1"
            # a reload mid-session reattaches: the same session, the positions done kept
            before = done_positions(first)
            first.refresh()
            until(first, lambda b: text(b, "file") == session_name and done_positions(b) >= before,
                  60)
            until(first, lambda b: b.execute_script("return window.stationStats.updates") > 5, 60)
            assert "positions" not in text(first, "session-error")
            shown = verdict_shown(first)
            shots(first, "3-rotary-result")
            assert verdict_shown(second) == shown
            links = {a.text: a.get_attribute("href").rsplit("/", 1)[1]
                     for a in first.find_elements(By.CSS_SELECTOR, "#outputs a")}
            calibration = json.loads(served_file(station.url, links["calibration file"]))
            report = served_file(station.url, links["report"]).decode()
            # the unit's history and the line, from the record store the session was recorded in
            first.find_element(By.ID, "history-serial").send_keys("SN-WEB-1")
            first.find_element(By.ID, "history").click()
            until(first, lambda b: links["calibration file"] in text(b, "records"), 60)
            assert "PASS" in text(first, "records")
            first.find_element(By.ID, "line").click()
            until(first, lambda b: "yield" in text(b, "records"), 60)
            first.execute_script("document.getElementById('records').scrollIntoView()")
            shots(first, "8-line")
            no_script_errors(first)
            no_script_errors(second)
        truth = twin.truth()
    assert shown == calibration["verdict"]["overall"] == "PASS"
    assert "PASS" in report  # the report shows the verdict too
    assert len(truth["mounted"]) == POSITIONS
    with Session.open(tmp_path / "sessions" / session_name) as session:
        assert session.last_completed_position() == POSITIONS - 1
    k_true = np.linalg.norm(np.array(truth["a"]), axis=0)
    k = np.array(calibration["invariants"]["scale_factors"])
    k_sigma = np.array(calibration["invariants"]["scale_factors_sigma"])
    assert np.all(np.abs(k - k_true) < 6 * k_sigma + 1e-4), (k, k_true)


def test_abort_mid_rotation_stops_the_table_then_the_session_resumes(browsers, shots, tmp_path):
    """Abort while the table turns: the twin's table is commanded to stop and comes to rest, the
    session file records the abort; Resume then records the rest to a verdict."""
    first, _ = browsers
    with BenchTwin(seed=5, positions=POSITIONS) as twin:
        (tmp_path / "rotary.toml").write_text(twin.profile_text("SIM-5"))
        bench = BenchProfile.load(tmp_path / "rotary.toml")
        with ServedStation([tmp_path / "rotary.toml"], tmp_path / "sessions") as station:
            start_session(first, station.url, "SN-ABORT")
            until(first, lambda b: done_positions(b) >= 1 and "rotating window" in
                  text(b, "windows") and "turning" in text(b, "table"))
            first.find_element(By.ID, "abort").click()
            until(first, lambda b: text(b, "state").startswith("aborted"), 120)
            until(first, lambda b: "standing still" in text(b, "table"), 120)
            assert "aborted from the browser" in text(first, "session-error")
            shots(first, "4-aborted")
            state = _table_state(bench)
            assert not state.running and not state.moving and state.rate == 0.0
            name = text(first, "file")
            assert 1 <= done_positions(first) < POSITIONS
            first.find_element(By.ID, "resume").click()
            assert verdict_shown(first) in ("PASS", "MARGINAL", "FAIL")
            shots(first, "5-resumed-result")
            no_script_errors(first)
        with Session.open(tmp_path / "sessions" / name) as session:
            aborts = [e for e in session.events() if e.kind == "abort"]
            assert session.last_completed_position() == POSITIONS - 1
    assert aborts and aborts[0].detail["table_stopped"] is True
    assert "aborted from the browser" in aborts[0].detail["error"]


def _table_state(bench):
    """The twin's table state, read over Modbus as the station reads it."""
    from drivers.rotary_table import RotaryTable

    table = RotaryTable(bench.table_host, bench.table_port, bench.table_map)
    table.connect()
    try:
        return table.state()
    finally:
        table.close()


def test_an_iron_session_with_its_poses_drawn(browsers, shots, tmp_path):
    """The iron's six faces: each asked with its picture (the face asked stands on the table:
    its opposite is the face drawn on top) and confirmed with Done; the verdict at the end."""
    first, _ = browsers
    with HandTwin("iron", seed=9, mountings=1) as twin:
        (tmp_path / "iron.toml").write_text(twin.profile_text("SN-IRON"))
        with ServedStation([tmp_path / "iron.toml"], tmp_path / "sessions") as station:
            start_session(first, station.url, "SN-IRON-1")
            asked = []
            while not first.find_element(By.ID, "result").is_displayed():
                until(first, lambda b: b.find_element(By.ID, "done").is_displayed()
                      or b.find_element(By.ID, "result").is_displayed())
                if not first.find_element(By.ID, "done").is_displayed():
                    break
                words = text(first, "ask-text")
                if "face" in words:
                    face = words.split("face ")[1].split()[0]
                    assert _top_face(first) == OPPOSITE[face], (words, _top_face(first))
                    if face == "+y":
                        shots(first, "6-iron-pose")
                    asked.append(face)
                first.find_element(By.ID, "done").click()
                until(first, lambda b, w=words: text(b, "ask-text") != w
                      or not b.find_element(By.ID, "done").is_displayed())
            shown = verdict_shown(first)
            shots(first, "7-iron-result")
            no_script_errors(first)
    assert sorted(asked) == sorted(OPPOSITE)  # every face once
    assert shown == "PASS"


OPPOSITE = {"+x": "−X", "-x": "+X", "+y": "−Y", "-y": "+Y", "+z": "−Z", "-z": "+Z"}
"""The face drawn on top when the iron stands on a face (as the page labels faces)."""


def _top_face(browser) -> str:
    """The label of the face drawn highest in the pose picture (the one facing up)."""
    labels = browser.find_elements(By.CSS_SELECTOR, "#pose text[font-size='20']")
    top = min(labels, key=lambda e: float(e.get_attribute("y")))
    return top.text
