"""The equilibrium equations of one group (or of the whole mechanism) as a small
linear system, and the bookkeeping of the loads passed from group to group.

Every moving link gives three d'Alembert equilibrium equations (Durango et al. 2014, Calle et al. 2014
eqs. 9-12): sum of forces = 0 (x, y) and sum of moments about its centre of mass = 0,
with the applied loads, the inertia force -m a_G and couple -J alpha, and the
reactions of its pairs. Moments are counterclockwise positive.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import cross, perp
from .._linalg import lu_factor, lu_solve
from ._layout import Pair

SINGULAR = 1e-10
"""A system is flagged singular when |det A| / prod(row norms of A) (Hadamard's
ratio: 1 for orthogonal rows, 0 for a singular matrix) falls below this."""


class Geometry(NamedTuple):
    """Global positions (m) of every point and centre of mass, and each link's
    rotation (cos, sin) of its local x axis (the guide direction for a slider)."""

    points: dict[str, Array]
    coms: dict[str, Array]
    rots: dict[str, Array]


class Reaction(NamedTuple):
    """A pair's reaction: force (N) on ``on`` by ``by`` and couple (N m; zero for a revolute)."""

    force: Array
    couple: Array


def moment_about_com(geom: Geometry, link: str, at: Array, force: Array) -> Array:
    return cross(at - geom.coms[link], force)


def moment_about(geom: Geometry, known: dict, link: str, centre: Array) -> Array:
    """Moment (N m) about ``centre`` of the known wrench of ``link`` (its force acts at the COM)."""
    f, m = known[link]
    return m + cross(geom.coms[link] - centre, f)


def guide_normal(geom: Geometry, pair: Pair) -> Array:
    """Left normal of the guide of a prismatic pair (the slider's x axis is along the guide)."""
    return perp(geom.rots[pair.on])


def _wrench_column(geom, index, link, at, force, couple, sign, size):
    """Column of a unit unknown: its force and moment about the COM on ``link`` (if in the system)."""
    col = jnp.zeros(size)
    if link in index:
        k = 3 * index[link]
        m = couple + (moment_about_com(geom, link, at, force) if force is not None else 0.0)
        f = force if force is not None else jnp.zeros(2)
        col = col.at[k : k + 2].set(sign * f).at[k + 2].set(sign * m)
    return col


def pair_columns(geom: Geometry, index: dict[str, int], pair: Pair, size: int) -> list[Array]:
    """Columns of a pair's unknowns: (Fx, Fy) of a revolute, (N, C) of a prismatic."""
    at = geom.points[pair.point]
    zero = jnp.zeros(())
    if pair.kind == "R":
        units = [jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0])]
        return [
            _wrench_column(geom, index, pair.on, at, e, zero, 1.0, size) + _wrench_column(geom, index, pair.by, at, e, zero, -1.0, size)
            for e in units
        ]
    n = guide_normal(geom, pair)
    return [
        _wrench_column(geom, index, pair.on, at, n, zero, 1.0, size) + _wrench_column(geom, index, pair.by, at, n, zero, -1.0, size),
        _wrench_column(geom, index, pair.on, at, None, jnp.ones(()), 1.0, size)
        + _wrench_column(geom, index, pair.by, at, None, jnp.ones(()), -1.0, size),
    ]


def driver_column(geom: Geometry, index: dict[str, int], driver, size: int) -> Array:
    """Column of the driving effort: a couple on a crank, a force along the guide on a slider."""
    link = driver.links[0]
    if driver.kind == "crank":
        return _wrench_column(geom, index, link, geom.points[driver.pivot], None, jnp.ones(()), 1.0, size)
    return _wrench_column(geom, index, link, geom.points[driver.point], geom.rots[link], jnp.zeros(()), 1.0, size)


def known_vector(known: dict, links) -> Array:
    return jnp.concatenate([jnp.concatenate([known[link][0], known[link][1][None]]) for link in links])


def solve_flagged(a: Array, rhs: Array) -> tuple[Array, Array]:
    """Solve a x = rhs by LU; ``ok`` is False (and x = 0, never NaN) when a is singular."""
    lu, pivots = lu_factor(a)
    row_norms = jnp.sqrt(jnp.sum(a * a, axis=-1))
    ratio = jnp.prod(jnp.abs(jnp.diagonal(lu)) / jnp.where(row_norms > 0, row_norms, 1.0))
    ok = ratio > SINGULAR
    x = lu_solve((jnp.where(ok, lu, jnp.eye(a.shape[0])), pivots), rhs)
    return jnp.where(ok, x, 0.0), ok


def unpack(geom: Geometry, pairs, x: Array) -> dict[str, Reaction]:
    """Reactions from the solution vector, in the order of :func:`pair_columns`."""
    out = {}
    for k, pair in enumerate(pairs):
        a, b = x[2 * k], x[2 * k + 1]
        if pair.kind == "R":
            out[pair.name] = Reaction(jnp.stack([a, b]), jnp.zeros(()))
        else:
            out[pair.name] = Reaction(a * guide_normal(geom, pair), b)
    return out


def solve_dense(links, pairs, geom: Geometry, known: dict, driver=None):
    """The general solve: all of the links' 3 n equilibrium equations at once (the
    12 x 12 system of Calle et al. 2014 for a class-IV group). Returns (reactions, driving
    effort or None, ok)."""
    index = {link: k for k, link in enumerate(links)}
    size = 3 * len(links)
    cols = [c for pair in pairs for c in pair_columns(geom, index, pair, size)]
    if driver is not None:
        cols.append(driver_column(geom, index, driver, size))
    x, ok = solve_flagged(jnp.stack(cols, axis=-1), -known_vector(known, links))
    return unpack(geom, pairs, x), (x[-1] if driver is not None else None), ok
