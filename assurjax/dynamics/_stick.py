"""Stick and slip: a mechanism with Coulomb friction that comes to rest stays at rest
while the friction can hold it, and breaks away when the loads overcome it.

In a one-degree-of-freedom mechanism every relative rate is (d phi_k/dq) w, so the
Coulomb sign of element k is sign(d phi_k/dq) sign(w). At rest the question is one of
direction: with the kinetic friction signs of a motion in direction s, the acceleration
a_s (``dynamics._field.frictional``). Friction only resists, so only the direction s of
the frictionless generalized force can start (``_field.rest_side``): the mechanism
sticks while s a_s <= 0, and breaks away in direction s when a time-dependent load
makes s a_s positive. (Testing both directions, as this module did, gives the same
answer at twice the cost.)

The motion is integrated by diffrax in segments inside one loop, each with its Coulomb
signs frozen, so that the field is smooth inside a segment and a derivative sees every
switch of the law (its saltation) through the located switch time: a slip segment ends
where w returns to 0, or where some element's d phi_k/dq changes sign (its integrated
value, ``State.friction_rates``, crosses 0: the motion goes on with that sign flipped),
each a diffrax.Event located by root finding (and, in a run that can be differentiated,
where a prismatic pair's block-end load changes sign or q, t or w reaches a knot of a load's
table: kinks, which derivatives must not step across, ``Settings.kink_events``); a stick
segment (w = 0, q fixed) ends where the break-away margin -s a_s crosses 0 (another
Event), its steps controlled on the margin's integral, carried in its state so that they
resolve how the loads move the margin (``_stuck_field``). A segment goes in the direction
sign(w) or, from rest, in s; there its own vector field decides whether the mechanism
breaks away: at w = 0 an acceleration not in direction s (or no consistent friction) is
0, so its first step ends at rest, which the step-size controller rejects and ends the
solve with (``_settings.LockupController``) -- the mechanism is held from there
(``refused`` below). So a segment's start solves no friction of its own (doing so made
the integration program a third larger: the Watt six-bar's first call 9.0 s instead of
7.3). Without loads that may vary in time (and user events to watch) a mechanism held at
rest stays held: the stick segment, whose field and event each solve the friction, is
left out, and the rest is filled to t1. A
user event ends the run in a slip or a stick segment; with ``stop='standstill'`` the loop
ends at the first rest. Each segment saves the requested times that fall inside it. A
batch (``simulate`` with an array of starts, ``batch_simulate``, a caller's vmap) steps its members
together, each diffrax call until its slowest member's segment ends: there a segment is
integrated in chunks of ``Settings.segment_steps`` steps, so that a member whose segment
ended waits at most one chunk for the next (the press, 16 starts: 15.6 -> 9.4 us per
member and step; a single run takes whole segments). The loop is equinox's checkpointed while loop
(the one diffrax's own steps run in): reverse-mode derivatives go through it; with
``adjoint='forward'`` a plain while loop, for forward mode.

A run without friction comes here only where it is cut at its load tables' knots
(``_solve.in_segments``): its segments end at the knots and where w returns to 0 (the
direction a q knot lies ahead in), and nothing holds it at rest.
"""

from __future__ import annotations

from typing import NamedTuple

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import AssurjaxError
from .._friction import (LOOKAHEAD, frictions_of, has_blocks, has_exact_law, has_static, iteration_tolerance,
                         rates_and_slopes, signs_ahead, static_in_order, with_block_signs)
from .._jit import any_mapped, jit
from .._loads import next_knot, piece_around, pieces_at, tables_in
from .._model import Model
from .._values import all_finite
from ._events import assembles, located_event, lockup_found, stop_event, user_margins, which_event
from ._field import (FieldArgs, State, block_loads, constant, frictional, kinematic_coefficients, near,
                     packed_vector_field, rest_analysis, rest_direction, rest_jams, start_kinematics)
from ._packed import packed_event, packed_term, packing_of, unpacked
from ._results import (DT_MIN, END_SWITCH, FINISHED, KNOT, LOCKUP, MAX_STEPS, NO_EVENT, RESULTS, STANDSTILL, USER,
                       finished, jam_text, result_code)
from ._settings import LOCKUP_RESOLUTION, Settings, adjoint_for, controller_for, lockup_controller, solver_for
from ._solution import Solution, limit_ahead, no_outputs, replaced, saved_rows

MAX_SEGMENTS = 4096  # stick, slip and Coulomb-sign segments in one simulation
# ... and where segments also end at the knots of the loads' tables: a measured table of 720
# points a turn crosses 4096 knots in under six turns (the bound only sizes reverse mode's checkpoints)
MAX_KNOTTED_SEGMENTS = 16 * MAX_SEGMENTS
FIRST_STEP = 1e-4  # in chunks, the first call's first step, times t1 - t0 (the controller adapts it)
BATCH_SEGMENT_STEPS = 16  # Settings.segment_steps of simulate's batches (benchmarks/bench_friction.py)


def batch_settings(settings: Settings, loads) -> Settings:
    """The settings of a batch of runs: with joint friction, segments in chunks of
    BATCH_SEGMENT_STEPS steps (see the module docstring)."""
    return settings._replace(segment_steps=BATCH_SEGMENT_STEPS) if frictions_of(loads) else settings


