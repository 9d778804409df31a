"""The ``assurjax`` command: run scenes, check them, sweep their kinematics, compute reactions.

    assurjax run [SCENE] [--out DIR] [--samples N]   simulate (default scene: watt_sixbar): CSV, plots, GIF, summary
    assurjax validate SCENE                          check a scene file (exit status 2 when it is bad)
    assurjax scenes                                  list the bundled scenes
    assurjax kinematics SCENE [--samples N]          sweep the driving coordinate: coupler curves, angular velocities
    assurjax reactions SCENE [--samples N]           joint reactions and driving effort along the motion (or at rest)

``--samples`` is the number of equally spaced output times (run, reactions; the
solver's own steps are saved with them, so fast changes are sampled where the solver
resolves them) or configurations (kinematics). Peak reactions and driving efforts are
located on the solver's dense output, not read off those samples.

Exit status: 0 success, 2 bad input (scene, file, arguments), 1 anything else: an
internal error, or a run whose solver failed (its files written, its lines saying the
motion is not to be trusted; a standstill, a lock-up, a user event and a friction jam
end a motion physically: 0). Errors print one line; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from typing import NamedTuple
from collections.abc import Sequence
from pathlib import Path

DEFAULT_SCENE = "watt_sixbar"
SCENE_HELP = "a scene file (.toml) or a bundled scene's name (see 'assurjax scenes')"
USER_ERROR, INTERNAL_ERROR = 2, 1
RUN_FAILED = 1  # a run whose solver failed (not a lock-up, standstill, event or friction jam): files written, lines warn
RUN_SAMPLES = 2001  # output times of run/reactions unless the scene's [simulation] samples says otherwise
SWEEP_SAMPLES = 721  # configurations of a kinematic sweep: half-degree steps over a crank turn
PATH_SAMPLES = 1441  # configurations behind a traced path: smooth curves, no polyline corners
MAX_SAMPLES = 100_000  # as [simulation] samples: beyond it the outputs alone would take minutes
MAX_FRAMES = 2_000  # animation frames: ~1 min to render


class UserError(Exception):
    """A mistake in the command line or its files (exit status 2)."""


# ---------------------------------------------------------------------------- helpers


def _progress(total: int, desc: str, quiet: bool):
    """A tqdm bar on stderr; silent when stderr is not a terminal or with --quiet."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, disable=quiet or not sys.stderr.isatty(), leave=False)


def _load(scene: str):
    import assurjax

    return assurjax.load_scene(scene)


def _out_dir(path: str | None, scene) -> Path:
    out = Path(path) if path else Path("assurjax-out") / scene.name
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create output directory {out}: {e.strerror}") from None
    return out


def _driver_kind(mechanism) -> str:
    return mechanism.driver.kind


def _write_csv(path: Path, columns: dict) -> Path:
    """One column per entry (equal lengths); numbers written with full precision, NaN (no
    value: where the mechanism does not assemble, or a ratio at a singular configuration)
    as an empty cell."""
    import numpy as np

    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float).reshape(-1) for n in names])
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(names)
        writer.writerows([["" if math.isnan(x) else repr(float(x)) for x in row] for row in data])
    return path


