"""Gradient-based synthesis: any optax method over a :class:`Design`, in one compiled loop.

The whole run -- every step, line search, backtracking, restart, continuation stage and
start -- is one program compiled with :func:`assurjax.jit`. Everything numeric (start values,
bounds, options such as the learning rate, target and tolerances, the continuation schedule's
values, the number of steps) is an argument of that program, so a new call with the same
objective, design structure and method runs without recompiling.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import optax

from .._errors import AssemblyError, AssurjaxError
from .._jit import QUICK_OPTIONS, jit
from .._mechanism import Mechanism
from .._structure import by_structure
from .._values import all_finite, check_value, check_values
from ._design import Design, check_inside

MAX_STEPS = 1_000_000  # optimizer steps per call: the history is allocated for them up front
MAX_STARTS = 10_000  # starting designs per call

STATUSES = ("steps", "target", "converged", "infeasible")
_STEPS, _TARGET, _CONVERGED, _INFEASIBLE, _RUNNING = 0, 1, 2, 3, -1


class History(eqx.Module):
    """One entry per accepted step (entry 0 of each stage: its starting design).

    ``loss``: objective value; ``grad_norm``: 2-norm of the gradient with respect
    to the unconstrained variables; ``time``: wall time since the start of the call
    (s, compilation included), apportioned to the steps by their evaluations (the
    loop runs compiled, without calling back to Python); ``evaluations``:
    cumulative objective evaluations (each with its gradient: the accepted points,
    the designs tried by backtracking, and the line search's trial points);
    ``backtracks``: step halvings needed to stay assemblable; ``stage``: the
    continuation stage of the entry; ``aux``: the objective's auxiliary output per
    step (when it has one); ``grad``: the gradient with respect to the
    unconstrained variables per step (a pytree like ``z``, each leaf stacked over
    steps); ``z``: the unconstrained variables per step.
    """

    loss: np.ndarray
    grad_norm: np.ndarray
    time: np.ndarray
    evaluations: np.ndarray
    backtracks: np.ndarray
    aux: Any = None
    grad: Any = None
    stage: np.ndarray | None = None
    z: Any = None


class StartResults(eqx.Module):
    """Every start of a multi-start :func:`optimize` (leading axis: the start).

    ``values``/``z``: each start's best design (parameter values / unconstrained
    variables); ``loss``: its objective (last stage); ``status``: one of
    ``"steps"``, ``"target"``, ``"converged"``, ``"infeasible"`` per start;
    ``evaluations``: objective evaluations per start; ``initial``: the starting
    parameter values.
    """

    values: Any
    z: Any
    loss: np.ndarray
    status: tuple
    evaluations: np.ndarray
    initial: Any


class SynthesisResult(eqx.Module):
    """What :func:`optimize` found.

    ``mechanism``: the best design found (lowest loss among assemblable designs
    in the last continuation stage, best start); ``values``: its selected
    parameters; ``z``: its unconstrained variables; ``loss``: its objective;
    ``status``: ``"target"`` (loss reached ``target``), ``"converged"`` (gradient
    norm below ``gtol``, or the best loss improved by less than ``rtol`` over
    ``patience`` steps with no restart left), ``"steps"`` (ran out of steps) or
    ``"infeasible"`` (no assemblable step even after backtracking and restarts;
    ``message`` says more); ``evaluations``: objective evaluations used (all
    starts); ``history``: a :class:`History` of the best start; ``starts``: a
    :class:`StartResults` for every start; ``time``: wall time of the call (s,
    compilation included when there was one).
    """

    mechanism: Any
    values: Any
    z: Any
    loss: float
    status: str = eqx.field(static=True)
    message: str = eqx.field(static=True)
    evaluations: int = eqx.field(static=True)
    history: History
    starts: StartResults | None = None
    time: float = 0.0


def assembles(mechanism_or_flags) -> jax.Array:
    """True when every ``ok`` flag is True: pass a Kinematics/Pose/Reduction or a bool array."""
    ok = getattr(mechanism_or_flags, "ok", mechanism_or_flags)
    return jnp.all(ok)


def _physical(tree) -> jax.Array:
    """Whether every mechanism in ``tree`` has non-negative masses and inertias: a design
    free in them (bounds are optional) stepped a rod's mass to -1.07 kg, which the
    Mechanism's constructor refuses but a rebuilt design skips."""
    ok = jnp.array(True)
    for found in jax.tree.leaves(tree, is_leaf=lambda x: isinstance(x, Mechanism)):
        if isinstance(found, Mechanism):
            for link in found.links.values():
                ok = ok & jnp.all(link.mass >= 0) & jnp.all(link.inertia >= 0)
    return ok


# --------------------------------------------------------------------------- the compiled problem


