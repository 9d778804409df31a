"""Cost of gradients through the simulation, per route.

The Watt six-bar of seed 000 falls from rest; f = theta(T) at T = 0.5 s (tsit5,
rtol = atol = 1e-8, no stop events). We time one forward simulation, then the gradient
of f with respect to every parameter of the scene (all point coordinates, centres of mass,
masses, inertias and gravity: 50 numbers) with

- ``quadrature``: forward sensitivities by variation of constants (assurjax.synthesis,
  ``adjoint="quadrature"``): the plain simulation saved at Gauss-Legendre nodes, one batched
  reverse pass of the reduced acceleration there, one solve of every panel's 2x2 transition
  matrix (no AD through diffrax),
- ``sensitivity``: the forward-sensitivity equations integrated with the state by diffrax
  (one reverse pass of the acceleration per solver stage),
- reverse mode through diffrax, RecursiveCheckpointAdjoint (default checkpoints, and every
  step stored),
- forward mode through diffrax, ForwardMode with jax.jacfwd (one tangent per parameter)
  and one directional derivative (jax.jvp),
- reverse mode, diffrax.BacksolveAdjoint (continuous adjoint backwards in time),

and the gradient of the standstill time through the event (implicit function theorem) with
the quadrature and the recursive routes. Every gradient is compared with a central finite
difference (Richardson-extrapolated) of the same forward simulation. Compile times are
reported apart; run times are medians over repeats; cost is a multiple of one forward
simulation measured in the same run (the target is below 5x for the full gradient).

Usage: python benchmarks/bench_gradients.py [--repeats 20] [--quick]
  --quick: only the forward simulations and the sensitivity routes (skips the minutes of
  compilation of reverse and forward mode through diffrax).
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
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax.dynamics import _settings
from assurjax import synthesis as syn

RESULTS = Path(__file__).parent / "results"
T = 0.5
T1_STANDSTILL = 2.0
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


def central_difference(f, theta, h=1e-4):
    """Richardson-extrapolated central difference of a scalar f along every axis (one vmapped call)."""
    eye = jnp.eye(theta.size, dtype=theta.dtype)
    batch = assurjax.jit(jax.vmap(f))

    def d(step):
        return (batch(theta + step * eye) - batch(theta - step * eye)) / (2 * step)

    return np.asarray((4 * d(h / 2) - d(h)) / 3)


def rel_diff(g, ref):
    return float(np.max(np.abs(np.asarray(g) - ref)) / np.max(np.abs(ref)))


def run_cases(rows, cases, theta, forward_s, reference, repeats, what_forward):
    for what, adjoint, fn, reps in cases:
        try:
            fn = assurjax.jit(fn)
            c, run = timed(fn, theta, reps or repeats)
            row = dict(what=what, adjoint=adjoint, compile_s=c, run_s=run, cost_vs_forward=run / forward_s,
                       relative_to=what_forward)
            value = np.asarray(fn(theta))
            if value.shape == reference.shape:
                row["max_rel_diff_vs_finite_differences"] = rel_diff(value, reference)
            rows.append(row)
        except Exception as e:  # a route that does not apply is reported, not hidden
            rows.append(dict(what=what, adjoint=adjoint, error=f"{type(e).__name__}: {str(e)[:200]}"))
        print_row(rows[-1])


def print_row(r):
    if "error" in r:
        print(f"{r['what']:<44} {r['adjoint']:<20} error: {r['error'][:70]}", flush=True)
        return
    ratio = f"{r['cost_vs_forward']:.2f}" if "cost_vs_forward" in r else "1"
    err = f"{r['max_rel_diff_vs_finite_differences']:.1e}" if "max_rel_diff_vs_finite_differences" in r else "-"
    print(f"{r['what']:<44} {r['adjoint']:<20} {r['compile_s']:>9.1f} {1e3 * r['run_s']:>9.3f} {ratio:>9} {err:>9}", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="skip reverse and forward mode through diffrax")
    ap.add_argument("--output", default="gradients.json")
    args = ap.parse_args()
    # every step stored: no recomputation in the backward pass (memory ~ steps x state)
    _settings.ADJOINTS["recursive_all_steps"] = lambda: diffrax.RecursiveCheckpointAdjoint(checkpoints=OPTS["max_steps"])

    scene = assurjax.load_scene("watt_sixbar")
    theta, unflatten = syn.flatten_parameters(scene, select=lambda s: (s.mechanism, s.gravity))
    direction = jax.random.normal(jax.random.key(0), theta.shape)

    def theta_T(th, adjoint="recursive"):
        return syn.final_state(unflatten(th), T, adjoint=adjoint, **OPTS)[0]

    def t_stop(th, adjoint="recursive"):
        return syn.standstill_time(unflatten(th), t1=T1_STANDSTILL, adjoint=adjoint, **OPTS)[0]

    print(f"{'what':<44} {'adjoint':<20} {'compile s':>9} {'run ms':>9} {'x forward':>9} {'vs FD':>9}")
    rows = []
    c, fwd = timed(assurjax.jit(theta_T), theta, args.repeats)
    rows.append(dict(what="forward simulation theta(T)", adjoint="-", compile_s=c, run_s=fwd))
    print_row(rows[-1])
    c, fwd_plain = timed(assurjax.jit(lambda th: theta_T(th, "quadrature")), theta, args.repeats)
    rows.append(dict(what="forward simulation theta(T), sensitivity path", adjoint="-", compile_s=c, run_s=fwd_plain))
    print_row(rows[-1])
    fd = central_difference(assurjax.jit(theta_T), theta)
    ad = lambda adjoint: (lambda th: theta_T(th, adjoint))  # noqa: E731
    cases = [
        ("gradient (jax.grad)", "quadrature", jax.grad(ad("quadrature")), None),
        ("gradient (jax.grad), 8 panels", "quadrature", jax.grad(lambda th: syn.final_state(
            unflatten(th), T, adjoint="quadrature", panels=8, **OPTS)[0]), None),
        ("gradient (jax.jacfwd)", "quadrature", jax.jacfwd(ad("quadrature")), None),
        ("gradient (jax.grad)", "sensitivity", jax.grad(ad("sensitivity")), None),
    ]
    if not args.quick:
        slow = max(3, args.repeats // 5)
        cases += [
            ("gradient, reverse", "recursive", jax.grad(ad("recursive")), None),
            ("gradient, reverse", "recursive_all_steps", jax.grad(ad("recursive_all_steps")), None),
            ("gradient, forward (jacfwd)", "forward", jax.jacfwd(ad("forward")), slow),
            ("directional derivative (jvp)", "forward", lambda th: jax.jvp(ad("forward"), (th,), (direction,))[1], None),
            ("gradient, reverse", "backsolve", jax.grad(ad("backsolve")), None),
        ]
    run_cases(rows, cases, theta, fwd, fd, args.repeats, "forward simulation theta(T)")

    c, fwd_t = timed(assurjax.jit(t_stop), theta, args.repeats)
    rows.append(dict(what="forward simulation to standstill", adjoint="-", compile_s=c, run_s=fwd_t))
    print_row(rows[-1])
    fd_t = central_difference(assurjax.jit(t_stop), theta)
    cases = [("gradient of standstill time", "quadrature", jax.grad(lambda th: t_stop(th, "quadrature")), None)]
    if not args.quick:
        cases.append(("gradient of standstill time", "recursive", jax.grad(t_stop), None))
    run_cases(rows, cases, theta, fwd_t, fd_t, args.repeats, "forward simulation to standstill")

    from assurjax import SimulationSettings as Settings, simulate_core

    sol = assurjax.jit(lambda th: simulate_core(unflatten(th).mechanism, scene.gravity, scene.loads, 0.0, 0.0, 0.0, T,
                                           settings=Settings(samples=2, domega=False, check_assembly=False, **OPTS)))(theta)
    out = dict(machine=platform.machine(), processor=platform.processor(), jax=jax.__version__, n_parameters=int(theta.size),
               T=T, options=OPTS, solver_steps=int(sol.num_steps), date=time.strftime("%Y-%m-%d %H:%M:%S"), rows=rows)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / args.output).write_text(json.dumps(out, indent=2))
    print(f"Watt six-bar, theta({T} s), {theta.size} parameters, {int(sol.num_steps)} solver steps; saved {RESULTS / args.output}")


if __name__ == "__main__":
    main()
