"""Peaks of joint reactions, driving effort and joint friction along a simulated motion, located on the
solver's dense output rather than read off the saved samples.

A grid of samples misses narrow peaks (a quick-return ram reverses in a few
milliseconds). The search refines around the largest sample only: a peak narrower than
the sample spacing elsewhere can still be missed, so keep the grid fine enough to see
every peak (the command line uses 2001 samples). Each peak is bracketed by the largest sample and its two neighbours;
the motion is then evaluated again at a few times inside the bracket
(``simulate(..., saveat=...)`` interpolates the solver's dense output), and the bracket
shrinks around the new largest value. A round refines every quantity at once, in one
simulation and one reactions analysis that save as many times as the run being refined:
they run that run's compiled programs (a program of their own cost a trace and compile
as long as the run's, the bulk of the command's peak search).
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


FRICTION = "friction "  # the key prefix of a friction element's |value|: "friction <pair>"


def magnitudes(scene, sol, joints=None) -> dict[str, np.ndarray]:
    """|F| (N) of each joint (default: all), |driving effort| (key ``"driving"``) and, with
    joint friction, |friction| of each pair's element (N m, or N on a prismatic pair; key
    ``"friction <pair>"``) at every sample of ``sol``."""
    import assurjax

    r = assurjax.reactions(scene, sol, joints=list(joints) if joints else None, check=False)
    return magnitudes_of(r.forces, r.driving, r.friction)


def magnitudes_of(forces: dict, driving, friction: dict) -> dict[str, np.ndarray]:
    """:func:`magnitudes` from reactions already computed: ``forces`` (..., 2) per joint, the
    ``driving`` effort and the ``friction`` value per pair (as :class:`assurjax.Reactions` has them)."""
    out = {k: np.hypot(*np.moveaxis(np.asarray(v), -1, 0)) for k, v in forces.items()}
    out["driving"] = np.abs(np.asarray(driving))
    return out | {FRICTION + k: np.abs(np.asarray(v)) for k, v in friction.items()}


def _bracket(t: np.ndarray, i: int) -> tuple[float, float]:
    return float(t[max(i - 1, 0)]), float(t[min(i + 1, len(t) - 1)])


def _largest_within(t: np.ndarray, values: np.ndarray, lo: float, hi: float):
    """(the largest value among the samples in [lo, hi], its time, the bracket around it:
    its neighbours among the distinct sample times there; a time saved twice, a save time
    at a solver step's end, counts once)."""
    inside = (t >= lo) & (t <= hi) & ~np.isnan(values)
    if not np.any(inside):  # nothing counted there: the bracket closes
        return -np.inf, lo, (lo, lo)
    times, first = np.unique(t[inside], return_index=True)
    values = values[inside][first]
    j = int(np.nanargmax(values))
    return float(values[j]), float(times[j]), _bracket(times, j)


def _refinement_times(template: np.ndarray, reached: int, fine: np.ndarray) -> list[np.ndarray]:
    """Save times for the refinement runs, each as many as ``template`` (the run's own, of
    which it reached the first ``reached``): the ``fine`` times in place of the template's
    earliest ones, so that as many times are reached and saved as in the run (its
    reactions' program fits too); in several runs where there are more fine times than that."""
    per_run = max(reached, 1)
    return [np.sort(np.concatenate([fine[i:i + per_run], template[len(fine[i:i + per_run]):]]))
            for i in range(0, len(fine), per_run)]


def peak_reactions(scene, sol, *, joints=None, grid: dict | None = None, points: int = 33, rounds: int = 4,
                   saveat=None, before: float | None = None, **simulate_options) -> dict[str, Peak]:
    """Peak |F| of every joint (``joints``: default all), the peak |driving effort|
    (key ``"driving"``) and with joint friction the peak |friction| of every element (key
    ``"friction <pair>"``) along the motion ``sol`` of ``scene``, each refined on the dense
    output around the largest sample of ``sol`` (see the module docstring).

    ``sol`` comes from ``assurjax.simulate(scene, saveat=saveat, **simulate_options)``;
    each refinement round simulates again with those options, saving ``points`` times
    inside each quantity's bracket (``rounds`` rounds, each dividing the brackets by
    (points - 1) / 2). ``saveat``: that run's save times (default: the times of ``sol``,
    which are those where it saved no solver steps), so that the refinements run its
    compiled programs. ``grid``: the magnitudes at the samples of ``sol`` when already
    computed (as :func:`magnitudes` returns them). ``before``: only samples earlier than this
    time count (the end of a run stopped at a lock-up or a jam, where the state's dw/dt is
    not the motion's: its reactions are not the motion's either).

    **Example:**
    >>> sol = assurjax.simulate(scene, saveat=np.linspace(0.0, 2.0, 201))
    >>> peak_reactions(scene, sol)["O2"].value    # N
    """
    import assurjax

    t = np.asarray(sol.t, dtype=float)
    template = t if saveat is None else np.asarray(saveat, dtype=float)
    reached = int(np.count_nonzero((template - template[0]) * (t[-1] - template) >= 0)) if len(t) else 0
    best, brackets = {}, {}
    counted = np.ones(len(t), dtype=bool) if before is None or not np.any(t < before) else t < before
    for name, values in (magnitudes(scene, sol, joints) if grid is None else grid).items():
        values = np.where(counted, np.asarray(values, dtype=float), np.nan)
        i = int(np.nanargmax(values))
        best[name], brackets[name] = (float(values[i]), float(t[i])), _bracket(t, i)
    for _ in range(rounds if len(t) > 1 else 0):
        brackets = {name: (lo, hi) for name, (lo, hi) in brackets.items() if hi > lo}
        if not brackets:
            break
        fine = np.sort(np.concatenate([np.linspace(lo, hi, points) for lo, hi in brackets.values()]))
        runs = [assurjax.simulate(scene, saveat=times, **simulate_options)
                for times in _refinement_times(template, reached, fine)]
        fine_t = np.concatenate([np.asarray(run.t, dtype=float) for run in runs])
        found = [magnitudes(scene, run, joints) for run in runs]
        for name, (lo, hi) in brackets.items():
            value, at, brackets[name] = _largest_within(fine_t, np.concatenate([f[name] for f in found]), lo,
                                                        hi if before is None else min(hi, np.nextafter(before, -np.inf)))
            if value > best[name][0]:
                best[name] = (value, at)
    return {name: Peak(name, *value) for name, value in best.items()}
