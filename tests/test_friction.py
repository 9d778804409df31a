"""Joint friction (Coulomb with stiction, viscous joint damping): forward and inverse dynamics.

Independent checks: the frictionless package at mu = 0, the energy balance (T + V - W
with W the work of the friction and the other loads outside V), a crank hanging on a
rough pivot whose break-away time under a ramped torque is mu r m g / k in closed form,
self-locking, and central differences for the gradient in mu; and the joint-based reference
with Coulomb friction (tests/joint_reference_friction.py) on four mechanisms.
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import assurjax as aj
from scene_texts import ROUGH_ARM

MU, RADIUS, BLOCK = 0.2, 0.02, 0.05
T1 = 2.0
TIMES = np.linspace(0.0, T1, 81)


def frictions(mechanism, mu=MU, viscous=0.0):
    names = aj.joint_names(mechanism)
    return tuple(aj.JointFriction(j, mu, RADIUS, viscous=viscous) for j in names if "/" not in j) + tuple(
        aj.SlideFriction(j, mu, BLOCK, viscous=viscous) for j in names if "/" in j)


@pytest.fixture(scope="module")
def slider():
    return aj.load_scene("slider_crank")


def run(scene, mu, q0=0.5, viscous=0.0, **kw):
    """One compiled program for every mu, q0 and viscous value (they are traced)."""
    return aj.simulate(scene, loads=frictions(scene.mechanism, mu, viscous), q0=q0, stop=None, t1=T1, saveat=TIMES,
                       energies=True, rtol=1e-10, atol=1e-10, **kw)


@pytest.fixture(scope="module")
def rough(slider):
    return run(slider, MU, viscous=1e-3)


def test_falls_oscillates_and_sticks(rough):
    """From rest under gravity: it moves, loses its energy to the friction and stops for good
    (w exactly 0 and q constant from then on, no creep, no chatter)."""
    assert rough.status.startswith("reached t1"), rough.status
    moving = np.flatnonzero(rough.omega != 0.0)
    assert moving.size > 10
    last = moving[-1]
    assert rough.t[last] < 0.75 * T1
    assert np.all(rough.omega[last + 1:] == 0.0) and np.all(rough.domega[last + 1:] == 0.0)
    assert np.all(rough.q[last + 1:] == rough.q[last + 1])
    assert rough.dissipated[-1] > 0.0 and np.all(np.diff(rough.dissipated) >= -1e-12)


def test_energy_balance_closes_with_friction(rough):
    """T + V - W stays at its initial value (W: the friction's and dampers' work)."""
    scale = np.max(np.abs(rough.total))
    assert np.max(np.abs(rough.balance)) < 1e-8 * scale
    # the friction work is all dissipated work here (no other load outside V)
    np.testing.assert_allclose(rough.work, -rough.dissipated, atol=1e-12 * scale)


@pytest.mark.slow  # 29 s of compiles (stick segments with user events): the default suite ran 10:03
def test_user_events_past_a_rest_and_while_held(slider, rough):
    """User events with friction past the first rest (0.52 s): t = 0.7 s, while it swings
    back, and t = 1.7 s, while the friction holds it at rest (from ~0.95 s): each stops the
    run there, in the state the run without events has at that time."""
    for t_event, k in ((0.7, 28), (1.7, 68)):
        assert TIMES[k] == pytest.approx(t_event)
        sol = run(slider, MU, viscous=1e-3, events=(lambda t, q, w, t_event=t_event: t - t_event,))
        assert sol.event == aj.dynamics._results.USER and abs(sol.t_stop - t_event) < 1e-9, sol.status
        np.testing.assert_allclose([sol.q_final, sol.omega_final], [rough.q[k], rough.omega[k]], rtol=0, atol=1e-8)
        np.testing.assert_array_equal(sol.q[:k], rough.q[:k])  # the same segments up to there
    assert rough.omega[68] == 0.0 and rough.omega[28] != 0.0


def test_self_locking_stays_at_rest(slider):
    """With friction larger than gravity's effort the mechanism never starts: exact rest."""
    locked = run(slider, 5.0)
    assert np.all(locked.q == 0.5) and np.all(locked.omega == 0.0), locked.status
    assert np.all(np.isfinite(locked.total))


# A slider-crank whose rod (0.105 m, massless) is barely longer than its crank (0.1 m, J = 1e-3
# kg m^2 about O, no mass elsewhere): the rod's pressure angle on the slider (1 kg) reaches 72
# deg. No gravity; Coulomb friction on the slider only (mu = 0.5, friction angle 26.6 deg).
STEEP_R, STEEP_L, STEEP_J, STEEP_M, STEEP_MU = 0.1, 0.105, 1e-3, 1.0, 0.5


def steep_slider_crank():
    import tomllib
    from pathlib import Path

    d = tomllib.loads(Path(aj.__file__).with_name("scenes").joinpath("slider_crank.toml").read_text())
    d["scene"]["gravity"] = [0.0, 0.0]
    d["links"]["crank"].update(mass=0.0, inertia=STEEP_J, com=[0.0, 0.0])
    d["links"]["rod"].update(points={"A": [0.0, 0.0], "B": [STEEP_L, 0.0]}, mass=0.0, inertia=0.0, com=[0.0, 0.0])
    d["links"]["slider"].update(mass=STEEP_M)
    return aj.scene_from_dict(d)


def steep_closed_form(q, w, tau):
    """Both branches of the hand-solved slider: the rod pushes (P > 0) or pulls, the friction
    -s mu |N| with N the rod's normal component, s the slider's direction of motion. Per
    branch: (dw/dt, effective inertia, the branch's sign of P holds)."""
    def x(q):
        return STEEP_R * jnp.cos(q) + jnp.sqrt(STEEP_L**2 - (STEEP_R * jnp.sin(q)) ** 2)

    v, a2 = float(jax.grad(x)(q)), float(jax.grad(jax.grad(x))(q))
    ex, ey = math.sqrt(STEEP_L**2 - (STEEP_R * math.sin(q)) ** 2) / STEEP_L, STEEP_R * math.sin(q) / STEEP_L
    out = []
    for sigma in (1.0, -1.0):  # slider: m x'' = P ex - s mu |P ey|, crank: J dw/dt = tau - P ex v
        d = ex - math.copysign(1.0, v * w) * sigma * STEEP_MU * abs(ey)
        inertia = STEEP_J + STEEP_M * ex * v * v / d
        alpha = (tau - STEEP_M * ex * v * a2 * w * w / d) / inertia
        force = STEEP_M * (v * alpha + a2 * w * w) / d
        out.append((alpha, inertia, math.copysign(1.0, force) == sigma))
    return out


def steep_rest_verdict(q, tau, push):
    """The steep slider at rest at q (hand-solved, independent), driven by tau on its crank
    and pushed by ``push`` (N) along its guide: "rest" where some slider force P within the
    friction limit holds it (the crank at rest: tau = P ex dx/dq; the slider: |P ex + push| <=
    mu |P ey|), else the directions in which a start has a consistent branch (positive
    effective inertia, w and P of the branch's signs): "forward", "backward", or "jam"."""
    x = lambda q: STEEP_R * jnp.cos(q) + jnp.sqrt(STEEP_L**2 - (STEEP_R * jnp.sin(q)) ** 2)  # noqa: E731
    v = float(jax.grad(x)(q))
    ex, ey = math.sqrt(STEEP_L**2 - (STEEP_R * math.sin(q)) ** 2) / STEEP_L, STEEP_R * math.sin(q) / STEEP_L
    holding = tau / (ex * v)
    if abs(holding * ex + push) <= STEEP_MU * abs(holding * ey):
        return "rest"
    starts = set()
    for s in (1.0, -1.0):  # w's direction, and the sign of P
        for sigma in (1.0, -1.0):
            d = ex - math.copysign(1.0, v * s) * sigma * STEEP_MU * abs(ey)
            inertia = STEEP_J + STEEP_M * ex * v * v / d
            alpha = (tau + push * ex * v / d) / inertia
            if inertia > 0 and alpha * s > 0 and (tau - STEEP_J * alpha) / (ex * v) * sigma > 0:
                starts.add("forward" if s > 0 else "backward")
    return starts.pop() if len(starts) == 1 else "jam" if not starts else "both"


def test_a_rest_the_friction_neither_holds_nor_starts_is_a_jam():
    """From rest, the steep slider pushed along its guide and driven on its crank: where no
    friction within its limit holds it and no start has a consistent friction, the run is a
    jam at rest (it was held silently: a slider pushed against a steeper rod needs more
    friction to stay than the guide gives, and sliding away it would wedge); where a larger
    drive makes the rod press harder, the friction holds it again (the drives that hold are
    not one interval). Every case against the hand-solved slider, in one compiled program."""
    scene = steep_slider_crank()
    rough = aj.SlideFriction("slider/ground", STEEP_MU, 0.05)
    found = {}
    for q, push, tau in ((1.4, 1.0, -0.5), (1.4, 1.0, -0.2), (1.4, 1.0, 0.05), (1.4, 1.0, 0.2), (1.4, -1.0, 0.05),
                         (1.4, -1.0, 0.5), (1.0, 1.0, 0.2), (1.0, -1.0, 0.5)):
        want = steep_rest_verdict(q, tau, push)
        sol = aj.simulate(scene, loads=(aj.Drive(tau), aj.PointForce("B", [push, 0.0], link="slider"), rough), q0=q,
                          stop=None, t1=0.02, samples=5)
        if want == "jam":
            assert sol.jammed and not sol.successful and sol.status.startswith("the joint friction jams the mechanism "
                                                                               "at rest at t = 0 s"), sol.status
            assert sol.t.tolist() == [0.0] and sol.q.tolist() == [q]
        else:
            assert sol.successful and not sol.jammed, (q, push, tau, sol.status)
            moved = float(sol.q[-1]) - q
            assert {"rest": moved == 0.0, "forward": moved > 0.0, "backward": moved < 0.0}[want], (q, push, tau, want, moved)
        found[want] = found.get(want, 0) + 1
    assert found == {"rest": 4, "jam": 2, "backward": 1, "forward": 1}, found


@pytest.mark.slow  # ~10 s: a batch's program; the single runs above stay in the default suite
def test_a_batch_counts_a_jam_at_rest_apart():
    """A batch of two starts of the steep slider above: the one the friction jams at rest is counted
    apart from the one that runs to t1."""
    scene = steep_slider_crank()
    rough = aj.SlideFriction("slider/ground", STEEP_MU, 0.05)
    batch = aj.simulate(scene, loads=(aj.Drive(-0.2), aj.PointForce("B", [1.0, 0.0], link="slider"), rough),
                        q0=np.array([1.4, 1.0]), stop=None, t1=0.02, samples=5)
    assert batch.jammed.tolist() == [True, False] and "1 jammed" in batch.status and "1 reached t1" in batch.status


# slow (~23 s): the default suite ran 9:47-10:58 in CI; the jam itself is checked there by
# test_a_friction_jam_is_named and test_a_toggle_locks_where_the_effective_inertia_turns_negative
@pytest.mark.slow
def test_a_slider_driven_past_its_friction_angle_jams():
    """Self-locking: the crank drives (tau = +1 N m) the slider through a rod steeper than
    the friction allows. Against the hand-solved slider (independent): where the branch that
    holds has a positive effective inertia, the package's dw/dt is its; where it is negative
    (the crank would slow the more, the harder it is driven), the package finds no
    consistent friction (it used to take that branch). The run from q = 1 jams where
    ex = mu |ey|, sin q = l / (r sqrt(1 + mu^2)); from rest inside that zone no drive moves it."""
    from assurjax.dynamics._field import State, frictional

    scene = steep_slider_crank()
    rough = aj.SlideFriction("slider/ground", STEEP_MU, 0.05)
    negative = 0
    for tau in (1.0, -1.0):
        model = aj.Model(scene.mechanism, scene.gravity, (aj.Drive(tau), rough))
        for q in (0.3, 1.0, 1.2, 1.3, 1.571, 1.9):
            f = frictional(model, 0.0, State(jnp.asarray(q), jnp.asarray(0.5)), 1.0)
            [(alpha, inertia, _)] = [b for b in steep_closed_form(q, 0.5, tau) if b[2]]
            assert bool(f.consistent) == (inertia > 0), (tau, q, inertia)
            negative += inertia < 0
            if inertia > 0:
                assert abs(float(f.alpha) - alpha) < 1e-9 * (1.0 + abs(alpha)), (tau, q)
    assert negative == 3  # tau = +1 at q = 1.3, 1.571, 1.9
    jam = math.asin(STEEP_L / (STEEP_R * math.sqrt(1.0 + STEEP_MU**2)))
    loads = (aj.Drive(aj.Polynomial([1.0], variable="t")), rough)
    sol = aj.simulate(scene, loads=loads, q0=1.0, omega0=0.5, stop=None, t1=0.5, samples=11, rtol=1e-10, atol=1e-10)
    assert sol.status.startswith("the joint friction jams the mechanism"), sol.status
    assert sol.jammed and not sol.successful and "limit position" not in sol.status  # the crank turns fully
    assert abs(float(sol.q_final) - jam) < 1e-8 and float(sol.omega_final) > 1.0
    for tau in (1.0, 100.0):
        held = aj.simulate(scene, loads=(aj.Drive(aj.Polynomial([tau], variable="t")), rough), q0=1.4, stop=None,
                           t1=0.5, samples=11, rtol=1e-10, atol=1e-10)
        assert held.status.startswith("reached t1") and np.all(held.q == 1.4) and np.all(held.omega == 0.0)


def test_inverse_dynamics_flags_a_motion_the_friction_self_locks():
    """Inverse dynamics of the steep slider (hand-solved, independent): the rod's force P
    on the slider moving in direction s needs P (ex - s sign(P) mu |ey|) = m x''. Where the
    rod is steeper than the friction angle (ex < mu |ey|) and x'' has the sign of s, no P
    gives x'' (the friction self-locks the slider against its driven motion: no drive
    produces it), and ``friction_ok`` says so; elsewhere the driving torque is J dw/dt +
    P ex dx/dq with the branch's P."""
    scene = steep_slider_crank()
    model = aj.Model(scene.mechanism, scene.gravity, (aj.SlideFriction("slider/ground", STEEP_MU, 0.05),))
    q, w, alpha = (v.ravel() for v in np.meshgrid(np.linspace(0.15, 3.0, 20), [0.5, -0.5], [3.0, -3.0], indexing="ij"))
    x = lambda q: STEEP_R * jnp.cos(q) + jnp.sqrt(STEEP_L**2 - (STEEP_R * jnp.sin(q)) ** 2)  # noqa: E731
    v, a2 = (np.asarray(jax.vmap(f)(q)) for f in (jax.grad(x), jax.grad(jax.grad(x))))
    ex, ey = np.sqrt(STEEP_L**2 - (STEEP_R * np.sin(q)) ** 2) / STEEP_L, STEEP_R * np.sin(q) / STEEP_L
    s, xdd = np.sign(v * w), v * alpha + a2 * w * w
    clear = np.abs(ex - STEEP_MU * np.abs(ey)) > 1e-3  # not on the friction angle itself
    locked = (ex < STEEP_MU * np.abs(ey)) & (np.sign(xdd) == s)
    r = aj.reactions(model, (q, w, alpha))
    ok = np.asarray(r.friction_ok)
    assert 0 < np.count_nonzero(locked & clear) < np.count_nonzero(clear)
    np.testing.assert_array_equal(ok[clear], ~locked[clear])
    free = clear & ~locked
    force = STEEP_M * xdd / (ex - s * np.sign(xdd) * STEEP_MU * np.abs(ey))
    np.testing.assert_allclose(np.asarray(r.driving)[free], (STEEP_J * alpha + force * ex * v)[free], rtol=1e-9, atol=1e-9)
    assert bool(aj.reactions(aj.Model(scene.mechanism, scene.gravity, ()), (q, w, alpha)).friction_ok.all())