def _savefig(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    if fig.get_layout_engine() is None:
        fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")  # a legend placed beside the axes is kept whole
    plt.close(fig)
    return path


def _units(kind: str) -> dict:
    slider = kind == "slider"
    return dict(q="m" if slider else "rad", omega="m/s" if slider else "rad/s", domega="m/s^2" if slider else "rad/s^2", driving="N" if slider else "N m")


# ---------------------------------------------------------------------------- scenes / validate


def cmd_scenes(args) -> int:
    import assurjax

    for name in assurjax.bundled_scenes():
        scene = assurjax.load_scene(name)
        print(f"{name:20s} {scene.description}")
    return 0


VALIDATE_SAMPLES = 361  # the assembly sweep of `validate`: one sample per degree of a crank turn


def cmd_validate(args) -> int:
    import assurjax
    import numpy as np

    from ._model import massless_members

    scene = _load(args.scene)
    mech = scene.mechanism
    pose = _pose_at_q0(scene)
    massless = bool(massless_members(mech).size)
    if not massless:  # what `run` would refuse (without masses it refuses to run at all: said below)
        _check_runnable(_as_run(scene), _samples(args, scene))
    print(f"{scene.name}: OK ({scene.source})")
    if scene.description:
        print(f"  {scene.description}")
    print(f"  links: {', '.join(mech.links)}")
    print(f"  formation: {' -> '.join(f'{g.name} ({g.kind})' for g in mech.groups)}")
    print(f"  loads: {len(scene.loads)}, gravity: {np.asarray(scene.gravity).tolist()} m/s^2")
    print(f"  assembles at q0 = {scene.state['q0']:.6g} {_units(_driver_kind(mech))['q']} ({len(pose.points)} points)")
    for note in scene.notes:
        print(f"  note: {note}")
    if massless:
        print("  note: no link has a mass or a moment of inertia: kinematics and statics only (`run` needs masses)")
    lo, hi = _sweep_range(scene, None, None)
    print("  over the driving range: " + _assembly_text(mech, np.linspace(lo, hi, VALIDATE_SAMPLES)).replace("\n", "\n  "))
    return 0


def _pose_at_q0(scene):
    """The pose at the scene's q0, or an AssemblyError naming the file, the group, why it does not
    close (with the lengths) and the scene fields that set them."""
    import assurjax
    from ._kinematics import raise_if_not_assembled

    q0 = scene.state["q0"]
    pose = assurjax.positions(scene.mechanism, q0)
    unit = _units(_driver_kind(scene.mechanism))["q"]
    raise_if_not_assembled(scene.mechanism, pose.ok, q0, pose=pose, where=f"{scene.source}: ",
                           advice=lambda links: f"check {_fields_of(scene, links)} (m), or [state] q0 ({unit})")
    return pose


def _fields_of(scene, links) -> str:
    """The scene file's fields where the points of these links are set (GROUND: the fixed points)."""
    import tomllib

    from .groups import GROUND

    moving = [link for link in links if link != GROUND]
    try:
        sketch = "sketch" in tomllib.loads(Path(scene.source).read_text(encoding="utf-8"))
    except (OSError, ValueError):  # not a file (a scene built in Python): the explicit form's names
        sketch = False
    if sketch:
        return f"the [sketch.joints] of link(s) {', '.join(moving)}" + (" and the ground joints" if GROUND in links else "")
    tables = [f"[links.{link}] points" for link in moving] + (["[ground]"] if GROUND in links else [])
    return ", ".join(tables[:-1]) + f" and {tables[-1]}" if len(tables) > 1 else tables[0]


def _assembly_text(mech, q) -> str:
    """Where the mechanism assembles over the driving coordinates ``q``, and where each group
    that fails on its own does not, with the condition it violates (lines; see
    ``assurjax.structure.assembly_report``)."""
    from assurjax.structure import assembly_report

    unit = "m" if _driver_kind(mech) == "slider" else "rad"
    return str(assembly_report(mech, q)).replace("samples of q", f"samples of q ({unit})")


# ---------------------------------------------------------------------------- kinematics


def _sweep_range(scene, start, stop) -> tuple[float, float]:
    import numpy as np

    from ._values import MAGNITUDE_LIMIT

    q0 = scene.state["q0"]
    if _driver_kind(scene.mechanism) == "slider":
        reach = _size(scene.mechanism)  # the slider cannot go much further than the links reach
        default = (q0 - reach, q0 + reach)
    else:
        default = (q0 - np.pi, q0 + np.pi)
    for option, value in (("--start", start), ("--stop", stop)):
        if value is not None and not np.isfinite(value):
            raise UserError(f"{option} must be a finite number, got {value}")
        if value is not None and abs(value) > MAGNITUDE_LIMIT:  # said of the option, not of the q it makes
            raise UserError(f"{option} must be at most {MAGNITUDE_LIMIT:g} in magnitude, got {value}")
    lo = default[0] if start is None else start
    hi = default[1] if stop is None else stop
    if not hi > lo:
        raise UserError(f"--stop ({hi}) must be greater than --start ({lo})")
    return lo, hi


def sweep_kinematics(mechanism, q, *, chunk: int = 256, quiet: bool = True):
    """Kinematics (order 1, omega = 1) at every q, in chunks of one compiled shape, with a progress bar."""
    import jax
    import numpy as np

    import assurjax

    parts = []
    with _progress(len(q), "kinematics", quiet) as bar:
        for start in range(0, len(q), chunk):
            piece = q[start : start + chunk]
            padded = np.concatenate([piece, np.full(chunk - len(piece), piece[-1])])
            kin = assurjax.kinematics(mechanism, padded, order=1, check=False)
            parts.append(jax.tree.map(lambda x: np.asarray(x)[: len(piece)], kin))
            bar.update(len(piece))
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


def cmd_kinematics(args) -> int:
    import numpy as np

    from . import viz

    scene = _load(args.scene)
    mech = scene.mechanism
    _check_count("--samples", args.samples, MAX_SAMPLES)
    lo, hi = _sweep_range(scene, args.start, args.stop)
    q = np.linspace(lo, hi, args.samples)
    out = _out_dir(args.out, scene)
    t0 = time.perf_counter()
    frames = viz.frames_from_kinematics(sweep_kinematics(mech, q, quiet=args.quiet))
    elapsed = time.perf_counter() - t0
    if not frames.ok.any():
        _pose_at_q0(scene)  # why, where it does not assemble at q0 either
        raise UserError(f"{scene.name}: the mechanism assembles nowhere in q = [{lo:.6g}, {hi:.6g}]")
    points = list(scene.outputs["points"]) or [p for p in mech.point_names if p not in mech.ground]
    units = _units(_driver_kind(mech))
    files = [_write_csv(out / "kinematics.csv", _kinematics_columns(mech, frames, points))]
    ax = viz.plot_coupler_curves(frames, points, mechanism=mech)  # framed on the mechanism: a path may run off
    files.append(_savefig(ax.figure, out / "coupler_curves.png"))
    ax = viz.plot_angular_velocities(frames, driver_kind=_driver_kind(mech))
    ax.set_ylabel(f"angular velocity per unit driving speed\n(rad/s per {units['omega']})")
    files.append(_savefig(ax.figure, out / "angular_velocities.png"))
    drawing = viz.draw_mechanism(mech, _shown_q(frames, points[:3], scene.state["q0"]), velocities=points[:3], trace=points,
                                 trace_q=q)
    files.append(_savefig(drawing.ax.figure, out / "mechanism.png"))
    print(f"{scene.name}: {args.samples} configurations of q in [{lo:.6g}, {hi:.6g}] {units['q']} in {elapsed:.2f} s")
    if frames.ok.all():
        print("  assembles at every one of them")
    else:  # where it does not, in intervals: one range from the first to the last would hide the gaps
        print("  " + _assembly_text(mech, q).replace("\n", "\n  "))
    for link in mech.links:
        print(f"  dtheta_{link}/dq {_range_text(frames.angular_velocities[link][frames.ok])}")
    _print_files(files)
    return 0


def _kinematics_columns(mech, frames, points) -> dict:
    """kinematics.csv's columns: q, ok, and every value NaN (an empty cell) where the mechanism
    does not assemble (there the numbers mean nothing)."""
    from .viz._frames import masked

    cols = {"q": frames.q, "ok": frames.ok}
    for p in points:
        cols |= {f"x_{p}": frames.points[p][:, 0], f"y_{p}": frames.points[p][:, 1]}
        cols |= {f"dx_{p}/dq": frames.velocities[p][:, 0], f"dy_{p}/dq": frames.velocities[p][:, 1]}
    for link in mech.links:
        cols |= {f"theta_{link}": frames.angles[link], f"dtheta_{link}/dq": frames.angular_velocities[link]}
    return {k: v if k in ("q", "ok") else masked(v, frames.ok) for k, v in cols.items()}


def _shown_q(frames, points, q0: float) -> float:
    """The driving coordinate drawn: the assembled sample nearest q0, one where the velocity
    ratios of ``points`` are defined (not NaN at a singular configuration) if there is one."""
    import numpy as np

    defined = frames.ok & np.all([np.isfinite(frames.velocities[p]).all(axis=1) for p in points], axis=0)
    pick = np.flatnonzero(defined if defined.any() else frames.ok)
    return float(frames.q[pick[np.argmin(np.abs(frames.q[pick] - q0))]])


def _range_text(values) -> str:
    """'in [least, largest]' of a ratio's values, NaN-aware: at a singular configuration a
    ratio is undefined (NaN), and how many are is said."""
    import numpy as np

    undefined = int(np.count_nonzero(np.isnan(values)))
    if undefined == len(values):
        return f"undefined (NaN) at all {undefined} samples where it assembles"
    text = f"in [{np.nanmin(values):.4g}, {np.nanmax(values):.4g}]"
    return text + (f", undefined (NaN) at {undefined} sample{'s' * (undefined > 1)} (singular configurations)" if undefined else "")


# ---------------------------------------------------------------------------- run


def _samples(args, scene) -> int:
    """Output times: --samples, else the scene's [simulation] samples, else RUN_SAMPLES."""
    given = getattr(args, "samples", None)  # validate has no --samples
    n = given if given is not None else int(scene.simulation.get("samples", RUN_SAMPLES))
    _check_count("--samples", n, MAX_SAMPLES)
    return n


def _check_count(option: str, n: int, limit: int) -> None:
    """A requested amount of work: at least 2, at most ``limit`` (stated with the error)."""
    if not 2 <= n <= limit:
        raise UserError(f"{option} must be between 2 and {limit}, got {n}")


def _output_times(scene, samples: int):
    """``samples`` equally spaced times (s) from the scene's t0 to t1, as ``saveat``: the
    peak search's simulations (``saveat`` too) then share one compiled program shape."""
    import numpy as np

    return np.linspace(float(scene.state.get("t0", 0.0)), float(scene.state.get("t1", 1.0)), samples)


def _covered(spans) -> float:
    """The time (s) the union of the intervals ``spans`` covers."""
    total, reach = 0.0, -math.inf
    for start, end in sorted(spans):
        total += max(0.0, end - max(start, reach))
        reach = max(reach, end)
    return total


RERUN_LIMIT = 10.0  # s: a first call that ran longer than this beside its compilation is not run again to time it


def _simulate(scene, samples: int):
    """Simulate twice: the first call includes compilation, the second is the run time
    (None where the first call's own run, beside compiling, took longer than RERUN_LIMIT:
    a long motion is not integrated twice for a timing line)."""
    import jax

    import assurjax

    spans = []  # (start, end) of each trace and compilation: they nest and run side by side

    def listen(event, duration, **kwargs):
        if event.startswith("/jax/core/compile/"):
            end = time.perf_counter()
            spans.append((end - duration, end))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        t0 = time.perf_counter()
        sol = assurjax.simulate(scene, **_run_keywords(scene, samples))
        first = time.perf_counter() - t0
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    if first - _covered(spans) > RERUN_LIMIT:
        return sol, first, None
    t0 = time.perf_counter()
    sol = assurjax.simulate(scene, **_run_keywords(scene, samples))
    return sol, first, time.perf_counter() - t0


def _run_keywords(scene, samples: int) -> dict:
    """simulate()'s keywords for the command's runs: its output grid, and the solver's steps."""
    return dict(saveat=_output_times(scene, samples), save_steps=_with_solver_steps(scene))


def _as_run(scene):
    """The scene as the command runs it. ``[simulation] steps`` (equal steps by lax.scan, saved
    at each, no events) becomes the same equal step as ``dt``: the command saves on its own grid
    and locates peaks on the dense output, which the scan's run has not."""
    import dataclasses

    steps = scene.simulation.get("steps")
    if steps is None:
        return scene
    if "dt" in scene.simulation:
        raise UserError(f"{scene.source or scene.name}: [simulation] steps = {steps} and dt = {scene.simulation['dt']} "
                        "both set the fixed step: give one of them")
    span = float(scene.state.get("t1", 1.0)) - float(scene.state.get("t0", 0.0))
    simulation = {k: v for k, v in scene.simulation.items() if k != "steps"} | {"dt": span / steps}
    return dataclasses.replace(scene, simulation=type(scene.simulation)(simulation))


def _check_runnable(scene, samples: int) -> None:
    """What simulate() would refuse in the command's run of ``scene``, before anything compiles,
    named with the file: a setting of its [simulation] that does not go with the mechanism,
    its loads or the other settings (validate says it; run and reactions stop there)."""
    from ._errors import AssurjaxError
    from ._model import check_has_inertia
    from .dynamics._solve import check_simulate

    check_has_inertia(scene.mechanism)  # said as it is: no setting is at fault
    try:
        check_simulate(scene, **_run_keywords(scene, samples))
    except AssurjaxError as e:
        raise UserError(f"{scene.source or scene.name}: {e}") from None


def _with_solver_steps(scene) -> bool:
    """Outputs at the solver's own steps as well as the grid, where simulate offers them and
    the run's default step budget stays within what it saves (long runs: the grid alone)."""
    from .dynamics._settings import SAVED_STEPS_LIMIT, step_budget
    from .dynamics._solve import saves_solver_steps

    budget = scene.simulation.get("max_steps", step_budget(scene.state.get("t0", 0.0), scene.state.get("t1", 1.0)))
    return saves_solver_steps(scene.loads) and budget <= SAVED_STEPS_LIMIT


class _Along(NamedTuple):
    """Reactions along a simulated motion, as numpy arrays: forces (N) per joint, the
    driving effort, whether every group solved, the friction value and friction power (W)
    per element (empty without friction), the seconds they took, and whether the friction
    had a consistent solution (see Reactions.friction_ok)."""

    forces: dict
    driving: object
    ok: object
    friction: dict
    friction_power: dict
    seconds: float
    friction_ok: object


def _reactions_along(scene, sol, joints) -> _Along:
    import numpy as np

    import assurjax

    t0 = time.perf_counter()
    r = assurjax.reactions(scene, sol, joints=list(joints) if joints else None, check=False)
    arrays = lambda d: {k: np.asarray(v) for k, v in d.items()}  # noqa: E731
    return _Along(arrays(r.forces), np.asarray(r.driving), np.asarray(r.ok).all(axis=-1), arrays(r.friction),
                  arrays(r.friction_power), time.perf_counter() - t0, np.asarray(r.friction_ok))


def _friction_unit(pair: str) -> str:
    """A prismatic pair ("<slider>/<guide link>") carries a friction force, a revolute a couple."""
    return "N" if "/" in pair else "N m"


def _friction_only_dissipates(scene) -> bool:
    """The joint friction is the scene's only dissipative load (its loss is ``sol.dissipated``)."""
    from ._friction import frictions_of

    return sum(load.dissipative for load in scene.loads) == len(frictions_of(scene.loads))


def _friction_total_line(scene, sol) -> list[str]:
    """Without reactions asked for (each element's friction comes with them): the friction's
    total loss where it is the only dissipative load (``sol.dissipated``), and how to get
    each element's; none without friction."""
    from ._friction import frictions_of

    frictions = frictions_of(scene.loads)
    if not frictions:
        return []
    if sol.dissipated is None:
        lost = "its loss is not integrated without [outputs] energies"
    elif _friction_only_dissipates(scene):
        lost = f"{float(sol.dissipated[-1]):.5g} J lost over the motion (integrated)"
    else:
        lost = f"{float(sol.dissipated[-1]):.5g} J lost over the motion with the dampers' (integrated, W_dissipated)"
    return [f"  friction: {lost}; each element's loss and peak: name its joints under [outputs] reactions"]


def _friction_lines(scene, sol, along: _Along, peaks: dict) -> list[str]:
    """The friction's energy loss over the motion per element (trapezoidal rule on the
    samples) and its largest value (``peaks``, located on the dense output), for the
    summary; none without friction. Where the friction is the only dissipative load, its
    total is the integrated one (``sol.dissipated``), and samples too coarse to resolve it
    are said to be."""
    import numpy as np

    from ._peaks import FRICTION

    if not along.friction:
        return []
    lost = {k: -float(np.trapezoid(p, np.asarray(sol.t))) for k, p in along.friction_power.items()}
    total = sum(lost.values())
    shares = ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in sorted(lost.items(), key=lambda kv: -kv[1])) if total > 0 else ""
    integrated = float(sol.dissipated[-1]) if _friction_only_dissipates(scene) and sol.dissipated is not None else None
    if integrated is not None and abs(total - integrated) > 1e-3 * abs(integrated):
        lines = [f"  friction: {integrated:.5g} J lost over the motion (integrated); shares from the friction power at the "
                 f"{len(sol.t)} samples, whose trapezoidal sum is {total:.5g} J (more --samples for finer shares)"
                 + (f": {shares}" if shares else "")]
    else:
        lines = [f"  friction: {total:.5g} J lost over the motion" + (f" ({shares})" if shares else "")]
    located = ", ".join(f"{k} {peaks[FRICTION + k].value:.5g} {_friction_unit(k)} at t = {_seconds(peaks[FRICTION + k].t)} s"
                        for k in _in_scene_order(scene.outputs["reactions"], along.friction))
    lines.append(f"  peak |friction| (located on the dense output): {located}")
    from ._kinetostatics._api import at_jam_state

    jam_state = at_jam_state(sol, np.shape(along.friction_ok))  # the status names the jam
    locked = int(np.count_nonzero(~along.friction_ok & (True if jam_state is None else ~jam_state)))
    if locked:
        lines.append(f"  the joint friction self-locks the mechanism at {locked} of {along.friction_ok.size} samples (no consistent "
                     "friction for a motion that way, nor, held at rest, a friction within its static limits that carries "
                     "the drive): the reactions, driving effort and friction values there are no statics, left out of the "
                     "peaks (the CSV's friction_ok column)")
    return lines


