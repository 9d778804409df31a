"""Ready-made synthesis problems (designs + objectives) used by the examples and benchmarks."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .._errors import AssemblyError
from ._design import Design
from ._linkages import roberts_like
from ._objectives import coupler_curve, straight_line_deviation

ROBERTS_Q0 = math.acos(1.0 / 3.0)  # the Roberts linkage's symmetric position (seed 001)


def straight_line_problem(lengths, *, stroke: float = 0.26, q0: float = ROBERTS_Q0, spread: float = 0.3, samples: int = 41):
    """Straight-line synthesis of a Roberts-type four-bar (seed 001).

    Design variables: the six lengths (AD, AB, DC, BC, BP, CP) in m, each free
    within ``(1 -/+ spread)`` times its start value, and the x position (m) of the
    middle of the ``stroke`` (m) of coupler point P, within 0.1 m of its start.
    The start centre is the middle of the stretch of x that P sweeps monotonically
    on the branch through ``q0`` (so a perturbed linkage starts with a reachable stroke).

    Returns ``(design, objective)`` for :func:`optimize` (with ``has_aux=True``):
    the objective is the smooth straight-line deviation (m); its aux holds the
    exact ``deviation`` (m) and the ``ok`` flag.
    """
    lengths = jnp.asarray(lengths, dtype=float)
    c0 = _reachable_centre(roberts_like(lengths), q0, stroke)
    design = Design((lengths, jnp.asarray(c0)), lambda t: (t[0], t[1]),
                    lower=(lengths * (1 - spread), c0 - 0.1), upper=(lengths * (1 + spread), c0 + 0.1))

    def objective(t):
        lengths, centre = t
        line = straight_line_deviation(roberts_like(lengths), "P", stroke=stroke, q0=q0, center=centre, samples=samples)
        return line.smooth, {"ok": line.ok, "deviation": line.deviation}

    return design, objective


def _reachable_centre(mechanism, q0: float, stroke: float, half_width: float = 1.5, n: int = 601) -> float:
    grid = q0 + np.linspace(-half_width, half_width, n)
    pts, ok = coupler_curve(mechanism, "P", grid)
    x, ok = np.asarray(pts[:, 0]), np.asarray(ok)
    i0 = (n - 1) // 2
    dx = np.diff(x)
    good = ok[:-1] & ok[1:] & (dx * np.sign(dx[i0]) > 0)
    right = i0
    while right < n - 1 and good[right]:
        right += 1
    left = i0
    while left > 0 and good[left - 1]:
        left -= 1
    lo, hi = sorted((x[left], x[right]))
    margin = 0.02 * stroke
    if hi - lo < stroke + 2 * margin:
        raise AssemblyError(
            f"straight-line problem: coupler point P sweeps only {1e3 * (hi - lo):.1f} mm monotonically on the branch "
            f"through q0 = {q0:.4g}, less than the {1e3 * stroke:.0f} mm stroke"
        )
    return float(np.clip(x[i0], lo + stroke / 2 + margin, hi - stroke / 2 - margin))