def test_a_slider_held_inside_its_friction_angle_carries_its_drive():
    """The steep slider at rest inside its self-locking zone (ex < mu |ey|) under a drive of
    +-1 N m and no other load: the friction holds it, so the pairs carry the drive (hand
    statics: the crank's torque balance gives the rod's force F along the rod, the guide's
    friction takes its component along the guide, within mu |F_y|). Its limits at rest are the
    zero root (no load but the drive), which the reactions took for the band's edges: they read
    0 N everywhere and 0 N m of drive."""
    scene = steep_slider_crank()
    q = np.array([1.25, 1.5, 1.9])
    for tau in (1.0, -1.0):
        model = aj.Model(scene.mechanism, scene.gravity, (aj.Drive(tau), aj.SlideFriction("slider/ground", STEEP_MU, 0.05)))
        r = aj.reactions(model, (q, np.zeros_like(q), np.zeros_like(q)))
        a = STEEP_R * np.stack([np.cos(q), np.sin(q)], -1)
        rod = np.stack([np.sqrt(STEEP_L**2 - a[:, 1] ** 2), -a[:, 1]], -1) / STEEP_L  # unit A -> B
        force = tau / (a[:, 0] * rod[:, 1] - a[:, 1] * rod[:, 0])  # tau + (A x (-F rod)) = 0
        on_slider = force[:, None] * rod
        assert np.all(np.abs(on_slider[:, 0]) < STEEP_MU * np.abs(on_slider[:, 1]))  # inside the zone: held
        np.testing.assert_allclose(r.driving, tau, rtol=1e-12)
        np.testing.assert_allclose(r.forces["B"], on_slider, rtol=1e-9)
        np.testing.assert_allclose(r.friction["slider/ground"], -on_slider[:, 0], rtol=1e-9)
        assert np.asarray(r.friction_ok).all()


def test_a_start_held_by_friction_is_a_standstill_at_t0(slider):
    """stop='standstill' from a start the friction holds: a standstill at t0, at rest (it
    used to run with the Coulomb signs of an assumed direction, against the motion they
    caused, and ran away to ~7e5 rad/s). Same program as the mu = 0 run below."""
    held = aj.simulate(slider, loads=frictions(slider.mechanism, 5.0), stop="standstill", t1=T1, dt=2e-3)
    assert held.t_stop == 0.0 and held.status == "standstill at t = 0 s, held there by the joint friction", held.status
    assert np.all(held.q == 0.5) and np.all(held.omega == 0.0)
    # a subnormal speed, which the compiled program flushes to 0, is a rest on the host too
    tiny = aj.simulate(slider, loads=frictions(slider.mechanism, 5.0), stop="standstill", t1=T1, dt=2e-3, omega0=5e-324)
    assert tiny.status == held.status and np.all(tiny.omega == 0.0)
    # the forward-sensitivity routes have no direction for the Coulomb signs: they say so
    loaded = aj.Scene(mechanism=slider.mechanism, gravity=slider.gravity, loads=frictions(slider.mechanism, 0.2),
                      state=slider.state, simulation=slider.simulation, outputs=slider.outputs, name=slider.name)
    with pytest.raises(aj.AssurjaxError, match="adjoint='recursive' .*adjoint='forward'"):
        aj.synthesis.standstill_time(loaded, adjoint="quadrature")


@pytest.mark.slow  # ~6 s; the default suite keeps to 10 min
def test_segment_budget_is_reported(slider, monkeypatch):
    """A run that needs more segments than the budget stops there and says so (its own
    max_steps makes it a program of its own, traced with the small budget)."""
    monkeypatch.setattr(aj.dynamics._stick, "MAX_SEGMENTS", 2)
    sol = run(slider, MU, viscous=1e-3, max_steps=4095)
    assert sol.result == aj.RESULTS.max_segments_reached and sol.t_final < T1
    assert "segments" in sol.status and "shorten the time span" in sol.status, sol.status


def triple_rocker(radius):
    """(scene, its friction loads): test_dynamics' triple rocker (no drive, no damper) with
    mu = 0.1 and friction-circle radius ``radius`` in its four pins, thrown at its limit."""
    import test_dynamics

    scene = test_dynamics.four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    return scene, tuple(scene.loads) + tuple(aj.JointFriction(j, 0.1, radius) for j in aj.joint_names(scene.mechanism))


def test_lockup_with_friction_stops_at_the_limit():
    """A triple rocker with friction in its pivots thrown into its limit position: the
    stick-slip loop stops there (the stretched dyad, closed form), naming the dyad. Pins of
    0.01 mm: the friction circles would lock the toggle 5e-11 rad short of the limit, below
    the lock-up's resolution (the distance goes with the pin radius squared: 5e-5, 5e-7 and
    5e-9 rad with 10, 1 and 0.1 mm pins; 10 mm in the test below)."""
    import test_dynamics

    scene, loads = triple_rocker(1e-5)
    sol = aj.simulate(scene, loads=loads, q0=0.9, omega0=-6.0, stop=None, t1=3.0)
    assert sol.event == aj.dynamics._results.LOCKUP and sol.failed_group == "dyad"
    assert abs(sol.q_final + test_dynamics.LIMIT) < 1e-8 and np.all(sol.q >= -test_dynamics.LIMIT - 1e-12)  # round-off


@pytest.mark.slow  # a quick-return with friction under a drive function: ~30 s to compile
def test_a_jam_where_the_effective_inertia_goes_to_zero_is_named():
    """The quick-return driven by 6 sin(2 pi t / 1.5) N m with friction in its slot and at O4:
    at t = 0.572 s dw/dt runs to -7.5e5 rad/s^2 as the effective inertia goes to 0 (det(I - S)
    2e-3 at the end, no consistent friction 1e-5 rad further on): a Painleve jam. The jam test
    probed only 5e-7 rad past the end and said 'NaN ahead' (a jam one of its possible causes)."""
    scene = aj.load_scene("quick_return")
    rough = (aj.SlideFriction("block/arm", 0.3, length=0.04), aj.JointFriction("O4", 0.3, radius=0.01))
    drive = aj.Drive(lambda q, w, t: 6.0 * jnp.sin(2 * jnp.pi * t / 1.5))
    sol = aj.simulate(scene, loads=rough + (drive,), q0=0.3, omega0=0.0, t1=0.6, stop=None, samples=7, throw=False)
    assert sol.status.startswith("the joint friction jams the mechanism at t = 0.57"), sol.status


@pytest.mark.slow  # ~8 s; the default suite keeps a jam's status (test_a_friction_jam_is_named)
def test_a_toggle_locks_where_the_effective_inertia_turns_negative():
    """The same rocker with 10 mm pins: near the stretched dyad its pins' friction circles
    take the coupler's force line, and the motion jams 5e-5 rad short of the limit (it used
    to run on with a negative effective inertia into the limit). Against the joint-based
    reference: its own forward dynamics' effective inertia (d tau / d dw/dt, from two drives)
    grows without bound as q nears the jam and is negative past it; 1 / M_eff, linear there,
    vanishes within 1e-6 rad of where the package stopped."""
    import joint_reference as jr
    import joint_reference_friction as jrf
    import test_dynamics

    scene, loads = triple_rocker(0.01)
    sol = aj.simulate(scene, loads=loads, q0=0.9, omega0=-6.0, stop=None, t1=3.0)
    assert sol.status.startswith("the joint friction jams the mechanism"), sol.status
    q_jam, w_jam = float(sol.q_final), float(sol.omega_final)
    assert 1e-5 < q_jam + test_dynamics.LIMIT < 1e-4 and w_jam < 0.0
    # the status names the limit just ahead (the stretched dyad, closed form) and a bound of its distance
    assert sol.jammed and "of a limit position (group 'dyad' (RRR)" in sol.status, sol.status
    stated = float(sol.status.split(", within ")[1].split(" of a limit")[0])
    assert q_jam + test_dynamics.LIMIT <= stated < 10 * (q_jam + test_dynamics.LIMIT) * (1 + abs(q_jam))
    reference = jrf.with_friction(jr.four_bar_motor(0.9, -6.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0), T_stall=0.0,
                                                    damper_c=0.0), {j: jrf.Friction(mu=0.1, radius=0.01) for j in ("O2", "A", "B", "O4")})
    assert_reference_locks_at(reference, q_jam, w_jam, drive=0.0)


def assert_reference_locks_at(reference, q_jam, w_jam, drive):
    """The joint-based reference's own forward dynamics at the package's jam (q_jam, reached
    moving at w_jam under a constant ``drive``): its effective inertia (d tau / d dw/dt, from
    two drives) is positive and grows as q nears q_jam from the side the motion came from,
    and is negative past it; 1 / M_eff, linear there, vanishes within 1e-6 rad of q_jam."""

    def inertia(q):
        wdot = [reference.forward(q, w_jam, tau=lambda t, q, w, d=d: drive + d)["wdot"] for d in (-1e-3, 1e-3)]
        return 2e-3 / (wdot[1] - wdot[0])

    back = -np.sign(w_jam)  # towards the side it came from
    before, nearer = inertia(q_jam + back * 1e-5), inertia(q_jam + back * 3e-6)
    assert 0.0 < before < nearer and inertia(q_jam - back * 1e-6) < 0.0 and inertia(q_jam - back * 1e-5) < 0.0
    slope = (1.0 / before - 1.0 / nearer) / 7e-6
    assert abs(3e-6 - (1.0 / nearer) / slope) < 1e-6


# tests/joint_reference.py two_dead_points: the rocker and the second rocker at dead points together at q = 0
TWO_DEAD_POINTS = """
[scene]
name = "two_dead_points"
gravity = [0.0, -9.81]
[ground]
O2 = [0.0, 0.0]
O4 = [0.4, -0.25]
O6 = [0.6, 0.25]
[links.crank]
points = { O2 = [0.0, 0.0], A = [0.1, 0.0] }
com = [0.05, 0.0]
mass = 0.5
inertia = 0.0005
[links.coupler]
points = { A = [0.0, 0.0], B = [0.3, 0.0] }
com = [0.15, 0.0]
mass = 1.0
inertia = 0.0075
[links.rocker]
points = { O4 = [0.0, 0.0], B = [0.25, 0.0], C = [0.3, 0.0] }
com = [0.15, 0.0]
mass = 1.0
inertia = 0.0075
[links.link5]
points = { C = [0.0, 0.0], D = [0.2, 0.0] }
com = [0.1, 0.0]
mass = 0.5
inertia = 0.002
[links.link6]
points = { O6 = [0.0, 0.0], D = [0.2, 0.0] }
com = [0.1, 0.0]
mass = 0.5
inertia = 0.002
[[formation]]
group = "crank"
link = "crank"
pivot = "O2"
[[formation]]
group = "RRR"
name = "dyad34"
links = ["coupler", "rocker"]
joints = ["A", "O4", "B"]
mode = "left"
[[formation]]
group = "RRR"
name = "dyad56"
links = ["link5", "link6"]
joints = ["C", "O6", "D"]
mode = "left"
"""


@pytest.mark.slow  # ~20 s: a new six-bar compiled, and the jam status program
def test_a_start_on_two_dead_points_then_a_jam():
    """Two four-bars in series whose dead points coincide at q = 0, friction in all seven
    pins (10 mm, mu = 0.2), from q = 0 at 6 rad/s under 3 N m: at the start the rocker's pin
    rate crosses 0 and the second rocker's pin rate vanishes like q^3 (its sign is read from
    round-off there). The motion agrees with the joint-based reference to 5e-10 rad over the
    first 0.1 s (q to 1.3 rad; measured 6e-11, and 1.1e-9 with that pin's sign forced to 0
    at the start); then the second four-bar self-locks at q ~ 1.377. There the
    reference's own forward dynamics has an effective inertia (d tau / d dw/dt) that grows
    without bound before the package's jam and is negative past it; 1 / M_eff, linear there,
    vanishes within 1e-6 rad of where the package stopped."""
    import tomllib

    import joint_reference as jr
    import joint_reference_friction as jrf

    scene = aj.scene_from_dict(tomllib.loads(TWO_DEAD_POINTS))
    table = {j: jrf.Friction(mu=0.2, radius=0.01, damping=1e-3) for j in ("O2", "A", "B", "O4", "C", "D", "O6")}
    loads = _package_frictions(scene.mechanism, table) + (aj.Drive(3.0),)
    times = np.linspace(0.0, 0.1, 21)
    sol = aj.simulate(scene, loads=loads, q0=0.0, omega0=6.0, stop=None, t1=0.3, saveat=times, rtol=1e-10, atol=1e-10)
    reference = jrf.with_friction(jr.two_dead_points(0.0, 6.0, tau=lambda t, q, w: 3.0), table)
    expected = reference.simulate(0.1, t_eval=times)
    assert expected.q[-1] > 1.2
    np.testing.assert_allclose(sol.q[:times.size], expected.q, rtol=0, atol=5e-10)
    assert sol.status.startswith("the joint friction jams the mechanism"), sol.status
    assert_reference_locks_at(reference, float(sol.q_final), float(sol.omega_final), drive=3.0)


@pytest.mark.slow  # ~7 s (and the lighter press below): the default suite keeps to 10 min
def test_a_heavier_mechanism_moves_the_same(slider):
    """Every mass and inertia 1e5 times larger scales every force, the friction included, by
    1e5: the same motion. The friction solves' absolute tolerance was capped at 1 N m, which
    elements with small reactions beside 1e5 N m ones could not meet (their round-off is the
    mechanism's force scale times epsilon): a jam reported at t = 0.15 s."""
    names = list(slider.mechanism.links)
    heavy = eqx.tree_at(lambda m: [m.links[n].mass for n in names] + [m.links[n].inertia for n in names], slider.mechanism,
                        [1e5 * slider.mechanism.links[n].mass for n in names] + [1e5 * slider.mechanism.links[n].inertia for n in names])
    loads = tuple(aj.JointFriction(j, 0.6, 0.05) for j in ("O", "A", "B"))
    light, heavy = (aj.simulate(slider, mechanism=m, loads=loads, stop=None, t1=1.0, samples=51) for m in (slider.mechanism, heavy))
    assert light.status == heavy.status and heavy.status.startswith("reached t1 = 1 s"), heavy.status
    np.testing.assert_allclose(heavy.q, light.q, rtol=0, atol=1e-7)