def _no_statics_line(sol) -> str:
    """What the summary says where no sample has statics (:func:`_consistent`)."""
    said = "  reactions, driving effort and friction: none reported: "
    if getattr(sol, "jammed", False):
        return said + ("its only sample is the jam's state" if len(sol.t) == 1 else
                       "no sample before the jam's state has a consistent friction solution") + \
            ", where the motion has no dw/dt; the CSV has the values read there, as no statics"
    return said + ("the joint friction has no consistent solution "
                   + (f"at any of the {len(sol.t)} samples" if len(sol.t) > 1 else "at its only sample")
                   + "; the CSV has their values, marked by its friction_ok column, as no statics")


def _consistent(along: _Along):
    """Samples with statics: a consistent friction solution (all of them without friction),
    not the state where the friction jammed the run (see Reactions.friction_ok)."""
    import numpy as np

    return np.broadcast_to(np.asarray(along.friction_ok, dtype=bool), np.shape(along.driving))


def _peaks(scene, sol, samples: int, joints, along: _Along) -> dict:
    """Peak |F| per joint, peak |driving effort| and peak |friction| per element, located on
    the dense output around the largest of the values ``along`` the samples of ``sol``
    (simulated by :func:`_simulate` with ``samples``: the search reruns its programs)."""
    import numpy as np

    from ._peaks import magnitudes_of, peak_reactions

    # a sample with no consistent friction (a jam's end) has no statics: its values do not count
    keep = _consistent(along)
    masked = lambda d: {k: np.where(keep.reshape(keep.shape + (1,) * (np.ndim(v) - keep.ndim)), v, 0.0)  # noqa: E731
                               for k, v in d.items()}
    grid = magnitudes_of(masked(along.forces), np.where(keep, along.driving, 0.0), masked(along.friction))
    # a jam's final state has no dw/dt of the motion: its reactions do not count; nor do those of
    # a lock-up's approach, which the steps do not resolve (1e-7 s before a slider's lock-up T was
    # 1e-3 of its value, and the peak |F| found there 569 N where the motion's tends to 307 N)
    before = None
    if _ended_at_lockup(sol):
        before = float(sol.t_final) - _lockup_window(sol)
    elif not sol.successful:
        before = float(sol.t_final)
    return peak_reactions(scene, sol, joints=list(joints) if joints else None, grid=grid,
                          before=before, **_run_keywords(scene, samples))


