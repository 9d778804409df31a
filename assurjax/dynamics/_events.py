"""Stop conditions of a simulation, as one diffrax.Event, and the assembly checks at its ends.

Standstill (w crosses 0 against the direction of motion), user conditions
``cond(t, q, omega)`` (stop when they change sign) and, with joint friction, a change of
sign of some element's d phi_k/dq (its Coulomb sign switches: the segment ends there,
``_stick``); each is a margin that is positive until it fires. A group that can no
longer assemble needs no event: the vector field is NaN there and the step-size
controller closes in on it (``_settings.lockup_controller``).
"""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._friction import frictions_of
from .._positions import assembled
from ._field import FieldArgs, State, end_margins
from ._results import END_SWITCH, KNOT, LOCKUP, NO_EVENT, RATE_SWITCH, RESULTS, STANDSTILL, USER
from ._settings import Settings

_SCALE = 1e-30  # see located_event
_FLOOR = 1e-200  # see margins


def margins(settings: Settings, t, y: State, args: FieldArgs) -> list:
    """One margin per enabled stop condition, positive until that condition fires.

    standstill: w times the direction of motion, the sign of w0, or from rest the
    displacement q - q0 (0 at the start, > 0 while moving, < 0 once w has reversed:
    no force evaluation at t0 is needed to know which way the mechanism starts);
    user events: cond(t, q, w) times its sign at t0; rate switches (a state with
    ``friction_rates``): the smallest d phi_k/dq times its sign frozen for the segment,
    over the elements with a Coulomb coefficient (the others do not switch);
    block-end switches (``args.end_signs``): the smallest of a slip segment's prismatic
    pairs' block-end loads times their frozen signs (``_field.end_margins``); knots
    (``args.knots``): the distance to the next knot of the loads' tables, in q, t or omega.
    """
    out = []
    if settings.standstill:  # a hair above 0 at a start from rest, so that it hides no other crossing there
        out.append(y.omega * jnp.where(args.direction != 0, args.direction, y.q - args.q0) + _FLOOR)
    out += user_margins(settings, t, y, args)
    if y.friction_rates is not None:
        out.append(jnp.min(rate_margins(args, y.friction_rates)))
    if args.end_signs is not None:
        out.append(jnp.min(end_margins(t, y, args)))
    if args.knots is not None:
        out.append(knot_margin(t, y, args))
    return out


def knot_margin(t, y: State, args: FieldArgs):
    """The distance to the next knot of the loads' tables: in q, ahead in the segment's
    direction (none at rest), in t, and in omega to either of the piece's bounds (it may go
    either way); positive until one is reached."""
    # no knot in q (inf): none ahead either way (moving down, direction * (inf - q) is -inf, which
    # hid every other crossing: the segment ran past its t and omega knots on its first piece)
    in_q = jnp.where((args.direction != 0) & jnp.isfinite(args.knots[0]), args.direction * (args.knots[0] - y.q), jnp.inf)
    in_omega = jnp.minimum(y.omega - args.knots[2], args.knots[3] - y.omega)
    return jnp.minimum(jnp.minimum(in_q, args.knots[1] - t), in_omega)


def user_margins(settings: Settings, t, y: State, args: FieldArgs) -> list:
    """Per user event: cond(t, q, w) times its sign at t0; +inf where NaN (it cannot fire
    there, and in the smallest margin a NaN kept every other event from firing)."""
    found = [args.user_signs[k] * jnp.asarray(cond(t, y.q, y.omega), dtype=float) for k, cond in enumerate(settings.events)]
    return [jnp.where(jnp.isnan(m), jnp.inf, m) for m in found]


def rate_margins(args: FieldArgs, friction_rates):
    """Per friction element: d phi_k/dq times its sign frozen for the segment, positive
    until it changes sign; inf for the elements that cannot switch (no Coulomb
    coefficient, a smoothed law, or a rate 0 with slope 0 at the segment's start)."""
    frictions = frictions_of(args.model.loads)
    coulomb = (jnp.stack([f.coefficient for f in frictions]) > 0) & np.array([f.smoothing is None for f in frictions])
    return jnp.where(coulomb & (args.rate_signs != 0), args.rate_signs * friction_rates, jnp.inf)


