"""Position and velocity analysis speed: nanoseconds per configuration, warm, and compile time.

The Roberts linkage (and the Watt six-bar for comparison) over 100 000 crank angles in one
jitted, vmapped call, float64. Each variant is compiled once (compile time reported apart),
then run ``--repeats`` times; the best time is kept (other processes share the machine).

    python benchmarks/bench_kinematics.py [--n 100000] [--repeats 20]

Prints a table and writes benchmarks/results/kinematics.json.
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

RESULTS = Path(__file__).resolve().parent / "results" / "kinematics.json"

# (label, scene, keyword arguments of assurjax.kinematics)
VARIANTS = [
    ("roberts: P, positions", "roberts", dict(points=["P"], order=0, coms=False, angles=False)),
    ("roberts: P, positions + velocities", "roberts", dict(points=["P"], order=1, coms=False, angles=False)),
    ("roberts: all points, positions", "roberts", dict(order=0, coms=False, angles=False)),
    ("roberts: all points, positions + velocities", "roberts", dict(order=1, coms=False, angles=False)),
    ("roberts: everything (points, coms, angles), positions", "roberts", dict(order=0)),
    ("roberts: everything, positions + velocities", "roberts", dict(order=1)),
    ("roberts: everything, + accelerations", "roberts", dict(order=2)),
    ("watt_sixbar: E, positions", "watt_sixbar", dict(points=["E"], order=0, coms=False, angles=False)),
    ("watt_sixbar: everything, positions", "watt_sixbar", dict(order=0)),
    ("watt_sixbar: everything, positions + velocities", "watt_sixbar", dict(order=1)),
]


def make_runner(options):
    @assurjax.jit
    def run(mech, q):
        return assurjax.kinematics(mech, q, 1.0, 0.0, check=False, **options)

    return run


def measure(run, mech, q, repeats):
    """Wall time (best and median of ``repeats``) and process CPU time (best): the CPU
    time is less sensitive to other processes on a shared machine, and exceeds the wall
    time when XLA splits the loop over both cores."""
    t0 = time.perf_counter()
    jax.block_until_ready(run(mech, q))  # trace + compile + first run
    first = time.perf_counter() - t0
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(run(mech, q))
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    best = min(wall)
    return dict(compile_s=first - best, best_s=best, median_s=float(np.median(wall)), cpu_s=min(cpu))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    print(f"{'variant (' + str(args.n) + ' configurations, float64)':56s} {'best ns':>7s} {'median':>8s} {'cpu ns':>7s} {'compile s':>8s}")
    rows = []
    for label, scene, options in VARIANTS:
        mech = assurjax.load_scene(scene).mechanism
        q0 = assurjax.load_scene(scene).state["q0"]
        q = jnp.asarray(q0 + 0.3 * np.sin(np.linspace(0.0, 50.0, args.n)))  # all inside the working range
        stats = measure(make_runner(options), mech, q, args.repeats)
        rows.append(dict(variant=label, scene=scene, options={k: v for k, v in options.items()}, n=args.n,
                         ns_per_config=stats["best_s"] / args.n * 1e9,
                         median_ns_per_config=stats["median_s"] / args.n * 1e9,
                         cpu_ns_per_config=stats["cpu_s"] / args.n * 1e9,
                         compile_s=stats["compile_s"]))
        r = rows[-1]
        print(f"{label:56s} {r['ns_per_config']:7.1f} {r['median_ns_per_config']:8.1f} {r['cpu_ns_per_config']:7.1f} {r['compile_s']:8.2f}", flush=True)

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(jax=jax.__version__, backend=jax.default_backend(), x64=bool(jax.config.jax_enable_x64),
                cpu_count=os.cpu_count(), load_average=os.getloadavg(), machine=platform.machine(), python=platform.python_version(), repeats=args.repeats)
    RESULTS.write_text(json.dumps(dict(meta=meta, results=rows), indent=2))
    print(f"\nwrote {RESULTS}")


if __name__ == "__main__":
    main()