def _force_peaks(peaks: dict) -> list:
    """The peaks of the joints' |F| (not the driving effort's, nor the friction's)."""
    from ._peaks import FRICTION

    return [p for name, p in peaks.items() if name != "driving" and not name.startswith(FRICTION)]


def _print_peaks(peaks: dict, units: dict, scene, sol=None, moves: bool = True, driving=None):
    """The peaks' lines; ``sol``: the run they were found on (a lock-up's says where they were
    searched); ``moves``: whether the mechanism moves at all (else it is held at rest);
    ``driving``: the driving effort at the samples (a constant one is said to be, without
    the time of its peak, which is where round-off put it)."""
    forces = _force_peaks(peaks)
    where = "located on the dense output"
    if sol is not None and _ended_at_lockup(sol):
        where += f", before the last {_lockup_window(sol):.3g} s: the approach to the lock-up is not resolved"
    print(f"  peak |F| ({where}): " + ", ".join(f"{p.name} {p.value:.5g} N at t = {_seconds(p.t)} s" for p in forces))
    drive = peaks["driving"]
    if _driving_is_round_off(peaks, scene, units):
        why = "the loads alone drive this motion" if moves else "it stays at rest"
        size = "exactly 0" if drive.value == 0 else f"largest value {drive.value:.1e} {units['driving']} is round-off"
        print(f"  driving effort: none needed ({why}; {size})")
    elif driving is not None and (value := _constant_driving(driving)) is not None:
        print(f"  driving effort: constant, {value:+.5g} {units['driving']}")
    else:
        print(f"  peak |driving effort|: {drive.value:.5g} {units['driving']} at t = {_seconds(drive.t)} s")


def _constant_driving(driving) -> float | None:
    """The driving effort's value where the samples hold one value to round-off (1e-9 of it),
    else None; NaN samples (no statics there) are gaps."""
    import numpy as np

    values = np.asarray(driving, dtype=float)
    values = values[~np.isnan(values)]
    if not values.size or not np.all(np.isfinite(values)) or np.ptp(values) > 1e-9 * np.max(np.abs(values)):
        return None
    return float(np.median(values))


def _driving_is_round_off(peaks: dict, scene, units: dict) -> bool:
    """Whether the peak driving effort is at the rounding level of the peak reactions."""
    forces = [p.value for p in _force_peaks(peaks)]
    return _round_off(peaks["driving"].value, max(forces, default=0.0), scene, units)


def _round_off(driving: float, force: float, scene, units: dict) -> bool:
    """A driving effort at the rounding level of the reactions (N, or N m over the mechanism's size)."""
    return driving <= 1e-9 * force * (1.0 if units["driving"] == "N" else _size(scene.mechanism))


def _size(mechanism) -> float:
    """The largest extent of the links' points in their own frames (m; 1 if they have none)."""
    import numpy as np

    pts = np.concatenate([np.atleast_2d(np.asarray(p)) for link in mechanism.links.values() for p in link.points.values()])
    return float(np.max(np.ptp(pts, axis=0))) or 1.0


def _in_scene_order(wanted, names) -> list[str]:
    """``names`` in the order the scene lists them (``wanted``), any others after."""
    return [n for n in wanted if n in names] + [n for n in names if n not in wanted]


def _solution_columns(scene, sol, forces, driving, along: _Along | None = None) -> dict:
    import numpy as np

    cols = {"t": sol.t, "q": sol.q, "omega": sol.omega}
    if getattr(sol, "domega", None) is not None:
        cols["domega"] = sol.domega
    for name, field in (("T", "kinetic"), ("V", "potential"), ("E", "total"), ("W", "work"), ("W_dissipated", "dissipated"),
                        ("balance", "balance")):
        if getattr(sol, field, None) is not None:
            cols[name] = getattr(sol, field)
    points, angles = getattr(sol, "points", {}), getattr(sol, "angles", {})
    for p in _in_scene_order(scene.outputs["points"], points):  # a pytree's dicts come back sorted by name
        cols |= {f"x_{p}": np.asarray(points[p])[:, 0], f"y_{p}": np.asarray(points[p])[:, 1]}
    for link in _in_scene_order(scene.outputs["angles"], angles):
        cols[f"theta_{link}"] = angles[link]
    for joint, f in forces.items():
        cols |= {f"Fx_{joint}": f[:, 0], f"Fy_{joint}": f[:, 1], f"F_{joint}": np.hypot(f[:, 0], f[:, 1])}
    if driving is not None:
        cols["driving"] = driving
    for name, u in (along.friction if along else {}).items():
        cols |= {f"friction_{name}": u, f"friction_power_{name}": along.friction_power[name]}
    if along and along.friction:  # False where the friction self-locks (its values are then no limits)
        cols["friction_ok"] = along.friction_ok
    return cols


def _without_legend(*axes) -> None:
    """Remove the legends of single-line panels whose title and axis label already name the
    line: a legend there only hides part of it (strandbeest's 'omega' sat on its curve)."""
    for ax in axes:
        if ax.get_legend() is not None:
            ax.get_legend().remove()


def _history_figure(scene, sol, forces, units, failed: bool = False):
    import textwrap

    import matplotlib.pyplot as plt
    import numpy as np

    from . import viz
    from .viz._plots import place_legend_clear

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), layout="constrained")
    viz.plot_time_histories(sol.t, {"q": sol.q}, ylabel=f"driving coordinate q ({units['q']})", ax=axes[0, 0], title="driving coordinate")
    viz.plot_time_histories(sol.t, {"omega": sol.omega}, ylabel=f"driving velocity ({units['omega']})", ax=axes[0, 1], title="driving velocity")
    _without_legend(axes[0, 0], axes[0, 1])  # one line each, named by its title and axis label
    if getattr(sol, "kinetic", None) is not None:
        lost = getattr(sol, "dissipated", None)
        lost = lost if lost is not None and np.max(np.abs(lost)) > 0 else None  # no flat zero line
        viz.plot_energies(sol.t, sol.kinetic, sol.potential, ax=axes[1, 0], work=sol.work, dissipated=lost)
        if _ended_at_lockup(sol):
            axes[1, 0].axvline(float(sol.t_final), color="0.5", ls="--", lw=1, label="lock-up (T not resolved at it)")
            place_legend_clear(axes[1, 0], len(axes[1, 0].get_lines()))
    else:
        axes[1, 0].text(0.5, 0.5, "energies not requested ([outputs] energies = false)", ha="center", transform=axes[1, 0].transAxes)
        axes[1, 0].axis("off")
    if forces:
        viz.plot_reactions(sol.t, forces, ax=axes[1, 1])
    else:
        axes[1, 1].text(0.5, 0.5, "no reactions requested ([outputs] reactions)", ha="center", transform=axes[1, 1].transAxes)
        axes[1, 1].axis("off")
    _single_sample_marked(fig, len(sol.t))
    # a jam's or a failure's status is a paragraph: wrapped to the figure, not cut at its edges
    warning = " (FAILED: not to be trusted)" if failed else ""
    fig.suptitle("\n".join(textwrap.wrap(f"{scene.name}{warning}: {sol.status}", width=110)), fontsize="medium")
    return fig


def _single_sample_marked(fig, samples: int) -> None:
    """A run of one sample (it stopped at its start) draws each curve as a marker: a line of one
    point is not drawn at all."""
    if samples == 1:
        for ax in fig.axes:
            for line in ax.get_lines():
                line.set_marker("o")


