"""The first ``simulate(scene, ...)`` with joint friction: what a notebook user waits for
each time the mechanism's structure changes (trace, compile, run; JAX's on-disk cache is
not used), with the warm call and the final state beside it.

Each case in a fresh process, as ``bench_regions.py`` measures it (friction in every pair
where the scene has none of its own): the slider-crank, Watt six-bar, press, quick-return
and triad.

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_friction_first_calls.py [--before REF] [--repeats 2]   # writes results/friction_first_calls.json
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
CASES = (("slider_crank", 2.0), ("watt_sixbar", 2.0), ("press_with_friction", 2.0), ("quick_return", 1.0),
         ("triad_mechanism", 0.5))

CHILD = r"""
import ast, json, sys
from bench_regions import child

name, t1 = ast.literal_eval(sys.argv[1])
print(json.dumps(child(name, True, t1)))
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
