"""Thermal chamber register map: profile parsing, value coding, refusals naming the key."""

import struct
import tomllib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.profile import Profile, ProfileError
from drivers.thermal_chamber import ChamberRegisterMap

PROFILES = Path(__file__).parents[1] / "drivers/profiles"


def chamber_section(name: str = "chamber_modbus") -> dict:
    with (PROFILES / f"{name}.toml").open("rb") as f:
        return tomllib.load(f)["chamber"]


def parse(chamber: dict) -> ChamberRegisterMap:
    return Profile("test.toml", {"chamber": chamber}).section("chamber", ChamberRegisterMap.parse)


def test_bundled_layouts():
    int16, float32 = (ChamberRegisterMap.load(n) for n in ("chamber_modbus", "chamber_float_rtu"))
    assert int16.span == (0, 5) and list(int16.addresses("ramp")) == [4]
    assert float32.span == (100, 12) and list(float32.addresses("temperature")) == [104, 105]
    assert (float32.word_order, float32.device_id, float32.run, float32.stop) == ("little", 7, 2, 1)
    assert float32.setpoint_range == (213.15, 423.15)


@given(st.integers(-(2**15), 2**15 - 1))
def test_int16_values_are_signed_counts_of_a_tenth_degree(counts):
    unwatched = {k: v for k, v in chamber_section().items() if k != "watchdog"}  # its safe
    # setpoint would lie outside these limits
    m = parse(unwatched | {"limits": {"setpoint_min": 1.0, "setpoint_max": 2.0,
                                      "ramp_max": 1.0}})
    words = m.encode("temperature", counts / 10.0)
    assert words == [counts & 0xFFFF]  # two's complement, by hand
    assert m.decode("temperature", words) == pytest.approx(counts / 10.0, abs=1e-9)


@given(st.floats(-1e4, 1e4, width=32), st.sampled_from(["big", "little"]))
def test_float32_values_follow_the_word_order(value, order):
    m = parse(chamber_section("chamber_float_rtu") | {"word_order": order})
    high, low = struct.unpack(">HH", struct.pack(">f", value))  # IEEE 754, by hand
    words = m.encode("setpoint", value)
    assert words == ([high, low] if order == "big" else [low, high])
    assert m.decode("setpoint", words) == value


def test_values_beyond_int16_are_refused():
    m = ChamberRegisterMap.load("chamber_modbus")
    with pytest.raises(ValueError, match="16-bit setpoint register"):
        m.encode("setpoint", 3300.0)


@pytest.mark.parametrize("name, edit, message", [
    ("chamber_modbus", lambda t: t["registers"].pop("ramp"),
     r"\[chamber.registers\] ramp: missing"),
    ("chamber_modbus", lambda t: t["status_bits"].pop("door_open"),
     r"\[chamber.status_bits\] door_open: missing"),
    ("chamber_modbus", lambda t: t["registers"].update(temperature=2),
     "registers setpoint and temperature overlap at address 2"),
    ("chamber_float_rtu", lambda t: t["registers"].update(ramp=101),
     "registers setpoint and ramp overlap at address 101"),
    ("chamber_modbus", lambda t: t.update(value_type="int32"),
     r"\[chamber\] value_type: must be one of 'int16', 'float32'; got 'int32'"),
    ("chamber_modbus", lambda t: t.pop("value_type"), r"\[chamber\] value_type: missing"),
    ("chamber_modbus", lambda t: t.pop("scale"), r"\[chamber\] scale: missing"),
    ("chamber_modbus", lambda t: t["scale"].update(ramp=-1.0), "must be positive"),
    ("chamber_modbus", lambda t: t["registers"].update(ramp=300), "one read of 125"),
    ("chamber_modbus", lambda t: t.update(word_order="middle"), "word_order: must be one of"),
    ("chamber_modbus", lambda t: t["status_bits"].update(alarm=0), "distinct numbers 0..15"),
    ("chamber_modbus", lambda t: t["limits"].update(setpoint_min=500.0), "0 < min < max"),
    ("chamber_modbus", lambda t: t["limits"].pop("ramp_max"),
     r"\[chamber.limits\] ramp_max: missing"),
    ("chamber_modbus", lambda t: t["scale"].update(temperature=1000.0),
     "limits do not fit the registers"),
    ("chamber_modbus", lambda t: t["serial"].update(parity="X"), "parity: must be one of"),
    ("chamber_modbus", lambda t: t["serial"].update(baudrate=0), "baudrate: must be positive"),
    ("chamber_modbus", lambda t: t["registers"].update(humidity=9),
     r"unknown keys \['humidity'\]"),
])
def test_bad_register_maps_are_refused_naming_the_key(name, edit, message):
    data = chamber_section(name)
    edit(data)
    with pytest.raises(ProfileError, match=message) as caught:
        parse(data)
    assert str(caught.value).count("test.toml") == 1  # the file, named once


def test_a_profile_without_a_chamber_section_is_refused():
    with pytest.raises(ProfileError, match=r"no \[chamber\] section"):
        ChamberRegisterMap.load("table_modbus")