def test_zero_friction_reproduces_the_frictionless_motion(slider):
    """mu = 0 on every pair: with the same (fixed) steps up to the first standstill, the same
    motion as without friction to round-off; past it, the stick-slip segments (adaptive)
    agree with the frictionless run to the solver's tolerance."""
    plain = aj.simulate(slider, stop="standstill", t1=T1, dt=2e-3)
    smooth = aj.simulate(slider, loads=frictions(slider.mechanism, 0.0), stop="standstill", t1=T1, dt=2e-3)
    np.testing.assert_allclose(smooth.q, plain.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(smooth.t_stop, plain.t_stop, rtol=0, atol=1e-12)
    free = aj.simulate(slider, stop=None, t1=T1, saveat=TIMES, rtol=1e-10, atol=1e-10)
    segmented = run(slider, 0.0)
    np.testing.assert_allclose(segmented.q, free.q, rtol=0, atol=1e-7)


HANGING = """
[scene]
name = "rough_pendulum"
gravity = [0.0, -9.81]
[state]
q0 = -1.5707963267948966
t1 = 1.0
[[loads]]
type = "drive"
value = { polynomial = [0.0, 0.5], variable = "t" }
""" + ROUGH_ARM


def test_breakaway_at_the_static_limit(write_scene):
    """An arm hanging on a rough pivot under a torque k t: at rest the pivot carries m g, so
    it breaks away when k t = mu r m g, not before (exact rest), and moves right after."""
    scene = aj.load_scene(write_scene(HANGING))
    t_star = 0.3 * 0.04 * 2.0 * 9.81 / 0.5
    eps = 1e-6
    sol = aj.simulate(scene, saveat=np.array([0.0, 0.5 * t_star, t_star - eps, t_star + eps, 0.9]), stop=None,
                      rtol=1e-11, atol=1e-11)
    assert np.all(sol.q[:3] == scene.state["q0"]) and np.all(sol.omega[:3] == 0.0)
    assert sol.omega[3] > 0.0 and sol.q[4] > scene.state["q0"] + 1e-3


@pytest.mark.slow  # reverse and forward mode through stick segments: ~1 min of compiles
def test_gradient_in_mu_through_a_breakaway(write_scene):
    """d q(0.9 s) / d mu of the arm under the ramped torque: held from t0 (its first segment
    ends at its first step, which stays at rest), a stick segment until the located
    break-away at mu r m g / k, then the swing: reverse and forward mode against central
    differences."""
    scene = aj.load_scene(write_scene(HANGING))
    ramp = tuple(load for load in scene.loads if isinstance(load, aj.Drive))

    def q_at(mu, adjoint="recursive"):
        rough = scene.with_loads(ramp + (aj.JointFriction("O", mu, 0.04),))
        return aj.synthesis.final_state(rough, 0.9, rtol=1e-11, atol=1e-11, adjoint=adjoint)[0]

    mu, h = jnp.asarray(0.3), 1e-6
    fd = (q_at(mu + h) - q_at(mu - h)) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(q_at)(mu)), float(fd), rtol=1e-6)
    np.testing.assert_allclose(float(jax.jacfwd(lambda m: q_at(m, "forward"))(mu)), float(fd), rtol=1e-6)


def test_backsolve_with_friction_is_a_clear_error(write_scene):
    """diffrax's backsolve adjoint cannot save a segment's outputs as the segments do: an
    error that names the adjoint and the ones to use, not diffrax's NotImplementedError."""
    scene = aj.load_scene(write_scene(HANGING))
    with pytest.raises(aj.AssurjaxError, match="adjoint 'backsolve' is not available with joint friction"):
        jax.grad(lambda mu: aj.synthesis.final_state(
            scene.with_loads(scene.loads[:1] + (aj.JointFriction("O", mu, 0.04),)), 0.9, adjoint="backsolve")[0])(0.3)


@pytest.mark.slow  # ~11 s; the default suite keeps the break-away under a scene torque
def test_breakaway_under_a_torque_given_as_a_function(write_scene):
    """The same arm under the same torque k t given as a Python function: a function is never
    assumed constant in time (the stick segment stays), so it breaks away at the same time."""
    scene = aj.load_scene(write_scene(HANGING))
    ramp = aj.Drive(Forcing(ramp=0.5))  # a callable module (its numbers traced: forced_arm's program)
    loads = (ramp,) + tuple(load for load in scene.loads if not isinstance(load, aj.Drive))
    assert ramp.may_depend_on_time() and not any(load.may_depend_on_time() for load in loads[1:])
    t_star = 0.3 * 0.04 * 2.0 * 9.81 / 0.5
    eps = 1e-6
    sol = forced_arm(scene, Forcing(ramp=0.5), np.array([0.0, t_star - eps, t_star + eps, 0.9]))
    assert np.all(sol.q[:2] == scene.state["q0"]) and np.all(sol.omega[:2] == 0.0)
    assert sol.omega[2] > 0.0 and sol.q[3] > scene.state["q0"] + 1e-3
    # with a constant torque below the limit it stays at rest to t1 (no stick segment in the program)
    held = aj.simulate(scene, loads=(aj.Drive(0.5 * 0.9 * t_star),) + loads[1:], saveat=np.array([0.0, 0.5, 1.0]), stop=None)
    assert np.all(held.q == scene.state["q0"]) and np.all(held.omega == 0.0) and held.status.startswith("reached t1")


class Forcing(eqx.Module):
    """A torque (N m) ramp t + (amp0 + amp_rate t) sin(freq t) + height exp(-((t - center) / width)^2)
    whose numbers are traced: the tests on the arm share one compiled program."""

    amp0: jax.Array
    amp_rate: jax.Array
    freq: jax.Array
    height: jax.Array
    center: jax.Array
    width: jax.Array
    ramp: jax.Array

    def __init__(self, amp0=0.0, amp_rate=0.0, freq=0.0, height=0.0, center=0.0, width=1.0, ramp=0.0):
        values = (amp0, amp_rate, freq, height, center, width, ramp)
        self.amp0, self.amp_rate, self.freq, self.height, self.center, self.width, self.ramp = (
            jnp.asarray(v, dtype=float) for v in values)

    def __call__(self, q, omega, t):
        return (self.ramp * t + (self.amp0 + self.amp_rate * t) * jnp.sin(self.freq * t)
                + self.height * jnp.exp(-(((t - self.center) / self.width) ** 2)))


ARM_LIMIT = 0.3 * 0.04 * 2.0 * 9.81  # mu r m g (N m): the pivot carries m g at rest


def forced_arm(scene, forcing, times):
    loads = tuple(load for load in scene.loads if not isinstance(load, aj.Drive)) + (aj.Drive(forcing),)
    return aj.simulate(scene, loads=loads, saveat=times, stop=None, rtol=1e-11, atol=1e-11)


def assert_breaks_away_at(sol, q0, direction):
    """Saved at t* - eps, t* + eps, then later: exactly at rest, then moving in ``direction``."""
    assert sol.q[0] == q0 and sol.omega[0] == 0.0
    assert direction * sol.omega[1] > 0.0 and direction * (sol.q[2] - q0) > 1e-4


@pytest.mark.slow  # ~8 s; the break-away at the static limit stays in the default suite
def test_a_short_pulse_of_torque_breaks_the_arm_away(write_scene):
    """A pulse 2 L exp(-((t - 0.5) / 0.05)^2) on the arm held at rest (L its static limit)
    breaks it away where the pulse reaches L, t* = 0.5 - 0.05 sqrt(ln 2) (closed form); a
    stick segment whose steps grew unchecked stepped over it and kept the arm at rest to t1.
    A pulse of 0.9 L leaves it exactly at rest."""
    scene = aj.load_scene(write_scene(HANGING))
    q0, eps = scene.state["q0"], 1e-6
    t_star = 0.5 - 0.05 * math.sqrt(math.log(2.0))
    times = np.array([t_star - eps, t_star + eps, 0.6, 1.0])
    assert_breaks_away_at(forced_arm(scene, Forcing(height=2 * ARM_LIMIT, center=0.5, width=0.05), times), q0, 1.0)
    held = forced_arm(scene, Forcing(height=0.9 * ARM_LIMIT, center=0.5, width=0.05), times)
    assert np.all(held.q == q0) and np.all(held.omega == 0.0) and held.status.startswith("reached t1")


@pytest.mark.slow  # ~7 s; a short pulse's break-away stays in the default suite
def test_a_pulse_shorter_than_the_steps_needs_max_step(write_scene):
    """A pulse of width 0.01 s: the controller's first steps grow past it, as an ODE solve
    steps over any forcing its stages do not sample (the arm stays at rest); with
    max_step = 2 ms the steps sample it and the arm breaks away at t* = 0.5 - 0.01 sqrt(ln 2)."""
    scene = aj.load_scene(write_scene(HANGING))
    q0, eps = scene.state["q0"], 1e-6
    t_star = 0.5 - 0.01 * math.sqrt(math.log(2.0))
    times = np.array([t_star - eps, t_star + eps, 0.6, 1.0])
    forcing = Forcing(height=2 * ARM_LIMIT, center=0.5, width=0.01)
    assert np.all(forced_arm(scene, forcing, times).omega == 0.0)
    loads = tuple(load for load in scene.loads if not isinstance(load, aj.Drive)) + (aj.Drive(forcing),)
    sol = aj.simulate(scene, loads=loads, saveat=times, stop=None, rtol=1e-11, atol=1e-11, max_step=2e-3)
    assert_breaks_away_at(sol, q0, 1.0)
    with pytest.raises(aj.AssurjaxError, match="'max_step' bounds the adaptive steps"):
        aj.simulate(scene, loads=loads, dt=1e-3, max_step=2e-3)
    with pytest.raises(aj.AssurjaxError, match="setting 'max_step': expected a positive finite step"):
        aj.simulate(scene, loads=loads, max_step=-1.0)


@pytest.mark.slow  # ~10 s; test_breakaway_at_the_static_limit keeps the break-away under a torque in time by default
def test_a_torque_that_reverses_while_held_breaks_away_the_other_way(write_scene):
    """L (0.5 + 2 t) sin(4 pi t): below the limit over its first half period (at most 0.76 L),
    so the arm stays; then negative, it reaches -L at t* (found by brentq on the closed form)
    and the arm breaks away downwards. The direction that can start flips with the torque
    while the arm is held, and the break-away margin with it."""
    scene = aj.load_scene(write_scene(HANGING))
    q0, eps = scene.state["q0"], 1e-6
    t_star = brentq(lambda t: (0.5 + 2 * t) * math.sin(4 * math.pi * t) + 1.0, 0.25, 0.375)
    times = np.array([t_star - eps, t_star + eps, t_star + 0.1, 1.0])
    forcing = Forcing(amp0=0.5 * ARM_LIMIT, amp_rate=2 * ARM_LIMIT, freq=4 * math.pi)
    assert_breaks_away_at(forced_arm(scene, forcing, times), q0, -1.0)


def holding_band(model, q, t, alpha=1e-9):
    """(tau_minus, tau_plus): the driving efforts at the break-away limits at rest at q, by
    inverse dynamics at dw/dt = -/+ alpha (the effort that just starts each way)."""
    return tuple(np.asarray(r.driving) for r in _starts(model, q, t, alpha))


def _starts(model, q, t, alpha):
    q, t = np.atleast_1d(q), np.atleast_1d(t)
    return [aj.reactions(model, (q, np.zeros_like(q), np.full_like(q, a), t)) for a in (-alpha, alpha)]


def assert_held_within_the_band(model, q, t, applied):
    """At rest, the drive within the band between the break-away limits, except on a side
    whose start the friction self-locks (``friction_ok`` False there: no drive starts it that
    way, and friction alone holds it)."""
    lo, hi = _starts(model, q, t, 1e-9)
    inside = ((applied >= np.asarray(lo.driving) - 1e-9) | ~np.asarray(lo.friction_ok)) & (
        (applied <= np.asarray(hi.driving) + 1e-9) | ~np.asarray(hi.friction_ok))
    assert np.all(inside), (q[~inside], applied[~inside], np.asarray(lo.driving)[~inside], np.asarray(hi.driving)[~inside])


def assert_moves_as_the_drive_accelerates_it(model, q, w, dw, t, applied):
    """Along a motion: the friction has a consistent solution (inverse dynamics), the
    effective inertia d(driving)/d(dw/dt) is positive (by differences), and the drive the
    motion needs differs from the one applied by no more than 1e-9 (1 + |dw/dt|) of
    acceleration (read in accelerations: next to a jam the effective inertia grows without
    bound, 1e8 on the tangent drive with mu ~ 0.7)."""
    state = (q, w, dw, t)
    found = aj.reactions(model, state)
    assert bool(np.all(np.asarray(found.friction_ok)))
    step = 1e-4 * (1.0 + np.abs(dw))
    up, down = (np.asarray(aj.reactions(model, (q, w, dw + h, t)).driving) for h in (step, -step))
    inertia = (up - down) / (2 * step)
    assert np.all(inertia > 0)
    np.testing.assert_array_less(np.abs(np.asarray(found.driving) - applied) / inertia, 1e-9 * (1.0 + np.abs(dw)))


@pytest.mark.slow  # seven programs with stick segments: ~7 min
@pytest.mark.parametrize("seed, name, mu_range", [(0, "slider_crank", (0.1, 0.5)), (1, "watt_sixbar", (0.1, 0.5)),
                                                  (2, "quick_return", (0.1, 0.5)), (3, "tangent_drive", (0.1, 0.5)),
                                                  (4, "triad_mechanism", (0.1, 0.5)), (3, "tangent_drive", (0.5, 1.3)),
                                                  (5, "quick_return", (0.5, 1.3))])
def test_stick_slip_under_random_varying_drives_agrees_with_inverse_dynamics(seed, name, mu_range):
    """Stress: friction in every pair (mu drawn from ``mu_range``), from rest at a random q0,
    under a drive tau_mid + A sin(f t) (tau_mid the middle of the holding band at q0, A 0.5-2
    times its half-width): 2 s with holds, break-aways and reversals, four draws in one
    program. Checked by other routes: where it moves, inverse dynamics of the simulated motion
    needs the drive applied (to 1e-9 of acceleration) with a consistent friction and a positive
    effective inertia; wherever it is held the drive lies within the holding band at q (or
    past a side whose start the friction self-locks); the energy balance closes (1e-8 of the
    largest energy). Moderate friction (mu <= 0.5) runs to t1, both held and moving, and the
    needed drive is the applied one to 1e-9 N m as well. Strong friction (mu 0.5-1.3: the
    tangent drive's law has several roots, its starts self-lock, its motions can jam) may end
    in a jam, which the motion up to it must show: a run that ends so has moved."""
    scene, rng = aj.load_scene(name), np.random.default_rng(seed)
    moderate = mu_range[1] <= 0.5
    held_samples = moving_samples = 0
    for _ in range(4):
        q0, mu = float(scene.state.get("q0", 0.0)) + rng.uniform(-0.3, 0.3), rng.uniform(*mu_range)
        rough = aj.Model(scene.mechanism, scene.gravity, scene.loads + frictions(scene.mechanism, mu, viscous=1e-3))
        (lo,), (hi,) = holding_band(rough, q0, 0.0)
        forcing = Forcing(amp0=0.5 * abs(hi - lo) * rng.uniform(0.5, 2.0), freq=rng.uniform(2.0, 8.0), height=0.5 * (lo + hi),
                          center=0.0, width=1e6)
        model = aj.Model(scene.mechanism, scene.gravity, rough.loads + (aj.Drive(forcing),))
        sol = aj.simulate(model, q0=q0, omega0=0.0, t1=2.0, stop=None, samples=201, energies=True, rtol=1e-10, atol=1e-10)
        jammed = sol.status.startswith("the joint friction jams")
        assert sol.status.startswith("reached t1") or (jammed and not moderate), sol.status
        valid = np.asarray(sol.valid)
        t, q, w, dw = (np.asarray(v)[valid] for v in (sol.t, sol.q, sol.omega, sol.domega))
        held, applied = (w == 0.0) & (dw == 0.0), np.asarray(forcing(None, None, jnp.asarray(t)))
        # a jam's end state is where the friction loses its consistent solution: the motion up to it
        moving = ~held & ~(jammed & (t == float(sol.t_final)))
        assert not jammed or np.any(moving)
        if np.any(moving):
            assert_moves_as_the_drive_accelerates_it(rough, q[moving], w[moving], dw[moving], t[moving], applied[moving])
        if moderate:
            driving = np.asarray(aj.reactions(rough, (q, w, dw, t)).driving)
            np.testing.assert_allclose(driving[moving], applied[moving], rtol=1e-9, atol=1e-9 * np.max(np.abs(applied)))
        if np.any(held):
            assert_held_within_the_band(rough, q[held], t[held], applied[held])
        total = np.asarray(sol.total)[valid]
        assert np.max(np.abs(np.asarray(sol.balance)[valid])) <= 1e-8 * max(np.max(np.abs(total)), 1e-12)
        held_samples, moving_samples = held_samples + np.count_nonzero(held[1:]), moving_samples + np.count_nonzero(moving)
    assert held_samples > 0 and (moving_samples > 0 or not moderate)


