"""The order the groups are solved in, and groups of one kind solved together.

A group's reactions need the loads handed back by every group built on it, so groups are
solved level by level from the outermost in: a group's *level* is one more than the highest
among the groups it hands loads back to (the driver's is 0); groups at one level are
independent. Groups at one level with the same solve (the class, its non-name fields and
name pattern, its pairs' layout) form a **batch**, solved by one ``jax.vmap`` under the
names of its first member, as the position analysis does (:mod:`assurjax._positions`):
the strandbeest's 24 leg dyads are four batches (four or eight legs of one side and
kind), so its programs trace four dyad solves instead of 24.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._mechanism import Mechanism
from .._positions import Options, _correspondence, signature
from ..groups._base import GROUND
from ._layout import feeds
from ._system import Geometry, moment_about_com

BATCHED_GROUPS = 2
"""Groups of one solve at one level are batched from this many on."""


def _layout(group, pairs) -> tuple:
    """The pairs of a group relative to it: (kind, its ``on`` link's slot, its ``by`` link's
    slot (-1: a link outside the group, -2: the ground), its point's slot among the pairs' points)."""
    points = [p.point for p in pairs]
    slot = {link: k for k, link in enumerate(group.links)}
    return tuple(sorted((p.kind, slot[p.on], -2 if p.by == GROUND else slot.get(p.by, -1), points.index(p.point))
                        for p in pairs))


def solve_order(mechanism: Mechanism, pairs, wanted, batched: bool = True) -> list[tuple[int, ...]]:
    """Batches of group indices in the order they are solved: levels from the highest down;
    within a level, the groups in reverse formation order, those of one solve together
    (``batched``) when there are BATCHED_GROUPS of them."""
    fed = feeds(mechanism, pairs)
    level: dict[int, int] = {}
    for j in sorted(wanted):  # a group feeds only earlier ones
        level[j] = 1 + max((level[i] for i in fed[j] if i in level), default=-1)
    order = []
    for k in sorted(set(level.values()), reverse=True):
        by_key: dict = {}
        for j in sorted((j for j in level if level[j] == k), reverse=True):
            group = mechanism.groups[j]
            key = (signature(group, Options()), _layout(group, pairs[j])) if batched else j
            by_key.setdefault(key, []).append(j)
        for members in by_key.values():
            order.extend([tuple(members)] if len(members) >= BATCHED_GROUPS else [(j,) for j in members])
    return order


def member_pairs(mechanism: Mechanism, pairs, rep: int, member: int):
    """(rep link -> member link, rep point -> member point, rep pair name -> member pair),
    or None where the member's pairs do not match the representative's under these names."""
    links, points = _correspondence(mechanism.groups[member], mechanism.groups[rep])
    by_key = {(p.point, p.on, p.kind): p for p in pairs[member]}
    out = {}
    for p in pairs[rep]:
        found = by_key.get((points.get(p.point), links.get(p.on), p.kind))
        if found is None:
            return None
        out[p.name] = found
    return links, points, out


def hand_backs(geom: Geometry, group_pairs_i, found: dict, by=lambda pair: pair.by) -> dict:
    """What each of a group's solved reactions puts on the earlier link it acts by, minus
    it (action and reaction), by pair name: (force, couple, moment of the force about that
    link's COM, ``by(pair)`` its name in ``geom``), each to subtract (the ground takes none)."""
    return {p.name: (found[p.name].force, found[p.name].couple,
                     moment_about_com(geom, by(p), geom.points[p.point], found[p.name].force))
            for p in group_pairs_i if p.by != GROUND}


def solve_batch(mechanism: Mechanism, pairs, batch: tuple[int, ...], geom: Geometry, known: dict, solve_one):
    """(each member's (reactions by its pair names, driving effort, ok, :func:`hand_backs`),
    the reactions stacked: per pair of the first member, (its members' pair names, forces
    (n, 2), couples (n,))) from one vmapped ``solve_one(rep index, geometry, known)`` under
    the first member's names; None where a member does not correspond to it (each is then
    solved on its own). The hand-backs are computed in the batch, so that each member's
    reactions are read apart only as outputs."""
    rep = batch[0]
    maps = [member_pairs(mechanism, pairs, rep, i) for i in batch]
    if any(m is None for m in maps):
        return None
    links = mechanism.groups[rep].links
    points = sorted({p.point for p in pairs[rep]})
    backs = [p for p in pairs[rep] if p.by != GROUND]
    coms = {link: jnp.stack([geom.coms[m[0][link]] for m in maps]) for link in links}
    coms.update({f"by {p.name}": jnp.stack([geom.coms[m[2][p.name].by] for m in maps]) for p in backs})
    sub = Geometry({name: jnp.stack([geom.points[m[1][name]] for m in maps]) for name in points}, coms,
                   {link: jnp.stack([geom.rots[m[0][link]] for m in maps]) for link in links})
    sub_known = {link: tuple(jnp.stack([known[m[0][link]][k] for m in maps]) for k in (0, 1)) for link in links}

    def solve(g, k):
        found, effort, ok = solve_one(rep, g, k)
        return found, effort, ok, hand_backs(g, pairs[rep], found, by=lambda p: f"by {p.name}")

    found, effort, ok, back = jax.vmap(solve)(sub, sub_known)
    member = lambda tree, n: jax.tree.map(lambda x: x[n], tree)  # noqa: E731
    each = [({m[2][name].name: member(r, n) for name, r in found.items()}, None if effort is None else effort[n], ok[n],
             {m[2][name].name: member(h, n) for name, h in back.items()}) for n, m in enumerate(maps)]
    return each, [(tuple(m[2][name].name for m in maps), r.force, r.couple) for name, r in found.items()]


def apply_hand_backs(known: dict, queued: dict, links) -> None:
    """Subtract from each of ``links``' known wrench what later groups handed back to it
    (``queued``: link -> [(group, pair slot, :func:`hand_backs`' value)]), in the order of a solve of
    one group after another (later groups first): the same sums to the bit."""
    for link in links:
        for _, _, (force, couple, moment) in sorted(queued.pop(link, []), key=lambda h: (-h[0], h[1])):
            f, m = known[link]
            known[link] = (f - force, m - couple - moment)


def queue_hand_backs(queued: dict, i: int, group_pairs_i, back: dict) -> None:
    """Queue group i's :func:`hand_backs` (by pair name) for the earlier links they act on."""
    for slot, pair in enumerate(group_pairs_i):
        if pair.by != GROUND:
            queued.setdefault(pair.by, []).append((i, slot, back[pair.name]))
