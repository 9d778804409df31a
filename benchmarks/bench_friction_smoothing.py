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

Then one step of the bundled press (motor, process force, friction in every pair) with its
friction exact, smoothed (0.05 rad/s on the pins, 0.005 m/s on the ram) and without friction,
measured in turns in one fresh process (``bench_friction.interleaved_marginal_per_step``: the
median of the rounds' ratios, and the ratio of the best times).

And the routes of a derivative (``--only routes``): d q(0.6 s) / d(every array of the scene)
of the slider-crank from rest, with the regularized law in every pair (0.05 rad/s, 0.005 m/s)
and without friction, by ``synthesis.final_state`` with ``adjoint="recursive"`` (reverse mode
through the solve) and ``"sensitivity"`` (forward sensitivities integrated with the state),
each in a fresh process: an unjitted ``jax.grad``'s first call, its second at other values
(a compiled program reused, or traced anew), and the best of 3 warm calls.

    python benchmarks/bench_friction_smoothing.py [--only laws|step|routes] [--out FILE]

Writes results/friction_smoothing.json unless told otherwise (``--only``: that part, the
other kept from the file).
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


STEP_CHILD = r"""
import json
import equinox as eqx, jax.numpy as jnp
import assurjax
from bench_friction import interleaved_marginal_per_step

press = assurjax.load_scene("press_with_friction")
plain = tuple(load for load in press.loads if not load.needs_reactions)
speed = lambda f: jnp.asarray(0.05 if f.kind == "R" else 0.005)
smoothed = plain + tuple(eqx.tree_at(lambda e: e.smoothing, f, speed(f), is_leaf=lambda x: x is None)
                         for f in press.loads if f.needs_reactions)
r = interleaved_marginal_per_step(press, dict(frictionless=plain, exact=press.loads, smoothed=smoothed))
print(json.dumps(r))
"""


ROUTES_CHILD = r"""
import json, sys, time
import equinox as eqx, jax, jax.numpy as jnp
import assurjax as aj

adjoint, smoothed = json.loads(sys.argv[1])
scene = aj.load_scene("slider_crank")
if smoothed:
    scene = scene.with_loads(tuple(scene.loads) + tuple(aj.JointFriction(j, 0.2, 0.02, smoothing=0.05) for j in ("O", "A", "B"))
                             + (aj.SlideFriction("slider/ground", 0.2, 0.04, smoothing=0.005),))
params, static = eqx.partition(scene, eqx.is_inexact_array)

def q_at(p):
    return aj.synthesis.final_state(eqx.combine(p, static), 0.6, q0=0.5, rtol=1e-10, atol=1e-10, adjoint=adjoint)[0]

def timed(p):
    t = time.perf_counter(); g = jax.block_until_ready(jax.grad(q_at)(p)); return time.perf_counter() - t, g

first, g = timed(params)
other = jax.tree.map(lambda v: v * 1.001, params)
second = timed(other)[0]
warm = min(timed(other)[0] for _ in range(3))
flat = jnp.concatenate([jnp.ravel(v) for v in jax.tree.leaves(g)])
print(json.dumps(dict(first_s=first, second_s=second, warm_ms=1e3 * warm, parameters=int(flat.size),
                      gradient=[float(v) for v in flat])))
"""


def child(code: str, argument) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(HERE)]))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code, json.dumps(argument)], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def laws() -> dict:
    """The slider-crank per law (see the module docstring), printed as measured."""
    runs = {str(speed): child(CHILD, speed) for speed in SPEEDS}
    exact = runs["None"]
    before = [k for k, tk in enumerate(exact["t"]) if tk < 0.45]
    for speed, r in runs.items():
        errors = [abs(a - b) for a, b in zip(r["q"], exact["q"])]
        r["error_before_standstill_rad"] = max(errors[k] for k in before)
        r["error_rad"] = max(errors)
        r["grad_difference"] = r["grad"] - exact["grad"]
        print(f"smoothing {speed:>6}: {r['status']}, {r['steps']} steps, first {r['first_s']:.2f} s, warm "
              f"{r['warm_ms']:.2f} ms, |q - q_exact| {r['error_before_standstill_rad']:.2e} rad before the standstill, "
              f"{r['error_rad']:.2e} over 0.8 s; d q/d mu {r['grad']:.6g}, first {r['grad_first_s']:.1f} s, warm "
              f"{r['grad_warm_ms']:.1f} ms")
    return runs


def step() -> dict:
    """The press's step per law against the frictionless one, printed as measured."""
    r = child(STEP_CHILD, None)
    for law in ("exact", "smoothed"):
        print(f"press step, {law}: {r[law]['us_per_step']:.2f} us against {r['frictionless']['us_per_step']:.2f} us "
              f"frictionless: {r[law + '_ratio']['median']:.2f}x (median of the rounds' ratios), "
              f"{r[law + '_ratio']['of_best_times']:.2f}x (best times)")
    return r


def routes() -> dict:
    """The derivative's routes with and without the regularized law, printed as measured."""
    out = {}
    for smoothed in (True, False):
        case = "smoothed" if smoothed else "frictionless"
        runs = {adjoint: child(ROUTES_CHILD, [adjoint, smoothed]) for adjoint in ("recursive", "sensitivity")}
        gap = max(abs(a - b) for a, b in zip(runs["recursive"]["gradient"], runs["sensitivity"]["gradient"]))
        for adjoint, r in runs.items():
            print(f"{case}, adjoint={adjoint!r}: jax.grad over {r['parameters']} arrays' entries, first "
                  f"{r['first_s']:.1f} s, second {r['second_s']:.3f} s, warm {r['warm_ms']:.1f} ms")
        print(f"{case}: the routes' gradients differ by {gap:.2e} at most")
        out[case] = dict(runs, largest_difference=gap)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=("laws", "step", "routes"))
    parser.add_argument("--out", type=Path, default=HERE / "results" / "friction_smoothing.json")
    args = parser.parse_args()
    saved = json.loads(args.out.read_text()) if args.only and args.out.exists() else {}
    if args.only in (None, "laws"):
        saved["runs"] = laws()
        saved["speeds_note"] = "pins rad/s; slider a tenth, m/s"
    if args.only in (None, "step"):
        saved["press_step"] = step()
    if args.only in (None, "routes"):
        saved["routes"] = routes()
    args.out.write_text(json.dumps(saved, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
