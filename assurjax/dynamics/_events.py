"""Stop conditions of a simulation, as one diffrax.Event, and the assembly checks at its ends.

Standstill (w crosses 0 against the direction of motion) and user conditions
``cond(t, q, omega)`` (stop when they change sign); each is a margin that is positive
until it fires. A group that can no longer assemble needs no event: the vector field is
NaN there and the step-size controller closes in on it (``_settings.lockup_controller``).
"""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import optimistix as optx

from .._positions import assembled
from ._field import FieldArgs, State
from ._results import LOCKUP, NO_EVENT, RESULTS, STANDSTILL, USER
from ._settings import Settings

_TINY = 1e-30


def margins(settings: Settings, t, y: State, args: FieldArgs) -> list:
    """One margin per enabled stop condition, positive until that condition fires.

    standstill: w times the direction of motion, the sign of w0, or from rest the
    displacement q - q0 (0 at the start, > 0 while moving, < 0 once w has reversed:
    no force evaluation at t0 is needed to know which way the mechanism starts);
    user events: cond(t, q, w) times its sign at t0.
    """
    out = []
    if settings.standstill:
        out.append(y.omega * jnp.where(args.direction != 0, args.direction, y.q - args.q0))
    for k, cond in enumerate(settings.events):
        out.append(args.user_signs[k] * jnp.asarray(cond(t, y.q, y.omega), dtype=float))
    return out


def event_codes(settings: Settings) -> tuple[int, ...]:
    codes = [STANDSTILL] if settings.standstill else []
    return tuple(codes + [USER + k for k in range(len(settings.events))])


def stop_event(settings: Settings):
    """One diffrax.Event on the smallest margin (down-crossing), located by bisection
    on the dense output (no right-hand-side evaluations). None when no condition is enabled."""
    if not event_codes(settings):
        return None

    def cond_fn(t, y, args, **kwargs):
        # Clipped at a tiny positive value: the bisection's |f| < atol test then holds
        # on both sides of the crossing, and the root is the first crossing.
        return jnp.minimum(jnp.min(jnp.stack(margins(settings, t, y, args))), _TINY)

    tol = min(1e-3 * settings.rtol, 1e-12)
    return diffrax.Event(cond_fn, optx.Bisection(rtol=tol, atol=tol, flip=True), direction=False)


def which_event(sol, settings: Settings, args: FieldArgs, last):
    """The code of the stop condition that fired (the smallest margin at the stop), or -1."""
    codes = event_codes(settings)
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


def checked_states(t0, y0: State, t_final, q_final, w_final, branch_final):
    """(t, q, w, stacked branch or None) of the states whose assembly a run checks: just
    past the final state in the direction of motion, the final state, the start."""
    stack = lambda *v: jnp.stack([jnp.asarray(x, dtype=float) for x in v])  # noqa: E731
    branch = None if branch_final is None else stack(branch_final, branch_final, y0.branch)
    return (stack(t_final, t_final, t0), stack(_just_past(q_final, w_final), q_final, y0.q), stack(w_final, w_final, y0.omega),
            branch)
