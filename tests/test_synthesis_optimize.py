"""The compiled synthesis loop: any optax method, continuation, multi-start, compiled once.

The optimum is checked against scipy's SLSQP on the epigraph (minimax) form of the same
problem, evaluated with numpy geometry only; gradients against central differences; "compiled
once" by counting traces (a Python side effect runs only while JAX traces).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from scipy.optimize import brentq, minimize

import assurjax
from assurjax import AssurjaxError
from assurjax import synthesis as syn
from test_synthesis import Q0, TRACES, roberts_point

STROKE = 0.2


# ----------------------------------------------------------------------------- numpy reference


def numpy_path(lengths, centre, stroke=STROKE, n=41):
    """y of the Roberts-type coupler point at n evenly spaced x over the stroke, on the branch
    through the symmetric crank angle (bracketed on a grid, refined by brentq)."""
    qs = Q0 + np.linspace(-1.2, 1.2, 481)
    with np.errstate(invalid="ignore"):
        xs = np.array([roberts_point(lengths, q)[0] for q in qs])
    i0 = len(qs) // 2
    lo = hi = i0
    sign = np.sign(xs[i0 + 1] - xs[i0])
    while lo > 0 and np.isfinite(xs[lo - 1]) and np.sign(xs[lo] - xs[lo - 1]) == sign:
        lo -= 1
    while hi < len(qs) - 1 and np.isfinite(xs[hi + 1]) and np.sign(xs[hi + 1] - xs[hi]) == sign:
        hi += 1
    targets = centre + np.linspace(-0.5, 0.5, n) * stroke
    ys = []
    for t in targets:
        j = next(k for k in range(lo, hi) if min(xs[k], xs[k + 1]) <= t <= max(xs[k], xs[k + 1]))
        q = brentq(lambda q: roberts_point(lengths, q)[0] - t, qs[j], qs[j + 1], xtol=1e-15, rtol=1e-15)
        ys.append(roberts_point(lengths, q)[1])
    return targets, np.array(ys)


def distances(x, y, y0, angle):
    return (y - y0) * np.cos(angle) - x * np.sin(angle)


# ----------------------------------------------------------------------------- the optimum vs SLSQP


@pytest.fixture(scope="module")
def coupler_point_problem():
    """Four-bar straight-line synthesis: the coupler point (BP, CP) and the line's pose (y0, angle)
    free, minimizing the largest distance of 41 samples over 200 mm of x from the line."""
    lengths = np.asarray(syn.roberts_lengths()) * np.array([1.0, 1.0, 1.0, 1.0, 1.04, 0.97])
    design, objective = syn.straight_line_problem(lengths, stroke=STROKE, line=0.0, frame="free",
                                                  fixed=("AD", "AB", "DC", "BC", "centre"))
    return lengths, design, objective


@pytest.mark.slow  # ~10 s; the objectives' gradients and the stopping rules stay in the default suite
def test_optimum_matches_slsqp_on_the_epigraph_form(coupler_point_problem):
    lengths, design, objective = coupler_point_problem
    centre = float(design.start()[1])
    result = syn.optimize(design, objective, optax.lbfgs, 300, has_aux=True, rtol=1e-10, patience=20, restarts=3,
                          schedule={"sharpness": [50.0, 500.0, 5e3, 5e4]})
    found_lengths, _, pose = (np.asarray(v) for v in result.values)
    x, y = numpy_path(found_lengths, centre)
    ours = np.max(np.abs(distances(x, y, *pose)))

    def path(v):
        return numpy_path(np.concatenate([lengths[:4], v[:2]]), centre)

    # epigraph: minimize t subject to -t <= r_i(v) <= t
    def constraints(v):
        x, y = path(v)
        r = distances(x, y, v[2], v[3])
        return np.concatenate([v[4] - r, v[4] + r])

    start = np.array([lengths[4], lengths[5], 0.0, 0.0, 0.01])
    ref = minimize(lambda v: v[4], start, jac=lambda v: np.eye(5)[4], method="SLSQP",
                   constraints=[{"type": "ineq", "fun": constraints}], options={"ftol": 1e-14, "maxiter": 200})
    assert ref.success, ref.message
    start_dev = np.max(np.abs(distances(*numpy_path(lengths, centre), 0.0, 0.0)))
    assert ours < 0.5 * start_dev  # the run did move
    assert abs(ours - ref.fun) < 1e-6, f"optimize {ours * 1e3:.5f} mm, SLSQP {ref.fun * 1e3:.5f} mm"


# ----------------------------------------------------------------------------- gradients vs differences


def _central(f, x, h):
    x = np.asarray(x, float)
    out = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = h
        out.append((f(x + e) - f(x - e)) / (2 * h))
    return np.array(out)


def _roberts(v):
    return syn.roberts_like(jnp.asarray(v))


LENGTHS = np.asarray(syn.roberts_lengths()) * np.array([1.05, 0.95, 1.08, 0.93, 1.02, 0.97])


@pytest.mark.parametrize("case", ["best line by x", pytest.param("given line by x", marks=pytest.mark.slow),
                                  pytest.param("best line by angle", marks=pytest.mark.slow)])
def test_straight_line_gradients_match_differences(case):
    kw = {"best line by x": dict(stroke=0.26), "given line by x": dict(stroke=0.2, line=((0.01, -0.002), 0.01)),
          "best line by angle": dict(stroke=0.8, drive="angle")}[case]

    def f(v):
        m = _roberts(v[:6])
        return syn.straight_line_deviation(m, "P", q0=Q0, center=v[6] if kw.get("drive") != "angle" else Q0 + v[6], **kw).smooth

    v0 = np.concatenate([LENGTHS, [0.004 if kw.get("drive") != "angle" else 0.0]])
    grad = np.asarray(jax.jit(jax.grad(f))(jnp.asarray(v0)))
    fd = _central(jax.jit(f), v0, 1e-6)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-9)
    if case == "best line by x":  # forward mode too (the coupler point at the roots has a rule of its own)
        np.testing.assert_allclose(np.asarray(jax.jit(jax.jacfwd(f))(jnp.asarray(v0))), fd, rtol=1e-5, atol=1e-9)


def test_other_objective_gradients_match_differences():
    q = jnp.linspace(0.6, 1.6, 5)
    targets = np.asarray(syn.coupler_curve(_roberts(LENGTHS), "P", q)[0]) + 0.003
    objectives = {
        "precision points": lambda v: syn.precision_point_error(_roberts(v), "P", q, targets)[0],
        "assembly margin": lambda v: jnp.sum(jax.vmap(lambda qi: syn.assembly_margin(_roberts(v), qi))(q)),
        "transmission angle": lambda v: jnp.sum(jnp.cos(jax.vmap(lambda qi: syn.transmission_angles(_roberts(v), qi)["dyad43"])(q))),
        "smooth max": lambda v: syn.smooth_max(syn.coupler_curve(_roberts(v), "P", q)[0][:, 1], 300.0),
        "inverse kinematics": lambda v: assurjax.inverse_kinematics(_roberts(v), ("P", "x"), 0.03, Q0)[0],
    }
    for name, f in objectives.items():
        grad = np.asarray(jax.jit(jax.grad(f))(jnp.asarray(LENGTHS)))
        fd = _central(jax.jit(f), LENGTHS, 1e-6)
        np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8, err_msg=name)


def test_differentiated_objectives_have_no_host_callback():
    """JAX's persistent cache does not keep programs with host callbacks (checked errors)."""
    design, objective = syn.straight_line_problem(LENGTHS)
    loss = lambda z: objective(design.values(z))[0]  # noqa: E731
    text = jax.jit(jax.value_and_grad(loss)).lower(design.init()).as_text()
    assert "callback" not in text
    ik = lambda v: assurjax.inverse_kinematics(_roberts(v), ("P", "x"), 0.03, Q0)[0]  # noqa: E731
    assert "callback" not in jax.jit(jax.grad(ik)).lower(jnp.asarray(LENGTHS)).as_text()


