"""The Mechanism: a formation sequence of groups (static) and its parameters (arrays).
The position analysis q -> Pose is in ``assurjax._positions`` (re-exported here)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._errors import MechanismError
from ._repr import value_pdoc
from ._values import check_value, concrete as _concrete
from .groups._base import GROUND, AbstractGroup, Link


# A mechanism's size: the scene loader's bound on a table (its MAX_ENTRIES), room for
# assurjax.n_four_bar(1000) (2001 links, 1001 groups, 1001 ground points, 4002 points on its
# links), whose constructor takes ~0.6 s; the checks grow with the size, 10^6 links ran for minutes.
MAX_PARTS = 2500  # ground points, links, groups: each
MAX_POINTS = 4 * MAX_PARTS  # the points of all links together


COM_PREFIX = "com:"
"""``"com:<link>"`` names a link's centre of mass where a load's point goes; no point may be so named."""


class Pose(eqx.Module):
    """Result of the position analysis at one driving coordinate q.

    ``points``: global position (m) of every named point; ``coms``: global
    position of every link's centre of mass; ``angles``: angle (rad) of every
    link's local x axis, counterclockwise from +x; ``ok``: one flag per group,
    False where that group cannot assemble (the values are then finite but
    meaningless).
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    points: dict[str, Array]
    coms: dict[str, Array]
    angles: dict[str, Array]
    ok: Array


class Mechanism(eqx.Module):
    """A one-degree-of-freedom planar mechanism.

    ``ground``: fixed points (m, global frame). ``links``: moving links with their
    named points in their own frames. ``groups``: the formation sequence, the
    driver first. Point names are global: a name shared by two links (or a link
    and the ground) is the revolute joint between them.

    Build-time checks (structure and, when the values are concrete, lengths,
    masses and inertias) raise :class:`MechanismError` naming the culprit. A mechanism has
    at most 2500 ground points, links and groups each, and 10000 points on its links in all
    (``MAX_PARTS``, ``MAX_POINTS``: a scene file's bound, room for ``n_four_bar(1000)``).
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    ground: dict[str, Array]
    links: dict[str, Link]
    groups: tuple[AbstractGroup, ...]
    owner: tuple[tuple[str, str], ...] = eqx.field(static=True)
    name: str = eqx.field(static=True)

    def __init__(self, ground: Mapping, links: Mapping[str, Link], groups: Iterable[AbstractGroup], *, name: str = "mechanism"):
        groups = tuple(groups)
        _check_size(name, ground, links, groups)  # before any value is converted or checked
        self.ground = {k: jnp.asarray(v, dtype=float) for k, v in ground.items()}
        self.links = dict(links)
        self.groups = groups
        _check_kinds(self.links, self.groups)
        self.name = name
        self.owner = tuple(_check_structure(self.ground, self.links, self.groups).items())
        _check_values(self)

    @property
    def driver(self) -> AbstractGroup:
        return self.groups[0]

    @property
    def group_names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.groups)

    @property
    def point_names(self) -> tuple[str, ...]:
        return tuple(p for p, _ in self.owner)

    def all_links(self) -> dict[str, Link]:
        """The moving links plus the ground as a massless link carrying the fixed points."""
        zero = jnp.zeros(())
        ground = Link(points=self.ground, com=jnp.zeros(2), mass=zero, inertia=zero)
        return {GROUND: ground, **self.links}

    def groups_needed(self, points: Iterable[str] = (), links: Iterable[str] = ()) -> tuple[int, ...]:
        """Indices of the groups that the given points and links depend on."""
        owner = dict(self.owner)
        group_of = {link: i for i, g in enumerate(self.groups) for link in g.links}
        todo = [group_of[owner[p]] for p in points if owner[p] != GROUND]
        todo += [group_of[link] for link in links]
        needed = set()
        while todo:
            i = todo.pop()
            if i in needed:
                continue
            needed.add(i)
            for p in self.groups[i].external_points():
                if owner[p] != GROUND:
                    todo.append(group_of[owner[p]])
        return tuple(sorted(needed))


def _check_size(name: str, ground: Mapping, links: Mapping, groups: tuple) -> None:
    for field, table in (("ground", ground), ("links", links), ("groups", groups)):
        if len(table) > MAX_PARTS:
            raise MechanismError(f"mechanism '{name}': {field} has {len(table)} entries; at most {MAX_PARTS} (the "
                                 "checks and the traced program grow with the size)")
    points = sum(len(link.points) for link in links.values() if isinstance(link, Link))
    if points > MAX_POINTS:
        raise MechanismError(f"mechanism '{name}': links has {points} points in all; at most {MAX_POINTS} (the checks "
                             "and the traced program grow with the size)")


def _check_structure(ground, links, groups) -> dict[str, str]:
    """Names, formation order and the Gruebler count; returns point -> owning link."""
    if GROUND in links:
        raise MechanismError(f"link name '{GROUND}' is reserved for the fixed frame")
    if not groups:
        raise MechanismError("the formation sequence is empty: it must start with a driver")
    if not groups[0].is_driver:
        raise MechanismError(f"{groups[0].describe()} comes first, but the formation sequence must start with a driver (crank or slider)")
    seen_groups, placed_links = set(), {}
    owner = {p: GROUND for p in ground}
    for g in groups:
        if g.name in seen_groups:
            raise MechanismError(f"duplicate group name '{g.name}'")
        seen_groups.add(g.name)
        if g.is_driver and g is not groups[0]:
            raise MechanismError(f"{g.describe()}: only one driver is allowed (one degree of freedom)")
        for p in g.external_points():
            if p not in owner:
                raise MechanismError(f"{g.describe()} uses point '{p}', which no earlier group (nor the ground) defines")
        for link in g.links:
            if link not in links:
                raise MechanismError(f"{g.describe()} uses unknown link '{link}'")
            if link in placed_links:
                raise MechanismError(f"{g.describe()}: link '{link}' is already placed by group '{placed_links[link]}'")
            placed_links[link] = g.name
        for link, needed in g.required_points().items():
            for p in needed:
                if p not in links[link].points:
                    raise MechanismError(f"{g.describe()}: link '{link}' has no point '{p}'")
        for link in g.links:
            for p in links[link].points:
                owner.setdefault(p, link)
    check_point_names(owner)
    unused = [name for name in links if name not in placed_links]
    if unused:
        raise MechanismError(f"link(s) {unused} belong to no group of the formation sequence")
    dof, n, pairs = gruebler(ground, links, groups)
    if dof != 1:
        raise MechanismError(
            f"the mechanism has {dof} degrees of freedom by Gruebler's count (3*{n} - 2*{pairs}); expected 1: "
            "check the point names shared between links (a shared name is a joint)"
        )
    return owner


PAIR_MARKS = "[]/"
"""Characters of the generated pair names ('B[rocker]': one pair of a joint of three links or
more; 'ram/guide': a prismatic pair), which no point's name may hold."""


