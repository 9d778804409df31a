"""What every Assur group (and driver) provides.

A group is an equinox Module: its structure (names, assembly mode) is static and
its own parameters (guide directions, offsets) are arrays. ``solve`` is a pure
JAX function: it reads the global positions of the group's external joints (and
the angles of the links carrying its guides) from a :class:`Placement` and
returns the frames of the group's own links plus an ``ok`` flag that is False
when the group cannot assemble. Values are kept finite (never NaN) even then.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import MechanismError
from .._geometry import V2, heading, relative_rotation, rotate
from .._repr import value_pdoc


class Frame(NamedTuple):
    """Pose of a link: global position of its local origin and its rotation as a
    unit vector (cos, sin) of the angle of its local x axis (rotations are kept
    as unit vectors so the position analysis needs no atan2, cos or sin)."""

    origin: Array
    rot: Array

    @property
    def angle(self) -> Array:
        """Angle (rad) of the local x axis, counterclockwise from +x, in (-pi, pi]."""
        return heading(self.rot)


class Link(eqx.Module):
    """A rigid link. ``points`` are named points in the link's own frame (m);
    a point name shared by two links is the joint between them. ``inertia`` is
    the centroidal moment of inertia (kg m^2).

    Defaults as in a scene file: ``com`` the centroid of the points, ``mass`` and
    ``inertia`` zero. Example: ``Link({"A": [0.0, 0.0], "B": [0.3, 0.0]}, mass=0.6)``.
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    points: dict[str, Array]
    com: Array
    mass: Array
    inertia: Array

    def __init__(self, points, com=None, mass=0.0, inertia=0.0):
        _check_points(points, com)
        # Python numbers become arrays: a float leaf would be static under filter_jit
        self.points = {k: _as_array(v) for k, v in points.items()}
        if com is None:
            shapes = {k: np.shape(v) for k, v in self.points.items()}
            if any(shape != (2,) for shape in shapes.values()):  # else the mean below fails in JAX's words
                raise MechanismError(f"Link: each point must be [x, y] (m), got shapes {shapes}")
        self.com = jnp.mean(jnp.stack(list(self.points.values())), axis=0) if com is None else _as_array(com)
        self.mass = _as_array(mass)
        self.inertia = _as_array(inertia)


def _check_points(points, com) -> None:
    """A mapping of point names to points, and one point at least where the centre of mass is
    their centroid (else JAX's "Need at least one array to stack", or an AttributeError)."""
    if not isinstance(points, Mapping):
        raise MechanismError(f"Link: points must map point names to [x, y] (m), e.g. {{'A': [0.0, 0.0]}}, got "
                             f"{type(points).__name__} {points!r:.60}")
    if not all(isinstance(k, str) for k in points):
        raise MechanismError(f"Link: point names must be strings, got {[k for k in points if not isinstance(k, str)]!r:.60}")
    if not points and com is None:
        raise MechanismError("Link: points is empty; a link needs at least one named point (its centre of mass "
                             "defaults to their centroid)")


def _as_array(x):
    words = isinstance(x, (str, bool)) or (isinstance(x, (list, tuple)) and any(isinstance(v, (str, bool, list, tuple, dict)) for v in x))
    if words:  # JAX reads "0.1" as 0.1 and True as 1.0
        raise MechanismError(f"Link: a point or value must hold numbers only, got {x!r}")
    return jnp.asarray(x, dtype=float) if isinstance(x, (int, float, list, tuple)) else x


MODES = {"left": 1, "right": -1, "forward": 1, "backward": -1, "+": 1, "-": -1, "+1": 1, "-1": -1, 1: 1, -1: -1}
"""Assembly modes by name: +1 is "left" (RRR) or "forward" (RRP, PRR, RPR), -1 "right" or "backward"."""


def as_mode(value):
    """An assembly mode as +1/-1 from a name in :data:`MODES` or an integer; other
    values are returned unchanged for :func:`check_mode` to reject with the group's name."""
    if isinstance(value, str):
        return MODES.get(value.strip().lower(), value)
    if not isinstance(value, bool) and isinstance(value, (int, np.integer)) and int(value) in (1, -1):
        return int(value)
    return value


def check_mode(group) -> None:
    if isinstance(group.mode, bool) or group.mode not in (1, -1):
        raise MechanismError(
            f"{group.describe()}: mode must be 'left'/'right' (or 'forward'/'backward', +1/-1), got {group.mode!r}"
        )


GROUND = "ground"


class Placement:
    """Links placed so far during the position analysis (a trace-time helper,
    not a pytree): ``owner`` maps each point name to the link it is read from.
    ``near`` (link angles to start from, rad) is the branch predictor; ``from_guess``
    and ``loose`` serve the iterative groups: start Newton from the group's own guess
    (at its reference coordinate), stop at continuation tolerance. ``mechanism`` is
    accepted for compatibility and not used (the groups never call back into it)."""

    def __init__(self, links: dict[str, Link], owner: dict[str, str], frames: dict[str, Frame], *, mechanism=None, near=None,
                 from_guess: bool = False, loose: bool = False):
        self.links = links
        self.owner = owner
        self.frames = frames
        self.mechanism = mechanism
        self.near = near
        self.from_guess = from_guess
        self.loose = loose

    def point(self, name: str) -> Array:
        link = self.owner[name]
        frame = self.frames[link]
        return frame.origin + rotate(self.links[link].points[name], frame.rot)

    def xy(self, name: str):
        """Like :meth:`point`, as separate components (a :class:`V2`)."""
        link = self.owner[name]
        frame = self.frames[link]
        return V2.of(frame.origin) + V2.of(self.links[link].points[name]).rotate(V2.of(frame.rot))

    def rotation_of_owner(self, name: str) -> Array:
        """Rotation (cos, sin) of the link that carries point ``name``."""
        return self.frames[self.owner[name]].rot

    def local(self, link: str, name: str) -> Array:
        return self.links[link].points[name]


