"""Regions on and off (``ASSURJAX_REGIONS``): a right-hand side compiled into one kernel
(``assurjax/_jit.py``, "regions") against XLA's kernel-by-kernel program, through the call a
user makes, ``simulate(scene, ...)``.

For each case, fresh processes (regions on, off, on, off: interleaved, so that a slower
stretch of the shared machine touches both), each measuring the first call (trace, compile,
run; JAX's on-disk cache is not used), the best of five warm calls, and one more step of the
press (``bench_friction.marginal_per_step``). Reported: medians over the two processes of each
setting, their ratio, and the final states, whose difference is round-off carried by the
adaptive steps (a region's kernel orders some sums differently).

    python benchmarks/bench_regions.py      # writes results/regions.json (~10 min)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
# (scene, with friction in every pair (bench_friction.frictions) or the scene's own, t1)
CASES = (("slider_crank", True, 2.0), ("watt_sixbar", True, 2.0), ("press_with_friction", True, 2.0),
         ("quick_return", True, 1.0), ("triad_mechanism", True, 0.5), ("strandbeest", True, 0.2),
         ("slider_crank", False, 2.0), ("watt_sixbar", False, 2.0), ("press_with_friction", False, 2.0),
         ("triad_mechanism", False, 0.5), ("class4_seed003", False, 0.5), ("strandbeest", False, 0.5))


def child(name: str, friction: bool, t1: float, extra_loads=()) -> dict:
    import time

    import jax
    import numpy as np

    import assurjax
    from bench_friction import best_time, frictions, marginal_per_step

    scene = assurjax.load_scene(name)
    own = tuple(load for load in scene.loads if not load.needs_reactions)
    if not friction:
        loads = own
    elif any(load.needs_reactions for load in scene.loads):
        loads = scene.loads
    else:
        loads = own + frictions(scene.mechanism)
    kwargs = dict(loads=loads + tuple(extra_loads), stop=None, t1=t1)
    start = time.perf_counter()
    sol = assurjax.simulate(scene, **kwargs)
    jax.block_until_ready(sol.q)
    first = time.perf_counter() - start
    warm = best_time(lambda: assurjax.simulate(scene, **kwargs).q, repeats=5)
    out = dict(first_s=first, warm_ms=1e3 * warm, steps=int(np.asarray(sol.num_steps)), q_end=float(sol.q[-1]),
               omega_end=float(sol.omega[-1]))
    if name == "press_with_friction":
        out["us_per_step"] = marginal_per_step(scene, loads)["us_per_step"]
    return out


def run_child(name: str, friction: bool, t1: float, regions: bool) -> dict:
    env = dict(os.environ, ASSURJAX_REGIONS="1" if regions else "0", JAX_ENABLE_COMPILATION_CACHE="false")
    command = [sys.executable, __file__, "--child", json.dumps([name, friction, t1])]
    run = subprocess.run(command, env=env, capture_output=True, text=True, cwd=HERE)
    if run.returncode != 0:
        raise SystemExit(f"{name} (regions {regions}) failed:\n{run.stderr[-3000:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "regions.json"))
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        sys.path.insert(0, HERE)
        print(json.dumps(child(*json.loads(args.child))))
        return
    cases = []
    for name, friction, t1 in CASES:
        runs = {True: [], False: []}
        for regions in (True, False, True, False):
            runs[regions].append(run_child(name, friction, t1, regions))
        case = dict(scene=name, friction=friction, t1=t1)
        for key in runs[True][0]:
            if key in ("q_end", "omega_end", "steps"):
                case[key] = {"on": runs[True][0][key], "off": runs[False][0][key]}
                continue
            on, off = (statistics.median(r[key] for r in runs[regions]) for regions in (True, False))
            case[key] = {"on": on, "off": off, "on_over_off": on / off}
        print(json.dumps(case))
        cases.append(case)
    out = dict(machine=platform.platform(), cpus=os.cpu_count(), cases=cases)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
