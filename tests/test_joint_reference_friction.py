"""Checks of the joint reference with friction (tests/joint_reference_friction.py) against
independent routes: the frictionless reference (mu = 0), the energy balance, a pendulum's
scalar equation of motion written and integrated here, body-by-body Newton-Euler with the
reported loads, the friction law re-evaluated from the reported reactions, and closed-form
static friction limits (self-locking, break-away time).
"""

import os
import sys

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402
import joint_reference_friction as jf  # noqa: E402

TIGHT = dict(rtol=1e-13, atol=1e-14)


def _drive(t, q, w):
    return 0.3 * np.sin(5 * t)


def _other(model, friction):
    return jf.with_friction(model, {k: jf.Friction(**v) for k, v in friction.items()})


RUNS = {
    # sticks and breaks away twice
    "slider_crank": (lambda: jf.slider_crank(0.5, 3.0, tau=_drive), 2.0),
    "watt": (lambda: jf.watt_sixbar(0.3, 1.0), 2.0),
    # a moving guide (the block slides on the rocker)
    "quick_return": (lambda: _other(jr.quick_return(0.4, 4.0, tau=lambda t, q, w: 0.5), dict(
        O=dict(mu=0.2, radius=0.005, damping=1e-3), A=dict(mu=0.2, radius=0.005),
        P=dict(mu=0.2, length=0.03, damping=0.2), O4=dict(mu=0.2, radius=0.01))), 0.7),
    # the driver is the slider (q = x, tau a force); it swings once and sticks
    "slider_driven": (lambda: _other(jr.slider_driven(0.2, 0.1), dict(
        P=dict(mu=0.2, length=0.03, damping=0.2), B=dict(mu=0.2, radius=0.005),
        C=dict(mu=0.2, radius=0.005), O3=dict(mu=0.2, radius=0.005))), 0.5),
}


@pytest.fixture(scope="module")
def runs():
    return {name: build().simulate(t1) for name, (build, t1) in RUNS.items()}


# ----------------------------------------------------------------------------- mu -> 0
@pytest.mark.parametrize("mu", [0.0, 1e-13])
def test_vanishing_friction_reproduces_the_frictionless_reference(mu):
    """mu = 0 (no friction at all) and mu = 1e-13 (every sign switch and rest event still
    handled) against joint_reference.py's own simulation."""
    t = np.linspace(0.0, 2.0, 21)
    friction = {k: jf.Friction(mu=mu, radius=0.01, length=0.04) for k in "OABP"}
    r = jf.slider_crank(0.5, 3.0, tau=_drive, friction=friction).simulate(2.0, t_eval=t, **TIGHT)
    r0 = jr.slider_crank(0.5, 3.0).simulate(2.0, tau=_drive, t_eval=t, **TIGHT)
    np.testing.assert_allclose(r.t, t, atol=0)
    np.testing.assert_allclose(r.q, r0.q, atol=1e-10, rtol=0)
    np.testing.assert_allclose(r.w, r0.w, atol=1e-10 * np.abs(r0.w).max(), rtol=0)
    for name in r0.reactions:
        np.testing.assert_allclose(r.reactions[name], r0.reactions[name], atol=1e-8, rtol=0)
    # it reverses (never sticks) where the frictionless w first crosses zero
    assert not r.stuck.any() and len(r.event_times("rest")) >= 3
    first = jr.slider_crank(0.5, 3.0).simulate(2.0, tau=_drive, standstill=0, **TIGHT).t_events[0]
    assert abs(r.event_times("rest")[0] - first) < 1e-10


def test_watt_without_friction_matches_the_frictionless_reference():
    t = np.linspace(0.0, 1.0, 11)
    r = jf.watt_sixbar(0.3, 1.0, friction={}).simulate(1.0, t_eval=t, **TIGHT)
    r0 = jr.watt_sixbar(0.3, 1.0).simulate(1.0, t_eval=t, **TIGHT)
    np.testing.assert_allclose(r.q, r0.q, atol=1e-10, rtol=0)
    np.testing.assert_allclose(r.w, r0.w, atol=1e-10, rtol=0)


