"""Stop conditions of a simulation, as one diffrax.Event.

Standstill (w crosses 0 against the direction of motion), a group that can no longer
assemble, and user conditions ``cond(t, q, omega)`` (stop when they change sign); each
is a margin that is positive until it fires.
"""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import optimistix as optx

from .._positions import assembled
from ._field import FieldArgs, State, near
from ._results import LOCKUP, NO_EVENT, STANDSTILL, USER
from ._settings import Settings

_TINY = 1e-30


def margins(settings: Settings, t, y: State, args: FieldArgs, lockup=None) -> list:
    """One margin per enabled stop condition, positive until that condition fires.

    standstill: w times the direction of motion, the sign of w0, or from rest the
    displacement q - q0 (0 at the start, > 0 while moving, < 0 once w has reversed:
    no force evaluation at t0 is needed to know which way the mechanism starts);
    assembly: +1 while every group assembles, -1 once one cannot; user events:
    cond(t, q, w) times its sign at t0. ``lockup``: the assembly margin when already
    known (then no position analysis here).
    """
    out = []
    if settings.standstill:
        out.append(y.omega * jnp.where(args.direction != 0, args.direction, y.q - args.q0))
    if settings.check_assembly:
        if lockup is None:
            ok = assembled(args.model.mechanism, y.q, near=near(args.model, y))
            lockup = jnp.where(jnp.all(ok), 1.0, -_TINY)
        out.append(lockup)
    for k, cond in enumerate(settings.events):
        out.append(args.user_signs[k] * jnp.asarray(cond(t, y.q, y.omega), dtype=float))
    return out


def event_codes(settings: Settings) -> tuple[int, ...]:
    codes = [STANDSTILL] if settings.standstill else []
    codes += [LOCKUP] if settings.check_assembly else []
    return tuple(codes + [USER + k for k in range(len(settings.events))])


def stop_event(settings: Settings):
    """One diffrax.Event on the smallest margin (down-crossing), located by bisection
    on the dense output: the assembly margin is a step, and bisection needs no
    right-hand-side evaluations. None when no condition is enabled."""
    if not event_codes(settings):
        return None

    def cond_fn(t, y, args, **kwargs):
        # Clipped at a tiny positive value: the bisection's |f| < atol test then holds
        # on both sides of a step (the assembly margin), and the root is the first crossing.
        return jnp.minimum(jnp.min(jnp.stack(margins(settings, t, y, args))), _TINY)

    tol = min(1e-3 * settings.rtol, 1e-12)
    return diffrax.Event(cond_fn, optx.Bisection(rtol=tol, atol=tol, flip=True), direction=False)


def which_event(sol, settings: Settings, args: FieldArgs, last, ok_final):
    """The code of the stop condition that fired (the smallest margin at the stop), or -1.
    The assembly condition is read at and just past the final state, since bisection
    may leave that state on the assembled side."""
    codes = event_codes(settings)
    if not codes:
        return jnp.asarray(NO_EVENT)
    y_final = jax.tree.map(lambda y: y[last], sol.ys)
    lockup = jnp.where(jnp.all(ok_final), 1.0, -1.0) if settings.check_assembly else None
    found = margins(settings, sol.ts[last], y_final, args, lockup)
    return jnp.where(sol.event_mask, jnp.asarray(codes)[jnp.argmin(jnp.stack(found))], NO_EVENT)


def assembles(mechanism, q_final, w_final, near=None):
    """Per group: assembled at the final state and just past it (in the direction of motion)."""
    nudge = 1e-9 * (1.0 + jnp.abs(q_final)) * jnp.sign(w_final)
    both = jax.vmap(lambda q: assembled(mechanism, q, near=near))(jnp.stack([q_final + nudge, q_final]))  # one copy
    return both[0] & both[1]