class _Problem(eqx.Module):
    """Everything the compiled loop needs; its arrays are traced, the rest is the program's structure."""

    design: Design
    objective: Any  # a plain function (compared by structure) or an equinox Module (its arrays traced)
    feasible: Any
    method: Any = eqx.field(static=True)  # an optax factory, or a GradientTransformation
    method_static: tuple = eqx.field(static=True)  # the factory's non-numeric options
    has_aux: bool = eqx.field(static=True)
    takes_params: bool = eqx.field(static=True)
    capacity: int = eqx.field(static=True)  # history entries per stage
    forward: bool = eqx.field(static=True, default=False)  # the gradient by forward mode (see optimize's gradient)

    def optimizer(self, numeric: dict) -> optax.GradientTransformationExtraArgs:
        if isinstance(self.method, optax.GradientTransformation):
            return optax.with_extra_args_support(self.method)
        return optax.with_extra_args_support(self.method(**dict(self.method_static), **numeric))

    def loss_and_aux(self, z, params):
        """(loss, (acceptable, aux)): the loss is +inf where the design is not acceptable."""
        return _by_forward_mode(z, self, params) if self.forward else _traced_once(self, z, params)

    def _loss_and_aux(self, z, params):
        tree = self.design.build(z)
        out = self.objective(tree, params) if self.takes_params else self.objective(tree)
        loss, aux = out if self.has_aux else (out, None)
        if jnp.shape(loss) != ():  # else JAX's "Gradient only defined for scalar-output functions"
            raise AssurjaxError(f"optimize: the objective must return one number (the loss"
                                f"{', then aux' if self.has_aux else ''}), got an array of shape {jnp.shape(loss)}")
        ok = jnp.all(aux["ok"]) if isinstance(aux, dict) and "ok" in aux else jnp.array(True)
        if self.feasible is not None:
            ok = ok & jnp.all(self.feasible(tree))
        ok = ok & jnp.isfinite(loss) & _physical(tree)
        return jnp.where(ok, loss, jnp.inf), (ok, aux)

    def evaluate(self, z, params):
        """Loss, gradient (w.r.t. z), acceptability and aux at z (a non-finite gradient is not acceptable)."""
        (loss, (ok, aux)), grad = jax.value_and_grad(self.loss_and_aux, has_aux=True)(z, params)
        ok = ok & all_finite(grad)
        grad = jax.tree.map(lambda g: jnp.where(ok, g, 0.0), grad)
        return jnp.where(ok, loss, jnp.inf), grad, ok, aux

    def line_search_value(self, params):
        """The scalar function a line search evaluates (+inf and a zero gradient where not acceptable)."""
        return lambda z: self.loss_and_aux(_finite_cotangent(z), params)[0]


@eqx.filter_jit
def _traced_once(problem: _Problem, z, params):
    """The objective as one jitted function: its trace (and its derivatives' traces) are reused by
    every place that evaluates it (the shape probe, the accepted steps, a line search's trials)."""
    return problem._loss_and_aux(z, params)


@eqx.filter_custom_vjp
def _by_forward_mode(z, problem: _Problem, params):
    """The objective, whose reverse-mode derivative in ``z`` (what ``evaluate`` and a line search
    take) is computed by forward mode: one tangent per variable, side by side."""
    return _traced_once(problem, z, params)


@_by_forward_mode.def_fwd
def _by_forward_mode_fwd(perturbed, z, problem: _Problem, params):
    return _value_and_slopes(problem, z, params)


@_by_forward_mode.def_bwd
def _by_forward_mode_bwd(slopes, cotangents, perturbed, z, problem: _Problem, params):
    loss_cotangent = cotangents[0]
    unravel = jax.flatten_util.ravel_pytree(z)[1]
    grads = unravel(slopes * (0.0 if loss_cotangent is None else loss_cotangent))
    return jax.tree.map(lambda g, p: g if p else None, grads, perturbed)


@eqx.filter_jit
def _value_and_slopes(problem: _Problem, z, params):
    """((loss, rest), d loss / d z flattened), the derivative by forward mode, traced once for
    every place that takes it (as :func:`_traced_once`); the jvp is taken inside this jit, where
    the objective's own functions see it (``synthesis.final_state`` then integrates forward)."""
    flat, unravel = jax.flatten_util.ravel_pytree(z)

    def along(tangent):
        return jax.jvp(lambda x: problem._loss_and_aux(unravel(x), params), (flat,), (tangent,), has_aux=True)

    loss, slopes, rest = jax.vmap(along)(jnp.eye(flat.size, dtype=flat.dtype))
    return (loss[0], jax.tree.map(lambda x: x[0], rest)), slopes


@jax.custom_vjp
def _finite_cotangent(z):
    return z


def _finite_cotangent_fwd(z):
    return z, None


def _finite_cotangent_bwd(_, g):
    # a line search's trial point that cannot assemble has value +inf; its gradient is not used
    # but must not poison the search with NaN
    return (jax.tree.map(lambda x: jnp.where(jnp.isfinite(x), x, 0.0), g),)


_finite_cotangent.defvjp(_finite_cotangent_fwd, _finite_cotangent_bwd)


