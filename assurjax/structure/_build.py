"""From a sketch to the explicit mechanism: link frames and local coordinates from the
drawing, each group's parameters (guide directions and offsets, assembly modes,
starting guesses) chosen so that the mechanism reproduces the drawing at q0."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from .._errors import AssemblyError, MechanismError
from .._mechanism import Mechanism
from ..groups import GROUND, Link, KINDS
from ._decompose import Decomposition, GroupPlan, decompose
from ._sketch import Sketch

SINGULAR = 1e-9  # relative: a drawn configuration this close to a singular one leaves the mode ambiguous


@dataclasses.dataclass(frozen=True)
class Built:
    """What :func:`build` returns: the mechanism, its decomposition, the driving
    coordinate of the drawing and notes (e.g. a mode that the drawing leaves ambiguous)."""

    mechanism: Mechanism
    decomposition: Decomposition
    q0: float
    notes: tuple[str, ...] = ()


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.hypot(*v)


def _cross(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _rotate(v, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def drawn_q0(sk: Sketch, driver: GroupPlan) -> float:
    """The driving coordinate of the drawing: the sketch's ``q0``, else for a crank the
    drawn angle from the pivot to the crank's first other joint (0 if it has none), for a slider 0."""
    if sk.q0 is not None:
        return sk.q0
    if driver.kind == "slider":
        return 0.0
    pivot = sk.joints[driver.joints[0]]
    for j in sk.links[driver.links[0]].joints:
        d = sk.joints[j] - pivot
        if np.hypot(*d) > 0:
            return math.atan2(d[1], d[0])
    return 0.0


def _frames(sk: Sketch, groups, q0: float) -> dict[str, tuple[np.ndarray, float]]:
    """(origin, angle) of every link's frame in the drawing. Where a group fixes a link's
    rotation (crank: q; sliders and RPR blocks: along their guide) the frame follows it;
    otherwise the origin is the link's first joint and x points to its next joint."""
    fixed = {}
    for g in groups:
        if g.kind == "crank":
            fixed[g.links[0]] = (sk.joints[g.joints[0]], q0)
        elif g.kind in ("slider", "RRP", "PRP", "RPR"):
            for k, (slider, _, u) in enumerate(g.guides):
                at = {"slider": g.joints[0], "RRP": g.joints[-1], "PRP": g.joints[0], "RPR": g.joints[0]}[g.kind]
                fixed[slider] = (sk.joints[at], math.atan2(u[1], u[0]))
    frames = {}
    for name, spec in sk.links.items():
        if name in fixed:
            frames[name] = fixed[name]
            continue
        origin = sk.joints[spec.joints[0]]
        angle = 0.0
        for j in spec.joints[1:]:
            d = sk.joints[j] - origin
            if np.hypot(*d) > 0:
                angle = math.atan2(d[1], d[0])
                break
        frames[name] = (origin, angle)
    return frames


