"""Forward dynamics of the reduced link (Durango et al. 2014, steps ii-v), integrated with diffrax.

:func:`simulate` (checks on the host, then one compiled program) and
:func:`simulate_core` (pure, jittable) integrate :func:`~._field.vector_field`, with
the stop events of ``_events`` and the outputs of ``_solution``. Durango et al.'s own scheme
(Euler in q) is the baseline in ``_baseline``.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable, Sequence
from typing import NamedTuple

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import AssemblyError, AssurjaxError
from .._friction import frictions_of, has_exact_law, in_range, smoothed_only, states_per_call
from .._jit import (Static, any_mapped, checks_without_callbacks, chunk_rows, combine, compile_side_by_side,
                    jit_arrays, split_arrays)
from .._loads import VARIABLES, tables_in
from .._mechanism import Mechanism, check_values_once, positions
from .._positions import assembled
from .._model import Model, as_model, check_has_inertia
from .._tracking import branch_angles, branch_mapping, stacked_branch
from .._values import all_finite, numbers_problem
from .._kinematics import START_SINGULAR_MEASURE, coefficients, singular_groups, singularity_measures, with_reason
from ._events import checked_states, lockup_found, stop_event, which_event
from ._field import FieldArgs, State, packed_vector_field
from ._results import LOCKUP, NO_EVENT, RESULTS
from ._packed import flattened, packed_event, packed_term, packing_of, unpacked
from ._settings import (BASELINES, SAVED_STEPS_LIMIT, WORK_LIMITS, Settings, adjoint_for, check_span_covered,
                        check_step_within_span, fixed_step_from, settings_from, solver_for, lockup_controller,
                        state_problem, step_budget, turn_probe)
from ._call_cache import CallCache
from ._solution import (SAVED_FIELDS, Solution, any_outputs, batch_summary, no_outputs, outputs, quadratures, replaced,
                        saved_rows, to_host, trim)
from ._stick import batch_settings, jammed_members, stick_slip, with_jam_status
from ._table import ReducedTable, build_table, build_table_core, check_table_matches, check_tabulable

AUTO_TABLE_BATCH = 64  # starting states from which reduction="auto" tabulates (a build costs ~15 exact runs)


def _initial_step(settings: Settings, dt):
    """The fixed step, or the controller's first step (None: diffrax's automatic choice,
    two right-hand-side evaluations; a small guess costs more steps to grow)."""
    if dt is None:
        dt = settings.dt
    if dt is not None:
        return jnp.asarray(dt, dtype=float)
    if settings.fixed_step:
        raise AssurjaxError("fixed_step needs a step dt")
    return None


def simulate_core(mechanism: Mechanism | Model, gravity=None, loads=(), q0=0.0, omega0=0.0, t0=0.0, t1=1.0, ts=None, dt=None,
                  *, settings: Settings = Settings(), table: ReducedTable | None = None) -> Solution:
    """The pure, jittable simulation (no Python-side checks or trimming).

    ``mechanism`` with ``gravity`` and ``loads``, or a :class:`assurjax.Model` as the
    first argument (then ``gravity`` and ``loads`` are ignored). ``q0``, ``omega0``,
    ``t0``, ``t1`` and the arrays inside the model may be traced (vmap over them with
    ``eqx.filter_vmap``); ``settings`` is static. ``ts``: save times (default
    ``settings.samples`` times from t0 to t1). ``dt``: the step (s) when
    ``settings.fixed_step`` (traced: a step-size sweep compiles once); else an optional
    initial step.

    ``settings.reduction == "table"``: the right-hand side interpolates ``table`` (a
    :class:`ReducedTable`; None: built here from ``settings.table_nodes`` nodes, traced,
    so differentiable in the mechanism's arrays but without the host-side checks of
    :func:`build_table`). For a batch over q0 pass one table built outside the vmap.
    Outputs are then computed from the saved (q, w) with the exact analysis, and the
    assembly event is off (the table checked a full turn).

    With joint friction, ``settings.kink_events`` (on by default) ends the segments at the
    kinks of the law and the loads as well, for derivatives that do not step across them;
    without friction, a model with load tables then runs in segments between their knots
    (:func:`in_segments`); off, the run is ``simulate``'s (cheaper where nothing is
    differentiated).

    **Example** (10 starting angles at once):
    >>> core = assurjax.jit(eqx.filter_vmap(
    ...     lambda q0: assurjax.simulate_core(mech, gravity, (), q0, 0.0, 0.0, 2.0,
    ...                                       settings=assurjax.SimulationSettings(samples=2))))
    >>> sols = core(jnp.linspace(0.0, 1.0, 10))
    """
    model = mechanism if isinstance(mechanism, Model) else Model(mechanism, gravity, loads)
    return _core(model, q0, omega0, t0, t1, ts, dt, settings, table)


def _core(model: Model, q0, omega0, t0, t1, ts, dt, settings: Settings, table) -> Solution:
    return _finished(model, *_integrate(model, q0, omega0, t0, t1, ts, dt, settings, table), settings)


class EndChecks(NamedTuple):
    """The states whose assembly decides how a run of the lock-up controller ended: just
    past the final state, the final state, the start (rows of ``q`` and ``branch``, the
    tracked branch's stacked link angles or None). :func:`_finished` checks them with the
    outputs' analysis."""

    q: jax.Array
    branch: jax.Array | None


def _integrate(model: Model, q0, omega0, t0, t1, ts, dt, settings: Settings, table):
    """(the Solution without its outputs, the tracked branch's saved link angles or None,
    the EndChecks still to make or None): the motion and its stop. :func:`_finished` does the rest."""
    q0, omega0, t0, t1 = (jnp.asarray(v, dtype=float) for v in (q0, omega0, t0, t1))
    sol, branch, checks = _motion(model, q0, omega0, t0, t1, ts, dt, settings, table)
    sol = replaced(sol, result=friction_result(model.loads, sol.result))
    if settings.check_assembly and not _tabulated(settings):
        sol = _checked_starts(sol, model.mechanism, q0, assembly=checks is None)
    # no weakly typed values: the outputs' program is compiled ahead for these types (compile_side_by_side)
    return jax.tree.map(lambda x: jnp.asarray(x, dtype=x.dtype), (sol, branch, checks))


def friction_result(loads, result):
    """``result`` (a RESULTS item), failed where a friction element's value is not finite or
    out of range: traced values (a sweep's, a vmap's), which no constructor saw; a negative
    coefficient made the friction drive the mechanism."""
    values = eqx.filter(frictions_of(loads), eqx.is_inexact_array)
    if not jax.tree.leaves(values):
        return result
    result = RESULTS.where(in_range(loads), result, RESULTS.friction_out_of_range)
    return RESULTS.where(all_finite(values), result, RESULTS.nonfinite_friction)


def _finished(model: Model, sol: Solution, branch, checks: EndChecks | None, settings: Settings) -> Solution:
    """The Solution of :func:`_integrate` with its end checks made and its outputs: the
    checked states ride as extra rows on the outputs' vmapped analysis."""
    if checks is None:
        return replaced(sol, **outputs(model, sol.t, sol.q, sol.omega, settings, branch)) if any_outputs(settings) else sol
    mechanism = model.mechanism
    if any_outputs(settings):
        n = checks.q.shape[0]  # the checked rows' t and w only feed outputs that are dropped
        rows = (jnp.full(n, sol.t_final), checks.q, jnp.zeros(n), checks.branch)
        t, q, w, near = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), (sol.t, sol.q, sol.omega, branch), rows)
        values = outputs(model, t, q, w, settings, near, flags=True)
        ok = values.pop("ok")[-n:]
        values = jax.tree.map(lambda v: v[:-n], values)
    else:
        values = {}
        ok = jax.vmap(lambda q, b: assembled(mechanism, q, near=branch_mapping(mechanism, b)))(checks.q, checks.branch)
    ok_final = ok[0] & ok[1]
    event, result = lockup_found(sol.event, sol.result, ok_final)
    failed = jnp.where((event == LOCKUP) & ~jnp.all(ok_final), jnp.argmin(ok_final), -1)
    ended = replaced(sol, **values, event=event, result=result, failed_group_index=failed,
                      t_stop=jnp.where(event >= 0, sol.t_final, jnp.inf))
    return _checked_start(ended, ok[2])


