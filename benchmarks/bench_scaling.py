"""Cost growth with the number of groups: the N-four-bar for N = 1 .. 40 and the strandbeest.

N-four-bar rows: one simulation of 1 s from the benchmark's initial state (rockers
up, B_0 at 1 m/s), tracked branch, Tsit5 at rtol = atol = 1e-8, in the lean diffrax
call of bench_work_precision.py (trace and XLA compile timed apart); one
right-hand-side evaluation alone (vmapped over 1000 states, per evaluation); the
user's call ``assurjax.simulate(scene, branch="tracked", t1=1.0)`` (first call in
the process: its wall time, and trace and compile time summed over JAX's own compile
events -- simulate() compiles its two programs side by side, so their compile times add
up to more than the wall time they take --, and warm run time); ``positions`` and
``kinematics`` (order 2) at one q: trace, compile, warm run.
Strandbeest row (``--strandbeest``): the bundled 8-leg scene (25 groups), the same
measurements with its own simulate() defaults (fixed branch), no lean call.
Sizes whose predicted compile time exceeds ``--compile-budget`` s are skipped.

    python benchmarks/bench_scaling.py [--sizes 1 2 5 10 20 30 40] [--strandbeest]
                                       [--no-user-calls] [--out scaling.json]

Writes benchmarks/results/<out> (default scaling.json) and the matching .png, prints a table.
The machine may be shared: compare rows of one run (or runs made side by side).
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
from assurjax.dynamics._field import State, field_args, vector_field
from assurjax._jit import COMPILER_OPTIONS
from assurjax._tracking import branch_angles, stacked_branch
from bench_work_precision import SOLVERS, best_time

import diffrax

RESULTS = Path(__file__).resolve().parent / "results"


def predicted_compile(rows, n):
    """Power-law extrapolation of the compile times measured so far (s)."""
    done = [(r["N"], r["compile_s"]) for r in rows if r.get("compile_s")]
    if len(done) < 2:
        return 0.0
    (n1, c1), (n2, c2) = done[-2], done[-1]
    p = np.log(c2 / c1) / np.log(n2 / n1) if n2 > n1 and c2 > c1 else 1.0
    return c2 * (n / n2) ** p


def lean_function(scene):
    """The lean simulation of bench_work_precision.lean_runner (tracked branch, Tsit5), unjitted."""
    mech, gravity, loads = scene.mechanism, scene.gravity, tuple(scene.loads)

    def run(q0, w0, ts, rtol, atol):
        y0 = State(q0, w0, branch=stacked_branch(mech, branch_angles(mech, assurjax.positions(mech, q0))))
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vector_field), SOLVERS["tsit5"](), 0.0, ts[-1], None, y0,
            args=field_args(assurjax.Model(mech, gravity, loads)),
            saveat=diffrax.SaveAt(ts=ts), stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
            max_steps=200_000, throw=False,
        )
        return sol.ys[0], sol.stats["num_steps"], sol.result._value

    return run


def trace_compile_run(fun, args, repeats):
    """(trace s, compile s, warm run s) of ``jax.jit(fun)`` with the package's compiler options."""
    t0 = time.perf_counter()
    lowered = jax.jit(fun).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile(compiler_options=COMPILER_OPTIONS)
    t2 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    return t1 - t0, t2 - t1, best_time(lambda: compiled(*args), repeats)


class CompileEvents:
    """Sums JAX's own trace and backend-compile durations while active (any jit inside a call)."""

    names = {"/jax/core/compile/jaxpr_trace_duration": "trace", "/jax/core/compile/backend_compile_duration": "compile"}

    def __init__(self):
        self.total = {"trace": 0.0, "compile": 0.0}
        self.active = False
        jax.monitoring.register_event_duration_secs_listener(self.listen)

    def listen(self, event, duration, **kwargs):
        if self.active and event in self.names:
            self.total[self.names[event]] += duration

    def measure(self, call):
        """(trace s, compile s, wall s) of one call."""
        self.total = {"trace": 0.0, "compile": 0.0}
        self.active = True
        t0 = time.perf_counter()
        try:
            jax.block_until_ready(call())
        finally:
            self.active = False
        return self.total["trace"], self.total["compile"], time.perf_counter() - t0


EVENTS = None
USER_CALLS = True  # --no-user-calls


def user_calls(scene, repeats, q, **options) -> dict:
    """simulate() (first and warm), positions and kinematics at one q: trace, compile, run."""
    global EVENTS
    EVENTS = EVENTS or CompileEvents()
    mech = scene.mechanism
    sim = lambda: assurjax.simulate(scene, **options).q  # noqa: E731
    trace, compile_, first = EVENTS.measure(sim)
    out = dict(simulate_trace_s=trace, simulate_compile_s=compile_, simulate_first_s=first, simulate_run_s=best_time(sim, repeats))
    qa = jnp.asarray(q)
    for name, fun in (("kinematics", lambda q: assurjax.kinematics(mech, q, 1.0, 0.0, check=False)),):
        t, c, r = trace_compile_run(fun, (qa,), repeats)
        out.update({f"{name}_trace_s": t, f"{name}_compile_s": c, f"{name}_run_s": r})
    return out