# ----------------------------------------------------------------------------- energy
@pytest.mark.parametrize("name", RUNS)
def test_energy_balance_with_friction_and_damping(name, runs):
    r = runs[name]
    assert r.work_friction[-1] < -1e-3 and r.work_damping[-1] < -1e-5  # friction really acts
    assert np.all(np.diff(r.work_friction) <= 1e-15) and np.all(np.diff(r.work_damping) <= 1e-15)
    assert np.ptp(r.balance) / r.T.max() < 1e-9


def test_the_driven_slider_crank_sticks_and_breaks_away(runs):
    r = runs["slider_crank"]
    assert len(r.event_times("stick")) == 2 and len(r.event_times("break")) == 2
    assert np.all(r.w[r.stuck] == 0.0) and np.all(r.wdot[r.stuck] == 0.0)
    # held only while the drive is within the holding range (inverse dynamics route)
    lo, hi = r.holding[r.stuck].T
    assert np.all(lo <= r.tau_applied[r.stuck] + 1e-12) and np.all(r.tau_applied[r.stuck] <= hi + 1e-12)
    # each break-away is where the drive leaves that range (at the stuck position)
    m = jf.slider_crank(0.5, 3.0, tau=_drive)
    for tb in r.event_times("break"):
        q = r.q[np.searchsorted(r.t, tb) - 1]
        lo, hi = m.holding_range(q)
        assert min(abs(_drive(tb, q, 0) - lo), abs(_drive(tb, q, 0) - hi)) < 1e-10


# ----------------------------------------------------------------------------- closed form
def _pendulum_ode(theta0, omega0, t_eval, mu, radius, damping, tau=0.0, g=jr.G):
    """The pendulum of jf.pendulum written as one scalar equation,
    J_O w' = tau - m g a cos(theta) - mu r |F| sign(w) - c w,  F = m (a_c - g),
    a_c = a (-sin, cos) w' - a (cos, sin) w^2; w' from brentq (h is increasing in w');
    solve_ivp between the zeros of w; at w = 0 it sticks if |tau - m g a cos| <= mu r m g."""
    d = jf.PENDULUM
    m, a = d["m"], d["a"]
    JO = d["J_c"] + m * a**2

    def accel(th, w, s):
        K = tau - m * g * a * np.cos(th) - damping * w

        def h(wd):
            ac = a * np.array([-np.sin(th) * wd - np.cos(th) * w**2, np.cos(th) * wd - np.sin(th) * w**2])
            return JO * wd - K + s * mu * radius * m * np.hypot(ac[0], ac[1] + g)

        wd0 = K / JO
        width = 2 * abs(h(wd0)) / (JO - mu * radius * m * a) + 1e-12
        return brentq(h, wd0 - width, wd0 + width, xtol=1e-15, rtol=4 * np.finfo(float).eps)

    t0, y, out = 0.0, np.array([theta0, omega0]), []
    t1 = t_eval[-1]
    while t0 < t1:
        if y[1] == 0.0:
            K0 = tau - m * g * a * np.cos(y[0])
            if abs(K0) <= mu * radius * m * g:  # stuck for good: the load does not change
                out += [(t, y[0], 0.0) for t in t_eval[t_eval >= t0]]
                break
            s = np.sign(K0)
        else:
            s = np.sign(y[1])
        ts = t0

        def stop(t, yy, s=s, ts=ts, a0=s * accel(y[0], 0.0, s)):
            return s * yy[1] / (t - ts) if t > ts else a0  # from rest: skip the root at ts

        stop.terminal, stop.direction = True, -1
        sol = solve_ivp(lambda t, yy: [yy[1], accel(yy[0], yy[1], s)], (t0, t1), y, method="DOP853",
                        t_eval=t_eval[t_eval >= t0], events=[stop], rtol=1e-13, atol=1e-14)
        out += [(t, q, w) for t, q, w in zip(sol.t, *sol.y) if not out or t > out[-1][0]]
        if sol.status == 1:
            t0, y = sol.t_events[0][0], np.array([sol.y_events[0][0][0], 0.0])
        else:
            t0 = t1
    return np.array(out).T


