"""Differentiable simulation results: the final state theta(T) and the standstill time.

Both wrap the pure, jittable ``simulate_core`` (diffrax) and take gradients with
the adjoint named by ``adjoint``:

- ``"recursive"`` (diffrax.RecursiveCheckpointAdjoint, the default): reverse mode,
  exact gradients of the computed solution (discretize-then-optimize); best for
  many parameters (the whole mechanism) and one scalar result.
- ``"forward"`` (diffrax.ForwardMode): forward mode (``jax.jvp``/``jax.jacfwd``);
  best for a few parameters or directional derivatives.
- ``"backsolve"`` (diffrax.BacksolveAdjoint): solves the adjoint ODE backwards in
  time, O(1) memory, gradients only to the solver tolerance; no events.

See benchmarks/bench_gradients.py for measured costs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._reduction import reduce_single


def _core():
    from .._dynamics import Settings, simulate_core

    return Settings, simulate_core


def final_state(scene, t1, *, q0=None, omega0=None, adjoint: str = "recursive", **settings):
    """(q(T), omega(T)) of the scene's motion from its initial state to ``t1`` (s),
    without stop events; differentiable with respect to every array of ``scene``
    (mechanism parameters, gravity, load values). ``settings``: fields of the
    dynamics Settings (``solver``, ``rtol``, ``atol``, ``dt``, ``max_steps``)."""
    Settings, simulate_core = _core()
    opts = Settings(**{"samples": 2, "domega": False, "check_assembly": False, **settings, "standstill": False, "adjoint": adjoint})
    state = scene.state
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    sol = simulate_core(scene.mechanism, scene.gravity, scene.loads, q0, omega0, state.get("t0", 0.0), t1, settings=opts)
    return sol.q_final, sol.omega_final


def standstill_time(scene, *, t1=None, q0=None, omega0=None, adjoint: str = "recursive", **settings):
    """The first time (s) at which the driving link comes to rest (omega = 0 against
    its direction of motion), and an ok flag (False: no standstill before ``t1``).

    The derivative follows the implicit function theorem on omega(t*, p) = 0
    (seed 000's standstill, differentiated):

        dt*/dp = -(d omega / dp at fixed t) / (d omega / dt at t*),

    built as t* - (omega(t*) - stop_gradient(omega(t*))) / stop_gradient(alpha(t*)),
    which is correct whether or not the event location itself carries a gradient.
    """
    Settings, simulate_core = _core()
    opts = Settings(**{"samples": 2, "domega": False, **settings, "standstill": True, "adjoint": adjoint})
    state = scene.state
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    t1 = state.get("t1", 1.0) if t1 is None else t1
    sol = simulate_core(scene.mechanism, scene.gravity, scene.loads, q0, omega0, state.get("t0", 0.0), t1, settings=opts)
    red = reduce_single(scene.mechanism, scene.gravity, scene.loads, sol.q_final, sol.omega_final, sol.t_final)
    alpha = (red.effort + red.torque - 0.5 * red.dinertia * sol.omega_final**2) / red.inertia
    alpha = jax.lax.stop_gradient(alpha)
    w = sol.omega_final
    t_star = sol.t_final - (w - jax.lax.stop_gradient(w)) / jnp.where(alpha == 0, 1.0, alpha)
    return t_star, sol.event == 0
