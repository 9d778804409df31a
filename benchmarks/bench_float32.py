"""float32 against float64: the error float32 gives, and what it saves.

Runs the same computations in a float32 process (ASSURJAX_FLOAT32=1) and here in
float64: the Watt six-bar's position and velocity analysis over 601 crank angles
(point E, against the independent float64 closed form of tests/joint_reference.py)
and 1 s of its motion from rest at theta2 = 0 (Tsit5, against a float64 run at
rtol = atol = 1e-13), with float32 tolerances 1e-3 .. 1e-6.

    python benchmarks/bench_float32.py

Writes benchmarks/results/float32.json and prints a table.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
import joint_reference as jr  # noqa: E402

SCRIPT = textwrap.dedent(
    """
    import json, sys, time
    sys.path.insert(0, {here!r})
    import jax, jax.numpy as jnp, numpy as np
    import assurjax
    from bench_work_precision import lean_runner, best_time
    scene = assurjax.load_scene("watt_sixbar")
    q = jnp.linspace(-3.0, 3.0, 601)
    kin = assurjax.kinematics(scene.mechanism, q, order=1)
    ts = jnp.asarray(np.round(np.arange(1, 11) * 0.1, 12))
    run = lean_runner(scene, "tsit5")
    sims = {{}}
    for tol in {tols!r}:
        a = (jnp.asarray(0.0), jnp.asarray(0.0), ts, jnp.asarray(tol), jnp.asarray(tol))
        out, steps, result = run(*a)
        sims[str(tol)] = dict(q=np.asarray(out, dtype=float).tolist(), steps=int(steps), result=int(result),
                              time=best_time(lambda: run(*a), 5))
    print(json.dumps(dict(dtype=str(kin.points["E"].dtype), E=np.asarray(kin.points["E"], dtype=float).tolist(),
                          vE=np.asarray(kin.velocities["E"], dtype=float).tolist(), sims=sims)))
    """
)


def run(float32: bool, tols) -> dict:
    env = dict(os.environ)
    if float32:
        env.update(ASSURJAX_FLOAT32="1", JAX_ENABLE_X64="0")
    out = subprocess.run([sys.executable, "-c", SCRIPT.format(here=str(HERE), tols=list(tols))], env=env, capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    tols32 = [1e-3, 1e-4, 1e-5, 1e-6]
    f32 = run(True, tols32)
    f64 = run(False, [1e-13] + tols32)
    q = np.linspace(-3.0, 3.0, 601)
    exact = np.array([jr.watt_sixbar_points(x)[0]["E"] for x in q])
    h = 1e-6
    v_exact = np.array([(jr.watt_sixbar_points(x + h)[0]["E"] - jr.watt_sixbar_points(x - h)[0]["E"]) / (2 * h) for x in q])
    ref = np.asarray(f64["sims"][str(1e-13)]["q"])
    rows = dict(
        dtype32=f32["dtype"],
        position_error_32=float(np.abs(np.asarray(f32["E"]) - exact).max()),
        position_error_64=float(np.abs(np.asarray(f64["E"]) - exact).max()),
        velocity_error_32=float(np.abs(np.asarray(f32["vE"]) - v_exact).max()),
        velocity_error_64_vs_central_differences=float(np.abs(np.asarray(f64["vE"]) - v_exact).max()),
        simulation=[dict(tol=tol, error_32=float(np.abs(np.asarray(f32["sims"][str(tol)]["q"]) - ref).max()),
                         steps_32=f32["sims"][str(tol)]["steps"], time_32_s=f32["sims"][str(tol)]["time"],
                         error_64=float(np.abs(np.asarray(f64["sims"][str(tol)]["q"]) - ref).max()),
                         steps_64=f64["sims"][str(tol)]["steps"], time_64_s=f64["sims"][str(tol)]["time"],
                         result_32=f32["sims"][str(tol)]["result"]) for tol in tols32],
    )
    print(f"point E over 601 angles: float32 error {rows['position_error_32']:.2e} m, float64 {rows['position_error_64']:.2e} m")
    print(f"velocity of E: float32 error {rows['velocity_error_32']:.2e} m/s (float64 vs central differences {rows['velocity_error_64_vs_central_differences']:.1e})")
    print(f"{'tol':>8s} {'err32 (rad)':>12s} {'steps32':>8s} {'ms32':>7s} {'err64 (rad)':>12s} {'steps64':>8s} {'ms64':>7s}")
    for r in rows["simulation"]:
        print(f"{r['tol']:8.0e} {r['error_32']:12.2e} {r['steps_32']:8d} {1e3 * r['time_32_s']:7.3f} {r['error_64']:12.2e} {r['steps_64']:8d} {1e3 * r['time_64_s']:7.3f}")
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "float32.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