def breakaway_margin(model: Model, t, y: State, bridge: float = 0.0, coeffs=None):
    """-s dw/dt of the only direction s that can start from rest (with that direction's
    friction; 0 where it has no consistent solution): > 0 while the friction holds.
    ``coeffs``: the kinematic coefficients at y.q, where the caller has them."""
    alpha, side = rest_analysis(model, t, y, bridge, coeffs)[:2]
    return -side * alpha


def _stuck_field(t, held, args):
    """A stick segment's (State, integral of the break-away margin): the state stays; the
    integral is there for the step-size controller, whose error estimate of it resolves how
    the loads move the margin in time (with a zero field alone the steps grew tenfold each,
    past any short pulse of load)."""
    y, _ = held
    return jax.tree.map(jnp.zeros_like, y), breakaway_margin(args.model, t, y, args.bridge, args.coeffs)


def _held(args: FieldArgs, coeffs) -> FieldArgs:
    """A stick segment's arguments: held, q stays, so its field and events (diffrax's three
    sites) read the kinematic coefficients of its start instead of each redoing the
    position analysis."""
    return eqx.tree_at(lambda a: a.coeffs, args, coeffs, is_leaf=lambda x: x is None)


def _states_only(run):
    """A stick segment's solution without the margin's integral (only its steps read it), so
    that it comes out of one lax.cond with a slip segment's."""
    return eqx.tree_at(lambda r: r.ys, run, [states for states, _ in run.ys])