@pytest.mark.parametrize("theta0, omega0, tau", [(-np.pi / 2 + 0.8, 0.0, 0.0), (0.3, -2.0, 0.02)])
def test_pendulum_matches_its_scalar_equation(theta0, omega0, tau):
    mu, radius, damping = 0.5, 0.02, 0.002
    t = np.linspace(0.0, 2.0, 41)
    ts, th, om = _pendulum_ode(theta0, omega0, t, mu, radius, damping, tau)
    model = jf.pendulum(theta0, omega0, tau=lambda *_: tau, mu=mu, radius=radius, damping=damping)
    r = model.simulate(2.0, t_eval=t)
    np.testing.assert_allclose(ts, t, atol=0)
    np.testing.assert_allclose(r.q, th, atol=1e-9, rtol=0)
    np.testing.assert_allclose(r.w, om, atol=1e-9, rtol=0)
    assert len(r.event_times("rest")) >= 2  # it reverses at least twice
    # the pivot reaction from the body's Newton-Euler: F on the bar = m (a_c - g)
    a = jf.PENDULUM["a"]
    ac = a * np.stack([-np.sin(r.q) * r.wdot - np.cos(r.q) * r.w**2, np.cos(r.q) * r.wdot - np.sin(r.q) * r.w**2], 1)
    F_bar = jf.PENDULUM["m"] * (ac - [0.0, -jr.G])
    np.testing.assert_allclose(-r.reactions["O"], F_bar, atol=1e-9)


# ----------------------------------------------------------------------------- stiction
def test_hanging_pendulum_holds_below_and_moves_above_its_static_limit():
    """At rest hanging down the pivot carries the weight: limit mu r m g (closed form)."""
    limit = 0.5 * 0.02 * jf.PENDULUM["m"] * jr.G
    # constant load: a coarse break-away scan is enough
    held = jf.pendulum(-np.pi / 2, 0.0, tau=lambda *_: 0.99 * limit).simulate(2.0, scan=0.01)
    assert held.stuck.all() and np.all(held.w == 0.0) and np.all(held.q == -np.pi / 2)
    assert [k for _, k, _ in held.events] == ["stick"]
    np.testing.assert_allclose(jf.pendulum(-np.pi / 2).holding_range(-np.pi / 2), [-limit, limit], rtol=1e-12)
    moved = jf.pendulum(-np.pi / 2, 0.0, tau=lambda *_: 1.01 * limit).simulate(0.2)
    assert not moved.stuck[0] and moved.q.max() > -np.pi / 2 + 1e-5


def test_self_locking_slider_crank_stays_at_rest():
    """Friction larger than the drive: at rest it stays exactly at rest for 2 s (no creep,
    no chatter); a drive just above the holding limit does move it."""
    big = dict(O=jf.Friction(mu=0.5, radius=0.02), A=jf.Friction(mu=0.5, radius=0.02),
               B=jf.Friction(mu=0.5, radius=0.02), P=jf.Friction(mu=0.5, length=0.02))
    lo, hi = jf.slider_crank(1.0, 0.0, friction=big).holding_range(1.0)
    assert lo < 0.0 < 0.5 < hi
    r = jf.slider_crank(1.0, 0.0, tau=lambda *_: 0.5, friction=big).simulate(2.0, scan=0.01)
    assert r.stuck.all() and np.all(r.w == 0.0) and np.all(r.q == 1.0) and r.t[-1] == 2.0
    assert [k for _, k, _ in r.events] == ["stick"]
    moved = jf.slider_crank(1.0, 0.0, tau=lambda *_: hi + 0.01, friction=big).simulate(0.2)
    assert not moved.stuck.any() and moved.q[-1] > 1.0 + 1e-4


def test_pendulum_comes_to_rest_without_chatter():
    r = jf.pendulum(-np.pi / 2 + 0.8, 0.0).simulate(3.0, scan=0.01)
    kinds = [k for _, k, _ in r.events]
    assert kinds[-1] == "stick" and kinds.count("stick") == 1 and "break" not in kinds
    after = r.t >= r.event_times("stick")[0]
    assert after.sum() >= 2 and np.all(r.w[after] == 0.0) and np.ptp(r.q[after]) == 0.0
    # it stopped inside the dead zone |m g a cos| <= mu r m g
    assert abs(jf.PENDULUM["a"] * np.cos(r.q[-1])) <= 0.5 * 0.02


