"""PRP dyad: two sliders on guides of earlier links, pinned together at J."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from ._base import AbstractGroup, Link, Placement, frame_from_rotation_xy
from ._guides import guide_line


class PRP(AbstractGroup):
    """``links`` = (slider 1, slider 2), joined at ``joint`` J. Slider k runs on the
    line through ``guide_points[k]`` along ``directions[k]`` (in the frame of the
    link carrying that point), shifted by ``offsets[k]`` to its left. J is the
    intersection of the two lines (unique: no assembly mode); parallel guides
    cannot assemble. Each slider's local x axis is along its guide.
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    joint: str = eqx.field(static=True)
    guide_points: tuple[str, str] = eqx.field(static=True)
    directions: Array  # (2, 2)
    offsets: Array  # (2,)
    kind = "PRP"
    name_fields = {"links": 2, "joint": 0, "guide_points": 2}
    n_prismatic = 2

    def external_points(self):
        return self.guide_points

    def prismatic_pairs(self, owner):
        return tuple((self.links[k], owner[self.guide_points[k]], self.joint) for k in (0, 1))

    def guides(self):
        return tuple(zip(self.guide_points, self.directions, self.offsets))

    def required_points(self):
        return {self.links[0]: (self.joint,), self.links[1]: (self.joint,)}

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        (s1, s2), j = self.links, self.joint
        b1, u1, _ = guide_line(placed, self.guide_points[0], self.directions[0], self.offsets[0])
        b2, u2, n2 = guide_line(placed, self.guide_points[1], self.directions[1], self.offsets[1])
        denom = n2.dot(u1)
        ok = jnp.abs(denom) > 1e-12
        pj = b1 + u1 * (n2.dot(b2 - b1) / jnp.where(ok, denom, 1.0))
        frames = {
            s1: frame_from_rotation_xy(links[s1].points[j], pj, u1),
            s2: frame_from_rotation_xy(links[s2].points[j], pj, u2),
        }
        return frames, ok