def stick_slip(model: Model, q0, omega0, t0, t1, ts, dt, y0: State, settings: Settings):
    """The motion with joint friction in segments (see the module docstring): to t1, or
    with ``settings.standstill`` to the first rest (a start held at rest: a standstill at t0).
    Returns (the Solution without outputs, the tracked branch's saved link angles or None)."""
    if settings.adjoint == "backsolve":  # diffrax's backsolve cannot save a segment's times and steps apart
        raise AssurjaxError("adjoint 'backsolve' is not available with joint friction (the motion runs in segments "
                            "that save their outputs as they go): use 'recursive' (reverse mode) or 'forward'")
    first_rest = settings.standstill
    solver, n, k_elements = solver_for(settings), ts.shape[0], len(frictions_of(model.loads))
    # a batch of runs steps together: diffrax's loop runs until its slowest member ends its segment; in chunks
    # of segment_steps steps a member whose segment has ended waits at most that many to start its next one
    # (a run the caller vmaps is such a batch too: whole segments there left a jammed member beside
    # one that ran on with the dense output of its NaN attempt, read as a lock-up)
    chunk = settings.segment_steps
    if chunk is None and any_mapped((model, q0, omega0, t0, t1, ts, dt, y0)):
        chunk = BATCH_SEGMENT_STEPS
    slip_settings = settings._replace(standstill=True)
    # prismatic pairs: each slip segment freezes their block ends' signs, and ends where a load changes sign
    blocks = settings.kink_events and has_blocks(frictions_of(model.loads))
    # the knots of the loads' tables in q, t and omega: each ends a slip segment too (kinks of the loads)
    tables = tuple(tables_in(model.loads, v) for v in ("q", "t", "omega")) if settings.kink_events else ((), (), ())
    knotted = any(tables)
    slip_event = stop_event(slip_settings, switches=True, ends=blocks, knots=knotted)
    user_signs = tuple(jnp.sign(jnp.asarray(c(t0, q0, omega0), dtype=float)) for c in settings.events) or None
    # without loads that vary in time a mechanism held at rest stays held: no stick segment
    # (and no break-away event, two copies of the friction solve) is needed in the program,
    # unless user events are to be watched while it rests
    # (without friction, a run in segments only at its loads' knots, nothing holds the
    # mechanism at rest: no stick segment, no start refused, no Coulomb rates in the state)
    frictionless = k_elements == 0
    holds = not frictionless and not first_rest and (bool(settings.events)
                                                     or any(load.may_depend_on_time() for load in model.loads))
    flat_model = not any_mapped(model)  # read here, outside the segments' loop (see _jit.any_mapped)
    static = has_static(model.loads)

    def stuck_margins(t, y, args):
        """The break-away margin (> 0 while stuck), then the user events' margins."""
        return [breakaway_margin(args.model, t, y, args.bridge, args.coeffs)] + user_margins(settings, t, y, args)

    # read afresh at each step's end (not integrated: the direction that can start flips with the
    # frictionless force, and that direction's friction may gain or lose a consistent solution)
    breakaway = located_event(lambda t, held, args: jnp.min(jnp.stack(stuck_margins(t, held[0], args))), settings)
    hold_codes = jnp.asarray([NO_EVENT] + [USER + k for k in range(len(settings.events))])

    kind = "lax" if settings.adjoint == "forward" else "checkpointed"

    def segment_args(y, direction, signs, ends, knots, pieces) -> FieldArgs:
        return FieldArgs(model=model, table=None, direction=direction, q0=y.q, user_signs=user_signs, rate_signs=signs,
                         bridge=settings.bridge, nan_unassembled=settings.check_assembly,
                         friction_tolerance=iteration_tolerance(settings.rtol, settings.atol), flat_model=flat_model,
                         end_signs=None if ends is None else ends[0], end_floor=None if ends is None else ends[1],
                         knots=knots, pieces=pieces)

    def segment(inputs, stuck):
        """The segment's diffeqsolve; ``inputs``: every value it reads that may carry a
        derivative (see :func:`_pullback_where_used`)."""
        args, start, y, step, coeffs, ts, t1, dt = inputs
        outputs = diffrax.SubSaveAt(ts=jnp.clip(ts, start, t1), t1=True)
        # a chunk also saves its steps: where it ends on its step count, its state is its last accepted
        # step (diffrax's final state of a batch member whose loop ended while another member's event
        # fired is its dense output at the end of its last attempted step, which may have been rejected)
        saveat = diffrax.SaveAt(subs=[outputs] if chunk is None else [outputs, diffrax.SubSaveAt(steps=True)])
        # in chunks, each call's first step is the last chunk's mean step (diffrax's own choice, made
        # afresh at every call, is small: 16 % more steps on the press), without its derivative, as
        # diffrax takes its own first step: a derivative of the step grid moved d q(T)/d mu of the
        # slider-crank's batch by 2.4e-6 at rtol 1e-10 from the single run's
        dt0 = jax.lax.stop_gradient(step) if chunk is not None else None if dt is None else jnp.asarray(dt, dtype=float)
        kwargs = dict(t0=start, t1=t1, args=args, saveat=saveat, max_steps=settings.max_steps if chunk is None else chunk,
                      adjoint=adjoint_for(settings), throw=False)
        slip = lambda: unpacked(packing, diffrax.diffeqsolve(  # noqa: E731
            packed_term(packing, packed_vector_field), solver, stepsize_controller=lockup_controller(settings, packing),
            event=packed_event(packing, slip_event), y0=packing.pack(y), dt0=dt0, **kwargs))
        # a first step of its own: diffrax's choice would add a copy of the field (its friction solve) to the program
        hold = lambda: _states_only(diffrax.diffeqsolve(  # noqa: E731
            diffrax.ODETerm(_stuck_field), solver, stepsize_controller=controller_for(settings), event=breakaway,
            y0=(y, jnp.zeros(())), dt0=FIRST_STEP * (t1 - start) if dt0 is None else dt0,
            **(kwargs | dict(args=_held(args, coeffs)))))
        return jax.lax.cond(stuck, hold, slip) if holds else slip()

    def body(carry):
        start, y, previous, held, broke, saved, filled, steps, result, event, failed, step, last_ends, switched, reached, _ = carry
        # which way does the segment go: sign(w), or at rest (the start, a standstill, a
        # break-away) the only direction it can start in; unless the last segment found it held
        side, rates, slopes, coeffs = start_kinematics(model, start, y, settings.bridge)
        at_rest = y.omega == 0
        static_held = jnp.asarray(False)
        if static:  # static coefficients: they decide whether a rest holds, the kinetic ones the motion
            # (not just after a located break-away, whose margin is 0 to the root finder's tolerance);
            # solved only where some member rests (a segment from a switch of a Coulomb sign moves)
            tested = at_rest & ~broke

            def holds_at_rest():
                return rest_direction(*rest_analysis(model, start, y, settings.bridge, coeffs)[:2]) == 0

            static_held = tested & jax.lax.cond(eqxi.unvmap_any(tested), holds_at_rest, lambda: jnp.asarray(False))
        go = jnp.where(at_rest, jnp.where(held | static_held, 0.0, side), jnp.sign(y.omega))
        direction, stuck = jnp.where(go != 0, go, previous), (go == 0) & (not frictionless)
        # the signs of d phi_k/dq in the segment: those just ahead in the direction of motion, so
        # that a rate 0 to round-off (a switch just located, or a start on one) takes the sign it
        # goes on with
        signs = signs_ahead(rates, slopes, direction, y.q)
        # such an element starts just on that side: the event watches the smallest margin, and
        # one at or below 0 would hide every other crossing
        start_rates = None if frictionless else jnp.where(signs * rates > 0, rates, signs * 1e-200)
        y_start, direction = y._replace(friction_rates=start_rates), jnp.where(static_held, 0.0, direction)
        block_ends = _block_signs(model, start, y_start, direction, settings.bridge, signs, last_ends, switched) if blocks else None
        # held by the static coefficients with no stick segment to follow: a slip segment that
        # does not move (direction 0), refused at its first step
        knots = pieces = None
        if knotted:  # the next knots, and the pieces the segment runs on up to them
            bounds, in_omega = jnp.array([-jnp.inf, jnp.inf]), jnp.zeros((0, 2))
            if tables[2]:  # omega goes either way: its piece is the one it goes on into past a knot just
                # reached (``reached``: +1 or -1), else the one it leaves a rest into, or any (on no knot)
                omega_side = jnp.where(reached != 0, reached, jnp.where(direction != 0, direction, 1.0))
                bounds, in_omega = piece_around(tables[2], y.omega, omega_side)
            knots = jnp.concatenate([jnp.stack([next_knot(tables[0], y.q, direction) if tables[0] else jnp.inf,
                                                next_knot(tables[1], start, 1.0) if tables[1] else jnp.inf]), bounds])
            pieces = jnp.concatenate([pieces_at(tables[0], y.q, direction), pieces_at(tables[1], start, 1.0), in_omega])
        args = segment_args(y_start, direction, signs, block_ends, knots, pieces)
        inputs = (args, start, y_start, step, coeffs, ts, t1, dt)
        # reverse mode with friction: a jam's segment is not differentiated (see _pullback_where_used)
        if kind == "lax" or frictionless:
            run = segment(inputs, stuck)
        elif chunk is not None:  # a batch: the pullback's cond is a select there (see _relinearized_where_used)
            run = _relinearized_where_used(inputs, segment, stuck)
        else:
            run = _pullback_where_used(inputs, segment, stuck)
        sol = _Saved(run.ts[0], run.ys[0], run.event_mask, run.result, run.stats)
        last = jnp.sum(jnp.isfinite(sol.ts)) - 1
        end = sol.ts[last]
        y_end = jax.tree.map(lambda z: z[last], sol.ys)
        more, accepted = jnp.asarray(False), sol.stats["num_accepted_steps"]
        if chunk is not None:  # a chunk that used its steps: the segment goes on in the next call, while the budget lasts
            more = sol.result == diffrax.RESULTS.max_steps_reached
            # its accepted steps, not the saved steps' last row: with an event in the call diffrax
            # appends its final state there, an interpolation at the end of the last attempt (NaN
            # where that attempt met NaN: a member stopped by a friction jam beside one whose event fired)
            stopped = more | ~finished(RESULTS.promote(sol.result))
            end = jnp.where(stopped, jnp.where(accepted > 0, run.ts[1][accepted - 1], start), end)
            y_end = jax.tree.map(lambda z, s, z0: jnp.where(stopped, jnp.where(accepted > 0, s[accepted - 1], z0), z),
                                 y_end, run.ys[1], y._replace(friction_rates=start_rates))
        steps = steps + sol.stats["num_steps"]
        segment_event, segment_result = jnp.asarray(NO_EVENT), RESULTS.promote(sol.result)
        if chunk is not None:
            segment_result = RESULTS.where(more & (steps < settings.max_steps), RESULTS.successful, segment_result)
        if settings.check_assembly:
            ok_end = assembles(model.mechanism, y_end.q, y_end.omega, near(model, y_end))
            segment_event, segment_result = lockup_found(segment_event, segment_result, ok_end)
        # a start from rest that did not start (its first step ended at rest, see LockupController):
        # the friction holds it, from here on
        # (without stick segments a start is stuck only where the static coefficients hold it)
        refused = (at_rest & (~stuck if holds else True) & (segment_result == RESULTS.dt_min_reached) & (accepted == 0)
                   & (not frictionless))
        segment_result = RESULTS.where(refused, RESULTS.successful, segment_result)
        end = jnp.where(refused, start, end)
        y_end = jax.tree.map(lambda z_end, z: jnp.where(refused, z, z_end), y_end, y._replace(friction_rates=start_rates))
        inside = (ts >= start) & (ts <= end) & ~filled & ~refused
        # a time at the end takes the end's state: a chunk's row there is the dense output of its
        # last attempt, NaN for a member stopped by a jam at its start (end = start)
        def save(old, new, z_end):
            return jnp.where(_expand(inside, old), jnp.where(_expand(ts == end, old), z_end, new[:-1]), old)

        # a slip segment's samples keep its direction: where its motion dies away (w -> 0+ as a motor
        # stalls at the band's edge) w dips past 0 by the solution's error between step ends (no
        # standstill event), and the outputs read the other direction's friction there (dw/dt +21.7
        # rad/s^2 where w fell by 3e-7 rad/s^2); such a w is 0 within the tolerance
        ys = sol.ys._replace(omega=jnp.where(direction * sol.ys.omega < 0, 0.0, sol.ys.omega))
        saved = jax.tree.map(save, saved, ys, y_end)
        filled = filled | inside
        fired = jnp.asarray(False if sol.event_mask is None else sol.event_mask)  # a stick segment's: break-away or user
        # a stick segment stopped by a user event (its margins are read only where there are any)
        hold_code = (hold_codes[jnp.argmin(jnp.stack(stuck_margins(end, y_end, _held(args, coeffs))))]
                     if holds and settings.events else NO_EVENT)
        code = jnp.where(fired, jnp.where(stuck, hold_code, which_event(sol, slip_settings, args, last)), NO_EVENT)
        locked = ~stuck & (segment_event == LOCKUP)
        failed = jnp.where(locked, jnp.argmin(ok_end), failed) if settings.check_assembly else failed
        rest = code == STANDSTILL
        y_next = y_end._replace(omega=jnp.where(rest, jnp.zeros_like(y_end.omega), y_end.omega))
        # held at rest: refused, or a stick segment going on in the next chunk
        held = refused | (stuck & more)
        # the run's own end: a user event; with stop='standstill' the first rest (or a start held at rest)
        held_start = first_rest & refused
        ends = (code >= USER) | (first_rest & rest) | held_start
        event = jnp.where(locked, LOCKUP, jnp.where(ends, jnp.where(held_start, STANDSTILL, code), event))
        # held where nothing varies in time: for good (filled to t1 below); else a stick segment follows
        done = (~fired & ~more & ~(refused & holds)) | locked | (end >= t1) | ~finished(segment_result) | ends
        result = RESULTS.where(finished(result), segment_result, result)
        # the chunk's mean step (not a stick segment's: its steps follow the loads, not the motion)
        step = jnp.where((accepted > 0) & ~stuck, (end - start) / jnp.maximum(accepted, 1), step)
        # a knot of a table in omega reached: the bound omega ended nearer to (a q or t knot: omega on none)
        if tables[2]:
            reached = jnp.where((code == KNOT) & ~stuck,
                                jnp.where(knots[3] - y_end.omega < y_end.omega - knots[2], 1.0, -1.0), 0.0)
        return (end, y_next, direction, held, stuck & fired, saved, filled, steps, result, event, failed, step,
                last_ends if block_ends is None else block_ends[0],
                code == END_SWITCH, reached, done)

    def cond(carry):
        return ~carry[-1]

    y0 = y0._replace(friction_rates=None if frictionless else jnp.zeros(k_elements))  # set at each segment's start
    packing = packing_of(y0, settings.adjoint, solver)
    saved0 = jax.tree.map(lambda z: jnp.broadcast_to(z, (n,) + jnp.shape(z)).astype(float), y0)
    carry = (t0, y0, jnp.asarray(1.0), jnp.asarray(False), jnp.asarray(False), saved0, jnp.zeros(n, dtype=bool), jnp.asarray(0),
             RESULTS.successful, jnp.asarray(NO_EVENT), jnp.asarray(-1), jnp.asarray(FIRST_STEP * (t1 - t0) if dt is None else dt,
                                                                                  dtype=float), jnp.zeros((k_elements, 2)),
             jnp.asarray(False), jnp.asarray(0.0), jnp.asarray(False))
    segments = MAX_KNOTTED_SEGMENTS if knotted else MAX_SEGMENTS
    calls = segments if chunk is None else segments + -(-settings.max_steps // chunk)
    end, y_end, _, held, _, saved, filled, steps, result, event, failed, _, _, _, _, done = eqxi.while_loop(
        cond, body, carry, max_steps=calls, kind=kind)
    result = RESULTS.where(done | ~finished(result), result, RESULTS.max_segments_reached)
    # a traced static coefficient below the kinetic one (checked on the host where it is concrete):
    # say so (values out of range or not finite: _solve.friction_result, on every path)
    result = RESULTS.where(static_in_order(model.loads), result, RESULTS.static_below_kinetic)
    if not holds and not first_rest:  # held at rest from the last standstill (or the start) to t1
        held = held & (event != LOCKUP) & finished(result)
        rest = held & (ts >= end)
        saved = jax.tree.map(lambda old, z: jnp.where(_expand(rest, old), z, old), saved, y_end)
        filled, end = filled | rest, jnp.where(held, t1, end)
    # the times reached, then the final state where it lies past them; the rest repeat it
    # (every output stays finite)
    past = end > jnp.max(jnp.where(filled, ts, -jnp.inf))
    valid = filled | ((jnp.arange(n) == jnp.sum(filled)) & past)
    saved = jax.tree.map(lambda z, z_end: jnp.where(_expand(filled, z), z, z_end), saved, y_end)
    t = jnp.where(filled, ts, end)
    sol = Solution(
        t=t, q=saved.q, omega=saved.omega, **no_outputs(), dissipated=saved.dissipated, work=saved.work, valid=valid,
        t_final=end, q_final=y_end.q, omega_final=y_end.omega,
        t_stop=jnp.where(event >= 0, end, jnp.inf), event=event, failed_group_index=failed,
        result=result, num_steps=steps,
    )
    return sol, saved.branch


# a block end's load at a segment's start within this share of the largest is taken as 0: just
# past an event on it (located to the root finder's tolerance), on either side of its root
END_ROUNDOFF = 1e-8
# the margins' cushion at a segment's start, per unit of the largest load: above the friction
# solve's own tolerance (1e-12), which is what the event's recomputed loads differ by; as small
# as that, since a segment runs on its frozen branch this far past the kink (with 1e-8 the
# press's d q(0.45 s)/d mu was 3.4e-6 off at rtol 1e-12, with 1e-13 1.6e-6)
END_CUSHION = 1e-11
# a flipped end (its load x0 on its old side, s x0 < 0) has the frozen law differ from the law
# as read by 2 |x0| in that pair's normal load, which moves every end's load by that times the
# friction's gain (the slider-crank's: 0.05): the floors give way by this many times the
# flipped loads (without it a margin started at -2.6e-11 and hid every later crossing: the run
# went on with stale signs, q(0.5 s) 1.2 rad off)
FLIP_ALLOWANCE = 4.0


def _block_signs(model: Model, t, y: State, direction, bridge, rate_signs, last, switched):
    """(signs (K, 2), floors (K, 2)) of a slip segment's block ends (``FieldArgs.end_signs``,
    ``end_floor``): the signs of their loads x0 at its start, with the law as written; a load 0
    to round-off takes the sign it goes on with: just after its own switch (``switched``, the last
    segment ended on one) the last segment's flipped, else +1 (a wrong guess ends the segment at
    its first step, and the next one flips it). Floors: min(s x0, 0) less END_CUSHION of the
    largest load and FLIP_ALLOWANCE times the flipped ends' loads, so that each margin
    s x - floor starts > 0 (the event recomputes x0 with the signs frozen, which moves it by
    the solve's tolerance, and where an end is flipped by the law's change; a margin at or
    below 0 at the start would hide every crossing)."""
    # the signs are discrete, and the floors the margins' fixed offsets: no derivatives
    loads = block_loads(*constant((with_block_signs(model, jnp.zeros_like(last)), t, y, direction)), bridge,
                        constant(rate_signs))
    loads = jnp.where(jnp.isfinite(loads), loads, 0.0)  # a jam at the start: the run stops there anyway
    read, largest = jnp.where(loads >= 0, 1.0, -1.0), jnp.max(jnp.abs(loads))
    signs = jnp.where((jnp.abs(loads) <= END_ROUNDOFF * largest) & switched & (last != 0), -last, read)
    signs = jnp.where(np.array([f.kind == "P" for f in frictions_of(model.loads)])[:, None], signs, 0.0)
    behind = jnp.minimum(signs * loads, 0.0)  # < 0 at the flipped ends only
    return signs, behind - END_CUSHION * largest + FLIP_ALLOWANCE * jnp.sum(behind) - 1e-200


class _Saved(NamedTuple):
    """A segment's solution as the rest of the loop reads it: the saved times and states
    (the requested times, then the end), whether an event fired, the result, the stats."""

    ts: jax.Array
    ys: State
    event_mask: jax.Array | None
    result: RESULTS
    stats: dict


def _expand(mask, like):
    return mask.reshape(mask.shape + (1,) * (jnp.ndim(like) - 1))


# past a stopped motion's end, its friction is tested where q moved by these x LOCKUP_RESOLUTION (1 + |q|):
# up to 1e4 (~2e-5 rad), where a Painleve jam's effective inertia goes to 0 only just past the end
JAM_PROBES = (1.0, 10.0, 100.0, 1e3, 1e4)


def with_jam_status(sol: Solution, model: Model, settings: Settings) -> Solution:
    """A run with joint friction that stopped on NaN ahead (``dt_min_reached``, no lock-up)
    where the friction of its motion has no consistent solution at or just past its end, or
    that ended held at rest where the friction can neither hold it nor start it (see
    :func:`jammed_members`): ``jammed`` True and a status naming the jam, and the limit
    position just ahead if there is one (on the host, compiled only for such a run: a run
    ending held at rest is tested there); else ``jammed`` False. A jam at rest ends the run
    at its first sample of that rest, as a failure."""
    if not jammed_members(sol, model):
        return replaced(sol, jammed=False, status=sol.status + _held_words(sol, model) + _standstill_words(sol, model)
                        + _stiff_smoothing_words(sol, model))
    q, omega = float(sol.q_final), float(sol.omega_final)
    if omega == 0:
        return _ended_at_rest_jam(sol)
    limit = limit_ahead(model.mechanism, q, omega, JAM_LIMIT_PROBES) if settings.branch == "fixed" else None
    return replaced(sol, jammed=True, status=jam_text(float(sol.t_final), q, omega, limit,
                                                      reversing=None if limit else reversing_pairs(model, q)))


def reversing_pairs(model: Model, q: float) -> list[str]:
    """The friction elements whose relative motion changes direction at q (their d phi/dq 0
    within LOOKAHEAD of q, a Coulomb switch just located): where a jam follows such a switch,
    the pairs whose friction turned round."""
    rates, slopes = (np.asarray(v) for v in _rates_at(model, jnp.asarray(q, dtype=float)))
    turns = (slopes != 0) & (np.abs(rates) <= np.abs(slopes) * LOOKAHEAD * (1.0 + abs(q)))  # not a pair that never slips
    return [f.pair for f, reverses in zip(frictions_of(model.loads), turns) if reverses]


@jit
def _rates_at(model: Model, q):
    """The friction elements' d phi_k/dq and d2 phi_k/dq2 at q."""
    coeffs = kinematic_coefficients(model, State(q, jnp.zeros_like(q)))
    return rates_and_slopes(model.mechanism, frictions_of(model.loads), coeffs)[:2]


def _held_words(sol: Solution, model: Model) -> str:
    """What a run that reached t1 at rest adds to its status where the joint friction holds
    it there (its exact law): held throughout, or since its last motion (between two
    samples: the rest's own time is not kept); '' otherwise."""
    if (not has_exact_law(model.loads) or float(sol.omega_final) != 0.0 or int(sol.event) != NO_EVENT
            or int(result_code(sol.result)) not in FINISHED):
        return ""
    t, omega = np.asarray(sol.t), np.asarray(sol.omega)
    moving = np.flatnonzero(omega != 0.0)
    if not moving.size:
        return ", held at rest by the joint friction throughout"
    last = int(moving[-1])
    if last + 1 >= t.size:
        return ""
    return f", held at rest by the joint friction since between the samples at t = {t[last]:.6g} and {t[last + 1]:.6g} s"


def _standstill_words(sol: Solution, model: Model) -> str:
    """What a run stopped at its first standstill (``stop='standstill'``) adds to its status
    with the joint friction's exact law: whether the friction holds the mechanism there, or
    it is a turning point the motion goes on from (as a run without the stop would), read
    from its last sample's dw/dt (0 where held, else the break-away's: the outputs' own
    analysis at rest); '' otherwise, or without dw/dt among the outputs."""
    if (not has_exact_law(model.loads) or int(sol.event) != STANDSTILL or float(sol.omega_final) != 0.0
            or sol.domega is None or not np.size(sol.t) or float(np.asarray(sol.t)[-1]) != float(sol.t_final)):
        return ""
    alpha = float(np.asarray(sol.domega)[-1])
    if alpha == 0.0:
        return ", held there by the joint friction"
    way = "forward" if alpha > 0 else "backward"
    return f", a turning point: the joint friction does not hold it there, and the motion goes on {way} (stop=None runs on)"


# a smoothed element whose relative rate is within this many smoothing speeds of 0 is in its stiff band
STIFF_BAND = 10.0


def _stiff_smoothing_words(sol: Solution, model: Model) -> str:
    """What a run that used up its step budget adds to its status where it ended within a few
    smoothing speeds of rest in some smoothed element: there the regularized law's friction
    turns from -F to F over a relative rate of ~v_s, a field as stiff as F / (J_red v_s), which
    an explicit solver crosses in steps of that scale (the slider-crank held by mu = 0.8:
    v_s = 1e-3 ran to t1 in ~700 steps, 1e-4 used up 4096 by t = 0.11 s); '' otherwise."""
    if int(result_code(sol.result)) != MAX_STEPS:
        return ""
    frictions = frictions_of(model.loads)
    if not any(f.smoothing is not None for f in frictions):
        return ""
    rates = np.asarray(_rates_at(model, jnp.asarray(float(sol.q_final)))[0]) * float(sol.omega_final)
    stiff = [f for f, rate in zip(frictions, rates)
             if f.smoothing is not None and abs(rate) <= STIFF_BAND * float(f.smoothing)]
    if not stiff:
        return ""
    named = ", ".join(f"'{f.pair}' (v_s = {float(f.smoothing):.3g})" for f in stiff)
    return (f"; it ended creeping within {STIFF_BAND:g} smoothing speeds of rest in {named}, where the regularized "
            "friction turns over a relative rate of ~v_s and the motion is stiff in proportion to 1 / v_s: raise the "
            "smoothing speed, or give those elements the exact law (no smoothing), whose stiction holds a mechanism "
            "at rest without steps")


def _ended_at_rest_jam(sol: Solution) -> Solution:
    """``sol`` cut at its first sample of the rest it ended in (the run held it from about
    there), as a run that stopped at a jam: no motion follows from there."""
    t, q, omega = (np.asarray(v) for v in (sol.t, sol.q, sol.omega))
    moving = np.flatnonzero((omega != 0) | (q != sol.q_final))
    first = int(moving[-1]) + 1 if moving.size else 0
    cut = saved_rows(sol, slice(0, first + 1))
    return replaced(cut, jammed=True, t_final=t[first], result=RESULTS.dt_min_reached, event=np.asarray(NO_EVENT),
                    t_stop=None, status=jam_text(float(t[first]), float(sol.q_final), 0.0))


# a jam this near (x (1 + |q|)) before a limit position is that position's: a toggle self-locks
# where its force line enters the pins' friction circles (a triple rocker with 10 mm pins: 5e-5 rad)
JAM_LIMIT_PROBES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)