def check_point_names(names: Iterable[str]) -> None:
    """Refuse the point names the package generates for other things (a centre of mass, a pair)."""
    for name in names:
        if not name:  # nothing for a load, an output or a message to name it by
            raise MechanismError("a point has an empty name ''; give it one (e.g. 'C')")
        if name.startswith(COM_PREFIX):
            raise MechanismError(f"point name '{name}': names starting with '{COM_PREFIX}' are reserved for centres of "
                                 "mass ('com:<link>')")
        marks = [c for c in PAIR_MARKS if c in name]
        if marks:
            raise MechanismError(f"point name '{name}': the characters {marks} are reserved for the names of pairs "
                                 "('B[rocker]', one pair of a joint shared by three links or more; 'ram/guide', a "
                                 "prismatic pair); rename the point")


def gruebler(ground, links, groups) -> tuple[int, int, int]:
    """(DOF, moving links, lower pairs): revolutes from shared point names plus declared prismatic pairs."""
    carriers: dict[str, int] = {p: 1 for p in ground}
    for link in links.values():
        for p in link.points:
            carriers[p] = carriers.get(p, 0) + 1
    pairs = sum(c - 1 for c in carriers.values()) + sum(g.n_prismatic for g in groups)
    return 3 * len(links) - 2 * pairs, len(links), pairs


def _check_kinds(links: dict, groups: tuple) -> None:
    for name, link in links.items():
        if not isinstance(link, Link):
            raise MechanismError(f"link '{name}': expected an assurjax.Link, got {type(link).__name__}")
    for g in groups:
        if not isinstance(g, AbstractGroup):
            raise MechanismError(f"groups: expected Assur groups (assurjax.groups.RRR, ...), got {type(g).__name__}")


def value_fields(mech: Mechanism):
    """(what, value, its shape, its ranges) of the mechanism's points, and its links' centres
    of mass, masses and inertias (read by :func:`_check_values`, and member by member for a
    batch by ``_sweep.check_batch_values``; the groups' guides are checked on their own)."""
    for p, xy in mech.ground.items():
        yield f"ground point '{p}'", xy, (2,), {}
    for name, link in mech.links.items():
        for p, xy in link.points.items():
            yield f"link '{name}': point '{p}'", xy, (2,), {}
        yield f"link '{name}': com", link.com, (2,), {}
        yield f"link '{name}': mass", link.mass, (), {"nonnegative": True}
        yield f"link '{name}': inertia", link.inertia, (), {"nonnegative": True}


