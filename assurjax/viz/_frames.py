"""Plain numpy views of kinematic results, the common input of every plot and animation."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .._errors import AssurjaxError
from .._kinematics import Kinematics, broadcasts_to, check_mechanism, kinematics
from .._mechanism import Mechanism
from .._values import check_values

LENGTH_UNITS = {"m": 1.0, "cm": 1e2, "mm": 1e3}


def length_scale(unit: str, where: str = "length_scale") -> float:
    """Factor from metres to ``unit`` ("m", "cm" or "mm"); ``where`` names the caller in the error."""
    if not isinstance(unit, str) or unit not in LENGTH_UNITS:  # a list is no dict key: test the type first
        raise AssurjaxError(f"{where}: unit must be one of {', '.join(map(repr, LENGTH_UNITS))} (the axes' length unit), "
                            f"got {unit!r:.60}")
    return LENGTH_UNITS[unit]


def check_coordinates(where: str, name: str, q) -> np.ndarray:
    """``q`` as a 1-D float array of at least one finite driving coordinate, or an error naming ``name``."""
    check_values(AssurjaxError, where, **{name: q})
    q = np.atleast_1d(np.asarray(q, dtype=float))
    if q.ndim != 1 or not q.size:
        raise AssurjaxError(f"{where}: {name} must be one value or a 1-D array of at least one, got shape {q.shape}")
    return q


@dataclass(frozen=True)
class Frames:
    """A sequence of mechanism configurations as numpy arrays (SI units).

    ``q``: (n,) driving coordinate; ``points[name]``: (n, 2) positions (m);
    ``angles[link]``: (n,) link angles (rad, counterclockwise from +x);
    ``velocities[name]``: (n, 2) point velocities (m/s) or None;
    ``angular_velocities[link]``: (n,) (rad/s) or None;
    ``ok``: (n,) True where every group assembles (elsewhere values are meaningless);
    ``omega``: (n,) the driving velocity the velocities are at, or None where not known.
    """

    q: np.ndarray
    points: dict[str, np.ndarray]
    angles: dict[str, np.ndarray]
    velocities: dict[str, np.ndarray] | None
    angular_velocities: dict[str, np.ndarray] | None
    ok: np.ndarray
    omega: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.q)

    def at(self, i: int) -> dict:
        """Configuration ``i`` as a dict of points, angles and velocities."""
        pick = lambda d: None if d is None else {k: v[i] for k, v in d.items()}  # noqa: E731
        return dict(points=pick(self.points), angles=pick(self.angles), velocities=pick(self.velocities), ok=bool(self.ok[i]))


def frames_from_kinematics(kin: Kinematics) -> Frames:
    """Flatten a (batched) :class:`assurjax.Kinematics` into :class:`Frames`."""
    as_np = lambda d: None if d is None else {k: np.asarray(v).reshape(-1, *np.shape(v)[np.ndim(kin.q):]) for k, v in d.items()}  # noqa: E731
    q = np.asarray(kin.q).reshape(-1)
    ok = np.asarray(kin.ok).reshape(q.shape[0], -1).all(axis=-1)
    return Frames(
        q=q,
        points=as_np(kin.points),
        angles=as_np(kin.angles),
        velocities=as_np(kin.velocities),
        angular_velocities=as_np(kin.angular_velocities),
        ok=ok,
        omega=np.broadcast_to(np.asarray(kin.omega, dtype=float), np.shape(kin.q)).reshape(-1),
    )


def mechanism_frames(mechanism: Mechanism, q, omega=None, *, velocities: bool = False, check: bool = False) -> Frames:
    """Kinematics of ``mechanism`` at every q in ``q``. ``omega`` (rad/s or m/s) scales
    the velocities; it defaults to 1, i.e. velocities are kinematic coefficients.

    Configurations that do not assemble are kept and flagged False in ``Frames.ok`` (a
    sweep over a whole turn of a rocker: its coupler curves have gaps there); their
    positions are not a pose of the mechanism, whatever numbers they hold. With ``check=True``
    such a configuration raises :class:`assurjax.AssemblyError` naming the first group that
    cannot assemble and its q, as ``assurjax.kinematics`` does."""
    check_mechanism(mechanism, "mechanism_frames")
    q = check_coordinates("mechanism_frames", "q", q)
    if omega is not None:
        check_values(AssurjaxError, "mechanism_frames", omega=omega)
        if not broadcasts_to(np.shape(omega), q.shape):
            raise AssurjaxError(f"mechanism_frames: omega of shape {np.shape(omega)} does not match q's {q.shape}")
    omega = np.ones_like(q) if omega is None else np.broadcast_to(np.asarray(omega, dtype=float), q.shape)
    kin = kinematics(mechanism, q, omega, order=1 if velocities else 0, check=bool(check))
    return frames_from_kinematics(kin)


def masked(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``values`` with NaN where the mechanism does not assemble (matplotlib leaves gaps)."""
    out = np.array(values, dtype=float, copy=True)
    out[~np.asarray(ok)] = np.nan
    return out


def extent(frames: Frames, names: Iterable[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lower-left and upper-right corners (m) of the points over all assembled frames
    (their finite positions; the origin where there are none)."""
    names = list(frames.points) if names is None else list(names)
    xy = np.concatenate([frames.points[n][frames.ok] for n in names]) if frames.ok.any() else np.zeros((0, 2))
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    xy = xy if len(xy) else np.zeros((1, 2))
    return xy.min(axis=0), xy.max(axis=0)


def _link_size(points) -> float:
    """The largest extent (m) of a link's points in its own frame; 0 for a single point."""
    xy = np.array([np.asarray(p, dtype=float) for p in points.values()]).reshape(-1, 2)
    return float(np.ptp(xy, axis=0).max()) if len(xy) else 0.0


def reach_box(mechanism: Mechanism) -> tuple[np.ndarray, np.ndarray]:
    """Lower-left and upper-right corners (m) of the region the mechanism spans about its
    ground: the box of its ground points widened on every side by its longest link. From its
    geometry alone: a path that runs off near a singular position does not widen it, as it
    widens the points' extent."""
    ground = np.array([np.asarray(xy, dtype=float) for xy in mechanism.ground.values()]).reshape(-1, 2)
    ground = ground if len(ground) else np.zeros((1, 2))
    longest = max((_link_size(link.points) for link in mechanism.links.values()), default=0.0)
    return ground.min(axis=0) - longest, ground.max(axis=0) + longest