@pytest.mark.parametrize("k", [0.5, -2.0])
def test_break_away_at_the_analytical_time(k):
    r = jf.pendulum(-np.pi / 2, 0.0, tau=lambda t, q, w: k * t).simulate(0.3)
    t_star = jf.pendulum_breakaway_time(abs(k))
    assert [kind for _, kind, _ in r.events][:2] == ["stick", "break"]
    assert abs(r.event_times("break")[0] - t_star) < 1e-12
    assert np.all(r.w[r.t <= t_star] == 0.0) and np.sign(r.w[-1]) == np.sign(k)


def test_slider_crank_ramp_breaks_away_where_inverse_dynamics_says():
    """Ramp from rest: break-away (forward route: accelerations and brentq in time) where the
    ramp reaches the effort inverse dynamics needs to start moving (tau_plus)."""
    k = 2.0
    lo, hi = jf.slider_crank(1.0).holding_range(1.0)
    assert lo < hi
    r = jf.slider_crank(1.0, 0.0, tau=lambda t, q, w: lo + k * t).simulate(0.5)
    assert [kind for _, kind, _ in r.events][:2] == ["stick", "break"]
    assert abs(r.event_times("break")[0] - (hi - lo) / k) < 1e-12
    assert r.w[-1] > 0.0


# ----------------------------------------------------------------------------- bookkeeping
def _guide(system, z, jt):
    i = system.idx[jt.body_i]
    e = jr._rot(0.0 if i < 0 else z[3 * i + 2]) @ np.asarray(jt.axis_i, float)
    return e / np.linalg.norm(e)


def _sliding_point(system, z, jt):
    return system._pt(z, system.idx[jt.body_j], system._rel(jt.body_j, jt.s_j))[0]


def _point_velocity(system, z, zd, body, P):
    k = system.idx[body]
    return np.zeros(2) if k < 0 else zd[3 * k: 3 * k + 2] + jr._perp(P - z[3 * k: 3 * k + 2]) * zd[3 * k + 2]


@pytest.mark.parametrize("name", RUNS)
def test_friction_law_from_the_reported_reactions(name, runs):
    """Every reported friction load re-evaluated from the reported reactions and body rates."""
    r = runs[name]
    s = r.system
    moving = np.flatnonzero(~r.stuck)
    for jt in s.joints:
        fr = s.friction[jt.name]
        for k in moving:
            z, zd = r.z[k], r.zd[k]
            if isinstance(jt, jr.Revolute):
                om = [0.0 if b == jr.GROUND else zd[3 * s.idx[b] + 2] for b in (jt.body_i, jt.body_j)]
                u = om[0] - om[1]
                rho = fr.radius * np.linalg.norm(r.reactions[jt.name][k])
            else:
                e, P = _guide(s, z, jt), _sliding_point(s, z, jt)
                u = e @ (_point_velocity(s, z, zd, jt.body_i, P) - _point_velocity(s, z, zd, jt.body_j, P))
                N, M = r.reactions[jt.name][k] @ jr._perp(e), r.couples[jt.name][k]
                N1, N2 = N / 2 - M / fr.length, N / 2 + M / fr.length
                np.testing.assert_allclose(r.contact[jt.name][k], [N1, N2], atol=1e-10)
                np.testing.assert_allclose(r.guides[jt.name][k], e, atol=1e-14)
                rho = abs(N1) + abs(N2)
            assert abs(r.rates[jt.name][k] - u) < 1e-12
            assert abs(r.damping[jt.name][k] + fr.damping * u) < 1e-12
            if abs(u) > 1e-8:
                assert abs(r.friction[jt.name][k] + fr.mu * rho * np.sign(u)) < 1e-10 * (1 + rho)