def _norm(tree) -> jax.Array:
    return jnp.sqrt(sum(jnp.sum(x**2) for x in jax.tree.leaves(tree)))


def _linesearch_evaluations(state) -> jax.Array:
    """Trial points a line search inside the optimizer evaluated in its last update (0 without one)."""
    found = optax.tree_utils.tree_get(state, "num_linesearch_steps", default=None)
    return jnp.asarray(0 if found is None else found, dtype=int)


# --------------------------------------------------------------------------- one stage


class _Loop(eqx.Module):
    z: Any
    state: Any
    update: Any  # the step to try next from z (zero at a start or restart)
    loss: jax.Array
    grad: Any
    step: jax.Array
    evaluations: jax.Array
    restarts_left: jax.Array
    best_loss: jax.Array
    best_z: Any
    since_better: jax.Array
    status: jax.Array
    history: dict


def _run_stage(problem: _Problem, options: dict, params, z0):
    """Minimize from z0 with the stage's objective parameters: returns (best z, best loss, status, evaluations, history)."""
    optimizer = problem.optimizer(options["method"])
    value_fn = problem.line_search_value(params)
    cap = problem.capacity
    shapes = jax.eval_shape(lambda z: problem.evaluate(z, params), z0)
    inf = jnp.asarray(jnp.inf, dtype=shapes[0].dtype)
    zeros = lambda s: jnp.zeros((cap,) + s.shape, s.dtype)  # noqa: E731
    history = dict(loss=jnp.full((cap,), jnp.inf), grad_norm=jnp.zeros(cap), evaluations=jnp.zeros(cap, int),
                   backtracks=jnp.zeros(cap, int), aux=jax.tree.map(zeros, shapes[3]), grad=jax.tree.map(zeros, shapes[1]),
                   z=jax.tree.map(lambda x: jnp.zeros((cap,) + jnp.shape(x)), z0))

    def tries(loop):
        """Evaluate z + 0.5^k * update for k = 0, 1, ... until acceptable or out of halvings."""

        # halving a zero step (at a start or restart) or a finished run's step (under vmap the
        # finished starts still run the loop body) would only repeat the same evaluation
        may_halve = (loop.step > 0) & (loop.status == _RUNNING) & (options["max_backtracks"] > 0)

        def cond(c):
            k, _, _, _, ok, _ = c
            return ~ok & ((k == 0) | (may_halve & (k <= options["max_backtracks"])))

        def body(c):
            k, evals, _, _, _, _ = c
            z_try = jax.tree.map(lambda a, u: a + 0.5**k * u, loop.z, loop.update)
            loss, grad, ok, aux = problem.evaluate(z_try, params)
            return k + 1, evals + 1, z_try, (loss, grad, aux), ok, k

        dummy = (inf, jax.tree.map(jnp.zeros_like, loop.z), jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes[3]))
        start = (jnp.array(0), jnp.array(0), loop.z, dummy, jnp.array(False), jnp.array(0))
        _, evals, z, (loss, grad, aux), ok, k = jax.lax.while_loop(cond, body, start)
        return z, loss, grad, aux, ok, k, evals

    def record(h, i, z, loss, grad, aux, evals, k):
        put = lambda buf, v: buf.at[i].set(v)  # noqa: E731
        return dict(loss=put(h["loss"], loss), grad_norm=put(h["grad_norm"], _norm(grad)),
                    evaluations=put(h["evaluations"], evals), backtracks=put(h["backtracks"], k),
                    aux=jax.tree.map(put, h["aux"], aux), grad=jax.tree.map(put, h["grad"], grad),
                    z=jax.tree.map(put, h["z"], z))

    def restart_or(loop, status):
        """Restart the method from the best design when restarts are left, else stop with ``status``."""
        again = loop.restarts_left > 0
        fresh = optimizer.init(loop.best_z)
        pick = lambda a, b: jax.tree.map(lambda x, y: jnp.where(again, x, y), a, b)  # noqa: E731
        zero = jax.tree.map(jnp.zeros_like, loop.z)
        return eqx.tree_at(lambda s: (s.z, s.state, s.update, s.restarts_left, s.since_better, s.status), loop,
                           (pick(loop.best_z, loop.z), pick(fresh, loop.state), pick(zero, loop.update), loop.restarts_left - again,
                            jnp.where(again, 0, loop.since_better), jnp.where(again, _RUNNING, status)))

    def body(loop: _Loop) -> _Loop:
        z, loss, grad, aux, ok, k, evals = tries(loop)
        evaluations = loop.evaluations + evals
        first = loop.step == 0

        def accepted(loop):
            better = jnp.isinf(loop.best_loss) | (loss < loop.best_loss - options["rtol"] * jnp.abs(loop.best_loss))
            history = record(loop.history, jnp.minimum(loop.step, cap - 1), z, loss, grad, aux, evaluations, k)
            new_best = loss < loop.best_loss
            updates, state = optimizer.update(grad, loop.state, z, value=loss, grad=grad, value_fn=value_fn)
            loop = _Loop(z=z, state=state, update=updates, loss=loss, grad=grad, step=loop.step + 1,
                         evaluations=evaluations + _linesearch_evaluations(state), restarts_left=loop.restarts_left,
                         best_loss=jnp.where(new_best, loss, loop.best_loss),
                         best_z=jax.tree.map(lambda a, b: jnp.where(new_best, a, b), z, loop.best_z),
                         since_better=jnp.where(better, 0, loop.since_better + 1), status=loop.status, history=history)
            stalled = (options["rtol"] > 0) & (loop.since_better >= options["patience"])
            status = jnp.where(loss <= options["target"], _TARGET,
                               jnp.where(_norm(grad) <= options["gtol"], _CONVERGED,
                                         jnp.where(loop.step > options["steps"], _STEPS, _RUNNING)))
            loop = eqx.tree_at(lambda s: s.status, loop, status)
            return jax.lax.cond(stalled & (status == _RUNNING), lambda s: restart_or(s, _CONVERGED), lambda s: s, loop)

        def rejected(loop):
            loop = eqx.tree_at(lambda s: s.evaluations, loop, evaluations)
            return jax.lax.cond(first, lambda s: eqx.tree_at(lambda t: t.status, s, jnp.array(_INFEASIBLE)),
                                lambda s: restart_or(s, _INFEASIBLE), loop)

        return jax.lax.cond(ok, accepted, rejected, loop)

    zero_z = jax.tree.map(jnp.zeros_like, z0)
    loop0 = _Loop(z=z0, state=optimizer.init(z0), update=zero_z, loss=inf, grad=zero_z, step=jnp.array(0), evaluations=jnp.array(0),
                  restarts_left=jnp.asarray(options["restarts"]), best_loss=inf, best_z=z0, since_better=jnp.array(0),
                  status=jnp.array(_RUNNING), history=history)
    last = jax.lax.while_loop(lambda s: (s.status == _RUNNING) & (s.step < cap), body, loop0)
    status = jnp.where(last.status == _RUNNING, _STEPS, last.status)
    return last.best_z, last.best_loss, status, last.evaluations, jnp.minimum(last.step, cap), last.history


