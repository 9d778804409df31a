"""Structural analysis of a sketch: Gruebler's count and the Assur decomposition.

The classic algorithm: the driver (a crank or a slider with the ground) is placed
first; then, repeatedly, the smallest Assur group whose external pairs all connect
to links already placed is found and placed (dyads first, then the class-III triad,
then the class-IV group). A link with two pairs to placed links is over-constrained;
links left over when no group is found are named in the error (a topology outside
the package's kinds, or an under-constrained chain)."""

from __future__ import annotations

import dataclasses
import itertools

from .._errors import MechanismError
from ..groups import GROUND
from ._sketch import Sketch

KINDS_TEXT = "crank/slider, RRR, RRP, PRR, RPR, PRP, triad, class IV"


@dataclasses.dataclass(frozen=True)
class GroupPlan:
    """One group of the formation sequence, in the package's conventions.

    ``links`` and ``joints`` are in the order of the group class (e.g. RRR: links
    (a, b), joints (E1, E2, J)); ``guides`` lists its prismatic pairs as
    (sliding link, guide link, drawn direction)."""

    kind: str
    name: str
    links: tuple[str, ...]
    joints: tuple[str, ...]
    guides: tuple[tuple[str, str, tuple[float, float]], ...] = ()

    def describe(self) -> str:
        roles = {
            "crank": "pivot {0}", "slider": "joint {0} on the ground",
            "RRR": "external {0}, {1}; internal {2}", "RRP": "external {0}; internal {1}",
            "RPR": "external {0}, {1}", "PRP": "internal {0}",
            "triad": "external {0}, {1}, {2}; internal {3}, {4}, {5}",
            "class4": "external {0}, {1}; internal {2}, {3}, {4}, {5}",
        }
        text = f"{self.kind:6s} '{self.name}': links {', '.join(self.links)} ({roles[self.kind].format(*self.joints)})"
        for slider, guide, _ in self.guides:
            if self.kind != "slider":
                text += f"; {slider} slides on {guide}"
        return text


