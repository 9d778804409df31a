"""RRR dyad: two binary links joined at an internal revolute J, each pinned to an
earlier link at an external revolute (E1 on the first link, E2 on the second)."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import V2, safe_sqrt
from ._base import AbstractGroup, as_mode, check_mode, Link, Placement, distance, frame_through_xy


def circle_circle(c1: V2, r1: Array, c2: V2, r2: Array, mode: int):
    """Intersection of two circles (centres as :class:`V2`); ``mode`` = +1 takes the
    point left of the directed line c1 -> c2, -1 the one on its right. Returns (point, ok)."""
    d = c2 - c1
    dd = d.dot(d)
    inv = 1.0 / jnp.where(dd > 0.0, dd, 1.0)  # one division, reused (divisions are costly)
    along = (dd + r1**2 - r2**2) * (0.5 * inv)  # as a fraction of |d|
    h2 = r1**2 * inv - along**2  # squared height, also as a fraction of |d|
    # at a stretched or folded dyad h2 = 0 up to rounding: accept it (a singular
    # configuration, not a failure) and keep the sqrt's derivative finite there
    tol = 16.0 * jnp.finfo(h2.dtype).eps * (r1**2 + r2**2) * inv
    ok = (h2 >= -tol) & (dd > 0.0)
    h = safe_sqrt(h2, h2 > tol)
    return c1 + d * along + d.perp() * (mode * h), ok


class RRR(AbstractGroup):
    """Closed form (circle intersection). ``mode`` +1: J lies left of the directed
    line E1 -> E2 ("left"); -1: right."""

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    joints: tuple[str, str, str] = eqx.field(static=True)  # (E1, E2, J)
    mode: int = eqx.field(static=True, converter=as_mode)  # +1/-1, or a name: 'left', 'forward'...
    kind = "RRR"
    name_fields = {"links": 2, "joints": 3}
    two_modes = True
    singular_configuration = "stretched or folded"

    def __check_init__(self):
        check_mode(self)

    def external_points(self):
        return self.joints[:2]

    def required_points(self):
        e1, e2, j = self.joints
        return {self.links[0]: (e1, j), self.links[1]: (e2, j)}

    def singularity(self, x: dict, dx: dict, turn: dict, dturn: dict):
        """The sine of the angle at J (signed): zero when the dyad is stretched or folded,
        or its external joints coincide (the link lengths are constant, so only the
        cross product varies)."""
        e1, e2, j = self.joints
        u, v, du, dv = x[j] - x[e1], x[j] - x[e2], dx[j] - dx[e1], dx[j] - dx[e2]
        cross = lambda a, b: a[0] * b[1] - a[1] * b[0]  # noqa: E731
        scale = 1.0 / jnp.sqrt(u.dot(u) * v.dot(v))
        return cross(u, v) * scale, (cross(du, v) + cross(u, dv)) * scale

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        (a, b), (e1, e2, j) = self.links, self.joints
        p1, p2 = placed.xy(e1), placed.xy(e2)
        pj, ok = circle_circle(p1, distance(links, a, e1, j), p2, distance(links, b, e2, j), self.mode)
        frames = {
            a: frame_through_xy(links[a].points[e1], links[a].points[j], p1, pj),
            b: frame_through_xy(links[b].points[e2], links[b].points[j], p2, pj),
        }
        return frames, ok