def _run_one(problem: _Problem, options: dict, schedule, z0):
    """Every continuation stage from one start (a stage starts from the previous stage's best design)."""

    def stage(z, params):
        best_z, best_loss, status, evaluations, count, history = _run_stage(problem, options, params, z)
        found = jnp.isfinite(best_loss)
        next_z = jax.tree.map(lambda a, b: jnp.where(found, a, b), best_z, z)
        return next_z, (best_z, best_loss, status, evaluations, count, history)

    _, per_stage = jax.lax.scan(stage, z0, schedule)
    return per_stage


def _run(problem: _Problem, options: dict, schedule, initial, batch: str):
    """Every start (parameter values with a leading start axis): side by side (vmap) or one after
    the other (lax.map); one start alone unbatched (a vmapped loop takes seconds longer to compile).
    The maps between values and unconstrained variables run here too: done eagerly, op by op,
    they cost more than a second of small compilations on a first call."""
    design = problem.design
    one = lambda x: _run_one(problem, options, schedule, design.unconstrained(x))  # noqa: E731
    if batch == "single":
        per_stage = jax.tree.map(lambda x: x[None], one(jax.tree.map(lambda x: x[0], initial)))
    else:
        per_stage = jax.vmap(one)(initial) if batch == "vmap" else jax.lax.map(one, initial)
    final_values = jax.vmap(design.values)(jax.tree.map(lambda x: x[:, -1], per_stage[0]))
    return per_stage, final_values


_RUN = {"optimized": jit(_run), "quick": jit(_run, compiler_options=QUICK_OPTIONS)}
COMPILE_MODES = ("auto", "quick", "optimized")
GRADIENT_MODES = ("auto", "forward", "reverse")
# "auto" takes the gradient by forward mode up to this many design variables with friction (see optimize)
FORWARD_MOST = 8


# --------------------------------------------------------------------------- the public entry point


