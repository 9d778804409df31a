"""Ready-made synthesis problems (designs + objectives) used by the examples and benchmarks."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import AssemblyError, AssurjaxError
from ._design import Design
from ._dynamic import standstill_time
from ._linkages import roberts_like
from ._objectives import coupler_curve, straight_line_deviation

ROBERTS_Q0 = math.acos(1.0 / 3.0)  # the Roberts linkage's symmetric position (seed 001)


def straight_line_problem(lengths, *, stroke: float = 0.26, q0: float = ROBERTS_Q0, spread: float = 0.3, samples: int = 41):
    """Straight-line synthesis of a Roberts-type four-bar (seed 001).

    Design variables: the six lengths (AD, AB, DC, BC, BP, CP) in m, each free
    within ``(1 -/+ spread)`` times its start value, and the x position (m) of the
    middle of the ``stroke`` (m) of coupler point P, within 0.1 m of its start.
    The start centre is the middle of the stretch of x that P sweeps monotonically
    on the branch through ``q0`` (so a perturbed linkage starts with a reachable stroke).

    Returns ``(design, objective)`` for :func:`optimize` (with ``has_aux=True``):
    the objective is the smooth straight-line deviation (m); its aux holds the
    exact ``deviation`` (m) and the ``ok`` flag.
    """
    lengths = jnp.asarray(lengths, dtype=float)
    c0 = _reachable_centre(roberts_like(lengths), q0, stroke)
    design = Design((lengths, jnp.asarray(c0)), lambda t: (t[0], t[1]),
                    lower=(lengths * (1 - spread), c0 - 0.1), upper=(lengths * (1 + spread), c0 + 0.1))

    def objective(t):
        lengths, centre = t
        line = straight_line_deviation(roberts_like(lengths), "P", stroke=stroke, q0=q0, center=centre, samples=samples)
        return line.smooth, {"ok": line.ok, "deviation": line.deviation}

    return design, objective


def _reachable_centre(mechanism, q0: float, stroke: float, half_width: float = 1.5, n: int = 601) -> float:
    grid = q0 + np.linspace(-half_width, half_width, n)
    pts, ok = coupler_curve(mechanism, "P", grid)
    x, ok = np.asarray(pts[:, 0]), np.asarray(ok)
    i0 = (n - 1) // 2
    dx = np.diff(x)
    good = ok[:-1] & ok[1:] & (dx * np.sign(dx[i0]) > 0)
    right = i0
    while right < n - 1 and good[right]:
        right += 1
    left = i0
    while left > 0 and good[left - 1]:
        left -= 1
    lo, hi = sorted((x[left], x[right]))
    margin = 0.02 * stroke
    if hi - lo < stroke + 2 * margin:
        raise AssemblyError(
            f"straight-line problem: coupler point P sweeps only {1e3 * (hi - lo):.1f} mm monotonically on the branch "
            f"through q0 = {q0:.4g}, less than the {1e3 * stroke:.0f} mm stroke"
        )
    return float(np.clip(x[i0], lo + stroke / 2 + margin, hi - stroke / 2 - margin))


def add_point_mass(mechanism, link: str, mass, position):
    """The mechanism with a point mass (kg) fixed to ``link`` at ``position`` (m, in the
    link's frame): the link's mass, centre of mass and inertia about it become those
    of the combination (parallel-axis theorem):

        m = m_l + m_c,  G = (m_l G_l + m_c P) / m,  J = J_l + m_l |G_l - G|^2 + m_c |P - G|^2.
    """
    if link not in mechanism.links:
        raise AssurjaxError(f"add_point_mass: unknown link {link!r} (known: {sorted(mechanism.links)})")
    body = mechanism.links[link]
    position = jnp.asarray(position, dtype=float)
    total = body.mass + mass
    com = (body.mass * body.com + mass * position) / total
    inertia = body.inertia + body.mass * jnp.sum((body.com - com) ** 2) + mass * jnp.sum((position - com) ** 2)
    return eqx.tree_at(lambda m: (m.links[link].mass, m.links[link].com, m.links[link].inertia), mechanism,
                       (total, com, inertia))


def standstill_time_problem(scene, target: float, *, link: str | None = None, mass=(0.5, 0.05, 3.0),
                            position=(-0.3, -0.8, 0.8), t1: float | None = None, adjoint: str = "quadrature", **settings):
    """Reach a target standstill time (synthesis problem 3, seed 000's standstill):
    choose a counterweight on the driving link so that the first standstill after the
    scene's initial state (from rest: released under its loads) happens at ``target`` (s).

    Design variables: the counterweight's mass (kg) and its position (m) along the x
    axis of the driving link's frame (negative: behind the pivot), each given as
    ``(start, lower, upper)``. ``link``: the driving link (default: the driver's).
    ``t1``: the simulation horizon (default ``1.5 * target``, at least the scene's t1).

    The objective is the squared relative error ((t* - target) / target)^2; its gradient
    goes through the simulation and the standstill event (implicit function theorem on
    omega(t*) = 0, forward sensitivities: ``adjoint``, see :func:`standstill_time`).
    Aux: ``standstill`` (s), ``ok`` (a standstill happened before ``t1``). The
    sensitivity routes do not check assembly along the motion: check the final design
    with :func:`assurjax.simulate`. Returns ``(design, objective, build)``; ``build(values)``
    gives the scene with the counterweight.

    **Example** (the Watt six-bar stops at 1.385 s; make it 1.6 s):
    >>> design, objective, build = syn.standstill_time_problem(assurjax.load_scene("watt_sixbar"), 1.6)
    >>> result = syn.optimize(design, objective, optax.adam(0.2), 200, has_aux=True, target=1e-8)
    >>> result.history.aux["standstill"][-1], result.values   # s; (kg, m)
    """
    if not target > 0:
        raise AssurjaxError(f"standstill_time_problem: target must be a positive time (s), got {target}")
    link = scene.mechanism.driver.links[0] if link is None else link
    horizon = max(1.5 * target, float(scene.state.get("t1", 0.0))) if t1 is None else t1
    base = (jnp.asarray(mass[0], dtype=float), jnp.asarray(position[0], dtype=float))
    design = Design(base, lambda v: v, lower=(mass[1], position[1]), upper=(mass[2], position[2]))

    def build(values):
        m, x = values
        mech = add_point_mass(scene.mechanism, link, m, jnp.stack([x, jnp.zeros_like(x)]))
        return eqx.tree_at(lambda s: s.mechanism, scene, mech)

    def objective(values):
        trial = build(values)
        t_star, fired = standstill_time(trial, t1=horizon, adjoint=adjoint, **settings)
        return ((t_star - target) / target) ** 2, {"ok": fired, "standstill": t_star}

    return design, objective, build