def _one_period(scene):
    """Driving coordinates over one period: one crank turn around q0, or the slider's
    stroke (the interval around q0 where the mechanism assembles)."""
    import numpy as np

    import assurjax

    lo, hi = _sweep_range(scene, None, None)
    q = np.linspace(lo, hi, PATH_SAMPLES)
    if _driver_kind(scene.mechanism) == "slider":
        ok = np.flatnonzero(np.asarray(assurjax.kinematics(scene.mechanism, q, order=0, check=False).ok).reshape(len(q), -1).all(axis=-1))
        if ok.size:
            q = np.linspace(q[ok[0]], q[ok[-1]], PATH_SAMPLES)
    return q


def _reduced_figure(scene):
    import numpy as np

    import assurjax

    from . import viz
    from ._friction import frictions_of

    q = _one_period(scene)
    red = assurjax.reduce(scene, q)
    ok = np.asarray(red.ok).all(axis=-1)
    j = np.where(ok, np.asarray(red.inertia), np.nan)
    tau = np.where(ok, np.asarray(red.force), np.nan)  # the drive (a motor's torque, a drive law) with the loads
    kind = _driver_kind(scene.mechanism)
    axes = viz.plot_reduced(q, j, tau, driver_kind=kind)
    _without_legend(*axes)
    period = "the slider's stroke" if kind == "slider" else "one crank turn"
    loads = scene.loads
    notes = [what for what, present in (("the drive included", bool(np.any(np.asarray(red.effort) != 0))),
                                        ("at omega = 0", any(load.velocity_dependent for load in loads)),
                                        ("at t = 0", any(getattr(load, "reads", lambda _: False)("t") for load in loads)),
                                        ("without joint friction", bool(frictions_of(loads)))) if present]
    axes[0].figure.suptitle(f"{scene.name}: inertia and load reduced to the driver over {period}"
                            + (f"\n({'; '.join(notes)})" if notes else ""))
    return axes[0].figure


def _path_frames(scene, sol, quiet: bool):
    """Kinematics on a fine grid over the driving coordinates the motion visits (one
    period at most: paths repeat), for smooth traced paths."""
    import numpy as np

    from . import viz

    visited = np.asarray(sol.q, dtype=float)
    visited = visited[np.isfinite(visited)]  # a failed run may end on a value that ran away
    lo, hi = float(np.min(visited)), float(np.max(visited))
    if _driver_kind(scene.mechanism) != "slider" and hi - lo >= 2 * np.pi:
        lo, hi = lo, lo + 2 * np.pi
    q = np.linspace(lo, hi, PATH_SAMPLES) if hi > lo else visited
    return viz.frames_from_kinematics(sweep_kinematics(scene.mechanism, q, quiet=quiet))


def _paths_figure(scene, frames, points):
    from . import viz

    ax = viz.plot_coupler_curves(frames, points, mechanism=scene.mechanism)  # framed on the mechanism: a path may run off
    ax.set_title(f"{scene.name}: paths of the output points during the motion")
    return ax.figure


def _animation(scene, sol, out: Path, frames: int, trace_q, quiet: bool, failed: bool = False) -> list[Path]:
    """animation.gif, and animation.mp4 when ffmpeg is on the PATH, from one rendering
    (a failed run's samples only where a drawing takes them: it may have run away before it stopped)."""
    import matplotlib.pyplot as plt
    import numpy as np

    from . import viz
    from ._values import MAGNITUDE_LIMIT

    drawable = (np.abs(sol.q) <= MAGNITUDE_LIMIT) & (np.abs(sol.omega) <= MAGNITUDE_LIMIT)  # False for NaN too
    ts, qs, ws = (np.asarray(v)[drawable] for v in (sol.t, sol.q, sol.omega))
    t = np.linspace(float(ts[0]), float(ts[-1]), frames)
    q, w = np.interp(t, ts, qs), np.interp(t, ts, ws)
    points = list(scene.outputs["points"])
    title = f"{scene.name} (FAILED run, not to be trusted)" if failed else None
    anim = viz.animate(scene.mechanism, q, w, t=t, trace=points, trace_q=trace_q, velocities=points[:3], title=title,
                       check=not failed)  # a failed run may have left the poses that assemble: drawn marked
    with _progress(frames, "animation", quiet) as bar:
        images = viz.render_frames(anim, progress=lambda i, n: bar.update(1))
    plt.close(anim._fig)
    files = [viz.save_gif(images, out / "animation.gif", fps=20)]
    if viz.ffmpeg_available():
        files.append(viz.save_mp4(images, out / "animation.mp4", fps=20))
    return files


def _energy_drift(scene, sol):
    """max |T + V - W - (T + V)(t0)| (J), W the work of every load outside the potential
    energy (drives, motors, forces, couples, dampers, friction), and that over the largest
    energy; None when energies were not computed."""
    import numpy as np

    if getattr(sol, "balance", None) is None:
        return None
    drift = float(np.max(np.abs(sol.balance)))
    scale = max(float(np.max(np.abs(sol.kinetic))), float(np.max(np.abs(sol.total))), float(np.max(np.abs(sol.work)))) or 1.0
    return drift, drift / scale


LOCKUP_APPROACH = 0.01  # the share of a run before its lock-up whose balance and peaks the command reports apart


def _ended_at_lockup(sol) -> bool:
    import numpy as np

    from .dynamics._results import LOCKUP

    return int(np.asarray(sol.event)) == LOCKUP


def _lockup_window(sol) -> float:
    """The last LOCKUP_APPROACH of a run (s), before its lock-up."""
    return LOCKUP_APPROACH * (float(sol.t_final) - float(sol.t[0]))


def _seconds(t) -> str:
    """A time to 6 significant digits (4 decimals read every peak of a millimetre mechanism as 0.0080 s)."""
    return f"{float(t):.6g}"


def _lockup_approach(sol):
    """(max |balance| before the last LOCKUP_APPROACH of the run, that window (s), max
    |balance| inside it) for a run that ended at a lock-up (where T is not resolved, see
    ``Solution.balance``); None otherwise."""
    import numpy as np

    if getattr(sol, "balance", None) is None or not _ended_at_lockup(sol):
        return None
    window = _lockup_window(sol)
    before = np.asarray(sol.t) < float(sol.t_final) - window
    balance = np.abs(np.asarray(sol.balance))
    return float(np.max(balance[before], initial=0.0)), window, float(np.max(balance[~before]))


def _solver_failed(sol) -> bool:
    """Whether the solver did not finish as asked: it neither reached t1 nor stopped at an
    event, nor where the joint friction jams the mechanism (a physical end: ``sol.jammed``)."""
    return not (sol.successful or bool(sol.jammed))


def _failure_lines(scene, sol, units: dict) -> list[str]:
    """What a failed run's files hold, in words: nothing to trust; with constant steps (no
    error estimate) not even the samples before the failure."""
    import numpy as np

    t_end, t1 = float(sol.t_final), float(scene.state.get("t1", 1.0))
    lines = [f"  FAILED: the solver stopped at t = {t_end:.6g} s, short of t1 = {t1:.6g} s: the motion is not to be trusted "
             "(exit status 1)"]
    constant = _constant_steps(scene)
    if constant:
        fastest = float(np.nanmax(np.abs(np.asarray(sol.omega)), initial=0.0))
        given = ", ".join(f"{k} = {v:g}" + (" s" if k == "dt" else "") for k, v in constant.items())
        lines.append(f"    with constant steps ({given}) no step's error is estimated: the samples before t = {t_end:.6g} s "
                     f"may be unresolved too (|omega| up to {fastest:.3g} {units['omega']}); compare with adaptive steps "
                     f"(no {' or '.join(constant)} in [simulation])")
    else:
        lines.append(f"    the samples before t = {t_end:.6g} s kept the solver's tolerances (adaptive steps); nothing after it")
    if _ran_away(sol):
        from ._values import MAGNITUDE_LIMIT

        lines.append(f"    its q, omega or dw/dt ran past {MAGNITUDE_LIMIT:g} (or to NaN) before it stopped: no reactions are "
                     "computed along it")
    return lines


def _constant_steps(scene) -> dict:
    """The scene's dt or steps: constant steps, without an error estimate."""
    return {k: scene.simulation[k] for k in ("dt", "steps") if k in scene.simulation}


