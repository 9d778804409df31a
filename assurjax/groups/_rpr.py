"""RPR dyad: a block pinned at E1 slides along a guide link pinned at E2 (the
inverted slider-crank, the Whitworth and Scotch-yoke style guide link)."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import V2, safe_sqrt
from ._base import AbstractGroup, as_mode, check_mode, Link, Placement, frame_from_rotation_xy


class RPR(AbstractGroup):
    """``links`` = (block, guide link); ``joints`` = (E1, E2). The guide is the line
    of the guide link through E2 along ``direction`` (in the guide link's frame);
    E1 lies at the signed distance ``offset`` (m, positive to the left) from it.
    ``mode`` +1: E1 is ahead of E2 along the guide direction; -1: behind. The
    block's local x axis is along the guide.
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    joints: tuple[str, str] = eqx.field(static=True)
    mode: int = eqx.field(static=True, converter=as_mode)  # +1/-1, or a name: 'left', 'forward'...
    direction: Array
    offset: Array
    kind = "RPR"
    name_fields = {"links": 2, "joints": 2}
    two_modes = True
    n_prismatic = 1  # block on the guide link
    singular_configuration = "the guide square to the line through its two pins"

    def __check_init__(self):
        check_mode(self)

    def external_points(self):
        return self.joints

    def prismatic_pairs(self, owner):
        return ((self.links[0], self.links[1], self.joints[0]),)

    def guides(self):
        return ((None, self.direction, self.offset),)

    def required_points(self):
        e1, e2 = self.joints
        return {self.links[0]: (e1,), self.links[1]: (e2,)}

    def singularity(self, x: dict, dx: dict, turn: dict, dturn: dict):
        """The cosine of the angle between E2 -> E1 and the guide (signed, along it): zero
        where E1 is at the foot of the guide's normal through it, |E1 E2| = |offset|, a
        limit position."""
        (e1, e2), block = self.joints, self.links[0]
        d, dd, u, du = x[e1] - x[e2], dx[e1] - dx[e2], turn[block], dturn[block]  # u: along the guide
        scale = 1.0 / jnp.sqrt(d.dot(d))
        along = d.dot(u) * scale
        return along, (dd.dot(u) + d.dot(du)) * scale - along * d.dot(dd) * scale**2

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        (block, guide), (e1, e2) = self.links, self.joints
        p1, p2 = placed.xy(e1), placed.xy(e2)
        d = p1 - p2
        r2 = d.dot(d)
        inv_r = jnp.where(r2 > 0.0, 1.0 / jnp.sqrt(jnp.where(r2 > 0.0, r2, 1.0)), 0.0)  # 1/|E1 - E2|, one division
        ratio = self.offset * inv_r
        eps = jnp.finfo(ratio.dtype).eps
        ok = (r2 > 0.0) & (jnp.abs(ratio) <= 1.0 + 16.0 * eps)  # |ratio| = 1 up to rounding: singular, not a failure
        # guide direction u: d turned by -asin(ratio) (mode +1) or by pi + asin(ratio) (mode -1)
        s = jnp.clip(jnp.where(ok, ratio, 0.0), -1.0, 1.0)
        c = safe_sqrt(1.0 - s**2, 1.0 - s**2 > 16.0 * eps)  # finite derivative at |ratio| = 1
        u = (d * (self.mode * inv_r)).rotate(V2(c, -self.mode * s))
        w = V2.of(self.direction).unit()  # the guide link's rotation takes w onto u: u * conj(w)
        frames = {
            block: frame_from_rotation_xy(links[block].points[e1], p1, u),
            guide: frame_from_rotation_xy(links[guide].points[e2], p2, V2(u.dot(w), w.cross(u))),
        }
        return frames, ok


