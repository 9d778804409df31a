"""Building blocks of synthesis objectives: coupler curves, transmission angles, assembly
margins, straight-line deviation (Fanghella et al. 2019), precision points, driving torque.

All are pure JAX functions of a Mechanism (jit/vmap/grad-able); the ones that can
meet a configuration that does not assemble return ``ok`` flags next to their value.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array

from .._errors import AssurjaxError
from .._values import check_value
from .._geometry import cross, dot
from .._friction import frictions_of
from .._mechanism import Mechanism, positions
from .._model import Model
from ..groups import RRR


def coupler_curve(mechanism: Mechanism, point: str, q) -> tuple[Array, Array]:
    """Global positions (m) of ``point`` at each driving coordinate of ``q`` (shape ``q.shape + (2,)``),
    and one ok flag per q (False: some group it depends on cannot assemble)."""
    q = jnp.asarray(q, dtype=float)
    pose = jax.vmap(lambda qi: positions(mechanism, qi, points=(point,)))(q.reshape(-1))
    return pose.points[point].reshape(q.shape + (2,)), jnp.all(pose.ok, axis=-1).reshape(q.shape)


def transmission_angles(mechanism: Mechanism, q) -> dict[str, Array]:
    """Transmission angle mu (rad) of every RRR dyad at the driving coordinate ``q``:
    the angle at the internal joint J between the dyad's two links, in (0, pi)
    when the dyad assembles (mu -> 0 or pi at its toggle positions, where it stops
    assembling). mu = atan2(mode * (E1 - J) x (E2 - J), (E1 - J) . (E2 - J))."""
    q = jnp.asarray(q, dtype=float)
    pose = positions(mechanism, q)
    out = {}
    for g in mechanism.groups:
        if isinstance(g, RRR):
            e1, e2, j = (pose.points[p] for p in g.joints)
            a, b = e1 - j, e2 - j
            out[g.name] = jnp.arctan2(g.mode * cross(a, b), dot(a, b))
    if not out:
        raise AssurjaxError(f"mechanism '{mechanism.name}' has no RRR dyad: no transmission angle to report")
    return out


def assembly_margin(mechanism: Mechanism, q) -> Array:
    """min over RRR dyads of sin(mu): positive while every dyad assembles, 0 at a toggle
    position. A smooth measure of how far a design is from losing assembly (use it as
    a barrier or a constraint)."""
    mus = transmission_angles(mechanism, q)
    return jnp.min(jnp.stack([jnp.sin(m) for m in mus.values()]), axis=0)


# --------------------------------------------------------------------------- straight-line deviation


class StraightLine(eqx.Module):
    """Result of :func:`straight_line_deviation` (lengths in m).

    ``deviation``: with the best line (``line=None``), half the width of the
    narrowest band parallel to the least-squares line that holds every sample,
    (max r - min r) / 2 (the minimum-zone straightness for the least-squares
    direction); with a given line, the largest distance max |r| from it;
    ``smooth``: the same with the extremes replaced by log-sum-exp soft maxima of
    sharpness ``p / max|r|`` (a differentiable stand-in, at most
    ``log(2 samples) max|r| / p`` above it, whose gradient is the derivative of
    its value); ``x``, ``y``: coupler point at the sample positions; ``q``: the
    driving coordinates there; ``residuals``: signed distances r from the line;
    ``ok``: every sample assembled (and, driving by x, was reached on the branch
    through ``q0``).
    """

    deviation: Array
    smooth: Array
    x: Array
    y: Array
    q: Array
    residuals: Array
    ok: Array


def straight_line_deviation(
    mechanism: Mechanism,
    point: str,
    *,
    stroke: float,
    q0: float,
    samples: int = 41,
    p: float = 50.0,
    search: tuple[float, int] = (1.5, 601),
    center=None,
    line=None,
    drive: str = "x",
) -> StraightLine:
    """How straight the path of ``point`` is over a stroke (Fanghella et al. 2019: < 1 mm over 260 mm).

    **Stroke.** ``drive="x"`` (the driving-dimension formulation, recommended for
    straight-line synthesis): the stroke is global ``x`` of the point from
    ``center - stroke/2`` to ``center + stroke/2`` (m; ``center`` defaults to x of
    the point at ``q0``), sampled at ``samples`` evenly spaced x. The driving
    coordinate of each sample is found on the branch through ``q0``: a scan of
    ``search = (half-width, points)`` around ``q0`` brackets it, Newton's method
    (optimistix) refines it, and gradients follow by the implicit function
    theorem (one Newton step at the converged root carries them: never through
    iterations, and no host callback in the differentiated program).
    ``drive="angle"``: the stroke is the crank angle from ``center - stroke/2``
    to ``center + stroke/2`` (rad; ``center`` defaults to ``q0``); the coverage of
    x is then up to the design, which usually needs a penalty.

    **Line.** ``line=None``: deviation from the best (least-squares) line;
    ``line=c`` (a number): from the line y = c (m); ``line=((x0, y0), angle)``:
    from the line through (x0, y0) (m) at ``angle`` (rad) from +x.

    ``p``: sharpness of the smooth maxima (may be traced, e.g. a continuation
    schedule in :func:`optimize`).

    **Example:**
    >>> line = straight_line_deviation(mech, "P", stroke=0.2, q0=1.23, line=0.0)
    >>> line.deviation   # m, the largest |y| of P over 200 mm of x
    """
    _check_stroke_request(stroke, q0, samples, p, search)
    q0 = jnp.asarray(q0, dtype=float)
    if drive == "x":
        q, pts, ok = _stroke_by_x(mechanism, point, stroke, q0, samples, search, center)
    elif drive == "angle":
        centre = q0 if center is None else jnp.asarray(center, dtype=float)
        q = centre + jnp.linspace(-0.5, 0.5, samples) * stroke
        pts, assembled = coupler_curve(mechanism, point, q)
        ok = jnp.all(assembled)
    else:
        raise AssurjaxError(f"straight_line_deviation: drive must be 'x' or 'angle', got {drive!r}")
    x, y = pts[:, 0], pts[:, 1]
    if line is None:
        r = _line_residuals(x, y)
        extremes = jnp.stack([r, -r])
    else:
        r = _given_line_residuals(x, y, line)
        extremes = jnp.concatenate([r, -r])[None]
    # the scale is differentiated too (no stop_gradient), so the gradient of `smooth` is the
    # derivative of its value (a stopped scale is off by up to ~log(samples)/p, a few per cent)
    highest = jnp.max(extremes, axis=1)  # max r and max -r (given line: max |r|); max |r| is their max
    sharpness = p / (jnp.max(highest) + 1e-300)
    smooth = jnp.mean(jax.vmap(lambda e: smooth_max(e, sharpness))(extremes))
    deviation = jnp.mean(highest)
    return StraightLine(deviation=deviation, smooth=smooth, x=x, y=y, q=q, residuals=r, ok=ok)


SAMPLES_LIMIT = 100_000  # of a stroke, and of its search scan: each is a position analysis


def _count_problem(n, least: int) -> str | None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        return f"must be a whole number, got {n!r}"
    return None if least <= n <= SAMPLES_LIMIT else f"must be from {least} to {SAMPLES_LIMIT:,}, got {n}"


def _check_stroke_request(stroke, q0, samples, p, search) -> None:
    """Raise naming a setting of :func:`straight_line_deviation` that is out of range (a zero
    stroke or one sample fitted a line to one point: NaN beside ok True)."""
    where = "straight_line_deviation"
    check_value(AssurjaxError, f"{where}: stroke", stroke, shape=(), positive=True)
    check_value(AssurjaxError, f"{where}: q0", q0, shape=())
    check_value(AssurjaxError, f"{where}: p", p, shape=(), positive=True)
    if (problem := _count_problem(samples, 2)) is not None:
        raise AssurjaxError(f"{where}: samples {problem}")
    if not (isinstance(search, (tuple, list)) and len(search) == 2):
        raise AssurjaxError(f"{where}: search must be (half-width, points), got {search!r}")
    check_value(AssurjaxError, f"{where}: search half-width", search[0], shape=(), positive=True)
    if (problem := _count_problem(search[1], 2)) is not None:
        raise AssurjaxError(f"{where}: search points {problem}")


def _stroke_by_x(mechanism, point, stroke, q0, samples, search, center):
    """Driving coordinates where ``point`` has evenly spaced x over the stroke, the point there,
    and whether every sample was found (assembled, on the branch through q0)."""
    if center is None:
        center = positions(mechanism, q0, points=(point,)).points[point][0]
    targets = center + jnp.linspace(-0.5, 0.5, samples) * stroke
    # no gradient into the search: the root carries none (below), and a guess with a tangent would
    # make JAX trace optimistix's implicit derivative only to discard it
    frozen, fixed_targets = jax.lax.stop_gradient((mechanism, targets))
    guess, bracketed = _bracket_on_branch(frozen, point, q0, fixed_targets, *search)
    # one point wanted: fused loops that re-derive the groups compile to fewer kernels (materialize=False)
    x_of = lambda q, t: positions(frozen, q, points=(point,), materialize=False).points[point][0] - t  # noqa: E731
    solver = optx.Newton(rtol=1e-12, atol=1e-13)
    sol = jax.vmap(lambda g, t: optx.root_find(x_of, solver, g, args=t, max_steps=32, throw=False))(guess, fixed_targets)
    root = jax.lax.stop_gradient(sol.value)

    # The root is found without gradients; one Newton step from it carries them (implicit function
    # theorem, dq = -(dx/dtheta) / (dx/dq)), with no checked linear solve (no host callback) in the
    # differentiated program. The point and its slope dP/dq at the root come from one jvp (_at_roots);
    # the point at the stepped q is P(root) + dP/dq (q - root), exact to first order in the ~1e-13 step.
    p_root, slope, assembled = _at_roots(mechanism, point, root)
    miss = p_root[:, 0] - targets
    dx = jnp.where(slope[:, 0] == 0, 1.0, slope[:, 0])
    step = -miss / dx
    q = root + step
    pts = p_root + slope * step[:, None]
    converged = (sol.result == optx.RESULTS.successful) & (jnp.abs(jax.lax.stop_gradient(miss)) < 1e-9) & (slope[:, 0] != 0)
    return q, pts, jnp.all(bracketed & converged & assembled)


def _at_roots(mechanism, point, roots):
    """The point, its slope dP/dq (no derivative) and whether it assembles, at each root (no derivative).

    The point's derivative with respect to the mechanism's parameters is taken in forward mode
    (one vectorised jacfwd over the flat parameters, with the slope) in a custom jvp: reverse mode
    transposes only its final product, where a reverse pass through the position analysis
    compiles to several times more kernels (seconds in a program that holds the objective's
    gradient several times); forward mode keeps working."""
    params, rest = eqx.partition(mechanism, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)

    def at(f, s):
        pose = positions(eqx.combine(unravel(f), rest), s, points=(point,), materialize=False)
        return pose.points[point], jnp.all(pose.ok)

    def one(f, s):
        (p, ok), (dp, _) = jax.jvp(lambda s: at(f, s), (s,), (jnp.ones_like(s),))
        return p, dp, ok

    @jax.custom_jvp
    def at_roots(f, r):
        return jax.vmap(one, in_axes=(None, 0))(f, r)

    @at_roots.defjvp
    def at_roots_jvp(primals, tangents):
        (f, r), (df, dr) = primals, tangents

        def with_value(f, s):
            p, ok = at(f, s)
            return p, (p, ok)

        (jac, slope), (p, ok) = jax.vmap(jax.jacfwd(with_value, argnums=(0, 1), has_aux=True), in_axes=(None, 0))(f, r)
        dp = jnp.einsum("sin,n->si", jac, df) + slope * dr[:, None]
        return (p, slope, ok), (dp, jnp.zeros_like(slope), np.zeros(ok.shape, dtype=jax.dtypes.float0))

    p, slope, ok = at_roots(flat, jax.lax.stop_gradient(roots))
    return p, jax.lax.stop_gradient(slope), ok


def _line_residuals(x, y):
    """Signed perpendicular distances from the least-squares line y = a + b x."""
    # sums side by side: each reduction over the samples compiles to a few kernels
    d = jnp.stack([x, y], axis=1) - jnp.mean(jnp.stack([x, y], axis=1), axis=0)
    sxx, sxy = jnp.sum(d[:, :1] * d, axis=0)
    b = sxy / sxx
    return (d[:, 1] - b * d[:, 0]) / jnp.sqrt(1.0 + b**2)


def _given_line_residuals(x, y, line):
    """Signed distances from a given line: y = c (a number) or ((x0, y0), angle)."""
    x0, y0, angle = line_pose(line)
    return (y - y0) * jnp.cos(angle) - (x - x0) * jnp.sin(angle)


def line_pose(line):
    """(x0, y0, angle) of a line given as a number c (the line y = c) or as ((x0, y0), angle)."""
    if isinstance(line, (tuple, list)) and len(line) == 2:
        (x0, y0), angle = line
        return x0, y0, angle
    if np.ndim(line) == 0 and np.issubdtype(np.asarray(line).dtype, np.number):
        return 0.0, line, 0.0
    raise AssurjaxError(f"line must be None, a number c (y = c) or ((x0, y0), angle), got {line!r}")


def _bracket_on_branch(mechanism, point, q0, targets, half_width, n):
    """Initial guesses (no gradient) for x_point(q) = target on the monotone, assembled
    stretch of q around q0; and whether each target lies on that stretch."""
    mechanism = jax.lax.stop_gradient(mechanism)
    grid = q0 + jnp.linspace(-half_width, half_width, n)
    pts, ok = coupler_curve(mechanism, point, grid)
    xs = pts[:, 0]
    dx = jnp.diff(xs)
    i0 = (n - 1) // 2
    direction = jnp.sign(dx[i0])
    good = ok[:-1] & ok[1:] & (dx * direction > 0)
    idx = jnp.arange(n - 1)
    # the stretch between the nearest bad intervals on either side of i0 (two reductions: a
    # cumulative product compiles to several times more kernels)
    first_bad = jnp.min(jnp.where(~good & (idx >= i0), idx, n - 1))
    last_bad = jnp.max(jnp.where(~good & (idx <= i0), idx, -1))
    on_branch = (idx > last_bad) & (idx < first_bad)

    def one(target):
        lo, hi = jnp.minimum(xs[:-1], xs[1:]), jnp.maximum(xs[:-1], xs[1:])
        hit = on_branch & (lo <= target) & (target <= hi)
        j = jnp.argmax(hit)
        frac = (target - xs[j]) / jnp.where(dx[j] == 0, 1.0, dx[j])
        return grid[j] + frac * (grid[j + 1] - grid[j]), jnp.any(hit)

    return jax.vmap(one)(targets)


# --------------------------------------------------------------------------- precision points


def precision_point_error(mechanism: Mechanism, point: str, q, targets, *, between: int = 8) -> tuple[Array, dict]:
    """Root-mean-square distance (m) between ``point`` at the driving coordinates ``q``
    (shape (n,)) and the precision points ``targets`` (shape (n, 2), m).

    Free timing: ``q`` is part of the design (see :class:`Design` over
    ``(mechanism, q)``). ``aux["ok"]`` is False when the mechanism fails to
    assemble at any q or at ``between`` points between consecutive q (sorted), so
    the coupler point can pass through the precision points in one motion.
    """
    q = jnp.asarray(q, dtype=float)
    targets = jnp.asarray(targets, dtype=float)
    if targets.shape != q.shape + (2,):
        raise AssurjaxError(f"precision points: targets must have shape {q.shape + (2,)} (one 2-vector per q), got {targets.shape}")
    pts, ok = coupler_curve(mechanism, point, q)
    qs = jnp.sort(q)
    fractions = jnp.linspace(0.0, 1.0, between + 2)[1:-1]
    path_q = (qs[:-1, None] + fractions * (qs[1:] - qs[:-1])[:, None]).reshape(-1)
    _, ok_path = coupler_curve(mechanism, point, path_q)
    err = jnp.sqrt(jnp.mean(jnp.sum((pts - targets) ** 2, axis=-1)))
    return err, {"ok": jnp.all(ok) & jnp.all(ok_path), "points": pts}


# --------------------------------------------------------------------------- driving torque


def driving_torque(mechanism: Mechanism, q, omega, *, gravity=(0.0, 0.0), loads: Sequence = ()) -> tuple[Array, Array]:
    """Driving torque (N m; N for a slider) holding the crank at constant speed ``omega``
    (rad/s) at each ``q``: inverse dynamics at dw/dt = 0. Returns (tau, ok) with one ok flag
    per q (False: some group cannot assemble or is singular; with joint friction also where
    the friction self-locks the mechanism against that motion, see :class:`assurjax.Reactions`).

    Without joint friction, via the reduction (Durango et al. 2014 eq. 1 with dw/dt = 0),
    tau = 0.5 dJ_red/dq omega^2 - tau_red(q, omega). With joint friction in ``loads``
    (:class:`assurjax.JointFriction`, :class:`assurjax.SlideFriction`), the kinetostatics
    of :func:`assurjax.inverse_dynamics` (its Coulomb signs those of the motion; at
    ``omega = 0`` the mechanism is held, as there). Jittable and differentiable either way."""
    q = jnp.asarray(q, dtype=float)
    loads = tuple(loads)
    if frictions_of(loads):
        return _frictional_torque(Model(mechanism, gravity, loads), q, omega)
    from .._reduction import reduce_single

    gravity = jnp.asarray(gravity, dtype=float)

    def one(qi):
        red = reduce_single(mechanism, gravity, loads, qi, jnp.asarray(omega, dtype=float), 0.0)
        return 0.5 * red.dinertia * omega**2 - red.torque, jnp.all(red.ok)

    tau, ok = jax.vmap(one)(q.reshape(-1))
    return tau.reshape(q.shape), ok.reshape(q.shape)


def _frictional_torque(model: Model, q, omega) -> tuple[Array, Array]:
    """(driving effort, ok) at dw/dt = 0 with joint friction: the friction law needs the
    joint reactions, which the reduction does not give, so the kinetostatics' own batch
    (that of :func:`assurjax.reactions`, chunked as there) solves it."""
    from .._kinetostatics._api import _batched, may_rest

    omega = jnp.broadcast_to(jnp.asarray(omega, dtype=float), q.shape)
    zeros = jnp.zeros(q.shape)
    _, _, tau, ok, _, _, consistent = _batched(model, (q, omega, zeros, zeros), "modular", None, False,
                                               may_rest(omega, zeros))
    return tau, jnp.all(ok, axis=-1) & consistent


def smooth_max(x, sharpness: float) -> Array:
    """A smooth upper bound of max(x): logsumexp(sharpness x) / sharpness (same units as x)."""
    return jax.scipy.special.logsumexp(sharpness * jnp.asarray(x)) / sharpness
