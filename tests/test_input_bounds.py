"""Keyword input of simulate, batch_simulate, batch_kinematics and final_state: every request
for work is bounded and every wrong value is refused by name before anything is traced; a
NumPy integer is as good as a Python one. One small scene, a few lean compiled programs."""

import re

import jax
import numpy as np
import pytest

import assurjax
from assurjax import synthesis
from assurjax._model import as_model
from assurjax.dynamics._settings import check_span_covered

SCENE = assurjax.load_scene("slider_crank")
MECH = SCENE.mechanism
PAIR = assurjax.stack_mechanisms([MECH, MECH])
LEAN = dict(t1=0.2, samples=2, points=(), angles=(), energies=False)  # one short run, no outputs: quick compiles


def raises(*fragments):
    """pytest.raises(AssurjaxError) whose message holds every fragment (the keyword at fault)."""
    return pytest.raises(assurjax.AssurjaxError, match=".*".join(map(re.escape, fragments)))


@pytest.fixture(scope="module")
def reference():
    """q(0.2 s) by the adaptive solver at tight tolerance: the independent reference."""
    return assurjax.simulate(SCENE, rtol=1e-11, atol=1e-11, **LEAN).q_final


def test_batch_simulate_bounds_members_times_samples_as_simulate_bounds_starts():
    many = assurjax.perturb(MECH, jax.random.key(0), 1001)
    with raises("1,001 starts x 100,000 saved states", "(at most 100,000,000 per call)"):
        assurjax.simulate(SCENE, q0=np.zeros(1001), samples=100_000)
    with raises("1,001 mechanisms x 100,000 saved states", "(at most 100,000,000 per call)"):
        assurjax.batch_simulate(SCENE, many, t1=0.1, samples=100_000)


def test_batch_kinematics_takes_at_most_as_many_states_as_kinematics():
    with raises("kinematics", "at most 1,000,000 states"):
        assurjax.kinematics(MECH, np.zeros(1_200_000))
    with raises("batch_kinematics", "at most 1,000,000 states", "1,200,000"):
        assurjax.batch_kinematics(PAIR, np.zeros(600_000))
    with raises("batch_kinematics", "at most 1,000,000 states", "1,200,000"):
        assurjax.batch_kinematics(PAIR, np.zeros((2, 600_000)), q_per_mechanism=True)


def test_a_fixed_step_beyond_the_scene_range_or_the_span_is_refused(reference):
    with raises("setting 'dt'", "at most 1000"):
        assurjax.simulate(SCENE, t1=0.2, dt=1e6)  # ran one step of the span: q = -8.25 rad
    with raises("setting 'dt'", "longer than the time span"):
        synthesis.final_state(SCENE, 0.2, dt=1e6)  # omega 1110 rad/s
    with raises("setting 'dt'", "longer than the time span"):
        assurjax.simulate(SCENE, t1=0.2, dt=0.3)
    with raises("setting 'dt'", "longer than the time span"):
        assurjax.batch_simulate(SCENE, PAIR, t1=0.2, dt=0.3)
    within = assurjax.simulate(SCENE, dt=4e-3, **LEAN)  # 50 steps of Tsit5
    assert within.status.startswith("reached t1")
    assert abs(within.q_final - reference) < 1e-8


def test_a_span_no_default_budget_covers_is_refused_unless_something_can_end_it():
    with raises("setting 't1'", "stop=None", "max_steps"):
        assurjax.simulate(SCENE, t1=1e12, stop=None)  # took 122 s to use up 16.7 million steps
    with raises("setting 't1'"):
        assurjax.simulate(SCENE, q0=np.zeros(3), t1=1e12, stop=None)
    with raises("setting 't1'", "max_steps"):  # final_state ran the press with friction to 2051 s, then refused it
        assurjax.synthesis.final_state(SCENE, 1e9)
    with raises("setting 't1'", "max_steps"):  # ran it, where simulate and final_state refuse it
        assurjax.batch_simulate(SCENE, PAIR, t1=1e9, stop=None)
    check_span_covered(0.0, 1e12, assurjax.settings_from(SCENE, stop="standstill"))  # a standstill may end it
    check_span_covered(0.0, 1e12, assurjax.settings_from(SCENE, events=(lambda t, q, w: q,)))
    budget = assurjax.simulate(SCENE, **{**LEAN, "t1": 1e12}, stop=None, max_steps=64)  # asked for: runs, quickly
    assert "step budget (max_steps = 64)" in budget.status