def _checked_starts(sol: Solution, mechanism, q0, *, assembly: bool) -> Solution:
    """The start checked to be regular (:func:`_checked_regular_start`) and, with ``assembly``
    (where no end check covers the start, see :func:`_finished`), assembled: one position
    analysis for both."""
    singular = singular_groups(mechanism)
    if not (singular or assembly):
        return sol
    start = coefficients(mechanism, q0, order=0)
    if singular:
        sol = _checked_regular_start(sol, mechanism, singularity_measures(mechanism, start, singular)[:, 0], singular)
    return _checked_start(sol, start.ok) if assembly else sol


def _checked_start(sol: Solution, ok_start) -> Solution:
    """A start where some group cannot assemble (``ok_start``: per group) is no motion at
    all: say so, whatever the solver did."""
    bad = ~jnp.all(ok_start)
    return eqx.tree_at(lambda s: (s.result, s.failed_group_index), sol,
                       (RESULTS.where(bad, RESULTS.start_not_assembled, sol.result),
                        jnp.where(bad, jnp.argmin(ok_start), sol.failed_group_index)))


def _checked_regular_start(sol: Solution, mechanism, measures, declared) -> Solution:
    """A start exactly at a singular configuration of a group that declares one (its
    ``singularity`` measure below START_SINGULAR_MEASURE; the RRR, RRP/PRR and RPR dyads:
    the square root of their closed form is clamped there, which keeps its derivatives
    finite, and they are not the motion's: a four-bar drawn at its crank's limit swung off
    it gaining 2 % of its energy) is no motion: say so. ``measures``: at the start, of the
    groups ``declared`` (:func:`assurjax._kinematics.singular_groups`). Within ~1e-14 rad of
    such a point; 1e-12 rad away the measure is ~1e-6 and the coefficients are the motion's."""
    at = jnp.abs(measures) <= START_SINGULAR_MEASURE
    first = jnp.asarray(declared)[jnp.argmax(at)]
    return eqx.tree_at(lambda s: (s.result, s.failed_group_index), sol,
                       (RESULTS.where(jnp.any(at), RESULTS.start_singular, sol.result),
                        jnp.where(jnp.any(at), first, sol.failed_group_index)))


def _motion(model: Model, q0, omega0, t0, t1, ts, dt, settings: Settings, table):
    """The solution without outputs, the tracked branch's saved link angles (or None) and
    the EndChecks still to make (None: only the start is checked, by _integrate)."""
    if _tabulated(settings):
        settings = settings._replace(check_assembly=False)
        table = build_table_core(model.mechanism, model.gravity, model.loads, settings.table_nodes) if table is None else table
    else:
        table = None
    if settings.steps is not None:
        return _steps_solve(model, q0, omega0, t0, t1, settings, table), None, None
    ts = jnp.linspace(t0, t1, settings.samples) if ts is None else jnp.asarray(ts, dtype=float)
    y0 = _initial_state(model, q0, omega0, settings, table)
    if in_segments(model, settings, table):
        return *stick_slip(model, q0, omega0, t0, t1, ts, dt, y0, settings), None
    user_signs = tuple(jnp.sign(jnp.asarray(c(t0, q0, omega0), dtype=float)) for c in settings.events) or None
    # the steps find a lock-up themselves: the field is NaN there, and such steps are rejected
    checked = settings.check_assembly and table is None
    args = FieldArgs(model=model, table=table, direction=jnp.sign(omega0), q0=q0, user_signs=user_signs,
                     bridge=settings.bridge, nan_unassembled=checked, flat_model=not any_mapped(model))
    solver = solver_for(settings)
    packing, (leaves, rebuild) = packing_of(y0, settings.adjoint, solver), flattened(args)
    event = stop_event(settings)
    sol = diffrax.diffeqsolve(
        packed_term(packing, packed_vector_field, rebuild),
        solver,
        t0=t0,
        t1=t1,
        dt0=_initial_step(settings, dt),
        y0=packing.pack(y0),
        args=leaves,
        # with an event, the last accepted step's end (see _last_accepted_unless_event)
        saveat=diffrax.SaveAt(ts=ts, t1=True, steps=settings.save_steps, controller_state=event is not None),
        stepsize_controller=lockup_controller(settings, packing, rebuild),
        event=packed_event(packing, event, rebuild),
        max_steps=settings.max_steps,
        adjoint=adjoint_for(settings),
        throw=False,
    )
    sol = unpacked(packing, sol)
    if event is not None:
        sol = _last_accepted_unless_event(sol, packing)
    return _package(model, sol, ts, args, settings, y0)


def in_segments(model: Model, settings: Settings, table) -> bool:
    """Whether the motion runs in segments (:func:`~assurjax.dynamics._stick.stick_slip`):
    with joint friction of the exact law (segments of frozen Coulomb signs; a smoothed law
    alone has none), and, where derivatives are taken (``settings.kink_events``), with load
    tables: a segment ends at their next knot and reads them as one piece up to it, so that
    no step straddles a kink. Not on a tabulated reduction, nor where the solver's own steps
    are saved or diffrax's backsolve adjoint runs (one solve each)."""
    if table is not None:
        return False
    frictions = frictions_of(model.loads)
    if frictions:
        return not smoothed_only(frictions)
    return (settings.kink_events and not settings.save_steps and settings.adjoint != "backsolve"
            and any(tables_in(model.loads, v) for v in VARIABLES))


