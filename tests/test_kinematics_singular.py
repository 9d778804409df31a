"""Exactly at a singular configuration (a dead centre) the driving coordinate does not carry
the motion: kinematics() and reduce() give NaN rates there and finite ones beside it.

References written here without package code: the Roberts linkage's RRR dyad is stretched at
theta2 = pi/2 (|BD| = 0.3 m = BC + DC); a slider-driven slider-crank (crank 0.1 m, rod 0.3 m)
is at its outer dead centre at q = 0.4 m (crank + rod) and its inner one at 0.2 m; a
crank-driven RRP with a rod shorter than its crank stands square to its guide where
sin(q) = rod / crank. Beside them the rates are central differences of closed-form
positions (extended precision where numpy has it, Richardson-extrapolated).
"""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from scene_texts import SLIDER_DRIVEN_CRANK

LD = np.longdouble
DELTA = 1e-6  # rad or m before the singular point: finite, large rates

# Roberts (bundled scene "roberts"): A, D on the ground, AB = DC = 0.18, BC = 0.12, P on BC's link
A, D = np.array([-0.12, 0.0]), np.array([0.12, 0.0])
L_AB, L_BC, L_DC = 0.18, 0.12, 0.18
P_LOCAL = np.array([0.06, -0.16970562748477142])  # in link4's frame: x along B -> C
Q_STRETCHED = np.pi / 2

# the slider-driven slider-crank (scene_texts.SLIDER_DRIVEN_CRANK): its lengths, masses and inertias
CRANK, ROD = 0.1, 0.3
MASS, INERTIA = dict(piston=0.8, crank=0.5, rod=1.0), dict(crank=0.001, rod=0.0075)

# a crank-driven RRP whose rod (0.1 m) is shorter than its crank (0.3 m): the rod stands square
# to the guide (the x axis) where the crank's height equals the rod, sin(q) = 1/3
SHORT_ROD = """
[scene]
name = "short_rod"
[ground]
O = [0.0, 0.0]
[links.crank]
points = { O = [0.0, 0.0], A = [0.3, 0.0] }
mass = 0.5
inertia = 0.001
[links.rod]
points = { A = [0.0, 0.0], B = [0.1, 0.0] }
mass = 0.2
inertia = 0.0002
[links.slider]
points = { B = [0.0, 0.0] }
mass = 0.3
inertia = 0.0
[[formation]]
group = "crank"
link = "crank"
pivot = "O"
[[formation]]
group = "RRP"
name = "rod_slider"
links = ["rod", "slider"]
joints = ["A", "B"]
guide_point = "O"
direction = [1.0, 0.0]
offset = 0.0
mode = "forward"
"""


def derivative(f, q, h=1e-8):
    """df/dq at q: central differences at steps h and 2h, Richardson-extrapolated (error ~h^4)."""
    q, h = LD(q), LD(h)
    d1, d2 = ((f(q + s) - f(q - s)) / (2 * s) for s in (h, 2 * h))
    return (4 * d1 - d2) / 3


def roberts_closed_form(q):
    """(B, C, P, theta3, theta4) of the Roberts linkage: C where the circles about B (BC) and
    D (DC) meet, left of B -> D (the scene's mode)."""
    b = A.astype(LD) + L_AB * np.array([np.cos(q), np.sin(q)])
    d = D.astype(LD) - b
    dist = np.sqrt(d @ d)
    along = (dist**2 + L_BC**2 - L_DC**2) / (2 * dist)
    height = np.sqrt(max(L_BC**2 - along**2, LD(0)))
    c = b + (along * d + height * np.array([-d[1], d[0]])) / dist
    theta4 = np.arctan2(c[1] - b[1], c[0] - b[0])
    rot = np.array([[np.cos(theta4), -np.sin(theta4)], [np.sin(theta4), np.cos(theta4)]])
    return b, c, b + rot @ P_LOCAL, np.arctan2(c[1] - D[1], c[0] - D[0]), theta4


def stroke_closed_form(q):
    """(A, crank angle, rod angle) of the slider-driven slider-crank, the piston at (q, 0)."""
    along = (q * q + CRANK**2 - ROD**2) / (2 * q)
    a = np.array([along, np.sqrt(max(CRANK**2 - along**2, LD(0)))])
    return a, np.arctan2(a[1], a[0]), np.arctan2(-a[1], q - a[0])