# ----------------------------------------------------------------------------- compiled once


def _four_bar_design(scale=1.0, relative=0.3):
    mech = syn.four_bar(ground=0.30 * scale, crank=0.10, coupler=0.25, rocker=0.22, coupler_point=(0.1, 0.05))
    return syn.Design(mech, lambda m: (m.links["link4"].points["P"], m.ground["D"]), relative=relative, absolute=0.01)


Q_PATH = jnp.linspace(0.0, 2 * np.pi, 24, endpoint=False)
GOAL = jnp.array([0.12, 0.2])


def test_new_starts_bounds_options_and_schedules_do_not_recompile():
    traces = []

    def objective(m, params):
        traces.append(1)  # runs only while JAX traces
        pts, ok = syn.coupler_curve(m, "P", Q_PATH)
        return params["weight"] * jnp.mean(jnp.sum((pts - GOAL) ** 2, -1)), {"ok": ok}

    def run(design, lr, weights, **kw):
        return syn.optimize(design, objective, optax.adam, 20, options={"learning_rate": lr}, has_aux=True,
                            schedule={"weight": weights}, **kw)

    first = run(_four_bar_design(), 0.05, [1.0, 2.0])
    after_first = len(traces)
    assert after_first > 0
    second = run(_four_bar_design(1.1, relative=0.2), 0.02, [3.0, 0.5], target=1e-9, rtol=1e-6, restarts=2)
    assert len(traces) == after_first, "a new start, bounds, options or schedule values recompiled"
    assert first.loss != second.loss
    # the same program also serves a different number of steps up to its capacity
    syn.optimize(_four_bar_design(), objective, optax.adam, 25, options={"learning_rate": 0.1}, has_aux=True,
                 schedule={"weight": [1.0, 1.0]})
    assert len(traces) == after_first


