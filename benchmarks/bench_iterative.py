"""Speed of the iterative Assur groups (class III triad, class IV): nanoseconds per
configuration, warm, and compile time, float64.

Variants, for the bundled ``triad_mechanism`` and ``class4_seed003`` scenes:

- ``positions`` of n crank angles in one jitted, vmapped call: every angle is continued
  independently from the group's reference (``substeps`` tangent-predicted Newton
  corrections, then the final implicitly differentiated solve); substeps 4, 8 (default), 16;
- ``positions_tracked``: the same n angles as one sweep (``lax.scan``), each solve started
  from the secant prediction of the previous samples' angles (one Newton solve per sample,
  sequential);
- ``kinematics`` (positions, velocities, accelerations: nested jvp through the
  implicit solve), vmapped, on n / 10 angles.

Each variant is compiled once (compile time reported apart), then run ``--repeats``
times; the best time is kept (other processes share the machine).

    python benchmarks/bench_iterative.py [--n 100000] [--repeats 5]

Prints a table and writes benchmarks/results/iterative_groups.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import assurjax

RESULTS = Path(__file__).resolve().parent / "results" / "iterative_groups.json"
SCENES = ("triad_mechanism", "class4_seed003")


def with_substeps(mech, substeps):
    group = dataclasses.replace(mech.groups[1], substeps=substeps)
    return eqx.tree_at(lambda m: m.groups, mech, (mech.groups[0], group, *mech.groups[2:]))


@assurjax.jit
def batch_positions(mech, q):
    return jax.vmap(lambda q: assurjax.positions(mech, q))(q)


def sweep(mech, q):
    return assurjax.positions_tracked(mech, q)  # jitted itself


@assurjax.jit
def batch_kinematics(mech, q):
    return assurjax.kinematics(mech, q, check=False)


def measure(run, mech, q, repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(run(mech, q))  # trace + compile + first run
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(run(mech, q))
        times.append(time.perf_counter() - t0)
    best = min(times)
    return dict(ns_per_config=1e9 * best / q.size, median_ns_per_config=1e9 * float(np.median(times)) / q.size,
                compile_s=first - best, all_ok=bool(np.asarray(out.ok).all()))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    results = []
    for name in SCENES:
        mech = assurjax.load_scene(name).mechanism
        q = jnp.linspace(-np.pi, np.pi, args.n)
        variants = [(f"positions, vmapped, substeps={s}", batch_positions, with_substeps(mech, s), q) for s in (4, 8, 16)]
        variants.append(("positions_tracked (scan sweep)", sweep, mech, q))
        variants.append(("kinematics order 2, vmapped (n/10)", batch_kinematics, mech, q[:: 10]))
        for label, run, m, qq in variants:
            r = dict(scene=name, variant=label, n=int(qq.size), **measure(run, m, qq, args.repeats))
            results.append(r)
            print(f"{name:16s} {label:38s} n={r['n']:7d}  {r['ns_per_config']:10.0f} ns/config  compile {r['compile_s']:5.1f} s  ok={r['all_ok']}")
    meta = dict(jax=jax.__version__, backend=jax.default_backend(), x64=bool(jax.config.jax_enable_x64),
                cpu_count=os.cpu_count(), machine=platform.machine(), python=platform.python_version(), repeats=args.repeats)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(dict(meta=meta, results=results), indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
