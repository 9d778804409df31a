"""Mechanisms from a sketch: joints where they are drawn, the Assur decomposition and
the assembly modes found by the package.

References, independent of the code under test:
- the bundled scenes themselves (hand-written formation sequences, modes, local
  frames): rebuilt from their joints drawn at q0 they must move identically;
- Jansen's leg from its 13 "holy numbers": a closed form written here (circle-circle
  intersections in numpy, branches chosen by which intersection is higher/further left);
- closed-form mass properties of a bar and a right triangle.
"""

from __future__ import annotations

import re
import time
import tomllib

import equinox as eqx
import jax
import numpy as np
import pytest

import assurjax
from assurjax import MechanismError, SceneError
from assurjax.structure import Sketch, Slide, build, decompose, explicit_toml, sketch_of
from slow_cases import marked_slow

# -- helpers --------------------------------------------------------------------------


def sweep_points(mechanism, qs):
    """Positions of every point at every q (numpy), and whether every group assembled."""
    pose = jax.vmap(lambda q: assurjax.positions(mechanism, q))(np.asarray(qs, dtype=float))
    return {p: np.asarray(x) for p, x in pose.points.items()}, np.asarray(pose.ok).all(axis=1)


def canonical(group):
    """(kind, links, branch) with the listing order factored out: an RRR listed (b, a)
    has the opposite mode of the same dyad listed (a, b); PRR is RRP listed from its slider."""
    kind, links, mode = group.kind, tuple(group.links), getattr(group, "mode", 0)
    if kind == "PRR":
        kind, links = "RRP", links[::-1]
    if kind == "RRR" and links != tuple(sorted(links)):
        links, mode = links[::-1], -mode
    if kind in ("triad", "class4", "PRP"):
        links = tuple(sorted(links))
    return kind, links, mode


def sweep_of(scene):
    q0 = scene.state["q0"]
    if scene.name == "tangent_drive":  # assembles on (0, pi) only
        return np.linspace(0.1, np.pi - 0.1, 61)
    return q0 + np.linspace(-np.pi, np.pi, 121)


# -- every bundled scene, rebuilt from its drawing ----------------------------------------


# the triad's and the class-IV scene's sweeps in the slow suite (~25 s each): both kinds are decomposed from
# random drawings by default (test_sketch_random.py)
@pytest.mark.parametrize("name", marked_slow(assurjax.bundled_scenes(), ("triad_mechanism", "class4_seed003")))
def test_bundled_scene_rebuilt_from_its_joints(name):
    scene = assurjax.load_scene(name)
    original = scene.mechanism
    q0 = scene.state["q0"]
    pose = assurjax.positions(original, q0)
    # the drawing: every point where the scene's own mechanism puts it at q0
    sk = sketch_of(original, q0)
    for p, x in sk.joints.items():
        assert np.array_equal(x, np.asarray(pose.points[p]))
    rebuilt = build(sk).mechanism
    assert sorted(map(canonical, rebuilt.groups)) == sorted(map(canonical, original.groups))
    qs = sweep_of(scene)
    expected, ok_a = sweep_points(original, qs)
    got, ok_b = sweep_points(rebuilt, qs)
    # same assembly range (the Roberts linkage turns through part of a revolution only)
    assert np.array_equal(ok_a, ok_b) and ok_a.sum() >= len(qs) // 4
    for p in original.point_names:
        assert np.max(np.abs(got[p] - expected[p])[ok_a]) <= 1e-12, p


@pytest.mark.parametrize("name", assurjax.bundled_scenes())
def test_bundled_scene_round_trips_through_the_explicit_form(name):
    scene = assurjax.load_scene(name)
    scene = scene.with_loads(()) if scene.loads else scene  # the explicit form writes no loads (yet): the mechanism's round trip
    again = assurjax.scene_from_dict(tomllib.loads(explicit_toml(scene)), source=f"{name}.toml")
    leaves_a, tree_a = jax.tree.flatten(scene.mechanism)
    leaves_b, tree_b = jax.tree.flatten(again.mechanism)
    assert tree_a == tree_b
    assert all(np.array_equal(a, b) for a, b in zip(leaves_a, leaves_b))
    assert dict(again.state) == dict(scene.state) and again.name == scene.name


# -- Jansen's leg ------------------------------------------------------------------------

HOLY = dict(a=38.0, b=41.5, c=39.3, d=40.1, e=55.8, f=39.4, g=36.7, h=65.7, i=49.0, j=50.0, k=61.9, l=7.8, m=15.0)


def circles(p, r, q, s):
    """Both intersections of the circles (p, r) and (q, s)."""
    d = q - p
    dist = np.hypot(d[0], d[1])
    along = (r**2 - s**2 + dist**2) / (2 * dist)
    height = np.sqrt(r**2 - along**2)
    foot = p + along * d / dist
    normal = np.array([-d[1], d[0]]) / dist
    return foot + height * normal, foot - height * normal


