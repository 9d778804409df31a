"""Which link a load at a shared joint acts on (its carrier), and loads at a link's
centre of mass ("com:<link>").

The bundled slider-crank (tests/joint_reference.py's slider_crank) with a spring from
the frame pivot O to the joint B, a force at B, and a force and a damper at the rod's
centre of mass. Against the joint-coordinate reference (numpy/scipy, its own springs
and point loads on explicit bodies): the joint reactions and driving effort with each
end on each possible carrier; the reactions of two carriers differ by the load; the
motion does not depend on the carrier; TOML and Python build the same loads; bad
carriers are rejected in words.
"""

import os
import sys
import tomllib
from importlib import resources

import jax
import numpy as np
import pytest

import assurjax as aj
from assurjax.scene._load import scene_from_dict

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402

SCENE = aj.load_scene("slider_crank")  # the reference's slider_crank, same masses and lengths
SCENE_TEXT = (resources.files("assurjax.scenes") / "slider_crank.toml").read_text()
ROD, ROD_COM = jr.SLIDER_CRANK["l"], (jr.SLIDER_CRANK["l"] / 2, 0.0)

# states (q, w, dw/dt): the reactions are compared at all of them in one call
Q, W, WDOT = np.array([0.3, 1.9, 4.0]), np.array([2.0, -3.0, 5.0]), np.array([1.0, -4.0, 0.5])
STIFFNESS, FREE_LENGTH = 150.0, 0.1  # spring O-B: about 35 N
F_B, F_COM, C_COM = (-20.0, 15.0), (12.0, -30.0), 4.0

# where each (point, carrier) is in the reference: (body, point in its frame)
REFERENCE_POINT = {
    ("O", "ground"): (jr.GROUND, (0.0, 0.0)), ("O", "crank"): ("crank", (0.0, 0.0)),
    ("B", "rod"): ("rod", (ROD, 0.0)), ("B", "slider"): ("slider", (0.0, 0.0)),
    ("com:rod", "rod"): ("rod", ROD_COM),
}
# our reaction (on the later link by the earlier) = sign * the reference's (on body_i by body_j)
OURS = {"O": ("O", -1.0), "A": ("A", -1.0), "B": ("B", -1.0), "slider/ground": ("P", -1.0)}


def _reference_spring(carriers):
    (ba, sa), (bb, sb) = REFERENCE_POINT[("O", carriers[0])], REFERENCE_POINT[("B", carriers[1])]
    return jr.Spring("spring", ba, sa, bb, sb, STIFFNESS, FREE_LENGTH)


def _reference_point_load(point, carrier, force):
    body, s = REFERENCE_POINT[(point, carrier)]
    return jr.PointLoad(f"{point} on {carrier}", body, s, force)


COM_DAMPER = jr.Damper("damper", jr.GROUND, (0.0, 0.0), "rod", ROD_COM, C_COM)


def _reference_states(springs=(), point_loads=(), dampers=()):
    """Reference at every state: (reactions in our convention, couple of slider/ground,
    driving effort, the springs' and point loads' forces [(body, point, force)])."""
    out = []
    for q, w, wdot in zip(Q, W, WDOT):
        model = jr.with_loads(jr.slider_crank(q, w), springs, point_loads, dampers)
        s = model.system
        z, _ = s.newton(q, s.to_internal(model.initial.coords))
        tau, lam, _, _ = s.inverse_dynamics(z, w, wdot)
        forces, couples = s.reactions(z, lam)
        ours = {name: sign * forces[theirs] for name, (theirs, sign) in OURS.items()}
        out.append((ours, -couples["P"], tau, s.applied_point_forces(z)))
    return out


def _ours(loads):
    r = aj.reactions(aj.Model(SCENE.mechanism, SCENE.gravity, tuple(loads)), (Q, W, WDOT))
    return {k: np.asarray(v) for k, v in r.forces.items()}, np.asarray(r.couples["slider/ground"]), np.asarray(r.driving)


def _assert_matches_reference(ours, reference):
    forces, couple, driving = ours
    for k, (ref_forces, ref_couple, ref_tau, _) in enumerate(reference):
        for name, f in ref_forces.items():
            np.testing.assert_allclose(forces[name][k], f, rtol=0, atol=1e-9, err_msg=f"{name} at state {k}")
        assert abs(couple[k] - ref_couple) < 1e-9
        assert abs(driving[k] - ref_tau) < 1e-9


