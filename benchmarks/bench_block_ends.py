"""Derivatives across the kinks of a slide's friction law: with and without the cuts.

A prismatic pair's Coulomb magnitude mu (|N/2 - M/L| + |N/2 + M/L|) has a kink where the
load on one end of its block passes through 0. Where a run is differentiated, each slip
segment freezes the block ends' signs and an event ends it there
(``Settings.kink_events``, on in the entry points that can be differentiated); "uncut"
switches that off in this process (the code before the cuts), so that both compare in one run.

Case: the bundled press with Coulomb friction mu = 0.15 in its pins O, A, B (r = 0.01 m)
and its slide (L = 0.05 m), from rest; q(T) and d q(T)/d mu of ``synthesis.final_state``
in forward mode (``jax.jvp`` under ``jax.jit``) at T = 0.1 s (two kinks, one Coulomb
switch) and T = 0.5 s, at rtol = atol = 1e-8 and 1e-10. Reference: central differences of
the run not differentiated (no cuts: its values are as accurate) at rtol = atol = 1e-12,
Richardson-extrapolated from h = 2e-3 and 1e-3. Costs: the jitted derivative's first call
(trace and compile) and its best warm call, and ``simulate()``'s warm run (never
differentiated: the same program either way).

    python benchmarks/bench_block_ends.py [--out FILE]

Writes results/block_ends.json unless told otherwise.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import assurjax as aj
from _timing import best_time

HERE = Path(__file__).resolve().parent
MU = 0.15


def press(mu):
    scene = aj.load_scene("press_with_friction")
    others = tuple(load for load in scene.loads if not isinstance(load, (aj.JointFriction, aj.SlideFriction)))
    rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("ram/ground", mu, 0.05),)
    return scene.with_loads(others + rough)


def q_at(mu, t1, tol):
    return aj.synthesis.final_state(press(mu), t1, rtol=tol, atol=tol, adjoint="forward")[0]


def reference(t1):
    def q(mu):
        return float(aj.synthesis.final_state(press(mu), t1, rtol=1e-12, atol=1e-12)[0])

    d = {h: (q(MU + h) - q(MU - h)) / (2 * h) for h in (2e-3, 1e-3)}
    return (4 * d[1e-3] - d[2e-3]) / 3, d[1e-3]


_RUN = None


def cuts(on: bool) -> None:
    """The cuts on (the package as it is) or off (every run as simulate()'s, not cut)."""
    global _RUN
    from assurjax.synthesis import _dynamic

    _RUN = _RUN or _dynamic._run

    def run(model, q0, omega0, t0, t1, dt, settings, **kwargs):
        return _RUN(model, q0, omega0, t0, t1, dt, settings._replace(kink_events=on), **kwargs)

    _dynamic._run = run


def measure(on: bool, t1: float, tol: float) -> dict:
    cuts(on)
    program = jax.jit(lambda mu, t: jax.jvp(lambda m: q_at(m, t, tol), (mu,), (jnp.ones(()),)))
    mu, t = jnp.asarray(MU), jnp.asarray(t1)
    start = time.perf_counter()
    q, slope = jax.block_until_ready(program(mu, t))
    first = time.perf_counter() - start
    warm = best_time(lambda: program(mu, t), repeats=5)
    return dict(q=float(q), slope=float(slope), first_call_s=first, warm_ms=1e3 * warm)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(HERE / "results" / "block_ends.json"))
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    rows = []
    for t1 in (0.1, 0.5):
        ref, plain = reference(t1)
        for tol in (1e-8, 1e-10):
            for on in (True, False):
                row = dict(T=t1, tol=tol, cuts=on, **measure(on, t1, tol))
                row["slope_error"] = abs(row["slope"] - ref) / abs(ref)
                rows.append(row)
                print(f"T {t1} tol {tol:g} {'cut  ' if on else 'uncut'}: d q/d mu {row['slope']:.10f} (reference "
                      f"{ref:.10f}, h=1e-3 alone {plain:.10f}) error {row['slope_error']:.1e}; first call "
                      f"{row['first_call_s']:.1f} s, warm {row['warm_ms']:.1f} ms", flush=True)
    cuts(True)
    scene = press(MU)
    simulate_ms = 1e3 * best_time(lambda: aj.simulate(scene, t1=0.5).q, repeats=7)
    print(f"simulate(press, t1=0.5) warm {simulate_ms:.2f} ms (never differentiated: no cuts)")
    out = dict(machine=platform.machine(), jax=jax.__version__, mu=MU, rows=rows, simulate_warm_ms=simulate_ms)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print("wrote", args.out)


if __name__ == "__main__":
    main()
