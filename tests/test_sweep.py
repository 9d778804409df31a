"""Batches of mechanisms: vmapped kinematics and simulation, chunking, sharding over devices."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax import AssurjaxError
from joint_reference import circle_intersection

Q = np.linspace(0.7, 1.5, 9)


@pytest.fixture(scope="module")
def roberts():
    return assurjax.load_scene("roberts").mechanism


@pytest.fixture(scope="module")
def batch(roberts):
    return assurjax.perturb(roberts, jax.random.key(3), 10, relative=0.03)


@pytest.fixture(scope="module")
def batch_kin(batch):
    return assurjax.batch_kinematics(batch, Q, points=["P"], order=1)


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def reference_coupler_point(m, q):
    """Coupler point of a four-bar (crank link2 about A, rocker link3 about D, coupler link4 BCP, C left
    of B -> D) from the numpy joint reference's circle intersection."""
    g = {k: np.asarray(v) for k, v in m.ground.items()}
    l2, l3, l4 = ({k: np.asarray(v) for k, v in m.links[n].points.items()} for n in ("link2", "link3", "link4"))
    b = g["A"] + _rot(q) @ (l2["B"] - l2["A"])
    c = circle_intersection(b, np.linalg.norm(l4["C"] - l4["B"]), g["D"], np.linalg.norm(l3["C"] - l3["D"]), left=True)
    frame = np.arctan2(*(c - b)[::-1]) - np.arctan2(*(l4["C"] - l4["B"])[::-1])
    return b + _rot(frame) @ (l4["P"] - l4["B"])


def test_batch_kinematics_matches_joint_reference(batch, batch_kin):
    assert batch_kin.points["P"].shape == (10, 9, 2)
    assert batch_kin.ok.shape == (10, 9, 2)
    for i in range(10):
        m = jax.tree.map(lambda x: x[i], batch)
        for j, q in enumerate(Q):
            if batch_kin.ok[i, j].all():
                np.testing.assert_allclose(batch_kin.points["P"][i, j], reference_coupler_point(m, q), atol=1e-12)
    assert batch_kin.ok.all(axis=-1).sum() >= 60


def test_batch_velocities_are_derivatives(batch, batch_kin):
    """v = dP/dq w with w = 1: central differences of the batched positions."""
    h = 1e-6
    plus = assurjax.batch_kinematics(batch, Q + h, points=["P"], order=0)
    minus = assurjax.batch_kinematics(batch, Q - h, points=["P"], order=0)
    ok = batch_kin.ok.all(-1) & plus.ok.all(-1) & minus.ok.all(-1)
    fd = (plus.points["P"] - minus.points["P"]) / (2 * h)
    np.testing.assert_allclose(batch_kin.velocities["P"][ok], fd[ok], rtol=1e-6, atol=1e-8)


def test_chunked_equals_unchunked_and_per_mechanism_q(batch, batch_kin):
    chunked = assurjax.batch_kinematics(batch, Q, points=["P"], order=1, chunk_size=4)  # 3 chunks, last one padded
    np.testing.assert_array_equal(chunked.points["P"], batch_kin.points["P"])
    np.testing.assert_array_equal(chunked.velocities["P"], batch_kin.velocities["P"])
    np.testing.assert_array_equal(chunked.ok, batch_kin.ok)
    per = assurjax.batch_kinematics(batch, np.tile(Q, (10, 1)), points=["P"], order=1, q_per_mechanism=True)
    np.testing.assert_array_equal(per.points["P"], batch_kin.points["P"])
    with pytest.raises(AssurjaxError, match="leading axis of 10"):
        assurjax.batch_kinematics(batch, Q, q_per_mechanism=True)


def test_sweep_reduce_and_index_batches(batch, batch_kin):
    """A per-chunk reduction gives the same as reducing the full result; an int batch passes indices."""
    from assurjax._sweep import _kinematics_item

    item = _kinematics_item(("P",), 0)
    q_items = np.broadcast_to(Q, (10,) + Q.shape)
    zeros = np.zeros_like(q_items)

    def peak(carry, kin):
        y = np.abs(kin.points["P"][..., 1]).max()
        return y if carry is None else max(carry, y)

    got = assurjax.sweep(item, (batch, q_items, zeros, zeros), chunk_size=3, reduce=peak)
    assert got == np.abs(batch_kin.points["P"][..., 1]).max()
    squares = assurjax.sweep(lambda i: i * i, 11, chunk_size=4)
    np.testing.assert_array_equal(squares, np.arange(11) ** 2)