def jansen_candidates(theta):
    """Both candidates of every constructed joint of Jansen's leg (holy numbers, in their
    units) at crank angle theta, with the chosen one: crank axle O at the origin, fixed
    pivot Z at (-a, -l); the leg hangs below: B and D are the lower intersections, C and
    E the ones further left, the foot F the lower one."""
    n = HOLY
    O, Z = np.zeros(2), np.array([-n["a"], -n["l"]])
    M = n["m"] * np.array([np.cos(theta), np.sin(theta)])
    lower = lambda pair: min(pair, key=lambda x: x[1])  # noqa: E731
    left = lambda pair: min(pair, key=lambda x: x[0])  # noqa: E731
    out = dict(O=(O, None), Z=(Z, None), M=(M, None))
    for name, (p, r, q, s, rule) in dict(B=("M", "j", "Z", "b", lower), D=("M", "k", "Z", "c", lower), C=("B", "d", "Z", "e", left),
                                         E=("C", "f", "D", "g", left), F=("E", "h", "D", "i", lower)).items():
        pair = circles(out[p][0], n[r], out[q][0], n[s])
        out[name] = (rule(pair), pair)
    return out


def jansen_closed_form(theta):
    return {k: v for k, (v, _) in jansen_candidates(theta).items()}


def jansen_sketch(theta0=0.4, names=None):
    names = names or {}
    rename = lambda j: names.get(j, j)  # noqa: E731
    joints = {rename(k): v for k, v in jansen_closed_form(theta0).items()}
    links = {"crank": ["O", "M"], "upper": ["M", "B"], "lower": ["M", "D"], "triangle": ["Z", "B", "C"],
             "rocker": ["Z", "D"], "bar": ["C", "E"], "foot": ["D", "E", "F"]}
    links = {k: [rename(j) for j in v] for k, v in links.items()}
    return Sketch(joints, links, ground=[rename("O"), rename("Z")], driver="crank", name="jansen")


def test_jansen_leg_foot_path_against_closed_form():
    sk = jansen_sketch()
    dec = decompose(sk)
    assert [g.kind for g in dec.groups] == ["crank", "RRR", "RRR", "RRR"] and dec.dof == 1
    mech = build(sk, check=True).mechanism
    thetas = np.linspace(0.0, 2 * np.pi, 181)
    got, ok = sweep_points(mech, thetas)
    assert ok.all()
    for p in "BCDEF":
        expected = np.array([jansen_closed_form(t)[p] for t in thetas])
        assert np.max(np.abs(got[p] - expected)) <= 1e-12, p
    # the closed form's branch choice is unambiguous over the turn: the two candidates stay apart
    for t in thetas:
        for name, (_, pair) in jansen_candidates(t).items():
            assert pair is None or np.hypot(*(pair[0] - pair[1])) > 10.0, name


def test_jansen_leg_independent_of_link_order_and_joint_names():
    names = {"B": "knee", "C": "hip", "E": "heel"}
    sk = jansen_sketch(theta0=2.0, names=names)
    shuffled = Sketch(sk.joints, dict(reversed(list(sk.links.items()))), ground=list(sk.ground)[::-1], driver="crank")
    mech = build(shuffled).mechanism
    thetas = np.linspace(0.0, 2 * np.pi, 37)
    got, ok = sweep_points(mech, thetas)
    expected = np.array([jansen_closed_form(t)["E"] for t in thetas])
    assert ok.all() and np.max(np.abs(got["heel"] - expected)) <= 1e-12


# -- the TOML sketch form, scenes, simulate/kinematics/reactions --------------------------

FOUR_BAR = """
    [scene]
    name = "fourbar"
    gravity = [0.0, -9.81]

    [sketch]
    driver = "crank"
    ground = ["A", "D"]
    joints = { A = [0.0, 0.0], B = [0.1, 0.2], C = [0.5, 0.3], D = [0.4, 0.0], P = [0.3, 0.45] }

    [sketch.links]
    crank = { joints = ["A", "B"], density = 2.0 }
    coupler = { joints = ["B", "C", "P"], density = 10.0 }
    rocker = { joints = ["D", "C"], mass = 0.3, inertia = 0.004 }

    [state]
    t1 = 0.5
"""


def four_bar_sketch():
    return Sketch({"A": (0.0, 0.0), "B": (0.1, 0.2), "C": (0.5, 0.3), "D": (0.4, 0.0), "P": (0.3, 0.45)},
                  {"crank": {"joints": ["A", "B"], "density": 2.0}, "coupler": {"joints": ["B", "C", "P"], "density": 10.0},
                   "rocker": {"joints": ["D", "C"], "mass": 0.3, "inertia": 0.004}},
                  ground=["A", "D"], driver="crank", name="fourbar")


