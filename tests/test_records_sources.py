"""What a record reads from its session (station.records.sources): the table's rate error from a
session recorded on the virtual bench whose table runs off its command, with an encoder on the
shaft (station.model.effects.rate_error), and the bench's devices from the recorded metadata."""

import pytest

from station.protocols.rotary import RotarySettings, suggested_axes
from station.records.sources import file_sha256, session_facts
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