def test_stack_mechanisms(batch, roberts):
    items = [jax.tree.map(lambda x: x[i], batch) for i in range(10)]
    stacked = assurjax.stack_mechanisms(items)
    for a, b in zip(jax.tree.leaves(stacked), jax.tree.leaves(batch)):
        np.testing.assert_array_equal(a, b)
    other = assurjax.load_scene("watt_sixbar").mechanism
    with pytest.raises(AssurjaxError, match="item 1 has a different structure"):
        assurjax.stack_mechanisms([roberts, other])
    with pytest.raises(AssurjaxError, match="not a batch"):
        assurjax.batch_kinematics(roberts, Q)



SHARDED = textwrap.dedent(
    """
    import os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax, numpy as np, assurjax
    assert len(jax.devices()) == 4, jax.devices()
    mech = assurjax.load_scene("roberts").mechanism
    batch = assurjax.perturb(mech, jax.random.key(5), 10, relative=0.03)
    q = np.linspace(0.7, 1.5, 6)
    plain = assurjax.batch_kinematics(batch, q, points=["P"], order=1)
    mesh = assurjax.batch_mesh()
    sharded = assurjax.batch_kinematics(batch, q, points=["P"], mesh=mesh, chunk_size=8, order=1)
    # the inputs really were split over the 4 devices
    chunk = assurjax.shard_batch(jax.tree.map(lambda x: x[:8], batch), mesh)
    assert len(chunk.ground["A"].sharding.device_set) == 4
    for name in ("points", "velocities"):
        a, b = getattr(plain, name)["P"], getattr(sharded, name)["P"]
        assert np.max(np.abs(a - b)) <= 1e-12, (name, np.max(np.abs(a - b)))
    print("EXACT" if all(np.array_equal(getattr(plain, n)["P"], getattr(sharded, n)["P"]) for n in ("points", "velocities")) else "CLOSE")
    """
)


def _run_on_cpu_devices(tmp_path, source: str, devices: int) -> str:
    """The last line ``source`` prints, run in a process of its own on ``devices`` forced CPU
    devices (XLA reads its flags once per process)."""
    script = tmp_path / "sharded.py"
    script.write_text(source)
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout.strip().splitlines()[-1]


def test_sharded_equals_unsharded_on_four_cpu_devices(tmp_path):
    assert _run_on_cpu_devices(tmp_path, SHARDED, 4) in ("EXACT", "CLOSE")


SHARDED_FRICTION = textwrap.dedent(
    """
    import os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    import jax, numpy as np, assurjax
    from assurjax import dynamics
    from assurjax.dynamics._field import field_args
    assert len(jax.devices()) == 2, jax.devices()
    pendulum = assurjax.scene_from_dict({  # a crank alone: the smallest field with friction
        "scene": {"name": "pendulum", "gravity": [0.0, -9.81]}, "ground": {"O": [0.0, 0.0]},
        "links": {"bar": {"points": {"O": [0.0, 0.0]}, "com": [0.3, 0.0], "mass": 2.0, "inertia": 0.02}},
        "formation": [{"group": "crank", "name": "crank", "link": "bar", "pivot": "O"}]})
    friction = (assurjax.JointFriction("O", 0.2, radius=0.02),)
    args = field_args(assurjax.Model(pendulum.mechanism, pendulum.gravity, friction))

    def rates(y):
        return dynamics.vector_field(0.0, dynamics.State(*y), args).omega

    states = (np.linspace(0.2, 2.0, 4), np.linspace(-3.0, 3.0, 4))
    plain = assurjax.sweep(rates, states)
    sharded = assurjax.sweep(rates, states, mesh=assurjax.batch_mesh())
    assert np.max(np.abs(sharded - plain)) <= 1e-12 * np.max(np.abs(plain)), (plain, sharded)
    print("REGIONS" if assurjax._jit.regions_enabled() else "NO REGIONS")
    """
)


@pytest.mark.slow  # ~7 s; a sharded sweep stays in the default suite
def test_a_sharded_sweep_with_friction_equals_the_unsharded_one(tmp_path):
    """The friction field's regions (_jit.region: one kernel each) hold loops over a batch-wide
    test (the iteration's and Newton's while loops, vmapped); partitioned by XLA over a sharded
    batch, such a test became an all-reduce, which a region's kernel cannot call on a CPU (the
    call raised 'INTERNAL: Failed to materialize symbols'). A sharded sweep runs each device's
    members on their own (shard_map): no collective, regions kept. 2 forced CPU devices,
    4 states of a pendulum with friction in its pivot."""
    assert _run_on_cpu_devices(tmp_path, SHARDED_FRICTION, 2) in ("REGIONS", "NO REGIONS")


