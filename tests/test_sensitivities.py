"""Derivatives with respect to every mechanism parameter, checked against central finite differences.

Every Jacobian J (reverse and forward mode) is compared with a Richardson-extrapolated
central difference D of the same function over the flat parameter vector:
max |J - D| <= 1e-6 max |D| (float64).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax import synthesis as syn
from assurjax._reduction import reduce_single

RTOL = 1e-6
Q_SYMMETRIC = float(np.arccos(1.0 / 3.0))  # Roberts symmetric position (seed 001)
Q_NEAR_TOGGLE = 1.565  # the Roberts dyad toggles at q ~ 1.5717: 7 mrad away


def central_difference(f, theta, h):
    """Richardson-extrapolated central difference of f at theta along every axis (O(h^4))."""
    eye = jnp.eye(theta.size, dtype=theta.dtype)

    def d(step):
        plus = jax.vmap(lambda e: f(theta + step * e))(eye)
        minus = jax.vmap(lambda e: f(theta - step * e))(eye)
        return jnp.moveaxis((plus - minus) / (2 * step), 0, -1)

    return (4 * d(h / 2) - d(h)) / 3


def assert_close_jacobian(jac, fd, rtol=RTOL):
    jac, fd = np.asarray(jac), np.asarray(fd)
    assert np.all(np.isfinite(jac))
    scale = np.max(np.abs(fd))
    err = np.max(np.abs(jac - fd))
    assert err <= rtol * scale, f"max |AD - FD| = {err:.3e} > {rtol} * {scale:.3e}"


@pytest.fixture(scope="module")
def roberts():
    return assurjax.load_scene("roberts").mechanism


@pytest.fixture(scope="module")
def watt():
    return assurjax.load_scene("watt_sixbar")


def _flat_check(fn, tree, h, select=None, rtol=RTOL, modes=("reverse", "forward")):
    """Jacobian of fn over the flat parameters, in the given modes, against central differences."""
    theta, unflatten = syn.flatten_parameters(tree, select=select)
    f = jax.jit(lambda th: fn(unflatten(th)))
    fd = central_difference(f, theta, h)
    out = None
    for mode in modes:
        jac = jax.jit(jax.jacrev(f) if mode == "reverse" else jax.jacfwd(f))(theta)
        assert_close_jacobian(jac, fd, rtol)
        out = jac
    return out


def test_coupler_curve_gradient_every_parameter(roberts):
    """Coupler point P of the Roberts linkage at five crank angles, one of them 7 mrad from a toggle."""
    q = jnp.array([0.9, Q_SYMMETRIC, 1.4, 1.53, Q_NEAR_TOGGLE])
    pts, ok = syn.coupler_curve(roberts, "P", q)
    assert np.all(ok)
    jac = _flat_check(lambda m: syn.coupler_curve(m, "P", q)[0], roberts, 1e-5)
    names = syn.parameter_names(roberts)
    assert jac.shape == (5, 2, len(names))
    # masses and inertias do not move the coupler point; the coupler's P does, one for one
    for i, name in enumerate(names):
        if "mass" in name or "inertia" in name or "com" in name:
            assert np.all(jac[..., i] == 0.0), name
    assert np.abs(jac[..., names.index(".links['link4'].points['P'][0]")]).max() > 0.5


def test_library_jacobian_matches_jax(roberts):
    """syn.jacobian (both modes) and syn.gradient agree with the flat Jacobian."""
    q = jnp.array([1.0, 1.3])
    fn = lambda m: syn.coupler_curve(m, "P", q)[0][:, 1]  # noqa: E731
    sel = lambda m: (m.ground["D"], m.links["link4"].points["P"])  # noqa: E731
    theta, unflatten = syn.flatten_parameters(roberts, select=sel)
    fd = central_difference(jax.jit(lambda th: fn(unflatten(th))), theta, 1e-5)
    assert_close_jacobian(syn.jacobian(fn, roberts, select=sel, mode="reverse"), fd)
    assert_close_jacobian(syn.jacobian(fn, roberts, select=sel, mode="forward"), fd)
    g = syn.gradient(lambda m: fn(m)[0], roberts, select=sel)
    assert_close_jacobian(np.concatenate([np.ravel(x) for x in g]), fd[0])
    assert syn.parameter_names(roberts, select=sel) == [".ground['D'][0]", ".ground['D'][1]", ".links['link4'].points['P'][0]", ".links['link4'].points['P'][1]"]
    assert ".links['link4'].points['P'][1]" in syn.parameter_names(roberts)
    # one array object in two places is named where it is selected (by identity it took the other's name)
    shared = jnp.zeros(2)
    twice = eqx.tree_at(lambda m: (m.links["link2"].points["A"], m.links["link4"].points["P"]), roberts, (shared, shared))
    assert syn.parameter_names(twice, select=lambda m: m.links["link2"].points["A"]) == [".links['link2'].points['A'][0]",
                                                                                       ".links['link2'].points['A'][1]"]


def _law_of_cosines_mu(l_a, l_b, d):
    return np.arccos((l_a**2 + l_b**2 - d**2) / (2 * l_a * l_b))


def test_transmission_angle_closed_form_and_gradient(roberts):
    """Transmission angle at C (coupler BC, rocker DC) against the law of cosines, then its gradient."""
    q = jnp.array([0.9, Q_SYMMETRIC, Q_NEAR_TOGGLE])
    mu = np.asarray(jax.vmap(lambda qi: syn.transmission_angles(roberts, qi)["dyad43"])(q))
    a, d_pt = np.array([-0.12, 0.0]), np.array([0.12, 0.0])
    b = a + 0.18 * np.stack([np.cos(q), np.sin(q)], -1)
    expected = _law_of_cosines_mu(0.12, 0.18, np.linalg.norm(b - d_pt, axis=-1))
    np.testing.assert_allclose(mu, expected, rtol=1e-12)
    _flat_check(lambda m: jax.vmap(lambda qi: syn.transmission_angles(m, qi)["dyad43"])(q), roberts, 1e-5)
    margin = jax.vmap(lambda qi: syn.assembly_margin(roberts, qi))(q)
    np.testing.assert_allclose(margin, np.sin(expected), rtol=1e-12)


def test_link_angles_gradient(watt):
    """Every link angle of the Watt six-bar at three crank angles."""
    q = jnp.array([0.0, 0.4, -0.5])

    def angles(m):
        pose = jax.vmap(lambda qi: assurjax.positions(m, qi))(q)
        assert pose.ok.shape == (3, 3)
        return jnp.stack([pose.angles[k] for k in sorted(pose.angles)])

    _flat_check(angles, watt.mechanism, 1e-5)


def test_reduction_directional_derivative(watt):
    """J_red, dJ_red/dq and tau_red at one crank angle: a forward-mode derivative along a random
    direction in the space of all 50 scene parameters, against the central difference (the full
    Jacobians in both modes are checked by the slow test below)."""
    theta, unflatten = syn.flatten_parameters(watt, select=lambda s: (s.mechanism, s.gravity))
    v = jax.random.normal(jax.random.key(1), theta.shape)

    def reduced(th):
        scene = unflatten(th)
        red = reduce_single(scene.mechanism, scene.gravity, scene.loads, 0.3, 0.0, 0.0)
        return jnp.stack([red.inertia, red.dinertia, red.torque])

    jvp = jax.jit(lambda th: jax.jvp(reduced, (th,), (v,))[1])(theta)
    f = jax.jit(reduced)
    d = lambda s: (f(theta + s * v) - f(theta - s * v)) / (2 * s)  # noqa: E731
    assert_close_jacobian(jvp, (4 * d(0.5e-5) - d(1e-5)) / 3)


@pytest.mark.slow  # reverse over nested jvp of a six-bar, 50 parameters: minutes on a busy 2-core machine
def test_reduction_and_peak_torque_gradients(watt):
    """J_red(q), dJ_red/dq, tau_red (gravity) at three crank angles, and the peak driving torque at
    constant crank speed (inverse dynamics via the reduction), w.r.t. every length, centre of mass,
    mass, inertia and gravity: one function, reverse and forward mode."""
    q = jnp.array([0.0, 0.3, -0.4])
    q_peak = jnp.linspace(-0.6, 0.6, 25)
    tau, ok = syn.driving_torque(watt.mechanism, q_peak, 3.0, gravity=watt.gravity)
    assert np.all(ok) and np.sum(np.asarray(tau) == np.max(np.asarray(tau))) == 1  # a unique, smooth peak

    def reduced(scene):
        red = jax.vmap(lambda qi: reduce_single(scene.mechanism, scene.gravity, scene.loads, qi, 0.0, 0.0))(q)
        tau, _ = syn.driving_torque(scene.mechanism, q_peak, 3.0, gravity=scene.gravity)
        return jnp.concatenate([red.inertia, red.dinertia, red.torque, jnp.max(tau)[None]])

    _flat_check(reduced, watt, 1e-5, select=lambda s: (s.mechanism, s.gravity))


def test_driving_torque_matches_energy_balance(watt):
    """At constant speed, tau w = dE/dt with E = J_red w^2 / 2 + V(q): checked by differencing E in q."""
    w = 3.0
    q = jnp.linspace(-0.5, 0.5, 11)
    tau, _ = syn.driving_torque(watt.mechanism, q, w, gravity=watt.gravity)

    def energy(qi):
        pose = assurjax.positions(watt.mechanism, qi)
        potential = -sum(link.mass * jnp.dot(watt.gravity, pose.coms[k]) for k, link in watt.mechanism.links.items())
        kin = assurjax.kinematics(watt.mechanism, qi, 1.0, order=1, check=False)
        j_red = sum(link.mass * jnp.sum(kin.com_velocities[k] ** 2) + link.inertia * kin.angular_velocities[k] ** 2
                    for k, link in watt.mechanism.links.items())
        return 0.5 * j_red * w**2 + potential

    h = 1e-5
    energies = jax.jit(jax.vmap(energy))
    de_dq = (energies(q + h) - energies(q - h)) / (2 * h)
    np.testing.assert_allclose(tau, de_dq, rtol=1e-7, atol=1e-8)


# ~10 s; test_synthesis_optimize's test_straight_line_gradients_match_differences[best line by x] checks
# the same objective's gradient (reverse and forward mode) against central differences by default
@pytest.mark.slow
def test_straight_line_objective_gradient():
    """The smooth straight-line objective (root finds on x(q) = target, least-squares line,
    soft maxima) of a perturbed Roberts linkage: its gradient over the six lengths and the
    stroke centre is the derivative of its value (central differences)."""
    lengths = np.asarray(syn.roberts_lengths()) * (1 + np.random.default_rng(0).uniform(-0.1, 0.1, 6))
    design, objective = syn.straight_line_problem(lengths)
    lengths0, centre0 = design.values(design.init())
    theta = jnp.concatenate([jnp.asarray(lengths0), jnp.atleast_1d(centre0)])
    f = jax.jit(lambda th: objective((th[:6], th[6]))[0])
    fd = central_difference(f, theta, 1e-5)
    grad = jax.jit(jax.grad(f))(theta)
    assert_close_jacobian(grad, fd, rtol=1e-5)


def test_no_nan_gradients_on_random_valid_configurations(roberts, watt):
    """Random perturbed mechanisms at random q: every gradient of an assembled configuration is finite,
    and so is every value where assembly fails (flagged, never NaN)."""
    n = 64
    key = jax.random.key(7)
    for mech, point in ((roberts, "P"), (watt.mechanism, "E")):
        batch = assurjax.perturb(mech, key, n, relative=0.1)
        q = jax.random.uniform(jax.random.fold_in(key, 1), (n,), minval=-np.pi, maxval=np.pi)

        def value_and_grads(m, qi):
            f = lambda m, qi: syn.coupler_curve(m, point, qi)[0]  # noqa: E731
            ok = syn.coupler_curve(m, point, qi)[1]
            jac_m = jax.jacrev(f)(m, qi)
            jac_q = jax.jacfwd(f, argnums=1)(m, qi)
            return f(m, qi), ok, jac_m, jac_q

        vals, ok, jac_m, jac_q = eqx.filter_jit(eqx.filter_vmap(value_and_grads))(batch, q)
        ok = np.asarray(ok)
        assert ok.sum() >= n // 4, "too few valid configurations to test"
        assert np.all(np.isfinite(np.asarray(vals)))
        for leaf in jax.tree.leaves(eqx.filter(jac_m, eqx.is_array)) + [jac_q]:
            leaf = np.asarray(leaf)
            assert np.all(np.isfinite(leaf[ok])), "NaN/inf gradient on an assembled configuration"
            assert np.all(np.isfinite(leaf)), "NaN/inf gradient where assembly fails"


# ----------------------------------------------------------------------------- through the simulation (diffrax)

SIM = dict(solver="tsit5", rtol=1e-10, atol=1e-10, max_steps=1024)


def _directional_fd(f, theta, v, h):
    d = lambda s: (f(theta + s * v) - f(theta - s * v)) / (2 * s)  # noqa: E731
    return (4 * d(h / 2) - d(h)) / 3


@pytest.fixture(scope="module")
def watt_flat(watt):
    theta, unflatten = syn.flatten_parameters(watt, select=lambda s: (s.mechanism, s.gravity))
    v = jax.random.normal(jax.random.key(0), theta.shape)
    return theta, unflatten, v / jnp.linalg.norm(v)


@pytest.mark.slow  # forward mode through diffrax: minutes of compilation on a busy 2-core machine
def test_final_angle_directional_derivative_forward_mode(watt_flat):
    """theta(T) of the falling Watt six-bar: jvp through diffrax (ForwardMode) along a random
    direction in the space of all 50 scene parameters equals the central difference."""
    theta, unflatten, v = watt_flat
    f = lambda th: syn.final_state(unflatten(th), 0.3, adjoint="forward", **SIM)[0]  # noqa: E731
    jvp = jax.jit(lambda th: jax.jvp(f, (th,), (v,))[1])(theta)
    fd = _directional_fd(jax.jit(f), theta, v, 1e-4)
    assert abs(jvp - fd) <= RTOL * abs(fd), (float(jvp), float(fd))


@pytest.mark.slow  # reverse mode through diffrax: minutes of compilation on a busy 2-core machine
def test_final_angle_gradient_reverse_mode_every_parameter(watt_flat):
    theta, unflatten, v = watt_flat
    f = jax.jit(lambda th: syn.final_state(unflatten(th), 0.3, **SIM)[0])
    grad = jax.jit(jax.grad(lambda th: syn.final_state(unflatten(th), 0.3, **SIM)[0]))(theta)
    fd = central_difference(f, theta, 1e-4)
    assert_close_jacobian(grad, fd)


@pytest.mark.slow  # the standstill event: minutes of compilation on a busy 2-core machine
def test_standstill_time_gradient(watt_flat):
    """Seed 000's standstill time: the implicit-function derivative, forward and reverse, vs central differences."""
    theta, unflatten, v = watt_flat
    t_stop = lambda th, adj="recursive": syn.standstill_time(unflatten(th), t1=2.0, adjoint=adj, **SIM)  # noqa: E731
    value, ok = jax.jit(t_stop)(theta)
    assert bool(ok) and 1.0 < float(value) < 2.0
    fd = _directional_fd(jax.jit(lambda th: t_stop(th)[0]), theta, v, 1e-4)
    jvp = jax.jit(lambda th: jax.jvp(lambda t: t_stop(t, "forward")[0], (th,), (v,))[1])(theta)
    grad = jax.jit(jax.grad(lambda th: t_stop(th)[0]))(theta)
    assert abs(jvp - fd) <= RTOL * abs(fd)
    assert abs(jnp.dot(grad, v) - fd) <= RTOL * abs(fd)


