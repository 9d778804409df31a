"""Where a step with friction goes beyond a frictionless one: the bundled press's step with
parts of the friction solve replaced by cheaper stand-ins, each against the frictionless step.

The issue's target is a step with friction at most 2x a frictionless one (not met: 2.4-2.5x).
The stand-ins are cost probes, not methods: most give a wrong motion (their final q is saved
beside them), and none is in the package. They bound what any formulation of the same exact
law can save:

- ``shipped``: the package as it is (the fixed-point iteration, optimistix; its consistency
  bound; the fallback's cond in the field).
- ``law once``: no iteration, u = law(0) (the statics, rates and bound stay): the step's
  floor with the iteration free.
- ``law once, no bound``: also without the consistency bound (the field's cond stays).
- ``no statics, law once, no bound``: also the statics' values replaced by zeros (XLA drops
  the statics; u = law(0) is then the viscous part): what the friction costs around its
  solve (the elements' rates and their integrated slopes, the Coulomb-switch events, the
  segments' loop, the fallback's cond), the floor of any formulation that keeps them.
- ``law 6x unrolled``: six evaluations of the law in straight-line code from law(0), no
  convergence test: about what the iteration needs at the default tolerance, without a loop.
- ``chord start``: the iteration from one chord step (the law's Jacobian at law(0), its
  inverse by a Neumann series to second order): fewer iterations, each start dearer.
- ``tolerance = rtol``: the iteration's tolerance the integration's own (diffrax's default for
  its implicit solvers), instead of 1e-2 of it.

Each variant in a fresh process, its step and the frictionless step measured in turns there
(``bench_friction.interleaved_marginal_per_step``: the median of the rounds' ratios is the
figure; the machine's load moves both alike).

    python benchmarks/bench_friction_step_parts.py [--repeats 2] [--out FILE]

Writes results/friction_step_parts.json unless told otherwise. With ``--rhs``, the same floors
on one right-hand side (``bench_friction.per_serial_evaluation``: evaluations one after another
in one program, as a step's stages call them) of the slider-crank, the Watt six-bar, the press
and the strandbeest with friction in every pair, each variant's against the frictionless one
measured in turns in one process (the median of the rounds' ratios); writes
results/friction_rhs_parts.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

HERE = Path(__file__).resolve().parent
VARIANTS = ("shipped", "law once", "law once, no bound", "no statics, law once, no bound", "law 6x unrolled",
            "chord start", "tolerance = rtol")

CHILD = r"""
import json, sys
import numpy as np
import assurjax
import bench_friction_step_parts as parts
from bench_friction import interleaved_marginal_per_step

variant = sys.argv[1]
parts.apply(variant)
press = assurjax.load_scene("press_with_friction")
plain = tuple(load for load in press.loads if not load.needs_reactions)
r = interleaved_marginal_per_step(press, dict(plain=plain, friction=press.loads))
q_end = float(np.asarray(assurjax.simulate(press, stop=None, t1=2.0, samples=2).q_final))
print(json.dumps(dict(plain_us=r["plain"]["us_per_step"], friction_us=r["friction"]["us_per_step"],
                      ratio=r["friction_ratio"]["median"], quartiles=r["friction_ratio"]["quartiles"],
                      steps=r["friction"]["steps"], q_end_2s=q_end)))
"""


RHS_VARIANTS = ("shipped", "law once, no bound", "no statics, law once, no bound")
RHS_SCENES = ("slider_crank", "watt_sixbar", "press_with_friction", "strandbeest")

RHS_CHILD = r"""
import json, sys
import numpy as np
import assurjax
import bench_friction_step_parts as parts
from bench_friction import frictions, per_serial_evaluation

name, variant = sys.argv[1].split(":")
parts.apply(variant)
scene = assurjax.load_scene(name)
plain = tuple(load for load in scene.loads if not load.needs_reactions)
rough = scene.loads if len(plain) < len(scene.loads) else scene.loads + frictions(scene.mechanism)
n = 200 if name == "strandbeest" else 1000
times = {"plain": [], "friction": []}
for _ in range(7):
    for key, loads in (("plain", plain), ("friction", rough)):
        times[key].append(1e6 * per_serial_evaluation(scene, loads, n=n))
