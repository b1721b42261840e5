"""What a record reads from its session (station.records.sources): the table's rate error from a
session recorded on the virtual bench whose table runs off its command, with an encoder on the
shaft (station.model.effects.rate_error), and the bench's devices from the recorded metadata."""

import pytest

from station.protocols.rotary import RotarySettings, suggested_axes
from station.records.sources import bench_facts, file_sha256, session_facts
from station.twin.rotary_bench import VirtualBench, record_rotary

SCALE = 2e-3  # the table turns 0.2 % fast
RESOLUTION = 1e-5  # rad/s: the table's rate register (drivers/profiles/table_modbus.toml)


def test_the_table_rate_error_is_read_from_the_sessions_table_stream(tmp_path):
    path = tmp_path / "drift.h5"
    settings = RotarySettings()
    with VirtualBench("serial", seed=4, rate_error={"scale": SCALE, "spread": 0.0,
                                                    "encoder": True}) as bench:
        record_rotary(bench, path, settings, suggested_axes(6))
    facts = session_facts(path)
    assert facts["session_sha256"] == file_sha256(path)
    # the encoder reads the true rate, the setpoint register the command, each to a count of
    # the register's resolution
    bound = 2 * RESOLUTION / abs(settings.rate)
    assert facts["table_rate_error"] == pytest.approx(SCALE, abs=bound)
    with VirtualBench("serial", seed=4) as bench:  # a table on its command
        record_rotary(bench, tmp_path / "true.h5", settings, suggested_axes(6))
    assert abs(session_facts(tmp_path / "true.h5")["table_rate_error"]) <= bound


def test_a_campaigns_facts_are_its_manifest_soaks_and_settling(tmp_path):
    """A thermal campaign's record: the manifest's sha256, the longest soak's settling time, the
    median table rate error of its soak sessions (here copies of the example rotary session)."""
    import shutil
    from pathlib import Path

    from station.session.campaign import Campaign

    example = Path(__file__).parents[1] / "sessions" / "rotary-12gyro.h5"
    campaign = Campaign.create(tmp_path / "c", "SN1", str(example), [263.15, 313.15])
    for k, seconds in enumerate((400.0, 512.0)):
        shutil.copy(example, campaign.directory / campaign.soaks[k]["file"])
        campaign.update(k, state="done", soak_seconds=seconds, unit_temperature=263.4 + 50 * k)
    facts = session_facts(campaign.directory)
    one = session_facts(example)
    assert facts["session_sha256"] == file_sha256(campaign.directory / "campaign.json")
    assert facts["chamber_settling_s"] == 512.0
    assert facts["table_rate_error"] == one["table_rate_error"]
    assert facts["model"] == one["model"]


def test_the_bench_and_its_devices_from_the_recorded_profiles():
    """bench_facts of metadata as `station record` writes it (station.acquire.bench.record): the
    bench profile's tables and the device profiles, here the bundled example bench's."""
    from pathlib import Path

    from drivers.profile import load_profile
    from station.records.sources import bench_facts

    profiles = Path(__file__).parents[1] / "drivers" / "profiles"
    bench = load_profile(profiles / "bench_serial.toml").tables
    metadata = {"bench": {"profile": str(profiles / "bench_serial.toml"), "tables": bench},
                "profiles": {"imu": load_profile(profiles / "imu12_serial.toml").tables,
                             "table": load_profile(profiles / "table_modbus.toml").tables}}
    facts = bench_facts(metadata)
    assert facts["model"] == "imu12-serial"
    assert facts["bench"] == "bench_serial"
    assert facts["table_id"] == "rotary-table-modbus at 192.168.0.50:502"
    assert facts["imu_link"] == "serial /dev/ttyUSB0"
    assert facts["chamber_id"] is None and len(facts["profile_sha256"]) == 64
    renamed = {**metadata, "bench": {**metadata["bench"], "tables": {
        **bench, "bench": {**bench["bench"], "name": "bench2"}}}}
    assert bench_facts(renamed)["bench"] == "bench2"
    assert bench_facts(renamed)["profile_sha256"] != facts["profile_sha256"]


def test_a_bench_profile_names_its_bench_and_lot(tmp_path):
    """[bench] name and lot: accepted by the bench profile (strings), recorded verbatim in the
    session's metadata and read by the records."""
    from pathlib import Path

    from drivers.errors import ProfileError
    from station.acquire.bench import BenchProfile

    text = (Path(__file__).parents[1] / "drivers" / "profiles" / "bench_serial.toml").read_text()
    named = tmp_path / "bench.toml"
    named.write_text(text.replace('unit_serial = "SN0001"',
                                  'unit_serial = "SN0001"\nname = "bench2"\nlot = "L7"'))
    tables = BenchProfile.load(named).tables
    assert (tables["bench"]["name"], tables["bench"]["lot"]) == ("bench2", "L7")
    facts = bench_facts({"bench": {"profile": str(named), "tables": tables}})
    assert (facts["bench"], facts["lot"]) == ("bench2", "L7")
    named.write_text(text.replace('unit_serial = "SN0001"', 'unit_serial = "SN0001"\nlot = 7'))
    with pytest.raises(ProfileError, match="lot: must be str"):
        BenchProfile.load(named)