def frame_through(local_a, local_b, global_a, global_b) -> Frame:
    """The frame that maps two local points of a link onto their global positions
    (the distance between them is assumed to match)."""
    rot = relative_rotation(local_b - local_a, global_b - global_a)
    return Frame(global_a - rotate(local_a, rot), rot)


def frame_through_xy(local_a, local_b, global_a, global_b) -> Frame:
    """:func:`frame_through` with the global points as :class:`V2` (no sqrt, no atan2)."""
    la, lb = V2.of(local_a), V2.of(local_b)
    local, glob = lb - la, global_b - global_a
    inv = 1.0 / local.dot(local)  # a constant of the link
    rot = V2(glob.dot(local) * inv, local.cross(glob) * inv)
    return Frame((global_a - la.rotate(rot)).array(), rot.array())


def frame_from_rotation_xy(local_a, global_a, rot) -> Frame:
    """:func:`frame_from_rotation` with ``global_a`` and ``rot`` as :class:`V2`."""
    return Frame((global_a - V2.of(local_a).rotate(rot)).array(), rot.array())


def frame_from_rotation(local_a, global_a, rot) -> Frame:
    """The frame with rotation ``rot`` (cos, sin) that maps a local point onto its global position."""
    return Frame(global_a - rotate(local_a, rot), rot)


def distance(links: dict[str, Link], link: str, a: str, b: str) -> Array:
    """Distance between two named points of one link (m)."""
    d = links[link].points[a] - links[link].points[b]
    return jnp.sqrt(d[0] ** 2 + d[1] ** 2)


class AbstractGroup(eqx.Module):
    """Base of drivers and Assur groups.

    Subclasses declare ``kind``, ``n_prismatic`` (prismatic pairs that are not
    visible as shared point names) and ``two_modes`` and implement ``external_points``,
    ``required_points`` and ``solve``.
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    name: eqx.AbstractVar[str]
    links: eqx.AbstractVar[tuple[str, ...]]
    kind: ClassVar[str]
    n_prismatic: ClassVar[int] = 0
    is_driver: ClassVar[bool] = False
    two_modes: ClassVar[bool] = False  # a closed form with two assembly modes, its field ``mode`` = +1 / -1
    # the fields naming links and points: how many names each holds (0: one name, a string)
    name_fields: ClassVar[dict[str, int]] = {}

    def __check_init__(self):
        for field, count in self.name_fields.items():
            names = getattr(self, field)
            if count == 0:
                good = isinstance(names, str)
            else:
                good = isinstance(names, tuple) and len(names) == count and all(isinstance(n, str) for n in names)
            if not good:
                wanted = "a name (a string)" if count == 0 else f"a tuple of {count} name{'s' if count > 1 else ''} (strings)"
                raise MechanismError(f"{self.describe()}: {field} must be {wanted}, got {names!r}")

    @abc.abstractmethod
    def external_points(self) -> tuple[str, ...]:
        """Points this group reads from earlier groups (joints, guide points)."""

    @abc.abstractmethod
    def required_points(self) -> dict[str, tuple[str, ...]]:
        """For each of the group's links, the point names it must carry."""

    @abc.abstractmethod
    def solve(self, links: dict[str, Link], placed: Placement, q: Array) -> tuple[dict[str, Frame], Array]:
        """Frames of this group's links and an ``ok`` flag (False: cannot assemble)."""

    def prismatic_pairs(self, owner: dict) -> tuple[tuple[str, str, str], ...]:
        """(slider link, link carrying the guide, sliding point) of each prismatic pair;
        ``owner`` maps point names to the links carrying them."""
        return ()

    def guides(self) -> tuple[tuple[str | None, Array, Array], ...]:
        """(point the guide line passes through, or None for a guide along the other link
        of the pair; direction in its link's frame; offset to the left, m) of each guide."""
        return ()

    singular_configuration = "its singular configuration"  # where ``singularity`` is zero, in words

    def singularity(self, x: dict, dx: dict, turn: dict, dturn: dict) -> tuple[Array, Array] | None:
        """A scale-free measure that crosses zero at this group's singular configurations
        and its q-derivative, from the global points ``x`` and their coefficients ``dx``
        (dx/dq), and the links' rotations ``turn`` ((cos, sin) by link name) and theirs
        ``dturn``; None when the kind declares none (then it is never bridged, see
        :func:`assurjax.bridged_coefficients`, nor its exact limit refused as a start).
        (The rotations were added for the slider dyads, whose guide's direction the points
        alone do not give: a group of one's own with the former ``(x, dx)`` takes them too.)"""
        return None

    def describe(self) -> str:
        return f"group '{self.name}' ({self.kind})"