def test_a_transformation_built_again_does_not_recompile():
    """``optax.adam(0.05)`` written again (a notebook cell run twice) is a new object of new
    closures: it used to trace and compile the whole loop again. Its functions now compare
    by structure (code and closure values, item by item through optax's chain); another
    rate is another program, never a stale one."""
    from assurjax._structure import by_structure

    traces = []

    def objective(m):
        traces.append(1)  # runs only while JAX traces
        pts, ok = syn.coupler_curve(m, "P", Q_PATH)
        return jnp.mean(jnp.sum((pts - GOAL) ** 2, -1)), {"ok": ok}

    first = syn.optimize(_four_bar_design(), objective, optax.adam(0.05), 20, has_aux=True)
    after_first = len(traces)
    again = syn.optimize(_four_bar_design(), objective, optax.adam(0.05), 20, has_aux=True)
    assert len(traces) == after_first, "the same method built again recompiled"
    assert again.loss == first.loss
    same = by_structure
    assert same(optax.adam(0.05)) == same(optax.adam(0.05)) and same(optax.lbfgs()) == same(optax.lbfgs())
    assert same(optax.adam(0.05)) != same(optax.adam(0.02))
    assert same(optax.adam(0.05)) != same(optax.sgd(0.05))
    assert same(optax.adam) == same(optax.adam)

    def recursive():  # a closure that holds itself keys without recursing for ever
        def walk(n):
            return 0 if n == 0 else walk(n - 1)
        return walk

    assert by_structure(recursive()) == by_structure(recursive())


def test_inverse_kinematics_with_a_fresh_lambda_does_not_recompile():
    mech = syn.roberts_like(syn.roberts_lengths())
    for i, x in enumerate((0.01, 0.02, 0.03)):
        TRACES.counts, TRACES.active = {}, True
        try:
            q, _ = assurjax.inverse_kinematics(mech, lambda pose: pose.points["P"][0], x, Q0)
        finally:
            TRACES.active = False
        assert ("_inverse_jit" in TRACES.counts) == (i == 0), TRACES.counts  # traced while the first solve compiled
        q2, pose = assurjax.inverse_kinematics(mech, ("P", "x"), x, Q0)
        assert abs(float(q - q2)) < 1e-12 and abs(float(pose.points["P"][0]) - x) < 1e-10
    with pytest.raises(AssurjaxError, match="quantity"):
        assurjax.inverse_kinematics(mech, ("Q", "x"), 0.01, Q0)


OFFSET = 0.0  # a global the next test's lambdas read


def test_a_fresh_lambda_reading_changed_values_is_traced_anew():
    """The same lambda written again where a global it reads changed (a notebook's cell run
    after another set it) was served the program traced with the old value: P_x + 0.01
    solved to 0.02 gave P_x = 0.02, not 0.01. The globals a function names are part of its
    structure now; a NumPy array it closes over, changed in place, makes it compare by
    identity (as jax.jit), so a fresh lambda is traced anew."""
    from assurjax._structure import by_structure

    global OFFSET
    mech = syn.roberts_like(syn.roberts_lengths())
    shift = np.zeros(1)
    try:
        for offset in (0.0, 0.01):
            OFFSET = offset
            _, pose = assurjax.inverse_kinematics(mech, lambda pose: pose.points["P"][0] + OFFSET, 0.02, Q0)
            assert float(pose.points["P"][0]) == pytest.approx(0.02 - offset, abs=1e-10)
            shift[0] = offset
            _, pose = assurjax.inverse_kinematics(mech, lambda pose: pose.points["P"][0] + shift[0], 0.02, Q0)
            assert float(pose.points["P"][0]) == pytest.approx(0.02 - offset, abs=1e-10)
    finally:
        OFFSET = 0.0
    reads = lambda: lambda x: x + OFFSET  # noqa: E731
    assert by_structure(reads()) == by_structure(reads())
    before = by_structure(reads())
    OFFSET = 1.0
    try:
        assert by_structure(reads()) != before
    finally:
        OFFSET = 0.0
    closes = lambda: lambda x: x + shift[0]  # noqa: E731
    assert by_structure(closes()) != by_structure(closes())  # an array that can change in place: by identity
    fn = closes()
    assert by_structure(fn) == by_structure(fn)


