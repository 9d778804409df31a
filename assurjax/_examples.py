"""Generated example mechanisms (scenes too regular to write out by hand)."""

from __future__ import annotations

import math

from ._errors import AssurjaxError
from .scene._load import scene_from_dict
from .scene._scene import Scene


def _bar(a: str, b: str) -> dict:
    """A uniform bar of 1 m and 1 kg from point a (local origin) to point b:
    centre of mass at its middle, centroidal inertia m L^2 / 12 (kg m^2)."""
    return {"points": {a: [0.0, 0.0], b: [1.0, 0.0]}, "com": [0.5, 0.0], "mass": 1.0, "inertia": 1.0 / 12.0}


def n_four_bar_dict(n: int, *, t1: float = 20.0) -> dict:
    """The scene tables of :func:`n_four_bar` (to edit before ``scene_from_dict``)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise AssurjaxError(f"n_four_bar: the number of windows N must be a positive integer, got {n!r}")
    ground = {f"O{i}": [float(i), 0.0] for i in range(n + 1)}
    links = {f"rocker{i}": _bar(f"O{i}", f"B{i}") for i in range(n + 1)}
    links.update({f"coupler{i}": _bar(f"B{i}", f"B{i + 1}") for i in range(n)})
    formation = [{"group": "crank", "name": "driver", "link": "rocker0", "pivot": "O0"}]
    formation += [
        # B_(i+1) starts left of the directed line B_i -> O_(i+1) (rockers up)
        {"group": "RRR", "name": f"window{i}", "links": [f"coupler{i}", f"rocker{i + 1}"], "joints": [f"B{i}", f"O{i + 1}", f"B{i + 1}"], "mode": "left"}
        for i in range(n)
    ]
    return {
        "scene": {"name": f"n_four_bar_{n}", "description": f"IFToMM A02: {n} four-bar windows of unit bars under gravity", "gravity": [0.0, -9.81]},
        "ground": ground,
        "links": links,
        "formation": formation,
        # rockers vertical (up); B_0 moves along +x at 1 m/s: omega = -1 rad/s
        "state": {"q0": math.pi / 2, "omega0": -1.0, "t1": float(t1)},
        "outputs": {"points": ["B0", f"B{n}"], "angles": ["rocker0", f"rocker{n}"], "energies": True},
    }


def n_four_bar(n: int, *, t1: float = 20.0) -> Scene:
    """IFToMM multibody benchmark A02, the N-four-bar mechanism, as a Scene.

    N four-bar windows built from 2N+1 uniform bars of 1 m and 1 kg (inertia
    1/12 kg m^2 about the centre): ground pivots O_0..O_N at x = 0..N m, a rocker
    ``rocker{i}`` from O_i to B_i on each, ``rocker0`` the driver (q = its angle,
    rad, from +x, counterclockwise), and couplers ``coupler{i}`` from B_i to B_(i+1).
    Window i is an RRR dyad (coupler i + rocker i+1; external joints B_i and
    O_(i+1), internal B_(i+1)). Gravity 9.81 m/s^2 along -y. The initial state has
    the rockers vertical (q0 = pi/2) and B_0 moving along +x at 1 m/s (omega0 = -1 rad/s).

    The motion stays on the parallelogram branch, which crosses two singular
    configurations per revolution (rockers along +x: every dyad's external joints
    coincide; along -x: every dyad is stretched). The fixed mode "left" is wrong
    past them: simulate with branch tracking (``near`` predictors).

    >>> scene = assurjax.n_four_bar(2)
    >>> scene.mechanism.group_names
    ('driver', 'window0', 'window1')
    """
    return scene_from_dict(n_four_bar_dict(n, t1=t1), source=f"n_four_bar({n})")
