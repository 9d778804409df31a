"""The frictionless paths a change of the vector field's interface can slow without
touching one simulation: vmapped batches and gradients, with the press's step beside them.

Each case in a fresh process (no compiled program kept on disk), warm best of 3 (the
gradient: 10th percentile of 200 calls) and the first call:

- ``vmapped_starts``: 10 000 Watt six-bars from q0 in [0, 6] rad, 2 s, exact reduction
  (``eqx.filter_vmap`` of ``simulate_core`` inside ``assurjax.jit``, as ``bench_dynamics.py``);
- ``parameter_sweep``: 2000 Watt six-bars, every third of their 50 parameters scaled by up
  to +-1 % (``jax.vmap`` over ``synthesis.flatten_parameters``), 2 s from q0 = 0.3 rad;
- ``quadrature_gradient``: the gradient of theta(0.5 s) with respect to the 50 parameters,
  ``adjoint="quadrature"`` (as ``bench_gradients.py``), and the forward run it is taken of;
- ``press_step``: one more step of the press without and with friction, interleaved in
  turns (``bench_friction.interleaved_marginal_per_step``, 10 rounds).

``--before REF`` also measures the package at git revision REF, run for run interleaved.

    python benchmarks/bench_vmapped_paths.py [--before REF] [--repeats 2]   # writes results/vmapped_paths.json
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
CASES = ("vmapped_starts", "parameter_sweep", "quadrature_gradient", "press_step")

CHILD = r"""
import json, sys, time
import equinox as eqx, jax, jax.numpy as jnp, numpy as np
import assurjax
from assurjax import synthesis as syn
from _timing import best_time

case = sys.argv[1]
watt = assurjax.load_scene("watt_sixbar")
settings = assurjax.SimulationSettings(samples=2, check_assembly=False, domega=False)

def first_and_warm(fn, *args):
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    return dict(first_s=first, warm_s=best_time(lambda: fn(*args), repeats=3))

if case == "vmapped_starts":
    run = assurjax.jit(eqx.filter_vmap(lambda q0: assurjax.simulate_core(
        watt.mechanism, watt.gravity, (), q0, 0.0, 0.0, 2.0, settings=settings).q))
    out = first_and_warm(run, jnp.linspace(0.0, 6.0, 10_000))
elif case == "parameter_sweep":
    theta, unflatten = syn.flatten_parameters(watt, select=lambda s: (s.mechanism, s.gravity))
    scale = jnp.linspace(-0.01, 0.01, 2000)[:, None] * (jnp.arange(theta.size) % 3 == 0)
    def member(th):
        s = unflatten(th)
        return assurjax.simulate_core(s.mechanism, s.gravity, (), 0.3, 0.0, 0.0, 2.0, settings=settings).q
    out = first_and_warm(assurjax.jit(jax.vmap(member)), theta[None, :] * (1.0 + scale))
elif case == "quadrature_gradient":
    theta, unflatten = syn.flatten_parameters(watt, select=lambda s: (s.mechanism, s.gravity))
    opts = dict(solver="tsit5", rtol=1e-8, atol=1e-8, max_steps=1024)
    f = lambda th: syn.final_state(unflatten(th), 0.5, adjoint="quadrature", **opts)[0]
    out = {}
    for name, fn in (("forward", f), ("gradient", jax.grad(f))):
        fn = assurjax.jit(fn)
        start = time.perf_counter()
        jax.block_until_ready(fn(theta))
        out[name + "_first_s"] = time.perf_counter() - start
        times = []
        for _ in range(200):
            start = time.perf_counter()
            jax.block_until_ready(fn(theta))
            times.append(time.perf_counter() - start)
        out[name + "_ms"] = 1e3 * float(np.percentile(times, 10))
else:
    from bench_friction import interleaved_marginal_per_step
    press = assurjax.load_scene("press_with_friction")
    plain = tuple(load for load in press.loads if not load.needs_reactions)
    r = interleaved_marginal_per_step(press, dict(plain=plain, friction=press.loads), rounds=10)
    out = dict(plain_us=r["plain"]["us_per_step"], friction_us=r["friction"]["us_per_step"],
               ratio_median=r["friction_ratio"]["median"])
print(json.dumps(out))
"""


def measure(code_dirs: dict, repeats: int) -> dict:
    """case -> version -> runs, the versions interleaved."""
    from bench_overhead import interleaved_children

    return interleaved_children(CHILD, CASES, code_dirs, repeats)


def ratios(runs: dict) -> dict:
    """before / after of each figure, the best of the runs (the ratio of the press's step: the median's)."""
    out = {}
    for case, versions in runs.items():
        keys = [k for k in versions["after"][0] if k != "ratio_median"]
        out[case] = {k: min(r[k] for r in versions["before"]) / min(r[k] for r in versions["after"]) for k in keys}
    return out


def main():
    from bench_overhead import versions_main

    versions_main(__doc__, HERE / "results" / "vmapped_paths.json", measure, ratios)


if __name__ == "__main__":
    main()