def test_toml_sketch_equals_python_sketch(write_scene):
    scene = assurjax.load_scene(write_scene(FOUR_BAR))
    python = four_bar_sketch().mechanism()
    leaves_a, tree_a = jax.tree.flatten(scene.mechanism)
    leaves_b, tree_b = jax.tree.flatten(python)
    assert tree_a == tree_b and all(np.array_equal(a, b) for a, b in zip(leaves_a, leaves_b))
    assert scene.state["q0"] == pytest.approx(np.arctan2(0.2, 0.1), abs=1e-15)  # the drawn crank angle
    # the explicit form of the sketch scene reads back to the same mechanism
    again = assurjax.scene_from_dict(tomllib.loads(explicit_toml(scene)))
    assert jax.tree.structure(again.mechanism) == tree_a
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(again.mechanism), leaves_a))


def test_mass_properties_from_densities():
    mech = four_bar_sketch().mechanism()
    crank, coupler = mech.links["crank"], mech.links["coupler"]
    length = np.hypot(0.1, 0.2)
    assert float(crank.mass) == pytest.approx(2.0 * length, rel=1e-14)
    assert float(crank.inertia) == pytest.approx(2.0 * length**3 / 12, rel=1e-14)
    # triangle B, C, P: area by the cross product, centroid the vertex mean, polar moment
    # about the centroid (a^2 + b^2 + c^2) m / 36 (sides a, b, c)
    B, C, P = np.array([0.1, 0.2]), np.array([0.5, 0.3]), np.array([0.3, 0.45])
    (ux, uy), (vx, vy) = C - B, P - B
    area = abs(ux * vy - uy * vx) / 2
    sides2 = sum(np.sum((x - y) ** 2) for x, y in ((B, C), (C, P), (P, B)))
    m = 10.0 * area
    assert float(coupler.mass) == pytest.approx(m, rel=1e-13)
    assert float(coupler.inertia) == pytest.approx(m * sides2 / 36, rel=1e-12)
    pose = assurjax.positions(mech, np.arctan2(0.2, 0.1))
    assert np.allclose(pose.coms["coupler"], (B + C + P) / 3, atol=1e-15)
    assert float(mech.links["rocker"].mass) == 0.3


def test_a_rectangular_plate_in_any_order_around_it_and_a_crossed_outline_refused():
    # a 0.4 x 0.1 m coupler plate B, C, Q, P: mass rho w h, polar moment m (w^2 + h^2) / 12,
    # whichever corner and sense the outline starts from; listed across (B, Q, C, P: a bow
    # tie) its signed shoelace area was 0 or another quad's (mass 12x too small), unflagged
    joints = {"A": (0.0, 0.0), "B": (0.1, 0.2), "C": (0.5, 0.2), "Q": (0.5, 0.3), "P": (0.1, 0.3), "D": (0.6, -0.1)}

    def coupler(order):
        links = {"crank": {"joints": ["A", "B"]}, "coupler": {"joints": order, "density": 5.0}, "rocker": {"joints": ["D", "C"]}}
        return Sketch(joints, links, ground=["A", "D"], driver="crank").mechanism().links["coupler"]

    m = 5.0 * 0.4 * 0.1
    for order in (["B", "C", "Q", "P"], ["Q", "C", "B", "P"], ["P", "B", "C", "Q"]):
        plate = coupler(order)
        assert float(plate.mass) == pytest.approx(m, rel=1e-13)
        assert float(plate.inertia) == pytest.approx(m * (0.4**2 + 0.1**2) / 12, rel=1e-12)
    for order, edges in ((["B", "Q", "C", "P"], "edge B-Q meets edge C-P"), (["B", "C", "P", "Q"], "edge C-P meets edge Q-B")):
        with pytest.raises(MechanismError, match=f"link 'coupler': its joints .* cross themselves \\({edges}\\)"):
            coupler(order)
    # four joints on one line: no order makes a plate of them (said so, not that they cross)
    joints.update(Q=(0.3, 0.2), P=(0.4, 0.2))
    with pytest.raises(MechanismError, match="link 'coupler': the plate outline .* has zero area \\(collinear joints\\)"):
        coupler(["B", "C", "Q", "P"])


def test_sketch_scene_simulates_and_gives_reactions(write_scene):
    scene = assurjax.load_scene(write_scene(FOUR_BAR))
    sol = assurjax.simulate(scene, stop=None)
    assert sol.status == "done" or sol.t[-1] == pytest.approx(0.5)
    drift = float(sol.total[-1] - sol.total[0])
    assert abs(drift) < 1e-6 * float(np.ptp(sol.potential) + 1e-3)
    kin = assurjax.kinematics(scene.mechanism, np.linspace(0.5, 1.5, 5))
    assert np.all(np.isfinite(np.asarray(kin.points["P"])))
    r = assurjax.reactions(scene, sol, joints=["A", "C"])
    assert all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree.leaves(r))


# -- modes as names, Link defaults --------------------------------------------------------


