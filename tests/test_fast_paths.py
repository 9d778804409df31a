"""The fast paths of simulate: fixed steps by lax.scan over the solver's own step
(``steps=``), batches of starting states (array ``q0``) and the automatic choice of
the tabulated reduction for them. Checked against the joint-based reference, the
closed-form limit angle of a non-Grashof four-bar, and single runs."""

import os

import numpy as np
import pytest

import assurjax as aj
from assurjax.dynamics._results import LOCKUP, NO_EVENT

import joint_reference as ref

T1 = 1.0


@pytest.fixture(scope="module")
def watt():
    return aj.load_scene("watt_sixbar")


@pytest.fixture(scope="module")
def table(watt):
    return aj.build_table(watt.mechanism, watt.gravity, watt.loads)


@pytest.fixture(scope="module")
def joint():
    """The joint-based reference from rest at theta2 = 0, at every 1/40 s of [0, 1]."""
    return ref.watt_sixbar(0.0).simulate(T1, t_eval=np.linspace(0.0, T1, 41))


def _steps_error(watt, joint, steps, **kw):
    sol = aj.simulate(watt, stop=None, t1=T1, solver="dopri8", steps=steps, points=(), angles=(), energies=False, **kw)
    stride = 40 // steps
    return sol, np.max(np.abs(sol.q - joint.q[::stride]))


# in the slow suite (~11 s each; fixed steps stay checked by default in test_dynamics.py's orders, the
# table against the reference in test_table.py): the default suite keeps to 10 min
@pytest.mark.slow
@pytest.mark.parametrize("reduction", ["exact", "table"])
def test_fixed_steps_converge_with_order_eight(watt, table, joint, reduction):
    """Dopri8 steps: errors against the joint reference fall by at least 2^6 per
    halving of the step (order 8) and 40 steps are within 1e-9 rad."""
    extra = dict(table=table) if reduction == "table" else dict(reduction="exact")
    errors = [_steps_error(watt, joint, n, **extra)[1] for n in (10, 20, 40)]
    assert errors[0] / errors[1] > 2**6
    assert errors[2] < 1e-9


def test_fixed_steps_solution_fields(watt, table, joint):
    sol, _ = _steps_error(watt, joint, 20, table=table)
    np.testing.assert_allclose(sol.t, np.linspace(0.0, T1, 21), atol=1e-14)
    assert sol.status.startswith("reached t1") and sol.t_stop is None and sol.valid.all()
    np.testing.assert_allclose(sol.omega, joint.w[::2], atol=1e-7)


def test_fixed_steps_refuse_events(watt):
    with pytest.raises(aj.AssurjaxError, match="stop=None"):
        aj.simulate(watt, steps=20)  # the scene asks to stop at standstill
    with pytest.raises(aj.AssurjaxError, match="positive"):
        aj.simulate(watt, stop=None, steps=0)
    with pytest.raises(aj.AssurjaxError, match="ReducedTable"):
        aj.simulate(watt, stop=None, table=np.zeros((8, 6)))


def _non_grashof():
    """Crank 1, coupler 1, rocker 0.5, ground 1.8 (m): the crank swings in |q| <= q_lim."""
    tables = aj._examples.n_four_bar_dict(1)
    tables["ground"]["O1"] = [1.8, 0.0]
    for link, length in (("rocker0", 1.0), ("coupler0", 1.0), ("rocker1", 0.5)):
        a, b = tables["links"][link]["points"]
        tables["links"][link] = dict(points={a: [0.0, 0.0], b: [length, 0.0]}, com=[length / 2, 0.0], mass=length,
                                     inertia=length**3 / 12)
    tables["state"].update(q0=0.5, omega0=3.0, t1=1.0)
    return aj.scene_from_dict(tables)


def test_fixed_steps_stop_at_lock_up():
    """Driven into its limit position (closed form |A - O1| = coupler + rocker), the
    fixed-step run ends its valid samples at the last assembled step before the limit,
    names the dyad, and has no NaN."""
    scene = _non_grashof()
    q_lim = np.arccos((1.0 + 1.8**2 - 1.5**2) / (2 * 1.8))
    sol = aj.simulate(scene, stop=None, steps=200, energies=False)
    assert sol.event == LOCKUP and sol.failed_group == "window0"
    assert np.isfinite(sol.q).all() and np.isfinite(sol.omega).all()
    assert sol.q.max() <= q_lim and sol.q[-1] > q_lim - 0.05  # within a step of the limit
    assert np.all(np.diff(sol.t) > 0)


