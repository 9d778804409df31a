"""What a static coefficient of friction (``static_coefficient``, mu_s >= mu) costs a
simulation: the slider-crank rough in every pair (the joint-based reference's table, viscous
terms too), from rest at 0.5 rad (it swings and sticks) and under a drive 0.3 sin 5t N m
(held and broken away twice), 2 s, rtol 1e-10, with mu alone and with mu_s = 1.5 mu.

Each run in a fresh process (JAX's on-disk cache off), through ``simulate(scene, ...)``:
the first call (trace, compile, run), the best of 5 warm calls, the steps and the final q.
A model with mu_s tests each rest with mu_s (one more friction solve at each segment's start
from rest, not at each step), so its warm runs should cost about what those with mu alone do.

    python benchmarks/bench_friction_static.py [--out FILE]

Writes results/friction_static.json unless told otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = r"""
import json, sys, time
import jax.numpy as jnp
import assurjax as aj

driven, ratio = json.loads(sys.argv[1])
scene = aj.load_scene("slider_crank")
table = dict(O=(0.2, 0.01, 1e-3), A=(0.2, 0.008, 1e-3), B=(0.2, 0.008, 1e-3))  # mu, radius, viscous
loads = tuple(aj.JointFriction(j, mu, r, viscous=c, static_coefficient=None if ratio is None else ratio * mu)
              for j, (mu, r, c) in table.items())
loads += (aj.SlideFriction("slider/ground", 0.15, 0.04, viscous=0.5, static_coefficient=None if ratio is None else ratio * 0.15),)
if driven:
    loads += (aj.Drive(lambda q, w, t: 0.3 * jnp.sin(5.0 * t)),)
start = dict(q0=0.5, omega0=3.0 if driven else 0.0)

def run():
    return aj.simulate(scene, loads=tuple(scene.loads) + loads, stop=None, t1=2.0, samples=201, energies=False, points=(),
                       angles=(), rtol=1e-10, atol=1e-10, **start)

t = time.perf_counter(); sol = run(); first = time.perf_counter() - t
warm = []
for _ in range(5):
    t = time.perf_counter(); run(); warm.append(time.perf_counter() - t)
print(json.dumps(dict(status=sol.status, steps=int(sol.num_steps), q_final=float(sol.q[-1]), first_s=first,
                      warm_ms=1e3 * min(warm), samples_at_rest=int((sol.omega == 0).sum()))))
"""


def child(argument) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["ASSURJAX_NO_CACHE"] = "1"
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(argument)], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "results" / "friction_static.json")
    args = parser.parse_args()
    out = {}
    for driven in (False, True):
        case = "driven 0.3 sin 5t" if driven else "from rest"
        for ratio in (None, 1.5):
            r = child([driven, ratio])
            law = "mu alone" if ratio is None else f"mu_s = {ratio} mu"
            out[f"{case}, {law}"] = r
            print(f"{case}, {law}: {r['status']}, {r['steps']} steps, {r['samples_at_rest']} of 201 samples at rest, "
                  f"first {r['first_s']:.2f} s, warm {r['warm_ms']:.2f} ms, q(2 s) {r['q_final']:.6f}")
    args.out.write_text(json.dumps(out, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