def jammed_members(sols: Solution, model: Model, *, models_batched: bool = False) -> np.ndarray:
    """Which runs (host arrays: one run or a batch) the joint friction jams: with friction,
    stopped on NaN ahead while moving where the friction of that motion has no consistent
    solution at the end or just past it; or ended held at rest (at t1, or a start held with
    ``stop='standstill'``) where the friction at its limits cannot hold it and the motion
    its loads start has no consistent friction either
    (:func:`~assurjax.dynamics._field.rest_jams`: the segments take such a rest as held).
    One program for all members of each kind, compiled only where some member is such a
    run. ``models_batched``: ``model``'s arrays carry the batch axis too (a batch of
    mechanisms, ``batch_simulate``)."""
    codes, omega = result_code(sols.result), np.asarray(sols.omega_final)
    jams = np.zeros(codes.shape, dtype=bool)
    if not frictions_of(model.loads):
        return jams
    moving = (codes == DT_MIN) & (omega != 0.0)
    event, t_first = np.asarray(sols.event), np.asarray(sols.t)[..., 0] if np.size(sols.t) else np.asarray(sols.t_final)
    held = np.isin(codes, FINISHED) & (omega == 0.0) & ((event == NO_EVENT) | ((event == STANDSTILL) & (sols.t_final == t_first)))
    t, q, w = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (sols.t_final, sols.q_final, sols.omega_final))
    if np.any(moving):
        jams |= moving & np.asarray(_jams_each(model, t, q, w) if models_batched else _jams(model, t, q, w)).reshape(codes.shape)
    if np.any(held) and len(frictions_of(model.loads)) == 1:  # several elements: no jam claimed (see rest_jams)
        jams |= held & np.asarray(_rest_jams_each(model, t, q) if models_batched else _rest_jams(model, t, q)).reshape(codes.shape)
    return jams


