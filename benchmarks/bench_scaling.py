"""Cost growth with the number of groups: the N-four-bar for N = 1, 2, 5, 10, 20, 40.

One simulation of 1 s from the benchmark's initial state (rockers up, B_0 at
1 m/s), tracked branch, Tsit5 at rtol = atol = 1e-8, in the lean diffrax call of
bench_work_precision.py; also one right-hand-side evaluation alone (vmapped over
1000 states, per evaluation). Compile time is reported apart. The compile time of
the unrolled formation sequence grows faster than linearly with N; sizes whose
predicted compile time exceeds ``--compile-budget`` seconds are skipped and
reported as such.

    python benchmarks/bench_scaling.py [--sizes 1 2 5 10 20 40] [--compile-budget 600]

Writes benchmarks/results/scaling.json and scaling.png, prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax._dynamics import _rhs
from assurjax._tracking import branch_angles
from bench_work_precision import best_time, lean_runner

RESULTS = Path(__file__).resolve().parent / "results"


def predicted_compile(rows, n):
    """Power-law extrapolation of the compile times measured so far (s)."""
    done = [(r["N"], r["compile_s"]) for r in rows if r.get("compile_s")]
    if len(done) < 2:
        return 0.0
    (n1, c1), (n2, c2) = done[-2], done[-1]
    p = np.log(c2 / c1) / np.log(n2 / n1) if n2 > n1 and c2 > c1 else 1.0
    return c2 * (n / n2) ** p


def measure(n: int, repeats: int) -> dict:
    scene = assurjax.n_four_bar(n)
    mech = scene.mechanism
    run = lean_runner(scene, "tsit5", tracked=True)
    args = (jnp.asarray(np.pi / 2), jnp.asarray(-1.0), jnp.asarray([1.0]), jnp.asarray(1e-8), jnp.asarray(1e-8))
    t0 = time.perf_counter()
    q, steps, result = jax.block_until_ready(run(*args))
    compile_s = time.perf_counter() - t0
    run_s = best_time(lambda: run(*args), repeats)
    exact = assurjax_exact(n)
    # one right-hand side alone, vmapped over 1000 states near the start
    z = branch_angles(mech, assurjax.positions(mech, np.pi / 2))
    qs = jnp.linspace(1.4, 1.7, 1000)
    rhs = assurjax.jit(jax.vmap(lambda q: _rhs(0.0, (q, -jnp.ones_like(q), z), (mech, scene.gravity, (), False))))
    rhs_s = best_time(lambda: rhs(qs), repeats) / qs.size
    return dict(N=n, groups=n + 1, compile_s=compile_s, run_s=run_s, steps=int(steps), result=int(result),
                error=float(abs(float(q[0]) - exact)), rhs_us=1e6 * rhs_s)


def assurjax_exact(n):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import joint_reference as jr

    return float(jr.n_four_bar_exact(n, np.array([1.0]))[0][0])


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows if r.get("run_s")]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    n = [r["N"] for r in done]
    ax.loglog(n, [r["run_s"] for r in done], "o-", label="simulation of 1 s (warm)")
    ax.loglog(n, [1e-6 * r["rhs_us"] for r in done], "^-", label="one right-hand side (vmapped)")
    ax.loglog(n, [r["compile_s"] for r in done], "s--", label="compile")
    ax.set_xlabel("N (windows; groups = N + 1)")
    ax.set_ylabel("wall time (s)")
    ax.set_title("N-four-bar, tracked branch, Tsit5 1e-8", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 5, 10, 20, 40])
    parser.add_argument("--compile-budget", type=float, default=600.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rows = []
    print(f"{'N':>4s} {'compile (s)':>12s} {'run (ms)':>10s} {'steps':>6s} {'error':>9s} {'rhs (us)':>9s}")
    for n in args.sizes:
        guess = predicted_compile(rows, n)
        if guess > args.compile_budget:
            rows.append(dict(N=n, groups=n + 1, skipped=f"predicted compile time {guess:.0f} s > budget {args.compile_budget:.0f} s"))
            print(f"{n:4d} skipped: {rows[-1]['skipped']}", flush=True)
            continue
        r = measure(n, args.repeats)
        rows.append(r)
        print(f"{n:4d} {r['compile_s']:12.1f} {1e3 * r['run_s']:10.3f} {r['steps']:6d} {r['error']:9.1e} {r['rhs_us']:9.2f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    info = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__)
    (RESULTS / "scaling.json").write_text(json.dumps(dict(info=info, rows=rows), indent=1))
    plot(rows, RESULTS / "scaling.png")


if __name__ == "__main__":
    main()