def test_inverse_dynamics_at_rest_takes_the_least_drive_within_the_stiction_band(write_scene):
    """The hanging arm held at rest at angle theta (omega = alpha = 0): gravity's moment about
    the pivot is -m g l_G cos(theta), the pin carries m g, and any drive within the friction
    limit mu r m g of balancing it keeps the arm at rest: the least drive is 0 inside that band,
    the excess beyond it outside (closed form). At the start of a motion (omega = 0,
    alpha != 0) the friction is that of the motion that starts."""
    scene = aj.load_scene(write_scene(HANGING))
    model = aj.Model(scene.mechanism, scene.gravity, tuple(load for load in scene.loads if not isinstance(load, aj.Drive)))
    m, g, l_g, limit = 2.0, 9.81, 0.15, 0.3 * 0.04 * 2.0 * 9.81
    theta = np.array([-math.pi / 2 + 0.05, -math.pi / 2 - 0.07, -math.pi / 2 + 0.3, 0.3, math.pi - 0.3, -0.2])
    r = aj.reactions(model, (theta, np.zeros_like(theta), np.zeros_like(theta)))
    gravity = -m * g * l_g * np.cos(theta)
    expected = -np.sign(gravity) * np.maximum(np.abs(gravity) - limit, 0.0)
    assert np.count_nonzero(expected == 0.0) == 2
    np.testing.assert_allclose(r.driving, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r["O"], np.broadcast_to([0.0, m * g], (theta.size, 2)), rtol=0, atol=1e-12)
    # the pivot's friction couple carries the rest of the balance (within +-limit), and takes no power at rest
    np.testing.assert_allclose(r.friction["O"], -gravity - expected, rtol=0, atol=1e-12)
    assert np.all(np.abs(r.friction["O"]) <= limit * (1 + 1e-12)) and np.all(r.friction_power["O"] == 0.0)
    # breaking away (alpha > 0 from rest at theta = -pi/2 + 0.3): kinetic friction against the start
    alpha, inertia = 2.0, 0.015 + m * l_g**2
    start = aj.reactions(model, (theta[2:3], np.zeros(1), np.full(1, alpha)))
    pin = np.hypot(m * l_g * alpha * np.sin(theta[2]), m * g + m * l_g * alpha * np.cos(theta[2]))  # |m (a_G - g)|
    np.testing.assert_allclose(start.driving, inertia * alpha - gravity[2] + 0.3 * 0.04 * pin, rtol=1e-12)
    # with the scene's drive k t (k = 0.5 N m/s): held, the drive it has where the band holds it
    # (the least drive was reported, as if there were none), the nearest edge where it is outside
    t = np.full(theta.shape, 0.2)
    driven = aj.reactions(scene, (theta, np.zeros_like(theta), np.zeros_like(theta), t))
    band = np.stack([-gravity - limit, -gravity + limit], axis=-1)
    np.testing.assert_allclose(driven.driving, np.clip(0.5 * 0.2, band[:, 0], band[:, 1]), rtol=0, atol=1e-12)
    assert 0 < np.count_nonzero(np.abs(driven.driving - 0.1) < 1e-12) < theta.size  # inside and outside
    np.testing.assert_allclose(driven.friction["O"], -gravity - driven.driving, rtol=0, atol=1e-12)


def test_breakaway_band_against_closed_forms_and_the_joint_based_reference(write_scene):
    """``breakaway_band``: the drives at which a start from rest goes each way. The hanging
    arm: m g l_G cos(theta) -+ mu r m g (closed form), and without its friction both edges
    m g l_G cos(theta) (the scene's drive is not counted: the band is what the driver must
    supply). The slider-crank with friction in every pair: the joint-based reference's
    holding range (inverse dynamics at rest with each start's Coulomb signs, in absolute
    coordinates with multipliers) round the turn. The steep slider (hand-solved): where the
    rod is steeper than the friction angle (ex < mu |ey|) no push starts the slider either
    way, both edges infinite, though at dw/dt = 0 the friction has a root (zero force);
    elsewhere, with no load and no gravity, both are 0."""
    import joint_reference_friction as jrf

    arm = aj.load_scene(write_scene(HANGING))
    theta = np.array([-math.pi / 2 + 0.05, -math.pi / 2 - 0.07, 0.3, math.pi - 0.3, -2.0])
    lower, upper = aj.breakaway_band(arm, theta)
    holding = 2.0 * 9.81 * 0.15 * np.cos(theta)  # the drive that balances gravity
    np.testing.assert_allclose(lower, holding - ARM_LIMIT, rtol=0, atol=1e-12)
    np.testing.assert_allclose(upper, holding + ARM_LIMIT, rtol=0, atol=1e-12)
    for edge in aj.breakaway_band(arm.with_loads(()), theta):  # no friction: no band, gravity's balance
        np.testing.assert_allclose(edge, holding, rtol=0, atol=1e-12)

    scene, table = aj.load_scene("slider_crank"), jrf.SLIDER_CRANK_FRICTION
    model = aj.Model(scene.mechanism, scene.gravity, tuple(scene.loads) + _package_frictions(scene.mechanism, table))
    q = np.array([-2.9, -2.0, -1.1, -0.3, 0.4, 1.3, 2.2, 2.95])  # not on a dead point (the slider's rate 0)
    expected = np.array([jrf.slider_crank(0.5, 0.0).holding_range(qi) for qi in q])
    assert np.all(expected[:, 1] - expected[:, 0] > 0.01)  # the friction holds over a band
    np.testing.assert_allclose(np.stack(aj.breakaway_band(model, q), axis=-1), expected, rtol=0, atol=1e-10)

    steep = steep_slider_crank()
    model = aj.Model(steep.mechanism, steep.gravity, (aj.SlideFriction("slider/ground", STEEP_MU, 0.05),))
    q = np.array([0.3, 1.2, 1.4, 1.9, 2.5, -1.4])
    ex, ey = np.sqrt(STEEP_L**2 - (STEEP_R * np.sin(q)) ** 2) / STEEP_L, STEEP_R * np.sin(q) / STEEP_L
    wedged = ex < STEEP_MU * np.abs(ey)
    assert 0 < np.count_nonzero(wedged) < q.size
    lower, upper = aj.breakaway_band(model, q)
    np.testing.assert_array_equal(lower, np.where(wedged, -np.inf, 0.0))
    np.testing.assert_array_equal(upper, np.where(wedged, np.inf, 0.0))
    # drawn without masses: no dw/dt to test a start by; the statics' own test wedges it alike
    links = {k: eqx.tree_at(lambda l: (l.mass, l.inertia), v, (0.0 * v.mass, 0.0 * v.inertia))
             for k, v in steep.mechanism.links.items()}
    massless = eqx.tree_at(lambda m: m.mechanism.links, model, links)
    for edge, expected in zip(aj.breakaway_band(massless, q), (lower, upper)):
        np.testing.assert_array_equal(edge, expected)


# the rough arm drawn without masses (kinematics and statics only), a force at its tip A
ARM_FORCE = np.array([2.0, -10.0])
MASSLESS_ARM = f"""
[scene]
name = "massless_arm"
gravity = [0.0, -9.81]
[state]
q0 = 0.3
[[loads]]
type = "force"
point = "A"
force = [{ARM_FORCE[0]}, {ARM_FORCE[1]}]
""" + ROUGH_ARM.replace("mass = 2.0", "mass = 0.0").replace("inertia = 0.015", "inertia = 0.0")


def test_the_band_of_a_drawing_without_masses_is_its_statics(write_scene, capsys):
    """Without masses the band's edges have no dw/dt to be tested by (J_red = 0: each came out
    infinite, and ``reactions --static`` said the friction self-locks it): the massless arm
    with a force F at its tip A, its pivot carrying F alone, holds between -(r_A x F) -+ mu r
    |F| (closed form); the command line prints that band."""
    from assurjax.cli import main

    path = write_scene(MASSLESS_ARM)
    q = np.array([0.3, 2.0, -2.5])
    tip = 0.3 * np.stack([np.cos(q), np.sin(q)], axis=-1)
    holding = -(tip[:, 0] * ARM_FORCE[1] - tip[:, 1] * ARM_FORCE[0])
    limit = 0.3 * 0.04 * np.hypot(*ARM_FORCE)
    scene = aj.load_scene(path)
    band = np.array([aj.breakaway_band(scene, qi) for qi in q])  # one q at a time: the program the CLI calls
    np.testing.assert_allclose(band, np.stack([holding - limit, holding + limit], axis=-1), rtol=0, atol=1e-12)
    assert main(["reactions", str(path), "--static"]) == 0
    text = capsys.readouterr().out
    assert (f"starts forward above {holding[0] + limit:+.6g} N m and backward below {holding[0] - limit:+.6g} N m"
            in text) and "self-locks" not in text


def test_a_mechanism_held_by_friction_needs_no_drive(slider, rough):
    """Where the rough slider-crank has come to rest and the friction holds it (the forward
    dynamics' stiction test), the inverse dynamics at those states needs no drive either."""
    scene = slider.model
    model = aj.Model(scene.mechanism, scene.gravity, frictions(scene.mechanism, MU, 1e-3))
    held = (rough.omega == 0.0) & (rough.t > 0.5)
    assert np.count_nonzero(held) > 10
    r = aj.reactions(model, (rough.q[held], rough.omega[held], rough.domega[held]))
    np.testing.assert_allclose(r.driving, 0.0, atol=1e-12)
    bare = aj.reactions(aj.Model(scene.mechanism, scene.gravity, ()), (rough.q[held], rough.omega[held], rough.domega[held]))
    assert np.min(np.abs(bare.driving)) > 1e-3  # without friction it would take a drive to stay there


def test_held_on_a_pins_dead_point_its_friction_stays_within_its_limit(slider, rough):
    """The rough slider-crank held at rest with its crank upright or hanging (q = +-pi/2): the
    rod's angle is at its extreme, so pin B's relative rate is 0 (a dead point) and both
    break-away limits load B the same way. The held friction, the two limits' in proportion,
    put 113 % of mu r |F_B| on B (|F| is convex: their F_B point apart), with friction_ok True.
    Every element's value now lies within its Coulomb limit at the reported reactions (computed
    here from them), and the drive is the least one: 0, as gravity has no moment there (each
    centre of mass at the top or bottom of its circle: d y_G/dq = (R/2) cos q = 0). Beside
    them (the run's held states; q = 0.4, held at the band's edge) all stays within the limits."""
    scene = slider.model
    model = aj.Model(scene.mechanism, scene.gravity, frictions(scene.mechanism, MU, 1e-3))
    q = np.array(rough.q[(rough.omega == 0.0) & (rough.t > 0.5)])  # the test above's shape: its compiled program
    q[:3] = [math.pi / 2, -math.pi / 2, 0.4]
    r = aj.reactions(model, (q, np.zeros_like(q), np.zeros_like(q)))
    ratio = {j: np.abs(r.friction[j]) / (MU * RADIUS * np.linalg.norm(r[j], axis=-1)) for j in ("O", "A", "B")}
    normal, couple = np.asarray(r["slider/ground"])[:, 1], np.asarray(r.couples["slider/ground"])  # the guide along x
    ratio["slider/ground"] = np.abs(r.friction["slider/ground"]) / (
        MU * (np.abs(normal / 2 - couple / BLOCK) + np.abs(normal / 2 + couple / BLOCK)))
    for name, value in ratio.items():
        assert np.all(value <= 1.0 + 1e-12), (name, value)
    np.testing.assert_allclose(ratio["B"][:2], 1.0, rtol=0, atol=1e-12)  # clipped to its limit
    assert np.all(np.asarray(r.friction_ok))
    np.testing.assert_allclose(np.delete(r.driving, 2), 0.0, rtol=0, atol=1e-12)
    for value in ratio.values():  # q = 0.4: gravity outweighs the band; its edge, every element at its limit
        assert abs(value[2] - 1.0) < 1e-9 and r.driving[2] > 0.4


def test_inverse_dynamics_with_friction_balances_the_power(slider, rough):
    """Along the rough motion the driving effort needed is zero (there is no drive), and
    the reactions put friction on every pair: the frictionless reactions differ."""
    scene = slider.model
    model = aj.Model(scene.mechanism, scene.gravity, frictions(scene.mechanism, MU, 1e-3))
    moving = rough.omega != 0.0
    state = (rough.q[moving], rough.omega[moving], rough.domega[moving])
    r = aj.reactions(model, state)
    np.testing.assert_allclose(r.driving, 0.0, atol=1e-8)
    bare = aj.reactions(scene, state)
    assert np.max(np.abs(bare.driving)) > 1e-3  # without friction the same motion needs a drive


def test_a_jammed_runs_last_state_has_no_statics(slider, rough):
    """Along a Solution whose run the friction jammed, the jam's state (its last sample, at
    t_final) has no dw/dt of a motion: reactions() marks it friction_ok False, there only
    (the command printed the statics of its saved dw/dt as values and peaks). The rough
    motion's held samples (the program of the test above), taken as a run jammed at its end;
    as run, every one is consistent."""
    import dataclasses

    from assurjax.dynamics._solution import saved_rows

    model = aj.Model(slider.mechanism, slider.gravity, frictions(slider.mechanism, MU, 1e-3))
    held = (rough.omega == 0.0) & (rough.t > 0.5)
    first = int(np.flatnonzero(held)[0])
    assert held[first:].all()
    tail = saved_rows(rough, slice(first, None))
    assert np.asarray(aj.reactions(model, tail).friction_ok).all()
    jammed = aj.reactions(model, dataclasses.replace(tail, jammed=True)).friction_ok
    np.testing.assert_array_equal(jammed, np.arange(tail.t.size) < tail.t.size - 1)


def _with_friction(scene, mu):
    return scene.with_loads(frictions(scene.mechanism, mu))


def test_a_pin_whose_links_turn_together_has_no_coulomb_sign(slider):
    """A pin whose two links turn at rates 1 ulp apart (round-off: the pin of a PRP dyad
    whose sliders turn together, tests/test_friction_random.py) has relative rate exactly 0,
    so no Coulomb sign and no friction couple, while its slope is still the difference's;
    a real relative rate is the difference."""
    from assurjax._friction import pairs_by_name, without_roundoff
    from assurjax._kinematics import coefficients

    mechanism = slider.mechanism
    pin = pairs_by_name(mechanism)["A"]
    element = aj.JointFriction("A", MU, RADIUS)
    c = coefficients(mechanism, jnp.asarray(0.5))

    def rate(on, by):  # as rates_and_slopes reads an element: its terms, and the round-off rule on them
        rate, terms = element.rate_terms(mechanism, c.x, (c.dx[0], c.dx[1], {**c.dx[2], pin.on: on, pin.by: by}))
        return without_roundoff(rate, jnp.sum(jnp.abs(terms)))

    turning = 0.8581982075567952
    assert float(rate(turning, np.nextafter(turning, 1.0))) == 0.0
    assert float(rate(0.7, 0.3)) == 0.7 - 0.3
    _, slope = jax.jvp(rate, (jnp.asarray(turning), jnp.asarray(np.nextafter(turning, 1.0))), (jnp.asarray(1.0), jnp.asarray(0.25)))
    assert float(slope) == 0.75


