"""Kinetostatics speed: joint reactions along a trajectory, group by group vs one global solve.

The Watt six-bar of seed 000 falling from rest at theta2 = 0 (assurjax.simulate,
1000 saved samples); the reactions at all its joints and the driving torque along
the whole trajectory in one jitted, vmapped call, float64:

- ``modular``: group by group in reverse formation order, closed forms (crank, RRR dyads);
- ``dense``: group by group, each group's own 3n x 3n system (6 x 6 per dyad, 3 x 3 crank);
- ``global``: every equilibrium equation of the mechanism in one 15 x 15 system.

Each is timed twice: end to end (kinematics with accelerations by jvp, loads, solve)
and the solve alone (kinematics computed beforehand). For the class-IV group of seed
003 (reconstructed geometry) the special-point 4 x 4 method is timed against the
group's 12 x 12 solve the same way. Compile time is reported apart; the best of
``--repeats`` runs is kept (other processes share the machine).

    python benchmarks/bench_kinetostatics.py [--samples 1000] [--repeats 20]

Prints a table and writes benchmarks/results/kinetostatics.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax._kinematics import _kinematics_single
from assurjax._kinetostatics._api import from_kinematics

RESULTS = Path(__file__).resolve().parent / "results" / "kinetostatics.json"
METHODS = ("modular", "dense", "global")


def trajectory(samples: int):
    scene = assurjax.load_scene("watt_sixbar")
    sol = assurjax.simulate(scene, samples=samples, stop=None)
    return scene, sol


def measure(fn, args, repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    best = min(times)
    return dict(compile_s=first - best, best_s=best, median_s=float(np.median(times)))


def end_to_end(scene, method):
    def one(q, w, a, t):
        kin = _kinematics_single(scene.mechanism, q, w, a, None, 2)
        return from_kinematics(scene, kin, t, method=method)

    return assurjax.jit(jax.vmap(one))


def solve_only(scene, method):
    return assurjax.jit(jax.vmap(lambda kin, t: from_kinematics(scene, kin, t, method=method)))


def kinematics_of(scene, q, w, a):
    return assurjax.jit(jax.vmap(lambda q, w, a: _kinematics_single(scene.mechanism, q, w, a, None, 2)))(q, w, a)


def bench_scene(label, scene, state, methods, repeats):
    q, w, a, t = state
    kin = jax.block_until_ready(kinematics_of(scene, q, w, a))
    rows = []
    for method in methods:
        full = measure(end_to_end(scene, method), (q, w, a, t), repeats)
        solve = measure(solve_only(scene, method), (kin, t), repeats)
        rows.append(dict(mechanism=label, method=method, samples=int(q.shape[0]),
                         end_to_end=full, solve_only=solve))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    scene, sol = trajectory(args.samples)
    state = (sol.q, sol.omega, sol.domega, sol.t)
    rows = bench_scene("watt_sixbar", scene, state, METHODS, args.repeats)

    c4 = assurjax.load_scene("class4_seed003")
    n = args.samples
    rng = np.random.default_rng(0)
    q = c4.state["q0"] + jnp.linspace(-0.2, 0.2, n)
    c4_state = (q, jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n)), jnp.zeros(n))
    rows += bench_scene("class4_seed003", c4, c4_state, ("modular", "dense"), args.repeats)

    print(f"{'mechanism':16s} {'method':8s} {'samples':>7s} {'end-to-end ms':>14s} {'solve-only ms':>14s} "
          f"{'us/sample solve':>16s} {'compile s':>10s}")
    for r in rows:
        e, s = r["end_to_end"], r["solve_only"]
        print(f"{r['mechanism']:16s} {r['method']:8s} {r['samples']:7d} {1e3 * e['best_s']:14.3f} {1e3 * s['best_s']:14.3f} "
              f"{1e6 * s['best_s'] / r['samples']:16.3f} {e['compile_s']:10.2f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(machine=platform.machine(), python=platform.python_version(), jax=jax.__version__,
                cpus=os.cpu_count(), load_average=os.getloadavg(), repeats=args.repeats,
                trajectory="watt_sixbar from rest at theta2 = 0, assurjax.simulate (dopri8), stop=None, t in [t0, t1]")
    RESULTS.write_text(json.dumps(dict(meta=meta, results=rows), indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
