"""Forward-dynamics benchmark: the Watt six-bar of seed 000 from rest at theta2 = 0 over 2 s.

Measures, on this machine:
- the first-call time (trace + compile + run) of `simulate` in a fresh process;
- the warm wall time of one simulation (the jitted core, median of repeats) and its error
  against a converged reference (rtol = atol = 1e-13, itself cross-checked with the
  joint-coordinate reference in tests/joint_reference.py), for several solvers and tolerances;
- the warm time of 10 000 vmapped simulations (different starting angles);
- the seed's own scheme (Euler in q, dq = 1e-3 rad) as a baseline.

Saves benchmarks/results/dynamics.json and prints a table. Run: python benchmarks/bench_dynamics.py [--quick]
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
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


def first_call_time() -> float:
    """simulate() on the bundled scene in a fresh interpreter (import excluded)."""
    code = (
        "import time, assurjax as aj, jax.numpy as jnp\n"
        "s = aj.load_scene('watt_sixbar')\n"
        "t = time.perf_counter(); sol = aj.simulate(s, stop=None, t1=2.0, samples=21, energies=False, points=(), angles=())\n"
        "print(time.perf_counter() - t)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def core(scene, settings):
    mech, g = scene.mechanism, scene.gravity
    ts = jnp.asarray(TS)
    fn = eqx.filter_jit(lambda q0: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, T1, ts, settings=settings))
    return fn


def main(quick: bool = False):
    scene = aj.load_scene("watt_sixbar")
    results = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                                load_average=os.getloadavg()), t1=T1, runs=[])

    # converged reference, cross-checked with the joint-coordinate formulation
    ref_settings = aj.SimulationSettings(solver="dopri8", rtol=1e-13, atol=1e-13, check_assembly=False, max_steps=100000, domega=False)
    reference = core(scene, ref_settings)(jnp.asarray(0.0))
    q_ref = np.asarray(reference.q)
    import joint_reference as jref

    joint = jref.watt_sixbar(0.0).simulate(T1, t_eval=TS)
    results["reference_vs_joint_max_abs_q"] = float(np.max(np.abs(q_ref - joint.q)))

    results["first_call_s"] = first_call_time()

    # lean: no events, no dw/dt at the saved times; otherwise assembly check and dw/dt too
    configs = [("dopri8", 1e-8, True), ("dopri8", 1e-8, False), ("dopri8", 1e-6, True), ("dopri8", 1e-10, True),
               ("tsit5", 1e-8, True), ("tsit5", 1e-6, True), ("dopri5", 1e-8, True)]
    if quick:
        configs = configs[:3]
    for solver, tol, lean in configs:
        if True:
            settings = aj.SimulationSettings(solver=solver, rtol=tol, atol=tol, check_assembly=not lean, domega=not lean)
            fn = core(scene, settings)
            q0 = jnp.asarray(0.0)
            sol = fn(q0)
            err = float(np.max(np.abs(np.asarray(sol.q) - q_ref)))
            med, best = median_time(lambda: fn(q0).q, 20 if quick else 100)
            results["runs"].append(dict(solver=solver, tol=tol, lean=lean, steps=int(sol.num_steps), max_abs_error_rad=err,
                                        warm_median_s=med, warm_min_s=best))
            print(f"  {solver} {tol:.0e} {'lean' if lean else 'events'}: {1e3 * med:.3f} ms, error {err:.2e}", flush=True)

    # 10 000 vmapped simulations, different starting angles, default settings, lean outputs
    n = 1000 if quick else 10000
    settings = aj.SimulationSettings(samples=2, check_assembly=False, domega=False)
    mech, g = scene.mechanism, scene.gravity
    batched = eqx.filter_jit(eqx.filter_vmap(lambda q0: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, T1, settings=settings)))
    q0s = jnp.linspace(-0.5, 0.5, n)
    t = time.perf_counter()
    jax.block_until_ready(batched(q0s).q)
    compile_and_run = time.perf_counter() - t
    med, best = median_time(lambda: batched(q0s).q, 3)
    results["vmapped"] = dict(n=n, warm_median_s=med, warm_min_s=best, first_call_s=compile_and_run)

    # the seed's scheme (Euler in q, dq = 1e-3 rad) until standstill
    base = aj.simulate_seed_euler(mech, g, (), 0.0, 0.0, t1=T1, dq=1e-3, standstill=True, max_steps=10000)
    exact = aj.simulate(scene, stop="standstill", t1=5.0, rtol=1e-13, atol=1e-13, max_steps=100000, check_assembly=False)
    med, best = median_time(lambda: aj.simulate_seed_euler(mech, g, (), 0.0, 0.0, t1=T1, dq=1e-3, standstill=True, max_steps=10000).q, 5)
    results["seed_euler"] = dict(dq=1e-3, t_stop=base.t_stop, t_stop_reference=exact.t_stop,
                                 t_stop_error=None if base.t_stop is None else abs(base.t_stop - exact.t_stop),
                                 q_stop_error=float(abs(base.q[-1] - exact.q[-1])), warm_median_s=med)

    out = HERE / "results" / "dynamics.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"reference vs joint formulation: max |dq| = {results['reference_vs_joint_max_abs_q']:.2e} rad")
    print(f"first call (fresh process): {results['first_call_s']:.2f} s")
    print(f"{'solver':8} {'tol':>7} {'outputs':>8} {'steps':>6} {'max err (rad)':>14} {'warm (ms)':>10}")
    for r in results["runs"]:
        print(f"{r['solver']:8} {r['tol']:7.0e} {'lean' if r['lean'] else 'events':>8} {r['steps']:6d} "
              f"{r['max_abs_error_rad']:14.2e} {1e3 * r['warm_median_s']:10.3f}")
    v = results["vmapped"]
    print(f"{v['n']} vmapped: {v['warm_median_s']:.3f} s warm ({v['first_call_s']:.2f} s first call)")
    s = results["seed_euler"]
    print(f"seed Euler-in-q dq=1e-3: standstill error {s['t_stop_error']}, q error {s['q_stop_error']:.2e}, "
          f"{1e3 * s['warm_median_s']:.1f} ms")
    print(f"saved {out}")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
