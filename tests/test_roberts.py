"""The Roberts straight-line linkage of seed 001 (bundled scene "roberts", metres).

Seed frame: A = (-l4, 0), D = (l4, 0), l2 = l3 = BP = CP = 180 mm, BC = l4 = 120 mm.
theta2 is the angle of AB, theta3 the angle of DC (link3, local x axis D -> C) and
theta4 the angle of BC (link4, local x axis B -> C), all from +x. The closed form
below is the seed's (eqs. 2-7), written here independently of the package.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax

L2, L4 = 0.18, 0.12
L4H = np.sqrt(L2**2 - (L4 / 2) ** 2)  # M4P, the height of P below BC
THETA_SYM = np.arccos(1.0 / 3.0)  # symmetric position of Fig. 1a: P at the origin


def closed_form_theta3(theta2):
    """Seed eqs. 2-4: U cos(theta3) + V sin(theta3) + W = 0, the '+' root."""
    U = 4 * L4 * L2 - 2 * L2**2 * np.cos(theta2)
    V = -2 * L2**2 * np.sin(theta2)
    W = -4 * L4 * L2 * np.cos(theta2) + 3 * L4**2 + 2 * L2**2
    return 2 * np.arctan((V + np.sqrt(V**2 + U**2 - W**2)) / (U - W))


def closed_form_theta4(theta2, theta3):
    """Seed eq. 6."""
    return np.arctan2(L2 * np.sin(theta3) - L2 * np.sin(theta2), 2 * L4 + L2 * np.cos(theta3) - L2 * np.cos(theta2))


def closed_form_P(theta2):
    """Seed eq. 7: P = (B + C)/2 + l4h (sin theta4, -cos theta4)."""
    t3 = closed_form_theta3(theta2)
    t4 = closed_form_theta4(theta2, t3)
    B = np.stack([-L4 + L2 * np.cos(theta2), L2 * np.sin(theta2)], -1)
    C = np.stack([L4 + L2 * np.cos(t3), L2 * np.sin(t3)], -1)
    return (B + C) / 2 + L4H * np.stack([np.sin(t4), -np.cos(t4)], -1)


def closed_form_rates(theta2):
    """omega3, omega4 for omega2 = 1 rad/s: eq. 2 differentiated implicitly, eq. 6 differentiated."""
    t3 = closed_form_theta3(theta2)
    s2, c2, s3, c3 = np.sin(theta2), np.cos(theta2), np.sin(t3), np.cos(t3)
    U = 4 * L4 * L2 - 2 * L2**2 * c2
    V = -2 * L2**2 * s2
    dU, dV, dW = 2 * L2**2 * s2, -2 * L2**2 * c2, 4 * L4 * L2 * s2
    w3 = -(dU * c3 + dV * s3 + dW) / (V * c3 - U * s3)
    nx, ny = 2 * L4 + L2 * (c3 - c2), L2 * (s3 - s2)
    dnx, dny = L2 * (-s3 * w3 + s2), L2 * (c3 * w3 - c2)
    w4 = (nx * dny - ny * dnx) / (nx**2 + ny**2)
    return w3, w4


@pytest.fixture(scope="module")
def mech(roberts_scene):
    return roberts_scene.mechanism


@pytest.fixture(scope="module")
def sweep(mech):
    """Kinematics over the working range around the symmetric position (omega2 = 1 rad/s):
    up to the toggle at theta2 = 90 deg, where |BD| = l3 + BC."""
    theta2 = np.linspace(THETA_SYM - 0.9, np.pi / 2 - 1e-3, 801)
    kin = assurjax.kinematics(mech, theta2, 1.0, 0.0, order=1)
    return theta2, jax.tree.map(np.asarray, kin)


def test_scene_matches_seed_geometry(mech):
    pose = assurjax.pose_at(mech, THETA_SYM)
    np.testing.assert_allclose(pose.points["A"], [-L4, 0.0], atol=1e-15)
    np.testing.assert_allclose(pose.points["D"], [L4, 0.0], atol=1e-15)
    np.testing.assert_allclose(pose.points["P"], [0.0, 0.0], atol=1e-12)  # Fig. 1a: P at the origin


def test_positions_match_closed_form(sweep):
    theta2, kin = sweep
    t3 = closed_form_theta3(theta2)
    np.testing.assert_allclose(np.cos(kin.angles["link3"] - t3), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.cos(kin.angles["link4"] - closed_form_theta4(theta2, t3)), 1.0, atol=1e-12)
    np.testing.assert_allclose(kin.points["P"], closed_form_P(theta2), atol=1e-12)


def test_straight_line_error_below_1mm(sweep):
    theta2, kin = sweep
    x, y = kin.points["P"][:, 0], kin.points["P"][:, 1]
    inside = np.abs(x) < 0.130
    assert x.min() < -0.130 and x.max() > 0.130  # the sweep covers the whole stroke
    assert (np.diff(inside.astype(int)) != 0).sum() == 2  # one contiguous stretch
    assert np.abs(y[inside]).max() < 1e-3
    assert np.abs(closed_form_P(theta2)[inside, 1]).max() < 1e-3  # and so says the closed form


def test_theta3_mirrors_theta2(mech, sweep):
    """The linkage is symmetric about the y axis: the mirror image of the configuration
    (theta2, theta3) is (180 - theta3, 180 - theta2) with x_P -> -x_P, y_P -> y_P.
    Checked over the straight-line stretch (seed Fig. 2a)."""
    theta2, kin = sweep
    inside = np.abs(kin.points["P"][:, 0]) < 0.130
    theta2, kin = theta2[inside], jax.tree.map(lambda x: x[inside], kin)
    mirror_theta2 = np.pi - kin.angles["link3"]
    mirrored = jax.tree.map(np.asarray, assurjax.kinematics(mech, mirror_theta2, order=0))
    np.testing.assert_allclose(np.pi - mirrored.angles["link3"], theta2, atol=1e-10)
    np.testing.assert_allclose(mirrored.points["P"][:, 0], -kin.points["P"][:, 0], atol=1e-12)
    np.testing.assert_allclose(mirrored.points["P"][:, 1], kin.points["P"][:, 1], atol=1e-12)
    at_sym = assurjax.pose_at(mech, THETA_SYM)
    np.testing.assert_allclose(np.pi - at_sym.angles["link3"], THETA_SYM, atol=1e-12)  # equal at Fig. 1a


def test_angular_velocities_closed_form_and_finite_differences(mech, sweep):
    theta2, kin = sweep
    w3, w4 = closed_form_rates(theta2)
    np.testing.assert_allclose(kin.angular_velocities["link3"], w3, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(kin.angular_velocities["link4"], w4, rtol=1e-9, atol=1e-10)
    h = 1e-6
    plus, minus = (np.asarray(assurjax.kinematics(mech, theta2 + s, order=0).angles["link3"]) for s in (h, -h))
    np.testing.assert_allclose(kin.angular_velocities["link3"], (plus - minus) / (2 * h), rtol=1e-6, atol=1e-7)
    plus, minus = (np.asarray(assurjax.kinematics(mech, theta2 + s, order=0).angles["link4"]) for s in (h, -h))
    np.testing.assert_allclose(kin.angular_velocities["link4"], (plus - minus) / (2 * h), rtol=1e-6, atol=1e-7)
    # velocity of P: v_P = v_B + w4 x (P - B) (seed eq. 8), B on the crank (w2 = 1)
    B, P = kin.points["B"], kin.points["P"]
    vB = np.stack([-B[:, 1], B[:, 0] + L4], -1)  # w2 x (B - A), A = (-l4, 0)
    vP = vB + w4[:, None] * np.stack([-(P - B)[:, 1], (P - B)[:, 0]], -1)
    np.testing.assert_allclose(kin.velocities["P"], vP, atol=1e-12)


def test_inverse_kinematics_x_p_50mm(mech):
    """Seed sec. 4: x_P becomes the driving dimension."""
    q, pose = assurjax.inverse_kinematics(mech, lambda pose: pose.points["P"][0], 0.050, THETA_SYM)
    pts = {k: np.asarray(v) for k, v in pose.points.items()}
    assert abs(pts["P"][0] - 0.050) < 1e-12
    assert abs(closed_form_P(float(q))[0] - 0.050) < 1e-12
    dist = lambda a, b: np.linalg.norm(pts[a] - pts[b])  # noqa: E731
    for (a, b), length in {("A", "B"): L2, ("D", "C"): L2, ("B", "C"): L4, ("B", "P"): L2, ("C", "P"): L2}.items():
        assert abs(dist(a, b) - length) < 1e-12, (a, b)
    assert abs(pts["P"][1]) < 1e-3  # still on the straight stretch


def test_inverse_kinematics_out_of_reach_raises(mech):
    with pytest.raises(assurjax.AssemblyError, match="out of reach|cannot"):
        assurjax.inverse_kinematics(mech, lambda pose: pose.points["P"][0], 1.0, THETA_SYM)


def test_positions_jit_and_vmap(mech):
    """Jitted and vmapped positions agree with the closed form over many crank angles."""
    f = eqx.filter_jit(jax.vmap(lambda q: assurjax.positions(mech, q, points=["P"]).points["P"]))
    theta2 = np.linspace(THETA_SYM - 0.9, np.pi / 2 - 1e-3, 5000)
    np.testing.assert_allclose(np.asarray(f(jnp.asarray(theta2))), closed_form_P(theta2), atol=1e-12)
