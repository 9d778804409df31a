"""The first ``simulate(scene, ...)`` with joint friction: what a notebook user waits for
each time the mechanism's structure changes (trace, compile, run; JAX's on-disk cache is
not used), with the warm call and the final state beside it.

Each case in a fresh process (friction in every pair where the scene has none of its own,
as ``bench_regions.py``): the slider-crank, Watt six-bar, press, quick-return and triad,
and the Watt six-bar under a drive ramped in time (0.2 t N m), whose program holds the
stick segments too (a mechanism held at rest may break away).

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_friction_first_calls.py [--before REF] [--repeats 2]   # writes results/friction_first_calls.json
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
# (scene, t1, slope of a drive ramped in time or 0)
CASES = (("slider_crank", 2.0, 0.0), ("watt_sixbar", 2.0, 0.0), ("press_with_friction", 2.0, 0.0),
         ("quick_return", 1.0, 0.0), ("triad_mechanism", 0.5, 0.0), ("watt_sixbar", 3.0, 0.2))

CHILD = r"""
import ast, json, sys, time
import jax
import assurjax
from bench_friction import best_time, frictions

name, t1, ramp = ast.literal_eval(sys.argv[1])
scene = assurjax.load_scene(name)
own = tuple(load for load in scene.loads if not load.needs_reactions)
loads = scene.loads if any(load.needs_reactions for load in scene.loads) else own + frictions(scene.mechanism)
if ramp:
    loads += (assurjax.Drive(assurjax.Polynomial([0.0, ramp], variable="t")),)
kwargs = dict(loads=loads, stop=None, t1=t1)
start = time.perf_counter()
sol = assurjax.simulate(scene, **kwargs)
jax.block_until_ready(sol.q)
first = time.perf_counter() - start
warm = best_time(lambda: assurjax.simulate(scene, **kwargs).q, repeats=5)
print(json.dumps(dict(first_s=first, warm_ms=1e3 * warm, steps=int(sol.num_steps), status=sol.status,
                      q_end=float(sol.q[-1]), omega_end=float(sol.omega[-1]))))
"""


def measure(code_dirs: dict, repeats: int) -> dict:
    """case -> version -> runs, the versions interleaved."""
    from bench_overhead import interleaved_children

    return interleaved_children(CHILD, CASES, code_dirs, repeats)


def ratios(runs: dict) -> dict:
    """before / after of the first and the warm call, the best of the runs."""
    return {case: {k: min(r[k] for r in versions["before"]) / min(r[k] for r in versions["after"])
                   for k in ("first_s", "warm_ms")}
            for case, versions in runs.items()}


def main():
    from bench_overhead import versions_main

    versions_main(__doc__, HERE / "results" / "friction_first_calls.json", measure, ratios)


if __name__ == "__main__":
    main()