def test_modes_as_names_everywhere():
    scene = assurjax.load_scene("watt_sixbar")
    named = [g if g.kind != "RRR" else type(g)(g.name, g.links, g.joints, "left") for g in scene.mechanism.groups]
    mech = assurjax.Mechanism(scene.mechanism.ground, scene.mechanism.links, named)
    a = assurjax.positions(mech, 0.3).points["E"]
    b = assurjax.positions(scene.mechanism, 0.3).points["E"]
    assert np.array_equal(np.asarray(a), np.asarray(b))
    g = scene.mechanism.groups[1]
    with pytest.raises(MechanismError, match="group 'dyad34' \\(RRR\\): mode must be"):
        type(g)(g.name, g.links, g.joints, "up")
    with pytest.raises(MechanismError, match="mode must be"):
        type(g)(g.name, g.links, g.joints, 2)


def test_link_defaults_match_the_scene_format(write_scene):
    scene = assurjax.load_scene(write_scene("""
        [ground]
        O = [0.0, 0.0]
        [links.crank]
        points = { O = [0.0, 0.0], A = [0.3, 0.1] }
        [[formation]]
        group = "crank"
        link = "crank"
        pivot = "O"
    """))
    from_toml = scene.mechanism.links["crank"]
    direct = assurjax.Link({"O": [0.0, 0.0], "A": [0.3, 0.1]})
    assert jax.tree.structure(from_toml) == jax.tree.structure(direct)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(from_toml), jax.tree.leaves(direct)))


# -- bad drawings ----------------------------------------------------------------------------

FOUR = dict(joints={"A": (0, 0), "B": (0.1, 0.2), "C": (0.5, 0.3), "D": (0.4, 0)},
            links={"crank": ["A", "B"], "coupler": ["B", "C"], "rocker": ["D", "C"]}, ground=["A", "D"], driver="crank")


def four(**changes):
    kw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in FOUR.items()}
    for k, v in changes.items():
        if isinstance(v, dict) and k in ("joints", "links"):
            kw[k].update(v)
        else:
            kw[k] = v
    return kw


