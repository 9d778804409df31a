"""Drivers: the links whose coordinate is the mechanism's generalized coordinate q."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import V2
from ._base import GROUND, AbstractGroup, Link, Placement, frame_from_rotation_xy


class Crank(AbstractGroup):
    """A link rotating about a fixed (ground) pivot.

    q is the angle (rad) of the crank's local x axis from global +x,
    counterclockwise; draw the crank with its joint on the local x axis and
    q is the usual crank angle theta2.
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    pivot: str = eqx.field(static=True)
    kind = "crank"
    is_driver = True

    def external_points(self):
        return (self.pivot,)

    def required_points(self):
        return {self.links[0]: (self.pivot,)}

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        link = self.links[0]
        frame = frame_from_rotation_xy(placed.local(link, self.pivot), placed.xy(self.pivot), V2(jnp.cos(q), jnp.sin(q)))
        return {link: frame}, jnp.array(True)


class Slider(AbstractGroup):
    """A link translating along a fixed (ground) guide.

    q is the displacement (m) of the slider's point ``point`` from the ground
    point ``guide_point`` along the unit vector of ``direction`` (global frame).
    The slider's local x axis is along the guide.
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    point: str = eqx.field(static=True)
    guide_point: str = eqx.field(static=True)
    direction: Array
    kind = "slider"
    n_prismatic = 1
    is_driver = True

    def external_points(self):
        return (self.guide_point,)

    def prismatic_pairs(self, owner):
        return ((self.links[0], GROUND, self.point),)

    def guides(self):
        return ((self.guide_point, self.direction, jnp.zeros(())),)

    def required_points(self):
        return {self.links[0]: (self.point,)}

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        link = self.links[0]
        u = V2.of(self.direction).unit()
        position = placed.xy(self.guide_point) + u * q
        frame = frame_from_rotation_xy(placed.local(link, self.point), position, u)
        return {link: frame}, jnp.array(True)


DRIVERS = {"crank": Crank, "slider": Slider}
