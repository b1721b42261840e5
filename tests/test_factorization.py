"""Hwangbo & Kanade factorization (station/solve/factorization.py), constraints
(station/solve/constraints.py).

Truth is generated here from a known layout and known stimuli; the solver sees only readings and
constraints. Noiseless data must be reproduced exactly (up to the rotation of Remark 1, via Eq. 19).
"""

import numpy as np
import pytest
from layouts import random_directions

from station.errors import CalibrationInputError
from station.model.frames import eps
from station.solve.constraints import Constraints, from_faces, magnitude_constraints
from station.solve.factorization import factorize
from station.solve.uncertainty import crlb

FACE_VECTORS = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
                "+z": (0, 0, 1), "-z": (0, 0, -1)}
EXACT = 1e-9
G = 9.81


def rotation(rng) -> np.ndarray:
    """A random proper rotation (3 x 3)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def iron_stimuli(rng, faces, mountings, scale=None) -> np.ndarray:
    """Stimuli (3 x n) of a right-angle iron: face vector, rotated by its mounting, times scale."""
    mounts = {m: rotation(rng) for m in dict.fromkeys(mountings)}
    scale = np.ones(len(faces)) if scale is None else scale
    return np.column_stack([s * mounts[m] @ np.array(FACE_VECTORS[f], float)
                            for f, m, s in zip(faces, mountings, scale, strict=True)])


def misaligned(rng, m: int) -> np.ndarray:
    """A random layout (3 x m): unit-ish axes with unequal scale factors, not orthogonal."""
    a = rng.standard_normal((3, m))
    return a / np.linalg.norm(a, axis=0) * rng.uniform(0.5, 2.0, m)


def assert_exact(M, result, a, b, c):
    """a and bias recovered, and the returned (a, v, bias) reproduce the readings."""
    assert eps(a, result.a) < EXACT
    np.testing.assert_allclose(result.bias, b, atol=EXACT)
    np.testing.assert_allclose(result.a.T @ result.v + result.bias[:, None], M, atol=EXACT * c)


# --- noiseless exactness -------------------------------------------------------------------------


def test_triad_with_biases_from_opposite_pairs_is_exact():
    rng = np.random.default_rng(1)
    a, b = np.eye(3) + 0.1 * rng.standard_normal((3, 3)), rng.standard_normal(3)
    faces, mountings = ["+x", "-x", "+y", "-y", "+z", "-z"] * 2, [0] * 6 + [1] * 6
    v = G * iron_stimuli(rng, faces, mountings)
    M = a.T @ v + b[:, None]
    result = factorize(M, from_faces(faces, mountings), magnitude=G)
    assert_exact(M, result, a, b, G)
    np.testing.assert_allclose(np.linalg.norm(result.v, axis=0), G, rtol=EXACT)
    assert np.allclose(np.tril(result.a, -1), 0) and np.all(np.diag(result.a) > 0)  # Eq. (19) frame


def test_known_biases_with_more_sensors_use_the_triad_case():
    rng = np.random.default_rng(2)
    a, b = misaligned(rng, 5), rng.standard_normal(5)
    faces = ["+x", "+y", "+z", "-x"] * 2
    v = iron_stimuli(rng, faces, [0] * 4 + [1] * 4)
    M = a.T @ v + b[:, None]
    assert_exact(M, factorize(M, from_faces(faces, [0] * 4 + [1] * 4), bias=b), a, b, 1.0)


def test_redundant_general_constraints_estimate_biases_exactly():
    rng = np.random.default_rng(3)
    a, b = misaligned(rng, 6), 2.5 + rng.standard_normal(6)
    faces, mountings = ["+x", "-x", "+y", "+z", "-y"] * 3, np.repeat([0, 1, 2], 5)
    v = G * iron_stimuli(rng, faces, mountings)
    M = a.T @ v + b[:, None]
    assert_exact(M, factorize(M, from_faces(faces, mountings), magnitude=G), a, b, G)


@pytest.mark.parametrize("m", [4, 7])
def test_magnitude_only_quartic_case_is_exact(m):
    rng = np.random.default_rng(10 + m)
    a, b = misaligned(rng, m), rng.standard_normal(m)
    v = random_directions(rng, 3, 12, G)
    M = a.T @ v + b[:, None]
    assert_exact(M, factorize(M, magnitude_constraints(12), magnitude=G), a, b, G)


def test_planar_unit_d2_magnitude_only_is_exact():
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((2, 3)), rng.standard_normal(3)
    v = random_directions(rng, 2, 8)
    M = a.T @ v + b[:, None]
    assert_exact(M, factorize(M, d=2), a, b, 1.0)


@pytest.mark.parametrize("joint", [False, True])
def test_orthogonality_only_with_reference_scale_is_exact(joint):
    """Gyros on a right-angle iron: unknown rates and signs, one position of known rate (Eq. 30)."""
    rng = np.random.default_rng(5)
    m = 5 if joint else 3
    a, b = misaligned(rng, m), rng.standard_normal(m)
    faces, mountings = ["+x", "+y", "+z"] * 4, np.repeat([0, 1, 2, 3], 3)
    rates = rng.uniform(0.5, 2.0, 12) * rng.choice([-1.0, 1.0], 12)
    rates[7] = 0.3  # the reference position: a known 0.3 rad/s turn
    v = iron_stimuli(rng, faces, mountings, rates)
    M = a.T @ v + b[:, None]
    constraints = from_faces(faces, mountings).orthogonal()
    assert np.all(constraints.h == 0) and len(constraints) == 12
    result = factorize(M, constraints, magnitude=0.3, reference=7, bias=None if joint else b)
    assert_exact(M, result, a, b, 1.0)
    np.testing.assert_allclose(np.linalg.norm(result.v, axis=0), np.abs(rates), rtol=EXACT)


# --- noise ---------------------------------------------------------------------------------------


def table1_like(rng, n=20):
    """Hwangbo & Kanade's four accelerometers (s4 at 45 deg between s1 and s3), |v| = 1."""
    a = np.column_stack([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.5**0.5, 0, 0.5**0.5]])
    b = np.full(4, 2.5)
    return a, b, random_directions(rng, 3, n)


