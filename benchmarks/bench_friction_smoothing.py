"""The regularized friction law (``smoothing``) against the exact one, on the slider-crank with
friction in every pair, from rest at q0 = 0.5 rad: run time against error, and what a
derivative costs.

Each law in a fresh process (JAX's on-disk cache off), through the calls a user makes:
``simulate(scene, ...)`` to t1 = 0.8 s (first call with its compile, then the best of 5 warm
calls, its steps and q at 17 times), and ``jax.jit(jax.grad(...))`` of
``synthesis.final_state``'s q(0.8 s) in mu (reverse mode; first call, then the best of 3). The exact law goes through its
segments of stick and slip; where every element is smoothed, one smooth solve. The error:
the largest |q - q_exact| over the samples before the first standstill (~0.49 s), where the
exact law's Coulomb signs are fixed, and over all of them.

    python benchmarks/bench_friction_smoothing.py [--out FILE]

Writes results/friction_smoothing.json unless told otherwise.
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
# the pins' smoothing speed (rad/s); the slider's is a tenth of it in m/s; None: the exact law
SPEEDS = (None, 0.5, 0.05, 0.005)

CHILD = r"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
import assurjax as aj

speed = json.loads(sys.argv[1])
scene = aj.load_scene("slider_crank")
times = np.linspace(0.0, 0.8, 17)
kw = dict(q0=0.5, rtol=1e-10, atol=1e-10)

def frictions(mu):
    slide = None if speed is None else 0.1 * speed
    return tuple(aj.JointFriction(j, mu, r, viscous=1e-3, smoothing=speed) for j, r in (("O", 0.01), ("A", 0.008), ("B", 0.008))) + (
        aj.SlideFriction("slider/ground", 0.75 * mu, 0.04, viscous=0.5, smoothing=slide),)

def run():
    return aj.simulate(scene, loads=frictions(0.2), stop=None, t1=0.8, saveat=times, energies=False, points=(), angles=(), **kw)

t = time.perf_counter(); sol = run(); first = time.perf_counter() - t
warm = []
for _ in range(5):
    t = time.perf_counter(); run(); warm.append(time.perf_counter() - t)

def q_at(mu):
    return aj.synthesis.final_state(scene.with_loads(tuple(scene.loads) + frictions(mu)), 0.8, **kw)[0]

grad = jax.jit(jax.grad(q_at))  # jitted once, as the README shows: later calls reuse it
t = time.perf_counter(); g = grad(jnp.asarray(0.2)).block_until_ready(); grad_first = time.perf_counter() - t
grad_warm = []
for _ in range(3):
    t = time.perf_counter(); grad(jnp.asarray(0.2)).block_until_ready(); grad_warm.append(time.perf_counter() - t)
print(json.dumps(dict(status=sol.status, steps=int(sol.num_steps), q=np.asarray(sol.q).tolist(), t=times.tolist(),
                      first_s=first, warm_ms=1e3 * min(warm), grad=float(g), grad_first_s=grad_first,
                      grad_warm_ms=1e3 * min(grad_warm))))
"""


def child(speed) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(speed)], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "results" / "friction_smoothing.json")
    args = parser.parse_args()
    runs = {str(speed): child(speed) for speed in SPEEDS}
    exact = runs["None"]
    q_exact, t = (json.loads(json.dumps(exact[k])) for k in ("q", "t"))
    before = [k for k, tk in enumerate(t) if tk < 0.45]
    for speed, r in runs.items():
        errors = [abs(a - b) for a, b in zip(r["q"], q_exact)]
        r["error_before_standstill_rad"] = max(errors[k] for k in before)
        r["error_rad"] = max(errors)
        r["grad_difference"] = r["grad"] - exact["grad"]
        print(f"smoothing {speed:>6}: {r['status']}, {r['steps']} steps, first {r['first_s']:.2f} s, warm "
              f"{r['warm_ms']:.2f} ms, |q - q_exact| {r['error_before_standstill_rad']:.2e} rad before the standstill, "
              f"{r['error_rad']:.2e} over 0.8 s; d q/d mu {r['grad']:.6g}, first {r['grad_first_s']:.1f} s, warm "
              f"{r['grad_warm_ms']:.1f} ms")
    args.out.write_text(json.dumps(dict(runs=runs, speeds_note="pins rad/s; slider a tenth, m/s"), indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