def _jams_at(model: Model, t, q, omega):
    """Whether the friction of the motion in sign(omega) has no consistent solution at
    (t, q, omega) or a little way along it (the JAM_PROBES, extrapolated with dw/dt there),
    where the loads are finite at all of them: a load that turns NaN (a user's function)
    stops the run too, and is no jam."""
    direction = jnp.sign(omega)
    at_end = frictional(model, t, State(q, omega), direction, iterate=False)
    h = jnp.asarray(JAM_PROBES) * LOCKUP_RESOLUTION * (1.0 + jnp.abs(q)) / jnp.abs(omega)
    alpha = jnp.where(jnp.isfinite(at_end.alpha), at_end.alpha, 0.0)

    def probe(h):
        f = frictional(model, t + h, State(q + omega * h, omega + alpha * h), direction, iterate=False)
        return f.consistent, _loads_finite(f)

    ahead, finite = jax.vmap(probe)(h)
    return ~(at_end.consistent & jnp.all(ahead)) & _loads_finite(at_end) & jnp.all(finite)


def _loads_finite(f) -> jax.Array:
    """Whether the reduction a friction analysis stands on (the loads' generalized force, the
    reduced inertia) is finite."""
    return all_finite((f.red.force, f.red.inertia))


def _rest_jams_at(model: Model, t, q):
    """:func:`~assurjax.dynamics._field.rest_jams` at (t, q), from finite values only."""
    jams, finite = rest_jams(model, t, State(q, jnp.zeros_like(q)))
    return jams & finite


