"""Durango et al.'s (2014) own integration scheme (Euler in q, Durango et al. 2014 eq. 2): a labelled baseline for benchmarks."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import AssurjaxError
from .._jit import jit
from .._loads import check_loads
from .._reduction import reduce_single
from .._values import check_value
from ._settings import check_single_start, setting_problem


class SeedEulerSolution(NamedTuple):
    """Durango et al.'s (2014) Euler-in-q baseline: samples every ``dq`` of travel. ``t`` (s), ``q``,
    ``omega`` (rad/s), ``t_stop`` (s, None if no standstill within ``t1`` or the
    step budget). ``valid`` marks the steps taken."""

    t: Array
    q: Array
    omega: Array
    valid: Array
    t_stop: Any
    status: str


@jit
def _seed_euler_core(mechanism, gravity, loads, q0, omega0, t0, t1, dq, n_steps: int, standstill: bool):
    """Seed 000 eq. 2 by jax.lax.scan: w_{i+1}^2 = (J_i w_i^2 + 2 (tau + tau_red)_i dq) / J_{i+1},
    with q stepping by dq in the direction of motion and dt = dq / mean(|w_i|, |w_{i+1}|)."""
    red = lambda q, w, t: reduce_single(mechanism, gravity, loads, q, w, t)  # noqa: E731
    r0 = red(q0, omega0, t0)
    a0 = r0.acceleration(omega0)
    s = jnp.where(omega0 != 0, jnp.sign(omega0), jnp.sign(a0))
    step = s * dq

    def body(carry, _):
        q, w2, t, j, moving = carry
        r = red(q, s * jnp.sqrt(w2), t)
        q_next = q + step
        j_next = red(q_next, s * jnp.sqrt(w2), t).inertia
        w2_next = (j * w2 + 2.0 * (r.effort + r.torque) * step) / j_next
        stops = w2_next <= 0.0
        dt = dq / (0.5 * (jnp.sqrt(w2) + jnp.sqrt(jnp.maximum(w2_next, 0.0))))
        dt = jnp.where(stops, 2.0 * dq / jnp.maximum(jnp.sqrt(w2), 1e-300), dt)  # decelerate to rest within the step
        t_next = t + dt
        go = moving & (t_next <= t1) & ~(stops & standstill)
        new = (jnp.where(go, q_next, q), jnp.where(go, jnp.maximum(w2_next, 0.0), w2), jnp.where(go, t_next, t),
               jnp.where(go, j_next, j), go)
        stopped_here = moving & stops & standstill & (t_next <= t1)
        return new, (new[0], s * jnp.sqrt(new[1]), new[2], go, stopped_here, t_next)

    init = (q0, omega0**2, t0, r0.inertia, jnp.asarray(True))
    _, (q, w, t, go, stopped, t_hit) = jax.lax.scan(body, init, None, length=n_steps)
    t_stop = jnp.where(jnp.any(stopped), t_hit[jnp.argmax(stopped)], jnp.inf)
    return q, w, t, go, t_stop


def simulate_seed_euler(mechanism, gravity, loads, q0, omega0, *, t0=0.0, t1=1.0, dq=1e-3, standstill=True, max_steps=None) -> SeedEulerSolution:
    """Durango et al.'s scheme (Euler in q with a fixed step ``dq`` rad, Durango et al. 2014 eq. 2) — a
    labelled baseline for benchmarks, first order in ``dq``. Integrates until ``t1``,
    the first standstill (``standstill=True``) or ``max_steps`` steps of ``dq``
    (default: 20 000; at most 1 000 000)."""
    check_single_start(q0, omega0, t0, t1)
    check_value(AssurjaxError, "simulate_seed_euler: dq", dq, shape=(), positive=True)
    if float(dq) > 1.0:
        raise AssurjaxError(f"simulate_seed_euler: dq is a step in q (rad or m), at most 1, got {float(dq):g}")
    if max_steps is not None and (problem := setting_problem("steps", max_steps)) is not None:
        raise AssurjaxError(f"simulate_seed_euler: max_steps: {problem}")
    n = int(max_steps or 20000)
    loads = tuple(loads)
    check_loads(mechanism, loads)
    q, w, t, go, t_stop = _seed_euler_core(mechanism, jnp.asarray(gravity, dtype=float), loads, jnp.asarray(q0, dtype=float),
                                          jnp.asarray(omega0, dtype=float), jnp.asarray(t0, dtype=float),
                                          jnp.asarray(t1, dtype=float), jnp.asarray(dq, dtype=float), n, bool(standstill))
    k = int(np.sum(np.asarray(go)))
    q = jnp.concatenate([jnp.asarray(q0, dtype=float)[None], q[:k]])
    w = jnp.concatenate([jnp.asarray(omega0, dtype=float)[None], w[:k]])
    t = jnp.concatenate([jnp.asarray(t0, dtype=float)[None], t[:k]])
    ts = float(t_stop) if np.isfinite(float(t_stop)) else None
    if ts is not None:
        status = f"standstill at t = {ts:.9g} s"
    elif k < n and float(w[-1]) == 0.0:
        status = (f"stopped at t = {float(t[-1]):.9g} s after {k} steps: omega reached 0, which Euler in q cannot "
                  "pass (a standstill; the scheme steps q in one direction)")
    elif k < n:
        status = f"reached t1 = {float(t1):g} s after {k} steps"
    else:
        status = f"stopped at t = {float(t[-1]):.9g} s after {k} steps: max_steps = {n} used up before t1"
    return SeedEulerSolution(t=t, q=q, omega=w, valid=jnp.ones(k + 1, dtype=bool), t_stop=ts, status=status)