def _balance_note(scene) -> str:
    """What a failed run's energy balance measures: nothing with constant steps (the motion
    itself may be unresolved), the motion up to the failure with adaptive ones."""
    return " (of the failed run: no measure of its accuracy)" if _constant_steps(scene) else " (until the solver failed)"


def _ran_away(sol) -> bool:
    """Whether some sample of q, omega or dw/dt is NaN or beyond MAGNITUDE_LIMIT, which the
    reactions refuse (a failed run's may be: it can run away before the solver stops)."""
    import numpy as np

    from ._values import MAGNITUDE_LIMIT

    values = [v for v in (sol.q, sol.omega, getattr(sol, "domega", None)) if v is not None]
    return not all(np.all(np.abs(np.asarray(v)) <= MAGNITUDE_LIMIT) for v in values)


def _say_failed(scene, sol, wrote: bool = True) -> int:
    """The one line on stderr of a run whose solver failed, and its exit status."""
    files = "its files are written for inspection, " if wrote else ""
    print(f"assurjax: error: {scene.name}: the solver failed at t = {float(sol.t_final):.6g} s (see the status above); "
          f"{files}the motion is not to be trusted", file=sys.stderr)
    return RUN_FAILED


def _standstill_line(scene, sol) -> str:
    if scene.simulation.get("stop") != "standstill":
        return "  standstill detection: off (set [simulation] stop = \"standstill\" to stop there)"
    if sol.t_stop is not None and "standstill" in sol.status:
        return f"  standstill time: {sol.t_stop:.6f} s"
    return f"  standstill: none before t1 = {float(sol.t[-1]):.6g} s"


def _moves(sol) -> bool:
    """Whether the mechanism moves at all over the run's samples."""
    import numpy as np

    return bool(np.any(np.asarray(sol.omega) != 0.0))


def _static_pairs(scene) -> list[str]:
    """'pair mu_s / mu' of the friction elements with a static coefficient of their own."""
    from ._friction import frictions_of

    return [f"{f.pair} {float(f.static_coefficient):g} / {float(f.coefficient):g}" for f in frictions_of(scene.loads)
            if f.static_coefficient is not None]


def _smoothed_pairs(scene) -> list[str]:
    """The pairs whose friction elements have the regularized law."""
    from ._friction import frictions_of

    return [f.pair for f in frictions_of(scene.loads) if f.smoothing is not None]


def _rest_line(scene, sol) -> str | None:
    """Where a run that reached t1 without joint friction's exact law is at rest throughout
    (nothing moves it from its start). None where it moves (a frictionless w passes through
    0 at a sample), where the standstill line reports the stop, or where the friction holds
    it (the run's status says since when)."""
    import numpy as np

    from ._friction import has_exact_law

    omega = np.asarray(sol.omega)
    if scene.simulation.get("stop") == "standstill" or not sol.successful or int(sol.event) >= 0 or omega[-1] != 0.0:
        return None
    if has_exact_law(scene.loads) or np.any(omega != 0.0):  # a smooth law holds nothing
        return None
    return "  at rest throughout: nothing moves it from its start"


def cmd_run(args) -> int:
    t0 = time.perf_counter()
    loaded = _load(args.scene)
    scene = _as_run(loaded)
    load_time = time.perf_counter() - t0
    _check_count("--frames", args.frames, MAX_FRAMES)
    samples = _samples(args, scene)
    _check_runnable(scene, samples)
    out = _out_dir(args.out, scene)
    units = _units(_driver_kind(scene.mechanism))
    _pose_at_q0(scene)  # a start that does not assemble: why, before the simulation compiles
    steps = 4 + (not args.no_animation)
    with _progress(steps, f"run {scene.name}", args.quiet) as bar:
        sol, first, second = _simulate(scene, samples)
        if not len(sol.t):  # nothing to write or plot
            raise UserError(f"{scene.name}: {sol.status} (it stopped before its first sample)")
        bar.update(1)
        failed = _solver_failed(sol)
        joints = () if failed and _ran_away(sol) else scene.outputs["reactions"]  # none the analysis takes
        forces, driving, rx_time, peaks, along = {}, None, None, None, None
        if joints:
            along = _reactions_along(scene, sol, joints)
            forces, driving, rx_time = along.forces, along.driving, along.seconds
            peaks = _peaks(scene, sol, samples, joints, along) if _consistent(along).any() else None
        bar.update(1)
        files = [_write_csv(out / "solution.csv", _solution_columns(scene, sol, forces, driving, along))]
        statics = _statics_only(forces, _consistent(along)) if along else forces  # no statics: gaps
        files.append(_savefig(_history_figure(scene, sol, statics, units, failed), out / "histories.png"))
        bar.update(1)
        files.append(_savefig(_reduced_figure(scene), out / "reduced.png"))
        points = list(scene.outputs["points"])
        path_frames = _path_frames(scene, sol, True) if points else None
        if points:
            files.append(_savefig(_paths_figure(scene, path_frames, points), out / "coupler_curves.png"))
        bar.update(1)
        if not args.no_animation:
            files += _animation(scene, sol, out, args.frames, None if path_frames is None else path_frames.q, args.quiet,
                                failed)
            bar.update(1)
    summary = dict(
        scene=scene.name, status=sol.status, solver_failed=failed, jammed=bool(sol.jammed), t_stop=sol.t_stop, samples=int(len(sol.t)), steps=int(getattr(sol, "num_steps", len(sol.t) - 1)),
        t_final=float(sol.t[-1]), q_final=float(sol.q[-1]), timings_s=dict(load=load_time, simulate_first_call=first, simulate_compiled=second, reactions=rx_time),
        units=dict(t="s", **units, energies="J", positions="m", angles="rad", forces="N"),
    )
    if peaks:
        summary["peaks"] = {name: dict(value=p.value, t=p.t) for name, p in peaks.items()}
        if _ended_at_lockup(sol):  # searched before the lock-up's unresolved approach
            summary["peaks_searched_before_s"] = float(sol.t_final) - _lockup_window(sol)
    drift = _energy_drift(scene, sol)
    if drift is not None:
        summary["energy_drift_J"], summary["energy_drift_relative"] = drift
    approach = _lockup_approach(sol)
    if approach is not None:
        summary["energy_drift_before_lockup_J"], summary["lockup_window_s"], _ = approach
    files.append(out / "summary.json")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"{scene.name}: {sol.status}")
    for line in _failure_lines(scene, sol, units) if failed else ():
        print(line)
    print(_standstill_line(scene, sol))
    rest = _rest_line(scene, sol)
    if rest is not None:
        print(rest)
    if drift is not None:
        print(f"  energy balance{_balance_note(scene) if failed else ''}: "
              f"max |T + V - W - E(0)| = {drift[0]:.3e} J ({drift[1]:.2e} of the largest energy; "
              "W: the work of the loads outside V)")
        if approach is not None:
            print(f"    {approach[0]:.3e} J until {approach[1]:.3g} s before the lock-up, {approach[2]:.3e} J after: at a limit "
                  "position J_red grows without bound as w goes to 0, and the driving coordinate no longer resolves T")
    else:
        print("  energy balance: not checked (energies not requested)")
    spacing = (float(scene.state.get("t1", 1.0)) - float(scene.state.get("t0", 0.0))) / (samples - 1)
    grid = f"every {spacing:.3g} s" + (" and at the solver's steps" if _with_solver_steps(scene) else "")
    if len(sol.t) == 1:  # a grid spacing would describe samples that are not there
        grid = f"at t = {_seconds(float(sol.t[0]))} s: the run stopped there"
    print(f"  {len(sol.t)} output sample{'s' * (len(sol.t) != 1)} ({grid}), {summary['steps']} solver steps tried "
          "(rejected ones included)")
    if scene is not loaded:
        print(f"  fixed steps: [simulation] steps = {loaded.simulation['steps']} run as equal steps of dt = "
              f"{scene.simulation['dt']:.6g} s (the command saves on its own grid)")
    if peaks:
        _print_peaks(peaks, units, scene, sol, moves=_moves(sol),
                     driving=along.driving[_consistent(along)] if along else None)
    elif along is not None:
        print(_no_statics_line(sol))
    for line in (_friction_lines(scene, sol, along, peaks) if peaks else []) if along else _friction_total_line(scene, sol):
        print(line)
    if along and along.friction and (smooth := _smoothed_pairs(scene)):
        print(f"  friction law: regularized as asked in {', '.join(smooth)} (sign(rate) -> tanh(rate / v_s), v_s each "
              "element's smoothing speed): no stiction there, where the exact law would hold it the mechanism creeps")
    if static := _static_pairs(scene):
        print(f"  friction at rest: static coefficients in {', '.join(static)} (mu_s against mu): they decide where it "
              "sticks and when it breaks away, the kinetic mu the motion")
    compiled = (f"{second * 1e3:.1f} ms (compiled)" if second is not None
                else f"not run again to time it compiled (the run itself took over {RERUN_LIMIT:g} s)")
    print(f"  timings: load {load_time:.2f} s, simulate {first:.2f} s (first call, with compilation), {compiled}"
          + (f", reactions {rx_time:.2f} s" if rx_time is not None else ""))
    _print_files(files)
    return _say_failed(scene, sol) if failed else 0