@pytest.mark.slow  # compiles a vmapped simulation with friction twice: about a minute
def test_a_sharded_batch_simulate_with_friction_equals_the_unsharded_one(tmp_path):
    """batch_simulate(mesh=) of the press with friction on 2 forced CPU devices, against the
    same batch unsharded (it crashed as the sweep above did)."""
    source = textwrap.dedent(
        """
        import os
        os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
        import jax, numpy as np, assurjax
        scene = assurjax.load_scene("press_with_friction")
        batch = assurjax.perturb(scene.mechanism, jax.random.key(3), 2, relative=0.05,
                                 select=lambda m: tuple(link.mass for link in m.links.values()))
        kw = dict(t1=0.2, samples=3, stop=None, points=(), angles=(), progress=False)
        plain = assurjax.batch_simulate(scene, batch, **kw)
        sharded = assurjax.batch_simulate(scene, batch, mesh=assurjax.batch_mesh(), **kw)
        assert np.all(sharded.result == assurjax.RESULTS.successful), sharded.status
        # the same members in programs of 2 and 1 members: a step may differ by round-off
        assert np.max(np.abs(sharded.q - plain.q)) <= 1e-9, np.max(np.abs(sharded.q - plain.q))
        print("OK")
        """
    )
    assert _run_on_cpu_devices(tmp_path, source, 2) == "OK"


@pytest.mark.slow  # compiles a vmapped diffrax solve: minutes on a busy 2-core machine
def test_batch_simulate_matches_single_simulations():
    """Each member of a vmapped batch of Watt six-bars equals its own simulation."""
    scene = assurjax.load_scene("watt_sixbar")
    batch = assurjax.perturb(scene.mechanism, jax.random.key(11), 3, relative=0.02,
                             select=lambda m: tuple(link.mass for link in m.links.values()))
    sols = assurjax.batch_simulate(scene, batch, t1=0.3, solver="tsit5", samples=4, domega=False, chunk_size=2)
    assert sols.q.shape == (3, 4)
    for i in range(3):
        m = jax.tree.map(lambda x: x[i], batch)
        one = assurjax.simulate(scene, mechanism=m, t1=0.3, solver="tsit5", samples=4, stop=None,
                                points=(), angles=(), energies=False)
        # the same method at the same tolerance, but two programs (vmapped with the scene's
        # standstill event, and alone): their step sequences may differ by a borderline
        # step, so they agree to the tolerance, not bit for bit; a mixed-up member would
        # differ by ~1e-3 (the masses differ by 2 %)
        np.testing.assert_allclose(sols.q[i], one.q, rtol=0, atol=1e-8)
    assert np.all(sols.result == assurjax.RESULTS.successful)


@pytest.mark.slow  # compiles a vmapped simulation with friction and three single ones
def test_batch_simulate_with_friction_matches_single_simulations():
    """batch_simulate of the press with friction (its segments in chunks, as simulate's
    batches): each member equals its own simulation to the tolerance (rtol = atol = 1e-10:
    two step sequences; a mixed-up member would differ by ~1e-2, the masses by 5 %); and
    simulate's batch whose step budget runs out says so."""
    from assurjax.dynamics._stick import BATCH_SEGMENT_STEPS

    scene = assurjax.load_scene("press_with_friction")
    batch = assurjax.perturb(scene.mechanism, jax.random.key(3), 3, relative=0.05,
                             select=lambda m: tuple(link.mass for link in m.links.values()))
    kw = dict(t1=0.5, samples=6, energies=False, points=(), angles=(), rtol=1e-10, atol=1e-10)
    sols = assurjax.batch_simulate(scene, batch, progress=False, **kw)
    assert np.all(sols.result == assurjax.RESULTS.successful)
    for i in range(3):
        one = assurjax.simulate(scene, mechanism=jax.tree.map(lambda x: x[i], batch), stop=None, **kw)
        np.testing.assert_allclose(sols.q[i], one.q, rtol=0, atol=1e-7)
    # a batch whose step budget runs out in its chunks says so, within a chunk of the budget
    short = assurjax.simulate(scene, q0=np.array([0.0, 1.0]), stop=None, max_steps=100, throw=False, **kw)
    assert not short.successful and "step budget" in short.status
    assert np.all(np.asarray(short.num_steps) <= 100 + BATCH_SEGMENT_STEPS)


