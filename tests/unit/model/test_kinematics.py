import numpy as np
import pytest

from bench.model.earth import Site, normal_gravity
from bench.model.kinematics import (
    attitude,
    attitude_and_body_rate,
    black_box_matrix,
    body_rate_from_frame_rates,
    frame_axes_in_body,
    pointing_labels,
    rot_y,
    rot_z,
    split_at_frame,
)
from bench.model.units import ARCSEC, DEG

# Paper Table 1, pointing column translated (东E 西W 南S 北N 天U 地D).
TABLE1 = [
    ((0, 0), (0, 180), ("E N U", "W S U")),
    ((0, 90), (90, 270), ("S U W", "N D W")),
    ((0, 180), (0, 180), ("W N D", "E S D")),
    ((0, 270), (90, 270), ("S D E", "N U E")),
    ((90, 90), (0, 180), ("U E N", "D W N")),
    ((90, 270), (0, 180), ("D E S", "U W S")),
    ((180, 0), (0, 180), ("W S U", "E N U")),
    ((180, 90), (90, 270), ("N U E", "S D E")),
    ((180, 180), (0, 180), ("E S D", "W N D")),
    ((180, 270), (90, 270), ("N D W", "S U W")),
    ((270, 90), (0, 180), ("U W S", "D E S")),
    ((270, 270), (0, 180), ("D W N", "U E N")),
]


@pytest.mark.parametrize("outer_middle, inners, expected", TABLE1)
def test_table1_pointing(outer_middle, inners, expected):
    for inner, label in zip(inners, expected):
        angles = np.array([*outer_middle, inner]) * DEG
        assert pointing_labels(attitude(angles)) == label


@pytest.mark.parametrize("start, frame, body_axis", [
    ((0, 90, 0), 0, 0), ((0, 270, 180), 0, 0), ((0, 90, 90), 0, 1), ((0, 270, 270), 0, 1),
    ((0, 0, 0), 2, 2), ((0, 0, 0), 2, 2)])
def test_table3_turning_axes(start, frame, body_axis):
    axis = frame_axes_in_body(np.array(start) * DEG)[frame]
    expected = np.zeros(3)
    expected[body_axis] = 1.0
    assert np.allclose(np.abs(axis), expected, atol=1e-15)


def test_frame_matrices_match_paper_equations():
    t = 0.3
    c, s = np.cos(t), np.sin(t)
    assert np.allclose(rot_z(t), [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert np.allclose(rot_y(t), [[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_black_box_is_exact_orthogonal_product_of_eq6():
    a, b, g = 0.01, -0.02, 0.015
    m = black_box_matrix(np.array([a, b, g]))
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-15)
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    # eq. 6 as printed, with the (1,1) element's dropped -sin(a)sin(b)sin(g) restored
    eq6 = [[ca * cg - sa * sb * sg, ca * sg + sa * sb * cg, -sa * cb],
           [-cb * sg, cb * cg, sb],
           [sa * cg + ca * sb * sg, sa * sg - ca * sb * cg, ca * cb]]
    assert np.allclose(m, eq6, atol=1e-16)


def test_black_box_perturbs_attitude_at_first_order():
    rng = np.random.default_rng(3)
    bb = rng.normal(0, 30 * ARCSEC, (3, 3))
    angles = np.array([90, 270, 180]) * DEG
    diff = attitude(angles, bb) - attitude(angles)
    assert 1 * ARCSEC < np.abs(diff).max() < 200 * ARCSEC


def test_ccw_turn_is_positive_rotation_about_frame_axis():
    # A CCW turn of the outer frame decreases its angle; the body turns +rate about +Z_o.
    angles = np.array([0.0, 90.0, 0.0]) * DEG
    w = body_rate_from_frame_rates(angles, np.array([-10.0, 0.0, 0.0]) * DEG)
    assert np.allclose(w, 10.0 * DEG * frame_axes_in_body(angles)[0])
    # Finite difference of the attitude agrees: dC/dt = -[w x] C
    dt = 1e-6
    c0 = attitude(angles)
    c1 = attitude(angles + np.array([-10.0 * DEG * dt, 0, 0]))
    skew = -(c1 - c0) @ c0.T / dt
    assert np.allclose([skew[2, 1], skew[0, 2], skew[1, 0]], w, atol=1e-9)


def test_split_at_frame_reassembles_attitude():
    rng = np.random.default_rng(1)
    angles = rng.uniform(0, 6.3, (4, 3))
    bb = rng.normal(0, 1e-3, (4, 3, 3))
    for k, f in ((0, rot_z), (1, rot_y), (2, rot_z)):
        left, right = split_at_frame(angles, k, bb)
        assert np.allclose(left @ f(angles[:, k]) @ right, attitude(angles, bb), atol=1e-15)


def test_mounting_rotation_is_applied_after_inner_frame():
    mount = rot_z(np.pi / 2)
    angles = np.array([0.0, 0.0, 0.0])
    assert pointing_labels(attitude(angles, mounting=mount)) == "S E U"


def test_earth_model():
    site = Site(30.27)
    assert site.gravity == pytest.approx(9.79346, abs=1e-4)
    assert normal_gravity(0.0) == pytest.approx(9.7803253359)
    assert normal_gravity(45.0, 1000.0) < normal_gravity(45.0)
    assert np.linalg.norm(site.earth_rate_enu) == pytest.approx(7.2921151467e-5)
    assert site.earth_rate_enu[0] == 0.0 and site.earth_rate_enu[2] > 0
    assert Site(30.0, local_g=9.79).gravity == 9.79
    with pytest.raises(ValueError, match="latitude"):
        Site(95.0)


def test_attitude_and_body_rate_are_the_two_functions_numbers():
    rng = np.random.default_rng(3)
    angles, rates = rng.uniform(-4.0, 4.0, (50, 3)), rng.uniform(-1.0, 1.0, (50, 3))
    black_box, mounting = rng.normal(0.0, 1e-3, (3, 3)), rot_z(np.array(0.3))
    for bb, mount in ((None, None), (black_box, mounting)):
        c_tb, w = attitude_and_body_rate(angles, rates, bb, mount)
        assert np.array_equal(c_tb, attitude(angles, bb, mount))
        assert np.array_equal(w, body_rate_from_frame_rates(angles, rates, bb, mount))