def test_numpy_integers_are_taken_as_python_integers(reference):
    given = assurjax.settings_from(SCENE, max_steps=np.int64(100), samples=np.int32(50), steps=np.int64(10),
                                   table_nodes=np.int64(64))
    assert all(type(getattr(given, k)) is int for k in ("max_steps", "samples", "steps", "table_nodes"))
    # equinox wanted a Python int (the program of the budget test above: 64 steps of a long span)
    assert "max_steps = 64" in assurjax.simulate(SCENE, **{**LEAN, "t1": 1e12}, stop=None, max_steps=np.int64(64)).status
    # TracerBoolConversionError in diffrax's checkpointed loop (batch_simulate's too: the same settings_from)
    q, _ = synthesis.final_state(SCENE, 0.2, max_steps=np.int64(1000))
    assert abs(q - reference) < 1e-6


@pytest.mark.parametrize("name", ["q0", "t1", "dt"])
def test_simulate_under_jit_says_it_cannot_be_traced_and_what_can(name):
    value = {"q0": 0.1, "t1": 0.1, "dt": 1e-3}[name]
    with raises(f"'{name}' is traced", "assurjax.simulate_core", "synthesis.final_state"):
        jax.jit(lambda v: assurjax.simulate(SCENE, **{name: v}).q_final)(value)


def test_simulate_and_batch_simulate_traced_otherwise_say_so():
    with raises("'q0' is traced", "simulate_core"):
        jax.grad(lambda q0: assurjax.simulate(SCENE, q0=q0).q_final)(0.1)
    with raises("'mechanism' is traced"):
        jax.jit(lambda m: assurjax.simulate(SCENE, mechanism=m).q_final)(MECH)
    with raises("batch_simulate", "'q0' is traced"):
        jax.jit(lambda q0: assurjax.batch_simulate(SCENE, PAIR, q0=q0).q_final)(0.1)


@pytest.mark.parametrize("keyword, value", [("gravity", "down"), ("gravity", ["a", "b"]), ("saveat", "abc"),
                                            ("saveat", [0.0, "x"])])
def test_strings_where_numbers_go_are_named(keyword, value):
    with raises(keyword, "must be a number or an array of numbers"):
        assurjax.simulate(SCENE, t1=0.2, **{keyword: value})


def test_one_load_alone_is_the_only_load_and_no_sequence_is_refused():
    rough = assurjax.JointFriction("A", 0.1, radius=0.01)
    assert assurjax.Model(MECH, loads=rough).loads == (rough,)
    assert as_model(SCENE, loads=rough).loads == (rough,)  # simulate's and final_state's keyword
    for loads in ("rough", 3, {"A": rough}):
        with raises("loads must be a sequence of loads"):
            assurjax.simulate(SCENE, t1=0.2, loads=loads)


def test_a_plain_string_is_one_name_for_points_angles_and_coms():
    settings = assurjax.settings_from(SCENE, points="A", angles="crank", coms="rod")
    assert (settings.points, settings.angles, settings.coms) == (("A",), ("crank",), ("rod",))
    with raises("setting 'points'", "unknown point 'AB'"):
        assurjax.simulate(SCENE, t1=0.2, points="AB")  # saved A and B
    with raises("setting 'coms'", "unknown link 'cranks'"):
        assurjax.simulate(SCENE, t1=0.2, coms="cranks")
    with raises("setting 'angles'", "expected a sequence of names"):
        assurjax.simulate(SCENE, t1=0.2, angles=3)
    for key in ("velocities", "accelerations"):
        with raises(f"setting '{key}'", "True or False"):
            assurjax.simulate(SCENE, t1=0.2, **{key: "yes"})


def test_throw_must_be_a_flag():
    with raises("setting 'throw'", "True or False"):
        assurjax.simulate(SCENE, t1=0.2, throw="yes")


def test_final_state_refuses_a_step_past_its_span_and_a_stop():
    """dt = 1e6 over 0.2 s took one step of the span (omega 1110 rad/s); stop= was dropped."""
    from assurjax import synthesis

    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(assurjax.AssurjaxError, match="setting 'dt'"):
        synthesis.final_state(scene, 0.2, dt=1e6)
    with pytest.raises(assurjax.AssurjaxError, match="stop='standstill'.*standstill_time"):
        synthesis.final_state(scene, 0.2, stop="standstill")


@pytest.mark.parametrize("spread", ["relative", "absolute"])
def test_perturb_spreads_are_half_widths_at_least_zero(spread):
    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(assurjax.AssurjaxError, match=f"perturb: {spread}.*negative"):
        assurjax.perturb(scene.mechanism, jax.random.key(0), 4, **{spread: -1.0})
