"""Tabulated reduced model vs exact reduction: the Watt six-bar of seed 000 from rest at theta2 = 0.

Measures, on this machine, for t1 = 1 s and 2 s, modes "exact" and "table", solvers tsit5 and
dopri8 at rtol = atol = 1e-6, 1e-8, 1e-10:
- the warm wall time of one simulation (the jitted core, best of 20),
- its error |q(t1) - q_ref(t1)| against a converged exact run (dopri8, rtol = atol = 1e-13),
- the compile time (first call minus a warm call);
and the table's build time (default grid, warm and first call), the interpolation error of the
table at random off-grid angles for several grid sizes, the warm single-run time with the table
built inside the jitted core (rebuilt per call), and the warm time of 10 000 vmapped
simulations (different starting angles, one table built outside the vmap).

Minimal saving in every run (fair for both modes): samples=2 (t0 and t1), no dw/dt, energies or
points, no assembly check (the table checks a full turn when built).

Saves benchmarks/results/table.json and prints a table. Run: python benchmarks/bench_table.py [--quick]
"""

from __future__ import annotations

import json
import math
import platform
import sys
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import assurjax as aj
from _timing import best_time

HERE = Path(__file__).resolve().parent
QUICK = "--quick" in sys.argv
T1S = (1.0, 2.0)
SOLVERS = ("tsit5", "dopri8")
TOLS = (1e-6, 1e-8, 1e-10)
REPEATS = 5 if QUICK else 20
BATCH = 1000 if QUICK else 10_000




def timed_first(fn):
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def settings(mode, solver, tol, **kw):
    return aj.SimulationSettings(solver=solver, rtol=tol, atol=tol, samples=2, domega=False, check_assembly=False,
                                 max_steps=100_000, reduction=mode, **kw)


def single_core(scene, s, with_table: bool):
    mech, g = scene.mechanism, scene.gravity
    if with_table:
        return aj.jit(lambda q0, t1, table: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, t1, settings=s, table=table))
    return aj.jit(lambda q0, t1, table: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, t1, settings=s))


def interpolation_errors(scene):
    q = np.random.default_rng(0).uniform(0.0, 2 * math.pi, 4096)
    red = aj.reduce(scene, q)
    exact = np.stack([red.inertia, red.dinertia, red.torque + red.effort], axis=-1)
    out = {}
    for n in (512, 1024, 2048, 4096, 8192):
        table = aj.build_table(scene.mechanism, scene.gravity, scene.loads, n)
        approx = np.stack(jax.vmap(table)(jnp.asarray(q)), axis=-1)
        rel = np.max(np.abs(approx - exact), axis=0) / np.max(np.abs(exact), axis=0)
        out[n] = dict(zip(("inertia", "dinertia", "torque"), map(float, rel)))
    return out


def main():
    scene = aj.load_scene("watt_sixbar")
    mech, g = scene.mechanism, scene.gravity
    nodes = aj.SimulationSettings().table_nodes
    q0 = jnp.asarray(0.0)
    results = dict(machine=platform.processor() or platform.machine(), jax=jax.__version__, devices=str(jax.devices()),
                   scene="watt_sixbar", q0=0.0, omega0=0.0, table_nodes=nodes, saving="samples=2, no domega/energies/points, "
                   "check_assembly=False", runs=[], batch=[])

    t = time.perf_counter()
    table = aj.build_table(mech, g, scene.loads, nodes)
    results["table_build_first_s"] = time.perf_counter() - t
    results["table_build_warm_s"] = best_time(lambda: aj.build_table(mech, g, scene.loads, nodes).data, 3)
    results["interpolation_rel_error"] = {} if QUICK else interpolation_errors(scene)

    ref = single_core(scene, settings("exact", "dopri8", 1e-13), False)
    reference = {t1: float(ref(q0, jnp.asarray(t1), None).q[-1]) for t1 in T1S}
    results["reference_q_t1"] = reference

    for mode in ("exact", "table"):
        for solver in SOLVERS:
            for tol in TOLS:
                fn = single_core(scene, settings(mode, solver, tol), mode == "table")
                tab = table if mode == "table" else None
                for t1 in T1S:
                    t1a = jnp.asarray(t1)
                    first = timed_first(lambda: fn(q0, t1a, tab).q) if t1 == T1S[0] else None
                    warm = best_time(lambda: fn(q0, t1a, tab).q, REPEATS)
                    sol = fn(q0, t1a, tab)
                    row = dict(mode=mode, solver=solver, tol=tol, t1=t1, warm_s=warm, steps=int(sol.num_steps),
                               error_rad=abs(float(sol.q[-1]) - reference[t1]),
                               compile_s=None if first is None else first - warm)
                    results["runs"].append(row)
                    print(f"{mode:5s} {solver:6s} tol={tol:.0e} t1={t1:.0f}s  warm {warm * 1e3:8.3f} ms  steps {row['steps']:5d}  "
                          f"err {row['error_rad']:.2e} rad" + ("" if first is None else f"  compile {row['compile_s']:.2f} s"), flush=True)

    # Table built inside the jitted core: rebuilt (and differentiable) at every call.
    inside = single_core(scene, settings("table", "tsit5", 1e-8), False)
    results["table_inside_core"] = dict(solver="tsit5", tol=1e-8, t1=1.0, compile_s=timed_first(lambda: inside(q0, jnp.asarray(1.0), None).q),
                                        warm_s=best_time(lambda: inside(q0, jnp.asarray(1.0), None).q, 3))
    print("table built inside the core:", results["table_inside_core"], flush=True)

    q0s = jnp.linspace(0.0, 2 * math.pi, BATCH, endpoint=False)
    for mode in ("exact", "table"):
        for tol in (1e-6, 1e-8):
            s = settings(mode, "tsit5", tol)
            tab = table if mode == "table" else None
            batch = aj.jit(eqx.filter_vmap(
                lambda q0, table: aj.simulate_core(mech, g, (), q0, 0.0, 0.0, 1.0, settings=s, table=table), in_axes=(0, None)))
            first = timed_first(lambda: batch(q0s, tab).q)
            warm = best_time(lambda: batch(q0s, tab).q, 1 if QUICK else 3)
            row = dict(mode=mode, solver="tsit5", tol=tol, t1=1.0, n=BATCH, warm_s=warm, compile_s=first - warm)
            results["batch"].append(row)
            print(f"batch {mode:5s} tsit5 tol={tol:.0e} n={BATCH}: warm {warm:.3f} s (compile {first - warm:.1f} s)", flush=True)

    out = HERE / "results" / "table.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"table build: first {results['table_build_first_s']:.2f} s, warm {results['table_build_warm_s'] * 1e3:.1f} ms ({nodes} nodes)")
    for n, e in results["interpolation_rel_error"].items():
        print(f"n={n:5d}: rel. interpolation error J {e['inertia']:.1e}  dJ/dq {e['dinertia']:.1e}  tau {e['torque']:.1e}")
    print(f"saved {out}")


if __name__ == "__main__":
    main()
