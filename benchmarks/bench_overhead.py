"""The Python work of ``simulate()`` around its compiled program (Watt six-bar).

For a few call shapes users make, measures on this machine:
- (a) the whole call ``assurjax.simulate(scene, ...)``, warm (best of many repeats);
- (b) the compiled program alone, called directly with the arguments ``simulate`` passes
  it (the jitted core, its dispatch included, outputs left on the device);
- overhead = (a) - (b) per call: checks, settings, the host transfer and trimming;
- a cProfile breakdown of the whole call (own time per call of the busiest functions; the
  compiled program's run shows up as the own time of equinox's jit call);
- the first ``simulate(scene)`` in a fresh process without the on-disk compilation cache
  (trace + compile + run; median of 3 processes).

``--before REF`` also measures the package as it is at git revision REF (exported to a
temporary directory), one after the other in separate processes, and reports the ratios.

Saves benchmarks/results/overhead.json. Run: python benchmarks/bench_overhead.py [--quick] [--before main]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
STEPS = 80
# name -> (what, keyword arguments of simulate; q0/omega0 "new" means new Python floats per call)
SHAPES = {
    "table_steps": ("simulate(scene, reduction='table', steps=80, stop=None)",
                    dict(reduction="table", steps=STEPS, stop=None)),
    "prebuilt_table_steps": ("simulate(scene, table=<prebuilt>, steps=80, stop=None)",
                             dict(table="prebuilt", steps=STEPS, stop=None)),
    "scene_defaults": ("simulate(scene): to standstill, 201 samples of points, angles, energies", {}),
    "new_start_each_call": ("simulate(scene, q0=<new float>, omega0=<new float>) at the scene's other settings",
                            dict(q0="new", omega0="new")),
}
FIRST_CALL = "sol = aj.simulate(s)"


def _calls(aj, scene, kwargs, n):
    """n keyword sets for simulate (new floats per call where asked)."""
    import numpy as np

    rng = np.random.default_rng(0)
    starts = rng.uniform(-0.5, 0.5, size=(n, 2))
    out = []
    for q0, w0 in starts:
        kw = dict(kwargs)
        if kw.get("q0") == "new":
            kw["q0"], kw["omega0"] = float(q0), float(w0)
        out.append(kw)
    return out


def _program_args(aj, scene, kw):
    """The jitted core's arguments as simulate passes them (single run, no saveat)."""
    import numpy as np

    from assurjax._model import as_model
    from assurjax.dynamics import _solve
    from assurjax.dynamics._settings import fixed_step_from, settings_from, step_budget

    model = as_model(scene)
    opts = {k: v for k, v in kw.items() if k not in ("q0", "omega0", "table")}
    settings = settings_from(scene, **opts)
    state = scene.state
    q0, omega0 = kw.get("q0", state.get("q0", 0.0)), kw.get("omega0", state.get("omega0", 0.0))
    t0, t1 = state.get("t0", 0.0), state.get("t1", 1.0)
    if "max_steps" not in scene.simulation:
        settings = settings._replace(max_steps=step_budget(t0, t1))
    if hasattr(_solve, "_integrate_jit"):  # simulate's programs never differentiate: diffrax's forward-mode loop
        settings = settings._replace(adjoint="forward")
    settings, table = _solve._resolve_reduction(settings, kw.get("table"), model, None)
    step = fixed_step_from(scene, None)
    return (model, *(np.asarray(v, dtype=float) for v in (q0, omega0, t0, t1)), None, step, settings, table)


_PARTS = {}  # id(model) -> the model split as simulate splits it, once (simulate keeps it per prepared call)


def _programs(solve, args):
    """What simulate runs for one start: the integration, then the end checks and outputs
    (two programs since they are compiled side by side), or the one program of earlier revisions."""
    if hasattr(solve, "_integrate_jit"):
        from assurjax._jit import split_arrays

        model, rest = args[0], args[1:]
        parts = _PARTS.setdefault(id(model), split_arrays(model))
        return solve._finished_jit(*parts, *solve._integrate_jit(*parts, *rest), rest[6])
    return solve._core_jit(*args)


