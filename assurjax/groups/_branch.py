"""Branch selection by proximity to a predictor, for every group kind.

A fixed assembly mode (``mode`` = left/right, forward/backward) names a branch
relative to the directed line between a group's external joints. Where that line
degenerates (the external joints coincide) or the group passes through a
singular configuration (stretched or folded: the two roots of its closed form
meet), the physical motion may continue on the branch that the fixed mode calls
the *other* one. The general answer used here: when a predictor is given (link
angles, rad, as in ``Pose.angles``: e.g. the previous sample of a sweep, or the
angles carried in the state of a simulation), each group returns the candidate
solution nearest to it:

- closed-form groups with a ``mode`` field: both roots are evaluated and the one
  whose link rotations are nearest to the predicted rotations wins
  (distance sum_links |(cos, sin) - (cos, sin)_pred|^2 = 2 sum (1 - cos(angle error)),
  smooth and free of angle wrapping); a root that cannot assemble always loses;
- iterative groups (triad, class IV) start Newton from the predictor
  (``Placement.near``, read by the group itself);
- groups without a branch choice (drivers, PRP) are unchanged.

Without a predictor every group keeps its fixed mode (the default, unchanged).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import rotation
from ._base import AbstractGroup, Frame, Link, Placement


def branch_candidates(group: AbstractGroup) -> tuple[AbstractGroup, ...]:
    """The group itself, then the same group with its assembly mode flipped
    (closed forms with two modes, ``AbstractGroup.two_modes``); just the group otherwise."""
    if not group.two_modes:
        return (group,)
    return (group, dataclasses.replace(group, mode=-group.mode))


def branch_distance(frames: dict[str, Frame], near: dict[str, Array], tracked: tuple[str, ...]) -> Array:
    """sum over ``tracked`` links of |rot - rotation(near angle)|^2 (dimensionless, in [0, 4] per link)."""
    return sum(jnp.sum((frames[k].rot - rotation(jnp.asarray(near[k], dtype=frames[k].rot.dtype))) ** 2) for k in tracked)


def solve_near(group: AbstractGroup, links: dict[str, Link], placed: Placement, q: Array):
    """``group.solve``, choosing among its branch candidates the one nearest to
    ``placed.near`` (link angles, rad) when it is given. Returns (frames, ok)."""
    near = placed.near
    candidates = branch_candidates(group)
    tracked = tuple(k for k in group.links if near is not None and k in near)
    if len(candidates) == 1 or not tracked:
        return group.solve(links, placed, q)
    near_rot = {k: jax.lax.stop_gradient(near[k]) for k in tracked}  # the predictor only selects
    solutions = [c.solve(links, placed, q) for c in candidates]
    penalty = 4.0 * len(tracked) + 1.0  # larger than any distance: an unassembled root always loses
    misses = [branch_distance(f, near_rot, tracked) + jnp.where(ok, 0.0, penalty) for f, ok in solutions]
    (frames_a, ok_a), (frames_b, ok_b) = solutions
    take_b = misses[1] < misses[0]
    frames = jax.tree.map(lambda a, b: jnp.where(take_b, b, a), frames_a, frames_b)
    return frames, jnp.where(take_b, ok_b, ok_a)