def test_with_loads_checks_the_loads(slider):
    rough = slider.with_loads(frictions(slider.mechanism, MU))
    assert [f.pair for f in rough.loads] == [f.pair for f in frictions(slider.mechanism, MU)]
    assert all(float(f.coefficient) == MU for f in rough.loads)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(rough.mechanism), jax.tree.leaves(slider.mechanism)))
    assert rough.state == slider.state and rough.name == slider.name
    with pytest.raises(aj.MechanismError, match="'Z' is not a revolute joint"):
        slider.with_loads((aj.JointFriction("Z", 0.1, radius=0.01),))
    with pytest.raises(aj.MechanismError, match="JointFriction 'A': coefficient must be a number or an array of numbers, got 'high'"):
        aj.JointFriction("A", "high", radius=0.01)


CLOSED_FORM_LAWS = [
    (1.0, 0.5, -0.1 / 1.05, True),  # weak coupling (dlaw/du = -0.05): the fixed-point iteration
    (1.0, 9.0, -0.1 / 1.9, True),  # dlaw/du = -0.9: too slow for the iteration, Newton's method
    # two roots: Newton's from u0, u = -0.2, has dlaw/du = +1.5 (not consistent: Painleve); the
    # consistent one (dlaw/du = -1.5), on the branch from mu = 0, by the continuation in mu
    (1.0, 15.0, -0.1 / 2.5, True),
    (1.0, -15.0, None, False),  # no u with u = law(u): reported, not invented
]


def _closed_form_solve(slider):
    """solve_friction on one revolute whose reaction is F = (a + b u, 0): u = -mu r |a + b u| (mu r = 0.1)."""
    from assurjax._friction import linearize_reactions, solve_friction

    element = aj.JointFriction("O", 0.5, 0.2)

    def solve(a, b):
        react = lambda u: ({"O": jnp.stack([a + b * u[0], 0.0])}, {})  # noqa: E731
        linear = linearize_reactions(react, (element,), 1)
        return solve_friction(slider.mechanism, (element,), linear, None, jnp.zeros(1), jnp.ones(1), 0.0)

    return solve


@pytest.mark.parametrize("a, b, expected, ok", CLOSED_FORM_LAWS)
def test_friction_solve_on_a_closed_form_law(slider, a, b, expected, ok):
    """The friction solve against the law solved by hand; either solver branch, and the failure flag."""
    u, found = jax.jit(_closed_form_solve(slider))(a, b)
    assert bool(found) == ok
    if ok:
        assert abs(float(u[0]) - expected) < 1e-14


def test_friction_solve_reverse_mode_takes_a_nan_cotangent(slider):
    """Reverse mode through the solve: du/da = -0.1 / (1 + 0.1 b) by hand (u = -0.1 (a + b u));
    a NaN cotangent (a step rejected where the friction jams: 0 x NaN) gives NaN, where the
    transposed lineax solve raised from inside the program."""
    solve = _closed_form_solve(slider)
    u, pullback = jax.vjp(lambda a: solve(a, 0.5)[0], 1.0)
    assert abs(float(pullback(jnp.ones(1))[0]) + 0.1 / 1.05) < 1e-12
    assert np.isnan(float(jax.jit(lambda ct: jax.vjp(lambda a: solve(a, 0.5)[0], 1.0)[1](ct)[0])(jnp.full(1, jnp.nan))))


def test_friction_solve_batched(slider):
    """The same laws as one vmapped batch (Newton's method runs for the batch because some
    members need it; each member keeps its own branch's answer), and a batch where the
    iteration converges for every member (no Newton)."""
    solve = jax.jit(jax.vmap(_closed_form_solve(slider)))
    a, b, expected, ok = zip(*CLOSED_FORM_LAWS)
    u, found = solve(jnp.asarray(a), jnp.asarray(b))
    assert list(np.asarray(found)) == list(ok)
    for k, value in enumerate(expected):
        if value is not None:
            assert abs(float(u[k, 0]) - value) < 1e-12  # the iteration's tolerance
    b_weak = jnp.asarray([0.5, -0.5, 0.2])
    u, found = solve(jnp.ones(3), b_weak)
    assert np.all(np.asarray(found))
    np.testing.assert_allclose(np.asarray(u[:, 0]), -0.1 / (1.0 + 0.1 * np.asarray(b_weak)), rtol=1e-12)


def test_iteration_stops_within_its_tolerance(slider):
    """The fixed-point iteration at the tolerance a simulation gives it (1e-2 of the
    integrator's, not below 1e-12) against the closed-form root of u = -0.1 (1 + b u): within
    c / (1 - c) of that tolerance, c = 0.1 |b| the law's slope (the bound the tolerance's
    docstring names)."""
    from assurjax._friction import iterate_friction, iteration_tolerance, linearize_reactions

    assert iteration_tolerance(1e-8, 1e-8) == pytest.approx(1e-10)
    assert iteration_tolerance(1e-6, 1e-9) == pytest.approx(1e-11)
    assert iteration_tolerance(1e-12, 1e-12) == iteration_tolerance(1e-10, 1e-3) == 1e-12
    element = aj.JointFriction("O", 0.5, 0.2)

    @jax.jit
    def roots(b):
        react = lambda u: ({"O": jnp.stack([1.0 + b * u[0], 0.0])}, {})  # noqa: E731
        linear = linearize_reactions(react, (element,), 1)
        return [iterate_friction(slider.mechanism, (element,), linear, None, jnp.zeros(1), jnp.ones(1), 0.0,
                                 tolerance=tolerance) for tolerance in (1e-10, 1e-12)]

    stopped_sooner = []
    for b in (0.5, -3.0, 3.0):  # slopes the iteration takes (below ~0.4, see FIXED_POINT_STEPS)
        exact, c = -0.1 / (1.0 + 0.1 * b), 0.1 * abs(b)
        found = roots(b)
        for fixed, tolerance in zip(found, (1e-10, 1e-12)):
            assert bool(fixed.converged)
            assert abs(float(fixed.value[0]) - exact) <= c / (1 - c) * tolerance * (1 + abs(exact))
        stopped_sooner.append(float(found[0].value[0]) != float(found[1].value[0]))
    assert any(stopped_sooner)  # the looser tolerance is the one applied


@pytest.mark.slow  # ~14 s (a program of its own); the samples of a stick-slip run stay checked by test_falls_oscillates_and_sticks
def test_a_motor_stalling_at_the_band_edge_keeps_its_direction():
    """The press with mu = 1 (pins of 1 um, a 10 mm block) creeps to where its motor's stall
    torque is the band's upper edge: w dies away (1e-8 rad/s by 1.3 s) and the solution's
    error took it past 0 between step ends, where the outputs read the backward friction
    (dw/dt +940 rad/s^2, the ram's friction +81 N beside -108.5 N: reactions read the same
    samples). Against the integrated motion's own finite differences: w never below 0, dw/dt
    there ~0."""
    press = aj.load_scene("press_with_friction")
    others = tuple(load for load in press.loads if not isinstance(load, (aj.JointFriction, aj.SlideFriction)))
    rough = press.with_loads(others + tuple(aj.JointFriction(j, 1.0, radius=1e-6) for j in ("O", "A", "B"))
                             + (aj.SlideFriction("ram/ground", 1.0, length=0.01),))
    ts = np.linspace(0.0, 2.0, 401)
    sol = aj.simulate(rough, t1=2.0, saveat=ts)
    w, dw = np.asarray(sol.omega), np.asarray(sol.domega)
    creep = ts > 1.3
    assert np.all(w >= 0.0) and np.max(w[creep]) < 1e-6, sol.status
    fd = np.gradient(w, ts)
    np.testing.assert_allclose(dw[creep], fd[creep], rtol=0, atol=1e-4)


@pytest.mark.slow  # 15-22 s of compiles; the default suite ran 9:41-11:05 in CI runs on a shared machine
def test_batch_of_starts_equals_single_runs():
    """A batch of simulations with friction (the driven press from rest: break-away, Coulomb
    switches) equals each member's own run: the friction solve's Newton fallback, taken
    for a batch only when some member needs it, leaves every member's answer its own. A
    batch integrates in chunks of BATCH_SEGMENT_STEPS steps (a single run in whole
    segments): other steps, the same motion to the tolerance (at rtol = atol = 1e-10 both lie
    within 3e-9 rad of a run at 1e-12; at 1e-8, 6e-8 to 3e-7 rad in the batch, 5e-8 to 3e-7
    alone: the Coulomb switches amplify a different step sequence's local errors)."""
    press = aj.load_scene("press_with_friction")
    q0 = np.array([0.0, 1.0, 2.5])
    kw = dict(stop=None, t1=0.5, samples=6, points=(), angles=(), energies=False, rtol=1e-10, atol=1e-10)
    batch = aj.simulate(press, q0=q0, **kw)
    assert batch.successful
    for k, start in enumerate(q0):
        single = aj.simulate(press, q0=start, **kw)
        np.testing.assert_allclose(batch.q[k], single.q, rtol=0, atol=1e-8)
        np.testing.assert_allclose(batch.omega[k], single.omega, rtol=0, atol=2e-7)


