"""Ready-made synthesis problems (designs + objectives) used by the examples and benchmarks."""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import AssemblyError, AssurjaxError
from .._values import check_value, check_values
from ._design import Design
from ._dynamic import SENSITIVITY_ROUTES, _check_start, _checked_table, _route, _settings, standstill_time
from ._sensitivity import _options
from ._linkages import roberts_like
from ._objectives import coupler_curve, line_pose, straight_line_deviation

ROBERTS_Q0 = math.acos(1.0 / 3.0)  # the Roberts linkage's symmetric position (Fanghella et al. 2019)


LENGTH_NAMES = ("AD", "AB", "DC", "BC", "BP", "CP")


class StraightLineObjective(eqx.Module):
    """The objective of :func:`straight_line_problem`: ``objective(values)`` or
    ``objective(values, params)`` -> (smooth deviation in m, aux).

    ``values`` = (six lengths, stroke centre[, line pose (y0 m, angle rad)]);
    ``params["sharpness"]`` (optional) overrides the smooth maximum's sharpness
    (a continuation schedule in :func:`optimize`). Aux: ``deviation`` (m, exact),
    ``span`` (m, the x range the samples cover) and ``ok``. Its numbers are arrays,
    so problems differing only in them share one compiled program.
    """

    stroke: jax.Array
    q0: jax.Array
    sharpness: jax.Array
    line: Any
    samples: int = eqx.field(static=True)
    drive: str = eqx.field(static=True)
    free_line: bool = eqx.field(static=True)

    def __call__(self, values, params=None):
        lengths, centre = values[0], values[1]
        p = self.sharpness if params is None or "sharpness" not in params else params["sharpness"]
        if self.free_line:
            line = ((0.0, values[2][0]), values[2][1])
        elif self.line is None:
            line = None
        else:
            line = ((self.line[0], self.line[1]), self.line[2])
        result = straight_line_deviation(roberts_like(lengths), "P", stroke=self.stroke, q0=self.q0, center=centre,
                                         samples=self.samples, p=p, line=line, drive=self.drive)
        return result.smooth, {"ok": result.ok, "deviation": result.deviation, "span": jnp.max(result.x) - jnp.min(result.x)}


