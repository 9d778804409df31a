"""Work-precision: error against warm wall time, assurjax side by side with MuJoCo.

Systems
- the Watt six-bar of seed 000 falling from rest over [0, T] s from several starting
  crank angles (no stop event: it swings back and forth);
- the N-four-bar (IFToMM A02) with the tracked branch, against its exact solution.

Methods (all in one run, so the ratios hold on a noisy machine)
- assurjax: the reduced equation integrated by diffrax (Tsit5, Dopri5, Dopri8,
  Kvaerno5) at tolerances 1e-3 .. 1e-12. The run is the package's own right-hand
  side inside the leanest diffrax call (save only at the grid, no events, no
  outputs), jitted once per solver with the tolerances traced; with the exact or
  the tabulated reduction (the table is built once per mechanism, outside the timed
  call); and Dopri8 / Tsit5 with fixed step counts by lax.scan over the solver's
  own step (``simulate_core`` with ``steps``), returning the angle at the grid;
- the seed's scheme (Euler in q, steps 1e-2 .. 1e-5 rad), a labelled baseline;
- the joint-based full-coordinate formulation (tests/joint_reference.py, scipy
  DOP853, numpy right-hand side) at tolerances 1e-3 .. 1e-12;
- MuJoCo: RK4 and implicitfast, time steps 1e-3 .. 1e-5 s, loops closed by
  connect constraints with solref time constant 2 dt and solimp 0.9999.

Error: max over the grid t = 0.1, 0.2, ..., T of |theta2 - theta2_ref| (rad). The
reference is assurjax with Dopri8 at rtol = atol = 1e-13 (Watt; cross-checked against
the joint-based formulation at 1e-12, difference reported) or the exact elliptic
solution (N-four-bar). Times are the best of ``--repeats`` warm runs (s).

    python benchmarks/bench_work_precision.py [--quick]

Writes benchmarks/results/work_precision.json and work_precision.png, prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax.dynamics._field import State, field_args, vector_field
from assurjax._tracking import branch_angles, stacked_branch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
import joint_reference as jr  # noqa: E402
from _timing import best_time  # noqa: E402

RESULTS = HERE / "results"
SOLVERS = {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8, "kvaerno5": diffrax.Kvaerno5}


# ----------------------------------------------------------------------------- assurjax


_RUNNERS: dict = {}


def lean_runner(scene, solver: str, *, tracked: bool = False, table: bool = False, max_steps: int = 200_000):
    """The package's reduced equation in the leanest diffrax call: saves q at the grid
    only; PID controller with traced tolerances. ``table``: the tabulated reduction
    (built once, outside the timed call). One compile per variant (cached)."""
    key = (scene.name, solver, tracked, table)
    if key in _RUNNERS:
        return _RUNNERS[key]
    mech, gravity, loads = scene.mechanism, scene.gravity, tuple(scene.loads)
    term = diffrax.ODETerm(vector_field)
    prebuilt = assurjax.build_table(mech, gravity, loads) if table else None

    @assurjax.jit
    def run(q0, w0, ts, rtol, atol):
        y0 = State(q0, w0)
        if tracked:
            y0 = y0._replace(branch=stacked_branch(mech, branch_angles(mech, assurjax.positions(mech, q0))))
        controller = diffrax.PIDController(rtol=rtol, atol=atol)
        sol = diffrax.diffeqsolve(
            term, SOLVERS[solver](), 0.0, ts[-1], None, y0, args=field_args(assurjax.Model(mech, gravity, loads), prebuilt),
            saveat=diffrax.SaveAt(ts=ts), stepsize_controller=controller, max_steps=max_steps, throw=False,
        )
        return sol.ys[0], sol.stats["num_steps"], sol.result._value  # diffrax's code

    _RUNNERS[key] = run
    return run


def steps_runs(scene, q0, w0, ts, ref, counts: dict, repeats, *, table=False):
    """Fixed steps by lax.scan over the solver's own step (simulate_core with
    ``steps``): no controller, no rejected steps, no event machinery. Step counts are
    multiples of the grid, so the saved steps include the grid times."""
    mech, gravity, loads = scene.mechanism, scene.gravity, tuple(scene.loads)
    tab = assurjax.build_table(mech, gravity, loads) if table else None
    rows = []
    for name, multiples in counts.items():
        for n in (len(ts) * k for k in multiples):
            stride = n // len(ts)
            settings = assurjax.SimulationSettings(solver=name, steps=n, check_assembly=False, domega=False,
                                                   reduction="table" if table else "exact")
            run = assurjax.jit(lambda q0, w0: assurjax.simulate_core(mech, gravity, loads, q0, w0, 0.0, ts[-1],
                                                                      settings=settings, table=tab).q[stride::stride])
            a = (jnp.asarray(q0), jnp.asarray(w0))
            err = float(np.max(np.abs(np.asarray(run(*a)) - ref)))
            rows.append(dict(method=f"assurjax {name} steps" + (" table" if table else ""), setting=n, error=err,
                             time=best_time(lambda: run(*a), repeats), steps=n))
    return rows


def assurjax_runs(scene, q0, w0, ts, ref, tolerances, repeats, *, tracked=False, compile_times=None, solvers=None, table=False):
    rows = []
    for name in solvers or SOLVERS:
        run = lean_runner(scene, name, tracked=tracked, table=table)
        label = " table" if table else ""
        args = lambda tol: (jnp.asarray(q0), jnp.asarray(w0), jnp.asarray(ts), jnp.asarray(tol), jnp.asarray(tol))  # noqa: E731
        t0 = time.perf_counter()
        jax.block_until_ready(run(*args(1e-6)))
        if compile_times is not None:
            compile_times[name + label] = time.perf_counter() - t0
        for tol in tolerances:
            q, steps, result = run(*args(tol))
            if int(result) != 0:
                rows.append(dict(method=f"assurjax {name}{label}", setting=tol, error=None, time=None, steps=int(steps), note="failed"))
                continue
            err = float(np.max(np.abs(np.asarray(q) - ref)))
            rows.append(dict(method=f"assurjax {name}{label}", setting=tol, error=err, time=best_time(lambda: run(*args(tol)), repeats), steps=int(steps)))
    return rows


def seed_euler_runs(scene, q0, w0, ts, ref, steps, repeats):
    rows = []
    for dq in steps:
        def run():
            # a little past the last grid time: the scheme takes whole steps of q, not of t
            return assurjax.simulate_seed_euler(scene.mechanism, scene.gravity, scene.loads, q0, w0, t1=ts[-1] + 0.05, dq=dq,
                                                standstill=False, max_steps=int(40.0 / dq))
        sol = run()
        t, q = np.asarray(sol.t), np.asarray(sol.q)
        if t[-1] < ts[-1] - 1e-9:
            rows.append(dict(method="seed Euler in q", setting=dq, error=None, time=None, note=sol.status))
            continue
        err = float(np.max(np.abs(np.interp(ts, t, q) - ref)))
        rows.append(dict(method="seed Euler in q", setting=dq, error=err, time=best_time(lambda: run().q, repeats)))
    return rows


# ----------------------------------------------------------------------------- references and others


def joint_based_runs(model_of, ts, ref, tolerances, repeats):
    rows = []
    for tol in tolerances:
        model = model_of()
        run = lambda: model.simulate(ts[-1], t_eval=ts, rtol=tol, atol=tol * 1e-1).q  # noqa: E731
        q = run()
        err = float(np.max(np.abs(q - ref)))
        rows.append(dict(method="joint-based (scipy DOP853)", setting=tol, error=err, time=best_time(run, max(1, repeats // 3))))
    return rows


def mujoco_runs(xml_of, theta0, omega0, ts, ref, steps, repeats):
    import mujoco
    import mujoco_models as mm

    rows = []
    for integrator in ("RK4", "implicitfast"):
        for dt in steps:
            model = mujoco.MjModel.from_xml_string(xml_of(dt, integrator))
            per = int(round((ts[1] - ts[0]) / dt))

            def run():
                data, qadr, theta_ref = mm.initial_data(model, theta0, omega0)
                out = np.empty(len(ts))
                for k in range(len(ts)):
                    mujoco.mj_step(model, data, nstep=per)
                    out[k] = data.qpos[qadr] + theta_ref
                return out

            q = run()
            err = float(np.max(np.abs(q - ref))) if np.isfinite(q).all() else None
            # the assembly of the initial state is set-up, not simulation: time only the stepping
            data0 = mm.initial_data(model, theta0, omega0)

            def stepping():
                data, qadr = mujoco.MjData(model), data0[1]
                data.qpos[:], data.qvel[:] = data0[0].qpos, data0[0].qvel
                for _ in range(len(ts)):
                    mujoco.mj_step(model, data, nstep=per)
                return data.qpos[qadr]

            rows.append(dict(method=f"MuJoCo {integrator}", setting=dt, error=err, time=best_time(stepping, max(1, repeats // 3))))
    return rows


# ----------------------------------------------------------------------------- systems


def watt(theta0, T, args, compile_times):
    import mujoco_models as mm

    scene = assurjax.load_scene("watt_sixbar")
    ts = np.round(np.arange(1, int(round(T / 0.1)) + 1) * 0.1, 12)
    ref_run = lean_runner(scene, "dopri8")
    ref = np.asarray(ref_run(jnp.asarray(theta0), jnp.asarray(0.0), jnp.asarray(ts), jnp.asarray(1e-13), jnp.asarray(1e-13))[0])
    joint = jr.watt_sixbar(theta0).simulate(T, t_eval=ts, rtol=1e-12, atol=1e-13).q
    cross = float(np.max(np.abs(joint - ref)))
    tols = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12]
    if args.quick:
        tols = tols[::3]
    explicit = [k for k in SOLVERS if k != "kvaerno5"]
    rows = assurjax_runs(scene, theta0, 0.0, ts, ref, tols, args.repeats, compile_times=compile_times, solvers=explicit if args.no_implicit else None)
    rows += assurjax_runs(scene, theta0, 0.0, ts, ref, tols, args.repeats, compile_times=compile_times, solvers=explicit, table=True)
    # step counts, as multiples of the grid's size
    table_steps = dict(tsit5=(2, 3, 4, 6, 8, 12, 16), dopri8=(1, 2, 4)) if not args.quick else dict(tsit5=(3, 8))
    rows += steps_runs(scene, theta0, 0.0, ts, ref, table_steps, args.repeats, table=True)
    rows += steps_runs(scene, theta0, 0.0, ts, ref, dict(tsit5=(4, 8), dopri8=(2,)) if not args.quick else dict(tsit5=(4,)), args.repeats)
    rows += seed_euler_runs(scene, theta0, 0.0, ts, ref, [1e-2, 1e-3, 1e-4] + ([] if args.quick else [1e-5]), args.repeats)
    rows += joint_based_runs(lambda: jr.watt_sixbar(theta0), ts, ref, tols[::2], args.repeats)
    mj_steps = [1e-3, 1e-4] + ([] if args.quick else [3e-5, 1e-5])
    rows += mujoco_runs(lambda dt, integ: mm.watt_sixbar_xml(dt=dt, integrator=integ), theta0, 0.0, ts, ref, mj_steps, args.repeats)
    return dict(system="watt_sixbar", theta0=theta0, T=T, reference_vs_joint_based=cross, rows=rows)


def n_four_bar(n, T, args):
    import mujoco_models as mm

    scene = assurjax.n_four_bar(n)
    ts = np.round(np.arange(1, int(round(T / 0.1)) + 1) * 0.1, 12)
    ref = jr.n_four_bar_exact(n, ts)[0]
    tols = [1e-4, 1e-6, 1e-8, 1e-10] if not args.quick else [1e-4, 1e-8]
    rows = []
    for name in ("tsit5", "dopri8"):  # the tracked state makes each compile longer: two solvers
        run = lean_runner(scene, name, tracked=True)
        for tol in tols:
            a = (jnp.asarray(np.pi / 2), jnp.asarray(-1.0), jnp.asarray(ts), jnp.asarray(tol), jnp.asarray(tol))
            q, steps, result = run(*a)
            err = float(np.max(np.abs(np.asarray(q) - ref))) if int(result) == 0 else None
            rows.append(dict(method=f"assurjax {name} (tracked)", setting=tol, error=err, time=best_time(lambda: run(*a), args.repeats), steps=int(steps)))
    mj_steps = [1e-3, 1e-4] + ([] if args.quick else [1e-5])
    rows += mujoco_runs(lambda dt, integ: mm.n_four_bar_xml(n, dt=dt, integrator=integ), np.pi / 2, -1.0, ts, ref, mj_steps, args.repeats)
    return dict(system=f"n_four_bar_{n}", theta0=np.pi / 2, T=T, reference_vs_joint_based=None, rows=rows)


# ----------------------------------------------------------------------------- summary


def pareto_time(rows, method_prefix, error, *, exclude=None):
    """Least time of a method family reaching ``error`` (None if it never does)."""
    ok = [
        r["time"] for r in rows
        if r["method"].startswith(method_prefix) and not (exclude and exclude in r["method"])
        and r["error"] is not None and r["time"] is not None and r["error"] <= error
    ]
    return min(ok) if ok else None


def summary(case):
    """Per error level: best assurjax time (exact reduction, and with the tabulated one), best MuJoCo time."""
    rows = case["rows"]
    out = {}
    for level in (1e-4, 1e-6, 1e-8, 1e-10):
        exact, a, m = pareto_time(rows, "assurjax", level, exclude="table"), pareto_time(rows, "assurjax", level), pareto_time(rows, "MuJoCo", level)
        out[f"{level:.0e}"] = dict(assurjax_exact=exact, assurjax=a, mujoco=m, ratio_exact=(m / exact) if exact and m else None, ratio=(m / a) if a and m else None)
    return out


def print_case(case):
    print(f"\n{case['system']} theta0 = {case['theta0']:.3f}, T = {case['T']} s"
          + (f", reference vs joint-based: {case['reference_vs_joint_based']:.2e} rad" if case["reference_vs_joint_based"] is not None else ""))
    print(f"  {'method':32s} {'setting':>9s} {'error (rad)':>12s} {'time (ms)':>10s}")
    for r in case["rows"]:
        err = "failed" if r["error"] is None else f"{r['error']:.2e}"
        tm = "-" if r["time"] is None else f"{1e3 * r['time']:.3f}"
        print(f"  {r['method']:32s} {r['setting']:9.0e} {err:>12s} {tm:>10s}")
    for level, s in summary(case).items():
        a = "-" if s["assurjax"] is None else f"{1e3 * s['assurjax']:.3f} ms"
        m = "-" if s["mujoco"] is None else f"{1e3 * s['mujoco']:.3f} ms"
        ratio = "-" if s["ratio"] is None else f"{s['ratio']:.0f}x"
        ratio_exact = "-" if s["ratio_exact"] is None else f"{s['ratio_exact']:.0f}x"
        print(f"  error <= {level}: assurjax {a}, MuJoCo {m}, MuJoCo/assurjax {ratio} (exact reduction only: {ratio_exact})")


def plot(cases, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(cases), figsize=(5.2 * len(cases), 4.4), squeeze=False)
    for ax, case in zip(axes[0], cases):
        methods = dict.fromkeys(r["method"] for r in case["rows"])
        for m in methods:
            pts = sorted((r["time"], r["error"]) for r in case["rows"] if r["method"] == m and r["error"] and r["time"])
            if pts:
                t, e = zip(*pts)
                style = "o-" if m.startswith("assurjax") else ("s--" if m.startswith("MuJoCo") else "^:")
                ax.loglog(t, e, style, label=m, ms=4)
        ax.set_xlabel("warm wall time (s)")
        ax.set_ylabel("max |theta2 - ref| (rad)")
        ax.set_title(f"{case['system']}, theta0 = {case['theta0']:.2f}, T = {case['T']} s", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer settings (a smoke run)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--nfb", type=int, default=2, help="N of the N-four-bar case")
    parser.add_argument("--no-implicit", action="store_true", help="skip Kvaerno5 (it compiles for minutes)")
    args = parser.parse_args()
    compile_times = {}
    cases = [watt(0.0, 1.0, args, compile_times)]
    for theta0 in ([] if args.quick else [0.0, 1.0, -1.0]):
        cases.append(watt(theta0, 2.0, args, None))
    cases.append(n_four_bar(args.nfb, 5.0, args))
    for case in cases:
        print_case(case)
    RESULTS.mkdir(exist_ok=True)
    info = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, compile_s=compile_times,
                note="times are warm wall times (s), best of repeats; errors in rad")
    for case in cases:
        case["summary"] = summary(case)
    (RESULTS / "work_precision.json").write_text(json.dumps(dict(info=info, cases=cases), indent=1))
    plot(cases, RESULTS / "work_precision.png")
    print(f"\ncompile time per solver (s): {', '.join(f'{k} {v:.1f}' for k, v in compile_times.items())}")


if __name__ == "__main__":
    main()