# ----------------------------------------------------------------------------- forward sensitivities (no AD through diffrax)

QUAD = dict(solver="tsit5", rtol=1e-10, atol=1e-10, max_steps=1024)


@pytest.mark.slow  # ~35 s of compilation; test_synthesis.py checks the quadrature route against differences (standstill objective)
def test_final_angle_gradient_quadrature_every_parameter(watt_flat):
    """theta(T) of the falling Watt six-bar: the sensitivity gradient (variation of constants, one
    batched reverse pass at Gauss nodes) w.r.t. all 50 scene parameters equals the central
    difference of the simulation itself, and so does the derivative w.r.t. the start angle."""
    theta, unflatten, v = watt_flat
    f = jax.jit(lambda th: syn.final_state(unflatten(th), 0.3, **QUAD)[0])
    grad = jax.jit(jax.grad(lambda th: syn.final_state(unflatten(th), 0.3, adjoint="quadrature", **QUAD)[0]))(theta)
    assert_close_jacobian(grad, central_difference(f, theta, 1e-4))


@pytest.mark.slow  # ~40 s of compilation; the fast synthesis test checks the same route on two parameters
def test_standstill_time_gradient_quadrature(watt_flat):
    """The standstill time through the event: implicit-function derivative with the forward
    sensitivities at t*, along a random direction of all 50 parameters, vs central differences
    of the event time located by the simulation."""
    theta, unflatten, v = watt_flat
    t_stop = lambda th, adj: syn.standstill_time(unflatten(th), t1=2.0, adjoint=adj, **QUAD)  # noqa: E731
    value_of = jax.jit(lambda th: t_stop(th, "quadrature"))
    value, ok = value_of(theta)
    assert bool(ok) and 1.0 < float(value) < 2.0
    fd = _directional_fd(lambda th: value_of(th)[0], theta, v, 1e-4)
    grad = jax.jit(jax.grad(lambda th: t_stop(th, "quadrature")[0]))(theta)
    assert abs(jnp.dot(grad, v) - fd) <= RTOL * abs(fd), (float(jnp.dot(grad, v)), float(fd))


