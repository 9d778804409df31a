"""Derivatives through joint friction: what a jitted derivative costs to its first call and
warm, by reverse mode (``adjoint="recursive"``, ``jax.grad``) and forward mode
(``adjoint="forward"``, ``jax.jacfwd``), with the exact law and the regularized one.

Cases, each in a fresh process (JAX's on-disk cache off), through the calls a user makes
(``jax.jit`` of the derivative of ``synthesis.final_state``'s q(T) in mu):

- the slider-crank from rest at 0.5 rad with friction in every pair (the scene of
  ``bench_friction_smoothing.py``), T = 0.8 s: it swings, stops and swings back (segments);
- the bundled press (motor, process force, friction in its four pairs), every coefficient
  scaled by mu / 0.15, T = 0.5 s.

``--root DIR`` (repeatable): the package checkout(s) to measure, each case in turns over
them (default: this one), so that two versions of the code compare in one run; ``--label``
(as many): what each one is, saved with the results.

    python benchmarks/bench_friction_gradients.py [--root DIR --label TEXT ...] [--quick] [--case S,L,M] [--out FILE]

``--quick``: the slider-crank alone; ``--case`` (repeatable): only these cases, each as
scene,law,mode (e.g. ``slider_crank,exact,reverse``); ``slider_crank,exact,batch-reverse``
and ``batch-forward``: ``jax.vmap`` of the derivative over four coefficients (asked only).

Writes results/friction_gradients.json unless told otherwise.
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
import jax, jax.numpy as jnp
import assurjax as aj

scene_name, law, mode = json.loads(sys.argv[1])

def slider_crank(mu):
    scene = aj.load_scene("slider_crank")
    speed = None if law == "exact" else 0.05
    slide = None if speed is None else 0.1 * speed
    pins = tuple(aj.JointFriction(j, mu, r, viscous=1e-3, smoothing=speed) for j, r in (("O", 0.01), ("A", 0.008), ("B", 0.008)))
    return scene.with_loads(tuple(scene.loads) + pins + (aj.SlideFriction("slider/ground", 0.75 * mu, 0.04, viscous=0.5,
                                                                                          smoothing=slide),))

def press(mu):
    scene = aj.load_scene("press_with_friction")
    def scaled(load):
        if not load.needs_reactions:
            return load
        load = aj.JointFriction(load.pair, mu, load.radius) if load.kind == "R" else aj.SlideFriction(load.pair, mu, load.length)
        return load if law == "exact" else type(load)(load.pair, mu, load.radius if load.kind == "R" else load.length,
                                                      smoothing=0.05 if load.kind == "R" else 0.005)
    return scene.with_loads(tuple(scaled(load) for load in scene.loads))

build, t1, kw, mu0 = {"slider_crank": (slider_crank, 0.8, dict(q0=0.5), 0.2), "press": (press, 0.5, {}, 0.15)}[scene_name]
adjoint = "recursive" if mode.endswith("reverse") else "forward"

def q_at(mu):
    return aj.synthesis.final_state(build(mu), t1, rtol=1e-10, atol=1e-10, adjoint=adjoint, **kw)[0]

derivative = jax.grad(q_at) if adjoint == "recursive" else jax.jacfwd(q_at)
batch = mode.startswith("batch")  # four designs in one vmapped call
derivative = jax.jit(jax.vmap(derivative) if batch else derivative)
mu = mu0 * jnp.array([0.5, 1.0, 1.5, 2.0]) if batch else jnp.asarray(mu0)
t = time.perf_counter(); lowered = derivative.lower(mu); traced = time.perf_counter() - t
compiled = lowered.compile(); compiled_at = time.perf_counter() - t
value = compiled(mu).tolist(); first = time.perf_counter() - t
warm = []
for _ in range(5):
    t = time.perf_counter(); compiled(mu).block_until_ready(); warm.append(time.perf_counter() - t)
print(json.dumps(dict(derivative=value, trace_s=traced, compile_s=compiled_at - traced, first_s=first,
                      warm_ms=1e3 * min(warm))))
"""

CASES = [(scene, law, mode) for scene in ("slider_crank", "press") for law in ("exact", "smoothed")
         for mode in ("reverse", "forward")]
# jax.vmap of the derivative over four coefficients (mu0 x 0.5, 1, 1.5, 2): only when asked (--case)
BATCH_CASES = [("slider_crank", "exact", "batch-reverse"), ("slider_crank", "exact", "batch-forward")]


def child(root: Path, case) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root), JAX_ENABLE_X64="1")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    # run from the checkout: ``python -c`` puts the working directory first on the path
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(case)], capture_output=True, text=True, env=env,
                         cwd=root)
    if out.returncode != 0:  # a code that cannot take the derivative (raised): recorded as such
        return dict(error=out.stderr.strip().splitlines()[-1][:300])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, action="append", help="a package checkout to measure (repeatable)")
    parser.add_argument("--label", action="append", help="what each --root is (as many)")
    parser.add_argument("--quick", action="store_true", help="the slider-crank alone")
    parser.add_argument("--case", action="append", help="scene,law,mode: only these cases (repeatable)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "friction_gradients.json")
    options = parser.parse_args()
    roots = options.root or [ROOT]
    labels = options.label or [f"code {k}" for k in range(len(roots))]
    if len(labels) != len(roots):
        parser.error("give one --label per --root")
    runs = []
    chosen = [tuple(c.split(",")) for c in options.case or []]
    if any(c not in CASES + BATCH_CASES for c in chosen):
        parser.error(f"--case: one of {', '.join(','.join(c) for c in CASES + BATCH_CASES)}")
    for case in [c for c in CASES + BATCH_CASES
                 if (not options.quick or c[0] == "slider_crank") and (c in chosen if chosen else c in CASES)]:
        for k, root in enumerate(roots):
            r = dict(case=dict(zip(("scene", "law", "mode"), case)), code=k, **child(root, case))
            runs.append(r)
            head = f"{case[0]}, {case[1]} law, {case[2]} mode, code {k}:"
            if "error" in r:
                print(f"{head} raised: {r['error']}", flush=True)
                continue
            print(f"{head} d q/d mu {r['derivative']}; first call {r['first_s']:.1f} s (trace {r['trace_s']:.1f}, "
                  f"compile {r['compile_s']:.1f}), warm {r['warm_ms']:.1f} ms", flush=True)
    options.out.write_text(json.dumps(dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count()),
                                           codes=labels, runs=runs), indent=1))


if __name__ == "__main__":
    main()