# ----------------------------------------------------------------------------- methods, starts, variables


def _path_objective(m):
    pts, ok = syn.coupler_curve(m, "P", Q_PATH)
    return jnp.mean(jnp.sum((pts - GOAL) ** 2, -1)), {"ok": ok}


@pytest.mark.parametrize("method,options", [
    (optax.lbfgs, {}),
    (optax.chain(optax.sgd(20.0), optax.scale_by_backtracking_linesearch(max_backtracking_steps=15, store_grad=True)), None),
])
def test_line_search_methods_run_and_count_their_evaluations(method, options):
    design = _four_bar_design()
    result = syn.optimize(design, _path_objective, method, 30, options=options, has_aux=True)
    h = result.history
    assert np.all(np.diff(h.loss) <= 0) and h.loss[-1] < h.loss[0]  # a line search never goes uphill
    assert np.all(np.diff(h.evaluations) >= 1) and result.evaluations >= h.evaluations[-1]
    assert result.evaluations > len(h.loss)  # the line search's trial points are counted too


def test_compile_modes_agree_and_auto_compiles_one_line_search_start_quickly(monkeypatch):
    from assurjax.synthesis import _optimize

    used = []
    for mode, run in list(_optimize._RUN.items()):
        monkeypatch.setitem(_optimize._RUN, mode, lambda *args, _run=run, _mode=mode: used.append(_mode) or _run(*args))
    design = _four_bar_design()
    auto = syn.optimize(design, _path_objective, optax.lbfgs, 30, has_aux=True)
    optimized = syn.optimize(design, _path_objective, optax.lbfgs, 30, has_aux=True, compile_mode="optimized")
    syn.optimize(design, _path_objective, optax.adam, 5, options={"learning_rate": 0.01}, has_aux=True)
    assert used == ["quick", "optimized", "optimized"]  # Adam's program is small: its code is optimized
    # the two programs compute the same run (the machine code differs, not the method)
    np.testing.assert_allclose(auto.history.loss, optimized.history.loss, rtol=1e-9)
    np.testing.assert_array_equal(auto.history.evaluations, optimized.history.evaluations)
    with pytest.raises(AssurjaxError, match="compile_mode"):
        syn.optimize(design, _path_objective, optax.lbfgs, 30, has_aux=True, compile_mode="fast")


@jax.custom_vjp
def _reverse_only(x):
    return x


_reverse_only.defvjp(lambda x: (x, None), lambda _, g: (g,))


def test_gradient_modes_agree_and_auto_takes_reverse_mode_where_the_objective_needs_it(monkeypatch):
    """The gradient by forward mode (one tangent per design variable) and by reverse mode: the
    same run to round-off. "auto" takes forward mode for a few variables of a design with joint
    friction, reverse mode otherwise; an objective that takes no forward mode (a jax.custom_vjp)
    runs by reverse mode under "auto", and is a clear error where forward mode was asked for."""
    from assurjax.synthesis import _optimize

    design = _four_bar_design()  # 4 variables, no friction
    run = functools.partial(syn.optimize, design, optimizer=optax.adam, steps=5, options={"learning_rate": 0.01}, has_aux=True)
    forward, reverse = run(_path_objective, gradient="forward"), run(_path_objective, gradient="reverse")
    np.testing.assert_allclose(forward.history.loss, reverse.history.loss, rtol=1e-12)
    for f, r in zip(jax.tree.leaves(forward.history.grad), jax.tree.leaves(reverse.history.grad)):
        np.testing.assert_allclose(f, r, rtol=1e-9, atol=1e-14)
    np.testing.assert_array_equal(run(_path_objective).history.loss, reverse.history.loss)  # auto, no friction: reverse
    assert _optimize._holds_friction(assurjax.load_scene("press_with_friction"))
    assert not _optimize._holds_friction(assurjax.load_scene("watt_sixbar"))

    def reverse_only(m):
        loss, aux = _path_objective(m)
        return _reverse_only(loss), aux

    monkeypatch.setattr(_optimize, "_holds_friction", lambda *trees: True)  # "auto" as for a design with friction
    for f, r in zip(jax.tree.leaves(run(_path_objective).history.grad), jax.tree.leaves(forward.history.grad)):
        np.testing.assert_array_equal(f, r)
    np.testing.assert_array_equal(run(reverse_only).history.loss, reverse.history.loss)
    with pytest.raises(AssurjaxError, match="gradient='forward', but the objective takes reverse-mode derivatives only"):
        run(reverse_only, gradient="forward")
    with pytest.raises(AssurjaxError, match="gradient must be 'auto', 'forward' or 'reverse'"):
        run(_path_objective, gradient="backward")