def test_error_is_first_order_in_the_noise():
    """The estimate is smooth in the readings, so eps(t sigma) = t eps(sigma) + O(t^2)."""
    rng = np.random.default_rng(6)
    a, b, v = table1_like(rng)
    noise = rng.standard_normal((4, 20))
    errors = [eps(a, factorize(a.T @ v + b[:, None] + s * noise).a) / s for s in (1e-7, 1e-5)]
    assert errors[0] > 0
    assert errors[1] == pytest.approx(errors[0], rel=1e-2)


def test_noisy_error_respects_the_cramer_rao_bound():
    """E[eps^2] of any (nearly) unbiased estimator is at least trace(CRLB); the linear method is
    not efficient (the paper's Table I: nonlinear refinement is several times better), so its RMS
    must lie above the bound but within a small multiple of it."""
    rng = np.random.default_rng(7)
    a, b, v = table1_like(rng)
    sigma, trials = 1e-3, 200
    sq = [eps(a, factorize(a.T @ v + b[:, None] + sigma * rng.standard_normal((4, 20))).a) ** 2
          for _ in range(trials)]
    bound = np.sqrt(np.trace(crlb(a, v, sigma, estimate_bias=True)))
    rms = np.sqrt(np.mean(sq))
    # the RMS of 200 trials is known to about 1/sqrt(2 * 200) = 5 %: allow 3 standard errors
    assert rms > 0.85 * bound
    assert rms < 5 * bound


