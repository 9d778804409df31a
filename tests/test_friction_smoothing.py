"""The regularized friction law (``smoothing``: sign(rate) -> tanh(rate / v_s)), asked for per element.

Independent checks: the joint-based reference (tests/joint_reference_friction.py) integrated
with the same regularized signs by scipy, the energy balance, the exact law's motion as
v_s -> 0, and central differences for the derivatives.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import assurjax as aj

SPEEDS = dict(O=0.05, A=0.05, B=0.05, P=0.005)  # rad/s for the pins, m/s for the slider
T1 = 0.6
TIMES = np.linspace(0.0, T1, 25)


def _frictions(mechanism, table, speeds, scale=1.0):
    """The reference's friction table as package loads, each with its smoothing speed (None: exact)."""
    out = []
    for name in aj.joint_names(mechanism):
        key = "P" if "/" in name else name
        ref, speed = table[key], None if speeds is None else speeds[key] * scale
        if "/" in name:
            out.append(aj.SlideFriction(name, ref.mu, ref.length, viscous=ref.damping, smoothing=speed))
        else:
            out.append(aj.JointFriction(name, ref.mu, ref.radius, viscous=ref.damping, smoothing=speed))
    return tuple(out)


def _reference_acceleration(model, q, w):
    """dw/dt of the reference's forward dynamics with the Coulomb signs tanh(rate / v_s)."""
    system = model.system
    z, zq = model.assembled(q)
    v_s = np.array([SPEEDS[name] for name in system.friction_joints])
    return system.forward(z, w, 0.0, zq, signs=np.tanh(system.directions(z)[0] @ zq * w / v_s))["wdot"]


def _reference_motion(model, q0, w0):
    """The reference's motion with that law, by scipy's DOP853."""
    return solve_ivp(lambda t, y: [y[1], _reference_acceleration(model, *y)], (0.0, T1), [q0, w0], method="DOP853",
                     t_eval=TIMES, rtol=1e-10, atol=1e-11)


@pytest.fixture(scope="module")
def case():
    import joint_reference_friction as jrf

    scene, table = aj.load_scene("slider_crank"), jrf.SLIDER_CRANK_FRICTION
    return scene, table, jrf.slider_crank(0.5, 0.0)


def _run(scene, loads, **kw):
    return aj.simulate(scene, loads=loads, q0=0.5, stop=None, t1=T1, saveat=TIMES, energies=True, rtol=1e-10,
                       atol=1e-10, **kw)