def test_tolerance_stops_and_multistart_keeps_every_start():
    design = _four_bar_design()
    lo, hi = (np.asarray(b[0]) for b in (design.lower, design.upper))
    starts = (jnp.asarray(lo + (hi - lo) * np.array([[0.3, 0.6], [0.5, 0.5], [0.7, 0.2]])),
              jnp.tile(design.start()[1], (3, 1)))
    result = syn.optimize(design, _path_objective, optax.lbfgs, 200, has_aux=True, gtol=1e-10, starts=starts)
    assert result.starts.loss.shape == (3,) and len(result.starts.status) == 3
    assert result.loss == result.starts.loss.min()
    np.testing.assert_allclose(np.asarray(result.starts.initial[0]), np.asarray(starts[0]))
    assert result.status == "converged" and result.history.grad_norm[-1] <= 1e-10
    # the values reported (computed inside the compiled run) are the design's values at the reported z
    best = int(np.argmin(result.starts.loss))
    for got, start, expected, in_mechanism in zip(result.values, result.starts.values, design.values(result.z),
                                                 design.select(result.mechanism)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(expected), rtol=1e-14)
        np.testing.assert_allclose(np.asarray(start[best]), np.asarray(expected), rtol=1e-14)
        np.testing.assert_allclose(np.asarray(in_mechanism), np.asarray(expected), rtol=1e-14)
    for batch in ("vmap", "sequential"):
        again = syn.optimize(design, _path_objective, optax.adam, 50, options={"learning_rate": 0.01}, has_aux=True,
                             starts=starts, batch=batch)
        assert again.starts.loss.shape == (3,)
    drawn = syn.optimize(design, _path_objective, optax.adam, 50, options={"learning_rate": 0.01}, has_aux=True, starts=3, seed=1)
    first = np.asarray(drawn.starts.initial[0])
    np.testing.assert_allclose(first[0], np.asarray(design.start()[0]))  # the design's own start comes first
    assert np.all((first > lo) & (first < hi)) and len(np.unique(first[:, 0])) == 3


def test_fixed_variables_and_absolute_bounds():
    mech = syn.four_bar(ground=0.30, crank=0.10, coupler=0.25, rocker=0.22, coupler_point=(0.1, 0.05))
    design = syn.Design(mech, lambda m: (m.links["link4"].points["P"], m.ground["D"]),
                        lower=(jnp.array([0.0, 0.0]), jnp.array([0.25, -0.05])), upper=(jnp.array([0.2, 0.1]), jnp.array([0.35, 0.05])),
                        fixed=(jnp.array([False, True]), False))
    result = syn.optimize(design, _path_objective, optax.lbfgs, 40, has_aux=True)
    p, d = (np.asarray(v) for v in result.values)
    assert p[1] == 0.05  # fixed
    assert 0.0 < p[0] < 0.2 and np.all(d > [0.25, -0.05]) and np.all(d < [0.35, 0.05])
    assert np.all(result.history.grad[0][:, 1] == 0)


def test_bad_options_are_reported():
    design = _four_bar_design()
    with pytest.raises(AssurjaxError, match="schedule"):
        syn.optimize(design, _path_objective, optax.adam, 5, options={"learning_rate": 0.1}, has_aux=True,
                     schedule={"a": [1.0, 2.0], "b": [1.0]})
    with pytest.raises(AssurjaxError, match="factory"):
        syn.optimize(design, _path_objective, optax.adam, 5, options={"learning_rat": 0.1}, has_aux=True)
    with pytest.raises(AssurjaxError, match="options go with"):
        syn.optimize(design, _path_objective, optax.adam(0.1), 5, options={"learning_rate": 0.1}, has_aux=True)
    with pytest.raises(AssurjaxError, match="fixed length"):
        syn.straight_line_problem(LENGTHS, fixed=("XY",))
    assert math.isfinite(syn.optimize(design, _path_objective, optax.adam(0.1), 3, has_aux=True).loss)