@pytest.mark.slow  # the "loop" method, jacfwd and the start angle: several compilations
def test_sensitivity_routes_agree_with_finite_differences(watt, watt_flat):
    """The "loop" forward sensitivities (S integrated with the state): gradient over every parameter
    and jacfwd of (q, w)(T) w.r.t. the initial state and T, vs central differences."""
    theta, unflatten, v = watt_flat
    f = jax.jit(lambda th: syn.final_state(unflatten(th), 0.3, **QUAD)[0])
    grad = jax.jit(jax.grad(lambda th: syn.final_state(unflatten(th), 0.3, adjoint="sensitivity", **QUAD)[0]))(theta)
    assert_close_jacobian(grad, central_difference(f, theta, 1e-4))
    x = jnp.array([0.1, 0.5, 0.3])  # q0, omega0, T

    def state(x, adj):
        return jnp.stack(syn.final_state(watt, x[2], q0=x[0], omega0=x[1], adjoint=adj, **QUAD))

    fd = central_difference(jax.jit(lambda x: state(x, "recursive")), x, 1e-4)
    for adj in ("sensitivity", "quadrature"):
        assert_close_jacobian(jax.jit(jax.jacfwd(lambda x: state(x, adj)))(x), fd)


def test_sensitivity_routes_reject_bad_input(watt):
    """Clear errors, before any tracing, for settings the sensitivity routes do not have."""
    with pytest.raises(assurjax.AssurjaxError, match="samples"):
        syn.final_state(watt, 0.5, adjoint="quadrature", samples=3)
    with pytest.raises(assurjax.AssurjaxError, match="method"):
        syn.final_state_sensitivity(watt, 0.5, method="euler")
    with pytest.raises(assurjax.AssurjaxError, match="panels"):
        syn.standstill_time(watt, adjoint="quadrature", panels=0)
    with pytest.raises(assurjax.AssurjaxError, match="link9"):
        syn.add_point_mass(watt.mechanism, "link9", 1.0, (0.0, 0.0))
    with pytest.raises(assurjax.AssurjaxError, match="target"):
        syn.standstill_time_problem(watt, -1.0)