def test_triad_noise_with_opposite_pairs_stays_at_noise_scale():
    """Eq. 14 averages opposite pairs: bias error ~ sigma / sqrt(2 pairs per sensor)."""
    rng = np.random.default_rng(8)
    a, b = np.eye(3), np.full(3, 0.1)
    faces, mountings = ["+x", "-x", "+y", "-y", "+z", "-z"] * 3, np.repeat([0, 1, 2], 6)
    v = iron_stimuli(rng, faces, mountings)
    sigma = 1e-4
    errors = []
    for _ in range(100):
        M = a.T @ v + b[:, None] + sigma * rng.standard_normal((3, 18))
        errors.append(factorize(M, from_faces(faces, mountings)).bias - b)
    # each bias is the mean of 9 pair means: std = sigma / sqrt(2 * 9)
    np.testing.assert_allclose(np.std(errors, axis=0), sigma / np.sqrt(18), rtol=0.25)


# --- degenerate inputs: error and advice ---------------------------------------------------------


def triad_iron(faces, mountings=None):
    """Readings of an ideal triad (unit biases) on the given faces, and their constraints."""
    rng = np.random.default_rng(9)
    v = iron_stimuli(rng, faces, mountings or [0] * len(faces))
    return np.eye(3).T @ v + 1.0, from_faces(faces, mountings)


def raises_with_advice(advice_words, call, *args, **kwargs):
    """Call must raise CalibrationInputError whose advice contains each of advice_words."""
    with pytest.raises(CalibrationInputError) as info:
        call(*args, **kwargs)
    for word in advice_words:
        assert word in info.value.advice, info.value.advice
    assert isinstance(info.value, ValueError)
    return info.value


def test_triad_without_opposite_pairs():
    M, con = triad_iron(["+x", "+y", "+z", "+x", "+y", "+z"], [0, 0, 0, 1, 1, 1])
    err = raises_with_advice(["both faces", "bias=", "estimate_bias"], factorize, M, con)
    assert "opposite" in err.problem


def test_all_positions_parallel():
    M, con = triad_iron(["+x", "-x", "+x", "-x"])
    raises_with_advice(["another face"], factorize, M, con)


def test_positions_in_one_plane_with_joint_biases():
    rng = np.random.default_rng(11)
    faces = ["+x", "-x", "+y", "-y"] * 2
    v = iron_stimuli(rng, faces, [0] * 8)
    M = misaligned(rng, 5).T @ v + 1.0
    raises_with_advice(["other faces"], factorize, M, from_faces(faces))


def test_zero_biases_cannot_be_estimated_jointly():
    rng = np.random.default_rng(12)
    M = misaligned(rng, 5).T @ random_directions(rng, 3, 10)
    raises_with_advice(["bias=", "zeros"], factorize, M)


def test_too_few_positions():
    M, con = triad_iron(["+x", "-x"])
    raises_with_advice(["more orientations"], factorize, M, con)


def test_too_few_constraints():
    rng = np.random.default_rng(13)
    M = misaligned(rng, 5).T @ random_directions(rng, 3, 8) + 1.0
    con = Constraints(np.arange(8), np.arange(8), np.ones(8)) + Constraints([0], [1], [0.0])
    err = raises_with_advice(["more positions"], factorize, M, con)
    assert "at least 10" in err.problem


def test_constraints_that_do_not_determine_the_upgrade():
    M, _ = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    repeated = Constraints([0] * 4 + [1] * 4, [0] * 4 + [1] * 4, np.ones(8))
    raises_with_advice(["other positions"], factorize, M, repeated, bias=np.ones(3))


def test_orthogonality_only_needs_a_reference():
    M, con = triad_iron(["+x", "+y", "+z", "+x", "+y", "+z"], [0, 0, 0, 1, 1, 1])
    raises_with_advice(["reference=", "magnitude"], factorize, M, con.orthogonal(), bias=np.ones(3))


def test_reference_with_magnitude_constraints_is_refused():
    M, con = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    raises_with_advice(["Drop reference="], factorize, M, con, reference=0)