def test_batch_simulate_refuses_what_simulate_refuses_with_fixed_steps():
    """steps= with joint friction (no stick or break-away can be located: the batch stayed at
    rest where the slider-crank falls to q = -0.77), and steps= with saveat (silently ignored):
    refused before any run, in simulate's words; and reduction='table'."""
    scene = assurjax.load_scene("slider_crank")
    rough = scene.with_loads(scene.loads + tuple(assurjax.JointFriction(j, 0.3, radius=0.02) for j in ("O", "A", "B")))
    batch = assurjax.stack_mechanisms([scene.mechanism] * 2)
    with pytest.raises(assurjax.AssurjaxError, match="steps= \\(fixed steps\\) cannot locate where a mechanism with joint friction"):
        assurjax.batch_simulate(rough, batch, q0=0.5, t1=1.0, steps=200)
    with pytest.raises(assurjax.AssurjaxError, match="steps= saves the state at each of its equal steps and takes no saveat"):
        assurjax.batch_simulate(scene, batch, t1=1.0, steps=100, saveat=[0.1, 0.2])
    # a table per member would run unchecked (a member whose rod is shorter than its crank ran
    # on through positions it cannot assemble in, 'reached t1'): refused; the scene's 'table' runs exact
    with pytest.raises(assurjax.AssurjaxError, match="batch_simulate: reduction='table' would need a table per mechanism"):
        assurjax.batch_simulate(scene, batch, t1=1.0, reduction="table")


@pytest.mark.slow  # ~8 s; the default suite keeps to 10 min
def test_a_member_that_locks_up_beside_one_that_stops_keeps_its_final_state():
    # crank 0.32 m, rod 0.3 m: from q0 = 0.5 at 5 rad/s the in-line slider-crank locks up at
    # q = asin(0.3 / 0.32); from -0.5 it comes to a standstill. Batched, diffrax re-evaluated
    # the lock-up member's end where the other's event fired: its final state was NaN
    import equinox as eqx

    scene = assurjax.load_scene("slider_crank")
    long_crank = eqx.tree_at(lambda m: m.links["crank"].points["A"], scene.mechanism, jnp.array([0.32, 0.0]))
    kw = dict(mechanism=long_crank, omega0=5.0, t1=2.0, stop="standstill", points=("B",))
    batch = assurjax.simulate(scene, q0=np.array([0.5, -0.5]), **kw)
    single = assurjax.simulate(scene, q0=0.5, **kw)
    assert list(np.asarray(batch.event)) == [1, 0]  # lock-up, standstill
    assert abs(float(batch.q_final[0]) - np.arcsin(0.3 / 0.32)) < 1e-8
    assert abs(float(single.q_final) - np.arcsin(0.3 / 0.32)) < 1e-8
    # the steps closing in on it differ by round-off between a batch and a single run
    assert abs(float(batch.t_final[0]) - float(single.t_final)) < 1e-6
    assert np.all(np.isfinite(np.asarray(batch.points["B"])[0][np.asarray(batch.valid)[0]]))


def test_batch_requests_that_do_not_fit_are_named(batch):
    # omega of another length than q: numpy's broadcast error, naming neither
    with pytest.raises(AssurjaxError, match="batch_kinematics: omega of shape \\(4,\\) does not fit q's \\(10, 3\\)"):
        assurjax.batch_kinematics(batch, np.zeros(3), omega=np.zeros(4))
    # the Euler baseline is simulate()'s for one start ("unknown solver 'seed_euler'; choose one of [..., 'seed_euler']")
    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(AssurjaxError, match="'seed_euler' is a baseline that simulate\\(\\) runs for one start"):
        assurjax.batch_simulate(scene, assurjax.stack_mechanisms([scene.mechanism, scene.mechanism]), solver="seed_euler", progress=False)
    # save_steps, refused for simulate's batches, saved max_steps rows per member here
    with pytest.raises(AssurjaxError, match="batch_simulate: save_steps .* not batches"):
        assurjax.batch_simulate(scene, assurjax.stack_mechanisms([scene.mechanism, scene.mechanism]), save_steps=True, progress=False)