def _last_accepted_unless_event(sol, packing):
    """``sol`` with its final row the last accepted step's end where no event of its own
    stopped the run and diffrax's final state is not finite (in a batch, a member that
    locked up beside one whose event fired: :class:`~assurjax.dynamics._settings.LastAccepted`);
    else as it is (a single run's final state is its last accepted step's end already, and
    its derivatives go through it as before)."""
    last = jnp.sum(jnp.isfinite(sol.ts)) - 1
    kept = sol.controller_state[1]
    own_event = jnp.any(jnp.stack(jax.tree.leaves(sol.event_mask)))
    final = jax.tree.map(lambda z: z[last], sol.ys)
    keep = own_event | all_finite(final)
    ts = sol.ts.at[last].set(jnp.where(keep, sol.ts[last], kept.t))
    ys = jax.tree.map(lambda z, k: z.at[last].set(jnp.where(keep, z[last], k)), sol.ys, packing.unpack(kept.y))
    return eqx.tree_at(lambda s: (s.ts, s.ys), sol, (ts, ys))


def _initial_state(model: Model, q0, omega0, settings: Settings, table) -> State:
    """(q0, w0) and the quadratures and branch the settings ask for."""
    return State(
        q=q0,
        omega=omega0,
        **quadratures(model, settings, exact=table is None),
        # the branch travels with the state, starting on the fixed modes
        branch=stacked_branch(model.mechanism, branch_angles(model.mechanism, positions(model.mechanism, q0)))
        if settings.branch == "tracked" else None,
    )


def _steps_solve(model: Model, q0, omega0, t0, t1, settings: Settings, table) -> Solution:
    """``settings.steps`` equal steps of the diffrax solver from t0 to t1, by
    ``jax.lax.scan`` over the solver's own ``step`` (no step-size controller, no
    event root finding, no dense output): the leanest use of diffrax for this
    two-state ODE, whose adaptive loop costs more per step than a tabulated
    right-hand side. Saves every step (``dissipated`` and ``work`` stay None). Without a
    table, a step any of whose stages meets a configuration that cannot assemble ends
    the valid samples before it (event 1, located to the step, not by root finding):
    with the fixed mode, stepping over a limit position would otherwise bounce back
    unphysically."""
    check_steps(settings)
    tabulated = table is not None
    y0 = State(q0, omega0)
    solver = solver_for(settings)
    packing = packing_of(y0, settings.adjoint, solver)
    term = packed_term(packing, packed_vector_field)
    args = FieldArgs(model=model, table=table, direction=jnp.sign(omega0), q0=q0, user_signs=None,
                     nan_unassembled=settings.check_assembly and not tabulated, flat_model=not any_mapped(model))
    h = (t1 - t0) / settings.steps

    def step(carry, k):
        y, state = carry
        t = t0 + k * h
        y1, _, _, state, _ = solver.step(term, t, t + h, y, args, state, False)
        return (y1, state), y1

    z0 = packing.pack(y0)
    _, zs = jax.lax.scan(step, (z0, solver.init(term, t0, t0 + h, z0, args)), jnp.arange(settings.steps))
    ys = packing.unpack(zs)
    t = t0 + h * jnp.arange(settings.steps + 1)
    q, w = jnp.concatenate([q0[None], ys.q]), jnp.concatenate([omega0[None], ys.omega])
    n = settings.steps
    mechanism = model.mechanism
    # a NaN or inf marks a step that met a configuration that cannot assemble, or steps too
    # long for the motion (they blew up: no group fails one step on, with a table none can)
    finite = jnp.isfinite(q) & jnp.isfinite(w)
    turns = _turns_at_limits(mechanism, h, q, w) if args.nan_unassembled else None
    if turns is not None:  # a step that turned the driver at a limit ends the samples as one that met NaN
        finite = finite & jnp.concatenate([jnp.array([True]), jnp.all(turns, axis=-1)])
    stopped = ~jnp.all(finite)
    last = jnp.where(stopped, jnp.argmin(finite) - 1, n)  # the last sample before it
    valid = jnp.arange(n + 1) <= last
    t, q, w = (jnp.where(valid, x, x[last]) for x in (t, q, w))
    if tabulated or not settings.check_assembly:
        failed = jnp.asarray(-1)
    else:
        ahead = assembled(mechanism, q[last] + h * w[last])  # the group failing one step on
        ahead = ahead & turns[jnp.minimum(last, n - 1)]  # or beyond the turn of the step after the last sample
        failed = jnp.where(stopped & ~jnp.all(ahead), jnp.argmin(ahead), -1)
    locked, unresolved = stopped & (failed >= 0), stopped & (failed < 0)
    return Solution(
        t=t, q=q, omega=w, **no_outputs(), dissipated=None, valid=valid,
        t_final=t[last], q_final=q[last], omega_final=w[last],
        t_stop=jnp.where(locked, t[last], jnp.inf), event=jnp.where(locked, LOCKUP, NO_EVENT),
        failed_group_index=failed, result=RESULTS.where(unresolved, RESULTS.dt_min_reached, RESULTS.successful),
        num_steps=jnp.asarray(n),
    )


def _turns_at_limits(mechanism: Mechanism, h, q, w):
    """Per step of ``steps=`` (n, groups): whether each group assembles where the step's
    turn of the driver must stand (all True where it did not turn; see
    ``_settings._turned_at_a_limit``: a step over a limit position turned w round on the
    same branch, a thrown slider-crank ran on with most of its energy gone). One position
    analysis per step, only where some step turned."""
    turned, probe, _ = turn_probe(h, q[:-1], w[:-1], q[1:], w[1:])
    assembles = lambda: jax.vmap(lambda x: assembled(mechanism, x))(probe)  # noqa: E731
    every = jnp.ones((q.shape[0] - 1, len(mechanism.groups)), dtype=bool)
    return jax.lax.cond(eqxi.unvmap_any(jnp.any(turned)), assembles, lambda: every) | ~turned[:, None]


def check_steps(settings: Settings, model: Model | None = None) -> None:
    if model is not None and smoothed_only(frictions_of(model.loads)):
        raise AssurjaxError("steps= (fixed steps) is not available with joint friction, even smoothed: only the adaptive "
                            "solver tells a jam of the friction (no consistent motion) from a lock-up; use steps=None")
    if model is not None and frictions_of(model.loads):
        raise AssurjaxError("steps= (fixed steps) cannot locate where a mechanism with joint friction comes to rest "
                            "or breaks away: use the adaptive solver (steps=None)")
    if int(settings.steps) < 1:
        raise AssurjaxError(f"steps must be a positive number of steps, got {settings.steps}")
    if settings.standstill or settings.events:
        raise AssurjaxError("steps= integrates with fixed steps and locates no events: use stop=None and no events, "
                            "or the adaptive solver (steps=None) for stop='standstill' and user events")
    if settings.branch == "tracked":
        raise AssurjaxError("steps= needs branch='fixed' (a tracked branch travels in the adaptive solver's state)")


