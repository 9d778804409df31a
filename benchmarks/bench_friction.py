"""Cost of joint friction: one right-hand side and one simulation, with and without friction.

With friction every right-hand side linearizes the kinetostatics once and solves the
friction values (fixed-point iteration, Newton's method where it is slow: see
assurjax/_friction.py); the target is at most 2x the cost of a frictionless step. Measured per right-hand-side evaluation (the
vector field alone, jitted): vmapped over 256 states (a batch, as in a sweep), and one
state after another inside one program (as a simulation's steps call it: there every
small operation is a call of its own, and a while loop's iterations cost more than their
arithmetic); and per simulation (the user's call ``assurjax.simulate``: steps, time,
time per step; and, on the driven press, the marginal cost of one more step, alone and
per member of a batch of 16, and the kernel calls per step that explain it).

    python benchmarks/bench_friction.py            # writes results/friction.json
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import platform
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

import assurjax
from assurjax.dynamics._field import State, field_args, vector_field

sys.path.insert(0, os.path.dirname(__file__))
from _timing import best_time  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def frictions(mechanism, mu=0.2):
    names = assurjax.joint_names(mechanism)
    return tuple(assurjax.JointFriction(j, mu, 0.02, viscous=1e-3) for j in names if "/" not in j) + tuple(
        assurjax.SlideFriction(j, mu, 0.05, viscous=1e-3) for j in names if "/" in j)


def moving_args(scene, loads):
    """The vector field's arguments for a motion in the + direction (no stop events)."""
    return field_args(assurjax.Model(scene.mechanism, scene.gravity, loads), direction=1.0)


def per_evaluation(scene, loads, n=256) -> float:
    """Seconds per right-hand-side evaluation (vmapped over n states)."""
    args = moving_args(scene, loads)
    field = assurjax.jit(jax.vmap(lambda q, w: vector_field(0.0, State(q, w), args).omega))
    q, w = jnp.linspace(0.3, 2.5, n), jnp.full(n, 1.5)
    return best_time(lambda: field(q, w)) / n


def per_serial_evaluation(scene, loads, n=1000) -> float:
    """Seconds per right-hand-side evaluation, n evaluations one after another in one program
    (each state depends on the last result, as the stages of a step do)."""
    args = moving_args(scene, loads)

    def run(q):
        body = lambda i, acc: acc + vector_field(0.0, State(q + 2e-3 * i, 1.5 + 1e-9 * acc), args).omega  # noqa: E731
        return jax.lax.fori_loop(0, n, body, jnp.zeros(()))

    loop, q = jax.jit(run), jnp.asarray(0.3)
    return best_time(lambda: loop(q)) / n


def per_simulation(scene, loads, q0, t1) -> dict:
    kwargs = dict(loads=loads, q0=q0, stop=None, t1=t1, rtol=1e-8, atol=1e-8)
    start = time.perf_counter()
    sol = assurjax.simulate(scene, **kwargs)
    first = time.perf_counter() - start
    seconds = best_time(lambda: assurjax.simulate(scene, **kwargs).q, repeats=5)
    steps = int(np.asarray(sol.num_steps))
    return dict(first_call_s=first, run_s=seconds, steps=steps, us_per_step=1e6 * seconds / steps, status=sol.status)


def marginal_per_step(scene, loads, t1=2.0, repeats=5, **options) -> dict:
    """Microseconds per integration step of a driven motion, from two runs that differ only
    in their length (t1 and 2 t1, two saved samples): what one more step costs, without the
    fixed cost of a call (setup, outputs, the start's analysis). With an array ``q0`` in
    ``options`` (a batch): per member and step, the steps summed over the members."""
    runs = []
    for t in (t1, 2 * t1):
        kwargs = dict(loads=loads, stop=None, t1=t, samples=2, **options)
        steps = int(np.sum(np.asarray(assurjax.simulate(scene, **kwargs).num_steps)))
        runs.append((best_time(lambda: assurjax.simulate(scene, **kwargs).q, repeats=repeats), steps))
    (short, n_short), (long, n_long) = runs
    return dict(steps=[n_short, n_long], run_s=[short, long], us_per_step=1e6 * (long - short) / (n_long - n_short))


def interleaved_marginal_per_step(scene, variants: dict, t1=2.0, rounds=40) -> dict:
    """:func:`marginal_per_step` of several ``variants`` (name -> loads) measured in turns:
    each round times every variant's short and long run one after another, so that the
    machine's load, which moves a single run's figure by 30 % and more on a shared machine,
    is nearly the same for the variants compared within a round. Per variant: the marginal
    step from the best times over the rounds (as :func:`marginal_per_step`) and from the
    median times; and each round's ratio of the variants' marginal steps (the first variant
    the denominator), whose median and quartiles are what the comparison reports."""
    runs = {}
    for name, loads in variants.items():
        for t in (t1, 2 * t1):
            kwargs = dict(loads=loads, stop=None, t1=t, samples=2)
            steps = int(np.asarray(assurjax.simulate(scene, **kwargs).num_steps))  # compiles
            runs[name, t] = (kwargs, steps, [])
    for _ in range(rounds):
        for kwargs, _, times in runs.values():
            t0 = time.perf_counter()
            jax.block_until_ready(assurjax.simulate(scene, **kwargs).q)
            times.append(time.perf_counter() - t0)
    out, per_round = {}, {}
    for name in variants:
        (_, n_short, short), (_, n_long, long) = runs[name, t1], runs[name, 2 * t1]
        steps = n_long - n_short
        per_round[name] = 1e6 * (np.asarray(long) - np.asarray(short)) / steps
        out[name] = dict(steps=[n_short, n_long], us_per_step=1e6 * (min(long) - min(short)) / steps,
                         us_per_step_median=1e6 * (np.median(long) - np.median(short)) / steps)
    first, *others = variants
    for name in others:
        ratios = per_round[name] / per_round[first]
        out[f"{name}_ratio"] = dict(rounds=rounds, median=float(np.median(ratios)),
                                    quartiles=[float(np.percentile(ratios, 25)), float(np.percentile(ratios, 75))],
                                    of_best_times=out[name]["us_per_step"] / out[first]["us_per_step"])
    return out