# spring carriers (O end, B end) in our keywords -> the carriers they mean
SPRING_CARRIERS = {
    (None, None): ("ground", "rod"),  # the default: the points' owners
    ("crank", ""): ("crank", "rod"),
    (None, "slider"): ("ground", "slider"),
    ("ground", "rod"): ("ground", "rod"),
}


@pytest.fixture(scope="module")
def springs():
    """Our reactions and the reference's for every spring carrier, computed once."""
    out = {}
    for links, carriers in SPRING_CARRIERS.items():
        reference = _reference_states(springs=[_reference_spring(carriers)])
        ours = _ours([aj.Spring("O", "B", STIFFNESS, FREE_LENGTH, links=links)])
        out[links] = ours, reference
    return out


@pytest.mark.parametrize("links", SPRING_CARRIERS)
def test_spring_reactions_match_the_reference_on_each_carrier(springs, links):
    ours, reference = springs[links]
    _assert_matches_reference(ours, reference)


def _end_force(reference, k, body):
    """The reference's spring force (N) on ``body`` at state k."""
    (found,) = [f for b, _, f in reference[k][3] if b == body]
    return found


@pytest.mark.parametrize("joint, base, moved, body", [
    ("O", (None, None), ("crank", ""), "crank"),       # O end: ground -> crank
    ("B", (None, None), (None, "slider"), "slider"),   # B end: rod -> slider
])
def test_spring_reactions_of_two_carriers_differ_by_the_spring_force(springs, joint, base, moved, body):
    """Moving one end from the earlier link to the later one changes the reaction on the
    later link by minus that end's force, and nothing else (other joints, driving effort)."""
    (f0, c0, d0), _ = springs[base]
    (f1, c1, d1), reference = springs[moved]
    for k in range(len(Q)):
        end = _end_force(reference, k, body)
        assert np.linalg.norm(end) > 10.0  # a real load, so a lost carrier would show
        np.testing.assert_allclose(f1[joint][k] - f0[joint][k], -end, rtol=0, atol=1e-9)
    for name in f0:
        if name != joint:
            np.testing.assert_allclose(f1[name], f0[name], rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(d1, d0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(c1, c0, rtol=0, atol=1e-9)


def test_explicit_default_carrier_is_the_default(springs):
    (f0, _, _), _ = springs[(None, None)]
    (f1, _, _), _ = springs[("ground", "rod")]
    for name in f0:
        np.testing.assert_array_equal(f0[name], f1[name])


def test_force_at_a_joint_on_each_carrier():
    """A force at B on the rod (the default) and on the slider: each against the
    reference, and r["B"] (on the slider by the rod) differs by minus the force."""
    found = {}
    for link in ("rod", "slider"):
        found[link] = _ours([aj.PointForce("B", F_B, link=None if link == "rod" else link)])
        _assert_matches_reference(found[link], _reference_states(point_loads=[_reference_point_load("B", link, F_B)]))
    difference = found["slider"][0]["B"] - found["rod"][0]["B"]
    np.testing.assert_allclose(difference, np.broadcast_to(-np.asarray(F_B), difference.shape), rtol=0, atol=1e-9)
    np.testing.assert_allclose(found["slider"][0]["A"], found["rod"][0]["A"], rtol=0, atol=1e-9)


def test_force_and_damper_at_a_centre_of_mass():
    """A force and a damper end at "com:rod": on the rod at its COM in the reference."""
    ours = _ours([aj.PointForce("com:rod", F_COM), aj.Damper("com:rod", "O", C_COM, links=("rod", None))])
    reference = _reference_states(point_loads=[_reference_point_load("com:rod", "rod", F_COM)], dampers=[COM_DAMPER])
    _assert_matches_reference(ours, reference)


# ---------------------------------------------------------------- the motion

TOML_LOADS = f"""
[[loads]]
type = "spring"
points = ["O", "B"]
links = ["crank", "slider"]
stiffness = {STIFFNESS}
free_length = {FREE_LENGTH}

[[loads]]
type = "force"
point = "B"
link = "slider"
force = [{F_B[0]}, {F_B[1]}]

[[loads]]
type = "force"
point = "com:rod"
force = [{F_COM[0]}, {F_COM[1]}]

[[loads]]
type = "damper"
points = ["com:rod", "O"]
coefficient = {C_COM}
"""


def _loads(o_carrier, b_carrier):
    return (aj.Spring("O", "B", STIFFNESS, FREE_LENGTH, links=(o_carrier, b_carrier)), aj.PointForce("B", F_B, link=b_carrier),
            aj.PointForce("com:rod", F_COM), aj.Damper("com:rod", "O", C_COM))


DEFAULT_LOADS, MOVED_LOADS = _loads(None, None), _loads("crank", "slider")
TS = np.linspace(0.0, 0.6, 7)
RUN = dict(q0=0.5, omega0=0.0, t1=0.6, saveat=TS, stop=None, rtol=1e-12, atol=1e-12, max_steps=20000)


@pytest.fixture(scope="module")
def motions():
    return {name: aj.simulate(aj.Model(SCENE.mechanism, SCENE.gravity, loads), **RUN)
            for name, loads in (("default", DEFAULT_LOADS), ("moved", MOVED_LOADS))}


def test_motion_does_not_depend_on_the_carrier(motions):
    a, b = motions["default"], motions["moved"]
    assert np.ptp(np.asarray(a.q)) > 0.5  # it really moves
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(b.omega, a.omega, rtol=0, atol=1e-9)


def test_motion_matches_the_reference(motions):
    """Spring O-B, force at B, force and damper at the rod's COM, from rest at q = 0.5."""
    model = jr.with_loads(jr.slider_crank(0.5, 0.0), springs=[_reference_spring(("ground", "rod"))],
                          point_loads=[_reference_point_load("B", "rod", F_B), _reference_point_load("com:rod", "rod", F_COM)],
                          dampers=[COM_DAMPER])
    run = model.simulate(0.6, t_eval=TS)
    np.testing.assert_allclose(motions["moved"].q, run.q, rtol=0, atol=1e-7)
    np.testing.assert_allclose(motions["moved"].omega, run.w, rtol=0, atol=1e-6)


# ---------------------------------------------------------------- TOML = Python


def test_toml_builds_the_python_loads():
    scene = scene_from_dict(tomllib.loads(SCENE_TEXT + TOML_LOADS))
    assert jax.tree.structure(scene.loads) == jax.tree.structure(MOVED_LOADS)  # points and carriers are static fields
    for ours, python in zip(jax.tree.leaves(scene.loads), jax.tree.leaves(MOVED_LOADS)):
        np.testing.assert_array_equal(ours, python)
    assert [load.links for load in scene.loads if hasattr(load, "links")] == [("crank", "slider"), (None, None)]
    assert [load.link for load in scene.loads if hasattr(load, "link")] == ["slider", None]


def test_toml_empty_carrier_is_the_default():
    text = SCENE_TEXT + '[[loads]]\ntype = "spring"\npoints = ["O", "B"]\nlinks = ["", "slider"]\nstiffness = 1.0\n'
    (spring,) = scene_from_dict(tomllib.loads(text)).loads
    assert spring.links == (None, "slider")


# ---------------------------------------------------------------- bad carriers

BAD_TOML = [
    ('type = "force"\npoint = "B"\nlink = "crank"\nforce = [1.0, 0.0]',
     r"#1 \(force\), field 'link': link 'crank' does not carry point 'B' \(carried by \['rod', 'slider'\]\)"),
    ('type = "force"\npoint = "B"\nlink = "bogie"\nforce = [1.0, 0.0]', r"#1 \(force\), field 'link': unknown link 'bogie'"),
    ('type = "spring"\npoints = ["O", "B"]\nlinks = ["rod", ""]\nstiffness = 1.0',
     r"#1 \(spring\), field 'links': entry 1 \(end 'O'\): link 'rod' does not carry point 'O' \(carried by \['ground', 'crank'\]\)"),
    ('type = "damper"\npoints = ["O", "B"]\nlinks = ["crank"]\ncoefficient = 1.0', r"#1 \(damper\), field 'links': expected a list of 2 names"),
    ('type = "spring"\npoints = ["O", "B"]\nlink = "crank"\nstiffness = 1.0', r"#1 \(spring\): unknown field\(s\) \['link'\]"),
    ('type = "force"\npoint = "com"\nlink = "rod"\nforce = [1.0, 0.0]',
     r"#1 \(force\), field 'point': unknown point 'com' .*centre of mass is written 'com:<link>'"),
    ('type = "force"\npoint = "com:bogie"\nforce = [1.0, 0.0]', r"#1 \(force\), field 'point': unknown link 'bogie' in 'com:bogie'"),
    ('type = "force"\npoint = "com:rod"\nlink = "slider"\nforce = [1.0, 0.0]',
     r"field 'link': link 'slider' does not carry point 'com:rod' \(carried by \['rod'\]\)"),
    ('type = "damper"\npoints = ["com:rod", "B"]\nlinks = ["crank", ""]\ncoefficient = 1.0',
     r"field 'links': entry 1 \(end 'com:rod'\): link 'crank' does not carry point 'com:rod'"),
    ('type = "rotary_damper"\njoint = "com:rod"\ncoefficient = 1.0', r"#1 \(rotary_damper\), field 'joint': point 'com:rod' must be a joint of exactly two links .*carried by \['rod'\]"),
]


@pytest.mark.parametrize("table, message", BAD_TOML)
def test_bad_carrier_in_a_scene_is_named(table, message):
    with pytest.raises(aj.SceneError, match=message):
        scene_from_dict(tomllib.loads(SCENE_TEXT + "[[loads]]\n" + table + "\n"), source="scene.toml")


BAD_PYTHON = [
    (lambda: aj.PointForce("B", F_B, link="crank"), r"force on point 'B', argument 'link': link 'crank' does not carry point 'B'"),
    (lambda: aj.Spring("O", "B", 1.0, links=(None, "crank")), r"spring O-B, argument 'links\[1\]': link 'crank' does not carry point 'B'"),
    (lambda: aj.Damper("O", "B", 1.0, links=("bogie", None)), r"damper O-B, argument 'links\[0\]': unknown link 'bogie'"),
    (lambda: aj.PointForce("com", F_B, link="rod"), r"unknown point 'com' .*'com:<link>'"),
    (lambda: aj.PointForce("com:ground", F_B), r"unknown link 'ground' in 'com:ground'"),
    (lambda: aj.PointForce("com:rod", F_B, link="slider"), r"link 'slider' does not carry point 'com:rod' \(carried by \['rod'\]\)"),
]


@pytest.mark.parametrize("make, message", BAD_PYTHON)
def test_bad_carrier_in_python_is_named(make, message):
    with pytest.raises(aj.MechanismError, match=message):
        aj.Model(SCENE.mechanism, SCENE.gravity, (make(),))


def test_links_must_be_one_per_end():
    with pytest.raises(aj.MechanismError, match=r"Spring: links must be \(carrier of a, carrier of b\)"):
        aj.Spring("O", "B", 1.0, links=("rod",))


def test_point_names_starting_with_com_are_reserved():
    text = SCENE_TEXT.replace('points = { A = [0.0, 0.0], B = [0.3, 0.0] }', 'points = { A = [0.0, 0.0], B = [0.3, 0.0], "com:x" = [0.1, 0.0] }')
    with pytest.raises(aj.SceneError, match=r"point name 'com:x': names starting with 'com:' are reserved"):
        scene_from_dict(tomllib.loads(text))


@pytest.mark.slow  # ~7 s; the default suite keeps to 10 min
def test_with_friction_in_the_pin_the_carrier_changes_the_driving_effort():
    """docs/kinetostatics.md's example, by its recipe: the press's friction alone (mu = 0.15
    in O, A, B of radius 0.01 m and on the ram's 0.05 m block) and (-300, 0) N at B, at
    q = 1, w = 2, dw/dt = 0, on the rod and on the ram."""
    press = aj.load_scene("press_with_friction")
    friction = tuple(l for l in press.loads if isinstance(l, (aj.JointFriction, aj.SlideFriction)))
    assert len(friction) == 4
    quoted = {"rod": (-27.154, 87.5), "ram": (-27.111, 298.3)}
    for link, (driving, r_b) in quoted.items():
        scene = press.with_loads(friction + (aj.PointForce("B", (-300.0, 0.0), link=link),))
        r = aj.reactions(scene, (1.0, 2.0, 0.0))
        assert round(float(r.driving), 3) == driving, link
        assert round(float(np.linalg.norm(r["B"])), 1) == r_b, link
