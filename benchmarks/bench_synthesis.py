"""Synthesis and sweep benchmarks.

1. Straight-line synthesis (seed 001): a Roberts-type four-bar with every length perturbed
   by up to 10 %, brought to a straight-line deviation at or below the Roberts linkage's own
   over a 260 mm stroke. Gradient-based (optax Adam through ``assurjax.synthesis.optimize``)
   against two gradient-free searches written here as labelled BASELINES (random search and a
   particle swarm), both on the same bounded design and the same jitted, vmapped objective.
   Reported: objective evaluations and wall time to reach the Roberts deviation (compile
   time apart).
2. Target standstill time (synthesis problem 3): a counterweight (mass and position on the
   crank) of the Watt six-bar of seed 000 so that the first standstill after release from rest
   happens at a target time; Adam through the simulation and the standstill event (forward
   sensitivities, ``adjoint="quadrature"``). Reported: iterations, wall time (compile apart),
   standstill time reached vs target, re-checked by ``assurjax.simulate`` (default solver).
3. A sweep of 1 000 000 kinematic configurations (1 000 perturbed Roberts linkages x 1 000
   crank angles) in chunks: throughput and peak resident memory.

Usage: python benchmarks/bench_synthesis.py [--seeds 3] [--quick]
Results: benchmarks/results/synthesis.json
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

import assurjax
from assurjax import synthesis as syn

RESULTS = Path(__file__).parent / "results"


def roberts_deviation() -> float:
    design, objective = syn.straight_line_problem(syn.roberts_lengths())
    return float(assurjax.jit(objective)(design.values(design.init()))[1]["deviation"])


def gradient_run(lengths, target, steps):
    design, objective = syn.straight_line_problem(lengths)
    result = syn.optimize(design, objective, optax.adam(0.05), steps, has_aux=True, progress=False)
    dev = np.asarray(result.history.aux["deviation"])
    hit = np.flatnonzero(dev <= target)
    compile_time = result.history.time[0]  # the first evaluation includes compilation
    return dict(
        reached=bool(hit.size),
        evaluations=int(result.history.evaluations[hit[0]]) if hit.size else None,
        time_s=float(result.history.time[hit[0]] - compile_time) if hit.size else None,
        compile_s=float(compile_time),
        final_deviation_mm=float(dev.min() * 1e3),
        total_evaluations=int(result.evaluations),
    )


def _batched_objective(design, objective):
    """Deviation of a population of designs, given in unconstrained coordinates (jit + vmap)."""

    def one(z):
        _, aux = objective(design.values(z))
        return jnp.where(aux["ok"], aux["deviation"], jnp.inf)

    return assurjax.jit(jax.vmap(one))


def random_search_baseline(lengths, target, budget, population=256, seed=0):
    """BASELINE (gradient-free): uniform random sampling of the bounded design box."""
    design, objective = syn.straight_line_problem(lengths)
    f = _batched_objective(design, objective)
    z0 = design.init()
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    f(jax.tree.map(lambda z: jnp.broadcast_to(z, (population,) + z.shape), z0)).block_until_ready()
    compile_time = time.perf_counter() - t0
    best, evals, t0 = np.inf, 0, time.perf_counter()
    while evals < budget:
        u = [rng.uniform(1e-6, 1 - 1e-6, (population,) + np.shape(z)) for z in jax.tree.leaves(z0)]
        zs = jax.tree.unflatten(jax.tree.structure(z0), [np.log(x) - np.log1p(-x) for x in u])
        best = min(best, float(np.min(f(zs))))
        evals += population
        if best <= target:
            break
    return dict(reached=bool(best <= target), evaluations=evals, time_s=time.perf_counter() - t0,
                compile_s=compile_time, final_deviation_mm=best * 1e3)


def particle_swarm_baseline(lengths, target, budget, population=64, seed=0, w=0.7, c1=1.5, c2=1.5):
    """BASELINE (gradient-free): a plain global-best particle swarm in the unconstrained coordinates."""
    design, objective = syn.straight_line_problem(lengths)
    f = _batched_objective(design, objective)
    z0 = np.concatenate([np.ravel(z) for z in jax.tree.leaves(design.init())])
    treedef = jax.tree.structure(design.init())
    shapes = [np.shape(z) for z in jax.tree.leaves(design.init())]

    def unflat(x):
        out, i = [], 0
        for s in shapes:
            k = int(np.prod(s))
            out.append(x[:, i : i + k].reshape((x.shape[0],) + s))
            i += k
        return jax.tree.unflatten(treedef, out)

    rng = np.random.default_rng(seed)
    x = z0 + rng.normal(0.0, 0.5, (population, z0.size))
    x[0] = z0
    v = np.zeros_like(x)
    t0 = time.perf_counter()
    fx = np.asarray(f(unflat(x)))
    compile_time = time.perf_counter() - t0
    t0 = time.perf_counter()
    pbest, pval = x.copy(), fx.copy()
    g = pbest[np.argmin(pval)]
    evals = population
    while evals < budget and pval.min() > target:
        r1, r2 = rng.uniform(size=x.shape), rng.uniform(size=x.shape)
        v = w * v + c1 * r1 * (pbest - x) + c2 * r2 * (g - x)
        x = x + v
        fx = np.asarray(f(unflat(x)))
        evals += population
        better = fx < pval
        pbest[better], pval[better] = x[better], fx[better]
        g = pbest[np.argmin(pval)]
    return dict(reached=bool(pval.min() <= target), evaluations=evals, time_s=time.perf_counter() - t0,
                compile_s=compile_time, final_deviation_mm=float(pval.min() * 1e3))


def straight_line_benchmark(seeds, steps, budget):
    target = roberts_deviation()
    rows = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        lengths = np.asarray(syn.roberts_lengths()) * (1 + rng.uniform(-0.1, 0.1, 6))
        rows.append(dict(seed=seed, method="adam (gradient)", **gradient_run(lengths, target, steps)))
        rows.append(dict(seed=seed, method="random search (BASELINE)", **random_search_baseline(lengths, target, budget, seed=seed)))
        rows.append(dict(seed=seed, method="particle swarm (BASELINE)", **particle_swarm_baseline(lengths, target, budget, seed=seed)))
    return dict(roberts_deviation_mm=target * 1e3, runs=rows)


def standstill_benchmark(targets=(1.3, 1.6, 1.75), steps=200):
    """Synthesis problem 3 on the Watt six-bar: one Adam run per target standstill time."""
    scene = assurjax.load_scene("watt_sixbar")
    opts = dict(solver="tsit5", rtol=1e-8, atol=1e-8, max_steps=2048)
    rows = []
    for target in targets:
        design, objective, build = syn.standstill_time_problem(scene, target, **opts)
        result = syn.optimize(design, objective, optax.adam(0.2), steps, has_aux=True, target=1e-8, progress=False)
        compile_time = float(result.history.time[0])
        mass, position = (float(v) for v in result.values)
        check = assurjax.simulate(build(result.values), t1=1.5 * target, stop="standstill", samples=2)
        start = float(result.history.aux["standstill"][0])
        rows.append(dict(target_s=target, status=result.status, iterations=len(result.history.loss) - 1,
                         evaluations=int(result.evaluations), time_s=float(result.history.time[-1]) - compile_time,
                         compile_s=compile_time, start_standstill_s=start,
                         reached_standstill_s=float(result.history.aux["standstill"][-1]),
                         simulate_standstill_s=check.t_stop, counterweight_mass_kg=mass, counterweight_x_m=position))
    return rows


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _coupler_item(args):
    mechanism, q = args
    return syn.coupler_curve(mechanism, "P", q)


def _reduce_assembled(carry, result):
    """Per chunk: count assembled configurations and track the largest |y_P| among them."""
    pts, ok = result
    count, peak = (0, 0.0) if carry is None else carry
    return count + int(ok.sum()), max(peak, float(np.abs(np.where(ok, pts[..., 1], 0.0)).max()))


def million_sweep(n_mechanisms=1000, n_q=1000, chunk=50):
    """1 000 000 configurations: perturbed Roberts linkages x crank angles, in chunks of ``chunk``
    mechanisms. (a) coupler point and ok flags written into preallocated numpy arrays (16 MB + 1 MB);
    (b) reduced per chunk (a count and a maximum), so memory does not grow with the sweep.
    Peak RSS (ru_maxrss) is read before and after each."""
    mech = assurjax.load_scene("roberts").mechanism
    batch = jax.tree.map(np.asarray, assurjax.perturb(mech, jax.random.key(0), n_mechanisms, relative=0.05))
    q = np.broadcast_to(np.linspace(0.0, 2 * np.pi, n_q), (n_mechanisms, n_q))  # a view: no copy per mechanism
    out = dict(configurations=n_mechanisms * n_q, chunk_mechanisms=chunk)
    assurjax.sweep(_coupler_item, (jax.tree.map(lambda x: x[:chunk], batch), q[:chunk]), chunk_size=chunk)  # compile
    rss0 = peak_rss_mb()
    t0 = time.perf_counter()
    reduced = assurjax.sweep(_coupler_item, (batch, q), chunk_size=chunk, reduce=_reduce_assembled)
    out["reduce_seconds"] = time.perf_counter() - t0
    out["reduce_peak_rss_mb"] = (rss0, peak_rss_mb())
    out["assembled"] = reduced[0]
    t0 = time.perf_counter()
    pts, ok = assurjax.sweep(_coupler_item, (batch, q), chunk_size=chunk)
    out["write_seconds"] = time.perf_counter() - t0
    out["write_peak_rss_mb"] = (rss0, peak_rss_mb())
    out["output_mb"] = (pts.nbytes + ok.nbytes) / 2**20
    out["configurations_per_s"] = n_mechanisms * n_q / out["reduce_seconds"]
    assert pts.shape == (n_mechanisms, n_q, 2) and int(ok.sum()) == reduced[0]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--budget", type=int, default=20000, help="objective evaluations for the baselines")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.budget = 1, 4096
    out = dict(machine=platform.machine(), processor=platform.processor(), devices=[str(d) for d in jax.devices()],
               jax=jax.__version__, date=time.strftime("%Y-%m-%d %H:%M:%S"))
    out["straight_line"] = straight_line_benchmark(args.seeds, args.steps, args.budget)
    out["standstill_time"] = standstill_benchmark(targets=(1.6,) if args.quick else (1.3, 1.6, 1.75))
    out["million_sweep"] = million_sweep(n_mechanisms=200 if args.quick else 1000)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "synthesis.json").write_text(json.dumps(out, indent=2))

    print(f"Straight-line synthesis: target = Roberts deviation {out['straight_line']['roberts_deviation_mm']:.4f} mm")
    print(f"{'seed':>4} {'method':<28} {'reached':>7} {'evals':>8} {'time s':>8} {'compile s':>9} {'best mm':>8}")
    for r in out["straight_line"]["runs"]:
        ev = "-" if r["evaluations"] is None else r["evaluations"]
        ts = "-" if r["time_s"] is None else f"{r['time_s']:.3f}"
        print(f"{r['seed']:>4} {r['method']:<28} {str(r['reached']):>7} {ev:>8} {ts:>8} {r['compile_s']:>9.1f} {r['final_deviation_mm']:>8.4f}")
    print("\nTarget standstill time, Watt six-bar + crank counterweight (Adam, forward sensitivities):")
    print(f"{'target s':>8} {'status':<8} {'iters':>5} {'time s':>7} {'compile s':>9} {'start s':>8} {'reached s':>10} {'simulate s':>10}")
    for r in out["standstill_time"]:
        sim = "-" if r["simulate_standstill_s"] is None else f"{r['simulate_standstill_s']:.6f}"
        print(f"{r['target_s']:>8.3f} {r['status']:<8} {r['iterations']:>5} {r['time_s']:>7.2f} {r['compile_s']:>9.1f} "
              f"{r['start_standstill_s']:>8.4f} {r['reached_standstill_s']:>10.6f} {sim:>10}")
    s = out["million_sweep"]
    print(f"\nSweep of {s['configurations']:,} configurations ({s['assembled']:,} assemble), chunks of {s['chunk_mechanisms']} mechanisms:")
    print(f"  reduced per chunk: {s['reduce_seconds']:.2f} s ({s['configurations_per_s']:,.0f}/s), "
          f"peak RSS {s['reduce_peak_rss_mb'][0]:.0f} -> {s['reduce_peak_rss_mb'][1]:.0f} MB")
    print(f"  written to numpy:  {s['write_seconds']:.2f} s, peak RSS -> {s['write_peak_rss_mb'][1]:.0f} MB (output {s['output_mb']:.1f} MB)")


if __name__ == "__main__":
    main()