# ---------------------------------------------------------------------------- reactions


def cmd_reactions(args) -> int:
    import numpy as np

    import assurjax

    from . import viz

    scene = _load(args.scene)
    units = _units(_driver_kind(scene.mechanism))
    joints = list(scene.outputs["reactions"]) or None
    _pose_at_q0(scene)  # a start that does not assemble: why, before anything compiles
    if args.static:  # printed only: no output directory
        from ._friction import frictions_of

        q0, rough = scene.state["q0"], bool(frictions_of(scene.loads))
        r = assurjax.static_reactions(scene, q0, joints=joints)
        without = " (reactions and drive without its joint friction)" if rough else ""
        print(f"{scene.name}: held at rest at q0 = {q0:.6g} {units['q']}{without}")
        _print_reaction_table({k: np.asarray(v) for k, v in r.forces.items()}, float(r.driving), units, scene)
        band = tuple(float(edge) for edge in assurjax.breakaway_band(scene, q0)) if rough else (float(r.driving),) * 2
        if rough:
            print(_band_line(*band, units))
        print(_own_drive_line(scene, q0, *band, units))
        return 0
    scene = _as_run(scene)
    samples = _samples(args, scene)
    _check_runnable(scene, samples)
    out = _out_dir(args.out, scene)
    # once: this command reports no simulation timings
    sol = assurjax.simulate(scene, **_run_keywords(scene, samples))
    failed = _solver_failed(sol)
    if failed and _ran_away(sol):  # no reactions along it: nothing to write
        print(f"{scene.name}: {sol.status}")
        for line in _failure_lines(scene, sol, units):
            print(line)
        return _say_failed(scene, sol, wrote=False)
    along = _reactions_along(scene, sol, joints)
    forces, driving, elapsed = along.forces, along.driving, along.seconds
    consistent = _consistent(along)
    peaks = _peaks(scene, sol, samples, joints, along) if consistent.any() else None
    columns = _solution_columns(scene, sol, forces, driving, along)
    files = [_write_csv(out / "reactions.csv", {"t": sol.t, "q": sol.q, "omega": sol.omega, "domega": sol.domega, "ok": along.ok}
                        | {k: v for k, v in columns.items() if k.startswith(("F", "driving", "friction"))})]
    import matplotlib.pyplot as plt

    # the samples with no consistent friction are no statics: gaps in the curves
    forces, driving = _statics_only(forces, consistent), np.where(consistent, driving, np.nan)
    panels = 3 if along.friction else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4), layout="constrained")
    viz.plot_reactions(sol.t, forces, ax=axes[0])
    viz.plot_time_histories(sol.t, {"driving effort": driving}, ylabel=f"driving effort ({units['driving']})", ax=axes[1], title="driving effort needed for this motion")
    _without_legend(axes[1])
    if peaks and _driving_is_round_off(peaks, scene, units):  # as the summary says: not magnified into a curve of noise
        axes[1].set_ylim(-1.0, 1.0)
        axes[1].set_title("driving effort needed: none (round-off)")
    elif (value := _constant_driving(driving)) is not None:  # nor a constant's round-off (ticks of 1e-13 about 1.5)
        axes[1].set_ylim(value - 0.5 * abs(value), value + 0.5 * abs(value))
        axes[1].set_title(f"driving effort needed: constant {value:+.5g} {units['driving']}")
    if along.friction:
        power = _statics_only(along.friction_power, consistent)
        viz.plot_time_histories(sol.t, {f"at {k}": -power[k] for k in _in_scene_order(scene.outputs["reactions"], power)},
                                ylabel="power lost (W)", ax=axes[2], title="power lost to friction")
    _single_sample_marked(fig, len(sol.t))
    if not consistent.any():
        for ax in axes:
            ax.text(0.5, 0.5, "none: no sample has statics\n(no consistent friction, or the jam's state)", transform=ax.transAxes,
                    ha="center", va="center")
            if len(sol.t) > 1:  # the run's time span, not matplotlib's default about 0 for curves of NaN only
                ax.set_xlim(float(sol.t[0]), float(sol.t[-1]))
    files.append(_savefig(fig, out / "reactions.png"))
    print(f"{scene.name}: reactions along the motion ({sol.status}), {len(sol.t)} sample{'s' * (len(sol.t) != 1)} in {elapsed:.2f} s")
    for line in _failure_lines(scene, sol, units) if failed else ():
        print(line)
    if not peaks:
        print(_no_statics_line(sol))
        _print_files(files)
        return _say_failed(scene, sol) if failed else 0
    first = int(np.argmax(consistent))  # the first sample with statics
    print(f"  at t = {float(sol.t[first]):.4g} s" + (" (the first sample with a consistent friction)" if first else "") + ":")
    _print_reaction_table({k: v[first] for k, v in forces.items()}, float(driving[first]), units, scene,
                          {k: float(v[first]) for k, v in along.friction.items()})
    _print_peaks(peaks, units, scene, sol, moves=_moves(sol), driving=driving[consistent])
    for line in _friction_lines(scene, sol, along, peaks):
        print(line)
    _print_files(files)
    return _say_failed(scene, sol) if failed else 0


def _statics_only(values: dict, consistent) -> dict:
    """Per name, the values with NaN at the samples that have no statics (see :func:`_consistent`)."""
    from .viz._frames import masked

    return {k: masked(v, consistent) for k, v in values.items()}


def _own_drive_line(scene, q0: float, lower: float, upper: float, units: dict) -> str:
    """Whether the scene's own drive (its loads on the driver, at q0, w = 0 and t0; none: 0)
    holds the mechanism there: the held drive and the band above stand for a drive in its place."""
    from ._loads import driver_effort, drives

    unit = units["driving"]
    if not any(drives(load) for load in scene.loads):
        return f"  it has no drive of its own: 0 {unit} is {_holds_verdict(0.0, lower, upper)}"
    effort = float(driver_effort(scene.mechanism, scene.loads, q0, 0.0, scene.state.get("t0", 0.0))) + 0.0  # not -0
    return f"  its own drive at q0 (w = 0, t = t0) is {effort:+.6g} {unit}, {_holds_verdict(effort, lower, upper)}"


def _holds_verdict(effort: float, lower: float, upper: float) -> str:
    """Whether a drive ``effort`` at rest holds the mechanism, by the band [lower, upper]."""
    if lower <= effort <= upper:
        return "within the band: it stays at rest" if lower < upper else "the drive that holds it: it stays at rest"
    return (f"{'above' if effort > upper else 'below'} {'the band' if lower < upper else 'it'}: it starts "
            f"{'forward' if effort > upper else 'backward'}")