@pytest.mark.slow  # a forward-mode compile through diffrax (~12 s): the default suite stays under 10 min
def test_forward_mode_through_the_default_adjoint():
    """jax.jvp / jax.jacfwd of final_state with the default adjoint (reverse-mode
    "recursive") raised JAX's "can't apply forward-mode autodiff (jvp) to a custom_vjp
    function"; it runs as adjoint="forward" there, against central differences in gravity.
    Forward over reverse (jax.hessian) neither adjoint takes: refused by name, before any run."""
    slider = assurjax.load_scene("slider_crank")
    g, v = jnp.asarray(slider.gravity, dtype=float), jnp.array([1.0, 0.5])
    f = lambda g: syn.final_state(eqx.tree_at(lambda s: s.gravity, slider, g), 0.3, **SIM)[0]  # noqa: E731
    jvp = jax.jvp(f, (g,), (v,))[1]
    fd = _directional_fd(jax.jit(f), g, v, 1e-3)
    assert abs(jvp - fd) <= RTOL * abs(fd), (float(jvp), float(fd))
    with pytest.raises(assurjax.AssurjaxError, match="final_state: forward-mode derivatives of reverse-mode ones"):
        jax.hessian(f)(g)
    with pytest.raises(assurjax.AssurjaxError, match="backsolve.*reverse mode only"):
        jax.jvp(lambda g: syn.final_state(eqx.tree_at(lambda s: s.gravity, slider, g), 0.3, adjoint="backsolve")[0],
                (g,), (v,))