def event_codes(settings: Settings, switches: bool = False, ends: bool = False, knots: bool = False) -> tuple[int, ...]:
    codes = [STANDSTILL] if settings.standstill else []
    return tuple(codes + [USER + k for k in range(len(settings.events))] + ([RATE_SWITCH] if switches else [])
                 + ([END_SWITCH] if ends else []) + ([KNOT] if knots else []))


def stop_event(settings: Settings, switches: bool = False, ends: bool = False, knots: bool = False):
    """One event on the smallest margin (:func:`located_event`). None when no condition is
    enabled. ``switches``: the state carries ``friction_rates`` (their sign changes end the run);
    ``ends``: the arguments carry frozen block-end signs (their loads' sign changes end it);
    ``knots``: the arguments carry the next knots of the loads' tables (reaching one ends it)."""
    if not event_codes(settings, switches, ends, knots):
        return None
    return located_event(lambda t, y, args: jnp.min(jnp.stack(margins(settings, t, y, args))), settings)


def located_event(margin, settings: Settings) -> diffrax.Event:
    """A diffrax.Event where ``margin(t, y, args)`` falls from > 0 to <= 0, located by
    bisection on the dense output (no right-hand-side evaluations). The margin is scaled
    far below the bisection's atol: the bisection stops on the interval's width alone,
    whichever side of the crossing it ends on, and the located time keeps its derivative
    (diffrax differentiates it implicitly, through the margin's slopes)."""
    tol = min(1e-3 * settings.rtol, 1e-12)
    # relative to t no finer than a few of its float spacings: finer, the bisection could not end
    # (at rtol 1e-13, or in float32, a run stopped where a pin's relative rate changed sign)
    spacing = 4.0 * float(jnp.finfo(jnp.result_type(float)).eps)
    return diffrax.Event(lambda t, y, args, **kwargs: _SCALE * margin(t, y, args),
                         optx.Bisection(rtol=max(tol, spacing), atol=tol, flip=True), direction=False)


def which_event(sol, settings: Settings, args: FieldArgs, last):
    """The code of the stop condition that fired (the smallest margin at the stop), or -1."""
    codes = event_codes(settings, sol.ys.friction_rates is not None, args.end_signs is not None, args.knots is not None)
    if not codes:
        return jnp.asarray(NO_EVENT)
    y_final = jax.tree.map(lambda y: y[last], sol.ys)
    found = margins(settings, sol.ts[last], y_final, args)
    return jnp.where(sol.event_mask, jnp.asarray(codes)[jnp.argmin(jnp.stack(found))], NO_EVENT)


def lockup_found(event, result, ok_final):
    """(event, result) of a run whose steps closed in on a configuration where some group
    cannot assemble (``dt_min_reached`` from ``_settings.lockup_controller``, and a group
    failing just past the final state): the lock-up event."""
    locked = (result == RESULTS.dt_min_reached) & ~jnp.all(ok_final)
    return jnp.where(locked, LOCKUP, event), RESULTS.where(locked, RESULTS.event_occurred, result)


def assembles(mechanism, q_final, w_final, near=None):
    """Per group: assembled at the final state and just past it (in the direction of motion)."""
    both = jax.vmap(lambda q: assembled(mechanism, q, near=near))(jnp.stack([_just_past(q_final, w_final), q_final]))  # one copy
    return both[0] & both[1]


def _just_past(q_final, w_final):
    return q_final + 1e-9 * (1.0 + jnp.abs(q_final)) * jnp.sign(w_final)


def checked_states(y0: State, q_final, w_final, branch_final):
    """(q, stacked branch or None) of the states whose assembly a run checks: just past the
    final state in the direction of motion, the final state, the start."""
    stack = lambda *v: jnp.stack([jnp.asarray(x, dtype=float) for x in v])  # noqa: E731
    branch = None if branch_final is None else stack(branch_final, branch_final, y0.branch)
    return stack(_just_past(q_final, w_final), q_final, y0.q), branch
