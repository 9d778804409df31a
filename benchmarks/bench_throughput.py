"""Throughput: vmapped batches of 1 .. 100 000 simulations of the Watt six-bar.

Each simulation: 1 s of motion from rest at a starting crank angle spread over
[-0.3, 0.3] rad, Tsit5 (the default solver) at rtol = atol = 1e-8 (the package's right-hand side in
the lean diffrax call of bench_work_precision.py, saving only q(1 s), forward-mode
adjoint). One
compile per batch size (reported apart); run time is the best warm call; peak
memory is XLA's own accounting of the compiled call (arguments + outputs +
temporaries) and the process's peak resident set.

    python benchmarks/bench_throughput.py [--max 100000] [--solver tsit5] [--tol 1e-8] [--reduction exact|table]

``--reduction table``: the right-hand side interpolates the tabulated reduction
(``assurjax.build_table``, built once outside the timed call).
Writes benchmarks/results/throughput[_table].json and .png, prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax._jit import COMPILER_OPTIONS
from assurjax.dynamics._field import State, field_args, vector_field

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
SOLVERS = {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8}


def batch_runner(scene, solver: str, tol: float, reduction: str = "exact"):
    mech, gravity, loads = scene.mechanism, scene.gravity, tuple(scene.loads)
    table = reduction == "table"
    prebuilt = assurjax.build_table(mech, gravity, loads) if table else None

    def one(q0):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vector_field), SOLVERS[solver](), 0.0, 1.0, None, State(q0, jnp.zeros_like(q0)),
            args=field_args(assurjax.Model(mech, gravity, loads), prebuilt),
            saveat=diffrax.SaveAt(t1=True), stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol), max_steps=4096, throw=False,
            adjoint=diffrax.ForwardMode(),  # no reverse-mode checkpointing: a plain while loop, cheaper under vmap
        )
        return sol.ys[0][-1], sol.stats["num_steps"], sol.result._value

    return jax.jit(jax.vmap(one), compiler_options=COMPILER_OPTIONS)  # the options assurjax.jit compiles with


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(run, n: int, repeats: int) -> dict:
    q0 = jnp.linspace(-0.3, 0.3, n)
    t0 = time.perf_counter()
    compiled = run.lower(q0).compile()
    compile_s = time.perf_counter() - t0
    mem = compiled.memory_analysis()
    xla_bytes = None if mem is None else int(mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes)
    q, steps, result = jax.block_until_ready(compiled(q0))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(q0))
        times.append(time.perf_counter() - t0)
    return dict(n=n, compile_s=compile_s, run_s=min(times), per_simulation_us=1e6 * min(times) / n,
                failed=int(np.sum(np.asarray(result) != 0)), mean_steps=float(np.mean(np.asarray(steps))),
                xla_peak_mb=None if xla_bytes is None else xla_bytes / 2**20, process_peak_rss_mb=peak_rss_mb())


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n"] for r in rows]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.loglog(n, [r["run_s"] for r in rows], "o-", label="warm run")
    ax.loglog(n, [r["compile_s"] for r in rows], "s--", label="compile")
    ax.set_xlabel("simulations in one vmapped call")
    ax.set_ylabel("wall time (s)")
    ax.set_title("Watt six-bar, 1 s each", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max", type=int, default=100_000)
    parser.add_argument("--solver", default="tsit5", choices=sorted(SOLVERS))
    parser.add_argument("--tol", type=float, default=1e-8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--reduction", default="exact", choices=("exact", "table"))
    args = parser.parse_args()
    run = batch_runner(assurjax.load_scene("watt_sixbar"), args.solver, args.tol, args.reduction)
    sizes = [n for n in (1, 10, 100, 1000, 10_000, 100_000) if n <= args.max]
    rows = []
    print(f"{'batch':>8s} {'compile (s)':>12s} {'run (s)':>10s} {'us/sim':>9s} {'steps':>7s} {'XLA MB':>8s} {'RSS MB':>8s}")
    for n in sizes:
        r = measure(run, n, args.repeats if n < 100_000 else 1)
        rows.append(r)
        xla = "-" if r["xla_peak_mb"] is None else f"{r['xla_peak_mb']:.1f}"
        print(f"{n:8d} {r['compile_s']:12.2f} {r['run_s']:10.4f} {r['per_simulation_us']:9.1f} {r['mean_steps']:7.1f} {xla:>8s} {r['process_peak_rss_mb']:8.0f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    info = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, solver=args.solver, tol=args.tol, reduction=args.reduction)
    name = "throughput" if args.reduction == "exact" else "throughput_table"
    (RESULTS / f"{name}.json").write_text(json.dumps(dict(info=info, rows=rows), indent=1))
    plot(rows, RESULTS / f"{name}.png")


if __name__ == "__main__":
    main()
