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
the cut run's q(T) at rtol = atol = 1e-12, Richardson-extrapolated from h = 2e-3 and 1e-3.
Cut, those values are smooth in mu: at T = 0.1 s the differences converge as h^2 (their
changes 1.8e-7, 4.7e-8, 1.2e-8, 3.0e-9 from h = 4e-3 halved down to 2.5e-4; Richardson
from (2e-3, 1e-3) and (1e-3, 5e-4) agree to 1.5e-9 relative); the uncut run's scatter by
~1e-8 from h = 1e-3 down (the steps across a kink err beyond the tolerance), which made an
uncut reference off by 2e-7. Costs: the jitted derivative's first call
(trace and compile) and its best warm call, and ``simulate()``'s warm run (never
differentiated: the same program either way).

Second case (kinks of a load in omega): the press's motor line replaced by a torque-speed
table with knots at 4, 8, 12 and 16 rad/s (omega rises through them from rest and falls back
through 16, 12 and 8 by T = 0.3 s), d q(0.3 s)/d mu cut, cut everywhere but at the table's
knots (``_stick.tables_in`` made to find no table in omega: the code before those cuts), and
uncut.

Third case (a run without friction: one diffrax solve before it was cut at its tables' knots
too): the press with its motor line and process force alone, d q(T)/d stall (the motor's
stall torque, 40 N m) at T = 0.35 and 0.5 s (past the process force's knots), cut and uncut;
the reference as above in the stall torque (h = 2e-2 and 1e-2).

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


SPEED_CURVE = ([0.0, 4.0, 8.0, 12.0, 16.0, 20.0], [40.0, 33.0, 25.0, 19.0, 10.0, 0.0])  # rad/s -> N m


def press(mu, curve=False):
    """The press with friction mu everywhere; ``curve``: its motor line replaced by SPEED_CURVE."""
    scene = aj.load_scene("press_with_friction")
    kept = (aj.PointForce,) if curve else (aj.PointForce, aj.MotorLine)
    others = tuple(load for load in scene.loads if isinstance(load, kept))
    if curve:
        others += (aj.Drive(aj.Table(*SPEED_CURVE, variable="omega")),)
    rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("ram/ground", mu, 0.05),)
    return scene.with_loads(others + rough)


STALL = 40.0  # N m, the press's motor line


def frictionless_press(stall):
    """The press with its motor line (stall torque ``stall``) and process force alone."""
    scene = aj.load_scene("press_with_friction")
    return scene.with_loads(tuple(load for load in scene.loads if isinstance(load, aj.PointForce)) + (aj.MotorLine(stall, 20.0),))


def scene_of(value, curve=False, frictionless=False):
    """The scene at the differentiated value: mu, or (``frictionless``) the stall torque."""
    return frictionless_press(value) if frictionless else press(value, curve)


def q_at(value, t1, tol, curve=False, frictionless=False):
    return aj.synthesis.final_state(scene_of(value, curve, frictionless), t1, rtol=tol, atol=tol, adjoint="forward")[0]


def reference(t1, curve=False, frictionless=False):
    cuts(True)  # set here, not left as the measurement before left it

    def q(value):
        return float(aj.synthesis.final_state(scene_of(value, curve, frictionless), t1, rtol=1e-12, atol=1e-12)[0])

    at, (h1, h2) = (STALL, (2e-2, 1e-2)) if frictionless else (MU, (2e-3, 1e-3))
    d = {h: (q(at + h) - q(at - h)) / (2 * h) for h in (h1, h2)}
    return (4 * d[h2] - d[h1]) / 3, d[h2]


_RUN = None


_TABLES_IN = None


def cuts(on: bool, in_omega: bool = True) -> None:
    """The cuts on (the package as it is) or off (every run as simulate()'s, not cut);
    ``in_omega`` False: on, but not at the knots of tables in omega."""
    global _RUN, _TABLES_IN
    from assurjax.dynamics import _field, _stick
    from assurjax.synthesis import _dynamic

    _RUN, _TABLES_IN = _RUN or _dynamic._run, _TABLES_IN or _stick.tables_in

    def run(model, q0, omega0, t0, t1, dt, settings, **kwargs):
        return _RUN(model, q0, omega0, t0, t1, dt, settings._replace(kink_events=on), **kwargs)

    _dynamic._run = run
    _stick.tables_in = _field.tables_in = (
        lambda loads, variable: () if variable == "omega" and not in_omega else _TABLES_IN(loads, variable))
    jax.clear_caches()  # the runs' programs are cached by their settings, which in_omega leaves as they are


def measure(on: bool, t1: float, tol: float, curve: bool = False, in_omega: bool = True, frictionless: bool = False) -> dict:
    cuts(on, in_omega)
    program = jax.jit(lambda mu, t: jax.jvp(lambda m: q_at(m, t, tol, curve, frictionless), (mu,), (jnp.ones(()),)))
    mu, t = jnp.asarray(STALL if frictionless else MU), jnp.asarray(t1)
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
    ref, plain = reference(0.3, curve=True)  # the torque-speed table
    for tol in (1e-8, 1e-10):
        for label, on, in_omega in (("cut", True, True), ("cut but in omega", True, False), ("uncut", False, True)):
            row = dict(case="torque-speed table", T=0.3, tol=tol, cuts=on, omega_knots_cut=on and in_omega,
                       **measure(on, 0.3, tol, True, in_omega))
            row["slope_error"] = abs(row["slope"] - ref) / abs(ref)
            rows.append(row)
            print(f"table in omega, T 0.3 tol {tol:g} {label}: d q/d mu {row['slope']:.10f} (reference {ref:.10f}, "
                  f"h=1e-3 alone {plain:.10f}) error {row['slope_error']:.1e}; first call {row['first_call_s']:.1f} s, "
                  f"warm {row['warm_ms']:.1f} ms", flush=True)
    for t1 in (0.35, 0.5):  # without friction: cut at the knots, or one solve across them
        ref, plain = reference(t1, frictionless=True)
        for tol in (1e-8, 1e-10):
            for on in (True, False):
                row = dict(case="without friction", T=t1, tol=tol, cuts=on, **measure(on, t1, tol, frictionless=True))
                row["slope_error"] = abs(row["slope"] - ref) / abs(ref)
                rows.append(row)
                print(f"without friction, T {t1} tol {tol:g} {'cut  ' if on else 'uncut'}: d q/d stall {row['slope']:.10f} "
                      f"(reference {ref:.10f}, h=1e-2 alone {plain:.10f}) error {row['slope_error']:.1e}; first call "
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