def optimize(
    design: Design,
    objective: Callable[..., Any],
    optimizer: optax.GradientTransformation | Callable[..., optax.GradientTransformation],
    steps: int,
    *,
    options: dict | None = None,
    has_aux: bool = False,
    feasible: Callable[[Any], jax.Array] | None = None,
    target: float | None = None,
    rtol: float = 0.0,
    gtol: float = 0.0,
    patience: int = 10,
    restarts: int = 0,
    max_backtracks: int = 10,
    schedule: dict | None = None,
    starts: Any = None,
    batch: str = "auto",
    seed: int = 0,
    progress: bool | None = None,
    callback: Callable[[int, float, Any], None] | None = None,
    compile_mode: str = "auto",
    gradient: str = "auto",
) -> SynthesisResult:
    """Minimize ``objective(design.build(z))`` over the unconstrained variables ``z``.

    The run is one compiled program (a ``lax.while_loop`` per continuation stage,
    all stages in a ``lax.scan``, starts vmapped), compiled once per problem
    structure: the same objective (same code), design structure and method with
    new start values, bounds, ``options``, ``target``/``rtol``/``gtol``/
    ``patience``/``restarts``, ``schedule`` values or ``steps`` (up to the next
    power of two) run without recompiling.

    **Arguments:**
    - ``objective``: pure JAX function of the built mechanism (or scene) returning
      a scalar loss, or ``(loss, aux)`` with ``has_aux=True``. When ``aux`` is a
      dict with an ``"ok"`` entry (e.g. ``Kinematics.ok``), the design must
      have every flag True to be accepted. With a ``schedule`` it is called as
      ``objective(tree, params)``, ``params`` a dict of the stage's values.
      An equinox Module works too (its arrays are traced, not compiled in).
    - ``optimizer``: any optax method, given either as a factory with its
      ``options`` (recommended: numeric options such as ``learning_rate`` are
      then traced, so changing them does not recompile; e.g. ``optax.lbfgs`` or
      ``optax.adam`` with ``options={"learning_rate": 0.05}``), or as a built
      ``optax.GradientTransformation`` (its values compiled in: the same method
      built again with the same values, e.g. ``optax.adam(0.05)`` in a cell run
      twice, reuses the program; other values compile anew).
      Line-search methods (``optax.lbfgs()``, ``optax.scale_by_zoom_linesearch``
      ...) get ``value``, ``grad`` and ``value_fn`` as optax documents; designs
      that cannot assemble have value +inf there, so the search steps back.
    - ``steps``: maximum number of optimizer steps per stage.
    - ``feasible``: optional extra test ``mechanism -> bool`` (e.g. a minimum
      transmission angle).
    - ``target``: stop as soon as the loss is at or below it.
    - ``gtol``: stop ("converged") when the gradient norm is at or below it.
    - ``rtol``/``patience``: when the best loss improved by less than ``rtol``
      (relative) over ``patience`` steps, restart the method from the best design
      (fresh optimizer state) while ``restarts`` remain, else stop ("converged").
    - ``max_backtracks``: a step that leads to a design that cannot assemble (or
      a non-finite loss or gradient, or a negative mass or inertia) is halved up to this many times; then the
      method restarts from the best design (while ``restarts`` remain) or the run
      stops with status ``"infeasible"``. Such designs are never scored.
    - ``schedule``: continuation, e.g. ``{"sharpness": [20., 50., 200., 1000.]}``:
      one stage per value (every entry the same length), each starting from the
      previous stage's best design with a fresh optimizer state; the values are
      traced.
    - ``starts``: multi-start. ``None``: the design's start; an int ``n``: the
      design's start and ``n - 1`` random starts uniform within the bounds
      (``seed``); or parameter values with a leading axis (a pytree like the
      selection). The best start is returned, every start in ``result.starts``.
    - ``batch``: ``"vmap"`` (the starts run side by side), ``"sequential"``
      (``lax.map``: one after the other) or ``"auto"``: sequential for
      line-search methods (under vmap every start would wait for the slowest line
      search, and a start that cannot assemble keeps searching at +inf) and for
      nothing else.
    - ``callback(step, loss, mechanism)``: called for every accepted step of the
      best start after the compiled run. ``progress`` is accepted for
      compatibility and ignored (the loop does not call back into Python).
    - ``compile_mode``: ``"optimized"`` (XLA's default optimization of the machine
      code), ``"quick"`` (optimized less: the first call compiles faster, every
      run is slower) or ``"auto"``: quick for one start of a line-search method
      (whose program holds the objective's value and gradient three times, so
      its compile dominates a first call), optimized otherwise. Measured on the
      straight-line four-bar with L-BFGS: first call 3.8 -> 2.9 s, a call
      without compiling 0.085 -> 0.37 s; with Adam quick saves only ~0.1 s and
      runs 5x slower. Calling one problem many times (new starts, bounds,
      options): pass ``"optimized"``. Each mode is compiled once per problem
      structure; results agree to round-off, which a run can amplify.
    - ``gradient``: how the gradient is taken: ``"reverse"`` (``jax.grad``),
      ``"forward"`` (``jax.jvp`` along each design variable, side by side) or
      ``"auto"``: forward for up to ``FORWARD_MOST`` (8) variables of a design with joint
      friction (in the design's base or an objective Module's fields), reverse otherwise.
      Through a run with friction forward mode is the cheaper one for a few variables
      (``synthesis.final_state`` and ``standstill_time`` then integrate forward
      sensitivities): the slider-crank with joint friction, one coefficient, Adam: first
      call 140 -> 35 s, 70 -> 7.3 ms per evaluation (benchmarks/bench_optimize_gradient.py);
      without friction reverse mode is as fast or faster. An objective that takes reverse
      mode only (a ``jax.custom_vjp``, an explicit ``adjoint="backsolve"``) runs by
      reverse mode under ``"auto"``.

    Raises :class:`AssemblyError` if no starting design can assemble.

    **Example** (L-BFGS with a sharpening smooth max and four starts):
    >>> design, objective = syn.straight_line_problem(lengths)
    >>> result = syn.optimize(design, objective, optax.lbfgs, 200, has_aux=True, rtol=1e-6, restarts=3,
    ...                       schedule={"sharpness": [50.0, 200.0, 1000.0]}, starts=4)
    >>> result.loss, result.values, result.evaluations
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or not 0 <= steps <= MAX_STEPS:
        raise AssurjaxError(f"optimize: steps must be an integer from 0 to {MAX_STEPS:,}, got {steps!r}")
    for name, value in (("patience", patience), ("restarts", restarts), ("max_backtracks", max_backtracks)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= MAX_STEPS:
            raise AssurjaxError(f"optimize: {name} must be an integer from 0 to {MAX_STEPS:,}, got {value!r}")
    check_values(AssurjaxError, "optimize", rtol=rtol, gtol=gtol, **({} if target is None else {"target": target}))
    if rtol < 0 or gtol < 0:
        raise AssurjaxError(f"optimize: rtol and gtol must be non-negative, got {rtol}, {gtol}")
    if batch not in ("auto", "vmap", "sequential"):
        raise AssurjaxError(f"optimize: batch must be 'auto', 'vmap' or 'sequential', got {batch!r}")
    if compile_mode not in COMPILE_MODES:
        raise AssurjaxError(f"optimize: compile_mode must be 'auto', 'quick' or 'optimized', got {compile_mode!r}")
    if gradient not in GRADIENT_MODES:
        raise AssurjaxError(f"optimize: gradient must be 'auto', 'forward' or 'reverse', got {gradient!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:  # NumPy's seeds
        raise AssurjaxError(f"optimize: seed must be a non-negative integer, got {seed!r}")
    started = time.perf_counter()
    numeric, static = _split_options(optimizer, options)
    problem = _Problem(design=design, objective=by_structure(objective), feasible=by_structure(feasible),
                       method=by_structure(optimizer) if isinstance(optimizer, optax.GradientTransformation) else optimizer,
                       method_static=static, has_aux=has_aux, takes_params=schedule is not None,
                       capacity=int(2 ** np.ceil(np.log2(steps + 2))))
    run_options = dict(method=numeric, steps=jnp.asarray(steps), target=jnp.asarray(-np.inf if target is None else target, dtype=float),
                       rtol=jnp.asarray(rtol, dtype=float), gtol=jnp.asarray(gtol, dtype=float), patience=jnp.asarray(patience),
                       restarts=jnp.asarray(restarts), max_backtracks=jnp.asarray(max_backtracks))
    stages = _stages(schedule)
    initial = _starting_values(design, starts, seed)
    _check_history_size(initial, stages, problem.capacity, steps)
    line_search = _has_line_search(problem, numeric, initial)
    if batch == "auto":
        batch = "sequential" if line_search else "vmap"
    if compile_mode == "auto":
        compile_mode = "quick" if line_search and _count(initial) == 1 else "optimized"
    run = _RUN[compile_mode]
    forward = gradient == "forward" or (gradient == "auto" and _variables(initial) <= FORWARD_MOST
                                        and _holds_friction(design, objective))
    batch = batch if _count(initial) > 1 else "single"
    try:
        out = run(dataclasses.replace(problem, forward=forward), run_options, stages, initial, batch)
    except (AssurjaxError, TypeError) as e:
        if not forward or not _forward_refused(e):
            raise
        if gradient == "forward":
            raise AssurjaxError(f"optimize: gradient='forward', but the objective takes reverse-mode derivatives only "
                                f"({e}); pass gradient='reverse'") from None
        out = run(problem, run_options, stages, initial, batch)  # auto: an objective that takes reverse mode only
    per_stage, final_values = jax.device_get(out)
    best_z, best_loss, status, evaluations, counts, history = per_stage
    elapsed = time.perf_counter() - started
    return _result(design, initial, best_z, final_values, best_loss, status, evaluations.sum(axis=1), counts, history, elapsed,
                   callback)


HISTORY_BYTES_LIMIT = 2**32  # a run's history (each start's z and gradient at every step of every stage) is allocated whole


def _check_history_size(initial, stages: dict, capacity: int, steps: int) -> None:
    starts = _count(initial)
    per_start = sum(int(np.prod(x.shape[1:])) for x in jax.tree.leaves(initial))
    stage_count = next(iter(stages.values())).shape[0]
    needed = starts * stage_count * capacity * (2 * per_start + 4) * 8
    if needed > HISTORY_BYTES_LIMIT:
        raise AssurjaxError(f"optimize: {starts} starts x {stage_count} stages x {steps:,} steps ({capacity:,} history "
                            f"rows a stage) of {per_start} parameters would need a history of {needed / 2**30:.3g} GiB "
                            f"(at most {HISTORY_BYTES_LIMIT / 2**30:g}): fewer steps, starts or stages")


def _has_line_search(problem: _Problem, numeric: dict, initial) -> bool:
    """Whether the method's state holds a line search (its value and gradient at the current point)."""
    z = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), initial)
    state = jax.eval_shape(lambda n, z: problem.optimizer(n).init(z), numeric, z)
    return optax.tree_utils.tree_get(state, "value", default=None) is not None


