"""The tabulated reduced model (assurjax._table): interpolation error against the
exact reduction with an h^4 bound, simulations against the exact mode and the
joint-based reference, energy balance, and the clear errors where a table is invalid.
The tables are built once per module (one compile per grid size)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj

import joint_reference as ref

TIGHT = dict(rtol=1e-12, atol=1e-12, max_steps=20000, check_assembly=False)
TS = np.linspace(0.0, 2.0, 21)
COARSE = 1024  # a second grid for the convergence order


@pytest.fixture(scope="module")
def watt():
    return aj.load_scene("watt_sixbar")


@pytest.fixture(scope="module")
def tables(watt):
    """The default grid, and every 4th of its nodes as a coarse grid (one build, one compile)."""
    n = aj.SimulationSettings().table_nodes
    fine = aj.build_table(watt.mechanism, watt.gravity, watt.loads, n)
    step = n // COARSE
    return {n: fine, COARSE: aj.ReducedTable(data=fine.data[::step], ok=fine.ok[::step])}


@pytest.fixture(scope="module")
def off_grid(watt):
    """Random angles over two turns (so the wrap-around is exercised) and the exact reduction there."""
    q = np.random.default_rng(7).uniform(-2 * math.pi, 2 * math.pi, 1500)
    red = aj.reduce(watt, q)
    return q, np.stack([red.inertia, red.dinertia, red.torque + red.effort], axis=-1)


def _interpolate(table, q):
    return np.stack(jax.vmap(table)(jnp.asarray(q)), axis=-1)


def _hermite_bound(table):
    """h^4 / 384 max|f''''| per quantity, with f'''' estimated from the tabulated
    derivatives f' by a periodic third difference (f'''' ~ delta^3 f' / h^3)."""
    n = table.nodes
    h = 2 * math.pi / n
    slopes = np.asarray(table.data[:, 3:])
    third = np.roll(slopes, -2, 0) - 3 * np.roll(slopes, -1, 0) + 3 * slopes - np.roll(slopes, 1, 0)
    return h**4 / 384 * np.max(np.abs(third), axis=0) / h**3


def test_interpolation_error_is_within_the_hermite_bound(tables, off_grid):
    q, exact = off_grid
    for table in tables.values():
        err = np.max(np.abs(_interpolate(table, q) - exact), axis=0)
        bound = _hermite_bound(table)
        assert np.all(err <= 2.0 * bound + 1e-14 * np.max(np.abs(exact), axis=0)), (table.nodes, err, bound)
    # The default grid: ~1e-10 relative or better for all three functions.
    default = tables[aj.SimulationSettings().table_nodes]
    rel = np.max(np.abs(_interpolate(default, q) - exact), axis=0) / np.max(np.abs(exact), axis=0)
    assert np.all(rel < 3e-10), rel


def test_interpolation_converges_at_fourth_order(tables, off_grid):
    q, exact = off_grid
    coarse, fine = (np.max(np.abs(_interpolate(tables[n], q) - exact), axis=0) for n in sorted(tables))
    ratio = coarse / fine
    expected = (max(tables) / min(tables)) ** 4  # 256 for 1024 -> 4096
    assert np.all(ratio > expected / 3) and np.all(ratio < expected * 3), ratio


def test_table_matches_exact_at_nodes(tables, watt):
    """At the nodes the table holds the exact values and the central-difference derivatives."""
    table = tables[COARSE]
    k = np.array([0, 17, 300, 777])
    q = 2 * math.pi * k / COARSE
    red = aj.reduce(watt, q)
    exact = np.stack([red.inertia, red.dinertia, red.torque + red.effort], axis=-1)
    np.testing.assert_allclose(np.asarray(table.data[k, :3]), exact, rtol=1e-13, atol=1e-13)
    eps = 1e-5
    hi, lo = aj.reduce(watt, q + eps), aj.reduce(watt, q - eps)
    fd = np.stack([(a - b) / (2 * eps) for a, b in ((hi.inertia, lo.inertia), (hi.dinertia, lo.dinertia), (hi.torque, lo.torque))], axis=-1)
    np.testing.assert_allclose(np.asarray(table.data[k, 3:]), fd, rtol=1e-7, atol=1e-7)


@pytest.fixture(scope="module")
def watt_runs(watt):
    kw = dict(q0=0.6, stop=None, t1=2.0, saveat=TS, energies=True, **TIGHT)
    return aj.simulate(watt, reduction="table", **kw), aj.simulate(watt, **kw), ref.watt_sixbar(0.6).simulate(2.0, t_eval=TS)


def test_table_mode_matches_exact_and_joint_reference(watt_runs):
    table, exact, reference = watt_runs
    assert table.status.startswith("reached t1")
    np.testing.assert_allclose(table.q, exact.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(table.q, reference.q, rtol=0, atol=1e-8)
    np.testing.assert_allclose(table.omega, reference.w, rtol=0, atol=1e-8)
    np.testing.assert_allclose(table.domega, reference.wdot, rtol=0, atol=1e-7)


def test_table_mode_conserves_energy(watt_runs):
    table, _, reference = watt_runs
    scale = np.max(np.abs(table.potential - table.potential[0]))  # energy exchanged during the motion
    assert np.max(np.abs(table.total - table.total[0])) < 1e-9 * scale
    np.testing.assert_allclose(table.kinetic, reference.T, rtol=0, atol=1e-8 * scale)


def test_batch_with_one_table_matches_single_runs(watt, tables):
    """A batch over q0 with a table built once, outside the vmap, against the joint reference."""
    settings = aj.SimulationSettings(reduction="table", rtol=1e-11, atol=1e-11, samples=2, domega=False, check_assembly=False)
    table = tables[settings.table_nodes]
    core = eqx.filter_jit(eqx.filter_vmap(
        lambda q0: aj.simulate_core(watt.mechanism, watt.gravity, (), q0, 0.0, 0.0, 0.5, settings=settings, table=table)))
    q0 = np.array([0.0, 1.0, -2.0])
    sols = core(jnp.asarray(q0))
    for k, theta0 in enumerate(q0):
        r = ref.watt_sixbar(theta0).simulate(0.5, t_eval=[0.0, 0.5])
        assert abs(float(sols.q[k, -1]) - r.q[-1]) < 1e-8


# ----------------------------------------------------------------------------- clear errors


def _bar(a, b, length, mass=1.0):
    return dict(points={a: [0.0, 0.0], b: [length, 0.0]}, com=[length / 2, 0.0], mass=mass, inertia=mass * length**2 / 12)


def non_grashof_four_bar():
    """Links 2, 3, 4 = 1.0, 0.6, 0.8 on a 1.0 base: s + l = 1.6 > p + q = 1.4 and the
    crank is not the shortest link, so it cannot turn fully (a triple rocker)."""
    return aj.scene_from_dict(dict(
        scene=dict(name="triple_rocker", gravity=[0.0, -9.81]),
        ground=dict(O2=[0.0, 0.0], O4=[1.0, 0.0]),
        links=dict(crank=_bar("O2", "A", 1.0), coupler=_bar("A", "B", 0.6), rocker=_bar("O4", "B", 0.8)),
        formation=[
            dict(group="crank", name="crank", link="crank", pivot="O2"),
            dict(group="RRR", name="dyad", links=["coupler", "rocker"], joints=["A", "O4", "B"], mode="left"),
        ],
        state=dict(q0=0.5),
    ))


def test_crank_that_cannot_turn_fully_is_a_clear_error():
    scene = non_grashof_four_bar()
    with pytest.raises(aj.AssurjaxError, match=r"group 'dyad' cannot assemble.*exact"):
        aj.simulate(scene, reduction="table", table_nodes=64)


def test_velocity_dependent_loads_are_a_clear_error(watt):
    with pytest.raises(aj.AssurjaxError, match=r"MotorLine.*driving velocity.*exact"):
        aj.simulate(watt, reduction="table", loads=[aj.MotorLine(1.0, 10.0)])


class LinearTorque(eqx.Module):
    """A user function a q + b t (N m): its arrays are traced, so both probes share one compile."""

    a: jax.Array
    b: jax.Array

    def __call__(self, q, omega, t):
        return self.a * q + self.b * t


def _drive(a, b):
    return [aj.Drive(LinearTorque(jnp.asarray(a), jnp.asarray(b)), velocity_dependent=False)]


def test_time_dependent_loads_are_a_clear_error(watt):
    with pytest.raises(aj.AssurjaxError, match=r"Drive load depends on time"):
        aj.simulate(watt, reduction="table", loads=[aj.Drive(aj.Polynomial([0.0, 1.0], variable="t"))])


@pytest.mark.slow  # ~17 s: a table compiled for each function (the default suite keeps to 10 min)
def test_functions_of_time_velocity_or_non_periodic_are_clear_errors(watt):
    # User functions flagged velocity-independent: their programs are read for t and omega
    with pytest.raises(aj.AssurjaxError, match=r"Drive load depends on time t"):
        aj.build_table(watt.mechanism, watt.gravity, _drive(0.0, 0.1), 16)
    with pytest.raises(aj.AssurjaxError, match=r"Drive load depends on the driving velocity"):
        aj.build_table(watt.mechanism, watt.gravity,
                       [aj.Drive(lambda q, w, t: 0.1 * w, velocity_dependent=False)], 16)
    with pytest.raises(aj.AssurjaxError, match=r"not 2 pi-periodic"):
        aj.build_table(watt.mechanism, watt.gravity, [aj.Drive(lambda q, w, t: 0.1 * q, velocity_dependent=False)], 16)
    # a function of q alone inside jit or checkpoint is read inside (it was blamed on omega)
    for wrap in (jax.jit, jax.checkpoint):
        q_only = wrap(lambda q, w, t: 0.1 * jnp.sin(q))
        assert aj.build_table(watt.mechanism, watt.gravity, [aj.Drive(q_only, velocity_dependent=False)], 16).data.shape == (16, 6)
    with pytest.raises(aj.AssurjaxError, match=r"Drive load depends on time t"):
        aj.build_table(watt.mechanism, watt.gravity,
                       [aj.Drive(jax.jit(lambda q, w, t: q * 0.0 + jnp.where(t > 0.5, 1.0, 0.0)), velocity_dependent=False)], 16)


def test_a_drive_switched_on_later_is_not_tabulated():
    """A drive that is 0 until t = 0.5 s (d/dt = 0 at t = 0, where a probe looked) was frozen
    at its t = 0 value by the table, which reduction='auto' picks for 64 starts or more: the
    slider-crank's crank at 0.51 rad after 1 s, 30.6 rad with the drive. The batch now runs
    on the exact reduction, and equals a single run; asked for, the table is refused."""
    scene = aj.load_scene("slider_crank").with_loads(
        (aj.Drive(lambda q, w, t: jnp.where(t > 0.5, 3.0, 0.0), velocity_dependent=False),))
    run = dict(omega0=1.0, t1=1.0, samples=2, stop=None)
    single = aj.simulate(scene, q0=0.5, **run)
    batch = aj.simulate(scene, q0=np.full(64, 0.5), **run)
    assert single.q[-1] > 20.0  # driven on after 0.5 s (undriven, the crank ends at 0.51 rad: the table's answer)
    np.testing.assert_allclose(batch.q[:, -1], single.q[-1], rtol=1e-6)
    with pytest.raises(aj.AssurjaxError, match=r"Drive load depends on time t"):
        aj.simulate(scene, q0=0.5, reduction="table", **run)


def test_build_table_checks_its_arguments(watt):
    """nodes = 2e6 took 2.4 GB, 8.9 was cut to 8, NaN gravity gave a table of NaN, an unknown
    link a raw KeyError."""
    m, g = watt.mechanism, watt.gravity
    for nodes in (2_000_000, 8.9, "abc", 4):
        with pytest.raises(aj.AssurjaxError, match=r"build_table: nodes: expected an integer from 8 to 1000000"):
            aj.build_table(m, g, (), nodes)
    for gravity, message in (([float("nan"), 0.0], "must be finite"), ([0.0, 0.0, 1.0], "must be a 2-vector")):
        with pytest.raises(aj.AssurjaxError, match=f"build_table: gravity {message}"):
            aj.build_table(m, gravity, (), 16)
    with pytest.raises(aj.MechanismError, match="unknown link 'foo'"):
        aj.build_table(m, g, (aj.Couple("foo", 1.0),), 16)


def test_unknown_reduction_is_a_clear_error(watt):
    with pytest.raises(aj.AssurjaxError, match=r"reduction must be 'exact', 'table' or 'auto'"):
        aj.simulate(watt, reduction="spline")


def test_slider_driver_is_a_clear_error():
    slider = aj.scene_from_dict(dict(
        scene=dict(name="slider_only"), ground=dict(G=[0.0, 0.0]),
        links=dict(block=dict(points=dict(P=[0.0, 0.0]), com=[0.0, 0.0], mass=1.0, inertia=0.0)),
        formation=[dict(group="slider", name="drive", link="block", point="P", guide_point="G", direction=[1.0, 0.0])],
    ))
    with pytest.raises(aj.AssurjaxError, match=r"needs a crank"):
        aj.build_table(slider.mechanism, slider.gravity, ())


def test_standstill_in_table_mode_matches_joint_reference(watt):
    sol = aj.simulate(watt, q0=0.0, stop="standstill", t1=5.0, reduction="table", **TIGHT)
    r = ref.watt_sixbar(0.0).simulate(5.0, standstill=0)
    assert sol.t_stop == pytest.approx(r.t_events[0], abs=1e-8)


def test_table_built_inside_the_core_is_differentiable(watt, watt_runs):
    """d q(2 s) / d m_3 through the traced table (forward mode) against central
    differences of the exact mode."""
    settings = aj.SimulationSettings(reduction="table", adjoint="forward", rtol=1e-12, atol=1e-12, max_steps=20000,
                                     samples=2, domega=False, check_assembly=False)
    with_mass = lambda m: eqx.tree_at(lambda mech: mech.links["link3"].mass, watt.mechanism, m)  # noqa: E731
    final_q = eqx.filter_jit(lambda m: aj.simulate_core(with_mass(m), watt.gravity, (), 0.6, 0.0, 0.0, 2.0, settings=settings).q[-1])
    m3 = watt.mechanism.links["link3"].mass
    _, dq_dm = jax.jvp(final_q, (jnp.asarray(m3),), (jnp.ones(()),))
    eps = 1e-4
    kw = dict(q0=0.6, stop=None, t1=2.0, saveat=TS, energies=True, **TIGHT)  # the settings of watt_runs: no new compile
    hi, lo = (aj.simulate(watt, mechanism=with_mass(m3 + s), **kw).q[-1] for s in (eps, -eps))
    assert float(dq_dm) == pytest.approx((hi - lo) / (2 * eps), rel=1e-5)


@pytest.mark.slow  # ~21 s: three tables compiled; the default suite keeps to 10 min
def test_a_table_given_to_simulate_must_be_the_scenes(watt, tables):
    """simulate(..., table=T) took any table as the whole reduced model: one built without
    gravity left the falling six-bar at rest ('reached t1', q = 0), one of the slider-crank
    moved it to -0.84 rad (-3.08 exact), a gravity override and reduction='exact' were
    ignored, and a scene's motor and friction dropped. Now each is refused by name."""
    table = tables[aj.SimulationSettings().table_nodes]
    run = dict(t1=0.2, stop=None, samples=2, energies=False, points=(), angles=())
    np.testing.assert_allclose(aj.simulate(watt, table=table, **run).q_final, aj.simulate(watt, **run).q_final, rtol=1e-7)
    slider = aj.load_scene("slider_crank")
    for given, kwargs in ((aj.build_table(watt.mechanism, nodes=64), {}),
                          (aj.build_table(slider.mechanism, slider.gravity, nodes=64), {}),
                          (table, dict(gravity=[0.0, 0.0]))):
        with pytest.raises(aj.AssurjaxError, match="table: it does not tabulate this scene's mechanism, gravity and loads"):
            aj.simulate(watt, table=given, **run, **kwargs)
    with pytest.raises(aj.AssurjaxError, match="give reduction='exact' or a table, not both"):
        aj.simulate(watt, table=table, reduction="exact", **run)
    with pytest.raises(aj.AssurjaxError, match="depend on the driving velocity"):
        aj.simulate(aj.load_scene("press_with_friction"), table=table, **run)


def test_the_table_checks_are_relative_to_the_mechanisms_own_size():
    """The slider-crank shrunk to L = 1e-3 (0.4 mm) and 1e-8 of its masses (torques ~1e-11 N m):
    the checks compared against 1 + the largest value, so a table built without gravity was
    taken (the crank stayed at q0 where it falls), and a linear torsion spring, not periodic
    by 3e-12 N m a turn, was tabulated. Both are refused now, as at full size."""
    import importlib.resources
    import tomllib

    text = (importlib.resources.files("assurjax") / "scenes" / "slider_crank.toml").read_text()
    data, length, mass = tomllib.loads(text), 1e-3, 1e-8
    data["ground"] = {k: [length * x for x in v] for k, v in data["ground"].items()}
    for link in data["links"].values():
        link["points"] = {k: [length * x for x in v] for k, v in link["points"].items()}
        link["com"] = [length * x for x in link["com"]]
        link["mass"] *= mass
        link["inertia"] *= mass * length**2
    small = aj.scene_from_dict(data, source="small slider-crank")
    with pytest.raises(aj.AssurjaxError, match="table: it does not tabulate this scene's mechanism, gravity and loads"):
        aj.simulate(small, table=aj.build_table(small.mechanism, None, small.loads, 64), t1=0.05, samples=2)
    spring = aj.Couple("crank", aj.Polynomial([0.0, -0.5 * mass * length], variable="q"))
    with pytest.raises(aj.AssurjaxError, match="not 2 pi-periodic"):
        aj.build_table(small.mechanism, small.gravity, [spring], 64)


def test_a_window_between_the_nodes_where_a_group_cannot_assemble_is_refused():
    """The bundled slider-crank with its guide 0.2 m + 1e-9 m off the pivot (the crank 0.1 m,
    rod 0.3 m: rod - crank = 0.2 m), tilted by pi / 4096 so that the window where the rod
    cannot reach (closed form: |offset - crank sin q| > rod, about 2.7e-4 rad round q = pi/2)
    falls between two of the 4096 nodes: every node assembles, and the table's runs went
    through the window. The squared singularity measure's cubic between the nodes dips below
    0 there: refused, naming the group. 1e-6 m the other way (it turns fully) is tabulated."""
    scene = aj.load_scene("slider_crank")
    tilt = np.pi / 4096
    guide = jnp.array([np.cos(tilt), np.sin(tilt)])
    short = eqx.tree_at(lambda m: (m.groups[1].offset, m.groups[1].direction), scene.mechanism, (-(0.2 + 1e-9), guide))
    q = np.linspace(np.pi / 2 - 1e-3, np.pi / 2 + 1e-3, 2001)  # the window exists (dense closed-form sweep)
    assert not np.all(np.asarray(aj.kinematics(short, q, order=0, check=False).ok))
    with pytest.raises(aj.AssurjaxError, match="group 'rod_slider' cannot assemble between the nodes"):
        aj.build_table(short, scene.gravity, scene.loads)
    turns = eqx.tree_at(lambda m: (m.groups[1].offset, m.groups[1].direction), scene.mechanism, (-(0.2 - 1e-6), guide))
    assert np.all(np.asarray(aj.build_table(turns, scene.gravity, scene.loads).ok))


@pytest.mark.slow  # ~7 s; simulate's checks of a table stay in the default suite
def test_final_state_with_a_table_checks_it_as_build_table_does():
    """final_state(..., reduction="table") built its table inside the traced program, without
    build_table's checks: on the slider-crank 1e-9 m short of turning fully (the window between
    nodes above) it returned a state 6 rad past the exact reduction's lock-up. Refused now
    where the mechanism is concrete; traced (under grad), the run goes as before."""
    from assurjax import synthesis as syn

    scene = aj.load_scene("slider_crank")
    tilt = np.pi / 4096
    guide = jnp.array([np.cos(tilt), np.sin(tilt)])
    short = scene.replace_mechanism(eqx.tree_at(lambda m: (m.groups[1].offset, m.groups[1].direction), scene.mechanism,
                                                (-(0.2 + 1e-9), guide)))
    with pytest.raises(aj.AssurjaxError, match="group 'rod_slider' cannot assemble between the nodes"):
        syn.final_state(short, 0.5, q0=0.5, omega0=20.0, reduction="table")
    q, w = syn.final_state(scene, 0.5, q0=0.5, omega0=2.0, reduction="table")
    q_exact, w_exact = syn.final_state(scene, 0.5, q0=0.5, omega0=2.0)
    assert abs(float(q) - float(q_exact)) < 1e-6
