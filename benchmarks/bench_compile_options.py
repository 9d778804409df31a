"""XLA's CPU code generators on this package's programs: compile time and run time with
the default options, with the legacy emitters alone and with ``assurjax._jit.COMPILER_OPTIONS``
(the legacy emitters, and no library (YNNPACK) fusions where the jaxlib has them).

Each program is traced and lowered once, then compiled with each option set; the run
time is the best of warm calls. Programs: a single simulation of the Watt six-bar with
the scene's events and outputs, the lean jitted core, 10 000 vmapped simulations (exact
and tabulated reduction), second-order kinematics of 100 000 configurations, reactions
of 10 000 states, the gradient of a final angle with respect to all parameters, and one
simulation of the strandbeest with friction in its 73 joints (the friction law's stacked
(K, K, 2) arrays, which the library fusions took).

Saves benchmarks/results/compile_options.json. Run: python benchmarks/bench_compile_options.py
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import assurjax as aj
from assurjax import SimulationSettings as Settings, simulate_core
from assurjax._jit import COMPILER_OPTIONS

from bench_friction import frictions

from _timing import best_time

HERE = Path(__file__).resolve().parent
EMITTERS = {"xla_cpu_use_fusion_emitters": False}


def programs():
    """name -> (function, arguments)."""
    scene = aj.load_scene("watt_sixbar")
    mech, g = scene.mechanism, scene.gravity
    outs = scene.outputs
    full = Settings(standstill=True, points=tuple(outs.get("points", ())), angles=tuple(outs.get("angles", ())),
                    energies=bool(outs.get("energies", False)))
    lean = Settings(check_assembly=False, domega=False, samples=21)
    batch = Settings(check_assembly=False, domega=False, samples=2)
    batch_table = batch._replace(reduction="table")
    table = aj.build_table(mech, g, ())
    q0s = jnp.asarray(np.linspace(-0.5, 0.5, 10_000))
    qs = jnp.asarray(np.linspace(0.0, 2 * np.pi, 100_000))
    run = lambda m, q0, s, tab=None: simulate_core(m, g, (), q0, 0.0, 0.0, 2.0, settings=s, table=tab)  # noqa: E731
    states = (q0s, jnp.ones_like(q0s), jnp.zeros_like(q0s))
    leg = aj.load_scene("strandbeest")
    beest = aj.Model(leg.mechanism, leg.gravity, tuple(leg.loads) + frictions(leg.mechanism))
    rough = lean._replace(rtol=1e-8, atol=1e-8, standstill=False)  # as bench_friction.py's runs
    return {
        "simulate, scene events and outputs": (lambda m, q0: run(m, q0, full), (mech, jnp.asarray(0.0))),
        "simulate core, lean": (lambda m, q0: run(m, q0, lean).q, (mech, jnp.asarray(0.0))),
        "10 000 simulations, exact": (lambda m, q0: jax.vmap(lambda q: run(m, q, batch).q_final)(q0), (mech, q0s)),
        "10 000 simulations, table": (lambda m, q0: jax.vmap(lambda q: run(m, q, batch_table, table).q_final)(q0), (mech, q0s)),
        "kinematics of 100 000 q (order 2)": (lambda m, q: aj.kinematics(m, q, check=False).points, (mech, qs)),
        "reactions of 10 000 states": (lambda q, w, a: aj.reactions(scene, (q, w, a), check=False).driving, states),
        "gradient of theta(2 s) wrt the mechanism": (jax.grad(lambda m: run(m, jnp.asarray(0.0), lean).q_final, allow_int=True), (mech,)),
        "strandbeest, friction in its 73 joints, 0.2 s": (
            lambda m, q0: simulate_core(m, q0=q0, omega0=leg.state["omega0"], t1=0.2, settings=rough).q,
            (beest, jnp.asarray(float(leg.state["q0"])))),
    }


def measure(fn, args, options):
    lowered = jax.jit(fn).lower(*args)
    t0 = time.perf_counter()
    compiled = lowered.compile(compiler_options=options)
    compile_s = time.perf_counter() - t0
    out = compiled(*args)
    return compile_s, best_time(lambda: compiled(*args)), out


def max_difference(*outs) -> float:
    """Largest difference between the floating-point outputs of the first compile and the others."""
    first = jax.tree.leaves(outs[0])
    pairs = [(np.asarray(x), np.asarray(y)) for other in outs[1:] for x, y in zip(first, jax.tree.leaves(other))]
    return float(max(np.max(np.abs(x - y), initial=0.0) for x, y in pairs if np.issubdtype(x.dtype, np.floating)))


def main():
    results = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                                load_average=os.getloadavg()), options=COMPILER_OPTIONS, programs=[])
    for name, (fn, args) in programs().items():
        row = dict(program=name)
        outs = []
        for label, options in (("default", {}), ("legacy emitters", EMITTERS), ("assurjax", COMPILER_OPTIONS)):
            compile_s, run_s, out = measure(fn, args, options)
            row[label] = dict(compile_s=compile_s, run_s=run_s)
            outs.append(out)
        row["max_abs_difference"] = max_difference(*outs)
        results["programs"].append(row)
        d, e, a = row["default"], row["legacy emitters"], row["assurjax"]
        print(f"{name}: compile {d['compile_s']:.2f} / {e['compile_s']:.2f} / {a['compile_s']:.2f} s, run "
              f"{1e3 * d['run_s']:.3f} / {1e3 * e['run_s']:.3f} / {1e3 * a['run_s']:.3f} ms (default / legacy emitters / "
              f"assurjax), outputs differ by {row['max_abs_difference']:.1e}", flush=True)
    out = HERE / "results" / "compile_options.json"
    out.write_text(json.dumps(results, indent=1))
    print(f"saved {out}")


if __name__ == "__main__":
    main()
