"""Self-consistency checks of the independent joint-coordinate reference.

Each check uses a route independent of the one under test: finite differences for
the constraint derivatives, energy for the integrator, body-by-body Newton-Euler for
the reactions, a hand-derived closed-form Lagrange equation for the slider-crank, and
an elliptic-function solution for the N-four-bar.
"""

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402

def _slider_driven_offset():
    """Slider-driven rocker with the slider COM off the pin: exercises the translating
    driver row with a rotating arm (the guide still locks the rotation)."""
    m = jr.slider_driven(0.2, 0.1)
    bodies = dict(m.system.body_data)
    bodies["slider"] = dict(bodies["slider"], com_local=(0.03, 0.02), inertia=1e-3)
    return jr.Model(jr.System(bodies, m.system.joints, m.system.driver), m.initial)


def _slider_crank_loaded():
    """Slider-crank with a spring from the frame to the slider pin, a force on the slider
    and on the rod's COM, and a damper at the rod's COM: the springs and point loads."""
    loads = dict(springs=[jr.Spring("spring", jr.GROUND, (0.0, 0.05), "slider", (0.0, 0.0), 150.0, 0.1)],
                 point_loads=[jr.PointLoad("push", "slider", (0.0, 0.0), (-20.0, 15.0)),
                              jr.PointLoad("at_com", "rod", (0.15, 0.0), (12.0, -30.0))],
                 dampers=[jr.Damper("damper", jr.GROUND, (0.0, 0.0), "rod", (0.15, 0.0), 4.0)])
    return jr.with_loads(jr.slider_crank(0.5, 3.0), **loads)


MODELS = {
    "watt": lambda: jr.watt_sixbar(0.3, 1.0),
    "slider_crank": lambda: jr.slider_crank(0.5, 3.0),
    "four_bar_motor": lambda: jr.four_bar_motor(0.2, 2.0),
    "slider_driven": lambda: jr.slider_driven(0.2, 0.1),
    "quick_return": lambda: jr.quick_return(0.4, 4.0),
    "slider_driven_offset": _slider_driven_offset,
    "slider_crank_loaded": _slider_crank_loaded,
}


@pytest.fixture(scope="module")
def runs():
    """Short simulations shared by several tests."""
    return {k: f().simulate(0.5) for k, f in MODELS.items()}


def _assembled(model):
    s = model.system
    z, _ = s.newton(model.initial.q, s.to_internal(model.initial.coords))
    return s, z


@pytest.mark.parametrize("name", MODELS)
def test_jacobian_and_gamma_match_finite_differences(name):
    s, z = _assembled(MODELS[name]())
    rng = np.random.default_rng(0)
    zd = rng.normal(size=s.n)  # gamma = -(Phi_z zd)_z zd holds for any zd
    h = 1e-6
    _, J, gam = s.constraints(z, zd)
    _, row, gD = s.driver_row(z, zd)
    J_fd = np.column_stack([(s.constraints(z + h * e)[0] - s.constraints(z - h * e)[0]) / (2 * h)
                            for e in np.eye(s.n)])
    np.testing.assert_allclose(J, J_fd, atol=1e-8)
    dJ = (s.constraints(z + h * zd)[1] - s.constraints(z - h * zd)[1]) / (2 * h)
    np.testing.assert_allclose(gam, -dJ @ zd, atol=1e-7)
    drow = (s.driver_row(z + h * zd)[1] - s.driver_row(z - h * zd)[1]) / (2 * h)
    assert abs(gD + drow @ zd) < 1e-7


@pytest.mark.parametrize("name", ["watt", "slider_crank", "slider_driven", "quick_return"])
def test_energy_conserved_without_dissipation(name):
    r = MODELS[name]().simulate(2.0)
    # relative to the largest kinetic energy reached (E itself may be near zero)
    assert np.ptp(r.E) / r.T.max() < 1e-9
    assert r.residual.max() < 1e-12


def test_energy_balance_with_springs_point_loads_and_damper():
    """Springs and constant point loads are in V, the damper's power in the work."""
    r = _slider_crank_loaded().simulate(1.0)
    assert np.ptp(r.E - r.work) / r.T.max() < 1e-9
    assert np.min(r.work) < -1e-3  # the damper really dissipates
    assert np.ptp(r.V) > 1.0  # and the spring and forces really work


def test_energy_balance_with_motor_and_damper():
    r = jr.four_bar_motor().simulate(1.0)
    assert r.q[-1] > 2 * np.pi  # the motor really drives it round
    # T + V - (work of the motor + damper) is conserved
    assert np.ptp(r.E - r.work) / r.T.max() < 1e-9
    assert np.min(r.work) < np.max(r.work)


@pytest.mark.parametrize("name", MODELS)
def test_constraints_at_all_levels(name, runs):
    r, s = runs[name], runs[name].system
    for k in range(len(r.t)):
        phi, J, gam = s.constraints(r.z[k], r.zd[k])
        D, row, gD = s.driver_row(r.z[k], r.zd[k])
        assert np.abs(phi).max() < 1e-12 and abs(D - r.q[k]) < 1e-12
        assert np.abs(J @ r.zd[k]).max() < 1e-11 and abs(row @ r.zd[k] - r.w[k]) < 1e-11
        assert np.abs(J @ r.zdd[k] - gam).max() < 1e-9
        assert abs(row @ r.zdd[k] - gD - r.wdot[k]) < 1e-9


@pytest.mark.parametrize("name", MODELS)
def test_reactions_satisfy_newton_euler_per_body(name, runs):
    r, s = runs[name], runs[name].system
    for k in range(len(r.t)):
        R = {n: v[k] for n, v in r.reactions.items()}
        C = {n: v[k] for n, v in r.couples.items()}
        res = jr.newton_euler_residuals(s, r.z[k], r.zd[k], r.zdd[k], R, C, r.tau_applied[k])
        assert np.abs(res).max() < 1e-10