@pytest.mark.slow  # ~20 s; the default suite checks the regularized law's derivative (the sensitivity route)
def test_smoothed_law_agrees_with_the_joint_based_reference(case):
    """The slider-crank from rest, every pair rough (viscous terms too) with the regularized law:
    one smooth field, no segments, so the solver's own steps are saved too (``save_steps``,
    which the exact law's segments do not offer); q within 1e-8 rad of the reference
    integrated with the same law at the grid's times, dw/dt of the output samples within
    1e-7, the energy balance closed at every saved state, and inverse dynamics along the
    motion asking for no drive (none is applied). At rest at t0 the law has no friction: the
    mechanism starts at once (no stiction)."""
    scene, table, reference = case
    loads = tuple(scene.loads) + _frictions(scene.mechanism, table, SPEEDS)
    sol = _run(scene, loads, save_steps=True)
    expected = _reference_motion(reference, 0.5, 0.0)
    assert sol.status.startswith("reached t1"), sol.status
    assert expected.success
    grid = np.searchsorted(sol.t, TIMES)
    assert sol.t.size > 3 * TIMES.size and np.all(sol.t[grid] == TIMES)
    np.testing.assert_allclose(sol.q[grid], expected.y[0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sol.omega[grid], expected.y[1], rtol=0, atol=1e-7)
    wdot = np.array([_reference_acceleration(reference, q, w) for q, w in zip(*expected.y)])
    np.testing.assert_allclose(sol.domega[grid], wdot, rtol=1e-7, atol=1e-6)
    assert np.max(np.abs(sol.balance)) < 1e-8 * np.max(np.abs(sol.total))  # as the exact law's, at this rtol
    assert sol.dissipated[-1] > 0.0
    r = aj.reactions(aj.Model(scene.mechanism, scene.gravity, loads), (sol.q, sol.omega, sol.domega))
    np.testing.assert_allclose(r.driving, 0.0, atol=1e-8)
    assert r.friction["A"][0] == 0.0  # at rest: tanh(0)


@pytest.mark.slow  # ~8-12 s (the exact law's program): the default suite keeps to 10 min
def test_smoothed_law_tends_to_the_exact_law(case):
    """Up to the first standstill (~0.49 s), the regularized motion approaches the exact
    law's as v_s -> 0, about in proportion to v_s (the smoothing speeds are traced: one
    program for both, the one of the test above)."""
    scene, table, _ = case
    exact = _run(scene, tuple(scene.loads) + _frictions(scene.mechanism, table, None))
    moving = TIMES < 0.45  # before the first standstill
    errors = []
    for scale in (1.0, 0.1):
        smooth = _run(scene, tuple(scene.loads) + _frictions(scene.mechanism, table, SPEEDS, scale), save_steps=True)
        q = smooth.q[np.searchsorted(smooth.t, TIMES)]
        errors.append(np.max(np.abs(q[moving] - exact.q[moving])))
    assert errors[0] < 1e-2 and 5.0 < errors[0] / errors[1] < 20.0, errors


@pytest.mark.slow  # ~17 s of compiles (the field's forward-mode derivative and the field)
def test_acceleration_derivatives_in_mu_and_the_smoothing_speed(case):
    """d(dw/dt)/d mu and d(dw/dt)/d v_s of the field at moving states (the friction solve's
    implicit derivative, tanh's own) against central differences."""
    from assurjax.dynamics._field import State, field_args, vector_field

    scene, table, _ = case
    q, w = jnp.array([0.5, 2.0, 4.0]), jnp.array([0.02, -0.01, 1.5])  # inside and past the smoothing band

    def acceleration(mu, speed):
        loads = tuple(scene.loads) + tuple(aj.JointFriction(j, mu, 0.02, viscous=1e-3, smoothing=speed)
                                           for j in ("O", "A", "B"))
        model = aj.Model(scene.mechanism, scene.gravity, loads + (aj.SlideFriction("slider/ground", mu, 0.04, smoothing=speed),))
        return jax.vmap(lambda q, w: vector_field(0.0, State(q, w), field_args(model, direction=jnp.sign(w))).omega)(q, w)

    f = jax.jit(acceleration)
    mu, speed, h = 0.2, 0.05, 1e-6
    d_mu, d_speed = jax.jit(jax.jacfwd(acceleration, argnums=(0, 1)))(mu, speed)
    np.testing.assert_allclose(d_mu, (f(mu + h, speed) - f(mu - h, speed)) / (2 * h), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(d_speed, (f(mu, speed + h) - f(mu, speed - h)) / (2 * h), rtol=1e-6, atol=1e-8)
    assert np.all(np.abs(d_speed[:2]) > 1e-3)  # inside the band the speed matters


def _rough(scene, mu):
    """The slider-crank with the regularized law in every pair, mu in each."""
    return scene.with_loads(tuple(scene.loads) + tuple(
        aj.JointFriction(j, mu, 0.02, smoothing=0.05) for j in ("O", "A", "B")) + (
        aj.SlideFriction("slider/ground", mu, 0.04, smoothing=0.005),))


@pytest.mark.slow  # reverse mode through a whole smoothed simulation: ~35 s of compiles
def test_gradient_through_a_smoothed_simulation(case, monkeypatch):
    """d q(0.8 s) / d mu through the one smooth solve (reverse mode), against central
    differences; a second call of the unjitted ``jax.grad`` at another mu reuses the compiled
    program (``synthesis.final_state`` traces the simulation once)."""
    from assurjax.synthesis import _dynamic

    scene, table, _ = case

    def q_at(mu):
        return aj.synthesis.final_state(_rough(scene, mu), 0.8, q0=0.5, rtol=1e-11, atol=1e-11)[0]

    h = 1e-5
    fd = (q_at(jnp.asarray(0.2 + h)) - q_at(jnp.asarray(0.2 - h))) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(q_at)(jnp.asarray(0.2))), float(fd), rtol=1e-6)
    traced = []
    monkeypatch.setattr(_dynamic, "simulate_core", lambda *a, **k: traced.append(1))  # only a new trace would call it
    assert np.isfinite(float(jax.grad(q_at)(jnp.asarray(0.25)))) and not traced


def _q_at(scene, mu, adjoint="sensitivity"):
    return aj.synthesis.final_state(_rough(scene, mu), 0.6, q0=0.5, rtol=1e-11, atol=1e-11, adjoint=adjoint)[0]