def stroke_reduction(q):
    """J_red (kg) and the reduced gravity force (N): kinetic-energy and power equivalence
    written over the closed form's central differences."""
    da = derivative(lambda s: stroke_closed_form(s)[0], q)
    rates = {k: derivative(lambda s: stroke_closed_form(s)[i], q) for i, k in ((1, "crank"), (2, "rod"))}
    dg = dict(piston=np.array([1.0, 0.0]), crank=da / 2, rod=(da + np.array([1.0, 0.0])) / 2)
    inertia = sum(MASS[k] * dg[k] @ dg[k] for k in MASS) + sum(INERTIA[k] * rates[k] ** 2 for k in INERTIA)
    return inertia, -9.81 * sum(MASS[k] * dg[k][1] for k in MASS)


def rates(kin) -> list:
    """Every velocity and acceleration array of a Kinematics."""
    fields = (kin.velocities, kin.accelerations, kin.com_velocities, kin.com_accelerations, kin.angular_velocities,
              kin.angular_accelerations)
    return [np.asarray(v) for d in fields if d for v in d.values()]


@pytest.fixture(scope="module")
def roberts():
    return assurjax.load_scene("roberts").mechanism


@pytest.fixture(scope="module")
def roberts_q():
    return np.array([Q_STRETCHED - 1e-4, Q_STRETCHED - DELTA, Q_STRETCHED])


@pytest.fixture(scope="module")
def roberts_kin(roberts, roberts_q):
    return assurjax.kinematics(roberts, roberts_q, order=2, check=False)


@pytest.fixture(scope="module")
def stroke():
    return assurjax.scene_from_dict(tomllib.loads(SLIDER_DRIVEN_CRANK), source="stroke")


def test_roberts_dyad_is_stretched_at_pi_over_2():
    b, _, _, _, _ = roberts_closed_form(LD(Q_STRETCHED))
    assert abs(np.sqrt((D - b) @ (D - b)) - (L_BC + L_DC)) < 1e-15


def test_roberts_rates_are_nan_exactly_at_the_stretched_dyad(roberts_kin):
    for v in rates(roberts_kin):
        assert np.all(np.isnan(v[2])), "a rate at the stretched dyad is a number"
        assert np.all(np.isfinite(v[:2]))
    assert np.all(roberts_kin.ok)
    b, c, p, _, _ = roberts_closed_form(LD(Q_STRETCHED))  # positions stay: they are right
    for name, ref in (("B", b), ("C", c), ("P", p)):
        np.testing.assert_allclose(roberts_kin.points[name][2], ref.astype(float), atol=1e-7)


def test_roberts_rates_beside_it_match_central_differences(roberts_kin):
    q = Q_STRETCHED - DELTA
    theta3, theta4, p = (derivative(lambda s: roberts_closed_form(s)[i], q) for i in (3, 4, 2))
    np.testing.assert_allclose(roberts_kin.angular_velocities["link3"][1], float(theta3), rtol=1e-6)
    np.testing.assert_allclose(roberts_kin.angular_velocities["link4"][1], float(theta4), rtol=1e-6)
    np.testing.assert_allclose(roberts_kin.velocities["P"][1], p.astype(float), rtol=1e-6)


def test_roberts_rates_grow_like_one_over_sqrt_distance(roberts_kin):
    # the dyad's height ~ sqrt(pi/2 - q), so the rates ~ 1/sqrt: 100 times closer, 10 times larger
    for link in ("link3", "link4"):
        w = np.asarray(roberts_kin.angular_velocities[link])
        np.testing.assert_allclose(w[1] / w[0], 10.0, rtol=3e-2)


def test_points_subset_gives_the_same_rates(roberts, roberts_q, roberts_kin):
    subset = assurjax.kinematics(roberts, roberts_q, order=2, points=["P"], check=False)
    for field in ("velocities", "accelerations"):
        np.testing.assert_allclose(getattr(subset, field)["P"], getattr(roberts_kin, field)["P"], rtol=1e-9)
    for field in ("angular_velocities", "angular_accelerations", "com_velocities"):
        for link, v in getattr(subset, field).items():
            np.testing.assert_allclose(v, getattr(roberts_kin, field)[link], rtol=1e-9)
    assert np.all(np.isnan(subset.velocities["P"][2]))


