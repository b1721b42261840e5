"""`station serve`'s requests, each untrusted, against the real server on the loopback: serials,
profile and file names refused by name, files outside the sessions folder never served, a foreign
Host refused, the token gate when bound beyond the loopback, one session per bench whatever the
number of browsers, and Abort through the API stopping the twin's table."""

import json
import time
import urllib.error
import urllib.request

import pytest
from servedstation import ServedStation

from station import cli
from station.acquire.bench import BenchProfile
from station.twin.served import BenchTwin


def call(url: str, path: str, body=None, headers=None, content_type="application/json"):
    """(status, JSON answer) of GET (body None) or POST `path`."""
    data = None if body is None else (body if isinstance(body, bytes) else
                                      json.dumps(body).encode())
    request = urllib.request.Request(url + path, data=data, headers={
        **({"Content-Type": content_type} if data is not None else {}), **(headers or {})})
    try:
        with urllib.request.urlopen(request, timeout=60) as reply:
            raw = reply.read()
            return reply.status, json.loads(raw) if raw[:1] in (b"{", b"[") else raw
    except urllib.error.HTTPError as err:
        raw = err.read()
        return err.code, json.loads(raw) if raw[:1] == b"{" else raw


@pytest.fixture(scope="module")
def twin_station(tmp_path_factory):
    """A rotary twin and `station serve` on its profile: (twin, station, bench profile)."""
    tmp = tmp_path_factory.mktemp("serve")
    with BenchTwin(seed=6, positions=7) as twin:
        (tmp / "rotary.toml").write_text(twin.profile_text("SIM-6"))
        with ServedStation([tmp / "rotary.toml"], tmp / "sessions") as station:
            yield twin, station, BenchProfile.load(tmp / "rotary.toml")


@pytest.mark.parametrize(("body", "words"), [
    ({"profile": "rotary", "serial": "../../etc"}, "unit serial '../../etc'"),
    ({"profile": "rotary", "serial": ""}, "scan the unit's barcode"),
    ({"profile": "rotary", "serial": 42}, "unit serial 42"),
    ({"profile": "/etc/passwd", "serial": "SN1"}, "choose one of rotary"),
    ({"serial": "SN1"}, "no bench profile None"),
])
def test_a_start_with_bad_fields_is_refused_by_name(twin_station, body, words):
    _, station, _ = twin_station
    status, answer = call(station.url, "/api/start", body)
    assert status == 400 and words in answer["error"], answer
    assert station.session.state == "idle"


def test_a_post_that_is_not_json_changes_nothing(twin_station):
    _, station, _ = twin_station
    status, answer = call(station.url, "/api/start", b"profile=rotary&serial=SN1",
                          content_type="application/x-www-form-urlencoded")
    assert status == 400 and "no bench profile None" in answer["error"]
    assert station.session.state == "idle"


def test_only_the_session_folder_files_are_served(twin_station, tmp_path):
    _, station, _ = twin_station
    station.folder.mkdir(parents=True, exist_ok=True)
    (station.folder / "SN1-20260101-000000.cal.json").write_text('{"ok": 1}')
    (station.folder / "notes.toml").write_text("secret = 1")
    (tmp_path / "outside.json").write_text('{"outside": 1}')
    (station.folder / "link.json").symlink_to(tmp_path / "outside.json")
    assert call(station.url, "/files/SN1-20260101-000000.cal.json") == (200, {"ok": 1})
    for name in ("notes.toml", "link.json", "..%2Foutside.json", "%2Fetc%2Fpasswd",
                 ".hidden.json", "missing.json"):
        status, _ = call(station.url, f"/files/{name}")
        assert status == 404, name
    assert call(station.url, "/assets/..%2F..%2Fapp.py")[0] == 404


def test_a_foreign_host_name_is_refused(twin_station):
    _, station, _ = twin_station
    assert call(station.url, "/api/state", headers={"Host": "evil.example"})[0] == 400
    assert call(station.url, "/api/state", headers={"Host": "localhost"})[0] == 200


def test_one_session_per_bench_abort_pause_and_resume(twin_station):
    """One session at a time; Abort stops the table; the aborted session resumed by its name,
    paused, resumed again and aborted."""
    twin, station, bench = twin_station
    assert call(station.url, "/api/start", {"profile": "rotary", "serial": "SN-API-1"})[0] == 200
    status, answer = call(station.url, "/api/start", {"profile": "rotary", "serial": "SN-API-2"})
    assert status == 409 and "one at a time" in answer["error"]
    first_done = stop_after(station, 0, "abort")
    _, state = call(station.url, "/api/state")
    assert state["state"] == "aborted" and state["serial"] == "SN-API-1"
    from drivers.rotary_table import RotaryTable

    with RotaryTable(bench.table_host, bench.table_port, bench.table_map) as table:
        reading = table.state()
    assert not reading.running
    status, answer = call(station.url, "/api/answer", {"id": 1, "value": "done"})
    assert status == 409 and answer == {"ok": False}  # nothing is asked
    # the interrupted session is listed, and resumed by its name
    _, listed = call(station.url, "/api/bench")
    (entry,) = [e for e in listed["sessions"] if e["name"] == state["session"]]
    assert entry["resumable"] and entry["planned"] == 7 and entry["done"] == first_done
    for name in ("../rotary.toml", "SN-API-1.h5", state["session"] + "x"):
        status, answer = call(station.url, "/api/resume", {"session": name})
        assert status == 400 and "choose one the page lists" in answer["error"], name
    assert call(station.url, "/api/resume", {"session": state["session"]})[0] == 200
    paused = stop_after(station, first_done, "pause")
    assert paused > first_done
    assert "Resume goes on" in call(station.url, "/api/state")[1]["error"]
    assert call(station.url, "/api/resume", {})[0] == 200  # the paused session, going on
    assert stop_after(station, paused, "abort") > paused


