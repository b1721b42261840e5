"""Rotary-table register map: profile parsing, fixed-point encoding, refusals."""

import tomllib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.profile import Profile, ProfileError
from drivers.rotary_table import TableRegisterMap

PROFILE = Path(__file__).parents[1] / "drivers/profiles/table_modbus.toml"


def table_section() -> dict:
    with PROFILE.open("rb") as f:
        return tomllib.load(f)["table"]


def parse(table: dict) -> TableRegisterMap:
    return Profile(str(PROFILE), {"table": table}).section("table", TableRegisterMap.parse)


def test_profile_layout():
    m = TableRegisterMap.load(PROFILE)
    assert m.span == (0, 8)  # status, command, then three int32 values
    assert list(m.addresses("angle")) == [6, 7]


@given(st.integers(-(2**31), 2**31 - 1), st.sampled_from(["big", "little"]))
def test_int32_fixed_point_round_trips_in_both_word_orders(counts, order):
    data = table_section() | {"word_order": order}
    m = parse(data)
    words = m.encode(counts / m.rate_scale, m.rate_scale)
    assert all(0 <= w <= 0xFFFF for w in words)
    high, low = (counts >> 16) & 0xFFFF, counts & 0xFFFF  # two's complement, by hand
    assert words == ([high, low] if order == "big" else [low, high])
    assert round(m.decode(words, m.rate_scale) * m.rate_scale) == counts


def test_values_beyond_int32_are_refused():
    m = TableRegisterMap.load(PROFILE)
    with pytest.raises(ValueError, match="32-bit fixed point"):
        m.encode(30000.0, m.rate_scale)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t["registers"].pop("angle"), r"\[table.registers\] angle: missing"),
    (lambda t: t["status_bits"].pop("fault"), r"\[table.status_bits\] fault: missing"),
    (lambda t: t["registers"].update(rate=3), "overlap"),
    (lambda t: t["registers"].update(angle=500), "one read of 125"),
    (lambda t: t.update(word_order="middle"), "word_order: must be one of"),
    (lambda t: t["scale"].update(rate=0.0), "positive"),
    (lambda t: t["status_bits"].update(fault=16), "0..15"),
    (lambda t: t.pop("scale"), r"scale: missing; add a \[table.scale\] table"),
    (lambda t: t["registers"].update(speed=9), r"unknown keys \['speed'\]"),
])
def test_bad_register_maps_are_refused_with_a_clear_message(edit, message):
    data = table_section()
    edit(data)
    with pytest.raises(ProfileError, match=message):
        parse(data)
