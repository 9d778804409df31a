"""Structural analysis of a sketch: Gruebler's count and the Assur decomposition.

The classic algorithm: the driver (a crank or a slider with the ground) is placed
first; then, repeatedly, the smallest Assur group whose external pairs all connect
to links already placed is found and placed (dyads first, then the class-III triad,
then the class-IV group). A link with two pairs to placed links is over-constrained;
links left over when no group is found are named in the error (a topology outside
the package's kinds, or an under-constrained chain)."""

from __future__ import annotations

import dataclasses
import heapq
import itertools

from .._errors import MechanismError
from .._listing import SHOWN, few
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
    """No group found: the links left over and the joints no placed link carries."""

    def __init__(self, remaining, undetermined):
        super().__init__(remaining)
        self.remaining = remaining
        self.undetermined = undetermined


class _Graph:
    """Incidence of a sketch: who carries which joint, which slides join which links, and
    each link's neighbours in the user's order (the result must not depend on hashing)."""

    def __init__(self, sk: Sketch):
        self.sk = sk
        self.carriers = sk.carriers()
        self.order = {name: i for i, name in enumerate(sk.links)}
        self.slides_of: dict[str, list] = {name: [] for name in (GROUND, *sk.links)}
        for s in sk.slides:
            self.slides_of[s.link].append(s)
            self.slides_of[s.on].append(s)
        self._adjacent = {name: self._find_neighbours(name) for name in (GROUND, *sk.links)}

    def neighbours(self, link: str) -> tuple[str, ...]:
        """The moving links sharing a joint or a slide with ``link``, in the user's order."""
        return self._adjacent[link]

    def _find_neighbours(self, link: str) -> tuple[str, ...]:
        out = {c for j in self._joints(link) for c in self.carriers[j] if c != link}
        out |= {s.on if s.link == link else s.link for s in self.slides_of[link]}
        out.discard(GROUND)
        return tuple(sorted(out, key=self.order.get))

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


def _names_text(names) -> str:
    """``a, b, c``; past SHOWN names the first SHOWN and a count of the rest (a sketch may
    have a thousand links: a message listing them all was unreadable)."""
    names = list(names)
    shown = ", ".join(names[:SHOWN])
    return shown if len(names) <= SHOWN else f"{shown} and {len(names) - SHOWN} more"


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
        links = _names_text(e.remaining)
        if dof > 1:
            raise MechanismError(f"under-constrained: {count}, expected 1: {dof - 1} degree(s) of freedom left beyond the "
                                 f"driver's; {len(e.remaining)} of the {n} links are in no group (links {links}; joints "
                                 f"{_names_text(e.undetermined)} not determined): add links or joints") from None
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
        raise MechanismError(f"disconnected: links {_names_text(loose)} are not connected to the ground (through joints or slides)")


def _formation(graph: _Graph) -> list[GroupPlan]:
    groups = [_driver(graph)]
    search = _Search(graph, placed={GROUND, graph.sk.driver})
    while search.known:
        group = search.next_group(len(groups))
        groups.append(group)
        search.place(group.links)
    return groups


