"""The first ``simulate(scene, ...)`` with joint friction: what a notebook user waits for
each time the mechanism's structure changes (trace, compile, run; JAX's on-disk cache is
not used), with the warm call and the final state beside it.

Each case in a fresh process, measured as ``bench_regions.py`` measures it (friction in
every pair where the scene has none of its own): the slider-crank, Watt six-bar, press,
quick-return and triad, and the Watt six-bar under a drive ramped in time (0.2 t N m),
whose program holds the stick segments too (a mechanism held at rest may break away).

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_friction_first_calls.py [--before REF] [--repeats 2] [--out FILE]

Writes results/friction_first_calls.json unless told otherwise (``--out``).
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
# (scene, t1, slope of a drive ramped in time or 0)
CASES = (("slider_crank", 2.0, 0.0), ("watt_sixbar", 2.0, 0.0), ("press_with_friction", 2.0, 0.0),
         ("quick_return", 1.0, 0.0), ("triad_mechanism", 0.5, 0.0), ("watt_sixbar", 3.0, 0.2))

CHILD = r"""
import ast, json, sys
import assurjax
from bench_regions import child

name, t1, ramp = ast.literal_eval(sys.argv[1])
extra = (assurjax.Drive(assurjax.Polynomial([0.0, ramp], variable="t")),) if ramp else ()
print(json.dumps(child(name, True, t1, extra)))
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