@pytest.mark.slow
def test_backsolve_adjoint_matches_the_recursive_one():
    """adjoint='backsolve' (diffrax's BacksolveAdjoint) against the recursive checkpointed
    adjoint on the Watt six-bar with a spring, and without any load (its empty loads tuple
    once failed inside diffrax's backward solve; see docs/design-notes.md)."""
    scene = assurjax.load_scene("watt_sixbar")

    def theta(g, adjoint, loads):
        s = assurjax.Scene(mechanism=scene.mechanism, gravity=jnp.stack([0.0, g]), loads=loads, state=scene.state,
                           simulation=scene.simulation, outputs=scene.outputs, name=scene.name)
        return assurjax.synthesis.final_state(s, 0.5, adjoint=adjoint)[0]

    for loads in ((assurjax.Spring("A", "E", 10.0, 0.2),), ()):
        back = jax.grad(theta)(-9.81, "backsolve", loads)
        recursive = jax.grad(theta)(-9.81, "recursive", loads)
        np.testing.assert_allclose(back, recursive, rtol=1e-6)


def test_final_state_past_a_lock_up_is_no_result():
    """A slider-crank whose rod (0.05 m) is shorter than its crank (0.1 m) locks up within
    0.5 s (simulate stops there). final_state, which does not stop at a lock-up, returned
    the pose it integrated on to, where the mechanism does not assemble, with a finite
    derivative; now it says so, and under jit the result is NaN."""
    scene = assurjax.load_scene("slider_crank")
    short = eqx.tree_at(lambda s: s.mechanism.links["rod"].points["B"], scene, jnp.array([0.05, 0.0]))
    assert assurjax.simulate(short, t1=0.5).status.startswith("group 'rod_slider' can no longer assemble")
    with pytest.raises(assurjax.AssurjaxError, match="final_state: the motion did not end as asked: the mechanism does "
                                                     "not assemble where the motion ended: it passed a lock-up"):
        syn.final_state(short, 0.5)
    q, w = jax.jit(lambda m: syn.final_state(short.replace_mechanism(m), 0.5))(short.mechanism)
    assert np.isnan(q) and np.isnan(w)
    q, w = syn.final_state(scene, 0.5)  # the bundled one runs on: a finite result, and it assembles there
    assert np.isfinite(q) and np.asarray(assurjax.positions(scene.mechanism, q).ok).all()


