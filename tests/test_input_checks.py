"""Input checks found missing by a user's probe: each bad input raises an AssurjaxError (or a
subclass) naming the keyword, field, load or point at fault, before anything is traced;
requests for too much work are refused at once."""

import copy
import time
import tomllib
from importlib import resources

import jax.numpy as jnp
import numpy as np
import optax
import pytest

import assurjax
from assurjax import AssurjaxError, MechanismError, SceneError, synthesis


@pytest.fixture(scope="module")
def slider_crank():
    return assurjax.load_scene("slider_crank")


def bundled_tables(name: str) -> dict:
    """A bundled scene's TOML tables, to edit before scene_from_dict."""
    return tomllib.loads((resources.files("assurjax.scenes") / f"{name}.toml").read_text())


def refused(call, error, *fragments) -> str:
    """The call raises ``error``, its message holding every fragment; the message."""
    with pytest.raises(error) as caught:
        call()
    for fragment in fragments:
        assert fragment in str(caught.value), (fragment, str(caught.value))
    return str(caught.value)


def refused_fast(call, error, *fragments) -> str:
    """:func:`refused`, within 10 s: the requests refused ran for minutes, the refusals take
    0.01-0.3 s here (a bound of 1 s failed once on a machine loaded with other work: 1.27 s)."""
    start = time.perf_counter()
    message = refused(call, error, *fragments)
    assert time.perf_counter() - start < 10.0
    return message


# 1. inverse_kinematics' solver settings (10**9 steps hung 12 min out of reach)
@pytest.mark.parametrize("keyword, value", [("max_steps", 10**9), ("max_steps", 0), ("max_steps", 2.5),
                                            ("rtol", np.nan), ("rtol", -1.0), ("atol", np.inf)])
def test_inverse_kinematics_checks_its_solver_settings(slider_crank, keyword, value):
    refused(lambda: assurjax.inverse_kinematics(slider_crank.mechanism, ("B", 0), 10.0, 0.1, **{keyword: value}),
                 AssurjaxError, f"'{keyword}'")


# 2. sizes of the mechanism builders


@pytest.mark.parametrize("build, fragment", [(lambda: assurjax.n_four_bar(10**6), "from 1 to 1000"),
                                             (lambda: assurjax.strandbeest(10**5), "from 1 to 100")])
def test_generated_mechanisms_are_bounded(build, fragment):
    refused_fast(build, AssurjaxError, fragment)


def chain(n: int) -> tuple[dict, dict]:
    """A chain of n bars with one end on the ground: joints and links of a sketch."""
    joints = {f"J{i}": (0.1 * i, 0.0) for i in range(n + 1)}
    return joints, {f"L{i}": [f"J{i}", f"J{i + 1}"] for i in range(n)}


def test_a_sketch_is_bounded():
    joints, links = chain(10**5)
    refused_fast(lambda: assurjax.Sketch(joints, links, ground=["J0"], driver="L0"), MechanismError, "100000 links", "at most 1000")


def test_a_plate_of_the_most_joints_is_checked_fast():
    joints = {f"J{i}": (np.cos(i), np.sin(i)) for i in range(2000)}
    joints["J1999"] = joints["J1000"]
    refused_fast(lambda: assurjax.Sketch(joints, {"plate": list(joints)}, ground=["J0"], driver="plate"), MechanismError,
                 "joints 'J1000' and 'J1999' coincide")


def test_a_long_list_of_names_is_cut_short():
    joints, links = chain(900)
    message = refused_fast(lambda: assurjax.Sketch(joints, links, ground=["J0"], driver="crank"), MechanismError,
                           "driver 'crank'", "and 892 more")
    assert len(message) < 300


def test_a_scene_table_is_bounded():
    data = bundled_tables("slider_crank")
    data["links"] |= {f"extra{i}": {"points": {f"P{i}": [0.0, 0.0]}} for i in range(10**4)}
    refused_fast(lambda: assurjax.scene_from_dict(data, source="big.toml"), SceneError, "big.toml: [links]", "at most 2500")


# 3. a Solution of another mechanism


def solution_of_slider_crank() -> assurjax.Solution:
    """A Solution as simulate returns it for the bundled slider-crank (its saved names), built
    without simulating."""
    n = 3
    z = np.zeros(n)
    return assurjax.Solution(t=np.linspace(0, 0.1, n), q=z + 0.5, omega=z, domega=z, kinetic=None, potential=None,
                             total=None, dissipated=None, points={"A": np.zeros((n, 2)), "B": np.zeros((n, 2))},
                             angles={"crank": z, "rod": z}, valid=np.ones(n, bool), t_final=0.1, q_final=0.5,
                             omega_final=0.0, t_stop=None, event=-1, failed_group_index=-1, result=None, num_steps=n)


