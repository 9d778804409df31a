"""Kinetostatics of a mechanism with repeated groups: its groups of one kind at one level solved
as one batch (``assurjax._kinetostatics._batches``) against one at a time.

The bundled strandbeest (8 legs of 3 dyads on one crank: batches of 4 and 8 dyads) and a
4-legged one (``assurjax.strandbeest(2)``), each in a fresh process (the library's calls keep
no compiled program on disk: a first call traces and compiles): ``reactions`` at every joint along 201
samples of a simulated motion (first call, warm), ``static_torque`` at 50 positions (first
call), and ``simulate`` with friction in every joint (mu 0.2, radius 0.02 m: the statics and
its K + 1 tangents at every right-hand side), 0.2 s (first call, warm, steps). The
mechanisms without repeated groups at one level (every other bundled scene) compile the same
programs as before.

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_batched_statics.py [--before REF] [--repeats 2]   # writes results/batched_statics.json
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCENES = ("strandbeest", "strandbeest(2)")

CHILD = r"""
import json, sys, time
import jax, numpy as np
import assurjax
from _timing import best_time

name = sys.argv[1]
scene = assurjax.load_scene(name) if name == "strandbeest" else assurjax.strandbeest(2)
out = {}

def first(f):
    start = time.perf_counter()
    jax.block_until_ready(f())
    return time.perf_counter() - start

sol = assurjax.simulate(scene, t1=0.5, stop=None, samples=201)
out["reactions_first_s"] = first(lambda: assurjax.reactions(scene, sol).driving)
out["reactions_warm_ms"] = 1e3 * best_time(lambda: assurjax.reactions(scene, sol).driving, repeats=5)
out["static_torque_first_s"] = first(lambda: assurjax.static_torque(scene, np.linspace(0.0, 6.0, 50)))
names = assurjax.joint_names(scene.mechanism)
rough = scene.loads + tuple(assurjax.JointFriction(j, 0.2, 0.02) for j in names)
kwargs = dict(loads=rough, stop=None, t1=0.2)
out["friction_simulate_first_s"] = first(lambda: assurjax.simulate(scene, **kwargs).q)
out["friction_simulate_warm_ms"] = 1e3 * best_time(lambda: assurjax.simulate(scene, **kwargs).q, repeats=5)
out["friction_steps"] = int(np.asarray(assurjax.simulate(scene, **kwargs).num_steps))
out["friction_elements"] = len(names)
print(json.dumps(out))
"""


def measure(code_dirs: dict, repeats: int) -> dict:
    """scene -> version -> runs, the versions interleaved."""
    from bench_overhead import interleaved_children

    return interleaved_children(CHILD, SCENES, code_dirs, repeats)


def ratios(runs: dict) -> dict:
    best = lambda scene, version, key: min(r[key] for r in runs[scene][version])  # noqa: E731
    keys = [k for k in runs[SCENES[0]]["after"][0] if k.endswith(("_s", "_ms"))]
    return {scene: {key: best(scene, "before", key) / best(scene, "after", key) for key in keys} for scene in SCENES}


def main():
    from bench_overhead import versions_main

    versions_main(__doc__, HERE / "results" / "batched_statics.json", measure, ratios)


if __name__ == "__main__":
    main()