_VALUES_CHECKED: dict = {}  # id -> the mechanisms whose values check_values_once passed (kept: ids stay theirs)


def check_values_once(mech: Mechanism) -> None:
    """:func:`_check_values` of a mechanism a dynamics entry point is given, once per object:
    one rebuilt by ``eqx.tree_at`` (a design step, ``flatten_parameters``' rebuild) skipped
    the constructor's checks, and a negative mass ran, a NaN one failed as 'a jam'."""
    if _VALUES_CHECKED.get(id(mech)) is mech:
        return
    _check_values(mech)
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(mech)):
        return  # traced values are not checked, nor kept
    if len(_VALUES_CHECKED) > 64:
        _VALUES_CHECKED.clear()
    _VALUES_CHECKED[id(mech)] = mech


def _check_values(mech: Mechanism) -> None:
    """Finite values of sane magnitude (the scene loader's words), non-negative masses and
    inertias, non-zero lengths and guide directions; tracers are checked where they are concrete."""
    for what, value, shape, ranges in value_fields(mech):
        check_value(MechanismError, what, value, shape=shape, **ranges)
    links = mech.all_links()
    for g in mech.groups:
        for link, needed in g.required_points().items():
            for a, b in zip(needed, needed[1:]):
                d = _concrete(links[link].points[a] - links[link].points[b])
                if d is not None and np.any(np.hypot(d[..., 0], d[..., 1]) <= 0):
                    raise MechanismError(f"{g.describe()}: link '{link}' has zero length between '{a}' and '{b}'")
        for _, direction, offset in g.guides():
            check_value(MechanismError, f"{g.describe()}: guide direction", direction, nonzero_vector=True)
            check_value(MechanismError, f"{g.describe()}: guide offset", offset)
    _check_crank_arms(mech)


def _check_crank_arms(mech: Mechanism) -> None:
    """A crank's joint that a later group hangs on (a revolute: not a guide's point, whose
    line still turns with the crank) must not sit on the crank's pivot: the rest of the
    mechanism would not follow the driver (a zero-length crank)."""
    crank = mech.groups[0]
    if crank.kind != "crank":
        return
    points = mech.links[crank.links[0]].points
    guides = {p for g in mech.groups[1:] for p in (getattr(g, "guide_point", None), *getattr(g, "guide_points", ())) if p}
    used = {p for g in mech.groups[1:] for p in g.external_points()} & set(points) - {crank.pivot} - guides
    for p in sorted(used):
        d = _concrete(points[p] - points[crank.pivot])
        if d is not None and np.any(np.hypot(d[..., 0], d[..., 1]) <= 0):
            raise MechanismError(f"{crank.describe()}: link '{crank.links[0]}' has zero length between its pivot "
                                 f"'{crank.pivot}' and '{p}', where the mechanism hangs on it")


def check_mechanism(mechanism, what: str) -> None:
    if not isinstance(mechanism, Mechanism):
        raise MechanismError(f"{what}: expected an assurjax.Mechanism (a scene's: scene.mechanism), got "
                             f"{type(mechanism).__name__}{sketch_hint(mechanism)}")


def sketch_hint(value, scene: bool = False) -> str:
    """For a :class:`assurjax.Sketch` given where a Mechanism (``scene``: or a Scene) is
    wanted, how to build one from it; else ""."""
    from .structure._sketch import Sketch  # the structure package imports this module

    if not isinstance(value, Sketch):
        return ""
    if scene:
        return ("; a Sketch is a drawing: pass sketch.scene() (its Scene; gravity, loads and settings as keywords, "
                "e.g. sketch.scene(gravity=(0, -9.81))) or sketch.mechanism() (its Mechanism)")
    return "; a Sketch is a drawing: pass sketch.mechanism() (its Mechanism)"


def point_names(mechanism: Mechanism, names, what: str) -> tuple[str, ...]:
    """``names`` as a tuple of the mechanism's point names (one name may be a plain string),
    unknown ones refused by name."""
    check_mechanism(mechanism, what)
    names = (names,) if isinstance(names, str) else tuple(names)
    unknown = [n for n in names if n not in mechanism.point_names]
    if unknown:
        raise MechanismError(f"{what}: unknown point(s) {unknown}; the mechanism has {sorted(mechanism.point_names)}")
    return names


# the position analysis needs Mechanism and Pose: imported last (kept importable from here)
from ._positions import _positions as _positions, positions as positions  # noqa: E402