def test_reactions_refuse_a_solution_of_another_mechanism():
    watt = assurjax.load_scene("watt_sixbar")
    refused(lambda: assurjax.reactions(watt, solution_of_slider_crank()), AssurjaxError, "'watt_sixbar'", "angles",
                 "'crank'")


def test_reactions_refuse_a_solution_of_another_mechanism_that_saved_no_names(slider_crank):
    """A Solution that saved no points nor angles (a drawn scene's default) is told by the
    simulated mechanism's point names, which simulate records."""
    sol = assurjax.simulate(slider_crank, t1=0.01, samples=2, points=(), angles=())
    assert set(sol.mechanism_points) == set(slider_crank.mechanism.point_names) and not sol.points and not sol.angles
    watt = assurjax.load_scene("watt_sixbar")
    refused(lambda: assurjax.reactions(watt, sol), AssurjaxError, "'watt_sixbar'", "without the point(s)", "'O2'")
    assert assurjax.reactions(slider_crank, sol).driving.shape == sol.t.shape  # its own mechanism's motion is taken


# 4. two friction elements on one pair


@pytest.mark.parametrize("loads, pair", [
    ((assurjax.JointFriction("A", 0.1, radius=0.01), assurjax.JointFriction("O", 0.1, radius=0.01),
      assurjax.JointFriction("A", 0.2, radius=0.02)), "revolute joint 'A'"),
    ((assurjax.SlideFriction("slider/ground", 0.1, length=0.05),
      assurjax.SlideFriction("slider/ground", 0.1, length=0.05, viscous=1.0)), "prismatic pair 'slider/ground'"),
], ids=["joint", "slide"])
def test_one_friction_element_per_pair(slider_crank, loads, pair):
    refused(lambda: slider_crank.with_loads(loads), MechanismError, pair)


def test_one_friction_element_per_pair_in_a_scene():
    data = bundled_tables("slider_crank")
    data["loads"] = [{"type": "joint_friction", "joint": "O", "coefficient": c, "radius": 0.01} for c in (0.15, 0.3)]
    refused(lambda: assurjax.scene_from_dict(data, source="dup.toml"), SceneError, "dup.toml: [[loads]] #1 and #2",
                 "revolute joint 'O'")


# 5. a link's points


@pytest.mark.parametrize("points, fragment", [({}, "points is empty"), ([(0, 0)], "points must map point names"),
                                              ({0: [0.0, 0.0]}, "point names must be strings")])
def test_a_link_needs_named_points(points, fragment):
    refused(lambda: assurjax.Link(points), MechanismError, "Link: ", fragment)


# 6. a load function of the wrong arguments


@pytest.mark.parametrize("make, load", [(lambda: assurjax.Couple("crank", lambda q: q), "Couple on link 'crank': moment"),
                                        (lambda: assurjax.PointForce("B", lambda q, w: jnp.zeros(2)), "PointForce on point 'B'"),
                                        (lambda: assurjax.Drive(lambda t: t), "Drive: value")])
def test_a_load_function_must_take_q_omega_t(make, load):
    refused(make, MechanismError, load, "f(q, omega, t)")


# 7. a [[loads]] entry without its type


def test_a_load_entry_without_type():
    data = bundled_tables("slider_crank")
    data["loads"] = [{"link": "crank", "moment": 1.0}]
    refused(lambda: assurjax.scene_from_dict(data, source="untyped.toml"), SceneError,
                 "untyped.toml: [[loads]] #1: missing field 'type'")


# 8. optimize's seed and schedule


@pytest.fixture(scope="module")
def design(slider_crank):
    return synthesis.Design(slider_crank.mechanism, lambda m: m.links["rod"].points["B"], relative=0.1, absolute=0.01)


def objective(mechanism):
    return jnp.sum(assurjax.kinematics(mechanism, jnp.linspace(0, 1, 5), check=False).points["B"][:, 1] ** 2)


@pytest.mark.parametrize("keywords, fragment", [(dict(seed=np.nan), "seed"), (dict(seed=-1), "seed"),
                                                (dict(schedule={"sharp": "x"}), "schedule 'sharp'"),
                                                (dict(schedule={"sharp": [1.0, np.inf]}), "schedule 'sharp'")])
def test_optimize_checks_seed_and_schedule(design, keywords, fragment):
    refused(lambda: synthesis.optimize(design, objective, optax.adam, 5, options={"learning_rate": 0.01}, **keywords),
                 AssurjaxError, f"optimize: {fragment}")


def test_kinematics_names_a_scene_given_for_a_mechanism_and_a_string_order():
    scene = assurjax.load_scene("slider_crank")
    refused(lambda: assurjax.kinematics(scene, 0.1), MechanismError, "kinematics", "scene.mechanism", "Scene")
    refused(lambda: assurjax.kinematics(scene.mechanism, 0.1, order="2"), AssurjaxError, "order", "'2'")
