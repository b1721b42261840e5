"""Right-angle iron and free static simulations: pose geometry, known turns, still intervals."""

import numpy as np
import pytest

from station.model.earth import normal_gravity
from station.model.effects import parse_all
from station.model.unit import SensorUnit
from station.sim.iron import simulate_iron
from station.sim.static import simulate_static

LSB = 1e-5


def unit(seed=0, a=None):
    a = np.diag([1.0, 1.02, 0.98]) if a is None else a
    return SensorUnit(a, bias=[0.1, -0.05, 0.02], counts_per_unit=1 / LSB, fs=100.0, rng=seed)


def test_iron_faces_see_gravity_along_their_normals():
    sim = simulate_iron(unit(), mountings=2, placement_deg=0.0, latitude_deg=45.0)
    f = sim.arrays["y"].mean(1) * LSB - [0.1, -0.05, 0.02]  # (12, 3) poses, bias removed
    v = np.linalg.solve(np.diag([1.0, 1.02, 0.98]), f.T).T  # specific force in the unit frame
    g = normal_gravity(45.0)
    assert np.allclose(np.linalg.norm(v, axis=1), g, rtol=1e-6)
    gram = v @ v.T / g**2
    faces, mount = np.array(sim.truth["face"]), sim.arrays["mounting"]
    same = mount[:, None] == mount[None, :]
    opposite = (
        same & (faces[:, None] // 2 == faces[None, :] // 2) & (faces[:, None] != faces[None, :])
    )
    perpendicular = same & (faces[:, None] // 2 != faces[None, :] // 2)
    assert np.allclose(gram[opposite], -1, atol=1e-6) and np.allclose(
        gram[perpendicular], 0, atol=1e-6
    )


def test_iron_placement_error_has_its_standard_deviation():
    sim = simulate_iron(unit(1), mountings=40, placement_deg=0.5)
    up = np.array(sim.truth["up"]).reshape(40, 6, 3)
    nominal_perp = np.einsum("kfi,kgi->kfg", up, up)[:, 0, 2:]  # face 0 vs faces 2..5
    # a small rotation error per pose tilts each up vector by N(0, sd^2) per axis
    sd = np.radians(0.5)
    assert abs(nominal_perp.std() / (sd * np.sqrt(2)) - 1) < 5 * np.sqrt(0.5 / nominal_perp.size)


def test_iron_turn_integrates_to_the_known_angle_about_the_vertical():
    sim = simulate_iron(unit(2, np.eye(3)), mountings=1, placement_deg=0.0, turn_deg=90.0)
    y = sim.arrays["y"] * LSB - [0.1, -0.05, 0.02]
    s0, s1 = sim.arrays["seg_turn"]
    turned = y[:, s0:s1].sum(1) / 100.0  # integral of the rate, rad
    assert np.allclose(turned, np.radians(90.0) * np.array(sim.truth["up"]), atol=1e-4)
    assert np.abs(y[:, : sim.arrays["seg_static"][1]]).max() < LSB


def test_static_poses_keep_gravity_magnitude_and_rest_during_still_intervals():
    sim = simulate_static(unit(3, np.eye(3)), poses=6, still=2.0, move=1.0, latitude_deg=10.0)
    f = sim.arrays["y"][0] * LSB - [0.1, -0.05, 0.02]
    g = normal_gravity(10.0)
    assert np.allclose(np.linalg.norm(f, axis=1), g, atol=3 * LSB)
    for j, (a, b) in enumerate(sim.truth["still"]):
        assert np.allclose(f[a:b], np.array(sim.truth["v"])[:, j], atol=2 * LSB)
    assert "still" not in sim.arrays  # the station has to find them itself


def test_protocols_without_a_table_refuse_table_effects():
    with pytest.raises(ValueError, match="need the rotary table"):
        simulate_iron(unit(), effects=parse_all(["rate_error=scale=0.1"]))
    with pytest.raises(ValueError, match="need the rotary table"):
        simulate_static(unit(), effects=parse_all(["axis_wobble=angle_deg=1"]))
