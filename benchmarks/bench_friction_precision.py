"""Work-precision with joint friction: error against warm wall time of ``assurjax.simulate``
and of the independent joint-based formulation with the same Coulomb law.

Systems (tests/joint_reference_friction.py's, friction and viscous damping in every joint)
- the slider-crank from rest at q0 = 0.5 rad, 2 s: it swings, sticks and breaks away;
- the Watt six-bar from q0 = 0.3 rad, w0 = 1 rad/s, 2 s: rests and reversals of the
  joints' relative rates.

Methods
- assurjax: ``simulate`` (the call a user makes: stick/slip segments, events at every
  Coulomb switch, the friction solved at each right-hand side), Tsit5 and Dopri8 at
  rtol = atol = 1e-4 .. 1e-11, saved at the grid only;
- the joint-based reference (absolute coordinates, Lagrange multipliers, the friction from
  the multipliers by Newton's method at every right-hand side; numpy, scipy's DOP853 in
  segments with its own events) at rtol = 1e-4 .. 1e-10, atol = rtol / 10.

Error: max over the grid t = 0.1, 0.2, ..., 2 of |q - q_ref| (rad), q_ref the joint-based
reference at rtol = 1e-12, atol = 1e-13 (its default); assurjax's tightest runs show how
far the two formulations agree. Times: best of a few warm runs for assurjax (its compile
apart), one run for the reference (numpy: no compile).

    python benchmarks/bench_friction_precision.py [--quick]

Writes benchmarks/results/friction_precision.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

import assurjax

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
import joint_reference_friction as jrf  # noqa: E402
from _timing import best_time  # noqa: E402

T1 = 2.0
GRID = np.linspace(0.1, T1, 20)
SYSTEMS = {
    "slider_crank": dict(q0=0.5, w0=0.0, table=jrf.SLIDER_CRANK_FRICTION, reference=lambda: jrf.slider_crank(0.5, 0.0)),
    "watt_sixbar": dict(q0=0.3, w0=1.0, table=jrf.WATT_FRICTION, reference=lambda: jrf.watt_sixbar(0.3, 1.0)),
}


def package_frictions(mechanism, table: dict):
    """The reference's friction table as the package's loads (same mu, radius, block, damping)."""
    out = []
    for name in assurjax.joint_names(mechanism):
        ref = table["P" if "/" in name else name]
        if "/" in name:
            out.append(assurjax.SlideFriction(name, ref.mu, ref.length, viscous=ref.damping))
        else:
            out.append(assurjax.JointFriction(name, ref.mu, ref.radius, viscous=ref.damping))
    return tuple(out)


def reference_run(system: dict, rtol: float, atol: float):
    t0 = time.perf_counter()
    result = system["reference"]().simulate(T1, t_eval=np.concatenate([[0.0], GRID]), rtol=rtol, atol=atol)
    return result.q[1:], time.perf_counter() - t0


def assurjax_run(scene, loads, system: dict, solver: str, tol: float):
    def run():
        return assurjax.simulate(scene, loads=loads, q0=system["q0"], omega0=system["w0"], t1=T1, stop=None,
                                 saveat=GRID, solver=solver, rtol=tol, atol=tol, energies=False, points=(), angles=())

    t0 = time.perf_counter()
    sol = run()
    first = time.perf_counter() - t0
    seconds = best_time(lambda: run().q, repeats=5, budget=2.0)
    return sol, first, seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer tolerances, the slider-crank only")
    parser.add_argument("--out", default=str(HERE / "results" / "friction_precision.json"))
    args = parser.parse_args()
    package_tols = [1e-5, 1e-8, 1e-11] if args.quick else [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11]
    reference_tols = [1e-5, 1e-8] if args.quick else [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
    systems = {"slider_crank": SYSTEMS["slider_crank"]} if args.quick else SYSTEMS
    out = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, t1=T1, systems={})
    for name, system in systems.items():
        q_ref, ref_seconds = reference_run(system, 1e-12, 1e-13)
        scene = assurjax.load_scene(name)
        loads = tuple(scene.loads) + package_frictions(scene.mechanism, system["table"])
        case = dict(reference_seconds=ref_seconds, assurjax=[], joint_based=[])
        for solver in ("tsit5", "dopri8"):
            for tol in package_tols:
                sol, first, seconds = assurjax_run(scene, loads, system, solver, tol)
                row = dict(solver=solver, tol=tol, seconds=seconds, first_call=first, steps=int(sol.num_steps),
                           error=float(np.max(np.abs(np.asarray(sol.q) - q_ref))), status=sol.status)
                case["assurjax"].append(row)
                print(name, json.dumps(row))
        for tol in reference_tols:
            q, seconds = reference_run(system, tol, tol / 10)
            row = dict(solver="DOP853 (joint-based)", tol=tol, seconds=seconds, error=float(np.max(np.abs(q - q_ref))))
            case["joint_based"].append(row)
            print(name, json.dumps(row))
        out["systems"][name] = case
    _table(out)
    if not args.quick:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


def _table(out: dict) -> None:
    for name, case in out["systems"].items():
        print(f"\n{name} (reference: {case['reference_seconds']:.1f} s at 1e-12)")
        print(f"{'method':24s} {'tol':>8s} {'error (rad)':>12s} {'time (ms)':>10s} {'steps':>6s}")
        for row in case["assurjax"] + case["joint_based"]:
            print(f"{row['solver']:24s} {row['tol']:8.0e} {row['error']:12.2e} {1e3 * row['seconds']:10.2f} {row.get('steps', ''):>6}")


if __name__ == "__main__":
    main()