def test_the_sensitivity_route_differentiates_the_regularized_law(case, write_scene):
    """adjoint='sensitivity' (forward sensitivities integrated with the state, one field of
    (q, w)) carries the regularized law: a rough arm falling from the horizontal, d q(1 s) / d mu
    against central differences of the route's plain runs (the slow suite: the slider-crank
    rough in every pair, against simulations). The exact law, and the quadrature route (its
    fixed panels miss the law's steep turns near a rest), are refused in words."""
    from scene_texts import ROUGH_ARM

    arm = aj.load_scene(write_scene('[scene]\nname = "arm"\ngravity = [0.0, -9.81]\n[state]\nq0 = 0.0\n' + ROUGH_ARM))

    def q_at(mu, adjoint="sensitivity"):
        rough = arm.with_loads((aj.JointFriction("O", mu, 0.04, smoothing=0.02),))
        return aj.synthesis.final_state(rough, 1.0, rtol=1e-11, atol=1e-11, adjoint=adjoint)[0]

    h = 1e-5
    fd = (q_at(jnp.asarray(0.3 + h)) - q_at(jnp.asarray(0.3 - h))) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(q_at)(jnp.asarray(0.3))), float(fd), rtol=1e-7)
    with pytest.raises(aj.AssurjaxError, match="does not resolve its steep turns"):
        q_at(0.3, "quadrature")
    scene, table, _ = case
    exact = scene.with_loads(tuple(scene.loads) + _frictions(scene.mechanism, table, None))
    with pytest.raises(aj.AssurjaxError, match="4 element\\(s\\) have \\(the first: 'O', no smoothing\\)"):
        aj.synthesis.standstill_time(exact, adjoint="sensitivity")


@pytest.mark.slow  # ~60 s of compiles
def test_the_sensitivity_route_on_the_slider_crank(case, monkeypatch):
    """The same route on the slider-crank rough in every pair, from rest: d q(0.6 s) / d mu in
    reverse and forward mode, and the first standstill's time d t*/d mu
    (the implicit function theorem at the event), against central differences of
    simulations (``simulate_core``, the package's own segment-free solve); a second
    reverse-mode call at another mu reuses the compiled program."""
    from assurjax.synthesis import _sensitivity

    scene, _, _ = case
    h = 1e-5
    fd = (_q_at(scene, jnp.asarray(0.2 + h), "recursive") - _q_at(scene, jnp.asarray(0.2 - h), "recursive")) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(lambda mu: _q_at(scene, mu))(jnp.asarray(0.2))), float(fd), rtol=1e-6)
    np.testing.assert_allclose(float(jax.jacfwd(lambda mu: _q_at(scene, mu))(jnp.asarray(0.2))), float(fd), rtol=1e-6)

    def t_stop(mu, adjoint="sensitivity"):
        t, ok = aj.synthesis.standstill_time(_rough(scene, mu), t1=2.0, q0=0.5, rtol=1e-11, atol=1e-11, adjoint=adjoint)
        assert bool(ok)
        return t

    fd = (t_stop(jnp.asarray(0.2 + h), "recursive") - t_stop(jnp.asarray(0.2 - h), "recursive")) / (2 * h)
    assert 0.3 < float(t_stop(jnp.asarray(0.2))) < 1.0
    np.testing.assert_allclose(float(jax.grad(t_stop)(jnp.asarray(0.2))), float(fd), rtol=1e-5)
    traced = []
    monkeypatch.setattr(_sensitivity, "_final_state_fn", lambda *a: traced.append(1))  # only a new trace would call it
    assert np.isfinite(float(jax.grad(lambda mu: _q_at(scene, mu))(jnp.asarray(0.25)))) and not traced


def test_smoothing_speed_is_checked(case):
    """A smoothing speed must be a positive number: the error names the element and field.
    Fixed steps stay refused with a smoothed law, for what they cannot do (tell a jam)."""
    scene, table, _ = case
    with pytest.raises(aj.AssurjaxError, match="not available with joint friction, even smoothed"):
        aj.simulate(scene, loads=_frictions(scene.mechanism, table, SPEEDS), steps=100, stop=None, t1=0.1)
    with pytest.raises(aj.MechanismError, match="JointFriction 'A': smoothing must be positive, got 0"):
        aj.JointFriction("A", 0.2, 0.01, smoothing=0.0)
    with pytest.raises(aj.MechanismError, match="SlideFriction 'slider/ground': smoothing must be finite"):
        aj.SlideFriction("slider/ground", 0.2, 0.04, smoothing=float("nan"))