def _count(batched) -> int:
    return jax.tree.leaves(batched)[0].shape[0]


def _variables(batched) -> int:
    """The number of scalar design variables of one start."""
    return sum(int(np.prod(np.shape(x)[1:])) for x in jax.tree.leaves(batched))


def _holds_friction(*trees) -> bool:
    """Whether joint friction is among the leaves of ``trees`` (a design's base, an objective
    that is a Module): its runs are where reverse mode costs most (see optimize's gradient)."""
    from .._friction import AbstractFriction

    return any(isinstance(leaf, AbstractFriction)
               for leaf in jax.tree.leaves(trees, is_leaf=lambda x: isinstance(x, AbstractFriction)))


def _forward_refused(error: Exception) -> bool:
    """Whether ``error`` is an objective's refusal of forward-mode derivatives: a reverse-mode
    adjoint asked of ``synthesis.final_state``/``standstill_time``, or a ``jax.custom_vjp``."""
    return (("forward" in str(error) and "reverse mode only" in str(error)) if isinstance(error, AssurjaxError)
            else "can't apply forward-mode autodiff (jvp) to a custom_vjp function" in str(error))


def _split_options(optimizer, options):
    """Numeric options (traced) and the rest (part of the compiled structure, hashable)."""
    options = dict(options or {})
    if isinstance(optimizer, optax.GradientTransformation):
        if options:
            raise AssurjaxError("optimize: options go with an optax factory (e.g. optax.adam), not with a built GradientTransformation")
        return {}, ()
    if not callable(optimizer):
        raise AssurjaxError("optimize: optimizer must be an optax GradientTransformation or a factory of one, "
                            f"got {type(optimizer).__name__}")
    rate = options.get("learning_rate")
    if isinstance(rate, (int, np.integer)) and not isinstance(rate, bool):  # an int is a rate too (-1 ran uphill unchecked)
        options["learning_rate"] = float(rate)
    numeric = {k: jnp.asarray(v, dtype=float) for k, v in options.items() if isinstance(v, float) or eqx.is_inexact_array(v)}
    for name, value in numeric.items():  # a NaN learning rate ran to "infeasible", blaming the design
        check_value(AssurjaxError, f"optimize: option '{name}'", value, positive=name == "learning_rate")
    static = tuple(sorted((k, v) for k, v in options.items() if k not in numeric))
    try:
        built = optimizer(**dict(static), **numeric)
    except TypeError as e:
        raise AssurjaxError(f"optimize: the optimizer factory does not take these options ({e})") from None
    if not isinstance(built, optax.GradientTransformation):
        raise AssurjaxError(f"optimize: the optimizer factory must return an optax GradientTransformation, got {type(built).__name__}")
    return numeric, static


