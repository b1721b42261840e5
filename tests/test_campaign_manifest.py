"""The thermal campaign's manifest (station.session.campaign) and the bench profile's [chamber]
section: untrusted input refused with a message that names the problem."""

import json

import pytest

from drivers.profile import ProfileError
from station.acquire.bench import BenchProfile
from station.session.campaign import Campaign, CampaignError

PROFILE = """
[bench]
unit_serial = "SN1"
[imu]
link = "serial"
profile = "{imu}"
port = "/dev/null"
[table]
host = "127.0.0.1"
port = 5020
profile = "table_fixture"
[protocol]
positions = 6
[chamber]
host = "127.0.0.1"
setpoints = {setpoints}
{extra}"""


def _profile(tmp_path, imu="imu12_serial_temp", setpoints="[263.15, 313.15]", extra=""):
    path = tmp_path / "bench.toml"
    path.write_text(PROFILE.format(imu=imu, setpoints=setpoints, extra=extra))
    return path


def test_a_campaign_manifest_round_trips_and_goes_on_at_the_first_soak_not_done(tmp_path):
    campaign = Campaign.create(tmp_path / "c", "SN1", _profile(tmp_path), [263.15, 313.15])
    campaign.update(0, state="done", unit_temperature=263.2)
    again = Campaign.load(tmp_path / "c")
    assert again.next_soak() == 1 and again.soaks[0]["unit_temperature"] == 263.2
    assert [p.name for _, p in again.done()] == ["soak_1_263K.h5"]
    with pytest.raises(CampaignError, match="holds a campaign already"):
        Campaign.create(tmp_path / "c", "SN1", _profile(tmp_path), [263.15])


@pytest.mark.parametrize("change, words", [
    (lambda d: d.update(format="other"), "format"),
    (lambda d: d.update(version=2), "version"),
    (lambda d: d["soaks"][1].update(file="../../etc/passwd"), "soak 2"),
    (lambda d: d["soaks"][0].update(state="finished"), "soak 1"),
    (lambda d: d.update(setpoints=[263.15]), "same length"),
    (lambda d: d.update(unit_serial=7), "strings"),
])
def test_a_changed_manifest_is_refused_naming_the_problem(tmp_path, change, words):
    Campaign.create(tmp_path / "c", "SN1", _profile(tmp_path), [263.15, 313.15])
    path = tmp_path / "c" / "campaign.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(CampaignError, match=words):
        Campaign.load(path)


def test_a_manifest_that_is_no_json_is_refused(tmp_path):
    (tmp_path / "campaign.json").write_text("{not json")
    with pytest.raises(CampaignError, match="cannot read"):
        Campaign.load(tmp_path)


def test_the_chamber_section_is_read_with_its_defaults(tmp_path):
    bench = BenchProfile.load(_profile(tmp_path))
    assert bench.chamber.setpoints == (263.15, 313.15) and bench.chamber.safe == 296.15
    assert bench.chamber.port == 502


def test_the_chamber_driver_waits_and_retries_as_the_profile_says(tmp_path):
    """Unset: the clock's reply timeout (0.5 s real time, 30 s in lockstep) and 2 retries."""
    from drivers.clock import REPLY, WallClock

    default = BenchProfile.load(_profile(tmp_path)).chamber.chamber(WallClock())
    assert (default.timeout, default.retries) == (REPLY, 2)
    bench = BenchProfile.load(_profile(tmp_path, extra="reply_timeout = 4.0\nretries = 0\n"))
    chamber = bench.chamber.chamber(WallClock())
    assert (chamber.timeout, chamber.retries) == (4.0, 0)


@pytest.mark.parametrize("extra, words", [("reply_timeout = 0.0", "reply_timeout"),
                                          ("retries = -1", "retries")])
def test_a_reply_timeout_or_retries_out_of_range_is_refused(tmp_path, extra, words):
    with pytest.raises(ProfileError, match=words):
        BenchProfile.load(_profile(tmp_path, extra=extra + "\n"))


@pytest.mark.parametrize("imu, setpoints, words", [
    ("imu12_serial", "[263.15, 313.15]", "temperature channel"),
    ("imu12_serial_temp", "[263.15]", "2 to"),
    ("imu12_serial_temp", "[23.0, 60.0]", "kelvin"),
])
def test_a_chamber_section_the_campaign_cannot_use_is_refused(tmp_path, imu, setpoints, words):
    with pytest.raises(ProfileError, match=words):
        BenchProfile.load(_profile(tmp_path, imu, setpoints))


def test_solving_a_campaign_without_two_soaks_or_with_session_options_is_refused(tmp_path,
                                                                                 capsys):
    from station.cli import main

    Campaign.create(tmp_path / "c", "SN1", _profile(tmp_path), [263.15, 313.15])
    assert main(["solve", str(tmp_path / "c"), "--magnitude", "2"]) == 2
    assert "--magnitude: not for a thermal campaign" in capsys.readouterr().err
    assert main(["solve", str(tmp_path / "c" / "campaign.json")]) == 2
    assert "0 soak(s) recorded" in capsys.readouterr().err