def measure(n: int, repeats: int) -> dict:
    scene = assurjax.n_four_bar(n)
    mech = scene.mechanism
    args = (jnp.asarray(np.pi / 2), jnp.asarray(-1.0), jnp.asarray([1.0]), jnp.asarray(1e-8), jnp.asarray(1e-8))
    t0 = time.perf_counter()
    lowered = jax.jit(lean_function(scene)).lower(*args)
    trace_s = time.perf_counter() - t0
    ops = lowered.as_text().count("= stablehlo.")  # program size: does not depend on the machine's load
    run = lowered.compile(compiler_options=COMPILER_OPTIONS)
    compile_s = time.perf_counter() - t0 - trace_s
    q, steps, result = jax.block_until_ready(run(*args))
    run_s = best_time(lambda: run(*args), repeats)
    exact = assurjax_exact(n)
    # one right-hand side alone, vmapped over 1000 states near the start
    z = stacked_branch(mech, branch_angles(mech, assurjax.positions(mech, np.pi / 2)))
    qs = jnp.linspace(1.4, 1.7, 1000)
    args = field_args(assurjax.Model(mech, scene.gravity))
    rhs = assurjax.jit(jax.vmap(lambda q: vector_field(0.0, State(q, -jnp.ones_like(q), branch=z), args).omega))
    rhs_s = best_time(lambda: rhs(qs), repeats) / qs.size
    row = dict(N=n, groups=n + 1, hlo_ops=ops, trace_s=trace_s, compile_s=trace_s + compile_s, xla_compile_s=compile_s, run_s=run_s,
               steps=int(steps), result=int(result), error=float(abs(float(q[0]) - exact)), rhs_us=1e6 * rhs_s)
    if USER_CALLS:
        row.update(user_calls(scene, repeats, 1.2, branch="tracked", t1=1.0))
    return row


def measure_strandbeest(repeats: int) -> dict:
    scene = assurjax.load_scene("strandbeest")
    row = dict(scene="strandbeest", groups=len(scene.mechanism.groups), links=len(scene.mechanism.links))
    row.update(user_calls(scene, repeats, 0.3))
    return row


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
    ax.loglog(n, [r["compile_s"] for r in done], "s--", label="compile (trace + XLA), lean call")
    if all("simulate_first_s" in r for r in done):
        ax.loglog(n, [r["simulate_first_s"] for r in done], "d:", label="first simulate() call")
    ax.set_xlabel("N (windows; groups = N + 1)")
    ax.set_ylabel("wall time (s)")
    ax.set_title("N-four-bar, tracked branch, Tsit5 1e-8", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 5, 10, 20, 30, 40])
    parser.add_argument("--compile-budget", type=float, default=600.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--strandbeest", action="store_true")
    parser.add_argument("--out", default="scaling.json")
    parser.add_argument("--no-user-calls", action="store_true", help="skip simulate() and kinematics per size")
    args = parser.parse_args()
    global USER_CALLS
    USER_CALLS = not args.no_user_calls
    rows = []
    head = f"{'N':>4s} {'trace':>6s} {'compile':>8s} {'run (ms)':>9s} {'error':>8s} {'rhs (us)':>8s} | simulate: {'first':>6s} {'trace':>6s} {'compile':>8s} {'run ms':>7s} | kinematics: {'trace':>6s} {'compile':>8s}"
    print(head)
    for n in args.sizes:
        guess = predicted_compile(rows, n)
        if guess > args.compile_budget:
            rows.append(dict(N=n, groups=n + 1, skipped=f"predicted compile time {guess:.0f} s > budget {args.compile_budget:.0f} s"))
            print(f"{n:4d} skipped: {rows[-1]['skipped']}", flush=True)
            continue
        r = measure(n, args.repeats)
        rows.append(r)
        line = f"{n:4d} {r['trace_s']:6.1f} {r['xla_compile_s']:8.1f} {1e3 * r['run_s']:9.3f} {r['error']:8.1e} {r['rhs_us']:8.2f} |"
        if USER_CALLS:
            line += (f" {r['simulate_first_s']:15.1f} {r['simulate_trace_s']:6.1f} {r['simulate_compile_s']:8.1f} {1e3 * r['simulate_run_s']:7.2f} | "
                     f"{r['kinematics_trace_s']:18.1f} {r['kinematics_compile_s']:8.1f}")
        print(line, flush=True)
    extra = []
    print("program size (StableHLO operations of the lean call):", {r["N"]: r.get("hlo_ops") for r in rows})
    if args.strandbeest:
        r = measure_strandbeest(args.repeats)
        extra.append(r)
        print(f"strandbeest ({r['groups']} groups): simulate trace {r['simulate_trace_s']:.1f} s, compile {r['simulate_compile_s']:.1f} s, "
              f"first call {r['simulate_first_s']:.1f} s, run {1e3 * r['simulate_run_s']:.2f} ms; kinematics trace "
              f"{r['kinematics_trace_s']:.1f} s, compile {r['kinematics_compile_s']:.1f} s", flush=True)
    RESULTS.mkdir(exist_ok=True)
    info = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, load_average=os.getloadavg(),
                note="shared machine: compare rows of one run, or runs made side by side")
    (RESULTS / args.out).write_text(json.dumps(dict(info=info, rows=rows, scenes=extra), indent=1))
    plot(rows, RESULTS / Path(args.out).with_suffix(".png").name)


if __name__ == "__main__":
    main()