def _stages(schedule):
    """The schedule as a dict of 1-D arrays (one entry per stage); no schedule: one stage."""
    if schedule is None:
        return {"_": jnp.zeros(1)}
    if not isinstance(schedule, dict) or not schedule:
        raise AssurjaxError("optimize: schedule must be a non-empty dict {parameter name: one value per stage}")
    for name, values in schedule.items():  # a NaN stage ended as "the starting design cannot assemble"
        check_value(AssurjaxError, f"optimize: schedule '{name}'", values)  # before JAX reads "x" as a float
    stages = {k: jnp.atleast_1d(jnp.asarray(v, dtype=float)) for k, v in schedule.items()}
    lengths = {k: v.shape[0] for k, v in stages.items()}
    if len(set(lengths.values())) != 1 or any(v.ndim != 1 for v in stages.values()):
        raise AssurjaxError(f"optimize: every schedule entry must be one value per stage, same count; got lengths {lengths}")
    return stages


def _starting_values(design: Design, starts, seed: int):
    """Starting parameter values with a leading start axis."""
    x0 = design.start()
    if starts is None:
        return jax.tree.map(lambda x: x[None], x0)
    if isinstance(starts, (int, np.integer)) and not isinstance(starts, bool):
        if not 1 <= starts <= MAX_STARTS:
            raise AssurjaxError(f"optimize: starts must be from 1 to {MAX_STARTS:,}, got {starts}")
        for lo, hi in zip(jax.tree.leaves(design.lower), jax.tree.leaves(design.upper)):
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                raise AssurjaxError("optimize: random starts need finite lower and upper bounds on every design variable")
        rng = np.random.default_rng(seed)
        def draw(x, lo, hi, fixed):
            lo, hi = np.asarray(lo), np.asarray(hi)
            random = lo + (hi - lo) * rng.uniform(0.02, 0.98, (starts - 1,) + np.shape(x))
            return jnp.where(fixed, x, jnp.asarray(np.concatenate([np.asarray(x)[None], random])))

        return jax.tree.map(draw, x0, design.lower, design.upper, design.fixed)
    try:
        given = jax.tree.map(lambda x, s: jnp.asarray(s, dtype=x.dtype).reshape((-1,) + jnp.shape(x)), x0, starts)
    except (ValueError, TypeError) as e:
        raise AssurjaxError(f"optimize: starts must be parameter values shaped like the selection, with a leading start axis ({e})") from None
    counts = {int(np.shape(x)[0]) for x in jax.tree.leaves(given)}
    if len(counts) != 1 or not 1 <= counts.pop() <= MAX_STARTS:
        raise AssurjaxError(f"optimize: starts must give every parameter the same number of starts, 1 to {MAX_STARTS:,}")
    for k in range(int(np.shape(jax.tree.leaves(given)[0])[0])):  # each inside its bounds, as Design's own start
        try:
            check_inside(jax.tree.map(lambda g: g[k], given), design.lower, design.upper, design.fixed)
        except AssurjaxError as e:
            raise AssurjaxError(f"optimize: starts[{k}]: {str(e).removeprefix('Design: ')}") from None
    return given