@pytest.mark.parametrize("name", MODELS)
def test_inverse_dynamics_recovers_applied_force(name, runs):
    r = runs[name]
    assert np.abs(r.tau_needed - r.tau_applied).max() < 1e-10


def test_state_forward_and_inverse_agree():
    m = jr.four_bar_motor()
    s = m.system
    guess = jr.four_bar_motor(1.0).initial.coords
    fwd = s.state(1.0, 4.0, guess, tau=0.7)
    inv = s.state(1.0, 4.0, guess, wdot=fwd["wdot"])
    assert inv["tau"] == pytest.approx(0.7, abs=1e-12)
    for name, f in fwd["reactions"].items():
        np.testing.assert_allclose(inv["reactions"][name], f, atol=1e-11)


def test_static_ground_reactions_carry_the_weight():
    """At rest and held still, the ground pushes up with the total weight: checks the
    'force on body_i by body_j' sign convention physically."""
    m = jr.watt_sixbar(0.7)
    s, z = _assembled(m)
    tau, lam, zd, zdd = s.inverse_dynamics(z, 0.0, 0.0)
    F, _ = s.reactions(z, lam)
    on_mech = -F["O2"] + F["O4"]  # O2 = (ground, crank), O4 = (rocker, ground)
    np.testing.assert_allclose(on_mech, [0.0, jr.G * s.mass.sum()], atol=1e-12)


def test_slider_crank_matches_closed_form_lagrange():
    m = jr.slider_crank()
    s, z = _assembled(m)
    rng = np.random.default_rng(1)
    q_prev = m.initial.q
    for th, om, tau in zip(np.linspace(0, 2 * np.pi, 13)[1:], rng.normal(0, 10, 12), rng.normal(0, 5, 12)):
        z, _, _ = s.track(th, q_prev, z)
        q_prev = th
        wdot = s.accelerations(z, om, tau)[0]
        wdot_ref, mass, cor, dV = jr.slider_crank_lagrange(th, om, tau)
        assert abs(wdot - wdot_ref) < 1e-10 * (1 + abs(wdot_ref))
        assert abs(s.inverse_dynamics(z, om, wdot_ref)[0] - tau) < 1e-10

    from scipy.integrate import solve_ivp

    motor = lambda t, q, w: 2.0 * np.cos(3 * t)  # noqa: E731
    t = np.linspace(0, 1, 21)
    ref = solve_ivp(lambda t_, y: [y[1], jr.slider_crank_lagrange(y[0], y[1], motor(t_, *y))[0]],
                    (0, 1), [0.0, 5.0], method="DOP853", t_eval=t, rtol=1e-12, atol=1e-13)
    r = jr.slider_crank(0.0, 5.0).simulate(1.0, tau=motor, t_eval=t)
    np.testing.assert_allclose(r.q, ref.y[0], atol=1e-9)
    np.testing.assert_allclose(r.w, ref.y[1], atol=1e-8)


def test_standstill_event_at_energy_turning_point():
    # From rest with the crank horizontal, V ~ sin(theta): it swings down to theta = -pi.
    r = jr.slider_crank(0.0, 0.0).simulate(5.0, standstill=+1)
    assert len(r.t_events) == 1 and 0.1 < r.t_events[0] < 5.0
    assert r.t[-1] == r.t_events[0]
    assert abs(r.q[-1] + np.pi) < 1e-6 and abs(r.w[-1]) < 1e-9
    # the opposite direction is not reached first: it runs to the end
    r2 = jr.slider_crank(0.0, 0.0).simulate(0.5, standstill=-1)
    assert len(r2.t_events) == 0


def test_n_four_bar_exact_solution():
    t = np.linspace(0, 10, 501)
    for N in (1, 4):
        th, om = jr.n_four_bar_exact(N, t)
        th2, om2 = jr.n_four_bar_ode(N, t)
        assert np.abs(th - th2).max() < 1e-9 and np.abs(om - om2).max() < 1e-9
        assert th[0] == pytest.approx(np.pi / 2) and om[0] == pytest.approx(-1.0)
        # its configurations satisfy the joint constraints and the multiplier dynamics
        m = jr.n_four_bar(N)
        s = m.system
        a = jr.n_four_bar_alpha(N)
        for k in range(0, 60, 7):  # before/around the first horizontal passage
            z = s.to_internal(jr.n_four_bar_coords(N, th[k]))
            assert np.abs(s.constraints(z)[0]).max() < 1e-14
            if abs(np.cos(th[k])) < 0.99:  # away from the singular horizontal position
                wdot, zd, *_ = s.accelerations(z, om[k])
                assert abs(wdot + a * np.cos(th[k])) < 1e-9
                T, V = s.energies(z, zd)
                z0 = s.to_internal(m.initial.coords)
                T0, V0 = s.energies(z0, s.influence(z0) * m.initial.w)
                assert abs(T + V - T0 - V0) < 1e-9


def test_watt_assembly_rules():
    for th in np.linspace(0, 2 * np.pi, 9):
        pts, _ = jr.watt_sixbar_points(th)
        assert jr._cross(pts["O4"] - pts["A"], pts["B"] - pts["A"]) > 0
        assert jr._cross(pts["D"] - pts["C"], pts["E"] - pts["C"]) > 0
        m = jr.watt_sixbar(th)
        s, z = _assembled(m)
        assert np.abs(s.to_internal(m.initial.coords) - z).max() < 1e-13