@pytest.mark.slow
def test_gradient_in_mu_against_differences(slider):
    """d t_stop / d mu (standstill, reverse mode through the segments, their located
    switches of the Coulomb signs and the friction's Newton solve by the implicit function
    theorem) against central differences. The run crosses two switches (the slider's and
    a pin's relative rate change sign) before it stops: without segments ending there the
    derivative missed their saltation (0.342 against 0.329)."""

    def t_stop(mu):
        return aj.synthesis.standstill_time(_with_friction(slider, mu), rtol=1e-11, atol=1e-11)[0]

    grad = jax.grad(t_stop)(jnp.asarray(MU))
    h = 1e-5
    fd = (t_stop(jnp.asarray(MU + h)) - t_stop(jnp.asarray(MU - h))) / (2 * h)
    assert math.isfinite(float(grad))
    np.testing.assert_allclose(float(grad), float(fd), rtol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("t1", [0.8, 1.5])
def test_gradient_in_mu_through_a_standstill_and_reversal(slider, t1):
    """d q(t1) / d mu past the first standstill (0.51 s), where the motion reverses and
    crosses more Coulomb-sign switches (0.8 s), and past the last (~0.95 s), from where the
    friction holds it (1.5 s: the segment from that rest ends at its first step, which
    stays at rest): reverse mode (the checkpointed segment loop) and forward mode
    (adjoint='forward') against central differences."""

    def q_at(mu, adjoint):
        return aj.synthesis.final_state(_with_friction(slider, mu), t1, rtol=1e-11, atol=1e-11, adjoint=adjoint)[0]

    h = 1e-5
    fd = (q_at(jnp.asarray(MU + h), "recursive") - q_at(jnp.asarray(MU - h), "recursive")) / (2 * h)
    reverse = jax.grad(lambda mu: q_at(mu, "recursive"))(jnp.asarray(MU))
    forward = jax.jacfwd(lambda mu: q_at(mu, "forward"))(jnp.asarray(MU))
    np.testing.assert_allclose(float(reverse), float(fd), rtol=1e-5)
    np.testing.assert_allclose(float(forward), float(fd), rtol=1e-5)


# Newton's method alone (the fallback, the batched analyses' solve) in the slow suite: its ~17 s of
# compiles went to breakaway_band's check against the joint-based reference (the default suite keeps to 10 min)
@pytest.mark.parametrize("iterate", [True, pytest.param(False, marks=pytest.mark.slow)], ids=["fixed point", "newton"])
def test_acceleration_gradient_in_mu_against_differences(slider, iterate):
    """d(dw/dt)/d mu at moving states of the slider-crank, both directions, mu = 0.2 and 1 in
    every pair: the derivative of the friction solve (the implicit function theorem, through
    optimistix) in reverse and forward mode against central differences, for the fixed-point
    iteration the integration takes and for Newton's method alone (its fallback, and the
    batched analyses' solve). The default suite's check of gradients in mu (the fixed-point
    case); Newton's, and through whole runs (stick segments, standstills, reversals), they are
    in the slow suite."""
    from assurjax.dynamics._field import State, frictional

    def alpha(mu, q, w):
        model = aj.Model(slider.mechanism, slider.gravity, tuple(slider.loads) + frictions(slider.mechanism, mu))
        f = frictional(model, 0.0, State(q, w), jnp.sign(w), iterate=iterate)
        return jnp.where(f.consistent, f.alpha, jnp.nan)

    h = 1e-6

    @jax.jit
    @jax.vmap  # over the states; one program for both values of mu
    def derivatives(mu, q, w):
        fd = (alpha(mu + h, q, w) - alpha(mu - h, q, w)) / (2 * h)
        return fd, jax.grad(alpha)(mu, q, w), jax.jacfwd(alpha)(mu, q, w)

    q = jnp.array([0.3, 1.2, 2.5, 4.0, 5.5, 0.9])
    w = jnp.array([2.0, -1.5, 3.0, -0.5, 1.0, -4.0])
    for mu in (0.2, 1.0):
        fd, reverse, forward = derivatives(jnp.full(q.shape, mu), q, w)
        assert np.all(np.isfinite(fd)) and np.min(np.abs(fd)) > 1e-3, fd  # consistent, and friction acts at every state
        np.testing.assert_allclose(reverse, fd, rtol=1e-8, atol=1e-7)  # agree to ~1e-10 (differences: ~1e-12 / h)
        np.testing.assert_allclose(forward, fd, rtol=1e-8, atol=1e-7)


# mu = 5 on pin A and on a 5 mm slider block, none elsewhere: the structure of frictions() (run()'s program)
STRONG = (aj.JointFriction("O", 0.0, RADIUS), aj.JointFriction("A", 5.0, RADIUS), aj.JointFriction("B", 0.0, RADIUS),
          aj.SlideFriction("slider/ground", 5.0, 0.005))


@pytest.mark.slow  # ~23 s; the default suite checks the friction solve's derivative in mu (the acceleration's)
def test_vector_field_derivative_in_mu_against_differences(slider):
    """The vector field's d(dw/dt)/d(scale of every mu), reverse and forward mode, against
    central differences: with moderate friction (the iteration settles) and with STRONG's at
    the state where Newton's method from the law's start lands on a root that is not
    consistent, so the field takes its fallback and the continuation in mu. Differentiated,
    the field is one path whose friction values take their derivative from the implicit
    function theorem (whichever solver found them): its values are the field's own."""
    from assurjax.dynamics._field import State, _settled_field, field_args, vector_field

    def scaled(loads, s):
        return tuple(eqx.tree_at(lambda f: f.coefficient, f, s * f.coefficient) for f in loads)

    def alpha(s, q, w, strong):
        loads = scaled(STRONG, s) if strong else frictions(slider.mechanism, s * 0.5)
        model = aj.Model(slider.mechanism, slider.gravity, tuple(slider.loads) + loads)
        return vector_field(0.0, State(q, w), field_args(model, direction=jnp.sign(w))).omega

    h = 1e-6

    @functools.partial(jax.jit, static_argnums=3)
    def derivatives(s, q, w, strong):
        value = alpha(s, q, w, strong)
        fd = (alpha(s + h, q, w, strong) - alpha(s - h, q, w, strong)) / (2 * h)
        reverse_value, reverse = jax.value_and_grad(alpha)(s, q, w, strong)
        return value, reverse_value, fd, reverse, jax.jacfwd(alpha)(s, q, w, strong)

    def settled(q, w, strong):  # whether the field's iteration settles there (else its fallback runs)
        loads = STRONG if strong else frictions(slider.mechanism, 0.5)
        args = field_args(aj.Model(slider.mechanism, slider.gravity, tuple(slider.loads) + loads), direction=jnp.sign(w))
        return bool(_settled_field(0.0, State(jnp.asarray(q), jnp.asarray(w)), args)[2].fixed.settled)

    for (q, w), strong in (((1.2, -1.5), False), ((2.5, 3.0), False), ((0.5067189849544655, 4.6), True)):
        assert settled(q, w, strong) != strong
        value, reverse_value, fd, reverse, forward = (float(v) for v in derivatives(1.0, q, w, strong))
        assert math.isfinite(value) and abs(fd) > 1.0, (value, fd)  # consistent, and the friction acts
        assert abs(reverse_value - value) <= 1e-12 * abs(value)
        np.testing.assert_allclose(reverse, fd, rtol=1e-7)  # differences: ~1e-12 / h
        np.testing.assert_allclose(forward, fd, rtol=1e-7)


def _strong_reference(omega0, continuation):
    """The joint-based reference with STRONG's friction, its Newton continued in that many steps."""
    import joint_reference_friction as jrf

    ref = jrf.slider_crank(0.5, omega0, friction=dict(A=jrf.Friction(mu=5.0, radius=RADIUS), P=jrf.Friction(mu=5.0, length=0.005)))
    ref.system.continuation = continuation
    return ref


def test_strong_friction_takes_the_root_on_the_branch_from_mu_0(slider):
    """Strong friction (mu = 5 on pin A and on a 5 mm slider block): the friction law has
    several roots. Newton's method from the law's value at u = 0 landed, at w = 4.6 rad/s on
    the way to rest, on one that is not consistent (det(I - dlaw/du) < 0): the run stopped
    there as if jammed. The solve now continues in mu from 0 where Newton's root is not
    consistent: the motion goes on to rest, the energy balance closes, and its dw/dt at
    every moving sample is that of the joint-based reference solved the same way
    (continued in mu) in its own coordinates, where Newton's method alone finds another root."""
    times = np.linspace(0.0, 0.04, TIMES.size)
    sol = aj.simulate(slider, loads=STRONG, q0=0.5, omega0=5.0, stop=None, t1=0.04, saveat=times, energies=True,
                      rtol=1e-10, atol=1e-10)
    assert sol.status.startswith("reached t1"), sol.status
    assert sol.omega[-1] == 0.0  # at rest, held by the friction
    assert np.max(np.abs(sol.balance)) < 1e-9 * np.max(np.abs(sol.total))
    state = (0.5067189849544655, 4.6)  # where Newton's method from u0 found the inconsistent root
    ref = _strong_reference(5.0, 4)
    assert abs(ref.forward(*state)["wdot"] - _strong_reference(5.0, 1).forward(*state)["wdot"]) > 10.0  # several roots
    moving = np.flatnonzero(sol.omega != 0.0)
    assert moving.size > 10
    for k in moving:
        expected = ref.forward(float(sol.q[k]), float(sol.omega[k]))["wdot"]
        assert abs(float(sol.domega[k]) - expected) < 1e-9 * abs(expected), (k, float(sol.domega[k]), expected)


def test_a_friction_jam_is_named(slider):
    """The same strong friction launched at 20 rad/s: no friction values satisfy the law of
    that motion with a positive effective inertia (the joint-based reference's Newton's
    method finds none, from the frictionless solution or continued in mu in 4 or 16
    steps). The run stops at once, and its status says the friction jams the mechanism,
    not that the solver could not get on."""
    sol = aj.simulate(slider, loads=STRONG, q0=0.5, omega0=20.0, stop=None, t1=T1, saveat=TIMES, energies=True,
                      rtol=1e-10, atol=1e-10)  # run()'s program
    assert not sol.successful
    assert sol.status.startswith("the joint friction jams the mechanism at t = 0 s (q = 0.5, w = 20):"), sol.status
    for steps in (1, 4, 16):
        with pytest.raises(RuntimeError, match="did not converge"):
            _strong_reference(20.0, steps).forward(0.5, 20.0)


def test_a_load_that_is_nan_is_no_friction_jam(slider):
    """The jam status reads the friction where a run stopped on NaN: with the loads NaN there
    (a user's function; here gravity, put in by tree_at, so that the jam test's program is
    shared), it is no jam (it was called one, with the remedy to lower the friction); the
    strong friction at 20 rad/s is one, with finite loads (control)."""
    from assurjax.dynamics._stick import _jams

    strong = aj.Model(slider.mechanism, slider.gravity, STRONG)
    at = tuple(np.array([v]) for v in (0.1, 0.5, 20.0))
    assert bool(_jams(strong, *at)[0])
    assert not bool(_jams(eqx.tree_at(lambda m: m.gravity, strong, jnp.array([0.0, jnp.nan])), *at)[0])


def test_a_jam_names_the_pairs_whose_motion_turns_round(slider):
    """A jam just after a Coulomb switch names the pairs whose relative motion turned round
    there. On the slider-crank (closed form): the slide at its dead centres, where the
    slider's velocity -r sin q (1 + r cos q / sqrt(l^2 - r^2 sin^2 q)) is 0 (q = 0, pi); the
    rod's pin B where the rod's angular velocity, r cos q / sqrt(l^2 - r^2 sin^2 q) times
    that of the crank, is 0 (q = pi/2); none elsewhere. (The strong friction's jam at 20 rad/s,
    at no switch, names none: test_a_friction_jam_is_named reads its whole opening.)"""
    from assurjax.dynamics._results import jam_text
    from assurjax.dynamics._stick import reversing_pairs

    model = aj.Model(slider.mechanism, slider.gravity, frictions(slider.mechanism))
    assert reversing_pairs(model, 0.0) == reversing_pairs(model, math.pi) == ["slider/ground"]
    assert reversing_pairs(model, math.pi / 2) == ["B"]
    assert reversing_pairs(model, 0.7) == [] and reversing_pairs(model, 1e-6) == []
    assert "where the relative motion in 'B' turns round" in jam_text(1.0, 1.5, 2.0, reversing=["B"])
    assert "turns round" not in jam_text(1.0, 1.5, 2.0, reversing=[])


@pytest.mark.slow  # ~20 s (a program for its Python drive); test_a_load_that_is_nan_is_no_friction_jam stays
def test_a_load_that_turns_nan_is_no_friction_jam(slider):
    """A user's drive that turns NaN (t > 0.05 s) stops a run with friction as it stops one
    without: the solver's failure naming a load, not a jam of the joint friction (it was
    called one, with the remedy to lower the friction); the friction is finite up to there."""
    drive = aj.Drive(lambda q, w, t: jnp.where(t > 0.05, jnp.nan, 2.0), velocity_dependent=False)
    sol = aj.simulate(slider, loads=frictions(slider.mechanism) + (drive,), q0=0.5, stop=None, t1=0.2, samples=5,
                      energies=False)
    assert not sol.successful and not sol.jammed, sol.status
    assert sol.status.startswith("solver stopped at t = ") and "the right-hand side turned NaN ahead" in sol.status
    assert abs(float(sol.t_final) - 0.05) < 1e-6, sol.status


@pytest.mark.slow  # ~8 s: the differentiable program; the default suite keeps to 10 min
def test_a_friction_jam_is_named_by_the_final_state(slider):
    """The differentiable final state of that jam has no q(T) to give: it says why (it returned
    the start as q(T))."""
    with pytest.raises(aj.AssurjaxError, match="final_state: the motion did not end as asked: the joint friction jams "
                                              "the mechanism at t = 0 s"):
        aj.synthesis.final_state(slider.with_loads(STRONG), 0.5, q0=0.5, omega0=20.0)


@pytest.mark.slow
def test_a_jammed_member_of_a_batch_keeps_its_last_state(slider):
    """A batch with the strong friction above, launched at 5 and 20 rad/s: the first member
    runs on to rest as alone, the second jams at once. The jammed member's state is its
    start, finite, and it counts as jammed by the friction (as the single run's status says),
    not as a lock-up (its final row was diffrax's interpolation into its NaN attempt, read
    where the other member's event fired: NaN, taken for a group that cannot assemble) nor
    as a solver failure."""
    kw = dict(loads=STRONG, stop=None, t1=T1, saveat=TIMES, energies=True, rtol=1e-10, atol=1e-10)
    batch = aj.simulate(slider, q0=np.array([0.5, 0.5]), omega0=np.array([5.0, 20.0]), **kw)
    alone = aj.simulate(slider, q0=0.5, omega0=5.0, **kw)
    assert batch.status.startswith("batch of 2: 1 reached t1, 1 jammed by the joint friction"), batch.status
    assert batch.jammed.tolist() == [False, True] and alone.jammed is False
    assert "solver failures" not in batch.status
    assert abs(batch.q_final[0] - alone.q_final) < 1e-8 and batch.omega_final[0] == 0.0
    assert (batch.t_final[1], batch.q_final[1], batch.omega_final[1]) == (0.0, 0.5, 20.0)
    # its one saved row is its start (it was NaN: the dense output of the attempt that met the jam)
    valid = batch.valid[1]
    assert valid.sum() == 1 and (batch.q[1][valid][0], batch.omega[1][valid][0]) == (0.5, 20.0)
    # a batch of mechanisms counts the jams too (its status was empty)
    mechanisms = jax.tree.map(lambda x: np.stack([x, x]), slider.mechanism)
    members = aj.batch_simulate(slider.with_loads(STRONG), mechanisms, q0=0.5, omega0=20.0, t1=0.5, progress=False)
    assert members.status.startswith("batch of 2: 2 jammed by the joint friction"), members.status
    # under a transformation the final state of a jammed run is NaN (not its start)
    q, w = jax.jit(lambda w0: aj.synthesis.final_state(slider.with_loads(STRONG), 0.5, q0=0.5, omega0=w0))(20.0)
    assert np.isnan(q) and np.isnan(w)


@pytest.mark.slow  # ~25 s: a vmapped program and a single run's
def test_a_jammed_member_of_a_vmapped_core_run_is_its_single_run(slider):
    """simulate_core under the caller's vmap (the route of assurjax.sweep): a member that the
    friction jams beside one that runs on to t1 ends as it does alone (a jam at t = 0.35 s;
    in the batch it was a lock-up with q NaN, its last saved row NaN: the dense output of its
    NaN attempt, read where the other member ran on)."""
    short = eqx.tree_at(lambda s: (s.mechanism.links["rod"].points["B"], s.mechanism.links["rod"].com), slider,
                        (jnp.array([0.12, 0.0]), jnp.array([0.06, 0.0])))  # a 0.12 m rod: mu = 0.6 jams it
    settings = aj.settings_from(short, stop=None, samples=11, energies=False, points=(), angles=(), kink_events=False,
                                reduction="exact")
    loads = lambda mu, tau: frictions(short.mechanism, mu) + (aj.Drive(tau),)  # noqa: E731
    core = aj.jit(eqx.filter_vmap(lambda mu, tau: aj.simulate_core(short.mechanism, short.gravity, loads(mu, tau), 0.5,
                                                                   0.0, 0.0, 1.0, settings=settings)))
    both = core(jnp.array([0.6, 0.1]), jnp.array([3.0, 1.0]))
    alone = aj.simulate(short, loads=loads(0.6, 3.0), q0=0.5, stop=None, t1=1.0, samples=11, kink_events=False)
    assert alone.jammed and both.event.tolist() == [-1, -1], alone.status
    from assurjax.dynamics._results import result_code

    assert result_code(both.result).tolist() == [result_code(aj.RESULTS.dt_min_reached), result_code(aj.RESULTS.successful)]
    # to the tolerance: chunks of steps (a batch's) and whole segments step apart
    assert abs(float(both.t_final[0]) - alone.t_final) < 1e-6 and abs(float(both.q_final[0]) - alone.q_final) < 1e-6
    assert np.all(np.isfinite(np.asarray(both.q[0])[np.asarray(both.valid[0])]))


# ---------------------------------------------------------------------------- against the joint-based reference


def _package_frictions(mechanism, table: dict, parts: int = 1):
    """The reference's friction table (tests/joint_reference_friction.py) as package loads;
    ``parts`` > 1 puts that many elements on every pair, sharing its mu and damping."""
    out = []
    for name in aj.joint_names(mechanism):
        ref = table["P" if "/" in name else name]
        mu, damping = ref.mu / parts, ref.damping / parts
        for _ in range(parts):
            if "/" in name:
                out.append(aj.SlideFriction(name, mu, ref.length, viscous=damping))
            else:
                out.append(aj.JointFriction(name, mu, ref.radius, viscous=damping))
    return tuple(out)


def _kinked_run_error(cuts: bool) -> float:
    """max |q - q_ref| of the driven slider-crank with a rough slide (mu = 0.2, a 40 mm block),
    whose block ends' loads change sign along the motion (kinks of its friction law), over
    0.6 s at the default tolerance, against the joint-based reference."""
    import joint_reference_friction as jrf

    times = np.linspace(0.0, 0.6, 13)
    expected = jrf.slider_crank(0.5, 5.0, tau=lambda t, q, w: 3.0, friction={"P": jrf.Friction(mu=0.2, length=0.04)}
                                ).simulate(0.6, t_eval=times)
    loads = (aj.Drive(3.0), aj.SlideFriction("slider/ground", 0.2, 0.04))
    sol = aj.simulate(aj.load_scene("slider_crank"), loads=loads, q0=0.5, omega0=5.0, stop=None, t1=0.6, saveat=times,
                      kink_events=cuts)
    assert sol.status.startswith("reached t1"), sol.status
    return float(np.max(np.abs(sol.q - expected.q)))


@pytest.mark.slow  # ~19 s (a program of its own); the cuts (on by default) stay checked against the reference by
# test_agrees_with_the_joint_based_reference[slider_crank], whose slide has a block length
def test_cuts_at_the_slides_kinks_keep_the_values_accurate():
    """simulate(kink_events=True) cuts at the slide's kinks, which the steps otherwise cross:
    q within 1e-6 rad of the joint-based reference (6.1e-7 measured)."""
    assert _kinked_run_error(True) < 1e-6


@pytest.mark.slow  # ~12 s (a program of its own)
def test_steps_across_the_slides_kinks_lose_accuracy():
    """Without the cuts the steps across the kinks leave q 13x further off the reference
    (8.1e-6 rad against 6.1e-7)."""
    assert _kinked_run_error(False) > 5 * _kinked_run_error(True)


@pytest.mark.slow  # ~40 s: the differentiable program and the reference's 0.5 s
def test_the_differentiable_run_keeps_every_cut_after_a_flipped_block_end(monkeypatch):
    """A slider-crank with a 0.12 m rod, 3 N m on the crank and mu = 0.19 in every pair: the
    slide's two block ends change sign ~1.2 ms apart each turn. Where an event on the first is
    located just before its root, the next segment flips that end's sign, and the frozen law
    moved its load past the margin's floor: the margin started below 0 and hid every later
    cut, and final_state (its default settings) gave q(0.5 s) = 14.609 rad, w = 51.4 rad/s.
    Against the joint-based reference with that rod: within 1e-6 rad and 1e-5 rad/s."""
    import joint_reference as jr
    import joint_reference_friction as jrf

    rod, mu = 0.12, 0.19
    monkeypatch.setitem(jr.SLIDER_CRANK, "l", rod)
    table = dict(O=jrf.Friction(mu=mu, radius=0.01), A=jrf.Friction(mu=mu, radius=0.01), B=jrf.Friction(mu=mu, radius=0.01),
                 P=jrf.Friction(mu=mu, length=0.05))
    expected = jrf.slider_crank(0.5, 0.0, tau=lambda t, q, w: 3.0, friction=table).simulate(0.5, t_eval=[0.5])
    scene = aj.load_scene("slider_crank")
    mechanism = eqx.tree_at(lambda m: (m.links["rod"].points["B"], m.links["rod"].com), scene.mechanism,
                            (jnp.array([rod, 0.0]), jnp.array([rod / 2, 0.0])))
    loads = (aj.JointFriction("O", mu, 0.01), aj.JointFriction("A", mu, 0.01), aj.JointFriction("B", mu, 0.01),
             aj.SlideFriction("slider/ground", mu, 0.05), aj.Drive(3.0))
    q, w = aj.synthesis.final_state(eqx.tree_at(lambda s: s.mechanism, scene.with_loads(loads), mechanism), 0.5, q0=0.5,
                                   omega0=0.0)
    assert abs(float(q) - expected.q[-1]) < 1e-6 and abs(float(w) - expected.w[-1]) < 1e-5, (q, w, expected.q[-1])


# slow (~14 s): the same path runs in the slow test_agrees_with_the_joint_based_reference[watt_sixbar]
@pytest.mark.slow
def test_pairs_read_one_by_one_give_the_reference_acceleration():
    """The Watt six-bar with friction in its seven pins: its reactions' tangents (8 x 14 doubles)
    pass ``_jit.THREADED_BYTES``, so the law reads them pair by pair, not packed (the
    slider-crank's path, checked by the reference case below). dw/dt of the package's vector
    field at moving states, both directions, against the joint-based reference's forward
    dynamics to 1e-9 relative."""
    import joint_reference_friction as jrf
    from assurjax._jit import THREADED_BYTES
    from assurjax.dynamics._field import State, field_args, vector_field

    scene, table, ref = aj.load_scene("watt_sixbar"), jrf.WATT_FRICTION, jrf.watt_sixbar(0.3, 1.0)
    assert 8 * (2 * len(table)) * 8 > THREADED_BYTES  # K + 1 tangents of K pins' forces: by pair
    model = aj.Model(scene.mechanism, scene.gravity, tuple(scene.loads) + _package_frictions(scene.mechanism, table))
    q, w = np.array([0.3, 0.5, 0.8, 0.3, 0.6]), np.array([1.0, 2.5, -1.5, -0.7, 4.0])
    field = jax.vmap(lambda q, w: vector_field(0.0, State(q, w), field_args(model, direction=jnp.sign(w))).omega)
    found = jax.jit(field)(q, w)
    expected = np.array([ref.forward(qi, wi)["wdot"] for qi, wi in zip(q, w)])
    np.testing.assert_allclose(found, expected, rtol=1e-9, atol=1e-9)


def _reference_case(case):
    """(package scene, q0, w0, drive (N m: a number or a function of t), t1, friction table, the
    joint-based reference model with that friction) of a case compared with the joint-based reference."""
    import tomllib

    import joint_reference as jr
    import joint_reference_friction as jrf
    from scene_texts import QUICK_RETURN, SLIDER_DRIVEN

    if case == "slider_crank":
        return aj.load_scene(case), 0.5, 0.0, 0.0, T1, jrf.SLIDER_CRANK_FRICTION, jrf.slider_crank(0.5, 0.0)
    if case == "slider_crank_driven":  # 0.3 sin 5t N m: held twice, each time until the drive breaks it away
        ref = jrf.slider_crank(0.5, 3.0, tau=lambda t, q, w: 0.3 * np.sin(5 * t))
        return aj.load_scene("slider_crank"), 0.5, 3.0, lambda t: 0.3 * jnp.sin(5 * t), T1, jrf.SLIDER_CRANK_FRICTION, ref
    if case == "watt_sixbar":
        return aj.load_scene(case), 0.3, 1.0, 0.0, T1, jrf.WATT_FRICTION, jrf.watt_sixbar(0.3, 1.0)
    slide = jrf.Friction(mu=0.2, length=0.03, damping=0.2)
    if case == "quick_return":  # the block slides on the rotating rocker, under a constant drive
        table = dict(O=jrf.Friction(mu=0.2, radius=0.005, damping=1e-3), A=jrf.Friction(mu=0.2, radius=0.005), P=slide,
                     O4=jrf.Friction(mu=0.2, radius=0.01))
        ref = jrf.with_friction(jr.quick_return(0.4, 4.0, tau=lambda t, q, w: 0.5), table)
        return aj.scene_from_dict(tomllib.loads(QUICK_RETURN)), 0.4, 4.0, 0.5, 0.7, table, ref
    # the driver is a slider on a rough guide: it swings once and sticks
    table = dict(P=slide, B=jrf.Friction(mu=0.2, radius=0.005), C=jrf.Friction(mu=0.2, radius=0.005),
                 O3=jrf.Friction(mu=0.2, radius=0.005))
    return aj.scene_from_dict(tomllib.loads(SLIDER_DRIVEN)), 0.2, 0.1, 0.0, 0.5, table, jrf.with_friction(jr.slider_driven(0.2, 0.1), table)


# the split case (K = 12, the stacked law), the driven slider-crank, the Watt six-bar, the quick-return and the
# slider driver in the slow suite: the default one ran 9:41 in CI (and 10:10 with the driven case in it); the
# quick-return's case (~35 s) moved there when the default suite took 20 min on a slower 2-core machine
@pytest.mark.parametrize("case", ["slider_crank", pytest.param("slider_crank_split", marks=pytest.mark.slow),
                                  pytest.param("slider_crank_driven", marks=pytest.mark.slow),
                                  pytest.param("watt_sixbar", marks=pytest.mark.slow),
                                  pytest.param("quick_return", marks=pytest.mark.slow),
                                  pytest.param("slider_driven", marks=pytest.mark.slow)])
def test_agrees_with_the_joint_based_reference(case, monkeypatch):
    """Friction in every joint (viscous terms too), motion through rests, sticking and sign
    reversals of the relative rates: q within 1e-8 rad (m) of the reference, and dw/dt of the
    output samples (their own friction solve) within 1e-7 relative; on the slider-crank also
    with the output samples and the reactions' states analysed in chunks (which many friction
    elements ask for, ``_friction.states_per_call``; forced here). Split: the
    slider-crank's friction shared by three elements per pair (K = 12, past SUMMED_TERMS:
    the friction law takes its stacked path). Quick-return: the RPR's block slides on the
    turning rocker (the pair's guide moves), under a constant drive; slider-driven: the
    driver's own pair is rough. Driven: a drive 0.3 sin 5t holds the slider-crank at rest twice and
    breaks it away twice (stick segments under a load in time).
    Then inverse dynamics along the reference's motion."""
    from assurjax._friction import SUMMED_TERMS

    parts = 3 if case.endswith("_split") else 1
    case = case.removesuffix("_split")
    assert parts == 1 or 4 * parts > SUMMED_TERMS
    scene, q0, w0, drive, t1, table, ref = _reference_case(case)
    times = np.linspace(0.0, t1, TIMES.size)
    expected = ref.simulate(t1, t_eval=times)
    in_time = callable(drive)
    drives = (aj.Drive(lambda q, w, t: drive(t)),) if in_time else (aj.Drive(drive),) if drive else ()
    loads = tuple(scene.loads) + drives + _package_frictions(scene.mechanism, table, parts)
    # split: three elements a pair, put in past check_loads (which refuses a second element on a pair)
    model = eqx.tree_at(lambda m: m.loads, scene.model, loads)

    def check_against_the_reference():
        sol = aj.simulate(model, q0=q0, omega0=w0, stop=None, t1=t1, saveat=times, energies=True, rtol=1e-10, atol=1e-10)
        assert sol.status.startswith("reached t1"), sol.status
        np.testing.assert_allclose(sol.q, expected.q, rtol=0, atol=1e-8)
        np.testing.assert_allclose(sol.omega, expected.w, rtol=0, atol=1e-7)
        np.testing.assert_array_equal(sol.omega[1:] == 0.0, expected.stuck[1:])  # t0: at rest before it moves
        np.testing.assert_allclose(sol.domega[1:], expected.wdot[1:], rtol=1e-7, atol=1e-6)  # the outputs' own friction solve
        assert np.max(np.abs(sol.balance)) < 1e-7 * np.max(np.abs(sol.total))  # T + V (outputs) - W (integrated)
        # inverse dynamics along the reference's own motion, where it moves: the driving effort needed is
        # the drive applied (a Drive load is the effort asked for; at rest the static friction is not set by the motion)
        moving = ~expected.stuck & (expected.w != 0.0)
        r = aj.reactions(model,
                         (expected.q[moving], expected.w[moving], expected.wdot[moving]))
        np.testing.assert_allclose(r.driving, drive(times[moving]) if in_time else drive, atol=1e-7)
        pins = [name for name in r.forces if name in expected.reactions]  # the revolutes: |F| whatever the convention
        assert pins
        for name in pins:
            np.testing.assert_allclose(np.hypot(*np.moveaxis(np.asarray(r.forces[name]), -1, 0)),
                                       np.linalg.norm(expected.reactions[name][moving], axis=-1), rtol=1e-7, atol=1e-7,
                                       err_msg=name)

    check_against_the_reference()
    if in_time:
        assert np.count_nonzero(np.diff(expected.stuck.astype(int)) == 1) == 2  # held twice (and released)
    if case == "slider_crank" and parts == 1:  # again, the analyses in chunks of 7 (outputs) and 5 (reactions)
        from assurjax._kinetostatics import _api
        from assurjax.dynamics import _solve

        calls, rows_of = [], _solve.integrated_rows
        monkeypatch.setattr(_solve, "states_per_call", lambda frictions: 7)
        monkeypatch.setattr(_api, "states_per_call", lambda frictions: 5)
        monkeypatch.setattr(_solve, "integrated_rows", lambda out, rows: calls.append(rows) or rows_of(out, rows))
        check_against_the_reference()
        # the 81 samples in 12 chunks of 7, the last one filled (a first call may come from compiling for a chunk)
        np.testing.assert_array_equal(np.concatenate(calls[-12:]), np.minimum(np.arange(84), times.size - 1))


@pytest.mark.slow  # ~11 s; the stacked path stays in the default suite (many_elements), batches through test_kinetostatics.py
def test_friction_through_statics_solved_in_batches_obeys_the_law():
    """The two-legged strandbeest with friction in every joint (K past SUMMED_TERMS: the
    stacked path; the legs' statics, and their tangents, solved in batches of one kind of
    group per level): along motions either way, each element's friction is mu r |F| of its
    joint's reaction as the mechanism's single dense system gives it (method "global")."""
    from assurjax._friction import SUMMED_TERMS

    scene = aj.strandbeest(1)
    mu, radius = 0.2, 0.02
    rough = scene.with_loads(scene.loads + tuple(aj.JointFriction(j, mu, radius) for j in aj.joint_names(scene.mechanism)))
    assert len(rough.loads) - len(scene.loads) > SUMMED_TERMS
    q = np.linspace(0.3, 5.9, 6)
    w, a = np.array([1.5, -2.0, 0.7, -0.3, 3.0, -1.0]), np.array([0.5, 2.0, -1.0, 0.0, -3.0, 1.0])
    r = aj.reactions(rough, (q, w, a), method="global")
    assert np.all(np.asarray(r.friction_ok))
    for joint, force in r.forces.items():
        np.testing.assert_allclose(np.abs(r.friction[joint]), mu * radius * np.hypot(*np.moveaxis(np.asarray(force), -1, 0)),
                                   rtol=1e-9, atol=1e-12, err_msg=joint)


@pytest.mark.slow  # ~11 s; the default suite checks the stacked path (13 elements) against the joint-based
# reference in test_friction_random.py
def test_many_elements_take_the_stacked_path_to_the_same_friction():
    """Past SUMMED_TERMS elements the friction takes its stacked path (the reactions stacked
    at the elements' pairs, the revolutes' rates gathered from the link angles, the prismatic
    pair's element by element, put back in order): the slider-crank's friction split into
    three elements per pair (K = 12) against one element per pair (K = 4, element by element)
    at states moving either way and at rest: the same dw/dt and friction power to
    round-off, each element's rate and slope that of its pair."""
    import joint_reference_friction as jrf
    from assurjax._friction import SUMMED_TERMS
    from assurjax.dynamics._field import State, frictional

    scene = aj.load_scene("slider_crank")
    q = jnp.linspace(0.2, 6.0, 8)
    w = jnp.array([1.5, -2.0, 0.7, -0.3, 3.0, -1.0, 0.0, 2.0])

    def analysis(parts, order):
        frictions = _package_frictions(scene.mechanism, jrf.SLIDER_CRANK_FRICTION, parts)[::order]
        # three elements a pair: put in past check_loads, which refuses a second element on a pair
        model = eqx.tree_at(lambda m: m.loads, scene.model, tuple(scene.loads) + frictions)
        f = jax.jit(jax.vmap(lambda q, w: frictional(model, 0.0, State(q, w), jnp.where(w != 0, jnp.sign(w), 1.0))))(q, w)
        return len(frictions), f

    # the split elements in reverse: the prismatic pair's first, its revolutes' after
    (k, one), (k_split, split) = analysis(1, 1), analysis(3, -1)
    assert k <= SUMMED_TERMS < k_split
    assert np.all(one.consistent) and np.all(split.consistent)
    np.testing.assert_allclose(split.alpha, one.alpha, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(split.power, one.power, rtol=1e-12, atol=1e-12)
    for name in ("rates", "slopes", "raw_slopes"):
        per_pair = getattr(split, name)[:, ::-1].reshape(-1, k, 3)
        np.testing.assert_allclose(per_pair, np.repeat(getattr(one, name)[..., None], 3, -1), rtol=1e-15, atol=1e-15,
                                   err_msg=name)


def test_inverse_dynamics_of_a_prescribed_motion_with_friction():
    """assurjax.inverse_dynamics along q(t) = 0.5 + 3 t + 0.2 sin 5t (a JAX function: w and
    dw/dt by jvp) of the slider-crank with friction in every joint: the driving torque and
    the pin reactions, every element's friction and its power against the joint-based
    reference's inverse dynamics."""
    import joint_reference_friction as jrf

    scene = aj.load_scene("slider_crank")
    model = aj.Model(scene.mechanism, scene.gravity, _package_frictions(scene.mechanism, jrf.SLIDER_CRANK_FRICTION))
    t = np.linspace(0.0, 1.0, 11)
    r = aj.inverse_dynamics(model, lambda t: 0.5 + 3.0 * t + 0.2 * jnp.sin(5.0 * t), t)
    ref = jrf.slider_crank(0.5, 0.0)
    for k, tk in enumerate(t):
        q, w, a = 0.5 + 3.0 * tk + 0.2 * np.sin(5 * tk), 3.0 + np.cos(5 * tk), -5.0 * np.sin(5 * tk)
        expected = ref.inverse(q, w, a)
        assert abs(float(r.driving[k]) - expected["tau"]) < 1e-9 * (1 + abs(expected["tau"]))
        for joint in ("O", "A", "B"):  # the reference reports the force on its body_i, the earlier link
            np.testing.assert_allclose(r[joint][k], -expected["reactions"][joint], atol=1e-9)
        for name, ref_name in (("O", "O"), ("A", "A"), ("B", "B"), ("slider/ground", "P")):
            friction = expected["friction"][ref_name] + expected["damping"][ref_name]  # on the earlier link, as above
            assert abs(float(r.friction[name][k]) + friction) < 1e-9 * (1 + abs(friction)), name
            power = friction * expected["rates"][ref_name]
            assert abs(float(r.friction_power[name][k]) - power) < 1e-9 * (1 + abs(power)), name


@pytest.mark.slow
def test_start_on_a_switch_takes_the_signs_it_goes_on_with():
    """The Watt six-bar from rest at q = 0, where four pins' relative rates are 0 (to
    round-off): the segment reads the signs just ahead of the start (a round-off sign held
    two pins' friction the wrong way through the whole segment). d q(0.3 s)/d mu, reverse
    and forward mode, against central differences."""
    scene = aj.load_scene("watt_sixbar")

    def q_at(mu, adjoint):
        rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O2", "A", "B", "O4", "C", "D", "E"))
        return aj.synthesis.final_state(scene.with_loads(rough), 0.3, q0=0.0, omega0=0.0, rtol=1e-11, atol=1e-11,
                                        adjoint=adjoint)[0]

    h = 1e-5
    fd = (q_at(jnp.asarray(0.15 + h), "recursive") - q_at(jnp.asarray(0.15 - h), "recursive")) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(lambda m: q_at(m, "recursive"))(jnp.asarray(0.15))), float(fd), rtol=1e-6)
    np.testing.assert_allclose(float(jax.jacfwd(lambda m: q_at(m, "forward"))(jnp.asarray(0.15))), float(fd), rtol=1e-6)