def straight_line_problem(lengths, *, stroke: float = 0.26, q0: float = ROBERTS_Q0, spread: float = 0.3, lower=None, upper=None,
                          fixed=(), samples: int = 41, line=None, frame: str = "fixed", drive: str = "x",
                          centre_range: float | None = None, sharpness: float = 50.0):
    """Straight-line synthesis of a Roberts-type four-bar (Fanghella et al. 2019).

    Design variables (``values`` = a tuple):
    - the six lengths (AD, AB, DC, BC, BP, CP) in m (see :func:`roberts_like`),
      each within ``(1 -/+ spread)`` times its start value (relative bounds) or
      within absolute ``lower``/``upper`` (six values, m); ``fixed``: names of
      lengths (or ``"centre"``) that stay at their start values (e.g. ``("AD",)``);
    - the middle of the stroke: with ``drive="x"`` (the driving-dimension
      formulation, recommended) global x of the coupler point P (m, within
      ``centre_range``, default 0.1 m, of its start: the middle of the stretch of
      x P sweeps monotonically on the branch through ``q0``), the stroke being
      ``stroke`` m of x; with ``drive="angle"`` the crank angle (rad, within
      ``centre_range``, default 0.5 rad, of ``q0``), the stroke being ``stroke``
      rad of crank angle (then how much x is covered is up to the design: aux
      ``span`` reports it, and an objective usually needs a coverage penalty);
    - with a given ``line`` and ``frame="free"``: the line's pose relative to the
      mechanism (y0 in m within 0.1 m, angle in rad within 0.2 rad), i.e. the
      frame placed freely relative to the line; ``frame="fixed"`` keeps the line.

    ``line``: ``None`` measures the deviation from the best (least-squares) line;
    a number c from y = c; ``((x0, y0), angle)`` from that line (see
    :func:`straight_line_deviation`). ``sharpness``: the smooth maximum's default
    sharpness (a schedule's ``"sharpness"`` overrides it).

    Returns ``(design, objective)`` for :func:`optimize` (with ``has_aux=True``):
    the objective (a :class:`StraightLineObjective`) is the smooth straight-line
    deviation (m); its aux holds the exact ``deviation`` (m), ``span`` and ``ok``.

    **Example:**
    >>> design, objective = syn.straight_line_problem(lengths, stroke=0.2, line=0.0, frame="free")
    >>> result = syn.optimize(design, objective, optax.lbfgs, 300, has_aux=True, schedule={"sharpness": [50., 300., 2000.]})
    """
    lengths = jnp.asarray(lengths, dtype=float)
    if lengths.shape != (6,):
        raise AssurjaxError(f"straight_line_problem: lengths must be the six lengths {LENGTH_NAMES} (m), got shape {lengths.shape}")
    if frame not in ("fixed", "free"):
        raise AssurjaxError(f"straight_line_problem: frame must be 'fixed' or 'free', got {frame!r}")
    if drive not in ("x", "angle"):
        raise AssurjaxError(f"straight_line_problem: drive must be 'x' or 'angle', got {drive!r}")
    unknown = [f for f in fixed if f not in LENGTH_NAMES + ("centre",)]
    if unknown:
        raise AssurjaxError(f"straight_line_problem: unknown fixed length(s) {unknown} (known: {LENGTH_NAMES})")
    if drive == "x":
        c0, width = _reachable_centre(roberts_like(lengths), q0, stroke), 0.1 if centre_range is None else centre_range
    else:
        c0, width = float(q0), 0.5 if centre_range is None else centre_range
    lo = lengths * (1 - spread) if lower is None else jnp.broadcast_to(jnp.asarray(lower, dtype=float), (6,))
    hi = lengths * (1 + spread) if upper is None else jnp.broadcast_to(jnp.asarray(upper, dtype=float), (6,))
    base, lows, highs = [lengths, jnp.asarray(c0)], [lo, c0 - width], [hi, c0 + width]
    given = None if line is None else _line_array(line)
    free_line = frame == "free" and line is not None
    if free_line:
        base.append(jnp.stack([given[1] - given[0] * jnp.tan(given[2]), given[2]]))
        lows.append(base[2] - jnp.array([0.1, 0.2]))
        highs.append(base[2] + jnp.array([0.1, 0.2]))
    mask = (jnp.array([n in fixed for n in LENGTH_NAMES]), "centre" in fixed) + (False,) * (len(base) - 2)
    design = Design(tuple(base), _whole, lower=tuple(lows), upper=tuple(highs), fixed=mask)
    objective = StraightLineObjective(stroke=jnp.asarray(stroke, dtype=float), q0=jnp.asarray(q0, dtype=float),
                                      sharpness=jnp.asarray(sharpness, dtype=float), line=given, samples=samples,
                                      drive=drive, free_line=free_line)
    return design, objective


def _whole(values):
    return values


def _line_array(line):
    """A given line as the array (x0, y0, angle)."""
    return jnp.array([float(v) for v in line_pose(line)])


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
    check_value(AssurjaxError, "add_point_mass: mass", mass, shape=(), nonnegative=True)  # a negative one may cancel the link's
    check_value(AssurjaxError, "add_point_mass: position", position, shape=(2,))
    body = mechanism.links[link]
    position = jnp.asarray(position, dtype=float)
    total = body.mass + mass
    com = (body.mass * body.com + mass * position) / total
    inertia = body.inertia + body.mass * jnp.sum((body.com - com) ** 2) + mass * jnp.sum((position - com) ** 2)
    return eqx.tree_at(lambda m: (m.links[link].mass, m.links[link].com, m.links[link].inertia), mechanism,
                       (total, com, inertia))