def check_steps_request(settings: Settings, model: Model, saveat, step) -> None:
    """:func:`check_steps` of a user's run (simulate, batch_simulate) with its save times and
    constant step: steps= saves its own equal steps and takes neither."""
    check_steps(settings, model)
    for given, name in ((saveat, "saveat"), (step, "dt")):
        if given is not None:
            raise AssurjaxError(f"steps= saves the state at each of its equal steps and takes no {name}: give one of "
                                f"them (steps, or the adaptive solver with {name})")


def _tabulated(settings: Settings) -> bool:
    """True in table mode; clear errors for unknown modes and unsupported combinations."""
    if settings.reduction not in ("exact", "table", "auto"):
        raise AssurjaxError(f"reduction must be 'exact', 'table' or 'auto', got {settings.reduction!r}")
    # 'auto' (settings_from's default) is simulate's choice, made on the host with the table's
    # checks; a traced run takes the exact reduction
    if settings.reduction == "table" and settings.branch == "tracked":
        raise AssurjaxError("reduction='table' needs branch='fixed' (the table is sampled on the scene's assembly modes)")
    return settings.reduction == "table"


def _package(model: Model, sol, ts, args: FieldArgs, settings: Settings, y0: State):
    # diffrax writes the saved times reached (and, with save_steps, every accepted step's
    # end, in time order), then the final state (an event deletes the times past it), and
    # pads with inf.
    if settings.save_steps:
        sol = _start_if_nothing_saved(sol, y0)
    last = jnp.sum(jnp.isfinite(sol.ts)) - 1
    ys: State = sol.ys
    t_final, q_final, w_final = sol.ts[last], ys.q[last], ys.omega[last]
    if settings.save_steps:  # diffrax's own times, the steps' ends among them: keep them all
        times, reached, head = sol.ts, jnp.arange(sol.ts.shape[0]) <= last, lambda z: z
    else:  # the times reached, then the final state itself (an event stops between two saved times)
        times, reached, head = ts, jnp.arange(ts.shape[0]) < last, lambda z: z[:-1]
    # the rest repeat the final state, so every output stays finite
    valid = jnp.arange(times.shape[0]) <= last
    along = lambda z: jnp.where(reached.reshape((-1,) + (1,) * (z.ndim - 1)), head(z), z[last])  # noqa: E731
    q, w = along(ys.q), along(ys.omega)
    t = jnp.where(reached, times, t_final)
    near = None if ys.branch is None else along(ys.branch)  # saved link angles (tracked branch), stacked
    checks = None
    if settings.check_assembly:  # just past the end, at the end, at the start
        # checked assembly: the lock-up controller steps (args.nan_unassembled)
        checks = EndChecks(*checked_states(y0, q_final, w_final, None if ys.branch is None else ys.branch[last]))
    event, result = which_event(sol, settings, args, last), RESULTS.promote(sol.result)
    solution = Solution(
        t=t, q=q, omega=w, **no_outputs(),
        dissipated=None if ys.dissipated is None else along(ys.dissipated),
        work=None if ys.work is None else along(ys.work),
        valid=valid, t_final=t_final, q_final=q_final, omega_final=w_final,
        t_stop=jnp.where(event >= 0, t_final, jnp.inf), event=event, failed_group_index=jnp.asarray(-1),
        result=result, num_steps=sol.stats["num_steps"],
    )
    return solution, near, checks


def _start_if_nothing_saved(sol, y0: State):
    """``sol`` with its start as its first saved state where diffrax saved nothing: with
    ``save_steps`` a solve that accepts no step (its field NaN from the start: a load) saves
    neither the save times it never passed nor its end, and that run was read as a lock-up at
    t = inf."""
    empty = ~jnp.isfinite(sol.ts[0])
    first = lambda saved, start: saved.at[0].set(jnp.where(empty, start, saved[0]))  # noqa: E731
    return eqx.tree_at(lambda s: (s.ts, s.ys), sol, (first(sol.ts, sol.t0), jax.tree.map(first, sol.ys, y0)))


# simulate()'s two programs (see _Prepared.run), on the model split by split_arrays
def _integrate_split(arrays, rest: Static, *args):
    return _integrate(combine(arrays, rest), *args)


def _finished_split(arrays, rest: Static, *args):
    return _finished(combine(arrays, rest), *args)


_integrate_jit = jit_arrays(_integrate_split, static_argnums=(1, 8))
_finished_jit = jit_arrays(_finished_split, static_argnums=(1, 5))


# ---------------------------------------------------------------------------- user-facing