def kernels_per_step(scene, loads, t1=0.2) -> dict:
    """XLA's CPU kernel calls (fusions, copies, loops, conditionals: the runtime's thunks) per
    integration step of one ``simulate()``, counted in profiler traces of warm calls: runs to
    t1 and 2 t1, the difference in calls over the difference in steps (as
    :func:`marginal_per_step`). A single run's step costs about its kernel calls times a few
    tens of ns each (the arithmetic inside is small), and the count, unlike a time, is the
    same on every run of the same program."""
    runs = [kernel_calls(scene, loads, t) for t in (t1, 2 * t1)]
    (n_short, short), (n_long, long) = ((steps, sum(calls.values())) for steps, calls in runs)
    return dict(steps=[n_short, n_long], kernels=[short, long], per_step=(long - short) / (n_long - n_short))


def kernel_calls(scene, loads, t1) -> tuple[int, collections.Counter]:
    """(steps, XLA's kernel calls by instruction name) of one warm ``simulate()`` to t1: the
    compiled program's own events in a profiler trace (not Python's, marked "$", nor the
    ends of async ones)."""
    kwargs = dict(loads=loads, stop=None, t1=t1, samples=2)
    steps = int(np.asarray(assurjax.simulate(scene, **kwargs).num_steps))
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            jax.block_until_ready(assurjax.simulate(scene, **kwargs).q)
        (path,) = glob.glob(os.path.join(folder, "**", "*.trace.json.gz"), recursive=True)
        with gzip.open(path) as f:
            events = json.load(f)["traceEvents"]
    return steps, collections.Counter(e["name"] for e in events if e.get("ph") == "X" and not e["name"].startswith(("$", "end:")))


def batch_marginal_per_step(scene, loads, n=16) -> dict:
    """:func:`marginal_per_step` of a batch of n simulations (exact reduction), runs of 1 and 2 s."""
    starts = np.linspace(0.0, 6.0, n)
    return dict(members=n, **marginal_per_step(scene, loads, t1=1.0, repeats=3, q0=starts, reduction="exact"))


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "friction.json"))
    args = parser.parse_args()
    out = dict(machine=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, cases={})
    for name, q0, t1 in (("slider_crank", 0.5, 2.0), ("watt_sixbar", 0.3, 2.0)):
        scene = assurjax.load_scene(name)
        rough = scene.loads + frictions(scene.mechanism)
        case = dict(rhs_us=1e6 * per_evaluation(scene, scene.loads), rhs_friction_us=1e6 * per_evaluation(scene, rough),
                    rhs_serial_us=1e6 * per_serial_evaluation(scene, scene.loads),
                    rhs_friction_serial_us=1e6 * per_serial_evaluation(scene, rough),
                    simulate=per_simulation(scene, scene.loads, q0, t1), simulate_friction=per_simulation(scene, rough, q0, t1))
        case["rhs_ratio"] = case["rhs_friction_us"] / case["rhs_us"]
        case["rhs_serial_ratio"] = case["rhs_friction_serial_us"] / case["rhs_serial_us"]
        case["step_ratio"] = case["simulate_friction"]["us_per_step"] / case["simulate"]["us_per_step"]
        out["cases"][name] = case
        print(name, json.dumps(case, indent=1))
    # a driven motion (the bundled press: motor, process force, friction in every pair) that
    # keeps moving, so a longer run is more steps of the same kind: the marginal cost of a step
    press = assurjax.load_scene("press_with_friction")
    plain = tuple(load for load in press.loads if not load.needs_reactions)
    # both in turns (interleaved_marginal_per_step): the ratio is each round's, its median reported
    case = dict(elements=len(press.loads) - len(plain),
                **interleaved_marginal_per_step(press, dict(plain=plain, friction=press.loads)))
    case["step_ratio"] = case["friction_ratio"]["median"]
    case["kernels"] = dict(plain=kernels_per_step(press, plain), friction=kernels_per_step(press, press.loads))
    case["kernel_ratio"] = case["kernels"]["friction"]["per_step"] / case["kernels"]["plain"]["per_step"]
    out["cases"]["press_marginal"] = case
    print("press_marginal", json.dumps(case, indent=1))
    # the same as a batch of 16 starts (a sweep): per member and step
    case = dict(plain=batch_marginal_per_step(press, plain), friction=batch_marginal_per_step(press, press.loads))
    case["step_ratio"] = case["friction"]["us_per_step"] / case["plain"]["us_per_step"]
    out["cases"]["press_batch"] = case
    print("press_batch", json.dumps(case, indent=1))
    # a large mechanism with friction in every joint (73 elements): what a first call costs
    # as K grows (the friction law's stacked path, _friction.SUMMED_TERMS)
    scene = assurjax.load_scene("strandbeest")
    q0, rough = float(scene.state["q0"]), scene.loads + frictions(scene.mechanism)
    case = dict(elements=len(frictions(scene.mechanism)), simulate=per_simulation(scene, scene.loads, q0, 0.2),
                simulate_friction=per_simulation(scene, rough, q0, 0.2))
    case["step_ratio"] = case["simulate_friction"]["us_per_step"] / case["simulate"]["us_per_step"]
    out["cases"]["strandbeest"] = case
    print("strandbeest", json.dumps(case, indent=1))
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