def test_reference_out_of_range():
    M, con = triad_iron(["+x", "+y", "+z", "+x", "+y", "+z"], [0, 0, 0, 1, 1, 1])
    raises_with_advice(["column number"], factorize, M, con.orthogonal(), bias=np.ones(3),
                       reference=6)


def test_joint_biases_need_a_redundant_sensor():
    M, con = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    raises_with_advice(["opposite pairs", "bias="], factorize, M, con, estimate_bias=True)
    raises_with_advice(["not both"], factorize, M, con, estimate_bias=True, bias=np.ones(3))


def test_wrong_face_label_contradicts_the_readings():
    M, _ = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    wrong = from_faces(["+x", "-x", "+y", "-y", "+z", "+x"])
    raises_with_advice(["face and mounting labels"], factorize, M, wrong)


def test_magnitude_only_with_varying_magnitude_has_no_valid_root():
    rng = np.random.default_rng(14)
    M = misaligned(rng, 5).T @ rng.standard_normal((3, 15)) + 1.0
    raises_with_advice(["still", "magnitude"], factorize, M)


def test_constraint_beyond_the_readings():
    M, _ = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    err = raises_with_advice(["same positions"], factorize, M, from_faces(["+x", "-x"] * 4))
    assert "position 7" in err.problem


@pytest.mark.parametrize("readings, words", [
    (np.ones(6), ["one column"]),
    (np.full((3, 6), np.nan), ["re-record"]),
    (np.ones((2, 6)), ["transpose"]),
])
def test_malformed_readings(readings, words):
    raises_with_advice(words, factorize, readings, magnitude_constraints(6))


def test_bad_magnitude_and_bias():
    M, con = triad_iron(["+x", "-x", "+y", "-y", "+z", "-z"])
    raises_with_advice(["SI units"], factorize, M, con, magnitude=0.0)
    raises_with_advice(["one bias per sensor"], factorize, M, con, bias=np.ones(2))


# --- constraint lists ----------------------------------------------------------------------------


def test_from_faces_relates_faces_within_a_mounting_only():
    con = from_faces(["+x", "-x", "+y", "+x"], ["a", "a", "a", "b"])
    got = {(int(j), int(k)): float(h) for j, k, h in zip(con.j, con.k, con.h, strict=True)}
    assert got == {(0, 0): 1, (0, 1): -1, (0, 2): 0, (1, 1): 1, (1, 2): 0, (2, 2): 1, (3, 3): 1}
    np.testing.assert_array_equal(con.opposite_pairs(), [[0, 1]])
    assert sorted(zip(con.orthogonal().j, con.orthogonal().k, strict=True)) == [(0, 2), (1, 2)]


def test_magnitude_constraints_and_concatenation():
    con = magnitude_constraints(3) + Constraints([0], [2], [-1.0])
    np.testing.assert_array_equal(con.j, [0, 1, 2, 0])
    np.testing.assert_array_equal(con.k, [0, 1, 2, 2])
    np.testing.assert_array_equal(con.h, [1, 1, 1, -1])
    with pytest.raises(ValueError):
        con.h[0] = 0.5  # read-only


@pytest.mark.parametrize("j, k, h, words", [
    ([0], [1], [1.5], ["-1 for opposite"]),
    ([0], [0], [0.0], ["h = 1"]),
    ([0.5], [1], [0.0], ["position indices"]),
    ([-1], [1], [0.0], ["counted from 0"]),
    ([0, 1], [1], [0.0], ["one (j, k, h)"]),
])
def test_invalid_constraints(j, k, h, words):
    raises_with_advice(words, Constraints, j, k, h)


def test_invalid_face_labels():
    err = raises_with_advice(["+x, -x"], from_faces, ["+x", "up"])
    assert "up" in err.problem
    raises_with_advice(["one mounting label"], from_faces, ["+x", "-x"], [0])
    raises_with_advice(["several"], magnitude_constraints, 0)
