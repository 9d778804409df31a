"""Analyses along many samples of a mechanism with many friction elements, in chunks: the
output samples of ``simulate`` and the states of ``reactions`` (``_friction.states_per_call``),
one program for a chunk of at most 64 called once per chunk, against one vmap over every sample.

The bundled strandbeest with friction in its 73 joints (mu 0.2, radius 0.02 m), 0.2 s of
motion saved at 201 and at 2001 samples, each in a fresh process (no compiled program kept
on disk): ``simulate`` (first call, warm) and ``reactions`` at every joint along the saved
motion (first call, warm).

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_chunked_outputs.py [--before REF] [--repeats 2]   # writes results/chunked_outputs.json
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
SAMPLES = (201, 2001)

CHILD = r"""
import json, sys, time
import jax, numpy as np
import assurjax
from _timing import best_time

samples = int(sys.argv[1])
scene = assurjax.load_scene("strandbeest")
names = assurjax.joint_names(scene.mechanism)
rough = scene.with_loads(scene.loads + tuple(assurjax.JointFriction(j, 0.2, 0.02) for j in names))
kwargs = dict(stop=None, t1=0.2, samples=samples)
out = dict(friction_elements=len(names))

def first(f):
    start = time.perf_counter()
    jax.block_until_ready(f())
    return time.perf_counter() - start

out["simulate_first_s"] = first(lambda: assurjax.simulate(rough, **kwargs).domega)
out["simulate_warm_ms"] = 1e3 * best_time(lambda: assurjax.simulate(rough, **kwargs).domega, repeats=3)
sol = assurjax.simulate(rough, **kwargs)
out["steps"] = int(np.asarray(sol.num_steps))
out["reactions_first_s"] = first(lambda: assurjax.reactions(rough, sol).driving)
out["reactions_warm_ms"] = 1e3 * best_time(lambda: assurjax.reactions(rough, sol).driving, repeats=3)
print(json.dumps(out))
"""


def measure(code_dirs: dict, repeats: int) -> dict:
    """"samples" -> version -> runs, the versions interleaved."""
    from bench_overhead import interleaved_children

    return interleaved_children(CHILD, SAMPLES, code_dirs, repeats)


def ratios(runs: dict) -> dict:
    best = lambda n, version, key: min(r[key] for r in runs[n][version])  # noqa: E731
    keys = [k for k in runs[str(SAMPLES[0])]["after"][0] if k.endswith(("_s", "_ms"))]
    return {n: {key: best(n, "before", key) / best(n, "after", key) for key in keys} for n in runs}


def main():
    from bench_overhead import versions_main

    versions_main(__doc__, HERE / "results" / "chunked_outputs.json", measure, ratios)


if __name__ == "__main__":
    main()