def _result(design, initial, best_z, final_values, best_loss, status, evaluations, counts, history, elapsed, callback) -> SynthesisResult:
    final_loss, names = best_loss[:, -1], tuple(STATUSES[k] for k in status[:, -1])
    found = np.isfinite(final_loss)
    if not found.any():
        raise AssemblyError("optimize: the starting design cannot assemble (some Kinematics.ok flag is False, the feasibility test "
                            "fails, or the objective or its gradient is not finite)" if len(names) == 1 else
                            f"optimize: none of the {len(names)} starting designs can assemble")
    best = int(np.argmin(np.where(found, final_loss, np.inf)))
    z = jax.tree.map(lambda x: jnp.asarray(x[best, -1]), best_z)
    share = elapsed * evaluations[best] / max(evaluations.sum(), 1)
    hist = _history(jax.tree.map(lambda x: x[best], history), counts[best], share)
    if callback is not None:
        for i in range(len(hist.loss)):
            callback(i, float(hist.loss[i]), design.build(jax.tree.map(lambda x: jnp.asarray(x[i]), hist.z)))
    values = jax.tree.map(lambda x: jnp.asarray(x[best]), final_values)
    starts = StartResults(values=final_values, z=jax.tree.map(lambda x: x[:, -1], best_z), loss=final_loss,
                          status=names, evaluations=evaluations, initial=jax.device_get(initial))
    return SynthesisResult(mechanism=design.with_values(values), values=values, z=z, loss=float(final_loss[best]),
                           status=names[best], message=_message(names[best], hist, len(counts[best])), evaluations=int(evaluations.sum()),
                           history=hist, starts=starts, time=elapsed)


def _history(history, counts, elapsed: float) -> History:
    """The valid entries of one start's per-stage buffers, concatenated; evaluations cumulative over stages."""
    take = lambda buf: np.concatenate([np.asarray(buf)[s, : counts[s]] for s in range(len(counts))])  # noqa: E731
    pick = lambda tree: jax.tree.map(take, tree)  # noqa: E731
    per_stage_total = [history["evaluations"][s, counts[s] - 1] if counts[s] else 0 for s in range(len(counts))]
    offsets = np.concatenate([[0], np.cumsum(per_stage_total)[:-1]])
    evals = np.concatenate([np.asarray(history["evaluations"])[s, : counts[s]] + offsets[s] for s in range(len(counts))])
    return History(loss=take(history["loss"]), grad_norm=take(history["grad_norm"]),
                   time=elapsed * evals / max(evals[-1] if len(evals) else 1, 1), evaluations=evals,
                   backtracks=take(history["backtracks"]), aux=pick(history["aux"]), grad=pick(history["grad"]),
                   stage=np.concatenate([np.full(c, s) for s, c in enumerate(counts)]), z=pick(history["z"]))


def _message(status: str, history: History, stages: int) -> str:
    steps = len(history.loss) - stages
    return {"steps": f"ran out of steps ({steps} steps over {stages} stage(s))",
            "target": f"loss {history.loss[-1]:.6g} reached the target after {steps} steps",
            "converged": f"converged after {steps} steps (gradient norm at or below gtol, or no relative improvement "
                         f"above rtol over patience steps with no restart left)",
            "infeasible": "a step led to a design that cannot assemble (or has a non-finite objective or gradient, "
                          "or a negative mass or inertia: bound them below by 0) even after every halving and restart"}[status]