def test_points_off_the_singular_group_keep_their_rates(roberts, roberts_q):
    # B is on the crank: the stretched dyad does not move it, its velocity stays a number
    kin = assurjax.kinematics(roberts, roberts_q, order=1, points=["B"], check=False)
    q = roberts_q[2]
    np.testing.assert_allclose(kin.velocities["B"][2], L_AB * np.array([-np.sin(q), np.cos(q)]), atol=1e-15)


def test_regular_samples_are_unchanged_bit_for_bit(roberts, roberts_q, roberts_kin):
    regular = roberts_q.copy()
    regular[2] = Q_STRETCHED - 1e-3  # the same program, no singular sample
    kin = assurjax.kinematics(roberts, regular, order=2, check=False)
    for a, b in zip(rates(kin), rates(roberts_kin)):
        np.testing.assert_array_equal(a[:2], b[:2])
        assert np.all(np.isfinite(a))


def test_under_jit_and_vmap(roberts, roberts_q, roberts_kin):
    jitted = jax.jit(lambda q: assurjax.kinematics(roberts, q, order=2, points=["P"], check=False).accelerations["P"])
    mapped = jax.vmap(lambda q: assurjax.kinematics(roberts, q, order=1, check=False).angular_velocities["link3"])
    np.testing.assert_allclose(jitted(jnp.asarray(roberts_q)), roberts_kin.accelerations["P"], rtol=1e-9)
    np.testing.assert_allclose(mapped(jnp.asarray(roberts_q)), roberts_kin.angular_velocities["link3"], rtol=1e-9)


def test_slider_crank_reduction_is_nan_at_its_stroke_ends(stroke):
    outer, inner = CRANK + ROD, ROD - CRANK  # dead centres: the crank along the rod
    q = np.array([outer - DELTA, outer, inner, inner + DELTA])
    red = assurjax.reduce(stroke, q)
    for v in (red.inertia, red.dinertia, red.torque, *red.group_inertia.values(), *red.group_torque.values()):
        np.testing.assert_array_equal(np.isnan(v), [False, True, True, False])
    assert np.all(red.ok) and np.all(np.isfinite(red.effort))
    for i in (0, 3):
        inertia, force = stroke_reduction(q[i])
        np.testing.assert_allclose(red.inertia[i], float(inertia), rtol=1e-6)
        np.testing.assert_allclose(red.torque[i], float(force), rtol=1e-6)
    dinertia = derivative(lambda s: stroke_reduction(s)[0], q[0], h=1e-9)
    np.testing.assert_allclose(red.dinertia[0], float(dinertia), rtol=1e-6)


def test_slider_crank_stroke_end_one_configuration_jitted_and_vmapped(stroke):
    outer = CRANK + ROD
    assert np.isnan(assurjax.reduce(stroke, outer).inertia)
    q = jnp.array([outer - DELTA, outer])
    inertia = lambda q: assurjax.reduce(stroke, q).inertia  # noqa: E731
    for found in (jax.vmap(inertia)(q), jax.jit(inertia)(q)):
        np.testing.assert_array_equal(np.isnan(found), [False, True])
    kin = assurjax.kinematics(stroke.mechanism, jnp.array([outer - DELTA, outer]), order=1, check=False)
    assert np.all(np.isnan(kin.velocities["A"][1])) and np.all(np.isfinite(kin.velocities["A"][0]))


@pytest.mark.parametrize("points", [None, ["B"]])
def test_rod_square_to_its_guide_reads_the_slider_rotation(points):
    mechanism = assurjax.scene_from_dict(tomllib.loads(SHORT_ROD), source="short_rod").mechanism
    limit = np.arcsin(1.0 / 3.0)
    kin = assurjax.kinematics(mechanism, np.array([limit - DELTA, limit]), order=1, points=points, check=False)
    assert np.all(kin.ok)
    assert np.all(np.isnan(kin.velocities["B"][1]))
    # B = (0.3 cos q + sqrt(0.1^2 - (0.3 sin q)^2), 0): its speed along the guide
    xb = lambda q: 0.3 * np.cos(q) + np.sqrt(LD(0.01) - (0.3 * np.sin(q)) ** 2)  # noqa: E731
    np.testing.assert_allclose(kin.velocities["B"][0], [float(derivative(xb, limit - DELTA)), 0.0], rtol=1e-6, atol=1e-12)