def simulate(
    scene,
    *,
    q0=None,
    omega0=None,
    t0=None,
    t1=None,
    saveat=None,
    stop: str | None | type(...) = ...,
    solver: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt: float | None = None,
    max_steps: int | None = None,
    samples: int | None = None,
    events: Sequence[Callable] = (),
    check_assembly: bool = True,
    mechanism: Mechanism | None = None,
    loads=None,
    gravity=None,
    points: Sequence[str] | None = None,
    angles: Sequence[str] | None = None,
    energies: bool | None = None,
    velocities: bool | None = None,
    accelerations: bool | None = None,
    coms: Sequence[str] | None = None,
    branch: str | None = None,
    reduction: str | None = None,
    table_nodes: int | None = None,
    table: ReducedTable | None = None,
    steps: int | None = None,
    save_steps: bool | None = None,
    bridge: float | None = None,
    max_step: float | None = None,
    kink_events: bool | None = None,
    throw: bool = False,
) -> Solution:
    """Simulate a mechanism's motion from its initial state (Durango et al.'s (2014) forward dynamics).

    ``scene``: a :class:`assurjax.Scene` (its initial state, ``[simulation]`` settings
    and ``[outputs]`` apply), a :class:`assurjax.Model` or a bare
    :class:`assurjax.Mechanism` (defaults: q0 = omega0 = t0 = 0, t1 = 1 s).

    Keyword arguments override the scene: ``q0`` (rad or m), ``omega0`` (rad/s or
    m/s), ``t0``, ``t1`` (s) from ``[state]``; ``stop`` (``"standstill"`` or None; the
    default is the scene's ``[simulation] stop``, and no stop without one: the motion
    runs to t1), ``solver`` (``"tsit5"`` default, ``"dopri5"``, ``"dopri8"``, ..., or the
    baseline ``"seed_euler"``: Durango et al.'s Euler in q, :func:`assurjax.simulate_seed_euler`,
    which takes ``dt`` as its step in q, rad or m, default 1e-3, and ``max_steps``, and
    returns t, q and omega only), ``rtol``, ``atol`` (default 1e-8: errors below 1e-6 rad
    over seconds of motion in the bundled scenes, up to ~1e-5 rad seen in stick-slip with
    joint friction; pass 1e-10 or tighter for reference-quality runs; with joint
    friction the friction is solved at each right-hand side to 1e-2 of the tighter of the
    two, not below 1e-12), ``dt`` (a
    fixed step, s, up to 1000 and at most the span t1 - t0; without error control the
    steps that close in on a lock-up find its position, and its time and final velocity only as well as they resolve the singular
    motion there: prefer the adaptive steps near limits), ``max_step`` (the longest adaptive step, s; default: no limit -- set it
    where a load varies in time faster than the motion shows, e.g. a short pulse on a
    mechanism held at rest by friction, which longer steps could pass over),
    ``max_steps`` (default: 4096 for up to 4 s of motion, doubled per doubling of the
    span up to 16.7 million steps; a span longer than those cover, ~3.4e5 s at the 50
    steps/s of the slowest bundled mechanism in motion, with nothing to end it sooner
    (stop=None, no events) is refused unless ``max_steps`` is given: t1 = 1e12 is likely a
    mistake, and the run took minutes to use up its budget), ``samples`` from ``[simulation]``; ``points``,
    ``angles``, ``energies`` from ``[outputs]`` (with ``energies`` the Solution also
    carries ``work`` and ``balance``: T + V - W, which closes for driven, damped and
    loaded mechanisms; not with the tabulated reduction, which ``reduction="auto"`` picks
    for 64 starts or more: there ``work`` and ``balance`` are None, pass
    ``reduction="exact"`` for them); ``coms`` (links whose centres of mass to save), ``velocities``,
    ``accelerations`` (True: also the velocities / accelerations of the saved points,
    centres of mass and link angles; for ``points``, ``angles`` and ``coms`` a plain string is one
    name). ``branch``: ``"fixed"`` (default: the scene's assembly modes)
    or ``"tracked"``: the link angles travel in the ODE state (d theta/dt =
    d theta/dq w, from the same jvp) and every group takes the root nearest to them,
    which keeps the motion on one continuous branch through singular configurations
    (e.g. the N-four-bar's). ``bridge`` (rad or m of q; default 0: off): within that
    distance of a dyad's singular configuration (RRR, RRP/PRR, RPR) the kinematic coefficients of a
    tracked branch are interpolated from outside the window
    (:func:`assurjax.bridged_coefficients`), where the closed forms lose their precision:
    ``bridge=5e-3`` lets tight tolerances (1e-12) pass such crossings (IFToMM A02, N = 40,
    20 s: 3.5e-7 rad with Dopri8 at 1e-12); it costs compile and run time (the tracked
    N = 40 program compiles ~4x longer), so it is off by default. ``reduction``: ``"exact"`` (the reduction at every
    right-hand side), ``"table"``: a :class:`ReducedTable` of ``table_nodes`` (default
    4096) nodes over one crank turn is built and checked first, and the right-hand side
    interpolates it (crank drivers, loads of q only; see :func:`build_table`), or
    ``"auto"`` (default): the table for a batch of at least AUTO_TABLE_BATCH starting
    states when the scene allows one (its build then costs less than the exact
    reduction saves), else exact. ``table``: a prebuilt :class:`ReducedTable` to use.
    ``steps``: integrate with that many equal steps by ``jax.lax.scan`` over the
    solver's own step (no step-size control, no events: ``stop`` must be None; saves
    every step) -- the fastest path for short runs: with a table, ``steps=80``
    (Tsit5) keeps the Watt six-bar within 4e-9 rad over 1 s in ~60 us.
    ``saveat``: an array of times (s). ``save_steps``: also save the state at the end of
    every accepted solver step, merged in time order with ``saveat`` (outputs then
    follow the solver where the motion changes fast; up to ``max_steps`` extra samples;
    single runs only, not with joint friction of the exact law). ``events``: functions ``cond(t, q, omega)``;
    the motion stops where one changes sign (with joint friction also past a rest, and
    while the friction holds the mechanism at rest; one function alone is one event).
    ``mechanism``, ``loads`` (one load alone is the only one), ``gravity`` replace the
    scene's. ``throw`` (True or False): raise :class:`assurjax.AssurjaxError` with the
    status when the solver stops early (e.g. the step budget is used up) instead of
    returning a Solution that says so. ``kink_events`` (default False, or the scene's
    ``[simulation] kink_events``): end the integration's segments where a slider block's
    end load changes sign (joint friction) and at the knots of the loads' tables,
    kinks of the right-hand side that the steps otherwise cross at a cost in accuracy: the
    press at rtol = 1e-8 is within 1.2e-9 rad of its converged motion with them, 6.5e-7
    without (1.5-2x the run time, fewer steps; below ~1e-7 rad the faster way there).

    ``q0`` and ``omega0`` may be 1-D arrays (broadcast together): then all starting
    states are simulated at once (vmapped) and the :class:`Solution` has a leading
    batch axis, untrimmed (read ``valid``; ``t_stop`` is +inf where no event fired).

    Returns a :class:`Solution` trimmed to the times reached (a single run).

    Not traceable as a whole (it checks on the host): under ``jax.jit``, ``vmap`` or
    ``grad`` use :func:`assurjax.simulate_core`, or :func:`assurjax.synthesis.final_state`
    and :func:`assurjax.synthesis.standstill_time` for derivatives.

    What depends only on the scene and the options (the checked settings and model, a
    table) is kept for later calls with the same scene object and equal options; a
    changed scene is a new object (scenes are immutable) and is checked anew.

    **Example:**
    >>> sol = assurjax.simulate(assurjax.load_scene("watt_sixbar"))
    >>> float(sol.t_stop)   # first standstill after falling from rest (the scene asks for stop = "standstill")
    >>> batch = assurjax.simulate(scene, q0=np.linspace(0, 6, 10_000), stop=None)
    """
    options = dict(stop=stop, solver=solver, rtol=rtol, atol=atol, dt=dt, max_steps=max_steps, samples=samples,
                   events=events, check_assembly=check_assembly, points=points, angles=angles, energies=energies,
                   velocities=velocities, accelerations=accelerations, coms=coms, branch=branch, reduction=reduction,
                   table_nodes=table_nodes, steps=steps, save_steps=save_steps, bridge=bridge, max_step=max_step,
                   kink_events=kink_events)
    request = checked_request(scene, options, q0=q0, omega0=omega0, t0=t0, t1=t1, saveat=saveat, gravity=gravity,
                              mechanism=mechanism, loads=loads, table=table, throw=throw)
    prepared = request.prepared
    model, settings = prepared.model, prepared.settings
    if settings.solver in BASELINES:
        from ._baseline import simulate_seed_euler

        return simulate_seed_euler(model.mechanism, model.gravity, model.loads, request.q0, request.omega0, t0=request.t0,
                                   t1=request.t1, dq=request.step or 1e-3, standstill=settings.standstill,
                                   max_steps=max_steps)
    q0, omega0, batch = request.q0, request.omega0, request.batch
    settings, table = prepared.resolved(table, batch, request.max_steps)
    if batch is not None:
        q0, omega0 = np.broadcast_to(q0, batch), np.broadcast_to(omega0, batch)
    args = (q0, omega0, request.t0, request.t1, request.saveat, request.step, settings, table)
    with checks_without_callbacks():  # saveat and the rest were checked above: see _jit
        sol = prepared.run(args, batch)
    if batch is None:
        try:
            sol = trim(sol, model.mechanism, settings, q0)
        except AssemblyError as e:  # a start that does not assemble: why (the lengths), as kinematics says
            raise with_reason(e, model.mechanism, q0) from None
        sol = with_jam_status(sol, model, settings)
        if throw and not sol.successful:
            raise AssurjaxError(f"simulation of '{model.mechanism.name}': {sol.status}")
        return sol
    sol = replaced(to_host(sol), mechanism_points=model.mechanism.point_names)
    sols = batch_summary(sol, jammed_members(sol, model), groups=model.mechanism.group_names)
    if throw and not sols.successful:
        raise AssurjaxError(f"simulation of '{model.mechanism.name}': {sols.status}")
    return sols


