"""Stick and slip: a mechanism with Coulomb friction that comes to rest stays at rest
while the friction can hold it, and breaks away when the loads overcome it.

In a one-degree-of-freedom mechanism every relative rate is (d phi/dq) w, so at rest
the question is one of direction: with the kinetic friction signs of a motion in
direction s, the acceleration a_s (``dynamics._field.frictional``). The mechanism sticks
when neither direction accelerates away (a_+ <= 0 <= a_-); it breaks away, in the
direction s whose a_s points that way, when a time-dependent load makes that change.

The motion is integrated by diffrax in segments inside one ``lax.while_loop``: a slip
segment ends where w returns to 0 (a diffrax.Event located by root finding), a stick
segment (w = 0, q fixed) where the break-away margin max(a_+, -a_-) crosses 0 (another
Event). Each segment starts by deciding its direction (sign(w), or at rest the break-away test),
so the test is in the program once. Without loads that may vary in time a mechanism held at
rest stays held: the stick segment is left out, and the rest is filled to t1. Each segment
saves the requested times that fall inside it. Forward-mode
derivatives go through the loop; reverse mode does not (JAX cannot reverse a
while_loop): differentiate runs up to the first standstill, or use ``jax.jvp``.
"""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import optimistix as optx

from .._errors import AssurjaxError
from .._model import Model
from ._events import assembles, lockup_found, stop_event
from ._field import FieldArgs, State, near, directional_accelerations, rest_direction, vector_field
from ._results import LOCKUP, NO_EVENT, RESULTS, finished
from ._settings import Settings, adjoint_for, controller_for, lockup_controller, solver_for
from ._solution import Solution, outputs

MAX_SEGMENTS = 256  # stick and slip phases in one simulation
_TINY = 1e-30


def _stuck_field(t, y, args):
    return jax.tree.map(jnp.zeros_like, y)


