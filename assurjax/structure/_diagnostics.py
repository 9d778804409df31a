"""Assembly diagnostics over a sweep: for each group that fails on its own (every group
it depends on assembles), the q intervals where it cannot assemble and the violated
condition with numbers, e.g. ``|C D| = 0.83 m > 0.50 + 0.30 m``."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .._jit import jit
from .._mechanism import Mechanism, check_mechanism, positions
from ..groups import GROUND


@dataclasses.dataclass(frozen=True)
class GroupFailure:
    """Where one group cannot assemble: ``intervals`` of q (closed, between samples of the
    sweep) and ``condition``, the violated condition at the first failing sample."""

    group: str
    kind: str
    intervals: tuple[tuple[float, float], ...]
    condition: str

    def __str__(self):
        spans = ", ".join(f"[{a:.6g}, {b:.6g}]" for a, b in self.intervals)
        return f"group '{self.group}' ({self.kind}) cannot assemble for q in {spans}: {self.condition}"


@dataclasses.dataclass(frozen=True)
class AssemblyReport:
    """The result of :func:`assembly_report`: ``failures`` (one per failing group) and the
    fraction of the sweep where the whole mechanism assembles. ``print`` it."""

    q: np.ndarray
    ok: np.ndarray
    failures: tuple[GroupFailure, ...]

    def __str__(self):
        head = f"assembles at {int(self.ok.sum())} of {len(self.q)} samples of q in [{self.q.min():.6g}, {self.q.max():.6g}]"
        return "\n".join([head] + [f"  {f}" for f in self.failures])


def _intervals(q: np.ndarray, bad: np.ndarray) -> tuple[tuple[float, float], ...]:
    out, start = [], None
    for i, b in enumerate(bad):
        if b and start is None:
            start = i
        if start is not None and (not b or i == len(bad) - 1):
            end = i if b else i - 1
            out.append((float(q[start]), float(q[end])))
            start = None
    return tuple(out)


def _length(mech: Mechanism, link: str, a: str, b: str) -> float:
    pts = mech.links[link].points
    return float(np.hypot(*(np.asarray(pts[a]) - np.asarray(pts[b]))))


def _condition(mech: Mechanism, g, points: dict, angles: dict) -> str:
    """The violated condition of group ``g`` at one pose (global points, link angles)."""
    xy = lambda p: np.asarray(points[p])  # noqa: E731
    owner = dict(mech.owner)

    def guide_line(guide_point, direction, offset):
        link = owner[guide_point]
        angle = 0.0 if link == GROUND else float(angles[link])
        c, s = np.cos(angle), np.sin(angle)
        u = np.asarray(direction, dtype=float) / np.hypot(*np.asarray(direction, dtype=float))
        u = np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]])
        n = np.array([-u[1], u[0]])
        return xy(guide_point) + float(offset) * n, u, n

    if g.kind == "RRR":
        (a, b), (e1, e2, j) = g.links, g.joints
        r1, r2, d = _length(mech, a, e1, j), _length(mech, b, e2, j), float(np.hypot(*(xy(e2) - xy(e1))))
        if d > r1 + r2:
            return f"|{e1} {e2}| = {d:.4g} m > {r1:.4g} + {r2:.4g} m (links {a}, {b} too short)"
        longer, other = (a, b) if r1 > r2 else (b, a)
        return f"|{e1} {e2}| = {d:.4g} m < |{r1:.4g} - {r2:.4g}| m (link {longer} too long beside {other}: one folds inside the other)"
    if g.kind in ("RRP", "PRR"):
        rod = g.links[0] if g.kind == "RRP" else g.links[1]
        e, j = g.joints if g.kind == "RRP" else g.joints[::-1]
        base, _, n = guide_line(g.guide_point, g.direction, g.offset)
        h, r = abs(float(np.dot(xy(e) - base, n))), _length(mech, rod, e, j)
        return f"distance of {e} from the guide = {h:.4g} m > {rod} {e}{j} = {r:.4g} m"
    if g.kind == "RPR":
        e1, e2 = g.joints
        d = float(np.hypot(*(xy(e1) - xy(e2))))
        return f"|{e1} {e2}| = {d:.4g} m < |offset| = {abs(float(g.offset)):.4g} m"
    if g.kind == "PRP":
        (_, u1, _), (_, u2, _) = (guide_line(p, d, o) for p, d, o in zip(g.guide_points, g.directions, g.offsets))
        angle = np.degrees(np.arcsin(np.clip(abs(u1[0] * u2[1] - u1[1] * u2[0]), 0, 1)))
        return f"the guides are parallel (angle {angle:.3g} deg)"
    return "Newton finds no assembly on the branch followed from the guess (the group's links cannot close)"


def violated_condition(mechanism: Mechanism, group, q: float, pose=None) -> str | None:
    """The condition ``group`` (one of the mechanism's, every group it depends on assembled)
    violates at the one driving coordinate ``q``, as :func:`assembly_report` words it;
    ``pose``: the mechanism's :class:`Pose` at q if at hand. None for a batch of mechanisms."""
    if any(np.ndim(v) != 1 for v in (*mechanism.ground.values(), *(p for link in mechanism.links.values() for p in link.points.values()))):
        return None
    if pose is None:
        pose = positions(mechanism, q)  # its own jit, once per structure
    return _condition(mechanism, group, *jax.tree.map(np.asarray, (pose.points, pose.angles)))


def links_to_check(mechanism: Mechanism, group) -> tuple[str, ...]:
    """The group's links and those carrying the points it reads from earlier groups (GROUND for a
    fixed one): where the lengths of a group that cannot assemble are set."""
    owner = dict(mechanism.owner)
    return tuple(dict.fromkeys((*group.links, *(owner[p] for p in group.external_points()))))


@jit
def _poses(mechanism: Mechanism, q):
    """Positions at every q: compiled once per mechanism structure (new dimensions reuse it)."""
    return jax.vmap(lambda qq: positions(mechanism, qq))(q)


def assembly_report(mechanism: Mechanism, q) -> AssemblyReport:
    """Where the mechanism assembles over the driving coordinates ``q`` (rad or m, an
    array), and for each group that fails while every group it depends on assembles:
    the q intervals and the violated condition with numbers (m).

    Example: ``print(assembly_report(load_scene("roberts").mechanism, np.linspace(-3, 3, 121)))``."""
    check_mechanism(mechanism, "assembly_report")
    q = np.asarray(q, dtype=float).reshape(-1)
    pose = _poses(mechanism, q)
    ok = np.asarray(pose.ok)
    failures = []
    for i, g in enumerate(mechanism.groups):
        deps = [k for k in mechanism.groups_needed(links=g.links) if k != i]
        own = ~ok[:, i] & ok[:, deps].all(axis=1) if deps else ~ok[:, i]
        if not own.any():
            continue
        first = int(np.flatnonzero(own)[0])
        at = jax.tree.map(lambda x: np.asarray(x)[first], (pose.points, pose.angles))
        failures.append(GroupFailure(g.name, g.kind, _intervals(q, own), _condition(mechanism, g, *at) + f" at q = {q[first]:.6g}"))
    return AssemblyReport(q, ok.all(axis=1), tuple(failures))