@jit
def _rest_jams(model: Model, t, q):
    return jax.vmap(lambda t, q: _rest_jams_at(model, t, q))(t, q)


@jit
def _rest_jams_each(models: Model, t, q):
    return jax.vmap(_rest_jams_at)(models, t, q)


@jit
def _jams(model: Model, t, q, omega):
    """:func:`_jams_at` per run (arrays), one model."""
    return jax.vmap(lambda t, q, omega: _jams_at(model, t, q, omega))(t, q, omega)


@jit
def _jams_each(models: Model, t, q, omega):
    """:func:`_jams_at` per run (arrays), each with its model (batched arrays)."""
    return jax.vmap(_jams_at)(models, t, q, omega)


@eqx.filter_custom_vjp
def _pullback_where_used(inputs, f, *rest):
    """``f(inputs, *rest)``, whose pullback runs only where some cotangent of its outputs is
    not 0. A segment that ended in a jam has outputs nothing reads (the run's value there is
    NaN, its derivative 0), and NaN partials at its rejected steps: its pullback sent 0 x NaN
    on to the earlier segments (lineax raised inside their event root finds). Exact: a zero
    cotangent pulls back to zero. (A loss on the samples a jam's segment saved before the jam
    reads its outputs: its pullback runs, as before.)"""
    return f(inputs, *rest)