@dataclasses.dataclass(frozen=True)
class Decomposition:
    """Gruebler's count and the formation sequence found for a sketch.

    ``print(d)`` lists the groups in order; :meth:`draw` colours the drawing by group."""

    groups: tuple[GroupPlan, ...]
    n_links: int
    n_revolute: int
    n_prismatic: int

    @property
    def dof(self) -> int:
        return 3 * self.n_links - 2 * (self.n_revolute + self.n_prismatic)

    def __str__(self) -> str:
        head = (f"Gruebler: 3*{self.n_links} - 2*({self.n_revolute} revolute + {self.n_prismatic} prismatic) = {self.dof}; "
                f"formation sequence of {len(self.groups)} groups:")
        return "\n".join([head] + [f"  {i + 1}. {g.describe()}" for i, g in enumerate(self.groups)])

    def draw(self, sketch: Sketch, *, ax=None):
        """Draw the sketch with each group's links in one colour (a matplotlib Axes)."""
        import matplotlib.pyplot as plt
        import numpy as np

        if ax is None:
            _, ax = plt.subplots(figsize=(6, 5))
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        xy = sketch.joints
        for i, g in enumerate(self.groups):
            c = colours[i % len(colours)]
            for k, link in enumerate(g.links):
                pts = np.array([xy[j] for j in sketch.links[link].joints])
                closed = np.vstack([pts, pts[:1]]) if len(pts) > 2 else pts
                ax.plot(closed[:, 0], closed[:, 1], "-o", color=c, lw=2, ms=4, label=f"{i + 1}. {g.kind} '{g.name}'" if k == 0 else None)
                if len(pts) > 2:
                    ax.fill(pts[:, 0], pts[:, 1], color=c, alpha=0.15)
        for j in sketch.ground:
            ax.plot(*xy[j], "k^", ms=9)
        for name, p in xy.items():
            ax.annotate(name, p, textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_aspect("equal")
        ax.legend(fontsize=8, loc="best")
        ax.set_title(f"{sketch.name}: Assur decomposition")
        return ax


class _Stuck(Exception):
    """No group found: the links left over."""

    def __init__(self, remaining):
        super().__init__(remaining)
        self.remaining = remaining


class _Graph:
    """Incidence of a sketch: who carries which joint, which slides join which links."""

    def __init__(self, sk: Sketch):
        self.sk = sk
        self.carriers = sk.carriers()
        self.slides_of: dict[str, list] = {name: [] for name in (GROUND, *sk.links)}
        for s in sk.slides:
            self.slides_of[s.link].append(s)
            self.slides_of[s.on].append(s)

    def neighbours(self, link: str):
        out = {c for j in self._joints(link) for c in self.carriers[j] if c != link}
        return out | {s.on if s.link == link else s.link for s in self.slides_of[link]}

    def _joints(self, link: str):
        return self.sk.ground if link == GROUND else self.sk.links[link].joints

    def known(self, link: str, placed: set) -> list:
        """Pairs of ``link`` with placed links: ("R", joint) or ("P", slide)."""
        out = [("R", j) for j in self.sk.links[link].joints if any(c in placed for c in self.carriers[j] if c != link)]
        return out + [("P", s) for s in self.slides_of[link] if (s.on if s.link == link else s.link) in placed]

    def between(self, a: str, b: str, placed: set) -> list:
        """Pairs joining two unplaced links (shared joints not already known, and slides)."""
        out = [("R", j) for j in self.sk.links[a].joints
               if b in self.carriers[j] and not any(c in placed for c in self.carriers[j])]
        return out + [("P", s) for s in self.slides_of[a] if {s.link, s.on} == {a, b}]


def _pairs_text(pairs) -> str:
    return ", ".join(f"joint {x}" if t == "R" else f"slide of {x.link} on {x.on}" for t, x in pairs)


def gruebler(sk: Sketch) -> tuple[int, int, int]:
    """(moving links, revolute pairs, prismatic pairs); a joint carried by k links is k - 1 pairs."""
    revolute = sum(max(len(c) - 1, 0) for c in sk.carriers().values())
    return len(sk.links), revolute, len(sk.slides)


def decompose(sk: Sketch) -> Decomposition:
    """Gruebler's count and the formation sequence of ``sk``; :class:`MechanismError`
    naming the links (and joints) at fault when the sketch is not a one-DOF mechanism
    made of the package's group kinds."""
    graph = _Graph(sk)
    _check_connected(graph)
    n, revolute, prismatic = gruebler(sk)
    dof = 3 * n - 2 * (revolute + prismatic)
    count = f"Gruebler's count 3*{n} - 2*({revolute} revolute + {prismatic} prismatic) = {dof}"
    try:
        groups = _formation(graph)
    except _Stuck as e:
        links = ", ".join(e.remaining)
        if dof > 1:
            raise MechanismError(f"under-constrained: {count}, expected 1; links {links} are not determined by the driver "
                                 f"(they keep {dof - 1} degree(s) of freedom: add links or joints)") from None
        if dof < 1:
            raise MechanismError(f"over-constrained: {count}, expected 1; links {links} cannot be placed") from None
        raise MechanismError(f"links {links} cannot be decomposed into the package's group kinds ({KINDS_TEXT})") from None
    except MechanismError as e:
        if dof != 1:
            raise MechanismError(f"{'over' if dof < 1 else 'under'}-constrained: {count}, expected 1: {e}") from None
        raise
    return Decomposition(tuple(groups), n, revolute, prismatic)


def _check_connected(graph: _Graph) -> None:
    seen, todo = {GROUND}, [GROUND]
    while todo:
        for other in graph.neighbours(todo.pop()):
            if other not in seen:
                seen.add(other)
                todo.append(other)
    loose = [name for name in graph.sk.links if name not in seen]
    if loose:
        raise MechanismError(f"disconnected: links {', '.join(loose)} are not connected to the ground (through joints or slides)")


def _formation(graph: _Graph) -> list[GroupPlan]:
    sk = graph.sk
    placed = {GROUND}
    groups = [_driver(graph)]
    placed.add(sk.driver)
    remaining = [name for name in sk.links if name != sk.driver]
    while remaining:
        known = {name: graph.known(name, placed) for name in remaining}
        for name, pairs in known.items():
            if len(pairs) > 1:
                raise MechanismError(f"link '{name}' is over-constrained: it is attached to already determined links by {_pairs_text(pairs)}")
        index = len(groups)
        group = _dyad(graph, remaining, known, placed, index) or _triad(graph, remaining, known, placed, index) \
            or _class4(graph, remaining, known, placed, index)
        if group is None:
            raise _Stuck(remaining)
        groups.append(group)
        placed.update(group.links)
        remaining = [name for name in remaining if name not in placed]
    return groups


def _driver(graph: _Graph) -> GroupPlan:
    sk = graph.sk
    pairs = graph.known(sk.driver, {GROUND})
    if not pairs:
        raise MechanismError(f"driver '{sk.driver}' is neither pinned to the ground nor sliding on it (ground joints: {list(sk.ground)})")
    if len(pairs) > 1:
        raise MechanismError(f"driver '{sk.driver}' is over-constrained: it is attached to the ground by {_pairs_text(pairs)} (a driver needs exactly one pair with the ground)")
    kind, x = pairs[0]
    if kind == "R":
        return GroupPlan("crank", "crank", (sk.driver,), (x,))
    point = sk.links[sk.driver].joints[0]
    return GroupPlan("slider", "slider", (sk.driver,), (point,), ((sk.driver, GROUND, x.direction),))


def _guide_of(slide, sliding: str) -> tuple[str, str, tuple]:
    return (sliding, slide.on if slide.link == sliding else slide.link, slide.direction)


def _dyad(graph, remaining, known, placed, index) -> GroupPlan | None:
    order = {name: i for i, name in enumerate(remaining)}  # the user's order: the result must not depend on hashing
    for a in remaining:
        if len(known[a]) != 1:
            continue
        for b in sorted((n for n in graph.neighbours(a) if n in order), key=order.get):
            if b == a or len(known[b]) != 1:
                continue
            inner = graph.between(a, b, placed)
            if not inner:
                continue
            if len(inner) > 1:
                raise MechanismError(f"links '{a}' and '{b}' are over-constrained: joined to each other by {_pairs_text(inner)} and each to determined links")
            return _dyad_plan(known[a][0], a, inner[0], b, known[b][0], index)
    return None


def _dyad_plan(ext_a, a, inner, b, ext_b, index) -> GroupPlan:
    code = ext_a[0] + inner[0] + ext_b[0]
    name = f"{code}{index}"
    if code == "RRR":
        return GroupPlan("RRR", name, (a, b), (ext_a[1], ext_b[1], inner[1]))
    if code == "RRP":
        return GroupPlan("RRP", name, (a, b), (ext_a[1], inner[1]), (_guide_of(ext_b[1], b),))
    if code == "PRR":  # the same dyad listed from its rod
        return GroupPlan("RRP", f"RRP{index}", (b, a), (ext_b[1], inner[1]), (_guide_of(ext_a[1], a),))
    if code == "RPR":
        slide = inner[1]
        block = slide.link
        guide = slide.on
        ext = {a: ext_a[1], b: ext_b[1]}
        return GroupPlan("RPR", name, (block, guide), (ext[block], ext[guide]), ((block, guide, slide.direction),))
    if code == "PRP":
        return GroupPlan("PRP", name, (a, b), (inner[1],), (_guide_of(ext_a[1], a), _guide_of(ext_b[1], b)))
    raise MechanismError(f"links '{a}' and '{b}' form an {code} dyad, which is not one of the package's kinds ({KINDS_TEXT})")


def _single_revolute(pairs) -> str | None:
    return pairs[0][1] if len(pairs) == 1 and pairs[0][0] == "R" else None


def _triad(graph, remaining, known, placed, index) -> GroupPlan | None:
    for t in remaining:
        if known[t]:
            continue
        arms = []  # (binary link, its external joint, the ternary's joint)
        for b in remaining:
            if b == t or _single_revolute(known[b]) is None:
                continue
            p = _single_revolute(graph.between(t, b, placed))
            if p is not None:
                arms.append((b, known[b][0][1], p))
        for trio in itertools.combinations(arms, 3):
            if len({p for _, _, p in trio}) == 3 and not any(graph.between(x[0], y[0], placed) for x, y in itertools.combinations(trio, 2)):
                (l1, e1, p1), (l2, e2, p2), (l3, e3, p3) = trio
                return GroupPlan("triad", f"triad{index}", (t, l1, l2, l3), (e1, e2, e3, p1, p2, p3))
    return None


def _class4(graph, remaining, known, placed, index) -> GroupPlan | None:
    for a in remaining:
        b_joint = _single_revolute(known[a])
        if b_joint is None:
            continue
        # closure links hanging from a: (link, joint on a)
        closures = [(x, p) for x in remaining if x != a and not known[x]
                    for p in [_single_revolute(graph.between(a, x, placed))] if p is not None]
        for (x, c), (z, e) in itertools.permutations(closures, 2):
            if c == e or graph.between(x, z, placed):
                continue
            for y in remaining:
                g_joint = _single_revolute(known[y])
                if y in (a, x, z) or g_joint is None or graph.between(a, y, placed):
                    continue
                d = _single_revolute(graph.between(x, y, placed))
                f = _single_revolute(graph.between(z, y, placed))
                if d is not None and f is not None and d != f:
                    return GroupPlan("class4", f"class4_{index}", (a, x, y, z), (b_joint, g_joint, c, d, e, f))
    return None