@pytest.mark.slow  # a reverse-mode compile through the standstill event (~10 s)
def test_standstill_time_without_a_standstill_has_t1s_derivative():
    """No standstill before t1: t* = t1, ok False, and d t*/d q0 = 0 (central differences);
    the implicit-function term was applied there too and gave 1.35. jax.grad with
    adjoint='forward' is refused by name (it raised JAX's while_loop error)."""
    slider = assurjax.load_scene("slider_crank")
    f = lambda q0: syn.standstill_time(slider, q0=q0, omega0=5.0, t1=0.1)  # noqa: E731
    t_star, ok = f(1.0)
    assert float(t_star) == 0.1 and not bool(ok)
    fd = (f(1.0 + 1e-4)[0] - f(1.0 - 1e-4)[0]) / 2e-4
    assert float(fd) == 0.0
    assert float(jax.grad(lambda q0: f(q0)[0])(1.0)) == 0.0
    with pytest.raises(assurjax.AssurjaxError, match="standstill_time: adjoint='forward'.*jax.grad use 'recursive'"):
        jax.grad(lambda q0: syn.standstill_time(slider, q0=q0, omega0=5.0, t1=0.1, adjoint="forward")[0])(1.0)


@pytest.mark.slow  # ~10 s; final_state past a lock-up stays in the default suite
def test_standstill_time_past_a_lock_up_is_no_result():
    """The sensitivity routes integrate through a lock-up (no assembly checks): an offset
    slider-crank that locks up at 0.31 s (simulate stops there) came to a 'standstill' at
    0.77 s, ok True, in a pose that does not assemble. Now refused as simulate's route
    refuses it; the public standstill_time_sensitivity gives NaN and ok False."""
    scene = assurjax.load_scene("slider_crank")
    offset = next(i for i, g in enumerate(scene.mechanism.groups) if g.name == "rod_slider")
    locking = eqx.tree_at(lambda s: s.mechanism.groups[offset].offset, scene, jnp.asarray(0.25))
    sol = assurjax.simulate(locking, t1=2.0, stop=None)
    assert sol.status.startswith("group 'rod_slider' can no longer assemble")
    for adjoint in ("recursive", "quadrature", "sensitivity"):
        with pytest.raises(assurjax.AssurjaxError, match="standstill_time: the motion did not end as asked"):
            syn.standstill_time(locking, t1=2.0, adjoint=adjoint)
    t_star, ok, _ = syn.standstill_time_sensitivity(locking, t1=2.0)
    assert np.isnan(t_star) and not ok
    t_star, ok = syn.standstill_time(scene, t1=2.0, adjoint="quadrature")  # the bundled one: no lock-up
    assert ok and np.isfinite(t_star)
    assert np.asarray(assurjax.positions(scene.mechanism, syn.final_state(scene, t_star)[0]).ok).all()