@_pullback_where_used.def_fwd
def _pullback_where_used_fwd(perturbed, inputs, f, *rest):
    out, pullback = eqx.filter_vjp(lambda x: f(x, *rest), inputs)
    return out, (pullback, _zeros_like_inexact(out))


@_pullback_where_used.def_bwd
def _pullback_where_used_bwd(residuals, cotangents, perturbed, inputs, f, *rest):
    pullback, zeros = residuals
    cotangents, used = _cotangents_and_use(zeros, cotangents)
    grads = jax.lax.cond(used, lambda: pullback(cotangents)[0], lambda: _zeros_like_inexact(inputs))
    return jax.tree.map(lambda g, p: g if p else None, grads, perturbed, is_leaf=lambda x: x is None)


@eqx.filter_custom_vjp
def _relinearized_where_used(inputs, f, *rest):
    """:func:`_pullback_where_used` for a batch (a vmap being traced): there its ``lax.cond``
    is a select, which runs the pullback for every member, and the jammed member's NaN
    partials reached lineax, which raised for the whole batch. Here nothing is linearized in
    the forward pass; the pullback linearizes ``f`` again, at ``inputs`` where some cotangent
    is not 0 and elsewhere at :func:`_emptied` inputs (a segment of no length), and returns 0 there.
    Exact as the other; the price is one more forward solve of each segment in reverse mode."""
    return f(inputs, *rest)


