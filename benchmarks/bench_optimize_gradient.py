"""``synthesis.optimize`` with its gradient by forward mode or by reverse mode (``gradient=``):
the first call (trace and compile included) and a warm call (the same problem again, new
start values), through the call a user makes.

Cases, each in a fresh process (JAX's on-disk cache off):

- ``incline``: a block sliding up a 30 degree incline from 2 m/s, Coulomb friction with
  stiction on its guide; the friction coefficient that makes it stop at t* = 0.25 s
  (``synthesis.standstill_time``, its default adjoint; closed form mu = (v0 / (g t*) - sin a)
  / cos a); one design variable, L-BFGS and Adam;
- ``watt``: the bundled Watt six-bar's counterweight (mass and position on the crank) for a
  standstill at 1.2 s (``synthesis.standstill_time_problem``, its quadrature route), Adam;
- ``slider``: the slider-crank with friction in its four pairs, q(0.5 s) to a target over
  n = 1, 2, 4 of its friction coefficients and, for 8, its pins' radii and block length
  (``synthesis.final_state``), Adam: where the
  forward mode's cost per variable overtakes reverse mode's (``FORWARD_MOST``).

    python benchmarks/bench_optimize_gradient.py [--case NAME ...] [--out FILE]

Writes results/optimize_gradient.json unless told otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = r"""
import json, sys, time
import numpy as np, jax, jax.numpy as jnp, optax
import assurjax as aj
from assurjax import synthesis as syn

case, mode = json.loads(sys.argv[1])
G = 9.81

def incline(mu):
    a = np.deg2rad(30.0)
    fr = {"type": "slide_friction", "pair": "block/ground", "coefficient": mu, "length": 0.05, "static_coefficient": 1.5}
    return aj.scene_from_dict({
        "scene": {"name": "incline", "gravity": [0.0, -G]}, "ground": {"O": [0.0, 0.0]},
        "links": {"block": {"points": {"P": [0.0, 0.0]}, "com": [0.0, 0.0], "mass": 2.0, "inertia": 0.01}},
        "formation": [{"group": "slider", "name": "drv", "link": "block", "point": "P", "guide_point": "O",
                       "direction": [float(np.cos(a)), float(np.sin(a))]}],
        "loads": [fr], "state": {"q0": 0.0, "omega0": 2.0, "t1": 1.0}})

def problem():
    name, method = case.split(",")[:2]
    if name == "incline":
        target = 0.25
        design = syn.Design(incline(0.1), lambda s: s.loads[0].coefficient, lower=0.0, upper=1.0)
        def objective(s):
            return (syn.standstill_time(s)[0] - target) ** 2 * 1e3
        exact = (2.0 / (G * target) - np.sin(np.deg2rad(30))) / np.cos(np.deg2rad(30))
        return design, objective, method, False, float(exact)
    if name == "watt":
        design, objective, _ = syn.standstill_time_problem(aj.load_scene("watt_sixbar"), 1.2, rtol=1e-10, atol=1e-10)
        return design, objective, method, True, None
    n = int(case.split(",")[2])
    base = aj.load_scene("slider_crank")
    pins = tuple(aj.JointFriction(j, 0.1, r) for j, r in (("O", 0.01), ("A", 0.008), ("B", 0.008)))
    scene = base.with_loads(tuple(base.loads) + pins + (aj.SlideFriction("slider/ground", 0.1, 0.04),))
    friction = [k for k, load in enumerate(scene.loads) if load.needs_reactions]
    # n values: the four pairs' mu, then their friction circles' radii and the block's length
    picks = [(k, "coefficient") for k in friction] + [(k, "radius" if hasattr(scene.loads[k], "radius") else "length")
                                                      for k in friction]
    picks = picks[:n]
    design = syn.Design(scene, lambda s: tuple(getattr(s.loads[k], f) for k, f in picks), lower=0.0, upper=1.0)
    def objective(s):
        return (syn.final_state(s, 0.5, q0=0.5, omega0=0.0)[0] - 1.0) ** 2
    return design, objective, method, False, None

design, objective, method, has_aux, exact = problem()
optimizer, options, steps = (optax.lbfgs, None, 40) if method == "lbfgs" else (optax.adam, {"learning_rate": 0.05}, 20)
kw = dict(options=options, has_aux=has_aux, gradient=mode)
if case.startswith("incline"):
    kw["target"] = 1e-14
t = time.perf_counter()
first = syn.optimize(design, objective, optimizer, steps, **kw)
first_s = time.perf_counter() - t
t = time.perf_counter()
warm = syn.optimize(design, objective, optimizer, steps, **kw)
warm_s = time.perf_counter() - t
values = [float(v) for v in jax.tree.leaves(first.values)]
print(json.dumps(dict(first_s=first_s, warm_s=warm_s, evaluations=int(warm.evaluations), warm_ms_per_evaluation=1e3 * warm_s / max(int(warm.evaluations), 1),
                      loss=float(first.loss), status=first.status, values=values, exact=exact,
                      last_grad=[float(g) for g in np.ravel(np.asarray(jax.tree.leaves(first.history.grad)[0])[-1:])])))
"""

CASES = ["incline,lbfgs", "incline,adam", "watt,adam", "slider,adam,1", "slider,adam,2", "slider,adam,4", "slider,adam,8"]


def run(case: str, mode: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), ASSURJAX_NO_CACHE="1", JAX_ENABLE_COMPILATION_CACHE="false")
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps([case, mode])], env=env, capture_output=True, text=True)
    if done.returncode:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", action="append", choices=CASES, help="only these cases (repeatable)")
    parser.add_argument("--out", default=str(HERE / "results" / "optimize_gradient.json"))
    args = parser.parse_args()
    results = []
    for case in args.case or CASES:
        for mode in ("forward", "reverse"):
            row = dict(case=case, mode=mode, **run(case, mode))
            results.append(row)
            print(json.dumps(row), flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(dict(machine=platform.processor() or platform.machine(), cpus=os.cpu_count(),
                                              results=results), indent=1) + "\n")


if __name__ == "__main__":
    main()