FAST_LOOPS_RUN = """
import json, sys
import assurjax as aj
aj.enable_fast_loops()
import jax, jax.numpy as jnp
sys.path.insert(0, {tests!r})
import test_friction as tf
slider = aj.load_scene("slider_crank")
sol = tf.run(slider, tf.MU, viscous=1e-3)
solve = jax.jit(tf._closed_form_solve(slider))
laws = [(float(u[0]), bool(ok)) for u, ok in (solve(a, b) for a, b, _, _ in tf.CLOSED_FORM_LAWS)]
print(json.dumps(dict(fast=aj._jit.fast_loops(), q=sol.q.tolist(), omega=sol.omega.tolist(), balance=sol.balance.tolist(), laws=laws)))
"""

FAST_LOOPS_TRIAD = """
import json, sys
import assurjax as aj
aj.enable_fast_loops()
sys.path.insert(0, {tests!r})
import test_friction as tf
print(json.dumps(dict(fast=aj._jit.fast_loops(), triad=tf.rough_triad_reactions())))
"""


def run_fast_loops(code: str) -> dict:
    """The last line a fresh Python process with fast loops prints, as JSON."""
    import json
    import os
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", code.format(tests=os.path.dirname(__file__))], check=True,
                         capture_output=True, text=True).stdout
    result = json.loads(out.strip().splitlines()[-1])
    assert result["fast"], "the child process did not run with the fast-loops flag"
    return result