BAD = {
    "over-constrained": (four(links={"brace": ["A", "C"]}), "over-constrained: Gruebler's count 3\\*4 - 2\\*\\(6 revolute.*= 0.*link 'brace' is over-constrained.*joint A, joint C"),
    "under-constrained": (four(joints={"E": (0.7, 0.1)}, links={"rocker": ["C", "E"], "tail": ["E", "D"]}),
                          "under-constrained: .*= 2.*links rocker, tail|links coupler, rocker, tail"),
    "disconnected": (four(joints={"X": (2, 2), "Y": (3, 2)}, links={"float": ["X", "Y"]}), "disconnected: links float"),
    "coincident joints": (four(joints={"C": (0.1, 0.2000000000001)}), "link 'coupler': joints 'B' and 'C' coincide"),
    "external joints coincide": (four(joints={"D": (0.1, 0.2)}), "external joints 'B' and 'D' coincide"),
    "slide without direction": (four(slides=[{"link": "rocker", "on": "ground"}]), "slide of 'rocker' on 'ground': no direction"),
    "driver not grounded": (four(driver="coupler"), "driver 'coupler' is neither pinned to the ground nor sliding on it"),
    "unknown joint": (four(links={"rocker": ["D", "Q"]}), "link 'rocker' uses joint\\(s\\) \\['Q'\\]"),
    "unused joint": (four(joints={"Q": (1, 1)}), "joint\\(s\\) \\['Q'\\] belong to no link"),
    "coordinates as strings": (four(joints={"C": ("0.5", "0.3")}), "joint 'C': a point \\[x, y\\] \\(m\\) must be a number or an array of numbers"),
    "a coordinate as a flag": (four(joints={"C": (True, 0.3)}), "joint 'C': a point \\[x, y\\] \\(m\\) must be a number or an array of numbers"),
    "ground as one string": (four(ground="AD"), "ground: expected a list of joint names, got 'AD'"),
    "no ground list": (four(ground=None), "ground: expected a list of joint names, got None"),
    "a joint beyond 1e12 m": (four(joints={"C": (1e200, 0.3)}), "joint 'C': a point \\[x, y\\] \\(m\\) must be at most 1e\\+12 in magnitude"),
    "an empty joint name": ({**FOUR, "joints": {"A": (0, 0), "B": (0.1, 0.2), "": (0.5, 0.3), "D": (0.4, 0)},
                             "links": {"crank": ["A", "B"], "coupler": ["B", ""], "rocker": ["D", ""]}},
                            "a point has an empty name ''"),
    # length 1.4e-160: its square 2e-320 is flushed to zero by JAX, as a drawing's below 1e-100 m
    "a slide direction too short to square": (
        four(slides=[{"link": "rocker", "on": "ground", "direction": (1e-160, 1e-160)}]),
        "slide of 'rocker' on 'ground': the direction must be a non-zero vector at least 1e-100 long"),
    "a drawing too small to square": ({**FOUR, "joints": {k: (1e-200 * x, 1e-200 * y) for k, (x, y) in FOUR["joints"].items()}},
                                      "the drawing spans 5e-201 m; at least 1e-100 m"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_drawings_are_rejected_by_name(case):
    kwargs, message = BAD[case]
    with pytest.raises(MechanismError, match=message):
        Sketch(**kwargs).mechanism()


def test_a_drawing_moved_far_from_the_origin_keeps_its_modes():
    # a 10 cm four-bar drawn in its lower mode (C below the line B-D), moved up to 10 km away: the
    # tolerances follow the drawing's extent, not its distance from the origin
    base = {"A": (0.0, 0.0), "B": (0.02, 0.04), "C": (0.04674, -0.03275), "D": (0.08, 0.0)}
    links = {"crank": ["A", "B"], "coupler": ["B", "C"], "rocker": ["D", "C"]}
    for offset in (0.0, 1e3, 1e4):
        joints = {k: (x + offset, y - offset) for k, (x, y) in base.items()}
        built = build(Sketch(joints, links, ground=["A", "D"], driver="crank"), check=True)  # reproduces the drawing
        assert built.mechanism.groups[1].mode == -1 and not built.notes, offset


def test_a_far_joint_elsewhere_leaves_a_groups_mode_as_drawn():
    # a 10 cm dyad drawn 10 um (2e-4 rad of its arms) from its singular configuration, in its
    # negative mode, beside a pointer 50 m long on the crank: the band that leaves a mode
    # ambiguous is the group's own, not the drawing's (it was, and mode +1 was taken)
    B, D = np.array([0.02, 0.04]), np.array([0.08, 0.0])
    normal = np.array([(D - B)[1], -(D - B)[0]]) / np.hypot(*(D - B))  # to the right of B -> D
    for pointer in (None, (50.0, 0.0)):
        joints = {"A": (0.0, 0.0), "B": tuple(B), "C": tuple((B + D) / 2 + 1e-5 * normal), "D": tuple(D)}
        links = {"crank": ["A", "B"], "coupler": ["B", "C"], "rocker": ["D", "C"]}
        if pointer:
            joints["P"], links["crank"] = pointer, ["A", "B", "P"]
        built = build(Sketch(joints, links, ground=["A", "D"], driver="crank"), check=True)  # reproduces the drawing
        assert built.mechanism.groups[1].mode == -1 and not built.notes, pointer
    # a slider whose rod is drawn 10 um from perpendicular to its guide, beside the same pointer
    joints = {"A": (0.0, 0.0), "B": (0.02, 0.04), "C": (0.02 - 1e-5, -0.1), "P": (50.0, 0.0)}
    sk = Sketch(joints, {"crank": ["A", "B", "P"], "rod": ["B", "C"], "block": ["C"]}, ground=["A"],
                slides=[Slide("block", "ground", (1, 0))], driver="crank")
    built = build(sk, check=True)
    assert not built.notes
    flipped = build(Sketch({**joints, "C": (0.02 + 1e-5, -0.1)}, sk.links, ground=["A"], slides=sk.slides, driver="crank"), check=True)
    assert built.mechanism.groups[1].mode == -flipped.mechanism.groups[1].mode and not flipped.notes


SCENE_SETTINGS = {
    "t1 before t0": (dict(t1=-1.0), "setting 't1': must be later than t0"),
    "omega0 a word": (dict(omega0="fast"), "setting 'omega0': must be a number"),
    "omega0 nan": (dict(omega0=float("nan")), "setting 'omega0': must be finite"),
    "q0 absurd": (dict(q0=1e300), "setting 'q0': must be at most 1e\\+12"),
    "gravity in 3-D": (dict(gravity=(0, -9.81, 0)), "setting 'gravity': must be a 2-vector"),
    "a typo in simulation": (dict(simulation={"rtoll": 1e-6}), "simulation: unknown field 'rtoll'"),
    "a typo in outputs": (dict(outputs={"point": ["C"]}), "outputs: unknown field 'point'"),
    "a word for a flag": (dict(outputs={"energies": "no"}), "outputs, field 'energies': expected true or false"),
    # the loads are checked against the drawn mechanism as with_loads checks them (they were taken unchecked)
    "a load that is a word": (dict(loads=["A", 3.0]), "load #1: expected an assurjax load"),
    "loads a number": (dict(loads=3.0), "Sketch.scene: loads must be a sequence of loads or one load"),
    "friction at a joint not drawn": (dict(loads=[assurjax.JointFriction("Z", 0.1, 0.01)]),
                                      "JointFriction: 'Z' is not a revolute joint of the mechanism"),
    "slide friction without a slide": (dict(loads=[assurjax.SlideFriction("coupler/crank", 0.1, 0.01)]),
                                       "SlideFriction: 'coupler/crank' is not a prismatic pair"),
}


@pytest.mark.parametrize("case", list(SCENE_SETTINGS))
def test_sketch_scene_settings_are_checked_by_name(case):
    settings, message = SCENE_SETTINGS[case]
    with pytest.raises(assurjax.AssurjaxError, match=message):
        Sketch(**FOUR).scene(**settings)


def test_one_load_alone_is_the_sketch_scenes_only_load():
    pin = assurjax.JointFriction("B", 0.1, 0.01)
    assert Sketch(**FOUR).scene(loads=pin).loads == (pin,)


def test_a_massless_drawing_has_kinematics_and_no_dynamics():
    # the sketch's default: no masses. Positions work; the forward dynamics (a zero reduced
    # inertia) says so before anything is traced, where it ran into a NaN at t0
    scene = Sketch(**FOUR).scene(gravity=(0.0, -9.81))
    assert np.asarray(assurjax.positions(scene.mechanism, 1.0).ok).all()
    message = "mechanism 'sketch': no link has a mass or a moment of inertia"
    for run in (lambda: assurjax.simulate(scene), lambda: assurjax.synthesis.final_state(scene, 0.5),
                lambda: assurjax.synthesis.final_state(scene, 0.5, adjoint="sensitivity")):
        with pytest.raises(assurjax.AssurjaxError, match=message):
            run()
    batch = jax.tree.map(lambda x: np.stack([x, x]), four_bar_sketch().mechanism())
    batch = eqx.tree_at(lambda m: m.links["crank"].mass, batch, np.array([0.1, 0.0]))
    for link in ("coupler", "rocker"):
        batch = eqx.tree_at(lambda m: (m.links[link].mass, m.links[link].inertia), batch, (np.zeros(2), np.zeros(2)))
    batch = eqx.tree_at(lambda m: m.links["crank"].inertia, batch, np.zeros(2))
    with pytest.raises(assurjax.AssurjaxError, match="mechanism 'fourbar' \\(batch member 1\\): no link has a mass"):
        assurjax.batch_simulate(scene.replace_mechanism(four_bar_sketch().mechanism()), batch, t1=0.1)


def test_a_typo_in_a_scenes_outputs_is_named_by_simulate():
    scene = assurjax.load_scene("slider_crank").with_settings(outputs={"point": ["B"]})
    with pytest.raises(assurjax.AssurjaxError, match="\\[outputs\\]: unknown field 'point'"):
        assurjax.simulate(scene)


def test_parallel_guides_do_not_close():
    # a PRP dyad whose two guides are drawn parallel: its joint is not determined
    sk = Sketch({"O": (0, 0), "K": (0.1, 0.0), "J": (0.2, 0.0)}, {"crank": ["O", "K"], "block": ["J"], "slide": ["J"]},
                ground=["O"], slides=[Slide("block", "crank", (1, 0)), Slide("slide", "ground", (1, 0))], driver="crank")
    with pytest.raises(MechanismError, match="PRP.*links block, slide.*parallel.*joint 'J'"):
        sk.mechanism()


def test_undecomposable_topology_is_rejected_with_its_links():
    # an RPP dyad: a rod pinned at B slides in a block that slides on the ground (one DOF, no such kind)
    sk = Sketch({"A": (0, 0), "B": (0.1, 0.1), "S": (0.4, 0.0)}, {"crank": ["A", "B"], "rod": ["B"], "block": ["S"]}, ground=["A"],
                slides=[Slide("rod", "block", (1, 0.3)), Slide("block", "ground", (1, 0))], driver="crank")
    with pytest.raises(MechanismError, match="links 'rod' and 'block' form an RPP dyad, which is not one of the package's kinds"):
        sk.mechanism()
    # a class-III triad hung on a slider instead of a binary link: outside the kinds
    pts = {"O": (0, 0), "A": (0.1, 0), "P1": (0.3, 0.2), "P2": (0.6, 0.4), "P3": (0.6, 0.0), "E2": (0.4, 1.0), "P": (0.9, 0.0)}
    links = {"crank": ["O", "A"], "L1": ["A", "P1"], "T": ["P1", "P2", "P3"], "L2": ["E2", "P2"], "block": ["P3"]}
    sk = Sketch(pts | {}, links | {}, ground=["O", "E2", "P"], slides=[Slide("block", "ground", (0.2, 1.0))], driver="crank")
    with pytest.raises(MechanismError, match="links L1, T, L2, block cannot be decomposed"):
        sk.mechanism()


def four_bar_chain(n: int) -> tuple[dict, dict]:
    """Joints and links of n four-bar windows in a row (IFToMM A02's N-four-bar, rockers pulled
    aside in turn): rockers O_i -> B_i on the ground pivots O_i, couplers B_i -> B_i+1."""
    joints = {f"O{i}": (float(i), 0.0) for i in range(n + 1)} | {f"B{i}": (i + 0.1 * (-1) ** i, 0.98) for i in range(n + 1)}
    links = {f"rocker{i}": [f"O{i}", f"B{i}"] for i in range(n + 1)} | {f"coupler{i}": [f"B{i}", f"B{i + 1}"] for i in range(n)}
    return joints, links


def triad_chain(n: int) -> tuple[dict, dict, list]:
    """Joints, links and ground joints of a crank and n class-III triads, each hung on the one
    before: plate k (P, Q, R) on arm k from the previous plate's P (the crank's A for the first)
    and on upper k, lower k from the ground joints E, F."""
    joints, links, ground, last = {"O": (0.0, 0.0), "A": (0.3, 0.1)}, {"crank": ["O", "A"]}, ["O"], "A"
    for k in range(n):
        joints |= {f"E{k}": (k + 1.0, 0.5), f"F{k}": (k + 1.0, -0.5), f"P{k}": (k + 0.35, 0.05), f"Q{k}": (k + 0.65, 0.25),
                   f"R{k}": (k + 0.65, -0.2)}
        links |= {f"plate{k}": [f"P{k}", f"Q{k}", f"R{k}"], f"arm{k}": [last, f"P{k}"], f"upper{k}": [f"E{k}", f"Q{k}"],
                  f"lower{k}": [f"F{k}", f"R{k}"]}
        ground += [f"E{k}", f"F{k}"]
        last = f"P{k}"
    return joints, links, ground


def test_an_under_constrained_chain_is_named_in_a_few_words():
    # 300 windows without rocker1: only the crank is placed, and Gruebler's count is 2 (a bar
    # less: 3 coordinates and 2 pairs fewer). The message counts the links and joints left and
    # names the first few (it listed all 599 links)
    n = 300
    joints, links = four_bar_chain(n)
    del links["rocker1"], joints["O1"]
    sk = Sketch(joints, links, ground=[j for j in joints if j.startswith("O")], driver="rocker0")
    with pytest.raises(MechanismError) as info:
        decompose(sk)
    message = str(info.value)
    left = [name for name in links if name != "rocker0"]
    assert "= 2, expected 1: 1 degree(s) of freedom left" in message
    assert f"{len(left)} of the {len(links)} links are in no group" in message
    assert f"links {', '.join(left[:8])} and {len(left) - 8} more" in message
    assert f"joints {', '.join(f'B{i}' for i in range(1, 9))} and {n - 8} more not determined" in message
    assert len(message) < 600


def test_a_chain_at_the_size_bound_decomposes_window_by_window_and_fast():
    # 999 links (the bound is 1000) in a random order: each window hangs on the one before, so
    # window i (coupler i, rocker i+1) is the group after window i-1, whatever the order
    n = 499
    joints, links = four_bar_chain(n)
    names = list(links)
    order = [names[i] for i in np.random.default_rng(0).permutation(len(names))]
    sk = Sketch(joints, {k: links[k] for k in order}, ground=[f"O{i}" for i in range(n + 1)], driver="rocker0")
    start = time.perf_counter()
    dec = decompose(sk)
    assert time.perf_counter() - start < 1.0
    assert [g.kind for g in dec.groups] == ["crank"] + ["RRR"] * n
    assert [set(g.links) for g in dec.groups[1:]] == [{f"coupler{i}", f"rocker{i + 1}"} for i in range(n)]


def test_a_chain_of_triads_at_the_size_bound_decomposes_in_order_and_fast():
    # 249 triads (997 links) listed last first: the search that looked at every link again each
    # round took ~30 s; only the triad hung on the last one placed can come next
    n = 249
    joints, links, ground = triad_chain(n)
    order = ["crank"] + [k for k in reversed(links) if k != "crank"]
    sk = Sketch(joints, {k: links[k] for k in order}, ground=ground, driver="crank")
    start = time.perf_counter()
    dec = decompose(sk)
    assert time.perf_counter() - start < 1.0
    assert [g.kind for g in dec.groups] == ["crank"] + ["triad"] * n
    for k, g in enumerate(dec.groups[1:]):
        assert g.links[0] == f"plate{k}" and set(g.links[1:]) == {f"arm{k}", f"upper{k}", f"lower{k}"}
        assert set(g.joints[:3]) == {f"P{k - 1}" if k else "A", f"E{k}", f"F{k}"}
        assert set(g.joints[3:]) == {f"P{k}", f"Q{k}", f"R{k}"}


def test_toml_sketch_errors_name_the_field(write_scene):
    bad = FOUR_BAR.replace('crank = { joints = ["A", "B"], density = 2.0 }', 'crank = { joints = ["A", "B"], colour = 2.0 }')
    with pytest.raises(SceneError, match="scene.toml: \\[sketch\\]: link 'crank': unknown field\\(s\\) \\['colour'\\]"):
        assurjax.load_scene(write_scene(bad))
    with pytest.raises(SceneError, match="either a \\[sketch\\] or the explicit"):
        assurjax.load_scene(write_scene(FOUR_BAR + "\n[ground]\nA = [0.0, 0.0]\n"))


# -- assembly diagnostics ---------------------------------------------------------------------


def test_assembly_report_names_the_group_interval_and_condition():
    from assurjax.structure import assembly_report

    q = np.linspace(-np.pi, np.pi, 121)
    report = assembly_report(assurjax.load_scene("roberts").mechanism, q)
    # closed form: the dyad (BC = 0.12, CD = 0.18) reaches from B = A + 0.18 (cos q, sin q) to D
    # only while |B D| <= 0.30 (A = (-0.12, 0), D = (0.12, 0))
    bd = np.hypot(-0.12 + 0.18 * np.cos(q) - 0.12, 0.18 * np.sin(q))
    expected_bad = bd > 0.30
    assert np.array_equal(~report.ok, expected_bad)
    (failure,) = report.failures
    assert failure.group == "dyad43" and failure.kind == "RRR"
    covered = np.zeros_like(q, dtype=bool)
    for lo, hi in failure.intervals:
        covered |= (q >= lo) & (q <= hi)
    assert np.array_equal(covered, expected_bad)
    assert f"|B D| = {bd[0]:.4g} m > 0.12 + 0.18 m" in failure.condition
    assert "group 'dyad43' (RRR) cannot assemble for q in" in str(report)


LIMIT_FOUR_BAR = """
[scene]
gravity = [0.0, -9.81]
[sketch]
driver = "crank"
ground = ["O2", "O4"]
joints = { O2 = [0.0, 0.0], O4 = [1.0, 0.0], A = [AX, AY], B = [BX, BY] }
[sketch.links]
crank = { joints = ["O2", "A"], density = 2.0 }
coupler = { joints = ["A", "B"], density = 2.0 }
rocker = { joints = ["O4", "B"], density = 2.0 }
[state]
t1 = 0.3
"""


@pytest.mark.slow  # ~9 s; starts at a dyad's limit stay in the default suite (test_dynamics.py)
def test_a_drawing_at_the_cranks_limit_is_no_start_and_a_start_beside_it_locks_up():
    # crank 0.8, coupler 0.5, rocker 0.6, ground 1 (not Grashof): the crank's limit is where
    # coupler and rocker are in line, |O4 A| = 1.1: cos q = (0.64 + 1 - 1.21) / 1.6. Drawn
    # there, the run swung off gaining 2 % of its energy ("reached t1"); from rest 1e-6 rad
    # inside, gravity takes it into the limit (it said a load gave NaN at t = 0)
    q_limit = np.arccos((0.64 + 1.0 - 1.21) / 1.6)
    a = 0.8 * np.array([np.cos(q_limit), np.sin(q_limit)])
    b = np.array([1.0, 0.0]) + 0.6 / 1.1 * (a - np.array([1.0, 0.0]))
    text = LIMIT_FOUR_BAR
    for key, value in (("AX", a[0]), ("AY", a[1]), ("BX", b[0]), ("BY", b[1])):
        text = text.replace(key, repr(float(value)))
    scene = assurjax.scene_from_dict(tomllib.loads(text))
    assert abs(scene.state["q0"] - q_limit) < 1e-12
    with pytest.raises(assurjax.AssemblyError, match="group 'RRR1' \\(RRR\\) is exactly at a singular configuration at the start"):
        assurjax.simulate(scene, stop=None)
    with pytest.raises(assurjax.AssemblyError, match="exactly at a singular configuration"):
        assurjax.simulate(scene, stop=None, branch="tracked")  # it drifted by 0.33 J of 0.71
    inside = assurjax.simulate(scene, stop=None, q0=q_limit - 1e-6)
    assert int(inside.event) == 1 and inside.failed_group == "RRR1" and 0 < float(inside.t_final) < 0.3
    assert abs(float(inside.q_final) - q_limit) < 1e-8  # it reached the limit
    batch = assurjax.simulate(scene, stop=None, q0=np.array([q_limit, q_limit - 1e-6]))
    assert batch.status == "batch of 2: 1 lock-up, 1 start exactly at a singular configuration"


@pytest.mark.parametrize("name", ["B[rocker]", "C/D", "com:C"])
def test_a_joint_may_not_take_a_name_the_package_gives_a_pair(name):
    """B is shared by coupler, rocker and l5, so its pairs are 'B[rocker]' and 'B[l5]'. A drawn
    pin named 'B[rocker]' took one of those names: the reactions had 6 pairs instead of 7 (the
    pin's own gone) and JointFriction('B[rocker]') went to either pin. Refused by name."""
    joints = {"O2": (0, 0), "A": (0.05, 0.0866), "B": (0.42, 0.29), "O4": (0.4, 0.0), "O6": (0.8, 0.4), name: (0.6178, 0.5142)}
    links = dict(crank=["O2", "A"], coupler=["A", "B"], rocker=["O4", "B"], l5=["B", name], l6=[name, "O6"])
    with pytest.raises(MechanismError, match=f"point name '{re.escape(name)}'.*reserved"):
        Sketch(joints=joints, links={k: {"joints": v} for k, v in links.items()}, ground=["O2", "O4", "O6"], driver="crank")
