"""Prismatic guides shared by the dyads that contain P pairs."""

import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import perp, rotate, safe_sqrt, unit
from ._base import Placement


def guide_line(placed: Placement, guide_point: str, direction: Array, offset: Array):
    """A guide line in global coordinates: (a point on it, unit direction, left normal).

    The line passes through ``guide_point`` shifted by ``offset`` (m) along the
    left normal; ``direction`` is given in the frame of the link carrying the guide.
    """
    u = rotate(unit(direction), placed.rotation_of_owner(guide_point))
    n = perp(u)
    return placed.point(guide_point) + offset * n, u, n


def line_circle(base: Array, u: Array, n: Array, centre: Array, radius: Array, mode: int):
    """Point at distance ``radius`` from ``centre`` on the line ``base + s u``.

    ``mode`` = +1 takes the intersection ahead (along ``u``) of the foot of the
    perpendicular from ``centre``, -1 the one behind. Returns (point, ok).
    """
    p = base - centre
    along, across = jnp.dot(p, u), jnp.dot(p, n)
    disc = radius**2 - across**2
    # tangent line: disc = 0 up to rounding is a singular configuration, not a failure
    tol = 16.0 * jnp.finfo(disc.dtype).eps * (radius**2 + across**2)
    ok = disc >= -tol
    root = safe_sqrt(disc, disc > tol)
    s = -along + mode * root
    return base + s * u, ok