def check_simulate(scene, **keywords) -> None:
    """Every check ``simulate(scene, **keywords)`` makes before it runs, without running it:
    raises :class:`assurjax.AssurjaxError` naming the setting at fault."""
    bound = inspect.signature(simulate).bind(scene, **keywords)
    bound.apply_defaults()
    given = dict(bound.arguments)
    extras = {k: given.pop(k) for k in ("scene", "q0", "omega0", "t0", "t1", "saveat", "gravity", "mechanism", "loads",
                                        "table", "throw")}
    checked_request(extras.pop("scene"), given, **extras)


class Request(NamedTuple):
    """A checked request of :func:`simulate`: the prepared model and settings, the start and
    span (NumPy arrays; as given for a baseline), the save times, the fixed step, the batch
    shape (None: one run) and the step budget (None: a baseline's own)."""

    prepared: "_Prepared"
    q0: object
    omega0: object
    t0: object
    t1: object
    saveat: np.ndarray | None
    step: object
    batch: tuple | None
    max_steps: int | None


def checked_request(scene, options: dict, *, q0=None, omega0=None, t0=None, t1=None, saveat=None, gravity=None,
                    mechanism=None, loads=None, table=None, throw=False) -> Request:
    """Every check :func:`simulate` makes before it runs (``options``: its settings keywords):
    raises :class:`assurjax.AssurjaxError` naming the setting at fault. The command's
    ``validate`` asks it what ``run`` would be refused."""
    refuse_traced("simulate", q0=q0, omega0=omega0, t0=t0, t1=t1, saveat=saveat, gravity=gravity,
                  **{k: options[k] for k in ("dt", "rtol", "atol", "max_step", "bridge", "samples", "max_steps", "steps",
                                             "table_nodes")})
    if not isinstance(throw, (bool, np.bool_)):  # a string 'no' read as True
        raise AssurjaxError(f"setting 'throw': expected True or False, got {throw!r}")
    prepared = _PREPARED.get(
        (scene, getattr(scene, "simulation", None), getattr(scene, "outputs", None), mechanism, gravity, loads, table,
         *(options[k] for k in sorted(options))),  # the same key for check_simulate, whose order differs
        lambda: _prepare(scene, mechanism, gravity, loads, table, options))
    model, scene_or_none, settings = prepared.model, prepared.scene, prepared.settings
    state = {} if scene_or_none is None else scene_or_none.state
    q0, omega0, t0, t1 = (v if v is not None else state.get(k, d)
                          for v, k, d in ((q0, "q0", 0.0), (omega0, "omega0", 0.0), (t0, "t0", 0.0), (t1, "t1", 1.0)))
    if (problem := state_problem(q0, omega0, t0, t1)) is not None:
        raise AssurjaxError(f"setting '{problem[0]}': {problem[1]}")
    _check_events_at_start(settings, q0, omega0, t0)
    step = fixed_step_from(scene_or_none, options["dt"])
    if settings.solver in BASELINES:
        tolerances = [key for key in ("rtol", "atol", "max_step")
                      if options[key] is not None or key in simulation_table(scene_or_none)]
        _check_baseline_request(settings, model, q0, omega0, saveat, tolerances)
        return Request(prepared, q0, omega0, t0, t1, saveat, step, None, None)
    if settings.steps is not None:
        check_steps_request(settings, model, saveat, step)
    if step is not None:
        check_step_within_span(step, t0, t1)
    if prepared.budget_per_span and settings.steps is None:
        check_span_covered(t0, t1, settings)
    # Arrays, not Python floats: filter_jit would treat floats as static and recompile per value.
    # NumPy scalars: jit takes them without the cost of creating device arrays one by one.
    q0, omega0, t0, t1 = (np.asarray(v, dtype=float) for v in (q0, omega0, t0, t1))
    # a subnormal speed is 0 here as in the compiled program, which flushes it (5e-324 ran as a
    # rest there and read as a motion on the host: a held start's status lacked its rest)
    omega0 = np.where(np.abs(omega0) < np.finfo(float).tiny, 0.0, omega0)
    saveat = None if saveat is None else checked_saveat(saveat, t0, t1)
    batch = _batch_shape(q0, omega0)
    _check_save_steps(settings, model, batch)
    if batch is not None:
        check_saved_total(batch[0], "starts", saveat, settings)
    max_steps = step_budget(t0, t1) if prepared.budget_per_span else settings.max_steps  # longer runs get a larger budget
    if settings.save_steps:  # every step is a saved row (with its outputs): the budget is the request for memory
        if prepared.budget_per_span:
            max_steps = min(max_steps, SAVED_STEPS_LIMIT)
        elif max_steps > SAVED_STEPS_LIMIT:
            raise AssurjaxError(f"save_steps saves every solver step: max_steps must be at most {SAVED_STEPS_LIMIT} with it, "
                                f"got {max_steps} (use samples or saveat for longer runs)")
    step = None if step is None else np.asarray(step, dtype=float)
    return Request(prepared, q0, omega0, t0, t1, saveat, step, batch, max_steps)


def _check_events_at_start(settings: Settings, q0, omega0, t0) -> None:
    """A user event that is NaN at the start can never change sign: it would never fire, and
    nothing would say so."""
    for i, cond in enumerate(settings.events):
        value = np.asarray(cond(t0, np.asarray(q0, dtype=float), np.asarray(omega0, dtype=float)), dtype=float)
        if np.any(np.isnan(value)):
            where = f"q0 = {float(q0):g}" if np.ndim(q0) == 0 else f"{np.count_nonzero(np.isnan(value))} of the starts"
            raise AssurjaxError(f"events: event #{i + 1} is NaN at the start (t0 = {float(t0):g} s, {where}): a NaN never "
                                "changes sign, so it would never fire; give a function defined along the motion")


