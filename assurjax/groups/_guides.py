"""Prismatic guides shared by the dyads that contain P pairs."""

import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import V2, safe_sqrt
from ._base import Placement


def guide_line(placed: Placement, guide_point: str, direction: Array, offset: Array) -> tuple[V2, V2, V2]:
    """A guide line in global coordinates, as :class:`V2`: (a point on it, unit direction, left normal).

    The line passes through ``guide_point`` shifted by ``offset`` (m) along the
    left normal; ``direction`` is given in the frame of the link carrying the guide
    (the link that owns ``guide_point``).
    """
    u = V2.of(direction).unit().rotate(V2.of(placed.rotation_of_owner(guide_point)))
    n = u.perp()
    return placed.xy(guide_point) + n * offset, u, n


def line_circle(base: V2, u: V2, n: V2, centre: V2, radius: Array, mode: int):
    """Point at distance ``radius`` from ``centre`` on the line ``base + s u`` (points as :class:`V2`).

    ``mode`` = +1 takes the intersection ahead (along ``u``) of the foot of the
    perpendicular from ``centre``, -1 the one behind. Returns (point, ok).
    """
    p = base - centre
    along, across = p.dot(u), p.dot(n)
    disc = radius**2 - across**2
    # tangent line: disc = 0 up to rounding is a singular configuration, not a failure
    tol = 16.0 * jnp.finfo(disc.dtype).eps * (radius**2 + across**2)
    ok = disc >= -tol
    root = safe_sqrt(disc, disc > tol)
    s = -along + mode * root
    return base + u * s, ok
