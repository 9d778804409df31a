"""The sketch: a mechanism as a designer draws it (joints where they are, links as
lists of joints, ground joints, sliding pairs, the driver), validated on construction."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import NamedTuple

import numpy as np

from .._errors import MechanismError
from .._listing import did_you_mean, few
from .._mechanism import check_point_names
from .._values import MIN_LENGTH, check_value
from ..groups import GROUND

LINK_FIELDS = ("joints", "mass", "inertia", "com", "density")
MIN_EXTENT = MIN_LENGTH  # m: below it the squares of the drawing's lengths underflow
# A sketch's size: 12 times the 81 links of bench_decomposition.py's 40-group chain. At the
# bound its decomposition takes ~20 ms (it grows about linearly) and its build ~1 s (the
# mechanism's arrays and checks), and the traced programs grow with it.
MAX_LINKS = 1000
MAX_JOINTS = 2 * MAX_LINKS  # a chain has about one joint a link; plates have more


class Slide(NamedTuple):
    """A prismatic pair: ``link`` slides on ``on`` (a link name or ``"ground"``) along the
    drawn global ``direction`` (a 2-vector of any length from 1e-100 up, its sign fixes what "forward" means).
    The guide line passes through the sliding joint as drawn."""

    link: str
    on: str
    direction: tuple[float, float]


class LinkSpec(NamedTuple):
    """One link of a sketch: its joints (names, in order: a plate's outline for ``density``)
    and optional mass properties (kg, kg m^2 about the centre of mass, centre of mass as a
    drawn global point in m, density in kg/m for bars or kg/m^2 for plates)."""

    joints: tuple[str, ...]
    mass: float | None = None
    inertia: float | None = None
    com: tuple[float, float] | None = None
    density: float | None = None


class Sketch:
    """A planar one-degree-of-freedom mechanism as drawn in one pose.

    ``joints``: name -> (x, y), the drawn global position (m) of every joint and point.
    ``links``: name -> list of joint names (two for a bar, three or more for a plate; a
    point carried by one link only is just a point of it, e.g. a foot), or a table
    ``{"joints": [...], "mass": .., "inertia": .., "com": (x, y), "density": ..}`` (all but
    ``joints`` optional; ``com`` drawn, global; ``density`` per length for a bar, per area
    for a plate whose outline is its joints in the listed order; explicit values win).
    ``ground``: the joints (and points) fixed to the frame. ``slides``: prismatic pairs,
    :class:`Slide` or ``{"link", "on", "direction"}`` tables. ``driver``: the link that
    drives, a crank (pinned to the ground) or a slider (sliding on the ground).
    ``q0``: the driving coordinate of the drawing, rad for a crank (default: the drawn
    angle from the pivot to the crank's next joint), m for a slider (default 0: the
    slider's first joint as drawn is q = 0).

    Lengths, link frames, guide offsets, the formation sequence, every group's assembly
    mode and the iterative groups' starting guesses all follow from the drawing
    (:meth:`mechanism`). Bad drawings raise :class:`MechanismError` naming the joints
    or links at fault. A sketch has at most 1000 links and 2000 joints (``MAX_LINKS``,
    ``MAX_JOINTS``: over ten times the largest the benchmarks decompose).

    Example (a four-bar)::

        sk = Sketch(joints={"A": (0, 0), "B": (0.1, 0.2), "C": (0.5, 0.3), "D": (0.4, 0)},
                    links={"crank": ["A", "B"], "coupler": ["B", "C"], "rocker": ["D", "C"]},
                    ground=["A", "D"], driver="crank")
        mech = sk.mechanism()
    """

    def __init__(self, joints: Mapping, links: Mapping, *, ground: Iterable[str] = (), slides: Iterable = (),
                 driver: str, q0: float | None = None, name: str = "sketch"):
        self.name = str(name)
        joints, links = dict(joints), dict(links)
        _check_size(joints, links)  # before any is read: 10^5 links ran for minutes
        self.joints = {str(k): _point(v, f"joint '{k}'") for k, v in joints.items()}
        self.links = {str(k): _link_spec(k, v) for k, v in links.items()}
        self.ground = _names(ground, "ground")
        self.slides = tuple(_slide(s) for s in slides)
        self.driver = driver
        self.q0 = None if q0 is None else _number(q0, "q0")
        _validate(self)

    # -- derived structure ---------------------------------------------------------

    def carriers(self) -> dict[str, tuple[str, ...]]:
        """joint -> links carrying it (``"ground"`` first for a ground joint)."""
        out: dict[str, list[str]] = {j: [] for j in self.joints}
        for j in self.ground:
            out[j].append(GROUND)
        for name, spec in self.links.items():
            for j in spec.joints:
                out[j].append(name)
        return {j: tuple(c) for j, c in out.items()}

    def scale(self) -> float:
        """The drawing's size (m): the extent of its joints, for relative tolerances (not their
        distance from the origin: a drawing moved away keeps its tolerances and its modes)."""
        pts = np.array(list(self.joints.values()))
        return float(max(np.ptp(pts, axis=0).max(), 1e-300))

    def roundoff(self) -> float:
        """What a difference of two drawn coordinates can be off by (m): their round-off, which
        grows with their distance from the origin."""
        pts = np.array(list(self.joints.values()))
        return float(64 * np.finfo(float).eps * np.abs(pts).max())

    def mechanism(self, *, check: bool = False):
        """The explicit :class:`~assurjax.Mechanism` (see :func:`assurjax.structure.build`)."""
        from ._build import build

        return build(self, check=check).mechanism

    def decomposition(self):
        """The Assur decomposition (a :class:`~assurjax.structure.Decomposition`: printable, drawable)."""
        from ._decompose import decompose

        return decompose(self)

    def scene(self, **settings):
        """A :class:`~assurjax.Scene` of this sketch (see :func:`assurjax.structure.to_scene`)."""
        from ._build import to_scene

        return to_scene(self, **settings)

    def __repr__(self):
        return f"Sketch('{self.name}': {len(self.joints)} joints, {len(self.links)} links, {len(self.slides)} slides, driver '{self.driver}')"


def _check_size(joints: dict, links: dict) -> None:
    for what, table, limit in (("links", links, MAX_LINKS), ("joints", joints, MAX_JOINTS)):
        if len(table) > limit:
            raise MechanismError(f"the sketch has {len(table)} {what}; at most {limit} (its build and the traced "
                                 "programs grow with its size)")


def _number(v, what: str) -> float:
    check_value(MechanismError, f"{what}:", v, shape=())
    return float(v)


def _point(v, what: str) -> np.ndarray:
    check_value(MechanismError, f"{what}: a point [x, y] (m)", v, shape=(2,))
    return np.asarray(v, dtype=float)


def _names(v, what: str) -> tuple[str, ...]:
    """A list of joint names (a single string is refused: "AD" is not ["A", "D"])."""
    if isinstance(v, str) or not isinstance(v, Iterable) or not all(isinstance(n, str) for n in v):
        raise MechanismError(f"{what}: expected a list of joint names, got {v!r}")
    return tuple(v)


def _link_spec(name, value) -> LinkSpec:
    if isinstance(value, LinkSpec):
        value = {k: v for k, v in value._asdict().items() if v is not None}
    if isinstance(value, Mapping):
        extra = sorted(set(value) - set(LINK_FIELDS))
        if extra:
            raise MechanismError(f"link '{name}': unknown field(s) {extra}{did_you_mean(extra, LINK_FIELDS)} (known: {list(LINK_FIELDS)})")
        if "joints" not in value:
            raise MechanismError(f"link '{name}': missing 'joints' (the names of its joints)")
        joints = value["joints"]
        opts = {k: value[k] for k in ("mass", "inertia", "density") if value.get(k) is not None}
        for k, v in opts.items():
            if _number(v, f"link '{name}', {k}") < 0:
                raise MechanismError(f"link '{name}': {k} must be non-negative, got {v}")
        com = value.get("com")
        spec = LinkSpec((), **{k: float(v) for k, v in opts.items()}, com=None if com is None else tuple(_point(com, f"link '{name}', com")))
    else:
        joints, spec = value, LinkSpec(())
    if isinstance(joints, str) or not isinstance(joints, Iterable):
        raise MechanismError(f"link '{name}': expected a list of joint names, got {joints!r}")
    joints = tuple(joints)
    if not joints or not all(isinstance(j, str) for j in joints):
        raise MechanismError(f"link '{name}': expected a non-empty list of joint names, got {list(joints)!r}")
    return spec._replace(joints=joints)


def _slide(s) -> Slide:
    if isinstance(s, Mapping):
        extra = sorted(set(s) - {"link", "on", "direction"})
        missing = [k for k in ("link", "on") if k not in s]
        if extra or missing:
            raise MechanismError(f"slide {dict(s)!r}: fields are 'link', 'on', 'direction'; unknown {extra}, missing {missing}"
                                 f"{did_you_mean(extra, ('link', 'on', 'direction'))}")
        s = Slide(s["link"], s["on"], s.get("direction"))
    elif not isinstance(s, Slide):
        raise MechanismError(f"slide {s!r}: expected Slide(link, on, direction) or a table with link, on, direction")
    where = f"slide of '{s.link}' on '{s.on}'"
    if s.direction is None:
        raise MechanismError(f"{where}: no direction (give the drawn direction of the guide, e.g. [1, 0])")
    u = _point(s.direction, f"{where}, direction")
    check_value(MechanismError, f"{where}: the direction", u, nonzero_vector=True)  # as a scene's guide directions
    return Slide(str(s.link), str(s.on), (float(u[0]), float(u[1])))


def _coincident(sk: Sketch, joints: tuple[str, ...], tol: float) -> tuple[str, str] | None:
    """The first two of a link's ``joints`` drawn within ``tol`` of each other, or None (every
    pair at once: a plate of 2000 joints has 2e6 pairs, seconds one by one)."""
    x = np.array([sk.joints[j] for j in joints])
    gap = np.hypot(*np.moveaxis(x[:, None] - x[None], -1, 0))
    first, second = np.nonzero(np.triu(gap <= tol, 1))
    return None if first.size == 0 else (joints[first[0]], joints[second[0]])


def _validate(sk: Sketch) -> None:
    if not sk.links:
        raise MechanismError("the sketch has no links")
    if sk.scale() < MIN_EXTENT:
        raise MechanismError(f"the drawing spans {sk.scale():.3g} m; at least {MIN_EXTENT:g} m (the squares of its "
                             "lengths must stay representable)")
    if GROUND in sk.links:
        raise MechanismError(f"link name '{GROUND}' is reserved for the frame: list fixed joints in 'ground'")
    if GROUND in sk.joints:
        raise MechanismError(f"joint name '{GROUND}' is reserved")
    check_point_names(sk.joints)
    for j in sk.ground:
        if j not in sk.joints:
            raise MechanismError(f"ground joint '{j}' is not among the joints {few(sorted(sk.joints))}")
    if len(set(sk.ground)) != len(sk.ground):
        raise MechanismError(f"a ground joint is listed twice: {few(sk.ground)}")
    tol = 1e-9 * sk.scale() + sk.roundoff()
    for name, spec in sk.links.items():
        unknown = [j for j in spec.joints if j not in sk.joints]
        if unknown:
            raise MechanismError(f"link '{name}' uses joint(s) {few(unknown)} that are not drawn (joints: {few(sorted(sk.joints))})")
        if len(set(spec.joints)) != len(spec.joints):
            raise MechanismError(f"link '{name}' lists a joint twice: {few(spec.joints)}")
        if (pair := _coincident(sk, spec.joints, tol)) is not None:
            raise MechanismError(f"link '{name}': joints '{pair[0]}' and '{pair[1]}' coincide in the drawing (a link cannot "
                                 f"carry two joints at one place; within {tol:.3g} m, 1e-9 of the drawing's extent "
                                 f"{sk.scale():.3g} m)")
    used = {j for spec in sk.links.values() for j in spec.joints} | set(sk.ground)
    unused = [j for j in sk.joints if j not in used]
    if unused:
        raise MechanismError(f"joint(s) {few(unused)} belong to no link and not to the ground")
    pairs = set()
    for s in sk.slides:
        for end in (s.link, s.on):
            if end != GROUND and end not in sk.links:
                raise MechanismError(f"slide of '{s.link}' on '{s.on}': unknown link '{end}' (links: {few(sk.links)})")
        if s.link == s.on:
            raise MechanismError(f"slide of '{s.link}' on itself")
        key = frozenset((s.link, s.on))
        if key in pairs:
            raise MechanismError(f"two slides between '{s.link}' and '{s.on}' (over-constrained)")
        pairs.add(key)
    if not isinstance(sk.driver, str) or sk.driver not in sk.links:
        raise MechanismError(f"driver {sk.driver!r} is not one of the links {few(sk.links)}")
