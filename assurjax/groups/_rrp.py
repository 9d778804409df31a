"""RRP and PRR dyads: a binary link and a slider joined at the internal revolute J;
the binary link is pinned to an earlier link at E, the slider runs on a guide
carried by an earlier link. RRP lists the revolute end first, PRR the prismatic
end first; the geometry is the same."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from ._base import AbstractGroup, as_mode, check_mode, Link, Placement, distance, frame_from_rotation_xy, frame_through_xy
from ._guides import guide_line, line_circle


class RRP(AbstractGroup):
    """``links`` = (rod, slider); ``joints`` = (E, J); the slider's point J runs on
    the line through ``guide_point`` (of an earlier link) along ``direction``
    (in that link's frame), shifted by ``offset`` (m) to the left of it.
    ``mode`` +1: J is ahead of the foot of the perpendicular from E (along the
    guide direction); -1: behind it. The slider's local x axis is along the guide.
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    joints: tuple[str, str] = eqx.field(static=True)
    guide_point: str = eqx.field(static=True)
    mode: int = eqx.field(static=True, converter=as_mode)  # +1/-1, or a name: 'left', 'forward'...
    direction: Array
    offset: Array
    kind = "RRP"
    name_fields = {"links": 2, "joints": 2, "guide_point": 0}
    two_modes = True
    n_prismatic = 1
    singular_configuration = "the rod square to the guide"

    def __check_init__(self):
        check_mode(self)

    def external_points(self):
        return (self.joints[0], self.guide_point)

    def prismatic_pairs(self, owner):
        return ((self.links[1], owner[self.guide_point], self.joints[1]),)

    def guides(self):
        return ((self.guide_point, self.direction, self.offset),)

    def required_points(self):
        e, j = self.joints
        return {self.links[0]: (e, j), self.links[1]: (j,)}

    def _rod_and_slider(self):
        """(E, J, the slider link)."""
        return (*self.joints, self.links[1])

    def singularity(self, x: dict, dx: dict, turn: dict, dturn: dict):
        """The cosine of the rod's angle with the guide (signed, along the guide): zero where
        the rod stands square to it, a limit position (the rod's length is constant)."""
        e, j, slider = self._rod_and_slider()
        rod, drod, u, du = x[j] - x[e], dx[j] - dx[e], turn[slider], dturn[slider]  # u: along the guide
        scale = 1.0 / jnp.sqrt(rod.dot(rod))
        return rod.dot(u) * scale, (drod.dot(u) + rod.dot(du)) * scale

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        (rod, slider), (e, j) = self.links, self.joints
        base, u, n = guide_line(placed, self.guide_point, self.direction, self.offset)
        pe = placed.xy(e)
        pj, ok = line_circle(base, u, n, pe, distance(links, rod, e, j), self.mode)
        frames = {
            rod: frame_through_xy(links[rod].points[e], links[rod].points[j], pe, pj),
            slider: frame_from_rotation_xy(links[slider].points[j], pj, u),
        }
        return frames, ok


class PRR(RRP):
    """The RRP dyad listed from its prismatic end: ``links`` = (slider, rod),
    ``joints`` = (J, E); same guide fields and mode convention as :class:`RRP`."""

    kind = "PRR"

    def external_points(self):
        return (self.joints[1], self.guide_point)

    def prismatic_pairs(self, owner):
        return ((self.links[0], owner[self.guide_point], self.joints[0]),)

    def required_points(self):
        j, e = self.joints
        return {self.links[0]: (j,), self.links[1]: (e, j)}

    def _rod_and_slider(self):
        return (*self.joints[::-1], self.links[0])

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        mirrored = RRP(self.name, self.links[::-1], self.joints[::-1], self.guide_point, self.mode, self.direction, self.offset)
        return mirrored.solve(links, placed, q)