def _check_baseline_request(settings: Settings, model: Model, q0, omega0, saveat, tolerances: list) -> None:
    """What the baseline (one start, no friction, events, save times or tolerances) refuses;
    ``tolerances``: the step-control settings given (it ignored them without a word)."""
    if np.ndim(q0) or np.ndim(omega0):
        raise AssurjaxError(f"solver={settings.solver!r} (a baseline) simulates one starting state at a time")
    if frictions_of(model.loads):
        raise AssurjaxError(f"solver={settings.solver!r} (a baseline, Durango et al.'s scheme) has no joint friction; "
                            "the scene has friction elements: use the default solver")
    for given, name in ((settings.events, "events"), (saveat, "saveat")):
        if given:
            raise AssurjaxError(f"solver={settings.solver!r} (a baseline: Euler in q, samples every dq of travel) "
                                f"takes no {name}: use the default solver")
    if tolerances:
        raise AssurjaxError(f"solver={settings.solver!r} (a baseline: Euler in q with a fixed travel dq, set by dt) has no "
                            f"step-size control and takes no {tolerances[0]}: use the default solver for tolerances")


@dataclasses.dataclass(frozen=True)
class _Prepared:
    """What simulate() derives from the scene and the options alone (checked once, then
    kept in _PREPARED for later calls with the same scene and options)."""

    model: Model
    scene: object | None  # the Scene (its [state] is read per call), or None for a Model or Mechanism
    settings: Settings  # validated; max_steps and the reduction are resolved per call
    budget_per_span: bool  # max_steps from the time span (neither the keyword nor the scene sets it)
    kink_events: bool  # cuts at the kinks of the friction law and the loads' tables: only where asked
    model_parts: tuple  # split_arrays(model): the programs' first two arguments
    _resolutions: dict = dataclasses.field(default_factory=dict)
    _compiled: set = dataclasses.field(default_factory=set)  # signatures compiled side by side (see run)

    def resolved(self, table, batch, max_steps: int):
        """(settings with max_steps and the reduction resolved, the table or None): the
        table is built (and checked) once per prepared call, not per call."""
        # all _resolve_reduction reads of batch, and whether it is one (the segments' chunks)
        key = (max_steps, batch is not None, batch is not None and batch[0] >= AUTO_TABLE_BATCH)
        if key not in self._resolutions:
            # simulate() returns host arrays, never differentiated: diffrax's plain while loop
            # (forward mode) traces faster than the checkpointed one and computes the same,
            # and no cuts at the kinks of the friction and the loads unless asked (Settings.kink_events): derivatives
            # need them; the values gain accuracy by them at some cost (see simulate's kink_events)
            settings = self.settings._replace(max_steps=max_steps, adjoint="forward", kink_events=self.kink_events)
            settings = settings if batch is None else batch_settings(settings, self.model.loads)
            self._resolutions[key] = _resolve_reduction(settings, table, self.model, batch)
        return self._resolutions[key]

    def run(self, args: tuple, batch):
        """simulate_core's work for ``args`` (its arguments after the model) as two programs:
        the integration, then the end checks and the outputs at the saved states, compiled
        side by side on the first call of a signature (the Watt six-bar's first call 2.6 ->
        1.8 s on two cores, against one program holding both); the outputs in chunks of
        saved states where dw/dt solves many friction elements (``_friction.states_per_call``)."""
        integrate, finish = (_integrate_jit, _finished_jit) if batch is None else (_batch_integrate_jit, _batch_finished_jit)
        parts, settings = self.model_parts, args[6]
        chunk = None if batch is not None or not settings.domega else states_per_call(frictions_of(self.model.loads))

        def chunked(out):  # whether the outputs' program takes the saved states in chunks
            return chunk is not None and out[0].t.shape[0] > chunk

        # what shapes the programs besides the prepared model (a signature missed here is not
        # wrong, only compiled one program after the other by the calls themselves)
        signature = (batch, None if args[4] is None else args[4].shape, args[5] is None, args[7] is None, settings)
        if signature not in self._compiled:
            rows = lambda out: integrated_rows(out, chunk_rows(out[0].t.shape[0], chunk)[0]) if chunked(out) else out  # noqa: E731
            compile_side_by_side(integrate, (*parts, *args), finish, lambda out: (*parts, *rows(out), settings))
            self._compiled.add(signature)
        out = integrate(*parts, *args)
        if not chunked(out):
            return finish(*parts, *out, settings)
        return finished_in_chunks(lambda part: finish(*parts, *part, settings), to_host(out), chunk)


def integrated_rows(out: tuple, rows) -> tuple:
    """(solution, branch, end checks) of :func:`_integrate` with only the saved states
    ``rows`` (host arrays)."""
    sol, branch, checks = out
    return saved_rows(sol, rows), None if branch is None else branch[rows], checks


def finished_in_chunks(finish, out: tuple, chunk: int) -> Solution:
    """``finish(out)`` with the saved states' outputs computed at most ``chunk`` states at a
    time (:func:`~.._jit.chunk_rows`; one program for a chunk, called once per chunk: a loop
    over the chunks inside one program took 1-3 s longer to compile): the end checks ride on
    every chunk, and give the same result on each."""
    n = out[0].t.shape[0]
    pieces = to_host([finish(integrated_rows(out, rows)) for rows in chunk_rows(n, chunk)])  # every call dispatched first
    joined = {k: jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *(getattr(p, k) for p in pieces)) for k in SAVED_FIELDS}
    return replaced(pieces[0], **joined)


def _prepare(scene, mechanism, gravity, loads, table, options: dict) -> _Prepared:
    refuse_traced("simulate", scene=jax.tree.leaves(scene), mechanism=jax.tree.leaves(mechanism),
                  loads=jax.tree.leaves(loads))
    model = as_model(scene, mechanism=mechanism, gravity=gravity, loads=loads, what="simulate")
    check_values_once(model.mechanism)
    check_has_inertia(model.mechanism)
    scene_or_none = None if isinstance(scene, (Model, Mechanism)) else scene
    settings = settings_from(scene_or_none, **options)
    _check_outputs(model.mechanism, settings)
    if settings.reduction == "table" and table is None:  # what the table's build would refuse, before any run
        _tabulated(settings)
        check_tabulable(model.mechanism, model.loads)
    budget_per_span = options["max_steps"] is None and "max_steps" not in simulation_table(scene_or_none)
    asked = options["kink_events"] if options["kink_events"] is not None else simulation_table(scene_or_none).get("kink_events")
    return _Prepared(model, scene_or_none, settings, budget_per_span, bool(asked), split_arrays(model))


_PREPARED = CallCache()


def simulation_table(scene) -> dict:
    """The scene's [simulation] table (empty for a Model or Mechanism)."""
    return {} if scene is None else scene.simulation