def _friction_wrench(system, z, friction, damping):
    """Per-body (fx, fy, couple about the COM) of the joint friction loads, applied as the
    module docstring says: couples on body_i (and minus on body_j), or a force along the
    guide on body_i at the sliding point (and minus on body_j)."""
    out = np.zeros((len(system.names), 3))
    for jt in system.joints:
        if jt.name not in friction:
            continue
        f = friction[jt.name] + damping[jt.name]
        for body, sign in ((jt.body_i, 1.0), (jt.body_j, -1.0)):
            k = system.idx[body]
            if k < 0:
                continue
            if isinstance(jt, jr.Revolute):
                out[k, 2] += sign * f
            else:
                force = sign * f * _guide(system, z, jt)
                out[k, :2] += force
                out[k, 2] += jr._cross(_sliding_point(system, z, jt) - z[3 * k: 3 * k + 2], force)
    return out


@pytest.mark.parametrize("name", RUNS)
def test_reported_loads_satisfy_newton_euler_per_body(name, runs):
    r = runs[name]
    s = r.system
    for k in range(len(r.t)):
        R = {n: v[k] for n, v in r.reactions.items()}
        C = {n: v[k] for n, v in r.couples.items()}
        res = jr.newton_euler_residuals(s, r.z[k], r.zd[k], r.zdd[k], R, C, r.tau_applied[k])
        wrench = _friction_wrench(s, r.z[k], {n: v[k] for n, v in r.friction.items()},
                                  {n: v[k] for n, v in r.damping.items()})
        assert np.abs(res - wrench).max() < 1e-10


@pytest.mark.parametrize("name", RUNS)
def test_inverse_dynamics_recovers_the_applied_effort(name, runs):
    r = runs[name]
    moving = ~r.stuck
    assert np.abs(r.tau_needed[moving] - r.tau_applied[moving]).max() < 1e-10
    assert np.all(np.isnan(r.tau_needed[r.stuck]))


def test_model_forward_and_inverse_agree():
    m = jf.watt_sixbar(0.3, 1.0, tau=lambda t, q, w: 0.4)
    fwd = m.forward(1.1, -2.0)
    inv = m.inverse(1.1, -2.0, fwd["wdot"])
    assert not fwd["stuck"] and abs(inv["tau"] - 0.4) < 1e-12
    for key in ("reactions", "friction", "damping"):
        for joint, v in fwd[key].items():
            np.testing.assert_allclose(inv[key][joint], v, atol=1e-10, err_msg=f"{key} {joint}")
    # friction changes the answer: the frictionless reference at the same state differs
    s0 = jr.watt_sixbar(1.1).system
    z0 = s0.newton(1.1, s0.to_internal(jr.watt_sixbar(1.1).initial.coords))[0]
    assert abs(s0.accelerations(z0, -2.0, 0.4)[0] - fwd["wdot"]) > 1e-2


def test_stuck_loads_stay_within_the_friction_limits(runs):
    r = runs["slider_crank"]
    s = r.system
    for k in np.flatnonzero(r.stuck):
        for jt in s.joints:
            fr = s.friction[jt.name]
            if isinstance(jt, jr.Revolute):
                limit = fr.mu * fr.radius * np.linalg.norm(r.reactions[jt.name][k])
            else:
                limit = fr.mu * np.abs(r.contact[jt.name][k]).sum()
            assert abs(r.friction[jt.name][k]) <= limit * (1 + 1e-12) + 1e-15


def test_bad_friction_input_is_rejected():
    with pytest.raises(ValueError, match="unknown joints"):
        jf.slider_crank(friction=dict(Q=jf.Friction(mu=0.1)))
    with pytest.raises(ValueError, match="block length"):
        jf.slider_crank(friction=dict(P=jf.Friction(mu=0.1)))


def test_switch_events_where_the_relative_rates_reverse(runs):
    """Slider-crank closed forms: the slider's velocity vanishes at the dead centres
    (sin q = 0), the rod's angular velocity (joint B: rod on slider) where cos q = 0."""
    r = runs["slider_crank"]
    tP, tB = r.event_times("switch", "P"), r.event_times("switch", "B")
    assert len(tP) and len(tB) and len(r.event_times("switch")) == len(tP) + len(tB)
    for times, f in ((tP, np.sin), (tB, np.cos)):
        for t in times:
            k = np.flatnonzero(r.t == t)[0]  # the event is a sample (the left limit)
            assert abs(f(r.q[k])) < 1e-10