def test_optimize_requests_and_starts_are_checked_by_name():
    # starts outside the bounds were clipped to them (where the sigmoid is flat: they never moved),
    # NaN starts ended 'infeasible'; 10**9 steps allocated their history up front
    design, objective = syn.straight_line_problem(LENGTHS)
    x0 = design.start()
    outside = jax.tree.map(lambda x, lo: jnp.stack([x, jnp.where(jnp.isfinite(lo), lo - 1.0, jnp.nan)]), x0, design.lower)
    with pytest.raises(AssurjaxError, match="optimize: starts\\[1\\]: selected parameter"):
        syn.optimize(design, objective, optax.adam, 10, starts=outside, has_aux=True, options={"learning_rate": 1e-3})
    with pytest.raises(AssurjaxError, match="optimize: steps must be an integer from 0 to 1,000,000, got 1000000000"):
        syn.optimize(design, objective, optax.adam, 10**9, has_aux=True, options={"learning_rate": 1e-3})
    with pytest.raises(AssurjaxError, match="optimize: steps must be an integer"):
        syn.optimize(design, objective, optax.adam, 2.5, has_aux=True, options={"learning_rate": 1e-3})
    with pytest.raises(AssurjaxError, match="optimize: starts must be from 1 to 10,000"):
        syn.optimize(design, objective, optax.adam, 10, starts=10**8, has_aux=True, options={"learning_rate": 1e-3})
    # each within its bound, together a history of 781 GiB allocated up front (a raw out-of-memory error)
    with pytest.raises(AssurjaxError, match="optimize: 10000 starts x 1 stages x 1,000,000 steps \\(1,048,576 history rows a stage\\) of .* GiB"):
        syn.optimize(design, objective, optax.adam, 10**6, starts=10**4, has_aux=True, options={"learning_rate": 1e-3})
    # a NaN learning rate or schedule stage ran to 'infeasible' or 'cannot assemble'; a vector loss failed in JAX's words
    with pytest.raises(AssurjaxError, match="optimize: option 'learning_rate' must be finite"):
        syn.optimize(design, objective, optax.adam, 10, has_aux=True, options={"learning_rate": float("nan")})
    for rate in (-1, 0):  # an integer passed unchecked: -1 ran uphill and ended 'steps'
        with pytest.raises(AssurjaxError, match="optimize: option 'learning_rate' must be positive"):
            syn.optimize(design, objective, optax.adam, 10, has_aux=True, options={"learning_rate": rate})
    with pytest.raises(AssurjaxError, match="optimize: schedule 'sharpness' must be finite"):
        syn.optimize(design, objective, optax.adam, 10, has_aux=True, options={"learning_rate": 1e-3},
                     schedule={"sharpness": [50.0, float("nan")]})
    with pytest.raises(AssurjaxError, match="optimize: the objective must return one number"):
        syn.optimize(design, lambda m: (jnp.zeros(2), {}), optax.adam, 10, has_aux=True, options={"learning_rate": 1e-3})


@pytest.mark.parametrize("option, message", [
    (dict(patience=-3), "optimize: patience must be an integer from 0"),
    (dict(restarts=-1), "optimize: restarts must be an integer from 0"),
    (dict(rtol=np.nan), "optimize: rtol must be finite"),
    (dict(target=np.nan), "optimize: target must be finite"),
])
def test_optimize_settings_are_checked_by_name(option, message):
    design, objective = syn.straight_line_problem(LENGTHS)
    with pytest.raises(AssurjaxError, match=message):
        syn.optimize(design, objective, optax.adam, 10, has_aux=True, options={"learning_rate": 1e-3}, **option)


def test_standstill_problem_horizon_and_link_are_checked():
    # a horizon before the target could only end 'infeasible', reported as "cannot assemble"
    scene = assurjax.load_scene("watt_sixbar")
    with pytest.raises(AssurjaxError, match="standstill_time_problem: t1 = 1.0 s must lie past the target 1.6 s"):
        syn.standstill_time_problem(scene, 1.6, t1=1.0)
    with pytest.raises(AssurjaxError, match="standstill_time_problem: unknown link 'zz'"):
        syn.standstill_time_problem(scene, 1.6, link="zz")
