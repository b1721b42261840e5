"""Geometry of the two-axis table (station.model.two_axis) against the identifiability checks of
station.solve.identifiability (Rupniewski Eq. 7)."""

import numpy as np
import pytest

from station.errors import CalibrationInputError, InputError
from station.model.two_axis import (
    ALPHA,
    diagonal_mount,
    orientation,
    position_angles,
    position_axes,
    position_axis,
    rate_axis,
)
from station.solve.identifiability import check_design, gram_design


def test_the_cone_has_half_angle_alpha_about_the_body_diagonal():
    u = rate_axis(np.linspace(0, 2 * np.pi, 37))
    c = position_axis()
    assert np.allclose(c, np.ones(3) / np.sqrt(3))
    assert np.allclose(np.linalg.norm(u, axis=1), 1)
    assert np.allclose(u @ c, 1 / np.sqrt(3))  # cos 54.74 deg
    assert np.allclose(diagonal_mount() @ diagonal_mount().T, np.eye(3))
    # the cone passes through each of the unit's axes
    for e in np.eye(3):
        assert np.max(rate_axis(np.linspace(0, 2 * np.pi, 3601)) @ e) > np.cos(np.radians(0.1))


def test_cone_directions_span_3d_but_leave_g_of_eq7_undetermined():
    u = rate_axis(position_angles(12))
    assert np.linalg.matrix_rank(u) == 3
    design, _ = gram_design(u.T)
    assert np.linalg.matrix_rank(design) == 5  # one relation: v^T (cc^T - cos^2 a I) v = 0
    with pytest.raises(CalibrationInputError, match="quadric cone"):
        check_design(design)


@pytest.mark.parametrize("alpha_deg", [30.0, np.degrees(ALPHA), 75.0])
def test_one_spin_of_the_position_axis_makes_the_design_full_rank(alpha_deg):
    axes = position_axes(6, spins=1, alpha=np.radians(alpha_deg))
    design, _ = gram_design(axes.T)
    check_design(design)  # raises if singular
    s = np.linalg.svd(design, compute_uv=False)
    assert s[-1] / s[0] > 1e-3


def test_no_spin_of_the_position_axis_is_refused():
    with pytest.raises(InputError, match="at least one spin of the position axis"):
        position_axes(6, spins=0)


@pytest.mark.parametrize("phi", [0.0, 1.0, -2.5])
def test_the_orientation_is_a_rotation_whose_table_axis_is_the_rate_axis(phi):
    r = orientation(phi)
    assert np.allclose(r.T @ r, np.eye(3)) and np.isclose(np.linalg.det(r), 1)
    assert np.allclose(r[:, 2], rate_axis(phi)[0])
