"""Cost of gradients through the simulation (diffrax), per adjoint.

The Watt six-bar of seed 000 falls from rest; f = theta(T) at T = 0.5 s (tsit5,
rtol = atol = 1e-8, no stop events). We time one forward simulation, then the gradient
of f with respect to every parameter of the scene (all point coordinates, centres of mass,
masses, inertias and gravity: 50 numbers) with

- reverse mode, diffrax.RecursiveCheckpointAdjoint (default checkpointing),
- reverse mode, RecursiveCheckpointAdjoint storing every step (checkpoints = max_steps),
- forward mode, diffrax.ForwardMode with jax.jacfwd (one tangent per parameter),
- forward mode, one directional derivative (jax.jvp),
- reverse mode, diffrax.BacksolveAdjoint (adjoint ODE backwards in time),

and the gradient of the standstill time (event) with the default adjoint. Compile times are
reported apart; run times are medians over repeats. The cost is reported as a multiple of one
forward simulation (the target is below 5x for the full gradient).

Usage: python benchmarks/bench_gradients.py [--repeats 20]
Results: benchmarks/results/gradients.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import diffrax
import jax
import numpy as np

import assurjax
from assurjax import _dynamics
from assurjax import synthesis as syn

RESULTS = Path(__file__).parent / "results"
T = 0.5
OPTS = dict(solver="tsit5", rtol=1e-8, atol=1e-8, max_steps=1024)


def timed(fn, x, repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(x))
    compile_s = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(x))
        runs.append(time.perf_counter() - t0)
    return compile_s, float(np.median(runs))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--max-steps", type=int, default=1024, help="diffrax max_steps (sizes the reverse-mode buffers)")
    ap.add_argument("--reverse-only", action="store_true", help="only the forward simulation and the reverse-mode gradients")
    ap.add_argument("--output", default="gradients.json")
    args = ap.parse_args()
    OPTS["max_steps"] = args.max_steps
    # every step stored: no recomputation in the backward pass (memory ~ steps x state)
    _dynamics.ADJOINTS["recursive_all_steps"] = lambda: diffrax.RecursiveCheckpointAdjoint(checkpoints=OPTS["max_steps"])

    scene = assurjax.load_scene("watt_sixbar")
    select = lambda s: (s.mechanism, s.gravity)  # noqa: E731
    theta, unflatten = syn.flatten_parameters(scene, select=select)
    direction = jax.random.normal(jax.random.key(0), theta.shape)

    def theta_T(th, adjoint="recursive"):
        return syn.final_state(unflatten(th), T, adjoint=adjoint, **OPTS)[0]

    rows = []
    c, fwd = timed(jax.jit(theta_T), theta, args.repeats)
    rows.append(dict(what="forward simulation theta(T)", adjoint="-", compile_s=c, run_s=fwd))
    cases = [
        ("gradient, reverse", "recursive", lambda f: jax.grad(f)),
        ("gradient, reverse", "recursive_all_steps", lambda f: jax.grad(f)),
        ("gradient, forward (jacfwd)", "forward", lambda f: jax.jacfwd(f)),
        ("directional derivative (jvp)", "forward", lambda f: (lambda th: jax.jvp(f, (th,), (direction,))[1])),
        ("gradient, reverse", "backsolve", lambda f: jax.grad(f)),
    ]
    if args.reverse_only:
        cases = cases[:2]
    grads = {}
    for what, adjoint, transform in cases:
        f = lambda th, adjoint=adjoint: theta_T(th, adjoint)  # noqa: E731
        try:
            fn = jax.jit(transform(f))
            c, run = timed(fn, theta, args.repeats if adjoint != "forward" or "jvp" in what else max(3, args.repeats // 5))
            grads[(what, adjoint)] = np.asarray(fn(theta))
            rows.append(dict(what=what, adjoint=adjoint, compile_s=c, run_s=run, cost_vs_forward=run / fwd))
        except Exception as e:  # an adjoint that does not apply is reported, not hidden
            rows.append(dict(what=what, adjoint=adjoint, error=f"{type(e).__name__}: {str(e)[:200]}"))
    ref = grads.get(("gradient, reverse", "recursive"))
    for r in rows:
        g = grads.get((r["what"], r.get("adjoint")))
        if ref is not None and g is not None and g.shape == ref.shape:
            r["max_rel_diff_vs_recursive"] = float(np.max(np.abs(g - ref)) / np.max(np.abs(ref)))

    def t_stop(th):
        return syn.standstill_time(unflatten(th), t1=2.0, **OPTS)[0]

    if not args.reverse_only:
        c, run_t = timed(jax.jit(t_stop), theta, args.repeats)
        rows.append(dict(what="forward simulation to standstill", adjoint="-", compile_s=c, run_s=run_t))
        c, run = timed(jax.jit(jax.grad(t_stop)), theta, args.repeats)
        rows.append(dict(what="gradient of standstill time, reverse", adjoint="recursive", compile_s=c, run_s=run, cost_vs_forward=run / run_t))
    from assurjax._dynamics import Settings, simulate_core

    sol = jax.jit(lambda th: simulate_core(unflatten(th).mechanism, scene.gravity, scene.loads, 0.0, 0.0, 0.0, T,
                                           settings=Settings(samples=2, domega=False, check_assembly=False, **OPTS)))(theta)
    num_steps = int(sol.num_steps)

    out = dict(machine=platform.machine(), processor=platform.processor(), jax=jax.__version__, n_parameters=int(theta.size),
               T=T, options=OPTS, solver_steps=num_steps, date=time.strftime("%Y-%m-%d %H:%M:%S"), rows=rows)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / args.output).write_text(json.dumps(out, indent=2))
    print(f"Watt six-bar, theta({T} s), {theta.size} parameters, {num_steps} solver steps, max_steps {OPTS['max_steps']}")
    print(f"{'what':<40} {'adjoint':<20} {'compile s':>9} {'run ms':>9} {'x forward':>9}")
    for r in rows:
        if "error" in r:
            print(f"{r['what']:<40} {r['adjoint']:<20} error: {r['error'][:60]}")
            continue
        ratio = f"{r['cost_vs_forward']:.2f}" if "cost_vs_forward" in r else "1"
        print(f"{r['what']:<40} {r['adjoint']:<20} {r['compile_s']:>9.1f} {1e3 * r['run_s']:>9.3f} {ratio:>9}")


if __name__ == "__main__":
    main()
