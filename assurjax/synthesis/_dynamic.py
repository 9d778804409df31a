"""Differentiable simulation results: the final state theta(T) and the standstill time.

Both wrap the pure, jittable ``simulate_core`` (diffrax) and take gradients with
the adjoint named by ``adjoint``:

- ``"recursive"`` (diffrax.RecursiveCheckpointAdjoint, the default): reverse mode,
  exact gradients of the computed solution (discretize-then-optimize); best for
  many parameters (the whole mechanism) and one scalar result.
  Under ``jax.jvp`` or ``jax.jacfwd`` (traced by them when this is called) it runs as
  ``"forward"``: the same derivatives (diffrax's reverse-mode adjoints take no forward
  mode; with joint friction they agree to ~1e-5 relative after many Coulomb switches: the
  press's dw/dr at rtol 1e-11, within what central differences resolve there). A ``jax.jacfwd`` of a jitted function calling this is not seen here and raises
  JAX's TypeError: jit inside the jacfwd, or ask ``adjoint="forward"``. Forward over
  reverse (``jax.hessian``) is refused: nest ``jax.jacfwd`` instead.
- ``"forward"`` (diffrax.ForwardMode): forward mode (``jax.jvp``/``jax.jacfwd``);
  best for a few parameters or directional derivatives (one jvp ~3x a simulation;
  ``jax.jacfwd`` over 50 parameters ~100-200x: every tangent goes through the
  second-order kinematics at every solver stage).
- ``"backsolve"`` (diffrax.BacksolveAdjoint): solves the adjoint ODE backwards in
  time, O(1) memory, gradients only to the solver tolerance; no events.
- ``"quadrature"`` (the fastest for the whole gradient, ~3.5-4x one simulation for the
  50 parameters of the Watt six-bar: benchmarks/README.md): forward sensitivities by the
  variation-of-constants formula (:mod:`._sensitivity`): the plain simulation, one
  batched reverse pass of the reduced acceleration at Gauss-Legendre nodes and a 2x2
  transition-matrix solve; no derivative through the solver. Its accuracy is that of the
  panel quadrature, not the solver's tolerance: on the Watt six-bar's standstill it is
  within the tolerance at the defaults, but on a slider-crank's half turn (0.7 s, rtol =
  atol = 1e-10, against central differences) the Jacobian erred by 2e-5 relative at 16
  panels (0.2 at 4, 2e-8 at 64, 3e-9 at 256) where "sensitivity" gave 2.5e-9. Settings: ``solver``, ``rtol``, ``atol``, ``dt``,
  ``max_steps``, ``panels`` (default 16), ``nodes`` (default 6 per panel): raise
  ``panels`` where the motion changes fast. The error is estimated (S again with A
  interpolated one degree lower, in the same transition solve): where it exceeds 1e-3 of a
  column's largest entry the derivatives are NaN, a loud failure (a slider-crank driven over
  two turns: 44x off at 16 panels, 1.7e-2 at 64 (estimated ~1e-2): NaN; 8e-6 at 128
  (estimated ~1e-5) and 1.4e-6 at 256 pass). Below it the error can still reach ~1e-3
  relative: compare two panel counts, or "sensitivity", where that matters.
- ``"sensitivity"``: the forward-sensitivity equations S' = f_y S + f_p integrated
  by diffrax together with the state (one reverse pass of the acceleration per stage);
  same accuracy, no quadrature parameters, slower.

Both sensitivity routes support ``jax.grad``, ``jax.jacfwd``, ``jax.jvp`` (one
``jax.custom_jvp``), the exact reduction on the scene's fixed assembly branch, and no
assembly check. Joint friction only by ``"sensitivity"``, and only with the regularized law
in every element (``smoothing``); the exact law goes by ``"recursive"`` or ``"forward"``.

See benchmarks/bench_gradients.py for measured costs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import AssurjaxError
from .._jit import any_mapped, jit
from .._mechanism import check_values_once
from .._model import check_has_inertia
from .._positions import assembled
from ..dynamics._field import arrival_acceleration
from ..dynamics._results import FINISHED, STANDSTILL, finished, jam_text, result_code, result_text, status_text
from ..dynamics._settings import (ADJOINTS, check_single_start, check_span_covered, check_step_within_span, fixed_step_from,
                                  settings_from)
from ..dynamics._stick import BATCH_SEGMENT_STEPS, jammed_members
from ..dynamics._table import build_table
from ..dynamics._solve import simulate_core
from ._sensitivity import final_state_sensitivity, standstill_state

SENSITIVITY_ROUTES = {"quadrature": "quadrature", "sensitivity": "loop"}


def _derivative_modes(*trees) -> set[str]:
    """The autodiff modes tracing any leaf of ``trees``: "forward" (jax.jvp, jax.jacfwd),
    "reverse" (jax.grad, jax.vjp, jax.linearize), read down each tracer's chain of primals
    (a vmapped jacfwd: a forward tracer over a batch tracer)."""
    modes = set()
    for leaf in jax.tree.leaves(trees):
        while isinstance(leaf, jax.core.Tracer):
            kind = type(leaf).__name__
            modes |= {"JVPTracer": {"forward"}, "LinearizeTracer": {"reverse"}}.get(kind, set())
            leaf = getattr(leaf, "primal", getattr(leaf, "val", None))
    return modes


def _adjoint_for_modes(name: str, adjoint: str, *inputs) -> str:
    """The diffrax adjoint for the derivatives being taken of ``inputs``: the default,
    reverse-mode "recursive", becomes "forward" under jax.jvp or jax.jacfwd (the same
    derivatives: diffrax's reverse-mode adjoints take no forward-mode derivative and raised
    JAX's own TypeError). Forward over reverse (jax.hessian, jax.jacfwd of jax.grad) neither
    adjoint can take, nor "forward" reverse mode: refused, naming the routes that can."""
    modes = _derivative_modes(*inputs)
    if adjoint == "forward" and "reverse" in modes:
        raise AssurjaxError(f"{name}: adjoint='forward' (diffrax's ForwardMode) takes forward-mode derivatives only "
                            "(jax.jvp, jax.jacfwd); for jax.grad use 'recursive' (the default), 'backsolve', "
                            "'quadrature' or 'sensitivity'")
    if adjoint not in ("recursive", "backsolve") or "forward" not in modes:
        return adjoint
    if "reverse" in modes:
        raise AssurjaxError(f"{name}: forward-mode derivatives of reverse-mode ones (jax.hessian, jax.jacfwd of "
                            f"jax.grad) do not pass diffrax's adjoint {adjoint!r}, and adjoint='forward' takes no "
                            "reverse mode: nest forward modes (jax.jacfwd of jax.jacfwd), or take the outer "
                            "derivative by differences")
    if adjoint == "backsolve":
        raise AssurjaxError(f"{name}: adjoint='backsolve' is reverse mode only; jax.jvp and jax.jacfwd need "
                            "adjoint='forward' (or 'recursive', the default, which switches to it)")
    return "forward"


def _route(adjoint: str, settings: dict) -> dict:
    return {**settings, "method": SENSITIVITY_ROUTES[adjoint]}


def _settings(scene, settings: dict, **fixed):
    """The scene's settings under the caller's, for a lean run (no outputs, exact reduction)."""
    opts = settings_from(scene, **{"samples": 2, "domega": False, "points": (), "angles": (), "energies": False,
                                   **settings, **fixed})
    return opts._replace(reduction="exact") if opts.reduction == "auto" else opts


def _checked_table(scene, opts):
    """With ``reduction="table"`` and a concrete model, the table built with every check of
    :func:`assurjax.build_table`, for the run to use; else None (the run builds it traced,
    where those checks cannot run: a window between its nodes where a group cannot assemble
    gave a state 6 rad past the exact reduction's lock-up)."""
    if opts.reduction != "table" or _traced(*jax.tree.leaves(scene.model)):
        return None
    return build_table(scene.mechanism, scene.gravity, scene.loads, opts.table_nodes)


def _check_start(scene, q0, omega0, t1, adjoint) -> None:
    """:func:`check_single_start` of the caller's start and horizon, else the scene's [state];
    the adjoint's name."""
    known = sorted(ADJOINTS) + sorted(SENSITIVITY_ROUTES)
    if adjoint not in known:
        raise AssurjaxError(f"unknown adjoint {adjoint!r}; choose one of {known}")
    check_values_once(scene.mechanism)
    check_has_inertia(scene.mechanism)
    state = scene.state
    check_single_start(state.get("q0", 0.0) if q0 is None else q0, state.get("omega0", 0.0) if omega0 is None else omega0,
                       state.get("t0", 0.0), state.get("t1", 1.0) if t1 is None else t1)


def final_state(scene, t1, *, q0=None, omega0=None, adjoint: str = "recursive", **settings):
    """(q(T), omega(T)) of the scene's motion from its initial state to ``t1`` (s),
    without stop events; differentiable with respect to every array of ``scene``
    (mechanism parameters, gravity, load values). ``settings``: fields of
    :class:`assurjax.SimulationSettings` (``solver``, ``rtol``, ``atol``, ``dt``,
    ``max_steps``) over the scene's ``[simulation]``.

    A run that does not reach ``t1`` (the joint friction jams the mechanism, the step
    budget runs out) or ends where the mechanism does not assemble (it passed a lock-up: the
    run does not stop at one unless ``check_assembly=True``) has no q(T): called as it is,
    this raises :class:`assurjax.AssurjaxError` naming how it ended; under ``jax.jit``,
    ``vmap``, ``grad`` or ``jacfwd`` it returns NaN (and derivative 0) for that run, also
    as a member of a vmapped batch whose other members go on to ``t1``.

    With joint friction, a start from rest (``omega0`` = 0) is a kink in ``omega0``: the
    Coulomb signs follow the direction the mechanism starts in, so the derivative in
    ``omega0`` there is the one-sided one, on the side the loads start it (central
    differences across 0 average the two sides). Its segments also end at the kinks of the
    friction law (a slide's block end lifting) and of the loads' tables (their knots in q, t
    or omega; with or without friction), so that its derivatives do not step across them;
    ``simulate`` does not cut there, so the two agree to the tolerance, not to round-off
    (``SimulationSettings.kink_events``)."""
    _check_start(scene, q0, omega0, t1, adjoint)
    if settings.get("stop") is not None:
        raise AssurjaxError(f"final_state runs to t1 without stop events (got stop={settings['stop']!r}): for the time "
                            "of the first standstill use synthesis.standstill_time")
    check_step_within_span(fixed_step_from(scene, settings.get("dt")), scene.state.get("t0", 0.0), t1)
    adjoint = _adjoint_for_modes("final_state", adjoint, scene, q0, omega0, t1, settings)
    if adjoint in SENSITIVITY_ROUTES:
        q, w, result = final_state_sensitivity(scene, t1, q0=q0, omega0=omega0, **_route(adjoint, settings))
        return _route_as_asked("final_state", result, (q, w), pose=(scene.mechanism, q))
    opts = _settings(scene, {"check_assembly": False, **settings}, standstill=False, adjoint=adjoint)
    state = scene.state
    if "max_steps" not in settings and "max_steps" not in scene.simulation and not _traced(t1):
        check_span_covered(state.get("t0", 0.0), t1, opts)  # as simulate (t1 = 1e9 ran ~2000 s first)
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    # past a lock-up the motion means nothing: whether the final pose assembles, in the run's program
    model = scene.model
    sol, assembles = _run(model, q0, omega0, state.get("t0", 0.0), t1, fixed_step_from(scene, settings.get("dt")), opts,
                          final_pose=True, table=_checked_table(scene, opts))
    return _run_as_asked("final_state", sol, model, opts, (sol.q_final, sol.omega_final),
                         ended=lambda event: event < 0, assembles=assembles)


LOCKUP_PASSED = ("the mechanism does not assemble where the motion ended: it passed a lock-up (a limit position) "
                 "on the way (simulate's check_assembly=True stops there)")


def _traced(*values) -> bool:
    return any(isinstance(v, jax.core.Tracer) for v in values)


def _failed_as_nan(ok, values):
    """``values`` where ``ok``; NaN where not (a flag: False), with derivative 0 there: a NaN
    derivative would carry NaN cotangents back through the run's linear solves, which
    lineax refuses in reverse mode with an error raised from inside the program."""
    return tuple(jnp.where(ok, v, jnp.nan) if jnp.issubdtype(jnp.result_type(v), jnp.floating) else v & ok
                 for v in values)


def _raise_unless(what: str, ended, assembles, why) -> None:
    """Outside any transformation (host values): raise where a run did not end as asked
    (``ended``: at t1, or at the event asked for, and no solver failure; ``why()`` says how it
    ended) or where the mechanism does not assemble at its end (a lock-up passed)."""
    if not ended:
        reason = why()
    elif not assembles:
        reason = LOCKUP_PASSED
    else:
        return
    raise AssurjaxError(f"{what}: the motion did not end as asked: {reason} (under jit, vmap or grad this result is NaN)")


def _route_as_asked(what: str, result, values: tuple, *, pose=None) -> tuple:
    """``values`` of a sensitivity route, which ends at t1 or its standstill event unless the
    solver fails (``result``: its integer code); ``pose``: (mechanism, final q) where the
    final pose must assemble. Refused as :func:`_run_as_asked` refuses a run."""
    if _traced(result, *values):
        ok = (result == FINISHED[0]) | (result == FINISHED[1])
        return _failed_as_nan(ok if pose is None else ok & jnp.all(assembled(*pose)), values)
    _raise_unless(what, int(result_code(result)) in FINISHED, True if pose is None else bool(np.all(assembled(*pose))),
                  lambda: result_text(int(result_code(result))))
    return values


def _run_as_asked(what: str, sol, model, settings, values: tuple, *, ended, assembles=True) -> tuple:
    """``values`` of a run of ``simulate_core`` that ended as asked (``ended(event)``: the stop
    events allowed; and no solver failure) where the mechanism assembles at its end. Where it
    did not (the joint friction jams it, a group locks up, the step budget runs out), the
    values are not the result asked for: outside any transformation raise, naming how it
    ended (its status); under one (jit, vmap, grad), NaN in its place. The flags are read on
    the host where nothing is traced: as jax operations, called one by one, they cost more
    than the run (final_state of the Watt six-bar 0.50 -> 0.75 ms)."""
    if _traced(sol.t_final, sol.q_final, sol.omega_final, *values):
        return _failed_as_nan(finished(sol.result) & ended(sol.event) & assembles, values)

    def why():
        code, event, t_final = int(result_code(sol.result)), int(sol.event), float(sol.t_final)
        if jammed_members(sol, model).any():
            return jam_text(t_final, float(sol.q_final), float(sol.omega_final))
        failed = int(sol.failed_group_index)
        group = model.mechanism.groups[failed].name if failed >= 0 else None
        return status_text(code, event, group, t_final, max_steps=settings.max_steps)

    _raise_unless(what, int(result_code(sol.result)) in FINISHED and ended(int(sol.event)), bool(assembles), why)
    return values


def _run(model, q0, omega0, t0, t1, dt, settings, *, final_pose: bool = False, table=None):
    """``simulate_core`` as one cached program (:func:`_core_program`), its numbers as arrays;
    with ``final_pose``, (the Solution, whether the mechanism assembles at its final q).
    ``table``: a checked table for ``reduction="table"`` (None: built in the program)."""
    numbers = tuple(None if v is None else jnp.asarray(v, dtype=float) for v in (q0, omega0, t0, t1, dt))
    if settings.segment_steps is None and any_mapped((model, numbers)):
        # a vmap is invisible inside the program's nested jit: its runs are a batch (see stick_slip)
        settings = settings._replace(segment_steps=BATCH_SEGMENT_STEPS)
    return _core_program(model, *numbers, settings, final_pose, table)


@jit
def _core_program(model, q0, omega0, t0, t1, dt, settings, final_pose: bool, table):
    """``simulate_core`` compiled once per structure and settings, the model's arrays and the
    numbers traced. Called in pieces, under a ``jax.grad`` that the user has not jitted, the
    segment loop of the exact friction law was traced and compiled anew at every call (the
    slider-crank's derivative in mu: 51 s a call, 0.1 s once compiled). ``final_pose``: also
    whether the mechanism assembles at the final q."""
    sol = simulate_core(model, None, (), q0, omega0, t0, t1, None, dt, settings=settings, table=table)
    return (sol, jnp.all(assembled(model.mechanism, sol.q_final))) if final_pose else sol


def standstill_time(scene, *, t1=None, q0=None, omega0=None, adjoint: str = "recursive", **settings):
    """The first time (s) at which the driving link comes to rest (omega = 0 against
    its direction of motion), and an ok flag (False: no standstill before ``t1``).

    The derivative follows the implicit function theorem on omega(t*, p) = 0
    (Durango et al.'s (2014) standstill, differentiated):

        dt*/dp = -(d omega / dp at fixed t) / (d omega / dt at t*),

    built as t* - (omega(t*) - stop_gradient(omega(t*))) / stop_gradient(alpha(t*)),
    which is correct whether or not the event location itself carries a gradient.
    With ``adjoint="quadrature"`` or ``"sensitivity"`` the same formula is applied to
    the forward sensitivities at t* (one solve for the whole gradient).

    A run that fails before its standstill or ``t1`` (a jam, a lock-up, the step budget)
    raises :class:`assurjax.AssurjaxError`, or under a transformation gives t* = NaN, ok False.
    """
    _check_start(scene, q0, omega0, t1, adjoint)
    if adjoint == "backsolve":  # diffrax's BacksolveAdjoint takes no events
        raise AssurjaxError("standstill_time: adjoint='backsolve' solves no events, and the standstill is one; use "
                            "'recursive', 'forward', 'quadrature' or 'sensitivity'")
    adjoint = _adjoint_for_modes("standstill_time", adjoint, scene, q0, omega0, t1, settings)
    if adjoint in SENSITIVITY_ROUTES:
        t_star, q_star, ok, result = standstill_state(scene, t1=t1, q0=q0, omega0=omega0, **_route(adjoint, settings))
        return _route_as_asked("standstill_time", result, (t_star, ok), pose=(scene.mechanism, q_star))
    opts = _settings(scene, settings, standstill=True, adjoint=adjoint)
    state = scene.state
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    t1 = state.get("t1", 1.0) if t1 is None else t1
    model = scene.model
    sol = _run(model, q0, omega0, state.get("t0", 0.0), t1, fixed_step_from(scene, settings.get("dt")), opts,
               table=_checked_table(scene, opts))
    alpha = jax.lax.stop_gradient(arrival_acceleration(model, sol.t_final, sol.q_final, sol.omega_final,
                                                       jnp.asarray(q0, dtype=float), jnp.asarray(omega0, dtype=float),
                                                       jnp.asarray(state.get("t0", 0.0), dtype=float)))
    w, stopped = sol.omega_final, sol.event == STANDSTILL
    # at its standstill the implicit-function term; at t1 with none before it (ok False) t1, whose
    # derivative is t1's own (the term there gave d t*/d q0 = 1.35 where differences give 0)
    moved = jnp.where(stopped, (w - jax.lax.stop_gradient(w)) / jnp.where(alpha == 0, 1.0, alpha), 0.0)
    return _run_as_asked("standstill_time", sol, model, opts, (sol.t_final - moved, stopped),
                         ended=lambda event: event <= STANDSTILL)