ratios = np.asarray(times["friction"]) / np.asarray(times["plain"])
print(json.dumps(dict(elements=len(rough) - len(plain), plain_us=min(times["plain"]), friction_us=min(times["friction"]),
                      ratio=float(np.median(ratios)), quartiles=[float(np.percentile(ratios, 25)), float(np.percentile(ratios, 75))])))
"""


def apply(variant: str) -> None:
    """Replace the part of the friction solve that ``variant`` leaves out (see the module docstring)."""
    import jax
    import jax.numpy as jnp
    import optimistix as optx

    from assurjax import _friction
    from assurjax.dynamics import _field

    if variant == "shipped":
        return
    if variant == "tolerance = rtol":  # iteration_tolerance reads the fraction at each call
        _friction.INTEGRATION_FRACTION = 1.0
        return

    def iterate(mechanism, frictions, reactions, kin, rates, signs, omega, *, inertial=None,
                tolerance=_friction.FIXED_POINT_TOLERANCE):
        law = _friction._law(mechanism, frictions, reactions, kin, rates, signs, omega)
        u0 = law(jnp.zeros(len(frictions)))
        value, converged = u0, jnp.array(True)
        if variant == "law 6x unrolled":
            for _ in range(6):
                value = law(value)
        elif variant == "chord start":
            jacobian, residual = jax.jacfwd(law)(u0), law(u0) - u0
            once = jacobian @ residual
            # the iterate as K scalars, as shipped (_friction.iterate_friction)
            split, join = (tuple, jnp.stack) if len(frictions) <= _friction.SUMMED_TERMS else (jnp.asarray,) * 2
            fixed = optx.fixed_point(lambda u, _: split(law(join(u))),
                                     optx.FixedPointIteration(rtol=tolerance, atol=tolerance),
                                     split(u0 + residual + once + jacobian @ once),
                                     max_steps=_friction.FIXED_POINT_STEPS, throw=False)
            value, converged = join(fixed.value), fixed.result == optx.RESULTS.successful
        settled = converged
        if not variant.endswith("no bound") and inertial is not None:  # as shipped: det(I - S) > 0 by a bound
            slopes = _friction._static_slopes(mechanism, kin, frictions, reactions, inertial, value)
            settled = converged & (_friction.spectral_bound(slopes) < 1.0)
        return _friction.FixedPoint(u0, value, converged, settled)

    if variant not in VARIANTS:
        raise SystemExit(f"unknown variant {variant!r}: one of {VARIANTS}")
    _friction.iterate_friction = _field.iterate_friction = iterate
    if variant.startswith("no statics"):
        statics = _field._linear_reactions

        def zero_statics(*args):  # the same structure, values that depend on nothing
            return jax.tree.map(jnp.zeros_like, statics(*args))

        _field._linear_reactions = zero_statics


def main():
    from bench_overhead import child_run

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=None)
    parser.add_argument("--rhs", action="store_true", help="the floors on one right-hand side of four mechanisms")
    args = parser.parse_args()
    if args.rhs:
        runs = {f"{name}:{variant}": [] for name in RHS_SCENES for variant in RHS_VARIANTS}
        for _ in range(args.repeats):
            for case, case_runs in runs.items():
                case_runs.append(child_run(RHS_CHILD, str(HERE.parent), case))
                print(case, json.dumps(case_runs[-1]), flush=True)
        result = dict(machine=platform.platform(), cpus=os.cpu_count(), variants=runs)
        with open(args.out or HERE / "results" / "friction_rhs_parts.json", "w") as f:
            json.dump(result, f, indent=1)
        return
    runs = {variant: [] for variant in VARIANTS}
    for _ in range(args.repeats):  # the variants in turns
        for variant in VARIANTS:
            runs[variant].append(child_run(CHILD, str(HERE.parent), variant))
            print(variant, json.dumps(runs[variant][-1]), flush=True)
    result = dict(machine=platform.platform(), cpus=os.cpu_count(), scene="press_with_friction", variants=runs)
    with open(args.out or HERE / "results" / "friction_step_parts.json", "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