@pytest.mark.slow  # ~9 s; batches equal single runs by default in test_batch_with_fixed_steps_equals_single_runs and test_dynamics.py
def test_small_batch_equals_single_runs(watt):
    """Fewer than AUTO_TABLE_BATCH starting states: the exact reduction, and every member
    equals its own single run."""
    q0 = np.array([0.0, 0.6, -1.2])
    kw = dict(stop=None, t1=T1, samples=11, points=(), angles=(), energies=False)
    batch = aj.simulate(watt, q0=q0, **kw)
    assert batch.q.shape == (3, 11) and batch.status == "batch of 3: 3 reached t1"
    for k, start in enumerate(q0):
        single = aj.simulate(watt, q0=start, **kw)
        np.testing.assert_allclose(batch.q[k], single.q, atol=1e-12)


def test_large_batch_uses_the_table_and_matches_the_reference(watt):
    """A batch of 64 starting angles at tight tolerance (tabulated automatically) against
    the joint-based reference for three of them; and a batch stopping at standstill."""
    q0 = np.linspace(-3.0, 3.0, aj.dynamics._solve.AUTO_TABLE_BATCH)
    ts = np.linspace(0.0, T1, 11)
    batch = aj.simulate(watt, q0=q0, stop=None, t1=T1, saveat=ts, rtol=1e-11, atol=1e-11, max_steps=20000,
                        points=(), angles=(), energies=False)
    assert np.all(batch.event == NO_EVENT) and batch.valid.all()
    for k in (0, 21, 63):
        r = ref.watt_sixbar(float(q0[k])).simulate(T1, t_eval=ts)
        np.testing.assert_allclose(batch.q[k], r.q, atol=2e-9)
        np.testing.assert_allclose(batch.omega[k], r.w, atol=2e-8)


def test_batch_shape_errors(watt):
    with pytest.raises(aj.AssurjaxError, match="broadcast"):
        aj.simulate(watt, q0=np.zeros(3), omega0=np.zeros(4))
    with pytest.raises(aj.AssurjaxError, match="1-D"):
        aj.simulate(watt, q0=np.zeros((2, 2)))


def test_fixed_steps_outputs_conserve_energy(watt, table):
    """Outputs along fixed steps: with no dissipation the total energy stays constant to
    the integration error (Tsit5, 80 steps over 1 s, with the table)."""
    sol = aj.simulate(watt, stop=None, t1=T1, steps=80, table=table, energies=True, points=("E",), angles=())
    assert sol.points["E"].shape == (81, 2) and sol.dissipated is None
    assert np.ptp(sol.total) < 1e-6 * np.max(np.abs(sol.kinetic))


def test_batch_with_fixed_steps_equals_single_runs(watt, table):
    q0 = np.array([0.0, 1.0])
    kw = dict(stop=None, t1=T1, steps=20, table=table, points=(), angles=(), energies=False)
    batch = aj.simulate(watt, q0=q0, **kw)
    for k, start in enumerate(q0):
        np.testing.assert_allclose(batch.q[k], aj.simulate(watt, q0=start, **kw).q, atol=1e-12)


def test_saveat_errors_name_the_field(watt):
    for saveat, message in (([0.0, 0.5, 0.2], "direction from t0 to t1"), ([0.0, 3.0], "between t0"),
                            ([[0.0, 1.0]], "1-D"), ([0.0, np.nan], "finite")):
        with pytest.raises(aj.AssurjaxError, match=message):
            aj.simulate(watt, saveat=saveat, t1=2.0)


def test_simulate_is_kept_by_the_persistent_cache(tmp_path):
    """simulate() compiles without host callbacks, so JAX's on-disk cache stores its program
    (with diffrax's own saveat checks as callbacks it wrote nothing). In a fresh process: the
    cache is global to a process."""
    import subprocess
    import sys

    code = (
        "import assurjax as aj\n"
        f"aj.enable_compilation_cache({str(tmp_path)!r})\n"
        "aj.simulate(aj.load_scene('watt_sixbar'), stop=None, t1=0.5, samples=5)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "ASSURJAX_NO_CACHE"}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, capture_output=True)
    assert any(tmp_path.iterdir()), "no compiled program was written to the cache"
