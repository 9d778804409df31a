"""Profile of the hot path: where the time of one integration step goes.

For the Watt six-bar of seed 000 this measures, each in its own jitted loop of many
iterations (so dispatch is excluded):

- the pieces of one right-hand-side evaluation: the position analysis alone, with its
  first-order jvp (kinematic coefficients), with the second-order jvp and the
  reduction (the exact right-hand side), and the tabulated right-hand side;
- one step of diffrax's Tsit5 / Dopri5 / Dopri8 (``solver.step`` in a lax.scan) with a
  trivial right-hand side (the integrator's own work per step), with the tabulated
  and with the exact right-hand side;
- one step of the adaptive loop (diffeqsolve with the PID controller) with the trivial
  right-hand side: the controller's and the loop's own cost per step.

From these: the share of a step spent in the position analysis, in the jvps, and in
the integrator. Saves benchmarks/results/profile.json. Run: python benchmarks/bench_profile.py
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp

import assurjax as aj
from _timing import best_time
from assurjax.dynamics._field import State, field_args, vector_field

HERE = Path(__file__).resolve().parent
LOOP = 20_000  # evaluations per timed loop
STEPS = 2_000  # integration steps per timed scan
SOLVERS = {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8}




def per_evaluation(f) -> float:
    """Seconds per call of f(q) -> scalar, in a fori_loop whose carry depends on it
    (so nothing is hoisted out of the loop)."""

    @aj.jit
    def loop(q):
        return jax.lax.fori_loop(0, LOOP, lambda i, q: q + 1e-9 * f(q) + 1e-6, q)

    return best_time(lambda: loop(jnp.asarray(0.3))) / LOOP


def per_step(solver, term, args) -> float:
    """Seconds per step of solver.step over STEPS fixed steps of 1e-3 s."""

    @aj.jit
    def scan(q0):
        h, y0 = 1e-3, State(q0, jnp.zeros(()))
        state = solver.init(term, 0.0, h, y0, args)

        def body(carry, k):
            y, state = carry
            y1, _, _, state, _ = solver.step(term, k * h, k * h + h, y, args, state, False)
            return (y1, state), None

        return jax.lax.scan(body, (y0, state), jnp.arange(STEPS))[0][0][0]

    return best_time(lambda: scan(jnp.asarray(0.3))) / STEPS


def adaptive_per_step(solver, term) -> tuple[float, int]:
    """Seconds per accepted-or-rejected step of diffeqsolve with the PID controller."""

    @aj.jit
    def solve(q0):
        sol = diffrax.diffeqsolve(term, solver, 0.0, 200.0, None, State(q0, jnp.zeros(())), saveat=diffrax.SaveAt(t1=True),
                                  stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-8), max_steps=100_000)
        return sol.ys.q, sol.stats["num_steps"]

    steps = int(solve(jnp.asarray(0.3))[1])
    return best_time(lambda: solve(jnp.asarray(0.3))) / steps, steps


def main():
    scene = aj.load_scene("watt_sixbar")
    mech, gravity = scene.mechanism, scene.gravity
    def coords(q):  # q -> (points, coms, angles), ok: what the reduction differentiates
        pose = aj.positions(mech, q)
        return (pose.points, pose.coms, pose.angles), pose.ok

    table = aj.build_table(mech, gravity, ())
    args = field_args(aj.Model(mech, gravity))
    table_args = field_args(aj.Model(mech, gravity), table)

    def first_order(q):
        x, dx, _ = jax.jvp(coords, (q,), (jnp.ones_like(q),), has_aux=True)
        return sum(jnp.sum(leaf) for leaf in jax.tree.leaves(dx))

    def positions(q):  # every output, so that none is optimized away
        return sum(jnp.sum(leaf) for leaf in jax.tree.leaves(coords(q)[0]))

    rhs = {
        "positions only": positions,
        "positions + first-order jvp": first_order,
        "exact right-hand side (second-order jvp + reduction)": lambda q: vector_field(0.0, State(q, 1.0), args).omega,
        "tabulated right-hand side": lambda q: vector_field(0.0, State(q, 1.0), table_args).omega,
    }
    out = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__, load_average=os.getloadavg()),
               per_evaluation_us={k: 1e6 * per_evaluation(f) for k, f in rhs.items()})
    trivial = diffrax.ODETerm(lambda t, y, a: State(y.omega, -jnp.sin(y.q)))
    terms = {"trivial": (trivial, None), "table": (diffrax.ODETerm(vector_field), table_args), "exact": (diffrax.ODETerm(vector_field), args)}
    out["per_step_us"] = {f"{s} {k}": 1e6 * per_step(cls(), *terms[k]) for s, cls in SOLVERS.items() for k in terms}
    seconds, steps = adaptive_per_step(diffrax.Tsit5(), trivial)
    out["adaptive_tsit5_trivial_per_step_us"] = 1e6 * seconds
    step = out["per_step_us"]
    ev = out["per_evaluation_us"]
    exact, rhs_exact = step["tsit5 exact"], ev["exact right-hand side (second-order jvp + reduction)"]
    out["tsit5_exact_step_shares"] = dict(
        position_analysis=6 * ev["positions only"] / exact,
        jvps_and_reduction=6 * (rhs_exact - ev["positions only"]) / exact,
        integrator_and_loop=1.0 - 6 * rhs_exact / exact,
        note="Tsit5 evaluates the right-hand side 6 times per step (FSAL); the right-hand side timed alone; "
             "the rest of the step is the integrator's own work and the stage loop",
    )
    path = HERE / "results" / "profile.json"
    path.write_text(json.dumps(out, indent=2))
    for k, v in ev.items():
        print(f"{k:55s} {v:8.3f} us / evaluation")
    for k, v in step.items():
        print(f"step {k:50s} {v:8.3f} us")
    print(f"adaptive Tsit5 loop, trivial right-hand side: {out['adaptive_tsit5_trivial_per_step_us']:.3f} us / step")
    shares = out["tsit5_exact_step_shares"]
    print("Tsit5 step with the exact reduction: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in shares.items() if k != "note"))
    print(f"saved {path}")


if __name__ == "__main__":
    main()
