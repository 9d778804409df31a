"""Drivers: the last step of the kinetostatic analysis gives the driving effort.

Crank (3 unknowns: the pivot force R and the driving torque tau, closed form):
    R + f = 0,   tau + m + (O - G) x R = 0
Slider (normal force N, couple C of the guide, driving force F along the guide u):
    N n + F u + f = 0,   C + m + (P - G) x (N n + F u) = 0
f, m: known force and moment about the centre of mass G of the driving link
(applied loads, inertia, and the reactions handed back by the groups built on it).
"""

import jax.numpy as jnp

from .._geometry import dot, perp
from ._system import Geometry, Reaction, moment_about


def solve_crank(group, pairs, geom: Geometry, known):
    link = group.links[0]
    (pivot,) = pairs
    tau = -moment_about(geom, known, link, geom.points[pivot.point])
    return {pivot.name: Reaction(-known[link][0], jnp.zeros(()))}, tau, jnp.array(True)


def solve_slider(group, pairs, geom: Geometry, known):
    link = group.links[0]
    f = known[link][0]
    (guide,) = pairs
    u = geom.rots[link]
    n = perp(u)
    normal, drive = -dot(f, n), -dot(f, u)
    couple = -moment_about(geom, known, link, geom.points[guide.point])
    return {guide.name: Reaction(normal * n, couple)}, drive, jnp.array(True)
