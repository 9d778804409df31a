"""The dyads with prismatic pairs in closed form against their 6 x 6 systems.

Every kinetostatic analysis (reactions, inverse dynamics, and each right-hand side of a
simulation with joint friction) solves the groups one by one. The RRR, RRP, PRR, RPR and
PRP dyads have closed forms (``assurjax/_kinetostatics/_dyads.py``); ``method="dense"``
still assembles and LU-solves each group's own 3n x 3n system. Timed as a simulation
calls it: 1000 solves one after another inside one jitted loop (each reads the last one's
driving effort, so that none runs ahead), on kinematics computed beforehand along a swing
of the driver; the best of ``--repeats`` runs, the two methods interleaved.

    python benchmarks/bench_dyads.py [--repeats 30]      # writes results/dyads.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp

import assurjax
from assurjax._kinematics import _kinematics_single
from assurjax._kinetostatics._api import from_kinematics

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = ("slider_crank", "quick_return", "tangent_drive", "press_with_friction")
N = 1000


def serial_solve(scene, method, kins):
    """A jitted loop of N solves at the given kinematics (one per row), each after the last."""

    def row(kin):  # the driving effort, every pair's force and the prismatic pairs' couples
        forces, couples, driving, _ = from_kinematics(scene, kin, 0.0, method=method)
        return jnp.concatenate([driving[None], *forces.values(), *(c[None] for c in couples.values())])

    width = jax.eval_shape(row, jax.tree.map(lambda x: x[0], kins)).shape[0]

    @jax.jit
    def run(kins):
        def body(i, carry):
            out, previous = carry
            kin = jax.tree.map(lambda x: x[i] + 1e-300 * previous if x.dtype == jnp.float64 else x[i], kins)
            values = row(kin)
            return out.at[i].set(values), values[0]

        return jax.lax.fori_loop(0, N, body, (jnp.zeros((N, width)), jnp.zeros(())))[0]

    return run


def bench_scene(name, repeats):
    scene = assurjax.load_scene(name)
    q = float(scene.state["q0"]) + 0.3 * jnp.sin(jnp.linspace(0.0, 6.0, N))
    kins = jax.jit(jax.vmap(lambda q: _kinematics_single(scene.mechanism, q, 1.3, -0.7, None, 2)))(q)
    runs = {method: serial_solve(scene, method, kins) for method in ("modular", "dense")}
    values = {method: jax.block_until_ready(run(kins)) for method, run in runs.items()}
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(repeats):
        for method, run in runs.items():
            start = time.perf_counter()
            jax.block_until_ready(run(kins))
            best[method] = min(best[method], time.perf_counter() - start)
    kinds = sorted({g.kind for g in scene.mechanism.groups})
    return dict(groups=kinds, modular_us=1e6 * best["modular"] / N, dense_us=1e6 * best["dense"] / N,
                max_difference=float(jnp.max(jnp.abs(values["modular"] - values["dense"]))),
                all_assembled=bool(jnp.all(kins.ok)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "dyads.json"))
    args = parser.parse_args()
    out = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, solves_per_run=N, cases={})
    for name in SCENES:
        case = bench_scene(name, args.repeats)
        out["cases"][name] = case
        print(f"{name:20s} {' '.join(case['groups']):24s} closed forms {case['modular_us']:6.2f} us   "
              f"6 x 6 systems {case['dense_us']:6.2f} us   max |difference| {case['max_difference']:.1e}")
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
