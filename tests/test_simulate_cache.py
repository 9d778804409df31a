"""simulate() keeps what depends only on the scene and the options between calls: a changed
scene or option must never be served from that cache. Each changed call is compared with
a simulation of a freshly loaded scene carrying the change, run with the cache emptied, and
with the unchanged result (it must differ, so that a stale entry would be caught)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj
from compile_events import BACKEND_COMPILE, EventCounter
from assurjax.dynamics._solve import _PREPARED

LEAN = dict(stop=None, steps=40, t1=0.5, points=(), angles=(), energies=False)  # one small program for the module


def fresh(change=lambda scene: scene, **options):
    """The simulation of a freshly loaded Watt six-bar with ``change`` applied, nothing cached."""
    _PREPARED.clear()
    return aj.simulate(change(aj.load_scene("watt_sixbar")), **{**LEAN, **options})


def same(a, b):
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.omega, b.omega)


def test_a_repeated_call_reuses_its_entry():
    scene = aj.load_scene("watt_sixbar")
    first = aj.simulate(scene, **LEAN)
    entries = len(_PREPARED)
    same(aj.simulate(scene, **LEAN), first)
    assert len(_PREPARED) == entries


def with_gravity(g):
    return lambda scene: eqx.tree_at(lambda s: s.gravity, scene, jnp.asarray(g))


def test_changed_gravity_is_simulated_anew():
    scene = aj.load_scene("watt_sixbar")
    before = aj.simulate(scene, **LEAN)
    after = aj.simulate(with_gravity([0.0, -3.0])(scene), **LEAN)
    assert not np.allclose(after.q, before.q)
    same(after, fresh(with_gravity([0.0, -3.0])))
    same(aj.simulate(scene, gravity=[0.0, -3.0], **LEAN), after)  # the same change as a keyword


def test_changed_options_and_scene_tables_are_simulated_anew():
    scene = aj.load_scene("watt_sixbar")
    base = aj.simulate(scene, **LEAN)
    finer = aj.simulate(scene, **{**LEAN, "steps": 80})
    assert finer.t.shape == (81,) and base.t.shape == (41,)
    same(finer, fresh(steps=80))
    moved = scene.with_settings(state={"q0": 0.3})
    started = aj.simulate(moved, **LEAN)
    assert started.q[0] == 0.3
    same(started, fresh(lambda s: s.with_settings(state={"q0": 0.3})))
    pointed = aj.simulate(scene.with_settings(outputs={"points": ["E"]}), **{**LEAN, "points": None})
    assert set(pointed.points) == {"E"}
    expected = fresh(lambda s: s.with_settings(outputs={"points": ["E"]}), points=None)
    np.testing.assert_array_equal(pointed.points["E"], expected.points["E"])


@pytest.mark.slow  # ~10 s (the table's programs); the default suite keeps a changed scene simulated anew (gravity)
def test_table_is_rebuilt_for_a_changed_scene():
    scene = aj.load_scene("watt_sixbar")
    tabulated = dict(reduction="table", **LEAN)
    before = aj.simulate(scene, **tabulated)
    after = aj.simulate(with_gravity([0.0, -3.0])(scene), **tabulated)
    assert not np.allclose(after.q, before.q)
    same(after, fresh(with_gravity([0.0, -3.0]), reduction="table"))
    # and the table agrees with the exact reduction, to the table's interpolation error
    np.testing.assert_allclose(after.q, aj.simulate(with_gravity([0.0, -3.0])(scene), **LEAN).q, atol=1e-7)


def test_a_numpy_leaf_changed_in_place_is_seen():
    scene = eqx.tree_at(lambda s: s.gravity, aj.load_scene("watt_sixbar"), np.array([0.0, -9.81]))
    before = aj.simulate(scene, **LEAN)
    scene.gravity[1] = -3.0  # NumPy arrays can change under the same object: such scenes are not cached
    after = aj.simulate(scene, **LEAN)
    assert not np.allclose(after.q, before.q)
    same(after, fresh(with_gravity([0.0, -3.0])))


def test_checks_run_for_every_distinct_option_value():
    scene = aj.load_scene("watt_sixbar")
    aj.simulate(scene, **{**LEAN, "steps": None, "samples": 5})
    with pytest.raises(aj.AssurjaxError, match="samples"):  # equal to 5 as a key, but not an integer
        aj.simulate(scene, **{**LEAN, "steps": None, "samples": 5.0})
    for _ in range(2):  # a failed check is not remembered as a success
        with pytest.raises(aj.AssurjaxError, match="rtol"):
            aj.simulate(scene, rtol=-1.0)


@pytest.mark.parametrize("values", [(0.0, 0.0, 0.0, 1.0), (1e12, -1e12, 0, 2), (1e12 + 1e-3, 0.0, 0.0, 1.0),
                                    (float("nan"), 0.0, 0.0, 1.0), (0.0, float("inf"), 0.0, 1.0), (0.0, 0.0, 1.0, 1.0),
                                    (0.0, 0.0, 2, 1), (10**400, 0.0, 0.0, 1.0), (0.0, 0.0, -1e12, 1e12)])
def test_start_checks_of_python_numbers_agree_with_numpy_scalars(values):
    """The start check decides Python numbers without NumPy: the same verdict and words as for NumPy scalars."""
    from assurjax.dynamics._settings import state_problem

    as_numpy = tuple(np.float64(v) if abs(v) < 1e300 else v for v in values)
    plain, numpy = state_problem(*values), state_problem(*as_numpy)
    assert (plain is None) == (numpy is None)
    if plain is not None:
        assert plain[0] == numpy[0]


COMPILES = EventCounter(BACKEND_COMPILE)


def test_simulate_compiles_its_two_programs_once_side_by_side():
    """The integration and the outputs are compiled on the first call of a signature (side
    by side) and found in JAX's cache by that call and every later one: no second compile."""
    scene = aj.load_scene("watt_sixbar")
    options = dict(samples=23, t1=0.7)  # a signature no other test compiles
    COMPILES.counts, COMPILES.active = {}, True
    try:
        first = aj.simulate(scene, **options)
        after_first = dict(COMPILES.counts)
        aj.simulate(scene, q0=0.4, **options)  # a new start: the same programs
        aj.simulate(scene.with_settings(state={"q0": 0.2}), **options)  # a new scene of the same structure
    finally:
        COMPILES.active = False
    ours = {k: v for k, v in COMPILES.counts.items() if k in ("jit(_integrate_split)", "jit(_finished_split)")}
    assert ours == {"jit(_integrate_split)": 1, "jit(_finished_split)": 1}, COMPILES.counts
    assert COMPILES.counts == after_first, "a later call compiled again"
    assert first.points and first.kinetic is not None