def _band_line(lower: float, upper: float, units: dict) -> str:
    """The break-away band (``assurjax.breakaway_band``) in words; an infinite edge: no drive
    starts the mechanism that way."""
    unit = units["driving"]
    lower, upper = lower + 0.0, upper + 0.0  # -0.0 printed as -0
    if lower == upper:  # no friction at rest (a regularized law, or no Coulomb coefficient)
        return (f"  with its joint friction only {upper:+.6g} {unit} holds it (the friction holds nothing at rest): any "
                "other drive starts it, forward above, backward below")
    if not (math.isfinite(lower) or math.isfinite(upper)):  # "between" would have no bounds
        return ("  with its joint friction no drive starts it either way: the friction self-locks it, any drive holds "
                "it (the break-away band is unbounded both ways)")
    if math.isfinite(lower) and math.isfinite(upper):
        return (f"  with its joint friction it starts forward above {upper:+.6g} {unit} and backward below "
                f"{lower:+.6g} {unit}; any drive between holds it (the break-away band)")
    way, edge, side, locked = (("forward above", upper, "below", "backward") if math.isfinite(upper)
                               else ("backward below", lower, "above", "forward"))
    return (f"  with its joint friction it starts {way} {edge:+.6g} {unit}; any drive {side} that holds it (the "
            f"break-away band); no drive starts it {locked}: the friction self-locks it")


def _print_reaction_table(forces: dict, driving: float, units: dict, scene, friction: dict | None = None):
    import numpy as np

    for k, f in forces.items():  # + 0.0 turns -0.0 into 0.0: no "-0 N" printed
        print(f"    {k:12s} Fx = {f[0] + 0.0:+.6g} N, Fy = {f[1] + 0.0:+.6g} N, |F| = {np.hypot(*f):.6g} N")
    for k, u in (friction or {}).items():
        print(f"    friction at {k}: {u + 0.0:+.6g} {_friction_unit(k)}")
    if driving != 0 and _round_off(abs(driving), max((float(np.hypot(*f)) for f in forces.values()), default=0.0), scene, units):
        print(f"    driving effort = 0 {units['driving']} (none needed: {driving:+.3g} {units['driving']} is round-off of the reactions)")
    else:
        print(f"    driving effort = {driving + 0.0:+.6g} {units['driving']}")


def _print_files(files):
    print("  wrote: " + ", ".join(str(f) for f in files))


# ---------------------------------------------------------------------------- argument parsing


COMMON_FLAGS = ("debug", "quiet", "no_cache")


def parse_args(parser: argparse.ArgumentParser, argv=None) -> argparse.Namespace:
    """The parsed arguments, the common flags False where given neither before nor after the command."""
    args = parser.parse_args(argv)
    for flag in COMMON_FLAGS:
        if not hasattr(args, flag):
            setattr(args, flag, False)
    return args


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")
    common.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress bars")
    common.add_argument("--no-cache", action="store_true", default=argparse.SUPPRESS,
                        help="do not keep compiled programs on disk (default: kept in $ASSURJAX_CACHE_DIR or "
                             "~/.cache/assurjax; ASSURJAX_NO_CACHE=1 also turns it off)")
    # the common options go before or after the command; their defaults are filled in by
    # parse_args below (set_defaults here would reach the subcommands' copies of them, which
    # share these actions, and reset a --debug given before the command)
    parser = argparse.ArgumentParser(prog="assurjax", description="Dynamics of planar one-DOF linkages built from Assur groups.", parents=[common])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    # ---- run
    p = sub.add_parser("run", parents=[common], help="simulate a scene: CSV, plots, animation, summary")
    p.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help=f"scene file or bundled name (default: {DEFAULT_SCENE})")
    p.add_argument("--out", help="output directory (default: assurjax-out/<scene name>)")
    p.add_argument("--samples", type=int, help=f"equally spaced output times, saved with the solver's own steps (default: the scene's [simulation] samples, else {RUN_SAMPLES})")
    p.add_argument("--frames", type=int, default=60, help="frames of the animation (default: 60)")
    p.add_argument("--no-animation", action="store_true", help="skip the animation (GIF, and MP4 when ffmpeg is installed)")
    p.set_defaults(func=cmd_run)

    # ---- validate
    p = sub.add_parser("validate", parents=[common], help="check a scene (exit status 2 if it is bad)")
    p.add_argument("scene", help=SCENE_HELP)
    p.set_defaults(func=cmd_validate)

    # ---- scenes
    p = sub.add_parser("scenes", parents=[common], help="list the bundled scenes")
    p.set_defaults(func=cmd_scenes)

    # ---- kinematics
    p = sub.add_parser("kinematics", parents=[common], help="sweep the driving coordinate: coupler curves, angular velocities")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--out", help="output directory (default: assurjax-out/<scene name>)")
    p.add_argument("--samples", type=int, default=SWEEP_SAMPLES, help=f"configurations in the sweep (default: {SWEEP_SAMPLES})")
    p.add_argument("--start", type=float, help="first driving coordinate (rad or m; default q0 - pi for a crank)")
    p.add_argument("--stop", type=float, help="last driving coordinate (rad or m; default q0 + pi for a crank)")
    p.set_defaults(func=cmd_kinematics)

    # ---- reactions
    p = sub.add_parser("reactions", parents=[common], help="joint reactions and driving effort along the simulated motion")
    p.add_argument("scene", help=SCENE_HELP)
    p.add_argument("--out", help="output directory (default: assurjax-out/<scene name>)")
    p.add_argument("--samples", type=int, help=f"equally spaced output times, saved with the solver's own steps (default: the scene's [simulation] samples, else {RUN_SAMPLES})")
    p.add_argument("--static", action="store_true", help="the mechanism held at rest at q0 instead (printed only)")
    p.set_defaults(func=cmd_reactions)
    return parser


# XLA's CPU runtime can stall a compiled call (every thread waiting, no CPU used) with its
# concurrency-optimized scheduler on; off, the stalls seen did not come back (docs/design-notes.md,
# known issues). The command is a process of its own, so it sets this; the library does not.
STALL_FREE_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"


def _avoid_runtime_stall() -> None:
    """Add :data:`STALL_FREE_FLAG` to ``XLA_FLAGS`` (read when JAX starts its CPU backend,
    which importing assurjax does not), keeping the user's own setting."""
    from ._jit import add_xla_flag

    add_xla_flag(STALL_FREE_FLAG, "xla_cpu_enable_concurrency_optimized_scheduler")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``assurjax`` command; returns the exit status."""
    _avoid_runtime_stall()
    import matplotlib

    matplotlib.use("Agg")  # files only: works without a display
    parser = build_parser()
    try:
        args = parse_args(parser, argv)
    except SystemExit as e:  # argparse already printed its usage message
        return int(e.code or 0)
    try:
        if not (args.no_cache or os.environ.get("ASSURJAX_NO_CACHE")):
            _enable_cache()
        status = args.func(args)
        sys.stdout.flush()  # a reader that left early (| head) shows up here, not at exit
        return status
    except BrokenPipeError:  # the reader closed the pipe (| head): nothing left to say
        _silence_stdout()
        return 0
    except Exception as e:  # one line for the user, the traceback with --debug
        if args.debug:
            raise
        return _report(e)


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again
    on the closed pipe (the recipe of Python's signal module documentation)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _enable_cache() -> None:
    """The persistent compilation cache: later runs load the compiled simulation,
    kinematics and reactions instead of compiling them again."""
    from ._cache import enable_compilation_cache

    try:
        enable_compilation_cache()
    except OSError as e:  # a read-only home: run without the cache
        print(f"assurjax: compilation cache disabled ({e.strerror or e})", file=sys.stderr)


def _report(e: Exception) -> int:
    from ._errors import AssurjaxError

    if isinstance(e, (AssurjaxError, UserError)):
        status = USER_ERROR
    elif isinstance(e, OSError):
        status, e = USER_ERROR, f"{e.strerror or e}: {e.filename}" if e.filename else e
    else:
        status = INTERNAL_ERROR
        e = f"internal error ({type(e).__name__}): {e} (run again with --debug for the traceback)"
    print(f"assurjax: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
