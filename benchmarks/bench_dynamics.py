"""Forward-dynamics benchmark: the Watt six-bar of seed 000 from rest at theta2 = 0 over 2 s.

Measures, on this machine:
- the first-call time (trace + compile + run) of `simulate` in a fresh process, with the
  scene's outputs and lean;
- the warm wall time of the user-facing `simulate(scene)` and of the jitted core (median of
  repeats) with its error against a converged reference (rtol = atol = 1e-13, itself
  cross-checked with the joint-coordinate reference in tests/joint_reference.py), for several
  solvers, tolerances, fixed step counts (lax.scan) and the exact or tabulated reduction;
- the warm time of 10 000 simulations from different starting angles: `simulate` with an
  array q0 (the table is chosen and built automatically, its build included), and the
  vmapped exact core;
- the seed's own scheme (Euler in q, dq = 1e-3 rad) as a baseline.

Saves benchmarks/results/dynamics.json and prints a table. Run: python benchmarks/bench_dynamics.py [--quick]
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import assurjax as aj

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
T1 = 2.0
TS = np.linspace(0.0, T1, 21)


def median_time(fn, repeats):
    fn()  # warm
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return float(np.median(times)), float(np.min(times))


FIRST_CALL = {
    "scene defaults (standstill event, assembly check, 201 samples of points, angles, energies)": "sol = aj.simulate(s)",
    "lean (no stop event, 21 samples, no outputs)": "sol = aj.simulate(s, stop=None, t1=2.0, samples=21, energies=False, points=(), angles=())",
}


def first_call_time(statement: str, cache_dir: str | None = None) -> float:
    """simulate() on the bundled scene in a fresh interpreter (import and scene loading
    excluded); with ``cache_dir``, JAX's persistent compilation cache there."""
    code = (
        "import time, assurjax as aj\n"
        + (f"aj.enable_compilation_cache({cache_dir!r})\n" if cache_dir else "")
        + "s = aj.load_scene('watt_sixbar')\n"
        f"t = time.perf_counter(); {statement}\n"
        "print(time.perf_counter() - t)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def first_call_times(statement: str) -> dict:
    """Cold (median of 3 fresh processes, nothing cached), and with the on-disk cache: the
    process that fills an empty cache, then a new process that loads from it."""
    with tempfile.TemporaryDirectory() as cache:
        filling, loading = first_call_time(statement, cache), first_call_time(statement, cache)
    return dict(cold_s=float(np.median([first_call_time(statement) for _ in range(3)])),
                cache_filling_s=filling, cache_loaded_s=loading)


def core(scene, settings, table=None):
    mech, g = scene.mechanism, scene.gravity
    ts = jnp.asarray(TS)
    if settings.steps is not None:  # saves every step: compare on the same grid
        stride = settings.steps // (len(TS) - 1)
        return aj.jit(lambda q0: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, T1, settings=settings, table=table).q[::stride])
    return aj.jit(lambda q0: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, T1, ts, settings=settings, table=table).q)


