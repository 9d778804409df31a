"""Quick check (not a test): MuJoCo models against the independent joint reference.

    python3 benchmarks/check_mujoco.py
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mujoco_models as mm  # noqa: E402
from mujoco_models import jr  # noqa: E402


def watt(t1=1.0, theta0=0.0, omega0=0.0):
    t0 = time.perf_counter()
    ref = jr.watt_sixbar(theta0, omega0).simulate(t1, t_eval=np.linspace(0, t1, 1001))
    print(f"Watt six-bar, {t1} s from theta2 = {theta0}, w = {omega0}; "
          f"reference {time.perf_counter() - t0:.2f} s, energy drift {np.ptp(ref.E):.1e} J")
    worst = {}
    for integrator in ("RK4", "implicitfast"):
        for dt in (1e-3, 1e-4):
            xml = mm.watt_sixbar_xml(dt=dt, integrator=integrator)
            t0 = time.perf_counter()
            t, th = mm.simulate_mujoco(xml, theta0, t1, dt, integrator, omega0=omega0)
            el = time.perf_counter() - t0
            err = np.abs(np.interp(ref.t, t, th) - ref.q).max()
            worst[integrator, dt] = err
            print(f"  {integrator:12s} dt={dt:g}: max |theta2 - ref| = {err:.2e} rad  ({el:.2f} s)")
    return worst


def n_four_bar(N, t1=10.0):
    print(f"N-four-bar N={N}, {t1} s, exact elliptic solution")
    for integrator, dt in (("RK4", 1e-3), ("RK4", 1e-4), ("implicitfast", 1e-4)):
        xml = mm.n_four_bar_xml(N, dt=dt, integrator=integrator)
        t0 = time.perf_counter()
        t, th = mm.simulate_mujoco(xml, np.pi / 2, t1, omega0=-1.0)
        el = time.perf_counter() - t0
        err = np.abs(th - jr.n_four_bar_exact(N, t)[0]).max()
        print(f"  {integrator:12s} dt={dt:g}: max |theta - exact| = {err:.2e} rad  ({el:.2f} s)")


if __name__ == "__main__":
    worst = watt()
    watt(1.0, 2.5, 3.0)
    for N in (1, 10):
        n_four_bar(N)
    assert worst["RK4", 1e-4] < 1e-3, worst