def stop_after(station, done: int, action: str) -> int:
    """Pause or abort (`action`) the running session through the API once more than `done`
    positions are done; the positions done then, the session paused or aborted."""
    deadline = time.monotonic() + 300  # a guard against a hang, not a measure

    def wait(condition) -> None:
        while not condition():
            assert time.monotonic() < deadline
            time.sleep(0.1)

    wait(lambda: station.session.state != "running" or (
        station.session.view and len(station.session.view.done) > done))
    assert station.session.state == "running"
    assert call(station.url, f"/api/{action}", {})[0] == 200
    wait(lambda: station.session.state != "running")
    assert station.session.state == {"pause": "paused", "abort": "aborted"}[action]
    return len(station.session.view.done)


def test_beyond_the_loopback_every_request_needs_the_token(tmp_path):
    """The token gate of the application (served on the loopback here; the command puts it in
    front whenever --host is not a loopback address)."""
    from station.serve.app import Listening, build
    from station.serve.session import BenchSession

    session = BenchSession({}, tmp_path, conclude=None)
    lookups = {"sessions": list}
    served = Listening(build(session, lookups, token="a-long-enough-token"), "127.0.0.1", 0)
    import threading

    thread = threading.Thread(target=served.serve)
    thread.start()
    try:
        while not served.server.started:
            assert thread.is_alive()
            time.sleep(0.02)
        url = f"http://127.0.0.1:{served.port}"
        assert call(url, "/api/bench")[0] == 401
        assert call(url, "/api/bench?token=wrong")[0] == 401
        with urllib.request.urlopen(f"{url}/api/bench?token=a-long-enough-token") as reply:
            cookie = reply.headers["set-cookie"].split(";")[0]
            assert reply.status == 200 and "HttpOnly" in reply.headers["set-cookie"]
        assert call(url, "/api/bench", headers={"Cookie": cookie}) == \
            (200, {"profiles": [], "sessions": []})
    finally:
        served.stop()
        thread.join(30)


@pytest.mark.parametrize(("args", "words"), [
    (["--port", "70000"], "--port 70000"),
    (["--host", "0.0.0.0", "--token", "short"], "at least 12 characters"),
    (["--token", "a-long-enough-token"], "leave it out"),
])
def test_bad_options_are_refused_before_serving(tmp_path, capsys, args, words):
    profile = tmp_path / "bench.toml"
    profile.write_text("")
    assert cli.main(["serve", "--profile", str(profile), *args]) == 2
    assert words in capsys.readouterr().err


def test_a_port_in_use_is_named(tmp_path, capsys):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        profile = tmp_path / "bench.toml"
        profile.write_text("")
        assert cli.main(["serve", "--profile", str(profile), "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err


def test_a_server_stopped_by_sigterm_mid_rotation_stops_the_table(tmp_path):
    """`station serve` in its own process, terminated while the table turns: the session is
    aborted (the file records it, the table stopped) and the server exits 130."""
    import signal
    import subprocess

    from twinproc import ENV, STATION

    from station.session import Session

    with BenchTwin(seed=7, positions=7) as twin:
        (tmp_path / "rotary.toml").write_text(twin.profile_text("SIM-7"))
        bench = BenchProfile.load(tmp_path / "rotary.toml")
        server = subprocess.Popen([*STATION, "serve", "--profile", str(tmp_path / "rotary.toml"),
                                   "--port", "0", "--sessions", str(tmp_path / "sessions"),
                                   "--no-db", "--json"], env=ENV, text=True,
                                  stdout=subprocess.PIPE)
        try:
            url = json.loads(server.stdout.readline())["url"].rstrip("/")
            assert call(url, "/api/start", {"profile": "rotary", "serial": "SN-TERM"})[0] == 200
            deadline = time.monotonic() + 300  # a guard against a hang
            while (state := call(url, "/api/state")[1])["view"] is None or \
                    state["view"].get("state") != "rotating":
                assert time.monotonic() < deadline and state["state"] == "running", state
                time.sleep(0.1)
            server.send_signal(signal.SIGTERM)
            assert server.wait(120) == 130
        finally:
            if server.poll() is None:
                server.kill()
                server.wait()
        from drivers.rotary_table import RotaryTable

        with RotaryTable(bench.table_host, bench.table_port, bench.table_map) as table:
            assert not table.state().running
    with Session.open(tmp_path / "sessions" / state["session"]) as session:
        aborts = [e for e in session.events() if e.kind == "abort"]
    assert aborts and aborts[-1].detail["table_stopped"] is True