def _profile(fn, calls: int, top: int = 12) -> list[dict]:
    """Own time per call (us) of the busiest functions over ``calls`` calls of fn."""
    profiler = cProfile.Profile()
    profiler.enable()
    for _ in range(calls):
        fn()
    profiler.disable()
    stats = pstats.Stats(profiler).stats
    rows = sorted(stats.items(), key=lambda item: -item[1][2])[:top]
    site = str(Path(os.__file__).parent)
    return [dict(function=f"{_short(path, site)}:{line}({name})", own_us_per_call=1e6 * tt / calls,
                 cumulative_us_per_call=1e6 * ct / calls, calls_per_call=nc / calls)
            for (path, line, name), (nc, _, tt, ct, _) in rows]


def _short(path: str, site: str) -> str:
    for marker in ("site-packages/", "assurjax/"):
        if marker in path:
            return (marker if marker == "assurjax/" else "") + path.split(marker, 1)[1]
    return path.replace(site, "")


def measure(quick: bool) -> dict:
    """Every measurement on the package importable in this process."""
    import jax
    import numpy as np

    import assurjax as aj
    from _timing import best_time
    from assurjax._jit import checks_without_callbacks
    from assurjax.dynamics import _solve
    from bench_dynamics import first_call_time

    repeats, budget = (100, 1.0) if quick else (400, 3.0)
    scene = aj.load_scene("watt_sixbar")
    prebuilt = aj.build_table(scene.mechanism, scene.gravity, scene.loads)
    out = dict(shapes={})
    for name, (what, kwargs) in SHAPES.items():
        kwargs = {k: prebuilt if v == "prebuilt" else v for k, v in kwargs.items()}
        calls = _calls(aj, scene, kwargs, repeats + 2)
        counter = iter(range(10**9))
        whole = lambda: aj.simulate(scene, **calls[next(counter) % len(calls)])  # noqa: E731
        base = _program_args(aj, scene, calls[0])  # per call only the start changes
        args = [(base[0], *(np.asarray(kw.get(k, scene.state.get(k, 0.0)), dtype=float) for k in ("q0", "omega0")),
                 *base[3:]) for kw in calls]
        counter_b = iter(range(10**9))
        program = lambda: _programs(_solve, args[next(counter_b) % len(args)])  # noqa: E731
        with checks_without_callbacks():  # as simulate calls it (the same compiled program)
            t_program = best_time(program, repeats, budget)
        t_whole = best_time(whole, repeats, budget)
        # the same result: the direct call is the program simulate runs
        sol, direct = aj.simulate(scene, **calls[0]), jax.device_get(_programs(_solve, args[0]))
        assert np.array_equal(sol.q, direct.q[: sol.q.shape[0]]), name
        out["shapes"][name] = dict(what=what, whole_us=1e6 * t_whole, program_us=1e6 * t_program,
                                   overhead_us=1e6 * (t_whole - t_program),
                                   profile=_profile(whole, 50 if quick else 200))
    times = [first_call_time(FIRST_CALL) for _ in range(1 if quick else 3)]
    out["first_call"] = dict(what=f"fresh process, no on-disk cache: {FIRST_CALL} (import and scene loading excluded)",
                             runs_s=times, median_s=float(np.median(times)))
    return out


def _export(ref: str, into: str) -> str:
    """The package at git revision ``ref``, extracted under ``into``; returns the directory to put on PYTHONPATH."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", ref, "assurjax"],
                             capture_output=True, check=True).stdout
    path = Path(into) / "archive.tar"
    path.write_bytes(archive)
    with tarfile.open(path) as tar:
        tar.extractall(into, filter="data")
    return into


def code_versions(before: str | None, into: str) -> tuple[dict, str | None]:
    """({"after": the working tree, "before": the package at git revision ``before``,
    extracted under ``into``, if given}, that revision's short hash or None)."""
    code_dirs = {"after": str(ROOT)}
    if not before:
        return code_dirs, None
    code_dirs["before"] = _export(before, into)
    short = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", before], capture_output=True, text=True,
                           check=True).stdout.strip()
    return code_dirs, short


