"""Drivers: the links whose coordinate is the mechanism's generalized coordinate q."""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import V2, perp, rotation
from ._base import GROUND, AbstractGroup, Link, Placement, frame_from_rotation_xy


@jax.custom_jvp
def turn(q):
    """(cos q, sin q), computed once however many derivatives and computations read it.

    XLA counts a sine or a cosine as cheap and copies it into every fused computation that
    reads it: the crank's rotation, read by its derivatives of each order, the reduction, the
    statics and the friction, cost six sine-cosine pairs per right-hand side of the press with
    friction (two without). A division XLA does not copy, so the pair is divided by a one it
    cannot fold (q * 0 + 1: exactly 1 for a finite q), and the derivatives are taken from the
    pair itself (below), not from sines and cosines of their own: one pair per right-hand side
    (the press's step 5.7k -> 1.4k instructions in libm with friction, 2.3k -> 1.4k without)."""
    one = q * 0.0 + 1.0
    return rotation(q) / one


@turn.defjvp
def _(primals, tangents):
    (q,), (dq,) = primals, tangents
    pair = turn(q)
    return pair, perp(pair) * dq


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
    name_fields = {"links": 1, "pivot": 0}
    is_driver = True

    def external_points(self):
        return (self.pivot,)

    def required_points(self):
        return {self.links[0]: (self.pivot,)}

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        link = self.links[0]
        cos, sin = turn(q)
        frame = frame_from_rotation_xy(placed.local(link, self.pivot), placed.xy(self.pivot), V2(cos, sin))
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
    name_fields = {"links": 1, "point": 0, "guide_point": 0}
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