def _mass_properties(name: str, spec, drawn: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(mass, centroidal inertia, drawn centre of mass) from explicit values and/or a density."""
    mass, inertia, com = 0.0, 0.0, drawn.mean(axis=0)
    if spec.density is not None:
        rho = spec.density
        if len(drawn) == 2:
            length = float(np.hypot(*(drawn[1] - drawn[0])))
            mass, inertia, com = rho * length, rho * length**3 / 12.0, drawn.mean(axis=0)
        elif len(drawn) >= 3:
            mass, inertia, com = _plate(name, rho, drawn, spec.joints)
        else:
            raise MechanismError(f"link '{name}': a density needs a bar (2 joints) or a plate (3 or more joints); give mass and inertia instead")
    if spec.mass is not None:
        if spec.density is not None and mass > 0:
            inertia *= spec.mass / mass  # same shape, the given mass
        mass = spec.mass
    if spec.inertia is not None:
        inertia = spec.inertia
    if spec.com is not None:
        com = np.asarray(spec.com, dtype=float)
    return mass, inertia, com


def _crossing_edges(p: np.ndarray) -> tuple[int, int] | None:
    """The first two edges (indices of their first vertices) of the closed outline ``p``
    that are not neighbours and cross or touch, or None: a simple polygon."""
    n = len(p)
    cross = lambda o, a, b: (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])  # noqa: E731
    for i in range(n):
        a, b = p[i], p[(i + 1) % n]
        for j in range(i + 2, n - (i == 0)):
            c, d = p[j], p[(j + 1) % n]
            if (cross(a, b, c) * cross(a, b, d) <= 0 and cross(c, d, a) * cross(c, d, b) <= 0
                    and min(a[0], b[0]) <= max(c[0], d[0]) and min(c[0], d[0]) <= max(a[0], b[0])
                    and min(a[1], b[1]) <= max(c[1], d[1]) and min(c[1], d[1]) <= max(a[1], b[1])):
                return i, j
    return None


def _plate(name: str, rho: float, drawn: np.ndarray, joints=None):
    """Mass, centroidal polar inertia and centroid of a uniform polygon (outline in listed order)."""
    p = drawn - drawn[0]
    far = p[np.argmax(np.hypot(p[:, 0], p[:, 1]))]
    if np.all(np.abs(p[:, 0] * far[1] - p[:, 1] * far[0]) <= SINGULAR * float(far @ far)):  # all on one line
        raise MechanismError(f"link '{name}': the plate outline {list(map(str, drawn.round(6).tolist()))} has zero area (collinear joints): give mass and inertia instead")
    if (edges := _crossing_edges(drawn)) is not None:
        names = list(joints) if joints is not None else list(range(len(drawn)))
        (i, j), n = edges, len(drawn)
        raise MechanismError(f"link '{name}': its joints {names} listed as a plate's outline cross themselves (edge "
                             f"{names[i]}-{names[(i + 1) % n]} meets edge {names[j]}-{names[(j + 1) % n]}): list them "
                             "in order around the plate, or give mass and inertia instead")
    p = drawn - drawn[0]  # about the first vertex, for accuracy
    x, y = p[:, 0], p[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cr = x * yn - xn * y
    area = cr.sum() / 2.0
    if abs(area) <= SINGULAR * float(np.ptp(p, axis=0).max()) ** 2:
        raise MechanismError(f"link '{name}': the plate outline {list(map(str, drawn.round(6).tolist()))} has zero area (collinear joints): give mass and inertia instead")
    cx = ((x + xn) * cr).sum() / (6 * area)
    cy = ((y + yn) * cr).sum() / (6 * area)
    polar = ((x**2 + x * xn + xn**2 + y**2 + y * yn + yn**2) * cr).sum() / 12.0  # about the first vertex, signed like area
    mass = rho * abs(area)
    inertia = rho * abs(polar) - mass * (cx**2 + cy**2)
    return mass, inertia, drawn[0] + np.array([cx, cy])


def _unique(name: str, taken) -> str:
    out, k = name, 1
    while out in taken:
        k += 1
        out = f"{name}{k}"
    return out


def _owners(sk: Sketch, groups) -> dict[str, str]:
    """point -> the link it is read from, as :class:`~assurjax.Mechanism` will decide:
    the ground first, then each group's links in formation order."""
    owner = {p: GROUND for p in sk.ground}
    for g in groups:
        for link in g.links:
            for p in sk.links[link].joints:
                owner.setdefault(p, link)
    return owner


def build(sk: Sketch, *, check: bool = False) -> Built:
    """The explicit mechanism of a sketch (see :class:`Sketch`).

    ``check=True`` also runs the position analysis at q0 (one compile) and raises
    :class:`AssemblyError` naming the group whose loop does not reproduce the drawing,
    with the mismatch in m. Without it the drawing is still checked for the
    configurations no group can solve (coincident external joints, parallel guides)."""
    dec = decompose(sk)
    q0 = drawn_q0(sk, dec.groups[0])
    frames = _frames(sk, dec.groups, q0)
    J = sk.joints

    def local(link: str, p) -> np.ndarray:
        origin, angle = frames[link]
        return _rotate(np.asarray(p) - origin, -angle)

    def direction_in(link: str, u) -> np.ndarray:
        return _unit(u) if link == GROUND else _rotate(_unit(u), -frames[link][1])

    ground = {j: J[j] for j in sk.ground}
    points = {name: {j: J[j] for j in spec.joints} for name, spec in sk.links.items()}
    owner = _owners(sk, dec.groups)
    guide_points = {}  # (sliding link, guide link) -> a point owned by the guide link

    def add_guide_point(slider: str, guide: str, at: str) -> None:
        """A point of the guide link to carry the guide line: one it owns (a guide is read in
        the frame of the link owning its point), else a new point at the drawn sliding joint."""
        own = [p for p in (sk.ground if guide == GROUND else sk.links[guide].joints) if owner[p] == guide]
        if own:
            guide_points[slider, guide] = own[0]
            return
        name = _unique(f"{slider}_guide", set(J) | set(ground))
        (ground if guide == GROUND else points[guide])[name] = J[at]
        guide_points[slider, guide] = name

    for g in dec.groups:
        if g.kind in ("RRP", "PRP"):
            for slider, guide, _ in g.guides:
                add_guide_point(slider, guide, g.joints[-1])
    links = {}
    for name, spec in sk.links.items():
        drawn = np.array([J[j] for j in spec.joints])
        mass, inertia, com = _mass_properties(name, spec, drawn)
        links[name] = Link({j: jnp.asarray(local(name, x)) for j, x in points[name].items()}, com=jnp.asarray(local(name, com)), mass=mass, inertia=inertia)

    def offset_of(point: str, line_point: str, u) -> float:
        """Signed distance (m) of a drawn joint to the left of the line through ``line_point`` along u."""
        base = ground[line_point] if line_point in ground else J.get(line_point, None)
        if base is None:
            base = next(pts[line_point] for pts in points.values() if line_point in pts)
        return float(np.dot(J[point] - base, np.array([-u[1], u[0]]) / np.hypot(*u)))

    notes, groups = [], []
    scale, roundoff = sk.scale(), sk.roundoff()
    for g in dec.groups:
        where = f"group '{g.name}' ({g.kind}: links {', '.join(g.links)})"

        def mode(offset: float, what: str, size: float, amplified: float = 1.0) -> int:
            """The sign of ``offset`` (m), the drawn distance from the group's singular
            configuration; ambiguous within SINGULAR of the group's own ``size`` (m; not the
            drawing's: a far joint elsewhere widened the band) or the coordinates' round-off
            (``amplified`` by how offset is computed)."""
            if abs(offset) <= SINGULAR * size + amplified * roundoff:
                notes.append(f"{where}: drawn at a singular configuration ({what}); mode +1 taken")
                return 1
            return 1 if offset > 0 else -1

        cls = KINDS[g.kind]
        if g.kind == "crank":
            groups.append(cls(g.name, g.links, g.joints[0]))
        elif g.kind == "slider":
            u = _unit(g.guides[0][2])
            origin = _unique(f"{g.links[0]}_guide", set(J) | set(ground))
            ground[origin] = J[g.joints[0]] - q0 * u
            groups.append(cls(g.name, g.links, g.joints[0], origin, jnp.asarray(u)))
        elif g.kind == "RRR":
            e1, e2, j = (J[p] for p in g.joints)
            d = e2 - e1
            if np.hypot(*d) <= SINGULAR * scale + roundoff:
                raise MechanismError(f"{where}: its external joints '{g.joints[0]}' and '{g.joints[1]}' coincide in the drawing, so the loop through it cannot close")
            base, arms = np.hypot(*d), max(np.hypot(*(j - e1)), np.hypot(*(j - e2)))
            groups.append(cls(g.name, g.links, g.joints, mode(_cross(d, j - e1) / base, "internal joint on the line of the external ones", arms, 1 + arms / base)))
        elif g.kind == "RRP":
            (slider, guide, u), (e, j) = g.guides[0], g.joints
            gp = guide_points[slider, guide]
            groups.append(cls(g.name, g.links, g.joints, gp, mode(float(np.dot(J[j] - J[e], _unit(u))), "rod perpendicular to the guide", float(np.hypot(*(J[j] - J[e])))),
                              jnp.asarray(direction_in(guide, u)), jnp.asarray(offset_of(j, gp, u))))
        elif g.kind == "RPR":
            (block, guide, u), (e1, e2) = g.guides[0], g.joints
            d = J[e1] - J[e2]
            if np.hypot(*d) <= SINGULAR * scale + roundoff:
                raise MechanismError(f"{where}: joints '{e1}' and '{e2}' coincide in the drawing, so the loop through it cannot close")
            groups.append(cls(g.name, g.links, g.joints, mode(float(np.dot(d, _unit(u))), "block at the foot of the guide", float(np.hypot(*d))),
                              jnp.asarray(direction_in(guide, u)), jnp.asarray(offset_of(e1, e2, u))))
        elif g.kind == "PRP":
            (s1, g1, u1), (s2, g2, u2) = g.guides
            if abs(_cross(_unit(u1), _unit(u2))) <= SINGULAR:
                raise MechanismError(f"{where}: the slides of '{s1}' on '{g1}' and of '{s2}' on '{g2}' are parallel in the drawing, so joint '{g.joints[0]}' is not determined (the loop does not close)")
            gp = (guide_points[s1, g1], guide_points[s2, g2])
            groups.append(cls(g.name, g.links, g.joints[0], gp, jnp.asarray(np.stack([direction_in(g1, u1), direction_in(g2, u2)])),
                              jnp.asarray([offset_of(g.joints[0], gp[0], u1), offset_of(g.joints[0], gp[1], u2)])))
        else:  # triad, class4: start Newton from the drawing
            internal = g.joints[3:] if g.kind == "triad" else g.joints[2:]
            groups.append(cls(g.name, g.links, g.joints, {p: jnp.asarray(J[p]) for p in internal}, guess_q=float(q0)))
    mechanism = Mechanism(ground, links, groups, name=sk.name)
    if check:
        check_drawing(mechanism, sk, q0)
    return Built(mechanism, dec, float(q0), tuple(notes))


def check_drawing(mechanism: Mechanism, sk: Sketch, q0: float, *, tol: float = 1e-9) -> None:
    """Raise :class:`AssemblyError` if the mechanism at ``q0`` does not reproduce the
    drawing within ``tol`` (relative to the drawing's size), naming the first group
    (its loop: its links) that misses and by how much (m)."""
    from .._mechanism import positions

    pose = positions(mechanism, q0)
    ok = np.asarray(pose.ok)
    for i, g in enumerate(mechanism.groups):
        points = {p for link in g.links for p in mechanism.links[link].points}
        miss = max(float(np.hypot(*(np.asarray(pose.points[p]) - sk.joints[p]))) for p in points)
        if not ok[i] or miss > tol * sk.scale() + sk.roundoff():
            state = "does not assemble" if not ok[i] else "does not close on the drawing"
            raise AssemblyError(f"group '{g.name}' ({g.kind}, loop through links {', '.join(g.links)}) {state} at q0 = {q0:.6g}: "
                                f"its joints miss the drawing by {miss:.3g} m", group=g.name)


def to_scene(sk: Sketch, *, gravity=(0.0, 0.0), q0: float | None = None, omega0: float = 0.0, t0: float = 0.0, t1: float = 1.0,
             loads=(), simulation: dict | None = None, outputs: dict | None = None, description: str = "", check: bool = False):
    """A :class:`~assurjax.Scene` of a sketch, ready for ``simulate``, ``kinematics``, ``reactions``.

    ``q0`` (rad or m, default: the drawing's driving coordinate) and ``omega0`` are the
    initial state; ``gravity`` in m/s^2; ``outputs`` as in a scene file (``points``,
    ``angles``, ``reactions``, ``energies``); ``simulation`` solver settings. Every value
    is checked as a scene file's would be."""
    from .._errors import AssurjaxError
    from .._model import load_tuple
    from .._values import check_value
    from ..dynamics._settings import OUTPUT_KEYS, check_simulation_table, check_single_start
    from ..scene._scene import Scene, Settings

    built = build(sk, check=check)
    q0 = built.q0 if q0 is None else q0
    check_single_start(q0, omega0, t0, t1)
    check_value(AssurjaxError, "setting 'gravity':", gravity, shape=(2,))
    simulation = check_simulation_table(simulation or {}, "simulation")
    state = dict(q0=float(q0), omega0=float(omega0), t0=float(t0), t1=float(t1))
    out = dict(points=(), angles=(), reactions=(), energies=True) | check_simulation_table(outputs or {}, "outputs", OUTPUT_KEYS)
    out = {k: tuple(v) if isinstance(v, list) else v for k, v in out.items()}
    scene = Scene(mechanism=built.mechanism, gravity=jnp.asarray(gravity, dtype=float), loads=(), state=Settings(state),
                  simulation=Settings(simulation), outputs=Settings(out), name=sk.name, description=description,
                  notes=built.notes)
    return scene.with_loads(load_tuple(loads, "Sketch.scene"))  # checked against the mechanism