def test_smoothing_in_a_scene_file(write_scene, capsys):
    """A friction entry's ``smoothing`` key gives the element its regularized law; a speed that
    is not positive is an error naming the entry and the field. The command's line on a run at
    rest does not say the friction holds it (a regularized law holds nothing)."""
    from types import SimpleNamespace

    from scene_texts import ROUGH_ARM

    from assurjax.cli import _rest_line, _smoothed_pairs

    header = '[scene]\nname = "arm"\ngravity = [0.0, -9.81]\n[state]\nq0 = 0.0\n'
    scene = aj.load_scene(write_scene(header + ROUGH_ARM + "smoothing = 0.02\n"))
    (element,) = [load for load in scene.loads if isinstance(load, aj.JointFriction)]
    assert float(element.smoothing) == 0.02 and _smoothed_pairs(scene) == ["O"]
    still = SimpleNamespace(t=np.linspace(0.0, 1.0, 3), omega=np.zeros(3), successful=True, event=np.asarray(-1))
    assert _rest_line(scene, still) == "  at rest throughout: nothing moves it from its start"
    exact = aj.load_scene(write_scene(header + ROUGH_ARM, "exact.toml"))
    assert exact.loads[0].smoothing is None and _smoothed_pairs(exact) == []
    with pytest.raises(aj.SceneError, match=r"\[\[loads\]\] #1 \(joint_friction\), field 'smoothing': must be positive, got -0.1"):
        aj.load_scene(write_scene(header + ROUGH_ARM + "smoothing = -0.1\n", "bad.toml"))


@pytest.mark.slow  # one more program (~6 s)
def test_mixed_laws_keep_the_exact_elements_stiction(case):
    """Pins smoothed, the slider exact: the run keeps its segments for the slider's law, whose
    stiction then holds the mechanism for good (w exactly 0, q constant: the smoothed pins carry
    no friction at rest), and the energy balance closes."""
    scene, table, _ = case
    speeds = {**SPEEDS, "P": None}
    loads = tuple(f if speeds["P" if "/" in f.pair else f.pair] is not None else
                  aj.SlideFriction(f.pair, f.coefficient, f.length, viscous=f.viscous)
                  for f in _frictions(scene.mechanism, table, {k: v or 1.0 for k, v in speeds.items()}))
    assert [f.smoothing is None for f in loads] == [False, False, False, True]
    sol = aj.simulate(scene, loads=tuple(scene.loads) + loads, q0=0.5, stop=None, t1=3.0, samples=61, energies=True,
                      rtol=1e-10, atol=1e-10)
    assert sol.status.startswith("reached t1"), sol.status
    held = np.flatnonzero(sol.omega == 0.0)
    assert held.size > 5 and held[-1] == sol.t.size - 1 and np.all(np.diff(held[held > 0]) == 1)
    assert np.all(sol.q[held[1:]] == sol.q[-1])
    assert np.max(np.abs(sol.balance)) < 1e-8 * np.max(np.abs(sol.total))


@pytest.mark.slow  # one more program (~8 s)
def test_a_stiff_smoothed_law_is_named_where_the_steps_run_out(case):
    """Every pair rough enough to hold the slider-crank at q = 0.5 (mu = 0.8): with the
    regularized law it creeps at a rate of order v_s, where the law's friction turns over
    ~v_s and the field is stiff as 1 / v_s. At v_s = 1e-3 the explicit steps still reach t1;
    at 1e-4 they use up the budget, and the status says why, naming each element."""
    scene = case[0]

    def rough(speed):
        return tuple(aj.SlideFriction(n, 0.8, 0.05, smoothing=speed) if "/" in n else
                     aj.JointFriction(n, 0.8, 0.05, smoothing=speed) for n in aj.joint_names(scene.mechanism))

    loose = aj.simulate(scene, loads=tuple(scene.loads) + rough(1e-3), q0=0.5, stop=None, t1=1.0)
    assert loose.status == "reached t1 = 1 s" and abs(loose.q[-1] - 0.5) < 1e-2, loose.status
    stiff = aj.simulate(scene, loads=tuple(scene.loads) + rough(1e-4), q0=0.5, stop=None, t1=1.0)
    assert "step budget" in stiff.status and "within 10 smoothing speeds of rest in 'O' (v_s = 0.0001)" in stiff.status
    assert all(f"'{n}' (v_s = 0.0001)" in stiff.status for n in aj.joint_names(scene.mechanism))
    assert "give those elements the exact law" in stiff.status and abs(stiff.q[-1] - 0.5) < 1e-3
