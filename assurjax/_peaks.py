"""Peaks of joint reactions and driving effort along a simulated motion, located on the
solver's dense output rather than read off the saved samples.

A grid of samples misses narrow peaks (a quick-return ram reverses in a few
milliseconds). The search refines around the largest sample only: a peak narrower than
the sample spacing elsewhere can still be missed, so keep the grid fine enough to see
every peak (the command line uses 2001 samples). Each peak is bracketed by the largest sample and its two neighbours;
the motion is then evaluated again at a few times inside the bracket
(``simulate(..., saveat=...)`` interpolates the solver's dense output), and the bracket
shrinks around the new largest value; every round uses the same number of times, so the
compiled simulation and reactions are reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Peak:
    """The largest magnitude of one quantity along a motion: ``value`` (N for a reaction
    |F|; N m or N for the driving effort) at time ``t`` (s)."""

    name: str
    value: float
    t: float


def magnitudes(scene, sol, joints=None) -> dict[str, np.ndarray]:
    """|F| (N) of each joint (default: all) and |driving effort| (key ``"driving"``) at
    every sample of ``sol``."""
    import assurjax

    r = assurjax.reactions(scene, sol, joints=list(joints) if joints else None, check=False)
    out = {k: np.hypot(*np.moveaxis(np.asarray(v), -1, 0)) for k, v in r.forces.items()}
    out["driving"] = np.abs(np.asarray(r.driving))
    return out


def _bracket(t: np.ndarray, i: int) -> tuple[float, float]:
    return float(t[max(i - 1, 0)]), float(t[min(i + 1, len(t) - 1)])


def peak_reactions(scene, sol, *, joints=None, grid: dict | None = None, points: int = 33, rounds: int = 4,
                   **simulate_options) -> dict[str, Peak]:
    """Peak |F| of every joint (``joints``: default all) and the peak |driving effort|
    (key ``"driving"``) along the motion ``sol`` of ``scene``, each refined on the dense
    output around the largest sample of ``sol`` (see the module docstring).

    ``sol`` comes from ``assurjax.simulate(scene, **simulate_options)``; each refinement
    simulates again with those options and ``points`` save times inside the bracket
    (``rounds`` rounds per quantity, each dividing the bracket by (points - 1) / 2).
    ``grid``: the magnitudes at the samples of ``sol`` when already computed
    (as :func:`magnitudes` returns them).

    **Example:**
    >>> sol = assurjax.simulate(scene, saveat=np.linspace(0.0, 2.0, 201))
    >>> peak_reactions(scene, sol)["O2"].value    # N
    """
    import assurjax

    t = np.asarray(sol.t, dtype=float)
    peaks = {}
    for name, values in (magnitudes(scene, sol, joints) if grid is None else grid).items():
        values = np.asarray(values, dtype=float)
        i = int(np.nanargmax(values))
        best, (lo, hi) = (float(values[i]), float(t[i])), _bracket(t, i)
        for _ in range(rounds if len(t) > 1 else 0):
            if not hi > lo:
                break
            fine = assurjax.simulate(scene, saveat=np.linspace(lo, hi, points), t1=hi, **simulate_options)
            fine_t = np.asarray(fine.t, dtype=float)
            fine_values = magnitudes(scene, fine, joints)[name]
            j = int(np.nanargmax(fine_values))
            if fine_values[j] > best[0]:
                best = (float(fine_values[j]), float(fine_t[j]))
            lo, hi = _bracket(fine_t, j)
        peaks[name] = Peak(name, *best)
    return peaks