@pytest.mark.slow  # ~25 s: two-turn slider-cranks differentiated at several panel counts
def test_quadrature_that_does_not_resolve_the_motion_gives_nan_not_a_wrong_derivative():
    """The slider-crank driven by c = 0.905 N m over two turns (0.7 s): the quadrature's default
    16 panels gave d(q, w)/dc = (30.0, +1936) against (19.38, -44.48) by central differences
    (a panel's polynomial did not resolve a_q at all), and 64 panels erred by 1.7e-2: NaN now
    (the estimated error, S with A one degree lower, past 1e-3), a loud failure. With 256
    panels it resolves and agrees with the differences."""
    scene = assurjax.load_scene("slider_crank")

    def state(c, **kw):
        return jnp.stack(syn.final_state(scene.with_loads(scene.loads + (assurjax.Drive(c),)), 0.7, q0=0.5, omega0=1.0, **kw))

    c, h = 0.905, 1e-5
    fd = (state(c + h, rtol=1e-12, atol=1e-12, max_steps=100_000) - state(c - h, rtol=1e-12, atol=1e-12, max_steps=100_000)) / (2 * h)
    assert np.all(np.isnan(np.asarray(jax.jacfwd(lambda c: state(c, adjoint="quadrature"))(c))))
    assert np.all(np.isnan(np.asarray(jax.jacfwd(lambda c: state(c, adjoint="quadrature", panels=64))(c))))
    fine = np.asarray(jax.jacfwd(lambda c: state(c, adjoint="quadrature", panels=256))(c))
    np.testing.assert_allclose(fine, fd, rtol=1e-4)


@pytest.mark.slow  # three compilations of the sensitivity routes (~20 s): the default suite stays under 10 min
def test_quadrature_with_fixed_steps_and_a_run_short_of_t1():
    """With a fixed step (dt) the quadrature's transition solve got the PID controller's place
    taken by constant steps and no dt0 (diffrax's ValueError): it takes the simulation's dt
    now, and agrees with the "sensitivity" route at that dt. A run that ends short of t1 (its
    step budget spent) is NaN under jit with derivative 0: the route saves the states at its
    nodes, which such a run does not reach."""
    scene = assurjax.load_scene("slider_crank")

    def value_and_derivative(adjoint, **kw):
        return jax.value_and_grad(lambda q0: syn.final_state(scene, 0.3, q0=q0, adjoint=adjoint, **kw)[0])(0.5)

    quadrature, sensitivity = (float(value_and_derivative(a, dt=1e-3)[1]) for a in ("quadrature", "sensitivity"))
    assert abs(quadrature - sensitivity) <= RTOL * abs(sensitivity), (quadrature, sensitivity)
    value, derivative = value_and_derivative("quadrature", max_steps=3)
    assert np.isnan(value) and derivative == 0.0
