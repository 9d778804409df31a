"""Building blocks of synthesis objectives: coupler curves, transmission angles, assembly
margins, straight-line deviation (seed 001), precision points, driving torque.

All are pure JAX functions of a Mechanism (jit/vmap/grad-able); the ones that can
meet a configuration that does not assemble return ``ok`` flags next to their value.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array

from .._errors import AssurjaxError
from .._geometry import cross, dot
from .._mechanism import Mechanism, positions
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

    ``deviation``: half the width of the narrowest band parallel to the
    least-squares line that holds every sample, (max r - min r) / 2, with r the
    signed perpendicular distances from that line (the minimum-zone straightness
    for the least-squares direction); ``smooth``: the same with both extremes
    replaced by log-sum-exp soft maxima of sharpness ``p / max|r|`` (a
    differentiable stand-in, at most ``log(samples) max|r| / p`` above it,
    whose gradient is the derivative of its value);
    ``x``, ``y``: coupler point at the sample positions; ``q``: the driving
    coordinates there; ``residuals``: signed distances from the line; ``ok``:
    every sample assembled and was reached on the branch through ``q0``.
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
) -> StraightLine:
    """How straight the path of ``point`` is over a stroke (seed 001: < 1 mm over 260 mm).

    The stroke is ``x`` from ``center - stroke/2`` to ``center + stroke/2`` (m,
    global x; ``center`` defaults to x of the point at ``q0``), sampled at
    ``samples`` evenly spaced x. The driving coordinate of each sample is found on
    the branch through ``q0``: a scan of ``search = (half-width, points)`` around
    ``q0`` brackets it, Newton's method (optimistix) refines it, and gradients
    follow by the implicit function theorem (never through iterations). The
    deviation is measured from the least-squares line through the samples.
    """
    q0 = jnp.asarray(q0, dtype=float)
    x_of = lambda q: positions(mechanism, q, points=(point,)).points[point][0]  # noqa: E731
    if center is None:
        center = x_of(q0)
    targets = center + jnp.linspace(-0.5, 0.5, samples) * stroke
    guess, bracketed = _bracket_on_branch(mechanism, point, q0, targets, *search)

    def residual(q, x_target):
        return x_of(q) - x_target

    solver = optx.Newton(rtol=1e-12, atol=1e-13)
    sol = jax.vmap(lambda g, xt: optx.root_find(residual, solver, g, args=xt, max_steps=32, throw=False))(guess, targets)
    q = sol.value
    pts, ok = coupler_curve(mechanism, point, q)
    converged = (sol.result == optx.RESULTS.successful) & (jnp.abs(pts[:, 0] - targets) < 1e-9)
    ok = jnp.all(ok & bracketed & converged)
    x, y = pts[:, 0], pts[:, 1]
    r = _line_residuals(x, y)
    # the scale is differentiated too (no stop_gradient), so the gradient of `smooth` is the
    # derivative of its value (a stopped scale is off by up to ~log(samples)/p, a few per cent)
    sharpness = p / (jnp.max(jnp.abs(r)) + 1e-300)
    return StraightLine(
        deviation=0.5 * (jnp.max(r) - jnp.min(r)),
        smooth=0.5 * (smooth_max(r, sharpness) + smooth_max(-r, sharpness)),
        x=x, y=y, q=q, residuals=r, ok=ok,
    )


def _line_residuals(x, y):
    """Signed perpendicular distances from the least-squares line y = a + b x."""
    xm, ym = jnp.mean(x), jnp.mean(y)
    b = jnp.sum((x - xm) * (y - ym)) / jnp.sum((x - xm) ** 2)
    return ((y - ym) - b * (x - xm)) / jnp.sqrt(1.0 + b**2)


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
    right = jnp.cumprod(jnp.where(idx >= i0, good, True))
    left = jnp.cumprod(jnp.where(idx <= i0, good, True)[::-1])[::-1]
    on_branch = jnp.where(idx >= i0, right, left).astype(bool)

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
    (rad/s) at each ``q``: inverse dynamics via the reduction (seed 000 eq. 1 with
    dw/dt = 0), tau = 0.5 dJ_red/dq omega^2 - tau_red(q, omega). Returns (tau, ok)
    with one ok flag per q."""
    from .._reduction import reduce_single

    q = jnp.asarray(q, dtype=float)
    gravity = jnp.asarray(gravity, dtype=float)

    def one(qi):
        red = reduce_single(mechanism, gravity, tuple(loads), qi, jnp.asarray(omega, dtype=float), 0.0)
        return 0.5 * red.dinertia * omega**2 - red.torque, jnp.all(red.ok)

    tau, ok = jax.vmap(one)(q.reshape(-1))
    return tau.reshape(q.shape), ok.reshape(q.shape)


def smooth_max(x, sharpness: float) -> Array:
    """A smooth upper bound of max(x): logsumexp(sharpness x) / sharpness (same units as x)."""
    return jax.scipy.special.logsumexp(sharpness * jnp.asarray(x)) / sharpness