class _Search:
    """The formation search after the driver: each round places the group started by the
    earliest remaining link (in the user's order) that starts a dyad, else a triad, else a
    class-IV group. Whether a link starts one depends only on the links within three pairs
    of it, so after a group is placed only the links near it are asked again: rescanning
    every link each round grew with the square of the links, or faster (a chain of 249
    triads, 997 links: 34 s; now 11 ms)."""

    def __init__(self, graph: _Graph, placed: set):
        self.graph = graph
        self.placed = set(placed)
        self.known: dict[str, list] = {}  # remaining link -> its pairs with placed links
        self.over: set[str] = set()  # remaining links with more than one such pair
        self._update_known([name for name in graph.sk.links if name not in self.placed])
        # what each search asks of a link (does it start one?) and how it builds the group
        self.searches = {"dyad": (lambda a: self._dyad_partner(a) is not None, self._dyad),
                         "triad": (lambda t: self._triad(t, 0) is not None, self._triad),
                         "class4": (lambda a: self._class4(a, 0) is not None, self._class4)}
        self.unchecked = {kind: set(self.known) for kind in self.searches}  # links to ask again
        self.starts = {kind: {} for kind in self.searches}  # link -> its last answer
        self.heaps: dict[str, list] = {kind: [] for kind in self.searches}  # (order, link): stale ones dropped when on top

    def next_group(self, index: int) -> GroupPlan:
        if self.over:
            name = min(self.over, key=self.graph.order.get)
            raise MechanismError(f"link '{name}' is over-constrained: it is attached to already determined links by {_pairs_text(self.known[name])}")
        for kind, (_, build) in self.searches.items():
            first = self._first(kind)
            if first is not None:
                return build(first, index)
        undetermined = [j for j, c in self.graph.carriers.items() if not any(x in self.placed for x in c)]
        raise _Stuck(sorted(self.known, key=self.graph.order.get), undetermined)

    def place(self, links) -> None:
        self.placed.update(links)
        for name in links:
            del self.known[name]
            self.over.discard(name)
        # only links sharing a joint or a slide with the group gain pairs with placed links (or lose
        # pairs between them); a search from a link reads links up to two pairs further (a class-IV
        # group's far binary link), so those are the links whose answers may change
        touched = {n for name in links for n in self.graph.neighbours(name) if n in self.known}
        self._update_known(touched)
        near = self._within(touched, 2)
        for unchecked in self.unchecked.values():
            unchecked |= near

    def _update_known(self, links) -> None:
        for name in links:
            self.known[name] = self.graph.known(name, self.placed)
            if len(self.known[name]) > 1:
                self.over.add(name)
            else:
                self.over.discard(name)

    def _within(self, links: set, steps: int) -> set:
        """The remaining links at most ``steps`` pairs from ``links``."""
        near, front = set(links), set(links)
        for _ in range(steps):
            front = {n for name in front for n in self.graph.neighbours(name) if n in self.known and n not in near}
            near |= front
        return near

    def _first(self, kind: str) -> str | None:
        """The earliest remaining link (user's order) that starts a group of ``kind``."""
        test, starts, heap = self.searches[kind][0], self.starts[kind], self.heaps[kind]
        for name in self.unchecked[kind]:
            if name in self.known:
                starts[name] = test(name)
                if starts[name]:
                    heapq.heappush(heap, (self.graph.order[name], name))
        self.unchecked[kind].clear()
        while heap and not (heap[0][1] in self.known and starts[heap[0][1]]):
            heapq.heappop(heap)
        return heap[0][1] if heap else None

    def _between(self, a: str, b: str) -> list:
        return self.graph.between(a, b, self.placed)

    def _remaining_neighbours(self, link: str):
        return (n for n in self.graph.neighbours(link) if n in self.known)

    def _dyad_partner(self, a: str):
        """(b, pairs joining a and b) of the first dyad ``a`` starts, b in the user's order, or None."""
        if len(self.known[a]) != 1:
            return None
        for b in self._remaining_neighbours(a):
            if len(self.known[b]) == 1 and (inner := self._between(a, b)):
                return b, inner
        return None

    def _dyad(self, a: str, index: int) -> GroupPlan:
        b, inner = self._dyad_partner(a)
        if len(inner) > 1:
            raise MechanismError(f"links '{a}' and '{b}' are over-constrained: joined to each other by {_pairs_text(inner)} and each to determined links")
        return _dyad_plan(self.known[a][0], a, inner[0], b, self.known[b][0], index)

    def _triad(self, t: str, index: int) -> GroupPlan | None:
        if self.known[t]:
            return None
        arms = []  # (binary link, its external joint, the ternary's joint)
        for b in self._remaining_neighbours(t):
            if _single_revolute(self.known[b]) is None:
                continue
            p = _single_revolute(self._between(t, b))
            if p is not None:
                arms.append((b, self.known[b][0][1], p))
        for trio in itertools.combinations(arms, 3):
            if len({p for _, _, p in trio}) == 3 and not any(self._between(x[0], y[0]) for x, y in itertools.combinations(trio, 2)):
                (l1, e1, p1), (l2, e2, p2), (l3, e3, p3) = trio
                return GroupPlan("triad", f"triad{index}", (t, l1, l2, l3), (e1, e2, e3, p1, p2, p3))
        return None

    def _class4(self, a: str, index: int) -> GroupPlan | None:
        b_joint = _single_revolute(self.known[a])
        if b_joint is None:
            return None
        # closure links hanging from a: (link, joint on a)
        closures = [(x, p) for x in self._remaining_neighbours(a) if not self.known[x]
                    for p in [_single_revolute(self._between(a, x))] if p is not None]
        for (x, c), (z, e) in itertools.permutations(closures, 2):
            if c == e or self._between(x, z):
                continue
            for y in self._remaining_neighbours(x):  # y shares joint d with x
                g_joint = _single_revolute(self.known[y])
                if y in (a, x, z) or g_joint is None or self._between(a, y):
                    continue
                d = _single_revolute(self._between(x, y))
                f = _single_revolute(self._between(z, y))
                if d is not None and f is not None and d != f:
                    return GroupPlan("class4", f"class4_{index}", (a, x, y, z), (b_joint, g_joint, c, d, e, f))
        return None


def _driver(graph: _Graph) -> GroupPlan:
    sk = graph.sk
    pairs = graph.known(sk.driver, {GROUND})
    if not pairs:
        raise MechanismError(f"driver '{sk.driver}' is neither pinned to the ground nor sliding on it (ground joints: {few(sk.ground)})")
    if len(pairs) > 1:
        raise MechanismError(f"driver '{sk.driver}' is over-constrained: it is attached to the ground by {_pairs_text(pairs)} (a driver needs exactly one pair with the ground)")
    kind, x = pairs[0]
    if kind == "R":
        return GroupPlan("crank", "crank", (sk.driver,), (x,))
    point = sk.links[sk.driver].joints[0]
    return GroupPlan("slider", "slider", (sk.driver,), (point,), ((sk.driver, GROUND, x.direction),))


def _guide_of(slide, sliding: str) -> tuple[str, str, tuple]:
    return (sliding, slide.on if slide.link == sliding else slide.link, slide.direction)


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
