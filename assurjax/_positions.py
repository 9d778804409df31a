"""The position analysis q -> Pose, organised by the levels of the formation graph.

A group's *level* is one more than the highest level among the groups that place its
external joints (the driver, on the ground, is level 0). Groups at one level do not
depend on each other. The analysis traces each kind of group once per level instead of
once per group (MuJoCo MJX groups bodies of one type per tree level the same way):

- groups of one *signature* (kind, assembly mode and other static options, which links
  carry a branch predictor) at one level form a **batch**, solved by one ``jax.vmap``
  over their stacked parameters, under the names of the batch's first group;
- a run of consecutive levels that each hold one batch of the same signature, where
  every step reads the same slots of the previous step's links (a chain such as the
  N-four-bar's windows), is a **chain**, solved by one ``jax.lax.scan`` over the steps;
- a group alone at its level is solved directly, as the formation sequence reads
  (smallest and fastest program for small mechanisms).

The values are those of the group-by-group analysis (``tests/test_positions.py``
compares with it); only the size of the traced program changes: it grows with the
number of kinds and levels, not with the number of groups. The jvps (kinematic
coefficients) and everything built on them inherit the structure.

The iterative groups (triad, class IV) need a starting point: a branch predictor
``near`` (their unknown links' angles), or else a continuation from their ``guess``
at their reference coordinate ``guess_q``, which is done here, for the whole
mechanism at once (see :func:`_continued_angles`): the groups never call back into
the mechanism.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import MechanismError
from ._values import check_value
from ._geometry import V2, heading, rotate, wrap_angle
from ._jit import jit
from ._mechanism import Mechanism, Pose, check_mechanism, point_names
from .groups._base import GROUND, AbstractGroup, Frame, Link, Placement
from .groups._branch import solve_near
from .groups._newton import IterativeGroup

# shortest run of levels solved as a lax.scan; shorter runs are vmapped level by level
# (a scan adds a loop to the program: worth it only when it replaces several levels)
CHAIN_MIN_STEPS = 3


def positions(
    mechanism: Mechanism, q, *, points: Iterable[str] | None = None, near: Mapping | None = None, materialize: bool = True
) -> Pose:
    """Position analysis at the driving coordinate ``q`` (rad for a crank, m for a slider).

    Groups are solved in formation order (groups of one kind at one level of the
    formation graph together, see ``assurjax._positions``). With ``points`` given, only
    the groups those points depend on are solved, and only they are returned.
    ``near`` (link name -> angle, rad, e.g. a previous ``Pose.angles``) gives the
    iterative groups (triad, class IV) their starting angles instead of
    continuation from their reference; no gradient flows through it. It also
    makes every closed-form group take the root nearest to those angles instead
    of its fixed mode (branch continuity through singular configurations, see
    ``assurjax.groups._branch``).

    ``materialize`` (default True) makes XLA keep each group's frames in memory once
    under ``jit``; without it every output's fused loop re-derives all the groups it
    depends on, which is fastest for one or two outputs (e.g. a coupler point) and
    very slow for many outputs of a deep mechanism (see benchmarks/bench_kinematics.py).
    The values are the same either way.

    >>> mech = assurjax.load_scene("watt_sixbar").mechanism
    >>> pose = assurjax.positions(mech, 0.3)
    >>> pose.ok.shape
    (3,)
    """
    points = checked_request(mechanism, q, points, near, "positions")
    # q as an array: the jit below would take a Python float as static and compile per value
    return _positions(mechanism, jnp.asarray(q, dtype=float), points, near, materialize)


def checked_request(mechanism: Mechanism, q, points, near, what: str):
    """The mechanism, q (one number, finite where it is concrete), the point names (one may be
    a plain string) and ``near`` (link -> one angle each). Returns the point names as a tuple
    (None: all)."""
    check_mechanism(mechanism, what)
    points = None if points is None else point_names(mechanism, points, what)
    check_value(MechanismError, f"{what}: q (one driving coordinate; for many, assurjax.kinematics or jax.vmap)", q,
                shape=())
    if near is not None:
        if not isinstance(near, Mapping):
            raise MechanismError(f"{what}: near must map link names to angles (rad), e.g. a previous Pose.angles; "
                                 f"got {type(near).__name__}")
        links = set(mechanism.links)
        unknown = sorted(str(k) for k in near if k not in links)
        if unknown:
            raise MechanismError(f"{what}: near names unknown link(s) {unknown}; the mechanism has {sorted(links)}")
        for link, angle in near.items():
            check_value(MechanismError, f"{what}: near['{link}']", angle, shape=())
    return points


# A nested jit: a simulation needs the position analysis in several places (events,
# outputs, the initial state); traced once and reused, it costs less tracing and compiling.
@jit
def _positions(mechanism: Mechanism, q, points, near, materialize: bool) -> Pose:
    if points is None:
        wanted_groups = _every_group(mechanism)
        wanted_points = mechanism.point_names
    else:
        wanted_points = tuple(points)
        wanted_groups = mechanism.groups_needed(wanted_points)
    table, ok = _analysis_with_flags(mechanism, q, wanted_groups, near, materialize)
    if table.grouped:
        return _pose_stacked(mechanism, table, ok, wanted_points)
    return _pose_per_name(mechanism, table, ok, wanted_points)


def assembled(mechanism: Mechanism, q, near: Mapping | None = None):
    """One flag per group: True where it assembles at ``q`` (``positions(...).ok``, without
    building the Pose: the events and start checks of a simulation need only this)."""
    return _assembled(mechanism, jnp.asarray(q, dtype=float), near)


@jit
def _assembled(mechanism: Mechanism, q, near):
    return _analysis_with_flags(mechanism, q, _every_group(mechanism), near, True)[1]


def stacked_positions(mechanism: Mechanism, q, near: Mapping | None = None):
    """The position analysis of every point, centre of mass and link angle as stacked
    arrays, ``((points (P, 2), coms (L, 2), angles (L,), rotations (L, 2)), ok, (point names,
    link names))``, rows in the order of :func:`positions`' dicts; ``rotations``: the links'
    (cos, sin) as the analysis found them (no trigonometry). What is computed on them (the
    kinematic coefficients, the reduction) takes a few operations instead of a few per name."""
    return _stacked_positions(mechanism, jnp.asarray(q, dtype=float), near)


@jit
def _stacked_positions(mechanism: Mechanism, q, near):
    table, ok = _analysis_with_flags(mechanism, q, _every_group(mechanism), near, True)
    points = mechanism.point_names
    moving = tuple(name for name in table.links if name != GROUND)
    if table.grouped:
        return _stacked_arrays(mechanism, table, points, moving), ok, (points, moving)
    pose = _pose_per_name(mechanism, table, ok, points)  # small mechanisms: name by name fuses best
    stacked = tuple(jnp.stack([d[k] for k in names]) for d, names in
                    ((pose.points, points), (pose.coms, moving), (pose.angles, moving)))
    return stacked + (jnp.stack([table[k].rot for k in moving]),), ok, (points, moving)


def _every_group(mechanism: Mechanism) -> tuple[int, ...]:
    return tuple(range(len(mechanism.groups)))


def _analysis_with_flags(mechanism: Mechanism, q, groups: tuple[int, ...], near, materialize: bool):
    """:func:`analysis` of ``groups`` and one ok flag per group of the mechanism (True where not solved)."""
    table, oks = analysis(mechanism, q, groups, near, materialize=materialize)
    return table, jnp.stack([oks.get(i, jnp.array(True)) for i in range(len(mechanism.groups))])


def _pose_per_name(mechanism: Mechanism, table: FrameTable, ok, wanted_points) -> Pose:
    """The Pose computed name by name (small mechanisms: fuses into the solve's loops)."""
    links = mechanism.all_links()
    placed = Placement(links, dict(mechanism.owner), table)
    moving = [name for name in table.links if name != GROUND]
    return Pose(
        points={p: placed.point(p) for p in wanted_points},
        coms={k: table[k].origin + rotate(links[k].com, table[k].rot) for k in moving},
        angles={k: table[k].angle for k in moving},
        ok=ok,
    )


def _pose_stacked(mechanism: Mechanism, table: FrameTable, ok, wanted_points) -> Pose:
    """The Pose computed for all points, centres of mass and angles at once from the
    stacked frames, then split by name (a few operations per name instead of a dozen)."""
    moving = [name for name in table.links if name != GROUND]
    points, coms, angles, _ = _stacked_arrays(mechanism, table, wanted_points, moving)
    return Pose(
        points={p: points[n] for n, p in enumerate(wanted_points)},
        coms={k: coms[n] for n, k in enumerate(moving)},
        angles={k: angles[n] for n, k in enumerate(moving)},
        ok=ok,
    )


def _stacked_arrays(mechanism: Mechanism, table: FrameTable, points, moving):
    """(points (P, 2), coms (L, 2), angles (L,), rotations (L, 2)) of the named points and
    moving links, from the stacked frames."""
    links = mechanism.all_links()
    owner = dict(mechanism.owner)
    origins, rots = table.stacked()

    def place(local, rows):
        rows = np.asarray(rows, dtype=int)
        return origins[rows] + rotate(local, rots[rows])

    moving_rots = rots[np.asarray([table.index(k) for k in moving], dtype=int)]
    return (place(_stack_params([links[owner[p]].points[p] for p in points]), [table.index(owner[p]) for p in points]),
            place(_stack_params([links[k].com for k in moving]), [table.index(k) for k in moving]),
            heading(moving_rots), moving_rots)


def _stack_params(values: list, dtype=float):
    """Mechanism parameters (one array each) stacked along a new leading axis."""
    return jnp.stack([jnp.asarray(v, dtype=dtype) for v in values]) if values else jnp.zeros((0, 2), dtype=dtype)


class FrameTable:
    """The frames of the links placed so far (trace time), kept as the blocks of rows in
    which they were solved (one block per group, batch or chain); read like a dict of
    :class:`Frame` (a link's frame is sliced from its block once, when first read).
    ``grouped``: some block holds more than one group."""

    def __init__(self):
        self.blocks: list[tuple] = []
        self.rows: dict[str, tuple[int, int]] = {}
        self.frames: dict[str, Frame] = {}
        self.links: list[str] = []
        self.grouped = False

    def add_frames(self, frames: dict[str, Frame]) -> None:
        """One group's frames (kept as they are for reading)."""
        names = list(frames)
        self.add_block(names, jnp.stack([frames[k].origin for k in names]), jnp.stack([frames[k].rot for k in names]))
        self.frames.update(frames)

    def add_block(self, names: list[str], origins, rots) -> None:
        """Frames as rows: ``origins``, ``rots`` of shape (len(names), 2)."""
        b = len(self.blocks)
        self.blocks.append((origins, rots))
        for r, k in enumerate(names):
            self.rows[k] = (b, r)
            self.links.append(k)

    def __getitem__(self, link: str) -> Frame:
        if link not in self.frames:
            b, r = self.rows[link]
            origins, rots = self.blocks[b]
            self.frames[link] = Frame(origins[r], rots[r])
        return self.frames[link]

    def __contains__(self, link: str) -> bool:
        return link in self.rows

    def stacked(self):
        """(origins, rots) of every placed link, rows in :meth:`index` order."""
        return jnp.concatenate([o for o, _ in self.blocks]), jnp.concatenate([r for _, r in self.blocks])

    def index(self, link: str) -> int:
        b, r = self.rows[link]
        return sum(len(o) for o, _ in self.blocks[:b]) + r


# --------------------------------------------------------------------------- the plan


class Options(NamedTuple):
    """How one group is solved: ``tracked`` (indices of its links that have a branch
    predictor), ``from_guess`` (an iterative group starts from its guess) and ``loose``
    (an iterative group stops at continuation tolerance)."""

    tracked: tuple[int, ...] = ()
    from_guess: bool = False
    loose: bool = False


class Batch(NamedTuple):
    """Groups (indices) of one signature (``key``) at one level, solved together."""

    groups: tuple[int, ...]
    key: tuple


class Chain(NamedTuple):
    """Consecutive levels, one batch each, every step fed by the previous one: ``steps``
    are the batches; ``sources[j]`` says where external point j of every member comes
    from in steps after the first: None (from links placed before the chain) or the
    (member, link slot) arrays of the previous step."""

    steps: tuple[Batch, ...]
    sources: tuple


def group_levels(mechanism: Mechanism, groups: Iterable[int]) -> dict[int, int]:
    """Level of each group: 0 for the driver, else 1 + the highest level of the groups
    placing its external joints."""
    owner = dict(mechanism.owner)
    group_of = {link: i for i, g in enumerate(mechanism.groups) for link in g.links}
    level: dict[int, int] = {}
    for i in sorted(groups):
        sources = [group_of[owner[p]] for p in mechanism.groups[i].external_points() if owner[p] != GROUND]
        level[i] = 1 + max((level[s] for s in sources), default=-1)
    return level


def _name_fields(group: AbstractGroup) -> tuple[list[str], list[str]]:
    """The static fields of a group that hold names: (link-name fields, point-name fields)."""
    link_fields, point_fields = [], []
    for f in dataclasses.fields(group):
        if not f.metadata.get("static", False) or f.name == "name":
            continue
        v = getattr(group, f.name)
        if isinstance(v, str) or (isinstance(v, tuple) and v and all(isinstance(x, str) for x in v)):
            (link_fields if f.name == "links" else point_fields).append(f.name)
    return link_fields, point_fields


def _names(group: AbstractGroup, fields: list[str]) -> tuple[str, ...]:
    out = []
    for f in fields:
        v = getattr(group, f)
        out.extend((v,) if isinstance(v, str) else v)
    return tuple(out)


def signature(group: AbstractGroup, options: Options):
    """What groups must share to be solved by one trace: the class, every static field
    that is not a name, the shapes of the array fields, the name pattern (which names
    repeat within the group) and the solve options."""
    link_fields, point_fields = _name_fields(group)
    static = tuple(
        (f.name, getattr(group, f.name))
        for f in dataclasses.fields(group)
        if f.metadata.get("static", False) and f.name != "name" and f.name not in link_fields + point_fields
    )
    arrays = tuple((jnp.shape(x), jnp.result_type(x)) for x in jax.tree.leaves(_renamed(group, group)))
    pattern = tuple(_names(group, point_fields).index(p) for p in _names(group, point_fields))
    return type(group), static, arrays, pattern, options


def _renamed(member: AbstractGroup, rep: AbstractGroup) -> AbstractGroup:
    """``member`` under the names of ``rep`` (same signature): its arrays, rep's names.
    Dict fields keyed by point names (an iterative group's guess) are re-keyed."""
    link_fields, point_fields = _name_fields(rep)
    point_map = dict(zip(_names(member, point_fields), _names(rep, point_fields)))
    changes = {f: getattr(rep, f) for f in ["name", *link_fields, *point_fields]}
    for f in dataclasses.fields(member):
        v = getattr(member, f.name)
        if not f.metadata.get("static", False) and isinstance(v, dict):
            changes[f.name] = {point_map[k]: x for k, x in v.items()}
    return dataclasses.replace(member, **changes)


def _correspondence(member: AbstractGroup, rep: AbstractGroup) -> tuple[dict[str, str], dict[str, str]]:
    """(rep link -> member link, rep point -> member point)."""
    link_fields, point_fields = _name_fields(rep)
    return (dict(zip(_names(rep, link_fields), _names(member, link_fields))),
            dict(zip(_names(rep, point_fields), _names(member, point_fields))))


def plan(mechanism: Mechanism, wanted: tuple[int, ...], options: dict[int, Options], *, batched: bool = True) -> list:
    """The solve order: a list of :class:`Batch` (one or more groups of one level) and
    :class:`Chain` items, level by level. ``batched=False``: one group per batch, in
    formation order (the group-by-group reference)."""
    if not batched:
        return [Batch((i,), ()) for i in wanted]
    level = group_levels(mechanism, wanted)
    by_level: dict[int, dict] = {}
    for i in wanted:
        sig = signature(mechanism.groups[i], options[i])
        by_level.setdefault(level[i], {}).setdefault(sig, []).append(i)
    levels = [[Batch(tuple(members), key) for key, members in by_level[k].items()] for k in sorted(by_level)]
    out: list = []
    k = 0
    while k < len(levels):
        steps, sources = _chain_from(mechanism, levels, k)
        if len(steps) >= CHAIN_MIN_STEPS:
            out.append(Chain(tuple(steps), sources))
            k += len(steps)
        else:
            out.extend(levels[k])
            k += 1
    return out


def _chain_from(mechanism: Mechanism, levels: list, start: int):
    """The longest chain starting at level ``start`` (its batches and input sources)."""
    if len(levels[start]) != 1:
        return [], ()
    steps, sources = [levels[start][0]], None
    chain_links = set(_batch_links(mechanism, steps[0]))
    for k in range(start + 1, len(levels)):
        if len(levels[k]) != 1:
            break
        step = levels[k][0]
        if step.key != steps[0].key or len(step.groups) != len(steps[0].groups):
            break
        found = _step_sources(mechanism, steps[-1], step, chain_links)
        if found is None or (sources is not None and not _same_sources(found, sources)):
            break
        steps.append(step)
        chain_links.update(_batch_links(mechanism, step))
        sources = found
    return steps, sources


def _batch_links(mechanism: Mechanism, batch: Batch) -> list[str]:
    return [link for i in batch.groups for link in mechanism.groups[i].links]


def _same_sources(a, b) -> bool:
    def same(x, y):
        return (x is None) == (y is None) and (x is None or all(np.array_equal(u, v) for u, v in zip(x, y)))

    return all(same(x, y) for x, y in zip(a, b))


def _step_sources(mechanism: Mechanism, previous: Batch, step: Batch, chain_links: set):
    """For each external point of ``step``'s members: None when every member reads it
    from links placed before the chain, or the (member index, link slot) arrays of the
    link in ``previous`` that carries it. None overall when a step mixes the two, reads
    an earlier step of the chain, or nothing of the previous one."""
    owner = dict(mechanism.owner)
    slot_of = {link: (m, k) for m, i in enumerate(previous.groups) for k, link in enumerate(mechanism.groups[i].links)}
    rep = mechanism.groups[step.groups[0]]
    sources = []
    for j in range(len(rep.external_points())):
        owners = [owner[mechanism.groups[i].external_points()[j]] for i in step.groups]
        if all(o in slot_of for o in owners):
            sources.append((np.array([slot_of[o][0] for o in owners]), np.array([slot_of[o][1] for o in owners])))
        elif any(o in chain_links for o in owners):
            return None
        else:
            sources.append(None)
    return tuple(sources) if any(s is not None for s in sources) else None


# --------------------------------------------------------------------------- the analysis


def analysis(mechanism: Mechanism, q, wanted: tuple[int, ...], near, *, materialize: bool = True,
             from_guess: frozenset = frozenset(), loose: frozenset = frozenset(), batched: bool = True):
    """The frames of the links of the ``wanted`` groups (a :class:`FrameTable`) and the
    groups' ok flags ({group index: flag}).

    ``near``: branch predictor (link angles, rad) or None. Iterative groups whose
    unknown links have no predictor are continued from their reference first
    (:func:`_continued_angles`), except those in ``from_guess``, which start from their
    guess; those in ``loose`` stop at continuation tolerance. ``batched=False`` solves
    group by group in formation order (the reference the tests compare with)."""
    near = None if near is None else dict(near)
    extra_ok: dict[int, object] = {}
    while True:
        pending = [i for i in wanted if i not in from_guess and _needs_start(mechanism.groups[i], near)]
        if not pending:
            break
        angles, oks = _continued_angles(mechanism, q, pending, near, batched)
        near = {**(near or {}), **angles}
        extra_ok.update(oks)
    options = {i: _options(mechanism.groups[i], near, i in from_guess, i in loose) for i in wanted}
    table, oks = solve_plan(mechanism, q, plan(mechanism, wanted, options, batched=batched), options, near, materialize)
    for i, ok in extra_ok.items():
        oks[i] = oks[i] & ok
    return table, oks


def _needs_start(group: AbstractGroup, near) -> bool:
    return isinstance(group, IterativeGroup) and not (near is not None and all(k in near for k in group.unknown_links()))


def _options(group: AbstractGroup, near, from_guess: bool, loose: bool) -> Options:
    tracked = tuple(k for k, link in enumerate(group.links) if near is not None and link in near)
    return Options(tracked, from_guess, loose)


def solve_plan(mechanism: Mechanism, q, items: list, options: dict[int, Options], near, materialize: bool):
    """Solve the plan's items in order into a :class:`FrameTable`; returns it and the ok flags."""
    links = mechanism.all_links()
    owner = dict(mechanism.owner)
    table = FrameTable()
    table.add_frames({GROUND: Frame(jnp.zeros(2), jnp.array([1.0, 0.0]))})
    placed = Placement(links, owner, table, near=near)
    oks: dict[int, object] = {}
    for item in items:
        barrier = jax.lax.optimization_barrier if materialize else (lambda x: x)  # frames in memory once (see positions())
        if isinstance(item, Batch) and len(item.groups) == 1:
            i = item.groups[0]
            one = Placement(links, owner, table, near=near, from_guess=options[i].from_guess, loose=options[i].loose)
            frames, ok = barrier(solve_near(mechanism.groups[i], links, one, q))  # fixed mode unless near is given
            table.add_frames(frames)
            oks[i] = ok
            continue
        table.grouped = True
        solve = _solve_chain if isinstance(item, Chain) else _solve_batch
        names, origins, rots, new_oks = solve(mechanism, item, placed, q, options, near)
        origins, rots, new_oks = barrier((origins, rots, new_oks))
        table.add_block(names, origins, rots)
        oks.update({i: new_oks[n] for n, i in enumerate(_item_groups(item))})
    return table, oks


def _item_groups(item) -> tuple[int, ...]:
    return tuple(i for step in item.steps for i in step.groups) if isinstance(item, Chain) else item.groups


class Inputs:
    """What a batched group reads instead of a :class:`Placement`: the global positions
    of its external points and the rotations of the links carrying them, its own links'
    local points (all under the batch representative's names) and its solve options."""

    def __init__(self, links, points, rotations, near, options: Options):
        self.links, self.points, self.rotations, self.near = links, points, rotations, near
        self.from_guess, self.loose = options.from_guess, options.loose

    def point(self, name):
        return self.points[name]

    def xy(self, name):
        return V2.of(self.points[name])

    def rotation_of_owner(self, name):
        return self.rotations[name]

    def local(self, link, name):
        return self.links[link].points[name]


def _members_data(mechanism: Mechanism, members: list[int], rep: AbstractGroup, near):
    """Per-member data stacked along a leading axis, under the names of ``rep``:
    (group arrays, local points of the group's links, branch predictor), the static
    part of the group, and the members' (link, point) name maps."""
    groups = [mechanism.groups[i] for i in members]
    renamed = [_renamed(g, rep) for g in groups]
    static = eqx.filter(renamed[0], eqx.is_array, inverse=True)
    group_arrays = jax.tree.map(lambda *xs: jnp.stack(xs), *[eqx.filter(g, eqx.is_array) for g in renamed])
    maps = [_correspondence(g, rep) for g in groups]
    local = {
        link: {p: _stack_params([mechanism.links[lm[link]].points[pm[p]] for lm, pm in maps]) for p in pts}
        for link, pts in rep.required_points().items()
    }
    tracked = [link for link in rep.links if near is not None and all(lm[link] in near for lm, _ in maps)]
    near_b = {link: _stack_params([near[lm[link]] for lm, _ in maps]) for link in tracked}
    return (group_arrays, local, near_b), static, maps


def _solve_members(static, q, options: Options, any_near: bool):
    """The function of one member's (group arrays, local points, predictor, external
    point positions, their owners' rotations) to (frames, ok), to be vmapped."""

    def solve(group_arrays, local, near, points, rotations):
        group = eqx.combine(group_arrays, static)
        zero = jnp.zeros((), dtype=q.dtype)
        links = {k: Link(points=v, com=jnp.zeros(2, dtype=q.dtype), mass=zero, inertia=zero) for k, v in local.items()}
        inputs = Inputs(links, points, rotations, near if any_near else None, options)
        return solve_near(group, links, inputs, q)

    return solve


def _external(mechanism: Mechanism, maps, rep: AbstractGroup, placed: Placement, names=None):
    """Global positions of the members' external points (``names`` of rep's, default
    all) and the rotations of the links carrying them, stacked, under rep's names:
    one gather from the frames placed so far."""
    owner = dict(mechanism.owner)
    table = placed.frames
    origins, rots = table.stacked()
    points, rotations = {}, {}
    for p in rep.external_points() if names is None else names:
        members = [pm[p] for _, pm in maps]
        rows = np.asarray([table.index(owner[x]) for x in members], dtype=int)
        local = _stack_params([placed.links[owner[x]].points[x] for x in members])
        points[p] = origins[rows] + rotate(local, rots[rows])
        rotations[p] = rots[rows]
    return points, rotations


def _rows(frames: dict[str, Frame], rep: AbstractGroup):
    """Batched frames {rep link: Frame((..., 2), (..., 2))} as rows (members, then links)."""
    origins = jnp.stack([frames[k].origin for k in rep.links], axis=-2)
    rots = jnp.stack([frames[k].rot for k in rep.links], axis=-2)
    return origins.reshape(-1, 2), rots.reshape(-1, 2)


def _solve_batch(mechanism: Mechanism, batch: Batch, placed: Placement, q, options, near):
    """One vmapped solve of the batch's groups: (link names, origins, rots, ok flags)."""
    rep = mechanism.groups[batch.groups[0]]
    data, static, maps = _members_data(mechanism, list(batch.groups), rep, near)
    points, rotations = _external(mechanism, maps, rep, placed)
    frames, ok = jax.vmap(_solve_members(static, q, options[batch.groups[0]], near is not None))(*data, points, rotations)
    names = [lm[k] for lm, _ in maps for k in rep.links]
    return (names, *_rows(frames, rep), ok)


def _solve_chain(mechanism: Mechanism, chain: Chain, placed: Placement, q, options, near):
    """The first step as a batch, the others by ``lax.scan``: the carry is the previous
    step's frames (member, link slot); points read from it are placed from their local
    coordinates inside the loop, the others are computed before it, all steps at once."""
    first, rest = chain.steps[0], chain.steps[1:]
    rep = mechanism.groups[first.groups[0]]
    names0, origins0, rots0, ok0 = _solve_batch(mechanism, first, placed, q, options, near)
    n_steps, n_members, n_links = len(rest), len(first.groups), len(rep.links)
    members = [i for step in rest for i in step.groups]  # step-major
    data, static, maps = _members_data(mechanism, members, rep, near)
    owner = dict(mechanism.owner)
    carried = [p for j, p in enumerate(rep.external_points()) if chain.sources[j] is not None]
    fixed = [p for j, p in enumerate(rep.external_points()) if chain.sources[j] is None]
    fixed_points, fixed_rots = _external(mechanism, maps, rep, placed, fixed)
    carried_local = {p: _stack_params([placed.links[owner[pm[p]]].points[pm[p]] for _, pm in maps]) for p in carried}
    by_step = lambda x: x.reshape((n_steps, n_members) + x.shape[1:])  # noqa: E731
    xs = jax.tree.map(by_step, (data, fixed_points, fixed_rots, carried_local))
    solve = jax.vmap(_solve_members(static, q, options[first.groups[0]], near is not None))
    sources = {p: chain.sources[j] for j, p in enumerate(rep.external_points())}

    def body(carry, x):
        origins, rots = carry  # (member, link slot, 2)
        data, points, rotations, local = x
        points, rotations = dict(points), dict(rotations)
        for p in carried:
            m, k = sources[p]
            points[p] = origins[m, k] + rotate(local[p], rots[m, k])
            rotations[p] = rots[m, k]
        frames, ok = solve(*data, points, rotations)
        new = tuple(a.reshape(n_members, n_links, 2) for a in _rows(frames, rep))
        return new, (new, ok)

    init = (origins0.reshape(n_members, n_links, 2), rots0.reshape(n_members, n_links, 2))
    _, ((origins, rots), ok) = jax.lax.scan(body, init, xs)
    names = names0 + [lm[k] for lm, _ in maps for k in rep.links]
    return (names, jnp.concatenate([origins0, origins.reshape(-1, 2)]), jnp.concatenate([rots0, rots.reshape(-1, 2)]),
            jnp.concatenate([ok0, ok.reshape(-1)]))


# --------------------------------------------------------------------------- continuation


def _stop(tree):
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


# Continuation step control (see _continued_angles). A step is kept when every corrector
# converged and the corrected angles fit the step: the trapezoidal rule with the tangents
# at both ends (third-order accurate on a smooth branch) predicts the change of the angles
# within STEP_TRUST of the predicted move (plus STEP_SLACK rad). Otherwise the step
# overshot a limit position or landed on another branch that passes close (near a singular
# configuration): it is retried at half the length, down to 2**-MAX_HALVINGS of the
# longest step (then the branch ends before q). A step never predicts a turn of more than
# LONGEST_MOVE (the relative test needs a move that is not huge where the angles turn fast,
# next to a limit position).
STEP_TRUST = 0.1
STEP_SLACK = 1e-4  # rad: branches closer than this are one branch to the continuation
LONGEST_MOVE = 0.25  # rad
MAX_HALVINGS = 12


def _continued_angles(mechanism: Mechanism, q, pending: list[int], near, batched: bool):
    """Starting angles at q for the iterative groups ``pending`` that share the first
    one's reference (guess_q) and substeps: each is solved from its guess at guess_q,
    then the mechanism is followed to q in steps of at most (q - guess_q) / substeps,
    halved where needed (see STEP_TRUST); each step predicts along the tangent
    d(angles)/dq (a jvp of the analysis: the implicit function theorem through the solves)
    and corrects with a loose Newton solve. For a crank the way is q - guess_q wrapped to
    (-pi, pi], and where that does not reach q the other way round (a crank that cannot
    turn fully, drawn nearer one end of its range than pi: the short way crosses the range
    where it does not assemble). Returns the angles at q (loosely corrected: the caller's
    final solve corrects them, and only it is differentiated) and, per group, whether the
    continuation reached q (when it did not: the groups whose last corrector failed, or
    all of them when the last step was rejected for another reason)."""
    first = mechanism.groups[pending[0]]
    if first.guess_q is None:
        raise MechanismError(f"{first.describe()}: guess_q is not set (the coordinate at which 'guess' places the internal joints)")
    key = (first.guess_q, first.substeps)
    swept = [i for i in pending if (mechanism.groups[i].guess_q, mechanism.groups[i].substeps) == key]
    unknown = tuple(k for i in swept for k in mechanism.groups[i].unknown_links())
    needed = mechanism.groups_needed(links=unknown)
    mech, near = _stop(mechanism), _stop(near)
    q = jax.lax.stop_gradient(q)
    q_ref = jnp.asarray(first.guess_q, dtype=q.dtype)
    swept_set = frozenset(swept)
    longest = 1.0 / first.substeps  # steps are fractions of the way from q_ref to q
    as_dict = lambda z: dict(zip(unknown, z))  # noqa: E731

    def follow(delta):
        """(angles at q_ref + delta, each swept group's flag), followed along delta."""

        def corrected(s, z, from_guess):
            """Angles of the unknown links at q_ref + s delta after a loose solve, and each swept group's convergence flag."""
            start = near if from_guess else {**(near or {}), **z}
            table, oks = analysis(mech, q_ref + s * delta, needed, start, materialize=False,
                                   from_guess=swept_set if from_guess else frozenset(), loose=swept_set, batched=batched)
            return jnp.stack([heading(table[k].rot) for k in unknown]), jnp.stack([oks[i] for i in swept])

        def with_tangent(s, z, from_guess):
            """Corrected angles at s, their tangent d(angles)/ds and the flags."""
            z_new, t, ok = jax.jvp(lambda ss: corrected(ss, z, from_guess), (s,), (jnp.ones_like(s),), has_aux=True)
            return z_new, jnp.where(jnp.isfinite(t), t, 0.0), ok  # singular: no tangent

        zero = jnp.zeros((), dtype=q.dtype)
        z0, t0, ok0 = with_tangent(zero, None, True)  # at the reference, from the guesses
        budget = 4 * first.substeps + 4 * MAX_HALVINGS  # steps, accepted or not

        def unfinished(state):
            s, _, _, h, _, n = state
            return (s < 1.0) & (h >= longest * 2.0**-MAX_HALVINGS) & (n < budget)

        def step(state):
            s, z, t, h, _, n = state
            h = jnp.minimum(h, LONGEST_MOVE / jnp.maximum(jnp.max(jnp.abs(t)), 1e-30))  # where the angles turn fast
            last = h >= 1.0 - s
            h = jnp.where(last, 1.0 - s, h)
            move = t * h
            z_new, t_new, converged = with_tangent(s + h, as_dict(z + move), False)
            # the trapezoidal rule with the tangents at both ends predicts the chord to third order
            mismatch = jnp.max(jnp.abs(wrap_angle(z_new - z) - (t + t_new) * h / 2))
            close = mismatch <= STEP_TRUST * jnp.max(jnp.abs(move)) + STEP_SLACK
            accept = jnp.all(converged) & close
            s = jnp.where(accept, jnp.where(last, 1.0, s + h), s)
            z, t = jnp.where(accept, z_new, z), jnp.where(accept, t_new, t)
            h = jnp.where(accept, jnp.minimum(2.0 * h, longest), h / 2.0)
            return s, z, t, h, converged, n + 1

        first_step = jnp.where(delta == 0, 1.0, longest)  # at the reference itself: one step, to q
        start = (zero, z0, t0, first_step.astype(q.dtype), ok0, jnp.zeros((), dtype=int))
        s, z, _, _, converged, _ = jax.lax.while_loop(unfinished, step, start)
        reached = s >= 1.0
        return z, ok0 & (reached | (converged & ~jnp.all(converged)))

    delta = q - q_ref
    if mechanism.driver.kind != "crank":
        z, ok = follow(delta)
        return as_dict(z), {i: ok[n] for n, i in enumerate(swept)}
    short = wrap_angle(delta)
    ways = jnp.stack([short, short - 2.0 * jnp.pi * jnp.where(short >= 0, 1.0, -1.0)])

    def attempt(carry, i):  # the short way; the other way round only where it failed
        z, ok = carry

        def run():
            z_new, ok_new = follow(ways[i])
            take = (i == 0) | (~jnp.all(ok) & jnp.all(ok_new))
            return jnp.where(take, z_new, z), jnp.where(take, ok_new, ok)

        # one trace of the continuation for both ways; the second runs only where some member needs it
        return jax.lax.cond((i == 0) | eqxi.unvmap_any(~jnp.all(ok)), run, lambda: carry), None

    unset = (jnp.zeros(len(unknown), dtype=q.dtype), jnp.zeros(len(swept), dtype=bool))
    (z, ok), _ = jax.lax.scan(attempt, unset, jnp.arange(2))
    return as_dict(z), {i: ok[n] for n, i in enumerate(swept)}