def main(quick: bool = False):
    scene = aj.load_scene("watt_sixbar")
    results = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                                load_average=os.getloadavg()), t1=T1, runs=[])
    mech, g = scene.mechanism, scene.gravity

    # converged reference, cross-checked with the joint-coordinate formulation
    ref_settings = aj.SimulationSettings(solver="dopri8", rtol=1e-13, atol=1e-13, check_assembly=False, max_steps=100000, domega=False)
    q_ref = np.asarray(core(scene, ref_settings)(jnp.asarray(0.0)))
    import joint_reference as jref

    joint = jref.watt_sixbar(0.0).simulate(T1, t_eval=TS)
    results["reference_vs_joint_max_abs_q"] = float(np.max(np.abs(q_ref - joint.q)))

    results["first_call_s"] = {label: first_call_times(stmt) for label, stmt in FIRST_CALL.items()}

    # the user-facing call, warm (Python-side checks, dispatch, host transfer and trimming included)
    lean = dict(stop=None, t1=T1, saveat=TS, energies=False, points=(), angles=())
    sol = aj.simulate(scene, **lean)
    med, best = median_time(lambda: aj.simulate(scene, **lean).q, 20 if quick else 100)
    results["simulate_warm"] = dict(what="aj.simulate(scene, stop=None, t1=2, saveat=21 times, no outputs)", warm_median_s=med,
                                    warm_min_s=best, max_abs_error_rad=float(np.max(np.abs(sol.q - q_ref))))
    med, best = median_time(lambda: aj.simulate(scene).q, 20 if quick else 100)
    results["simulate_warm_scene_outputs"] = dict(what="aj.simulate(scene): to standstill, 201 samples with points, angles, energies",
                                                  warm_median_s=med, warm_min_s=best)

    # the jitted core; "events": assembly check and dw/dt too. steps: lax.scan over the solver's step
    table = aj.build_table(mech, g, ())
    configs = [("tsit5", 1e-8, True, None, False), ("tsit5", 1e-8, False, None, False), ("tsit5", 1e-7, True, None, False),
               ("tsit5", 1e-6, True, None, False), ("dopri5", 1e-8, True, None, False), ("dopri8", 1e-8, True, None, False),
               ("dopri8", 1e-10, True, None, False), ("tsit5", 1e-8, True, None, True),
               ("tsit5", None, True, 160, False), ("tsit5", None, True, 80, True), ("tsit5", None, True, 160, True)]
    if quick:
        configs = configs[:2] + configs[-2:-1]
    for solver, tol, lean_outputs, steps, tabulated in configs:
        settings = aj.SimulationSettings(solver=solver, rtol=tol or 1e-8, atol=tol or 1e-8, check_assembly=not lean_outputs,
                                         domega=not lean_outputs, steps=steps, reduction="table" if tabulated else "exact")
        fn = core(scene, settings, table if tabulated else None)
        q0 = jnp.asarray(0.0)
        err = float(np.max(np.abs(np.asarray(fn(q0)) - q_ref)))
        med, best = median_time(lambda: fn(q0), 20 if quick else 100)
        label = f"{solver} " + (f"{steps} steps" if steps else f"{tol:.0e}") + (" table" if tabulated else "") + ("" if lean_outputs else " events")
        results["runs"].append(dict(label=label, solver=solver, tol=tol, steps=steps, table=tabulated, lean=lean_outputs,
                                    max_abs_error_rad=err, warm_median_s=med, warm_min_s=best))
        print(f"  {label}: {1e3 * med:.3f} ms, error {err:.2e}", flush=True)

    # 10 000 simulations from different starting angles
    n = 1000 if quick else 10000
    q0s = np.linspace(-0.5, 0.5, n)
    batch = dict(q0=q0s, **lean)
    t = time.perf_counter()
    sols = aj.simulate(scene, **batch)
    first = time.perf_counter() - t
    med, best = median_time(lambda: aj.simulate(scene, **batch).q, 3)
    check = np.arange(0, n, n // 50)
    ref_batch = aj.jit(eqx.filter_vmap(core(scene, ref_settings)))(jnp.asarray(q0s[check]))
    results["batch_simulate"] = dict(
        what=f"aj.simulate(scene, q0=<{n} angles>): table built automatically (included), tsit5 1e-8", n=n,
        warm_median_s=med, warm_min_s=best, first_call_s=first,
        max_abs_error_rad_50_members=float(np.max(np.abs(np.asarray(sols.q)[check] - np.asarray(ref_batch)))))
    settings = aj.SimulationSettings(samples=2, check_assembly=False, domega=False)
    exact = aj.jit(eqx.filter_vmap(lambda q0: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, T1, settings=settings)))
    jax.block_until_ready(exact(jnp.asarray(q0s)).q)
    med, best = median_time(lambda: exact(jnp.asarray(q0s)).q, 3)
    results["vmapped_exact"] = dict(n=n, what="vmapped simulate_core, exact reduction, tsit5 1e-8", warm_median_s=med, warm_min_s=best)

    # the seed's scheme (Euler in q, dq = 1e-3 rad) until standstill
    base = aj.simulate_seed_euler(mech, g, (), 0.0, 0.0, t1=T1, dq=1e-3, standstill=True, max_steps=10000)
    converged = aj.simulate(scene, stop="standstill", t1=5.0, rtol=1e-13, atol=1e-13, max_steps=100000, check_assembly=False)
    med, best = median_time(lambda: aj.simulate_seed_euler(mech, g, (), 0.0, 0.0, t1=T1, dq=1e-3, standstill=True, max_steps=10000).q, 5)
    results["seed_euler"] = dict(dq=1e-3, t_stop=base.t_stop, t_stop_reference=converged.t_stop,
                                 t_stop_error=None if base.t_stop is None else abs(base.t_stop - converged.t_stop),
                                 q_stop_error=float(abs(base.q[-1] - converged.q[-1])), warm_median_s=med)

    out = HERE / "results" / "dynamics.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"reference vs joint formulation: max |dq| = {results['reference_vs_joint_max_abs_q']:.2e} rad")
    for label, times in results["first_call_s"].items():
        print(f"first call, fresh process, {label}: {times['cold_s']:.2f} s cold, {times['cache_loaded_s']:.2f} s "
              f"from the on-disk cache ({times['cache_filling_s']:.2f} s filling it)")
    for key in ("simulate_warm", "simulate_warm_scene_outputs"):
        print(f"{results[key]['what']}: {1e3 * results[key]['warm_median_s']:.3f} ms warm")
    print(f"{'jitted core':28} {'max err (rad)':>14} {'warm (ms)':>10}")
    for r in results["runs"]:
        print(f"{r['label']:28} {r['max_abs_error_rad']:14.2e} {1e3 * r['warm_median_s']:10.3f}")
    b, v = results["batch_simulate"], results["vmapped_exact"]
    print(f"{b['what']}: {b['warm_median_s']:.3f} s warm ({b['first_call_s']:.2f} s first call), "
          f"max error of 50 members {b['max_abs_error_rad_50_members']:.1e} rad")
    print(f"{v['what']}: {v['warm_median_s']:.3f} s warm")
    s = results["seed_euler"]
    print(f"seed Euler-in-q dq=1e-3: standstill error {s['t_stop_error']}, q error {s['q_stop_error']:.2e}, "
          f"{1e3 * s['warm_median_s']:.1f} ms")
    print(f"saved {out}")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
