"""Branch continuity along a path of the driving coordinate (kinematic sweeps).

The group-level rule (nearest root to a predictor of the link angles) is in
``assurjax.groups._branch``; here the predictor travels along a sweep. A
zero-order predictor (the previous angles) is not enough: just after a group
passes through a stretched or folded configuration, the wrong root is a mirror
image of the right one and lies about as close to the previous sample. The
secant (first-order) extrapolation of the last two samples is nearer to the
right root by O(step) and to the wrong one by O(step^2) only, so it follows the
smooth branch through the crossing.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import MechanismError
from ._geometry import wrap_angle
from ._jit import jit
from ._mechanism import Mechanism, Pose, positions
from ._positions import STEP_SLACK, checked_request
from ._values import check_state_count, check_value
from .groups._newton import IterativeGroup


def tracked_links(mechanism: Mechanism) -> tuple[str, ...]:
    """Links whose angles carry the branch: those of every group but the driver."""
    return tuple(link for g in mechanism.groups if not g.is_driver for link in g.links)


def branch_angles(mechanism: Mechanism, pose: Pose) -> dict:
    """The branch state of a pose: the angles (rad) of the tracked links."""
    return {k: pose.angles[k] for k in tracked_links(mechanism)}


def stacked_branch(mechanism: Mechanism, angles: dict):
    """The tracked angles as one array (last axis: ``tracked_links`` order): one state leaf
    for the solver instead of one per link (a smaller program for long chains)."""
    return jnp.stack([angles[k] for k in tracked_links(mechanism)], axis=-1)


def branch_mapping(mechanism: Mechanism, z) -> dict | None:
    """The stacked tracked angles back as link -> angle (None stays None)."""
    if z is None:
        return None
    return {k: z[..., i] for i, k in enumerate(tracked_links(mechanism))}


def branch_rates(reduction, near: dict, omega) -> dict:
    """d(angle)/dt = d(angle)/dq * omega (rad/s) of the carried angles, from the
    kinematic coefficients the reduction already computed (no extra jvp)."""
    return {k: reduction.angle_rates[k] * omega for k in near}


def positions_tracked(mechanism: Mechanism, qs, *, near: Mapping | None = None, points: Iterable[str] | None = None) -> Pose:
    """Positions along a 1-D path of driving coordinates ``qs`` (rad or m), staying
    on one continuous assembly branch through singular configurations.

    Every sample takes, group by group, the root nearest to a secant prediction
    of the link angles from the two previous samples (``lax.scan``). The first
    sample uses ``near`` (link name -> angle, rad) if given, else the groups'
    fixed modes. Consecutive samples must be closer than the branches are apart
    away from the singular points (a few degrees of q is typical).
    Returns a :class:`Pose` with a leading axis of ``len(qs)``; ``ok`` is False
    where a group cannot assemble, and for an iterative group (triad, class IV) from where
    its branch ends on (a limit position passed: Newton's method would land on another
    assembly; see TRACK_TRUST).

    >>> scene = assurjax.n_four_bar(3)
    >>> pose = assurjax.positions_tracked(scene.mechanism, jnp.linspace(1.6, -4.7, 600))
    """
    check_value(MechanismError, "positions_tracked: qs", qs)  # before jit, where an array of qs is still concrete
    return _positions_tracked(mechanism, qs, near=near, points=points)


@jit
def _positions_tracked(mechanism: Mechanism, qs, *, near: Mapping | None, points: Iterable[str] | None) -> Pose:
    """:func:`positions_tracked`, its values checked."""
    if np.ndim(qs) != 1 or np.shape(qs)[0] < 1:
        raise MechanismError(f"positions_tracked: qs must be a 1-D path of driving coordinates, got shape {np.shape(qs)}")
    check_state_count(MechanismError, "positions_tracked: qs", np.shape(qs))
    pts = checked_request(mechanism, 0.0, points, near, "positions_tracked")
    qs = jnp.asarray(qs, dtype=float)
    first = positions(mechanism, qs[0], near=near)
    start = branch_angles(mechanism, first)

    def step(carry, q):
        angles, previous_angles, q_prev, dq_prev, ended = carry
        ratio = (q - q_prev) / jnp.where(dq_prev == 0.0, 1.0, dq_prev)
        predicted = jax.tree.map(lambda a, b: a + wrap_angle(a - b) * ratio, angles, previous_angles)
        pose = positions(mechanism, q, near=predicted)
        # an iterative group's branch that ended (a limit position passed) stays ended: a root
        # found further on belongs to another assembly
        ended = ended | ~_continued(mechanism, pose, angles, predicted, dq_prev != 0.0)
        pose = eqx.tree_at(lambda p: p.ok, pose, pose.ok & ~ended)
        # a sample that cannot assemble (e.g. exactly at coinciding external joints)
        # must not steer the next prediction: carry the prediction over it instead
        assembled = jnp.all(pose.ok)
        reached = jax.tree.map(lambda a, p: jnp.where(assembled, a, p), branch_angles(mechanism, pose), predicted)
        return (reached, angles, q, q - q_prev, ended), _select(pose, pts)

    # an iterative group that does not assemble at the first sample has no branch to track
    iterative = np.array([isinstance(g, IterativeGroup) for g in mechanism.groups])
    carry = (start, start, qs[0], jnp.zeros_like(qs[0]), ~first.ok & iterative)
    _, rest = jax.lax.scan(step, carry, qs[1:])
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), _select(first, pts), rest)


# An iterative group's root counts as the tracked branch's where it lies within TRACK_TRUST
# times the secant's predicted move (plus STEP_SLACK rad) of the prediction. Past a limit
# position the branch ends, and Newton's method lands on another assembly (a triad's angle
# jumping by 0.5 rad, 17 predicted moves, between samples 0.3 degrees apart) where a dyad
# finds no root. Looser than the continuation's STEP_TRUST: next to a limit position q* the
# angles go as sqrt(q* - q), and a step that ends at q* misses the secant's prediction by
# sqrt(1 + b/a) predicted moves (b: the previous step, a: the distance it left to q*): 1.41
# for even steps, 3 where the previous step was 8 times the distance left.
TRACK_TRUST = 3.0


def _continued(mechanism: Mechanism, pose: Pose, angles: dict, predicted: dict, secant):
    """Per group: False for an iterative group whose root is not on the tracked branch (see
    TRACK_TRUST); ``secant``: whether the prediction had two samples (the first step's had one:
    it is not tested)."""
    flags = []
    for group in mechanism.groups:
        if not isinstance(group, IterativeGroup):
            flags.append(jnp.asarray(True))
            continue
        links = group.unknown_links()
        move = jnp.max(jnp.stack([jnp.abs(wrap_angle(predicted[k] - angles[k])) for k in links]))
        miss = jnp.max(jnp.stack([jnp.abs(wrap_angle(pose.angles[k] - predicted[k])) for k in links]))
        flags.append(~secant | (miss <= TRACK_TRUST * move + STEP_SLACK))
    return jnp.stack(flags)


def _select(pose: Pose, points: tuple[str, ...] | None) -> Pose:
    if points is None:
        return pose
    return Pose(points={p: pose.points[p] for p in points}, coms=pose.coms, angles=pose.angles, ok=pose.ok)
