"""What a user sees when printing the package's objects (a Jupyter cell's last line):
scalars and small arrays by value, long tables cut to their first entries and a count,
and a result item under its public name with a message. Printing only: the objects'
pytrees, equality and jit are unchanged."""

import pickle

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import assurjax as aj


def test_strandbeest_scene_repr_is_bounded():
    scene = aj.load_scene("strandbeest")
    mechanism = scene.mechanism
    text = repr(scene)
    assert len(text) < 3000 and text.count("\n") < 100, (len(text), text.count("\n"))  # was 13 kB, 561 lines
    # the first links and groups, then a count of the rest
    first, last = list(mechanism.links)[0], list(mechanism.links)[-1]
    assert f"'{first}': Link(" in text and f"'{last}'" not in text
    assert f"({len(mechanism.links) - 3} more, {len(mechanism.links)} in all)" in text
    assert f"({len(mechanism.groups) - 3} more, {len(mechanism.groups)} in all)" in text
    assert f"({len(mechanism.owner) - 3} more, {len(mechanism.owner)} in all)" in text
    assert "name='strandbeest'" in text and "gravity=[0.0, -9.81]" in text


def test_small_mechanism_repr_shows_everything():
    mechanism = aj.load_scene("watt_sixbar").mechanism
    text = repr(mechanism)
    for name in list(mechanism.links) + [g.name for g in mechanism.groups] + list(mechanism.ground):
        assert f"'{name}'" in text
    assert "more," not in text
    assert "'O4': [1.6, 0.0]" in text


def test_joint_friction_and_link_show_their_values():
    friction = aj.JointFriction("A", 0.137, radius=0.0125, viscous=0.002)
    text = repr(friction)
    assert "coefficient=0.137" in text and "radius=0.0125" in text and "viscous=0.002" in text
    assert "f64[]" not in text and "velocity_dependent" not in text
    link = aj.Link({"A": [0.0, 0.0], "B": [0.3, 0.0]}, com=[0.15, 0.01], mass=0.63, inertia=0.0047)
    text = repr(link)
    assert "mass=0.63" in text and "inertia=0.0047" in text
    assert "com=[0.15, 0.01]" in text and "'B': [0.3, 0.0]" in text
    # nested in a scene, and a float32 value in its own precision
    scene = aj.load_scene("press_with_friction")
    text = repr(scene)
    assert "mass=0.8" in text and "coefficient=0.15" in text and "length=0.05" in text and "stall=40.0" in text
    assert "mass=0.3," in repr(aj.Link({"A": [0.0, 0.0]}, mass=np.float32(0.3)))


def test_big_and_traced_arrays_stay_summaries():
    sol = aj.simulate(aj.load_scene("watt_sixbar"), t1=0.2, stop=None)  # 201 samples
    text = repr(sol)
    assert "q=f64[201]" in text and "t_final=0.2" in text
    seen = []

    @jax.jit
    def double_mass(link):
        seen.append(repr(link))
        return 2 * link.mass

    assert float(double_mass(aj.Link({"A": [0.0, 0.0]}, mass=1.5))) == 3.0
    assert "mass=weak_f64[]" in seen[0] or "mass=f64[]" in seen[0]


def test_printing_changes_nothing_else():
    scene = aj.load_scene("press_with_friction")
    model = scene.model
    copy = pickle.loads(pickle.dumps(model))
    assert bool(eqx.tree_equal(copy, model))
    assert jax.tree_util.tree_structure(copy) == jax.tree_util.tree_structure(model)
    assert eqx.tree_pformat(model) == repr(model)


def test_result_prints_under_its_public_name_with_a_message():
    sol = aj.simulate(aj.load_scene("watt_sixbar"), t1=0.2, stop=None)  # the programs of the test above
    assert bool(sol.result == aj.RESULTS.successful)
    assert repr(sol.result) == "assurjax.RESULTS<The run finished as asked (at t1 or at a stop event).>"
    assert repr(aj.RESULTS.max_steps_reached).startswith("assurjax.RESULTS<The maximum number of solver steps")
    assert pickle.loads(pickle.dumps(sol.result)) == sol.result