def stick_slip(model: Model, q0, omega0, t0, t1, ts, dt, y0: State, settings: Settings) -> Solution:
    """The motion with stick and slip (see the module docstring); no user events."""
    if settings.events:
        raise AssurjaxError("user events are not supported yet with joint friction when the motion runs on past "
                            "standstill; use stop='standstill' or no events")
    solver, n = solver_for(settings), ts.shape[0]
    slip_settings = settings._replace(standstill=True)
    # without loads that vary in time a mechanism held at rest stays held: no stick segment
    # (and no break-away event, two copies of the friction solve) is needed in the program
    timeless = not any(load.may_depend_on_time() for load in model.loads)

    def breakaway_cond(t, y, args, **kwargs):
        a_plus, a_minus = directional_accelerations(args.model, t, y)
        return jnp.minimum(-jnp.maximum(a_plus, -a_minus), _TINY)  # > 0 while stuck

    tol = min(1e-3 * settings.rtol, 1e-12)
    breakaway = diffrax.Event(breakaway_cond, optx.Bisection(rtol=tol, atol=tol, flip=True), direction=False)

    def segment(start, y, direction, stuck):
        args = FieldArgs(model=model, table=None, direction=direction, q0=y.q, user_signs=None, bridge=settings.bridge,
                         nan_unassembled=settings.check_assembly)
        # held for good (nothing varies in time): a segment of length zero ends the loop
        stop = jnp.where(stuck, start, t1) if timeless else t1
        kwargs = dict(t0=start, t1=stop, dt0=None if dt is None else jnp.asarray(dt, dtype=float), y0=y, args=args,
                      saveat=diffrax.SaveAt(ts=jnp.clip(ts, start, stop), t1=True), max_steps=settings.max_steps,
                      adjoint=adjoint_for(settings), throw=False)
        slip = lambda: diffrax.diffeqsolve(diffrax.ODETerm(vector_field), solver, stepsize_controller=lockup_controller(settings),  # noqa: E731
                                           event=stop_event(slip_settings), **kwargs)
        hold = lambda: diffrax.diffeqsolve(diffrax.ODETerm(_stuck_field), solver,  # noqa: E731
                                           stepsize_controller=controller_for(settings), event=breakaway, **kwargs)
        return slip() if timeless else jax.lax.cond(stuck, hold, slip)

    def body(carry):
        start, y, previous, _, saved, filled, k, steps, result, event, failed, _ = carry
        # which way does the segment go: sign(w), or at rest (the start, a standstill, a
        # break-away) the direction the mechanism accelerates in, if any (else it sticks)
        a_plus, a_minus = directional_accelerations(model, start, y._replace(omega=jnp.zeros_like(y.omega)))
        go = jnp.where(y.omega != 0, jnp.sign(y.omega), rest_direction(a_plus, a_minus))
        direction, stuck = jnp.where(go != 0, go, previous), go == 0
        sol = segment(start, y, direction, stuck)
        last = jnp.sum(jnp.isfinite(sol.ts)) - 1
        end = sol.ts[last]
        y_end = jax.tree.map(lambda z: z[last], sol.ys)
        inside = (ts >= start) & (ts <= end) & ~filled
        saved = jax.tree.map(lambda old, new: jnp.where(_expand(inside, old), new[:-1], old), saved, sol.ys)
        filled = filled | inside
        fired = jnp.asarray(False) if sol.event_mask is None else jnp.asarray(sol.event_mask)
        segment_event, segment_result = jnp.asarray(NO_EVENT), RESULTS.promote(sol.result)
        if settings.check_assembly:
            ok_end = assembles(model.mechanism, y_end.q, y_end.omega, near(model, y_end))
            segment_event, segment_result = lockup_found(segment_event, segment_result, ok_end)
        locked = ~stuck & (segment_event == LOCKUP)
        failed = jnp.where(locked, jnp.argmin(ok_end), failed) if settings.check_assembly else failed
        y_next = y_end._replace(omega=jnp.where(fired, jnp.zeros_like(y_end.omega), y_end.omega))
        done = ~fired | locked | (end >= t1) | ~finished(segment_result)
        result = RESULTS.where(finished(result), segment_result, result)
        event = jnp.where(locked, LOCKUP, event)
        return (end, y_next, direction, stuck, saved, filled, k + 1, steps + sol.stats["num_steps"], result, event, failed,
                done)

    def cond(carry):
        return ~carry[-1] & (carry[6] < MAX_SEGMENTS)

    saved0 = jax.tree.map(lambda z: jnp.broadcast_to(z, (n,) + jnp.shape(z)).astype(float), y0)
    carry = (t0, y0, jnp.asarray(1.0), jnp.asarray(False), saved0, jnp.zeros(n, dtype=bool), jnp.asarray(0),
             jnp.asarray(0), RESULTS.successful, jnp.asarray(NO_EVENT), jnp.asarray(-1), jnp.asarray(False))
    end, y_end, _, stuck, saved, filled, _, steps, result, event, failed, _ = jax.lax.while_loop(cond, body, carry)
    if timeless:  # held at rest from the last standstill (or the start) to t1
        held = stuck & (event != LOCKUP) & finished(result)
        rest = held & (ts >= end)
        saved = jax.tree.map(lambda old, z: jnp.where(_expand(rest, old), z, old), saved, y_end)
        filled, end = filled | rest, jnp.where(held, t1, end)
    valid = filled  # the times reached; the rest repeat the last one reached
    last = jnp.maximum(jnp.sum(valid) - 1, 0)
    pick = lambda z: None if z is None else jnp.where(valid, z, z[last])  # noqa: E731
    t, q, w = jnp.where(valid, ts, end), pick(saved.q), pick(saved.omega)
    values = outputs(model, t, q, w, settings)
    return Solution(
        t=t, q=q, omega=w, **values, dissipated=pick(saved.dissipated), work=pick(saved.work), valid=valid,
        t_final=end, q_final=y_end.q, omega_final=y_end.omega,
        t_stop=jnp.where(event >= 0, end, jnp.inf), event=event, failed_group_index=failed,
        result=result, num_steps=steps,
    )


def _expand(mask, like):
    return mask.reshape(mask.shape + (1,) * (jnp.ndim(like) - 1))

