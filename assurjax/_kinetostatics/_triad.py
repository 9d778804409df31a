"""Class-III triad (ternary link T and three binary links): its own 12 x 12 system
(four links, six revolutes). No special-point reduction is implemented for it."""

from ._system import Geometry, solve_dense


def solve_triad(group, pairs, geom: Geometry, known):
    return solve_dense(group.links, pairs, geom, known)