def rough_triad_reactions() -> list:
    """Driving torque and every joint's force of the triad mechanism with friction in its seven
    joints, at three states (moving both ways, starting from rest): its group's dense statics
    and the friction's Newton solve (K = 7), the solves fast loops do without LAPACK."""
    triad = aj.load_scene("triad_mechanism")
    rough = triad.with_loads(tuple(triad.loads) + tuple(aj.JointFriction(j, MU, RADIUS, viscous=1e-3)
                                                        for j in aj.joint_names(triad.mechanism)))
    found = aj.reactions(rough, (jnp.array([0.3, 1.2, 2.5]), jnp.array([1.0, -2.0, 0.0]), jnp.array([0.5, 0.1, -1.0])))
    assert bool(jnp.all(found.ok))
    return [found.driving.tolist()] + [found.forces[j].tolist() for j in sorted(found.forces)]


@pytest.mark.slow  # a fresh process compiling the rough slider-crank again (~20 s)
def test_fast_loops_give_the_same_motion(rough):
    """With assurjax.enable_fast_loops() (a fresh process: the XLA flag is read once) the
    friction's Newton fallback solves without LAPACK (plain LU): the rough slider-crank's
    motion as in this process, its energy balance, the closed-form laws with their failure
    flags; and in this process, where JAX has run, the call says it is too late."""
    import os

    fast = run_fast_loops(FAST_LOOPS_RUN)
    np.testing.assert_allclose(fast["q"], rough.q, rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast["omega"], rough.omega, rtol=0, atol=1e-7)
    assert np.max(np.abs(fast["balance"])) < 1e-8 * np.max(np.abs(rough.total))
    for (u, ok), (_, _, expected, expected_ok) in zip(fast["laws"], CLOSED_FORM_LAWS):
        assert ok == expected_ok and (expected is None or abs(u - expected) < 1e-12)
    if "xla_cpu_small_while_loop_byte_threshold" not in os.environ.get("XLA_FLAGS", ""):
        with pytest.raises(aj.AssurjaxError, match="too late"):
            aj.enable_fast_loops()


@pytest.mark.slow
def test_fast_loops_give_the_same_triad_reactions():
    """With fast loops a triad's dense statics and the friction's Newton solve (K = 7) use plain
    LU: the rough triad's reactions as this process's (LAPACK) ones."""
    fast = run_fast_loops(FAST_LOOPS_TRIAD)
    for fast_values, values in zip(fast["triad"], rough_triad_reactions()):
        np.testing.assert_allclose(fast_values, values, rtol=1e-10, atol=1e-10 * np.max(np.abs(values)))


@pytest.mark.slow  # ~15 s; the band against closed forms stays in the default suite
def test_the_break_away_band_at_a_dead_point_is_that_of_the_starts():
    """At the slider-crank's dead points (q = 0, pi) the slider's rate is 0, and the band gave
    it no friction: 0.7089-0.7629 N m at q = 0 where 0.7077-0.7640 holds just beside it, and a
    drive of 0.7634 did not start the mechanism that the band said it would (simulate reads
    the signs just ahead). Now each edge is the start's that way, as the joint-based
    reference's (which reads its signs at q +- 1e-6 through its own position analysis); and
    driven just inside the band a run stays at rest with dw/dt = 0 (it was 0.09 rad/s^2 held),
    just past it, it starts."""
    import joint_reference_friction as jrf

    scene, table = aj.load_scene("slider_crank"), jrf.SLIDER_CRANK_FRICTION
    model = aj.Model(scene.mechanism, scene.gravity, tuple(scene.loads) + _package_frictions(scene.mechanism, table))
    q = np.array([0.0, math.pi])
    expected = np.array([jrf.slider_crank(0.5, 0.0).holding_range(qi) for qi in q])
    band = np.stack(aj.breakaway_band(model, q), axis=-1)
    np.testing.assert_allclose(band, expected, rtol=0, atol=1e-10)
    beside = np.stack(aj.breakaway_band(model, q + 1e-9), axis=-1)  # continuous there
    np.testing.assert_allclose(band, beside, rtol=0, atol=1e-6)
    lower, upper = band[0]
    for drive, moves in ((upper - 1e-6, 0), (upper + 1e-6, 1), (lower + 1e-6, 0), (lower - 1e-6, -1)):
        driven = aj.Model(model.mechanism, model.gravity, model.loads + (aj.Drive(drive),))
        sol = aj.simulate(driven, q0=0.0, omega0=0.0, t1=0.2, stop=None, samples=3, rtol=1e-10, atol=1e-10)
        assert np.sign(sol.q[-1]) == moves, (drive, sol.q)
        if not moves:
            assert np.all(sol.domega == 0.0) and np.all(sol.omega == 0.0)


def _press_weighing(factor: float):
    """The press with every mass, inertia and applied force times ``factor`` (the friction
    radii as they are): by dynamic similarity its motion is the same."""
    import copy
    import pathlib
    import tomllib

    raw = tomllib.loads(pathlib.Path(aj.__file__).with_name("scenes").joinpath("press_with_friction.toml").read_text())
    raw = copy.deepcopy(raw)
    raw.pop("simulation", None)
    for link in raw["links"].values():
        link["mass"] *= factor
        link["inertia"] *= factor
    for load in raw["loads"]:
        if load["type"] == "motor":
            load["stall"] *= factor
        if load["type"] == "force":
            load["force"][0]["values"] = [factor * v for v in load["force"][0]["values"]]
    return aj.scene_from_dict(raw)


@pytest.mark.slow  # ~13 s (as test_a_heavier_mechanism_moves_the_same): the default suite keeps to 10 min
def test_a_press_a_trillion_times_lighter_moves_the_same():
    # the friction solve's tolerance was absolute (N, N m): at 1e-12 of the masses and forces the
    # press's angle erred by 1.9e-3 rad after 1 s, and no tolerance of the run brought it down
    ts = np.linspace(0.0, 1.0, 41)
    heavy = aj.simulate(_press_weighing(1.0), stop=None, t1=1.0, saveat=ts)
    light = aj.simulate(_press_weighing(1e-12), stop=None, t1=1.0, saveat=ts)
    assert heavy.successful and light.successful
    np.testing.assert_allclose(light.q, heavy.q, rtol=0, atol=1e-5)  # the runs' own error: ~2e-7


@pytest.mark.slow  # ~30 s: two programs at rtol 1e-13 and in float32
def test_a_coulomb_switch_is_located_at_tight_tolerances_and_in_float32(tmp_path):
    # the switch's bisection asked for 1e-16 s at t ~ 1 s (finer than the float spacing), and for
    # 1e-12 s in float32: the runs stopped there, 'maximum number of steps ... nonlinear solver'
    watt = aj.load_scene("watt_sixbar")
    rough = tuple(aj.JointFriction(j, 0.15, radius=0.01) for j in ("O2", "A", "B", "O4", "C", "D", "E"))
    tight = aj.simulate(watt, loads=rough, stop=None, t1=1.5, rtol=1e-13, atol=1e-13)
    loose = aj.simulate(watt, loads=rough, stop=None, t1=1.5, rtol=1e-11, atol=1e-11)
    assert tight.successful and abs(float(tight.q_final) - float(loose.q_final)) < 1e-8
    script = tmp_path / "f32.py"
    script.write_text(
        "import assurjax as aj\n"
        "sc = aj.load_scene('slider_crank')\n"
        "rough = tuple(aj.JointFriction(j, 0.15, radius=0.01) for j in ('O', 'A', 'B'))\n"
        "sol = aj.simulate(sc, loads=sc.loads + rough + (aj.Drive(5.0),), q0=0.0, t1=0.3, stop=None, rtol=1e-5, atol=1e-5)\n"
        "print(sol.successful, float(sol.q_final))\n")
    import os
    import subprocess
    import sys

    env = {**os.environ, "ASSURJAX_FLOAT32": "1", "JAX_ENABLE_X64": "0"}
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    ok, q32 = out.stdout.split()
    sc = aj.load_scene("slider_crank")
    rough3 = tuple(aj.JointFriction(j, 0.15, radius=0.01) for j in ("O", "A", "B"))
    q64 = float(aj.simulate(sc, loads=sc.loads + rough3 + (aj.Drive(5.0),), q0=0.0, t1=0.3, stop=None, rtol=1e-10, atol=1e-10).q_final)
    assert ok == "True" and abs(float(q32) - q64) < 1e-3  # float32 at 1e-5 against float64


def test_traced_friction_values_out_of_range_are_flagged():
    """A friction value traced past its constructor's checks (a sweep's, a vmap's): in_range()
    is False where the constructor would refuse it (a negative coefficient, radius, damping
    or static coefficient, a block length or smoothing speed not positive), True at its edges;
    the runs read it (the test below, and a sweep of the press with mu = -0.2 had the friction
    put 22 J into the press, its result "successful")."""
    def joint(mu, r, c, v, mu_s):
        return aj.JointFriction("O", mu, r, viscous=c, smoothing=v).in_range() & aj.JointFriction(
            "O", mu, r, viscous=c, static_coefficient=mu_s).in_range()

    def slide(mu, length, c):
        return aj.SlideFriction("slider/ground", mu, length, viscous=c).in_range()

    joint, slide = jax.jit(joint), jax.jit(slide)
    assert bool(joint(0.0, 0.0, 0.0, 1e-3, 0.0)) and bool(slide(0.0, 1e-3, 0.0))
    for bad in ((-0.1, 0.01, 0.0, 1e-3, 0.2), (0.1, -0.01, 0.0, 1e-3, 0.2), (0.1, 0.01, -1.0, 1e-3, 0.2),
                (0.1, 0.01, 0.0, 0.0, 0.2), (0.1, 0.01, 0.0, 1e-3, -0.2)):
        assert not bool(joint(*bad)), bad
    for bad in ((-0.1, 0.05, 0.0), (0.1, 0.0, 0.0), (0.1, 0.05, -2.0)):
        assert not bool(slide(*bad)), bad
    # inverse dynamics reads it too: the driving torque's flag (it was ok, the friction aiding the drive)
    crank = aj.load_scene("slider_crank").mechanism
    torque = jax.jit(lambda mu: aj.synthesis.driving_torque(crank, jnp.array([0.5, 2.0]), 3.0,
                                                            loads=(aj.JointFriction("O", mu, 0.01),)))
    assert np.all(torque(0.2)[1]) and not np.any(torque(-0.2)[1])


@pytest.mark.slow  # ~30 s: three friction programs of their own (no default test traces mu through a run to share one)
def test_a_traced_friction_coefficient_that_is_not_finite_is_named_not_held(slider):
    """A friction coefficient traced under the user's jit (an optimizer's step gone NaN)
    cannot be checked before the run; it read as a mechanism held at rest (from rest, q(T) =
    q0, a plausible answer) or as a jam. The run's result names it, and final_state is NaN.
    A negative one ran as a successful motion driven by its friction: its result names it."""
    settings = aj.SimulationSettings(samples=2)
    run = jax.jit(lambda mu: aj.simulate_core(slider.mechanism, slider.gravity, frictions(slider.mechanism, mu), 0.5, 0.0, 0.0,
                                              0.3, settings=settings))
    for mu in (np.nan, np.inf):
        assert run(jnp.asarray(mu)).result == aj.RESULTS.nonfinite_friction
    assert run(jnp.asarray(-MU)).result == aj.RESULTS.friction_out_of_range  # it ran, the friction driving it
    band = jax.jit(lambda mu: aj.breakaway_band(_with_friction(slider, mu), jnp.array([0.5, 2.0]), check=False))
    assert np.all(np.isfinite(band(jnp.asarray(MU)))) and np.all(np.isnan(band(jnp.asarray(-MU))))
    assert run(jnp.asarray(MU)).result == aj.RESULTS.successful
    q, w = jax.jit(lambda mu: aj.synthesis.final_state(_with_friction(slider, mu), 0.3))(jnp.asarray(np.nan))
    assert np.isnan(q) and np.isnan(w)
