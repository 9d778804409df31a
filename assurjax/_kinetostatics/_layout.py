"""Which pairs (joints) a mechanism has, who acts on whom, and which group solves for each.

Conventions (see docs/kinetostatics.md):

- A **revolute** is a point name carried by two links (or a link and the ground).
  Its reaction is the force (N, global x, y) exerted ON the link placed later in
  the formation sequence (within a group: later in the group's ``links``) BY the
  link placed earlier (the ground is earliest). It is named by the point, e.g. "A".
- A point carried by more than two links is split as if every later carrier were
  pinned to the first carrier (the point's owner): one reaction per later link,
  named "<point>[<link>]", the force on that link by the owner. The owner receives
  minus their sum.
- A **prismatic** pair is named "<slider>/<guide link>". Its reaction is the force
  ON the slider (or block) BY the link carrying the guide, normal to the guide and
  acting at the slider's sliding point (the joint point it carries on the guide),
  plus a couple (N m, counterclockwise positive) on the slider by the guide link.
- Each pair is solved by the group that placed its ``on`` link.
"""

from __future__ import annotations

from typing import NamedTuple

from .._errors import MechanismError
from .._mechanism import Mechanism
from ..groups._base import GROUND


class Pair(NamedTuple):
    """One kinematic pair. ``kind`` "R" (revolute) or "P" (prismatic); the reaction
    acts ON ``on`` BY ``by`` at ``point``; ``group`` is the index of the group that
    solves it."""

    name: str
    kind: str
    on: str
    by: str
    point: str
    group: int


def _carriers(mechanism: Mechanism) -> dict[str, int]:
    count = {p: 1 for p in mechanism.ground}
    for link in mechanism.links.values():
        for p in link.points:
            count[p] = count.get(p, 0) + 1
    return count


def group_pairs(mechanism: Mechanism) -> tuple[tuple[Pair, ...], ...]:
    """The pairs each group solves for, in formation order (a trace-time helper)."""
    owner = dict(mechanism.owner)
    carriers = _carriers(mechanism)
    out = []
    for i, group in enumerate(mechanism.groups):
        pairs = []
        for link in group.links:
            for p in mechanism.links[link].points:
                if owner[p] != link:
                    name = p if carriers[p] == 2 else f"{p}[{link}]"
                    pairs.append(Pair(name, "R", link, owner[p], p, i))
        if group.n_prismatic:
            prismatic = group.prismatic_pairs(owner)
            if len(prismatic) != group.n_prismatic:
                raise MechanismError(
                    f"{group.describe()}: kinetostatics does not know where its {group.n_prismatic} prismatic pair(s) are"
                )
            for slider, guide, point in prismatic:
                pairs.append(Pair(f"{slider}/{guide}", "P", slider, guide, point, i))
        unknowns = sum(2 for _ in pairs) + (1 if group.is_driver else 0)
        if unknowns != 3 * len(group.links):
            raise MechanismError(
                f"{group.describe()}: {unknowns} reaction unknowns for {3 * len(group.links)} equilibrium equations; "
                "the group is not statically determinate (check the point names shared between links)"
            )
        out.append(tuple(pairs))
    return tuple(out)


def joint_names(mechanism: Mechanism) -> tuple[str, ...]:
    """Names of every pair whose reaction :func:`assurjax.reactions` returns."""
    return tuple(p.name for pairs in group_pairs(mechanism) for p in pairs)


def feeds(mechanism: Mechanism, pairs) -> dict[int, set[int]]:
    """Group j -> the earlier groups it hands loads back to: i < j where one of j's pairs
    acts BY a link of i."""
    group_of = {link: i for i, g in enumerate(mechanism.groups) for link in g.links}
    return {j: {group_of[p.by] for p in pairs[j] if p.by != GROUND and group_of[p.by] != j} for j in range(len(pairs))}


def groups_for(mechanism: Mechanism, pairs, wanted_groups: set[int]) -> tuple[int, ...]:
    """Groups to solve so that ``wanted_groups`` get their reactions: those groups and
    every later group that hands loads back to them, directly or through others."""
    fed, needed = feeds(mechanism, pairs), set()
    for j in range(len(pairs)):
        if j in wanted_groups or fed[j] & needed:
            needed.add(j)
    return tuple(sorted(needed))