def standstill_time_problem(scene, target: float, *, link: str | None = None, mass=(0.5, 0.05, 3.0),
                            position=(-0.3, -0.8, 0.8), t1: float | None = None, adjoint: str = "quadrature", **settings):
    """Reach a target standstill time (synthesis problem 3, Durango et al.'s (2014) standstill):
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
    with :func:`assurjax.simulate`. Returns ``(design, objective, build)``: the objective
    a :class:`StandstillObjective` (its scene's arrays, the target and the horizon traced: the problem
    made again reuses the compiled loop), ``build(values)`` the scene with the counterweight.

    **Example** (the Watt six-bar stops at 1.385 s; make it 1.6 s):
    >>> design, objective, build = syn.standstill_time_problem(assurjax.load_scene("watt_sixbar"), 1.6)
    >>> result = syn.optimize(design, objective, optax.adam(0.2), 200, has_aux=True, target=1e-8)
    >>> result.history.aux["standstill"][-1], result.values   # s; (kg, m)
    """
    check_values(AssurjaxError, "standstill_time_problem", target=target, **({} if t1 is None else {"t1": t1}))
    if not target > 0:
        raise AssurjaxError(f"standstill_time_problem: target must be a positive time (s), got {target}")
    link = scene.mechanism.driver.links[0] if link is None else link
    if link not in scene.mechanism.links:
        raise AssurjaxError(f"standstill_time_problem: unknown link {link!r}; the mechanism has {list(scene.mechanism.links)}")
    horizon = max(1.5 * target, float(scene.state.get("t1", 0.0))) if t1 is None else t1
    if not horizon > target:  # the standstill at the target would lie past the horizon: no design could reach it
        raise AssurjaxError(f"standstill_time_problem: t1 = {horizon} s must lie past the target {target} s")
    for name, triple in (("mass", mass), ("position", position)):
        if not (isinstance(triple, (tuple, list)) and len(triple) == 3):
            raise AssurjaxError(f"standstill_time_problem: {name} must be (start, lower, upper), got {triple!r}")
        check_values(AssurjaxError, f"standstill_time_problem: {name}", start=triple[0], lower=triple[1], upper=triple[2])
    if not mass[1] >= 0:  # a negative counterweight may cancel the link's mass (add_point_mass)
        raise AssurjaxError(f"standstill_time_problem: the counterweight's mass is at least 0 kg: lower bound {mass[1]}")
    _check_start(scene, None, None, horizon, adjoint)  # the adjoint's name and the scene's start, before any run
    if adjoint in SENSITIVITY_ROUTES:  # a misspelt or out-of-range setting, before any run
        _options(scene, _route(adjoint, settings))
    else:
        _checked_table(scene, _settings(scene, settings, standstill=True, adjoint=adjoint))
    base = (jnp.asarray(mass[0], dtype=float), jnp.asarray(position[0], dtype=float))
    design = Design(base, lambda v: v, lower=(mass[1], position[1]), upper=(mass[2], position[2]))
    objective = StandstillObjective(scene=scene, target=jnp.asarray(target, dtype=float), link=link, horizon=jnp.asarray(horizon, dtype=float),
                                    adjoint=adjoint, settings=_plain_settings(settings))
    return design, objective, objective.build


class StandstillObjective(eqx.Module):
    """The objective of :func:`standstill_time_problem`: ``objective(values)`` ->
    (((t* - target) / target)^2, aux with ``standstill`` and ``ok``); ``build(values)``
    gives the scene with the counterweight. Its scene's arrays, the target and the horizon are traced,
    so the problem made again (a notebook cell run twice, a scene of the same structure,
    another target or horizon) reuses the optimizer's compiled loop."""

    scene: Any
    target: jax.Array
    horizon: jax.Array  # t1 (s); traced, as a new target's default horizon (1.5 x target) changes with it
    link: str = eqx.field(static=True)
    adjoint: str = eqx.field(static=True)
    settings: tuple = eqx.field(static=True)  # (name, value) pairs for standstill_time

    def build(self, values):
        m, x = values
        mech = add_point_mass(self.scene.mechanism, self.link, m, jnp.stack([x, jnp.zeros_like(x)]))
        return eqx.tree_at(lambda s: s.mechanism, self.scene, mech)

    def __call__(self, values):
        t_star, fired = standstill_time(self.build(values), t1=self.horizon, adjoint=self.adjoint, **dict(self.settings))
        return ((t_star - self.target) / self.target) ** 2, {"ok": fired, "standstill": t_star}


def _plain_settings(settings: dict) -> tuple:
    """The checked settings as (name, value) pairs, lists as tuples: hashable, for they are
    part of the compiled structure (``points=["E"]`` is a valid setting)."""
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in settings.items()))
