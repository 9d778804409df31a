"""Modular reduction to the driving link (seed 000 eqs. 3-6) against closed forms,
the reference's closed-form positions with central differences, and virtual work."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj
from assurjax._reduction import reduce_single

import joint_reference as ref

QS = np.array([-2.5, -1.0, 0.0, 0.7, 2.0])
WATT_L = dict(link2=1.0, link3=1.5, link4=1.5, link5=1.0, link6=1.0)
REF_NAME = dict(link2="crank", link3="coupler", link4="rocker", link5="link5", link6="link6")
START = dict(link2="O2", link3="A", link4="O4", link5="C", link6="D")


@pytest.fixture(scope="module")
def watt():
    return aj.load_scene("watt_sixbar")


@pytest.fixture(scope="module")
def watt_reduced(watt):
    return aj.reduce(watt, jnp.asarray(QS))


def _watt_coms(theta):
    pts, ang = ref.watt_sixbar_points(theta)
    ang = {k: ang[REF_NAME[k]] for k in WATT_L}
    return {k: pts[START[k]] + WATT_L[k] / 2 * np.array([np.cos(ang[k]), np.sin(ang[k])]) for k in WATT_L}, ang


def _watt_closed_form(theta, h=1e-6):
    """J_red (kinetic-energy equivalence with unit crank speed) and V, from the
    reference's closed-form positions and central differences."""
    m = {k: ref.WATT["m"][REF_NAME[k]] for k in WATT_L}
    J = {k: ref.WATT["J"][REF_NAME[k]] for k in WATT_L}
    (cp, ap), (cm, am) = _watt_coms(theta + h), _watt_coms(theta - h)
    per_link = {k: m[k] * np.sum(((cp[k] - cm[k]) / (2 * h)) ** 2) + J[k] * ((ap[k] - am[k]) / (2 * h)) ** 2 for k in WATT_L}
    return per_link


def _watt_potential(theta):
    coms, _ = _watt_coms(theta)
    return sum(ref.WATT["m"][REF_NAME[k]] * 9.81 * c[1] for k, c in coms.items())


def test_reduced_inertia_is_kinetic_energy_equivalent(watt_reduced):
    for i, q in enumerate(QS):
        per_link = _watt_closed_form(q)
        assert abs(watt_reduced.inertia[i] - sum(per_link.values())) < 1e-7
        # each group's own terms: the crank alone, then the dyads' links
        assert abs(watt_reduced.group_inertia["crank2"][i] - per_link["link2"]) < 1e-7
        assert abs(watt_reduced.group_inertia["dyad34"][i] - per_link["link3"] - per_link["link4"]) < 1e-7
        assert abs(watt_reduced.group_inertia["dyad56"][i] - per_link["link5"] - per_link["link6"]) < 1e-7


def test_crank_group_inertia_closed_form(watt_reduced):
    # J2 + m2 (l/2)^2 about the pivot, for every q
    np.testing.assert_allclose(watt_reduced.group_inertia["crank2"], 0.0833 + 1.0 * 0.5**2, atol=1e-12)


def test_reduced_gravity_torque_is_minus_dV_dq(watt_reduced):
    h = 1e-6
    for i, q in enumerate(QS):
        dv = (_watt_potential(q + h) - _watt_potential(q - h)) / (2 * h)
        assert abs(watt_reduced.torque[i] + dv) < 1e-6
    total = sum(watt_reduced.group_torque.values())
    np.testing.assert_allclose(watt_reduced.torque, total, atol=1e-12)


def test_dJ_dq_matches_central_differences(watt, watt_reduced):
    h = 1e-6
    plus, minus = aj.reduce(watt, jnp.asarray(QS + h)), aj.reduce(watt, jnp.asarray(QS - h))
    fd = (np.asarray(plus.inertia) - np.asarray(minus.inertia)) / (2 * h)
    np.testing.assert_allclose(watt_reduced.dinertia, fd, atol=1e-5, rtol=1e-6)


def test_slider_crank_matches_hand_derived_lagrange():
    scene = aj.load_scene("slider_crank")
    thetas = np.linspace(-3.0, 3.0, 7)
    red = aj.reduce(scene, jnp.asarray(thetas))
    for i, th in enumerate(thetas):
        _, mass, cor, dV = ref.slider_crank_lagrange(th, 0.0)
        assert abs(red.inertia[i] - mass) < 1e-12
        assert abs(0.5 * red.dinertia[i] - cor) < 1e-12
        assert abs(red.torque[i] + dV) < 1e-12


def test_reduce_is_vmappable_and_jittable(watt, watt_reduced):
    single = jax.jit(jax.vmap(lambda q: reduce_single(watt.mechanism, watt.gravity, (), q, 0.0, 0.0).inertia))
    np.testing.assert_allclose(single(jnp.asarray(QS)), watt_reduced.inertia, rtol=1e-13)


def test_velocity_dependent_reduction_damper(watt):
    """A damper between O4 and E: tau_red(w) - tau_red(0) = -c (dL/dq)^2 w (power equivalence)."""
    c, w = 3.0, 2.5
    loads = (aj.Damper("O4", "E", c),)
    q = 0.4
    r0 = aj.reduce(watt.mechanism, q, 0.0, loads=loads)
    r1 = aj.reduce(watt.mechanism, q, w, loads=loads)
    h = 1e-6

    def length(th):
        pts, _ = ref.watt_sixbar_points(th)
        return np.linalg.norm(pts["E"] - pts["O4"])

    dl = (length(q + h) - length(q - h)) / (2 * h)
    assert abs((r1.torque - r0.torque) + c * dl**2 * w) < 1e-7


def test_point_force_and_couple_reduce_by_virtual_work(watt):
    q, h = -0.8, 1e-6
    force = np.array([3.0, -2.0])
    loads = (aj.PointForce("E", force), aj.Couple("link5", 1.5))
    red = aj.reduce(watt.mechanism, q, loads=loads)
    pp, ap = ref.watt_sixbar_points(q + h)
    pm, am = ref.watt_sixbar_points(q - h)
    expected = force @ (pp["E"] - pm["E"]) / (2 * h) + 1.5 * (ap["link5"] - am["link5"]) / (2 * h)
    assert abs(red.torque - expected) < 1e-7


def test_loads_without_velocity_never_see_velocities(watt):
    seen = []

    class Spy(aj.AbstractLoad):
        velocity_dependent: bool = False

        def wrenches(self, mechanism, kin, t):
            seen.append(kin.velocities is None)
            return []

    reduce_single(watt.mechanism, watt.gravity, (Spy(),), 0.3, 1.0, 0.0)
    reduce_single(watt.mechanism, watt.gravity, (Spy(), aj.Damper("O4", "E", 1.0)), 0.3, 1.0, 0.0)
    assert seen == [True, False]