def checked_saveat(saveat, t0, t1) -> np.ndarray:
    """The save times as a 1-D float array, sorted from t0 towards t1 and inside [t0, t1]."""
    if (problem := numbers_problem(saveat)) is not None:  # before NumPy reads "abc" and names no field
        raise AssurjaxError(f"saveat {problem}")
    saveat = np.asarray(saveat, dtype=float)
    if saveat.ndim != 1 or not saveat.size:
        raise AssurjaxError(f"saveat must be a 1-D array of at least one time, got shape {saveat.shape}")
    if saveat.size > WORK_LIMITS["samples"][0]:  # bounded as samples are
        raise AssurjaxError(f"saveat: at most {WORK_LIMITS['samples'][0]:,} times, got {saveat.size:,}")
    steps = np.diff(saveat) * np.sign(t1 - t0)
    if np.any(steps < 0) or not np.all(np.isfinite(saveat)):
        raise AssurjaxError("saveat must be finite times in the direction from t0 to t1")
    if np.any((saveat - t0) * (saveat - t1) > 0):
        raise AssurjaxError(f"saveat must lie between t0 = {float(t0)} and t1 = {float(t1)} s; "
                            f"got times from {saveat.min()} to {saveat.max()}")
    return saveat


def _batch_shape(q0, omega0):
    """None for one starting state, else the common 1-D shape of q0 and omega0."""
    if q0.ndim == 0 and omega0.ndim == 0:
        return None
    try:
        shape = np.broadcast_shapes(q0.shape, omega0.shape)
    except ValueError:
        raise AssurjaxError(f"q0 (shape {q0.shape}) and omega0 (shape {omega0.shape}) do not broadcast together") from None
    if len(shape) != 1:
        raise AssurjaxError(f"a batch of starting states needs 1-D q0/omega0, got shape {shape}")
    if not 1 <= shape[0] <= MAX_STARTS:
        raise AssurjaxError(f"a batch of starting states holds 1 to {MAX_STARTS:,} of them, got {shape[0]:,} "
                            "(split larger batches over several calls)")
    return shape


MAX_STARTS = 1_000_000  # starting states per simulate call: each saves its samples
SAVED_STATES_LIMIT = 100_000_000  # saved states of a batch's call, all runs together (24 bytes each at least)


def check_saved_total(runs: int, what: str, saveat, settings: Settings) -> None:
    """Each bound on its own, a batch's runs (``what``: "starts", "mechanisms") times their
    saved states may still not fit in memory (a million starts of 100 000 samples: 745 GiB, a
    raw MemoryError; a million mechanisms of 201: RESOURCE_EXHAUSTED after 17 s): bounded too."""
    rows = saveat.size if saveat is not None else settings.steps + 1 if settings.steps is not None else settings.samples
    if runs * rows > SAVED_STATES_LIMIT:
        raise AssurjaxError(f"{runs:,} {what} x {rows:,} saved states each would hold {runs * rows:,} states "
                            f"(at most {SAVED_STATES_LIMIT:,} per call): fewer samples, or split the {what} over calls")


def refuse_traced(where: str, **values) -> None:
    """Raise naming the first of ``values`` that JAX traces (jax.jit, vmap, grad): ``where``
    checks its inputs and shapes its result on the host, so it cannot be traced as a whole
    (a traced q0 met NumPy as TracerArrayConversionError deep inside)."""
    for name, value in values.items():
        if any(isinstance(v, jax.core.Tracer) for v in (value if isinstance(value, (list, tuple)) else (value,))):
            raise AssurjaxError(
                f"{where} cannot be traced as a whole (under jax.jit, vmap or grad: its '{name}' is traced here): it "
                "checks its inputs and trims its result on the host. Inside a traced function use "
                "assurjax.simulate_core (pure and jittable; vmap it with eqx.filter_vmap), or, for derivatives, "
                "assurjax.synthesis.final_state and assurjax.synthesis.standstill_time")


def _resolve_reduction(settings: Settings, table, model: Model, batch):
    """(settings with reduction 'exact' or 'table', the table or None). The table is
    built and checked on the host, once, outside the jitted core."""
    if table is not None:
        if not isinstance(table, ReducedTable):
            raise AssurjaxError(f"table must be an assurjax.ReducedTable (from assurjax.build_table), got {type(table).__name__}")
        if settings.reduction == "exact":
            raise AssurjaxError("table= replaces the exact reduction: give reduction='exact' or a table, not both")
        check_table_matches(table, model.mechanism, model.gravity, model.loads)
        return settings._replace(reduction="table"), table
    if settings.reduction == "auto":
        wanted = batch is not None and batch[0] >= AUTO_TABLE_BATCH and settings.branch == "fixed"
        if wanted:
            try:
                return settings._replace(reduction="table"), build_table(model.mechanism, model.gravity, model.loads,
                                                                         settings.table_nodes)
            except AssurjaxError:  # not tabulable (slider, velocity/time loads, a crank that cannot turn fully)
                pass
        return settings._replace(reduction="exact"), None
    if _tabulated(settings):
        return settings, build_table(model.mechanism, model.gravity, model.loads, settings.table_nodes)
    return settings, None


def _batch_integrate(arrays, rest: Static, q0, omega0, t0, t1, ts, dt, settings, table):
    model = combine(arrays, rest)
    return jax.vmap(lambda q, w: _integrate(model, q, w, t0, t1, ts, dt, settings, table))(q0, omega0)


def _batch_finished(arrays, rest: Static, sols, branch, checks, settings):
    model = combine(arrays, rest)
    return jax.vmap(lambda sol, b, c: _finished(model, sol, b, c, settings))(sols, branch, checks)


_batch_integrate_jit = jit_arrays(_batch_integrate, static_argnums=(1, 8))
_batch_finished_jit = jit_arrays(_batch_finished, static_argnums=(1, 5))


def saves_solver_steps(loads) -> bool:
    """Whether a single run with these loads can save the solver's own steps (``save_steps``):
    not with joint friction of the exact law, whose motion is integrated in segments (a
    smoothed law alone is one solve)."""
    return not has_exact_law(loads)


def _check_save_steps(settings: Settings, model: Model, batch) -> None:
    if not settings.save_steps:
        return
    if batch is not None:
        raise AssurjaxError("save_steps saves up to max_steps states per run: it is for single runs, not batches")
    if not saves_solver_steps(model.loads):
        raise AssurjaxError("save_steps is not available with joint friction of the exact law (the motion is integrated "
                            "in segments between rests and changes of a joint's Coulomb sign): use saveat or samples, "
                            "or give every friction element a smoothing speed")


def _check_outputs(mechanism: Mechanism, settings: Settings) -> None:
    for p in settings.points:
        if p not in mechanism.point_names:
            raise AssurjaxError(f"setting 'points': unknown point '{p}' (known: {sorted(mechanism.point_names)})")
    for key in ("angles", "coms"):
        for a in getattr(settings, key):
            if a not in mechanism.links:
                raise AssurjaxError(f"setting '{key}': unknown link '{a}' (known: {sorted(mechanism.links)})")