def child_run(child: str, code_dir: str, case) -> dict:
    """The JSON that the Python code ``child`` prints last, run with ``case`` as its argument
    in a fresh process importing the package from ``code_dir``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([code_dir, str(HERE)]))
    done = subprocess.run([sys.executable, "-c", child, str(case)], env=env, capture_output=True, text=True, cwd=str(HERE))
    if done.returncode != 0:
        raise SystemExit(f"{case} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def interleaved_children(child: str, cases, code_dirs: dict, repeats: int) -> dict:
    """str(case) -> version -> runs of :func:`child_run`, the versions interleaved run for run."""
    runs = {str(case): {version: [] for version in code_dirs} for case in cases}
    for case in cases:
        for _ in range(repeats):
            for version, code_dir in code_dirs.items():
                runs[str(case)][version].append(child_run(child, code_dir, case))
                print(case, version, json.dumps(runs[str(case)][version][-1]), flush=True)
    return runs


def versions_main(doc: str, default_out: Path, measure, ratios) -> None:
    """The command line of a benchmark that can also measure an earlier revision:
    ``--before REF``, ``--repeats``, ``--out``. ``measure(code_dirs, repeats)`` -> runs;
    ``ratios(runs)`` -> the before / after ratios, saved with them when REF is given."""
    parser = argparse.ArgumentParser(description=doc)
    parser.add_argument("--before", metavar="REF", help="also measure the package at this git revision")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=str(default_out))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        code_dirs, before = code_versions(args.before, tmp)
        runs = measure(code_dirs, args.repeats)
    result = dict(machine=platform.platform(), cpus=os.cpu_count(), before=before, repeats=args.repeats, scenes=runs)
    if before:
        result["before_over_after"] = ratios(runs)
        print(json.dumps(result["before_over_after"], indent=1))
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)


def _in_process(code_dir: str, quick: bool) -> dict:
    """measure() in a fresh interpreter importing the package from ``code_dir``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([code_dir, str(HERE)]))
    args = [sys.executable, str(Path(__file__).resolve()), "--worker"] + (["--quick"] if quick else [])
    done = subprocess.run(args, env=env, capture_output=True, text=True, cwd=str(HERE))
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-3000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def _revision() -> str:
    """This tree's commit, marked when files differ from it."""
    git = lambda *a: subprocess.run(["git", "-C", str(ROOT), *a], capture_output=True, text=True).stdout.strip()  # noqa: E731
    return git("rev-parse", "--short", "HEAD") + (" with uncommitted changes" if git("status", "--porcelain", "assurjax") else "")


def _print(label: str, result: dict) -> None:
    print(f"== {label}")
    print(f"{'call shape':24} {'whole (us)':>11} {'program (us)':>13} {'overhead (us)':>14}")
    for name, r in result["shapes"].items():
        print(f"{name:24} {r['whole_us']:11.0f} {r['program_us']:13.0f} {r['overhead_us']:14.0f}")
    for name, r in result["shapes"].items():
        print(f"  profile of {name} (own us per call):")
        for row in r["profile"][:6]:
            print(f"    {row['own_us_per_call']:8.1f}  {row['function']}")
    first = result["first_call"]
    print(f"first call: {first['median_s']:.2f} s ({', '.join(f'{t:.2f}' for t in first['runs_s'])}) -- {first['what']}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, one fresh process")
    parser.add_argument("--before", metavar="REF", help="also measure the package at this git revision (e.g. main)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:  # one measurement, printed as JSON for the parent
        print(json.dumps(measure(args.quick)))
        return
    import jax

    results = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                                load_average_at_start=os.getloadavg()))
    if args.before:
        with tempfile.TemporaryDirectory() as tmp:
            results["before"] = dict(ref=args.before, **_in_process(_export(args.before, tmp), args.quick))
        _print(f"before ({args.before})", results["before"])
    results["after"] = dict(ref=_revision(), **_in_process(str(ROOT), args.quick))
    results["machine"]["load_average_at_end"] = os.getloadavg()
    _print(f"this tree ({results['after']['ref']})", results["after"])
    if args.before:
        results["ratios_before_over_after"] = {
            name: {key: results["before"]["shapes"][name][key] / results["after"]["shapes"][name][key]
                   for key in ("whole_us", "overhead_us")} for name in SHAPES}
        results["ratios_before_over_after"]["first_call"] = (results["before"]["first_call"]["median_s"]
                                                             / results["after"]["first_call"]["median_s"])
        print("before / after:", json.dumps(results["ratios_before_over_after"], indent=1))
    path = HERE / "results" / "overhead.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(results, indent=2))
    print(f"saved {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