@_relinearized_where_used.def_fwd
def _relinearized_where_used_fwd(perturbed, inputs, f, *rest):
    out = f(inputs, *rest)
    return out, _zeros_like_inexact(out)


@_relinearized_where_used.def_bwd
def _relinearized_where_used_bwd(zeros, cotangents, perturbed, inputs, f, *rest):
    cotangents, used = _cotangents_and_use(zeros, cotangents)
    grads = eqx.filter_vjp(lambda x: f(x, *rest), _emptied(inputs, unless=used))[1](cotangents)[0]
    grads = jax.tree.map(lambda g: None if g is None else jnp.where(used, g, jnp.zeros_like(g)), grads)
    return jax.tree.map(lambda g, p: g if p else None, grads, perturbed, is_leaf=lambda x: x is None)


def _cotangents_and_use(zeros, cotangents):
    """The cotangents with 0 for those JAX passes as None, and whether any is not 0."""
    cotangents = jax.tree.map(lambda z, c: None if z is None else z if c is None else c, zeros, cotangents,
                              is_leaf=lambda x: x is None)
    found = jax.tree.leaves(cotangents)
    return cotangents, jnp.any(jnp.stack([jnp.any(c != 0) for c in found])) if found else jnp.asarray(False)


def _emptied(inputs, unless):
    """A segment's inputs (see ``segment`` in :func:`stick_slip`), ending where it starts
    unless ``unless``."""
    args, start, y, step, coeffs, ts, t1, dt = inputs
    return args, start, y, step, coeffs, ts, jnp.where(unless, t1, start), dt


def _zeros_like_inexact(tree):
    """Zeros for each floating-point array of ``tree``, None for every other leaf."""
    return jax.tree.map(lambda x: jnp.zeros_like(x) if eqx.is_inexact_array(x) else None, tree)