@pytest.mark.slow  # ~8 s; the default suite keeps to 10 min
def test_simulate_agrees_with_the_single_program_of_simulate_core():
    """The split's own guard (a restructuring changes no result beyond 1e-12): simulate()'s two
    programs (diffrax's forward-mode loop) give what the one jitted program of simulate_core
    gives (the checkpointed loop, outputs in the same program). The motion itself is checked
    against the joint-based reference in test_dynamics.py; here the outputs the second program
    computes are also checked against the closed-form assembly at the saved angles."""
    import joint_reference as ref
    from assurjax.dynamics._settings import settings_from

    scene = aj.load_scene("watt_sixbar")
    sol = aj.simulate(scene)
    settings = settings_from(scene)._replace(reduction="exact", max_steps=8192)
    core = aj.jit(lambda q0: aj.simulate_core(scene.model, None, (), q0, 0.0, 0.0, 2.0, settings=settings))(0.0)
    n = sol.t.shape[0]
    assert int(core.num_steps) == int(sol.num_steps)
    assert abs(float(core.t_stop) - sol.t_stop) < 1e-12  # located by bisection to 1e-12
    # the saved times before the stop to 1e-12; the stop itself (the last row) is located by
    # bisection to 1e-12 s, so there values differ by up to their rate times that
    for name in ("t", "q", "omega", "domega", "kinetic", "potential", "work"):
        ours, theirs = getattr(sol, name), np.asarray(getattr(core, name))[:n]
        np.testing.assert_allclose(ours[:-1], theirs[:-1], rtol=1e-13, atol=1e-12, err_msg=name)  # round-off of other fusions
        np.testing.assert_allclose(ours[-1], theirs[-1], rtol=0, atol=1e-10, err_msg=name)
    for point in sol.points:
        np.testing.assert_allclose(sol.points[point], np.asarray(core.points[point])[:n], rtol=0, atol=1e-12)
    closed = [ref.watt_sixbar_points(q)[0] for q in sol.q]  # the end checks' rows must not shift the outputs
    for point in ("A", "B", "E"):
        np.testing.assert_allclose(sol.points[point], np.array([c[point] for c in closed]), rtol=0, atol=1e-12)


def test_a_simulation_not_jitted_as_a_whole_compiles_once():
    """simulate_core called outside any jit, as a user's unjitted jax.grad calls it: diffrax's
    own jit must find its program from the second call on. Its term and events are Modules,
    equal from call to call; closures made at each call compiled the whole simulation again
    at every call (~14 s per gradient of the Watt six-bar). synthesis.final_state runs it as
    one cached program of its own (the exact friction law's segment loop, called in pieces,
    was compiled again at every call): that program too is compiled once."""
    scene = aj.load_scene("watt_sixbar")
    other = with_gravity([0.0, -3.0])(scene)
    settings = aj.SimulationSettings(samples=2, domega=False, points=(), angles=(), energies=False)
    COMPILES.counts, COMPILES.active = {}, True
    try:
        first = aj.simulate_core(scene.model, None, (), 0.0, 0.0, 0.0, 0.05, settings=settings).q_final
        after_first = dict(COMPILES.counts)
        second = aj.simulate_core(other.model, None, (), 0.0, 0.0, 0.0, 0.05, settings=settings).q_final
        finals = [aj.synthesis.final_state(s, 0.05, samples=2)[0] for s in (scene, other)]
    finally:
        COMPILES.active = False
    assert after_first.get("jit(diffeqsolve)") == 1, after_first
    assert COMPILES.counts["jit(diffeqsolve)"] == 1, "the second call compiled the simulation again"
    assert COMPILES.counts["jit(_core_program)"] == 1, COMPILES.counts
    assert float(first) != float(second)
    np.testing.assert_allclose([float(f) for f in finals], [float(first), float(second)], rtol=0, atol=1e-12)


def test_simulate_core_takes_the_settings_settings_from_builds():
    """SimulationSettings' docstring says to build them with settings_from, whose default
    reduction is 'auto' (simulate's choice, made on the host); simulate_core refused it from
    inside the user's trace. It takes the exact reduction there (traced only: no compile)."""
    from assurjax.dynamics._settings import settings_from

    scene = aj.load_scene("slider_crank")
    settings = settings_from(scene)
    assert settings.reduction == "auto"
    out = jax.eval_shape(lambda q0: aj.simulate_core(scene.model, None, (), q0, 0.0, 0.0, 0.5, settings=settings).q_final,
                         0.0)
    assert out.shape == ()