def test_a_batch_of_mechanisms_is_checked_before_it_runs():
    import equinox as eqx

    scene = assurjax.load_scene("slider_crank")
    pair = assurjax.stack_mechanisms([scene.mechanism, scene.mechanism])
    # a rod mass for three members beside two of everything else: numpy's broadcast error
    ragged = eqx.tree_at(lambda m: m.links["rod"].mass, pair, jnp.ones(3))
    with pytest.raises(AssurjaxError, match="not a batch: every array needs the same leading batch axis"):
        assurjax.batch_simulate(scene, ragged, progress=False)
    # another mechanism's batch reached the scene's outputs inside the trace: KeyError 'crank'
    watt = assurjax.load_scene("watt_sixbar").mechanism
    with pytest.raises(AssurjaxError, match="batch_simulate: the mechanisms are not of the scene's structure: "
                                            "its groups are \\['crank2', 'dyad34', 'dyad56'\\], not \\['crank', 'rod_slider'\\]"):
        assurjax.batch_simulate(scene, assurjax.stack_mechanisms([watt, watt]), t1=0.1, progress=False)
    m = scene.mechanism
    slider = m.groups[1]
    behind = assurjax.groups.RRP(slider.name, slider.links, slider.joints, slider.guide_point, -slider.mode,
                                 slider.direction, slider.offset)
    flipped = assurjax.Mechanism(m.ground, m.links, [m.groups[0], behind], name=m.name)
    with pytest.raises(AssurjaxError, match="item 1 has a different structure than item 0: group 'rod_slider' \\(RRP\\) "
                                            "differs .*mode"):
        assurjax.stack_mechanisms([m, flipped])
    # a NaN or negative mass set past the Mechanism's checks ran as a solver failure or to the step budget
    for bad, word in ((np.nan, "finite"), (-1.0, "non-negative")):
        member = eqx.tree_at(lambda m: m.links["rod"].mass, pair, jnp.asarray([1.0, bad]))
        with pytest.raises(AssurjaxError, match=f"batch_simulate: batch member 1: link 'rod': mass must be {word}"):
            assurjax.batch_simulate(scene, member, progress=False)


def test_a_stack_of_scenes_is_named_where_batch_simulate_takes_one_scene():
    """batch_simulate runs a batch of mechanisms under one scene's loads: a user who stacked
    scenes to vary a friction coefficient read "not of the scene's structure" (in place of the
    mechanisms) or "Model: gravity must be a 2-vector" (in place of the scene); both now say
    what it takes and where loads are varied."""
    import equinox as eqx

    scene = assurjax.load_scene("slider_crank")
    rough = [scene.with_loads(scene.loads + (assurjax.JointFriction("O", mu, 0.01),)) for mu in (0.1, 0.2)]
    stack = jax.tree.map(lambda *v: jnp.stack(v) if eqx.is_array(v[0]) else v[0], *rough)
    with pytest.raises(AssurjaxError, match="batch_simulate: mechanisms takes a batch of Mechanisms .* got a Scene; .*"
                                            "sweep simulate_core with assurjax.sweep"):
        assurjax.batch_simulate(rough[0], stack, progress=False)
    with pytest.raises(AssurjaxError, match=r"batch_simulate: the scene is a stack of scenes \(gravity of shape \(2, 2\)\)"):
        assurjax.batch_simulate(stack, stack.mechanism, progress=False)
    stacked_mu = eqx.tree_at(lambda s: s.loads[-1].coefficient, rough[0], jnp.array([0.1, 0.2]))
    with pytest.raises(AssurjaxError, match=r"the friction coefficient of 'O' of shape \(2,\)"):
        assurjax.batch_simulate(stacked_mu, stack.mechanism, progress=False)


def test_a_batch_of_starts_is_bounded_by_all_it_saves():
    # a million starts and 100 000 samples, each within its own bound: a raw MemoryError (745 GiB)
    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(AssurjaxError, match="1,000,000 starts x 100,000 saved states each .*at most 100,000,000 per call"):
        assurjax.simulate(scene, q0=np.zeros(1_000_000), samples=100_000)


def test_a_sweep_names_a_count_that_is_no_count_and_results_that_would_not_fit():
    import jax.numpy as jnp

    with pytest.raises(AssurjaxError, match="sweep: batch must be .* or a whole number of items, got 5.0"):
        assurjax.sweep(lambda i: jnp.zeros(2) + i, 5.0)
    # 10**12 items in chunks of 1000: the first chunk ran, then 14.9 TiB of results were asked for at once
    with pytest.raises(AssurjaxError, match="sweep: 1,000,000,000,000 items of 16 bytes of results each .* reduce="):
        assurjax.sweep(lambda i: jnp.zeros(2) + i, 10**12, chunk_size=1000)
    # folded, the results are not kept whole: only each chunk's in turn
    assert assurjax.sweep(lambda i: jnp.zeros(2) + i, 3000, chunk_size=1000, reduce=lambda c, r: (c or 0) + len(r)) == 3000
