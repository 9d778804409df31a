"""Bad input: every mistake raises an error of the right class whose message names the culprit
(scene field, group, link or point), never a raw JAX traceback or a silent NaN."""

import copy
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax import AssemblyError, Link, Mechanism, MechanismError, SceneError, groups, synthesis

FOUR_BAR = {
    "scene": {"name": "four_bar"},
    "ground": {"O2": [0.0, 0.0], "O4": [1.0, 0.0]},
    "links": {
        "crank": {"points": {"O2": [0.0, 0.0], "A": [0.3, 0.0]}, "mass": 1.0, "inertia": 0.01},
        "coupler": {"points": {"A": [0.0, 0.0], "B": [1.0, 0.0]}, "mass": 1.0, "inertia": 0.1},
        "rocker": {"points": {"O4": [0.0, 0.0], "B": [0.8, 0.0]}, "mass": 1.0, "inertia": 0.05},
    },
    "formation": [
        {"group": "crank", "name": "drive", "link": "crank", "pivot": "O2"},
        {"group": "RRR", "name": "dyad", "links": ["coupler", "rocker"], "joints": ["A", "O4", "B"], "mode": "left"},
    ],
    "outputs": {"points": ["B"]},
}


def scene(edit=None):
    """The four-bar above, edited by ``edit(data)``."""
    data = copy.deepcopy(FOUR_BAR)
    if edit:
        edit(data)
    return assurjax.scene_from_dict(data, source="bad.toml")


def raises(cls, *fragments):
    """pytest.raises that also checks every fragment appears in the message."""

    class Check:
        def __enter__(self):
            self.ctx = pytest.raises(cls)
            self.info = self.ctx.__enter__()
            return self.info

        def __exit__(self, *exc):
            suppressed = self.ctx.__exit__(*exc)
            message = str(self.info.value)
            for fragment in fragments:
                assert fragment in message, f"{fragment!r} not in: {message}"
            return suppressed

    return Check()


def test_the_base_scene_is_valid():
    s = scene()
    assert s.mechanism.group_names == ("drive", "dyad")


def test_unknown_group_kind():
    def edit(d):
        d["formation"][1]["group"] = "RRX"

    with raises(SceneError, "bad.toml", "'group'", "RRX", "#2"):
        scene(edit)


def test_missing_field():
    def edit(d):
        del d["formation"][1]["joints"]

    with raises(SceneError, "missing field 'joints'", "'dyad'"):
        scene(edit)


def test_missing_links_table():
    with raises(SceneError, "missing field 'links'"):
        scene(lambda d: d.pop("links"))


@pytest.mark.parametrize(
    "edit,fragments",
    [
        (lambda d: d["links"]["crank"].update(mass="heavy"), ("[links.crank]", "'mass'", "number")),
        (lambda d: d["formation"][1].update(joints="A O4 B"), ("'joints'", "'dyad'", "list of 3 names")),
        (lambda d: d["ground"].update(O4=[1.0]), ("[ground]", "'O4'", "2 numbers")),
        (lambda d: d["formation"][1].update(mode="sideways"), ("'mode'", "'dyad'", "sideways")),
        (lambda d: d["links"]["rocker"].update(points="O4"), ("[links.rocker].points", "table")),
    ],
    ids=["mass-string", "joints-string", "short-vector", "bad-mode", "points-not-table"],
)
def test_wrong_type(edit, fragments):
    with raises(SceneError, "bad.toml", *fragments):
        scene(edit)


def test_unknown_field_is_rejected():
    with raises(SceneError, "[links.crank]", "lenght"):
        scene(lambda d: d["links"]["crank"].update(lenght=0.3))


@pytest.mark.parametrize(
    "edit, where, typed, meant",
    [
        (lambda d: d["links"]["crank"].update(mas=1.0), "[links.crank]", "mas", "mass"),
        (lambda d: d.update(output={"points": ["B"]}), "the top level", "output", "outputs"),
        (lambda d: d["scene"].update(descripton="x"), "[scene]", "descripton", "description"),
        (lambda d: d.update(state={"omega_0": 1.0}), "[state]", "omega_0", "omega0"),
        (lambda d: d["formation"][1].update(mdoe="left"), "[[formation]] #2", "mdoe", "mode"),
        (lambda d: d.update(simulation={"rtoll": 1e-6}), "[simulation]", "rtoll", "rtol"),
        (lambda d: d["outputs"].update(point=["B"]), "[outputs]", "point", "points"),
        # an optional field the parser only looks for (static_coefficient) is suggested too
        (lambda d: d.update(loads=[{"type": "joint_friction", "joint": "A", "coefficient": 0.1, "radius": 0.01,
                                    "static_coeficient": 0.2}]), "[[loads]] #1", "static_coeficient", "static_coefficient"),
        (lambda d: d.update(loads=[{"type": "couple", "link": "crank", "moment": {"polynomal": [1.0]}}]), "'moment'",
         "polynomal", "polynomial"),
    ],
)
def test_unknown_fields_get_the_field_they_misspell(edit, where, typed, meant):
    """'mas' in a link table and an [output] table were refused with no suggestion, where a
    misspelt required field got one."""
    with raises(SceneError, "bad.toml", where, typed, f"'{typed}': did you mean '{meant}'?"):
        scene(edit)


@pytest.mark.parametrize("value, stray", [
    ({"polynomial": [1.0], "x": [0.0, 1.0], "values": [0.0, 1.0]}, "['x', 'values']"),
    ({"polynomial": [1.0], "period": 6.283185307179586}, "['period']"),
])
def test_a_load_value_takes_one_form(value, stray):
    """A polynomial given a table's entries was read as the polynomial alone, the rest dropped unsaid."""
    with raises(SceneError, "bad.toml", "[[loads]] #1 (drive), field 'value'", f"'polynomial' does not go with {stray}"):
        scene(lambda d: d.update(loads=[{"type": "drive", "value": value}]))


def test_an_unknown_field_like_no_known_one_lists_the_known_ones():
    with raises(SceneError, "[links.crank]: unknown field(s) ['colour']; rename or remove it",
                "known fields: com, inertia, mass, points") as info:
        scene(lambda d: d["links"]["crank"].update(colour="red"))
    assert "did you mean" not in str(info.value)


def test_a_sketch_link_field_gets_the_field_it_misspells():
    with raises(MechanismError, "link 'crank': unknown field(s) ['masss']", "did you mean 'mass'?"):
        assurjax.Sketch({"O": (0, 0), "A": (0.1, 0)}, {"crank": {"joints": ["O", "A"], "masss": 1.0}}, ground=["O"],
                        driver="crank").mechanism()


def test_one_load_alone_is_the_only_load_of_with_loads():
    """scene.with_loads(load) raised a raw TypeError ('JointFriction' object is not iterable);
    simulate(loads=load) took it."""
    base = scene()
    friction = assurjax.JointFriction("A", 0.1, radius=0.01)
    assert base.with_loads(friction).loads == (friction,)
    with raises(assurjax.AssurjaxError, "with_loads: loads must be a sequence of loads or one load", "got float"):
        base.with_loads(0.1)


def test_a_sketch_given_for_a_mechanism_or_scene_says_how_to_build_one():
    sketch = assurjax.Sketch({"O": (0, 0), "A": (0.1, 0)}, {"crank": ["O", "A"]}, ground=["O"], driver="crank")
    for call, what, fix in [
        (lambda: assurjax.kinematics(sketch, 0.5), "kinematics", "pass sketch.mechanism()"),
        (lambda: assurjax.pose_at(sketch, 0.5), "pose_at", "pass sketch.mechanism()"),
        (lambda: assurjax.simulate(sketch), "simulate", "pass sketch.scene()"),
        (lambda: assurjax.reactions(sketch, (0.5, 0.0, 0.0)), "reactions", "pass sketch.scene()"),
    ]:
        with raises(assurjax.AssurjaxError, f"{what}: expected an assurjax", "got Sketch", "a Sketch is a drawing", fix):
            call()


def test_unknown_link():
    with raises(SceneError, "'dyad'", "unknown link 'rockr'"):
        scene(lambda d: d["formation"][1].update(links=["coupler", "rockr"]))


def test_point_used_before_defined():
    """The dyad's external joint 'Z' is defined by no earlier group nor the ground."""

    def edit(d):
        d["links"]["rocker"]["points"] = {"Z": [0.0, 0.0], "B": [0.8, 0.0]}
        d["formation"][1]["joints"] = ["A", "Z", "B"]

    with raises(SceneError, "'dyad'", "point 'Z'", "no earlier group"):
        scene(edit)


def test_duplicate_group_name():
    with raises(SceneError, "duplicate group name 'drive'"):
        scene(lambda d: d["formation"][1].update(name="drive"))


def test_link_placed_twice():
    def edit(d):
        d["formation"].append({"group": "RRR", "name": "again", "links": ["coupler", "rocker"], "joints": ["A", "O4", "B"], "mode": "left"})

    with raises(SceneError, "'again'", "link 'coupler' is already placed by group 'dyad'"):
        scene(edit)


def test_link_in_no_group():
    with raises(SceneError, "spare", "no group"):
        scene(lambda d: d["links"].update(spare={"points": {"S": [0.0, 0.0]}}))


def test_wrong_dof_count():
    """B pinned to the ground as well: a structure (0 DOF by Gruebler's count 3*3 - 2*5 = -1)."""
    with raises(SceneError, "degrees of freedom", "Gruebler", "-1"):
        scene(lambda d: d["ground"].update(B=[1.2, 0.8]))


def test_zero_length():
    with raises(SceneError, "'dyad'", "link 'rocker'", "zero length", "'O4'", "'B'"):
        scene(lambda d: d["links"]["rocker"].update(points={"O4": [0.5, 0.5], "B": [0.5, 0.5]}))
    # a crank whose joint A lies on its pivot: the dyad hangs on a point that does not move
    with raises(SceneError, "'drive'", "link 'crank'", "zero length", "'O2'", "'A'"):
        scene(lambda d: d["links"]["crank"].update(points={"O2": [0.0, 0.0], "A": [0.0, 0.0]}))


@pytest.mark.parametrize("field", ["mass", "inertia"])
def test_negative_mass_or_inertia_in_scene(field):
    with raises(SceneError, "[links.coupler]", f"'{field}'", "non-negative"):
        scene(lambda d: d["links"]["coupler"].update({field: -1.0}))


@pytest.mark.parametrize("field", ["mass", "inertia"])
def test_negative_mass_or_inertia_in_python(field):
    mech = scene().mechanism
    links = dict(mech.links)
    links["rocker"] = eqx.tree_at(lambda lk: getattr(lk, field), links["rocker"], jnp.asarray(-2.0))
    with raises(MechanismError, "link 'rocker'", field, "non-negative"):
        Mechanism(mech.ground, links, mech.groups)


@pytest.mark.parametrize("direction, fragment", [([0.0, 0.0], "non-zero"),
                                                 # NumPy's length 1.4e-160, squared 2e-320, flushed to 0 by JAX
                                                 ([1e-160, 1e-160], "at least 1e-100 long")])
def test_zero_guide_direction(direction, fragment):
    data = {
        "ground": {"O": [0.0, 0.0]},
        "links": {
            "crank": {"points": {"O": [0.0, 0.0], "A": [0.1, 0.0]}},
            "rod": {"points": {"A": [0.0, 0.0], "B": [0.3, 0.0]}},
            "slider": {"points": {"B": [0.0, 0.0]}},
        },
        "formation": [
            {"group": "crank", "link": "crank", "pivot": "O"},
            {"group": "RRP", "name": "rod_slider", "links": ["rod", "slider"], "joints": ["A", "B"], "guide_point": "O", "direction": direction, "mode": "forward"},
        ],
    }
    with raises(SceneError, "'rod_slider'", "field 'direction'", fragment):
        assurjax.scene_from_dict(data, source="bad.toml")


def test_unknown_point_in_outputs():
    with raises(SceneError, "[outputs]", "'points'", "unknown point 'Q'"):
        scene(lambda d: d["outputs"].update(points=["B", "Q"]))


def test_unknown_link_in_outputs():
    with raises(SceneError, "[outputs]", "'angles'", "unknown link 'link7'"):
        scene(lambda d: d["outputs"].update(angles=["link7"]))


def test_invalid_toml(write_scene):
    path = write_scene(
        """
        [scene]
        name = "broken
        """
    )
    with raises(SceneError, str(path), "not valid TOML"):
        assurjax.load_scene(path)


def test_missing_scene_file(tmp_path, monkeypatch):
    with raises(SceneError, "no such scene file") as info:
        assurjax.load_scene(tmp_path / "nowhere.toml")
    assert "bundled" not in str(info.value)  # no bundled scene of that name: no hint
    with raises(SceneError, "neither a scene file nor a bundled scene", "roberts"):
        assurjax.load_scene("no_such_bundled_scene")
    # a bundled scene's name written as a file name: how to load it
    monkeypatch.chdir(tmp_path)
    for given, name in (("watt_sixbar.toml", "watt_sixbar"), ("scenes/roberts.toml", "roberts")):
        assert name in assurjax.bundled_scenes()
        with raises(SceneError, f"{given}: no such scene file", f"bare name, '{name}' (no '.toml'"):
            assurjax.load_scene(given)
    with raises(SceneError, "'wat_sixbar' is neither", "did you mean 'watt_sixbar'?"):
        assurjax.load_scene("wat_sixbar")


def test_cannot_assemble_outside_jit_names_the_group():
    """Coupler + rocker (1.8) cannot reach O4 from A when |A O4| > 1.8: make the crank long."""
    mech = scene(lambda d: d["links"]["crank"].update(points={"O2": [0.0, 0.0], "A": [1.5, 0.0]})).mechanism
    with raises(AssemblyError, "'dyad'", "cannot assemble") as info:
        assurjax.pose_at(mech, np.pi)  # A at (-1.5, 0): 2.5 from O4
    assert info.value.group == "dyad"
    with raises(AssemblyError, "'dyad'", "cannot assemble"):
        assurjax.kinematics(mech, np.array([0.0, np.pi]))
    kin = assurjax.kinematics(mech, np.array([0.0, np.pi]), check=False)
    np.testing.assert_array_equal(np.asarray(kin.ok), [[True, True], [True, False]])


def _length(link: str, a: str, b: str, data=FOUR_BAR) -> float:
    points = data["links"][link]["points"]
    return float(np.hypot(*np.subtract(points[a], points[b])))


def test_cannot_assemble_says_why_with_the_lengths_and_what_to_check():
    """The AssemblyError of pose_at and kinematics carries the condition assembly_report words
    (it said only 'group ... cannot assemble at q = 0'): the lengths, from the scene's numbers."""
    long_crank = copy.deepcopy(FOUR_BAR)
    long_crank["links"]["crank"]["points"]["A"] = [1.5, 0.0]
    mech = assurjax.scene_from_dict(long_crank, source="bad.toml").mechanism
    # at q = pi, A = (-1.5, 0): |A O4| = 1.5 + |O2 O4| > coupler + rocker
    gap = 1.5 + float(np.hypot(*np.subtract(FOUR_BAR["ground"]["O4"], FOUR_BAR["ground"]["O2"])))
    coupler, rocker = _length("coupler", "A", "B"), _length("rocker", "O4", "B")
    why = f"|A O4| = {gap:.4g} m > {coupler:.4g} + {rocker:.4g} m (links coupler, rocker too short)"
    todo = "check the points (m) of link(s) coupler, rocker, crank and the ground points"
    for call in (lambda: assurjax.pose_at(mech, np.pi), lambda: assurjax.kinematics(mech, np.array([0.0, np.pi]))):
        with raises(AssemblyError, "group 'dyad' (RRR) cannot assemble at q = 3.14159", why, todo, "assembly_report"):
            call()
    # a length typed in mm (1000 for 1.0 m): the coupler is the long one, the other folds inside it
    mm = copy.deepcopy(FOUR_BAR)
    mm["links"]["coupler"]["points"]["B"] = [1000.0, 0.0]
    mech = assurjax.scene_from_dict(mm, source="mm.toml").mechanism
    gap = _length("crank", "O2", "A") - 1.0  # A = (0.3, 0), O4 = (1, 0) at q = 0
    with raises(AssemblyError, "cannot assemble at q = 0", f"|A O4| = {abs(gap):.4g} m < |1000 - {rocker:.4g}| m",
                "link coupler too long beside rocker"):
        assurjax.pose_at(mech, 0.0)


def test_cannot_assemble_inside_jit_sets_flags_and_stays_finite():
    mech = scene(lambda d: d["links"]["crank"].update(points={"O2": [0.0, 0.0], "A": [1.5, 0.0]})).mechanism

    @eqx.filter_jit
    def run(mech, q):
        return assurjax.kinematics(mech, q, 1.0, 0.0)  # check is a no-op under tracing

    kin = run(mech, jnp.array([0.0, np.pi]))
    np.testing.assert_array_equal(np.asarray(kin.ok)[:, 1], [True, False])
    for tree in (kin.points, kin.velocities, kin.accelerations, kin.angles, kin.angular_velocities):
        for v in jax.tree.leaves(tree):
            assert np.all(np.isfinite(np.asarray(v)))


def test_inverse_kinematics_out_of_reach():
    mech = assurjax.load_scene("slider_crank").mechanism  # x_B stays within [0.2, 0.4] m
    with raises(AssemblyError, "inverse kinematics", "out of reach"):
        assurjax.inverse_kinematics(mech, lambda pose: pose.points["B"][0], 0.6, 0.5)
    # under jit nothing can be raised: q was a meaningless number (4308 rad on the triad), now NaN
    q, pose = jax.jit(lambda v: assurjax.inverse_kinematics(mech, ("B", "x"), v, 0.5))(jnp.array(0.6))
    assert np.isnan(q) and not np.asarray(pose.ok).all()
    q, pose = jax.jit(lambda v: assurjax.inverse_kinematics(mech, ("B", "x"), v, 0.5))(jnp.array(0.35))
    assert abs(float(pose.points["B"][0]) - 0.35) < 1e-12  # within reach: the root


def test_unknown_point_in_kinematics():
    mech = scene().mechanism
    with raises(assurjax.AssurjaxError, "unknown point(s) ['Q']"):
        assurjax.kinematics(mech, 0.1, points=["Q"])


@pytest.mark.parametrize(
    "call, fragments",
    [
        (lambda m: assurjax.kinematics(m, [0.1, np.nan]), ["kinematics: q", "finite", "nan"]),
        (lambda m: assurjax.kinematics(m, np.zeros(3), omega=np.ones(2)), ["kinematics: omega", "(2,)", "q's shape (3,)"]),
        (lambda m: assurjax.kinematics(m, 0.1, alpha=np.inf), ["kinematics: alpha", "finite"]),
        (lambda m: assurjax.reactions(m, ([0.1, 0.2], np.nan, 0.0)), ["state: omega", "finite"]),
        (lambda m: assurjax.reactions(m, (np.zeros(3), np.zeros(2), 0.0)), ["must broadcast together", "q (3,)", "omega (2,)"]),
        (lambda m: assurjax.static_torque(m, [0.1, np.inf]), ["state: q", "finite"]),
        (lambda m: assurjax.breakaway_band(assurjax.Model(m), "0.1 rad"), ["state: q", "must be a number", "'0.1 rad'"]),
        # a bare mechanism has no gravity, loads or friction: its band was (-0, -0)
        (lambda m: assurjax.breakaway_band(m, 0.3), ["breakaway_band: takes a scene", "got a Mechanism"]),
        (lambda m: assurjax.inverse_dynamics(m, lambda t, x: t, [0.0, 0.1]),
         ["inverse_dynamics: motion must be a function of the time alone, q(t)", "takes (t, x)"]),
        (lambda m: assurjax.sweep(3, jnp.arange(4.0)), ["sweep: fn must be a function", "got 3"]),
        (lambda m: assurjax.stack_mechanisms([1, 2]), ["stack_mechanisms: item 0 is int 1, not an assurjax Mechanism"]),
        (lambda m: assurjax.reactions(m, (0.1, "fast", 0.0)), ["state: omega", "must be a number", "'fast'"]),
        (lambda m: assurjax.inverse_dynamics(m, lambda t: t, [0.0, np.nan]), ["inverse_dynamics: t", "finite"]),
        (lambda m: assurjax.inverse_dynamics(m, lambda t: jnp.stack([t, t]), [0.0, 0.1]),
         ["inverse_dynamics", "motion q(t)", "a single number", "shape (2,)"]),
        (lambda m: assurjax.inverse_kinematics(m, ("B", "x"), np.nan, 0.5), ["inverse kinematics: value", "finite"]),
        (lambda m: assurjax.inverse_kinematics(m, ("B", "x"), 0.1, [0.5, 0.6]), ["inverse kinematics: q0", "a single number"]),
        (lambda m: assurjax.batch_kinematics(assurjax.stack_mechanisms([m, m]), [0.1, np.nan]), ["batch_kinematics: q", "finite"]),
        (lambda m: assurjax.perturb(m, jax.random.key(0), 4, relative=np.inf), ["perturb: relative", "finite"]),
        (lambda m: assurjax.perturb(m, jax.random.key(0), 10**9), ["perturb: n", "at most 10000000"]),
        (lambda m: assurjax.perturb(m, 0, 4), ["perturb: key must be a JAX random key"]),
        (lambda m: assurjax.perturb(m, jax.random.key(0), 4, select=lambda x: x.links["zz"]), ["perturb: select failed", "'zz'"]),
        (lambda m: assurjax.sweep(lambda i: i, 10, chunk_size=2.5), ["sweep: chunk_size must be a positive integer"]),
    ],
)
def test_states_given_to_the_analyses_are_checked(call, fragments):
    """Numbers that are not finite, or arrays that do not fit together, are named before anything
    is traced (not a group 'that cannot assemble at q = nan', not a broadcasting error from JAX)."""
    with raises(assurjax.AssurjaxError, *fragments):
        call(scene().mechanism)


@pytest.mark.parametrize(
    "call, fragments",
    [
        (lambda s: synthesis.final_state(s, [0.5, 1.0]), ["'t1'", "a single number", "shape (2,)"]),
        (lambda s: synthesis.final_state(s, np.nan), ["'t1'", "finite"]),
        (lambda s: synthesis.final_state(s, 1.0, q0=np.inf), ["'q0'", "finite"]),
        (lambda s: synthesis.final_state(s, -1.0, adjoint="quadrature"), ["'t1'", "later than t0"]),
        (lambda s: synthesis.standstill_time(s, omega0=[0.0, 1.0]), ["'omega0'", "a single number"]),
        (lambda s: assurjax.simulate(s, t1=[0.5, 1.0]), ["'t1'", "a single number"]),
        (lambda s: assurjax.simulate(s, t1="two"), ["'t1'", "must be a number", "'two'"]),
        (lambda s: assurjax.batch_simulate(s, assurjax.stack_mechanisms([s.mechanism] * 2), t1=[0.5, 1.0]),
         ["'t1'", "a single number"]),
        (lambda s: assurjax.batch_simulate(s, assurjax.stack_mechanisms([s.mechanism] * 2), q0=np.nan), ["'q0'", "finite"]),
        (lambda s: assurjax.simulate(s, events=[lambda t, q, w: q, lambda t, q, w: jnp.stack([q, w])]),
         ["events", "event #2 returns an array of shape (2,)"]),
    ],
)
def test_runs_check_their_start_horizon_and_events(call, fragments):
    with raises(assurjax.AssurjaxError, *fragments):
        call(scene())


def test_formation_must_start_with_a_driver():
    def edit(d):
        d["formation"].reverse()

    with raises(SceneError, "'dyad'", "must start with a driver"):
        scene(edit)


def test_python_mechanism_errors_name_the_culprit():
    """The same checks guard mechanisms built in Python (MechanismError)."""
    mech = scene().mechanism
    bad = groups.RRR("dyad", ("coupler", "rocker"), ("A", "O9", "B"), 1)
    with raises(MechanismError, "'dyad'", "point 'O9'"):
        Mechanism(mech.ground, mech.links, [mech.groups[0], bad])
    with raises(MechanismError, "'ground'", "reserved"):
        Mechanism(mech.ground, {**mech.links, "ground": mech.links["crank"]}, mech.groups)
    lonely = Link(points={"S": jnp.zeros(2)}, com=jnp.zeros(2), mass=jnp.asarray(1.0), inertia=jnp.asarray(0.0))
    with raises(MechanismError, "'lonely'", "no group"):
        Mechanism(mech.ground, {**mech.links, "lonely": lonely}, mech.groups)


def test_a_mechanism_built_in_python_is_bounded_by_field():
    """At most 2500 ground points, links and groups each and 10000 points on the links, as a scene
    file: refused by name before any value is read (values that are not points, and no structure
    check, come later)."""
    mech = scene().mechanism
    bar, crank = mech.links["coupler"], mech.groups[0]
    plate = Link(points={f"P{i}": [float(i), i % 2] for i in range(5)})
    cases = [
        (lambda: Mechanism({f"G{i}": "not a point" for i in range(2501)}, mech.links, mech.groups),
         ["mechanism 'mechanism': ground has 2501 entries", "at most 2500"]),
        (lambda: Mechanism(mech.ground, {f"bar{i}": bar for i in range(3000)}, mech.groups, name="big"),
         ["mechanism 'big': links has 3000 entries", "at most 2500"]),
        (lambda: Mechanism(mech.ground, mech.links, (crank for _ in range(2501))),
         ["groups has 2501 entries", "at most 2500"]),
        (lambda: Mechanism(mech.ground, {f"plate{i}": plate for i in range(2001)}, mech.groups),
         ["links has 10005 points in all", "at most 10000"]),
    ]
    for build, fragments in cases:
        start = time.perf_counter()
        with raises(MechanismError, *fragments):
            build()
        assert time.perf_counter() - start < 1.0


def test_the_mechanism_bound_holds_the_largest_generated_and_loaded_mechanisms():
    # n_four_bar at its bound of 1000 windows (2001 links; building it takes seconds: its tables
    # are counted), and a scene file whose tables are at the loader's bound
    from assurjax._examples import n_four_bar_dict
    from assurjax.scene._load import MAX_ENTRIES

    tables = n_four_bar_dict(1000)
    sizes = [len(tables["ground"]), len(tables["links"]), len(tables["formation"])]
    assert sizes == [1001, 2001, 1001] and max(sizes) <= 2500
    assert sum(len(link["points"]) for link in tables["links"].values()) <= 10000
    assert MAX_ENTRIES <= 2500


# -- hostile values: the scene loader and the Python API reject them in the same words ----------

import assurjax as load_forms  # noqa: E402  (the load classes)
from assurjax.dynamics._settings import settings_from  # noqa: E402


def _tail(message: str, field: str) -> str:
    """The words after the field's name: what both the scene and the API say is wrong."""
    return message.rsplit(field, 1)[1].lstrip("': ")


@pytest.mark.parametrize(
    "field, value, words",
    [("mass", float("inf"), "must be finite, got inf"), ("inertia", float("nan"), "must be finite, got nan"),
     ("mass", 1e300, "must be at most 1e+12 in magnitude"), ("inertia", -1.0, "must be non-negative, got -1.0")],
)
def test_link_values_scene_and_python_agree(field, value, words):
    with raises(SceneError, "bad.toml", "[links.coupler]", f"'{field}'", words) as scene_error:
        scene(lambda d: d["links"]["coupler"].update({field: value}))
    mech = scene().mechanism
    links = {**mech.links, "coupler": eqx.tree_at(lambda lk: getattr(lk, field), mech.links["coupler"], jnp.asarray(value))}
    with raises(MechanismError, "link 'coupler'", field, words) as api_error:
        Mechanism(mech.ground, links, mech.groups)
    assert _tail(str(scene_error.value), field) == _tail(str(api_error.value), field)


@pytest.mark.parametrize(
    "edit, fragments",
    [
        (lambda d: d["links"]["coupler"].update(com=[1e300, 0.0]), ["[links.coupler]", "'com'", "magnitude"]),
        (lambda d: d["ground"].update(O2=[-float("inf"), 0.0]), ["[ground]", "'O2'", "finite"]),
        (lambda d: d.update(scene={"gravity": [0.0, -float("inf")]}), ["[scene]", "'gravity'", "finite"]),
        (lambda d: d.update(state={"omega0": 1e300}), ["[state]", "'omega0'", "magnitude"]),
        (lambda d: d.update(state={"t0": float("nan")}), ["[state]", "'t0'", "finite"]),
        (lambda d: d.update(state={"t0": 2.0, "t1": 1.0}), ["[state]", "'t1'", "later than t0"]),
        (lambda d: d["formation"][1].update(group=["RRR"]), ["#2", "'group'", "unknown group kind"]),
        (lambda d: d["formation"][1].update(mode=["left"]), ["'dyad'", "'mode'"]),
        (lambda d: d.update(loads=[{"type": ["spring"]}]), ["[[loads]] #1", "'type'"]),
        (lambda d: d.update(loads=[{"type": "couple", "link": "crank", "moment": float("nan")}]), ["'moment'", "finite"]),
        (lambda d: d.update(loads=[{"type": "motor", "stall": float("nan"), "no_load_speed": 1.0}]), ["'stall'", "finite"]),
        (lambda d: d.update(loads=[{"type": "spring", "points": ["A", "O4"], "stiffness": float("inf")}]), ["'stiffness'", "finite"]),
        (lambda d: d.update(loads=[{"type": "couple", "link": "crank",
                                    "moment": {"x": [0.0, 1.0], "values": [0.0, 1.0], "period": float("nan")}}]), ["'moment'", "period", "finite"]),
        (lambda d: d.update(simulation={"samples": 2_000_000}), ["[simulation]", "'samples'", "from 2 to 100000", "48 MB", "the limit allows 2.4 MB"]),
        (lambda d: d.update(simulation={"table_nodes": "big"}), ["[simulation]", "'table_nodes'", "'big'"]),
        (lambda d: d.update(simulation={"steps": [10]}), ["[simulation]", "'steps'"]),
        (lambda d: d["outputs"].update(velocities="yes"), ["[outputs]", "'velocities'", "true or false"]),
        (lambda d: d["outputs"].update(energys=True), ["[outputs]", "unknown field 'energys'"]),
    ],
)
def test_hostile_scene_values_name_the_field(edit, fragments):
    with raises(SceneError, "bad.toml", *fragments):
        scene(edit)


def test_iterative_group_substeps_are_bounded():
    data = assurjax.load_scene("triad_mechanism")  # the bundled scene must load first
    assert data.mechanism.groups[1].substeps >= 1
    import tomllib
    from importlib import resources

    raw = tomllib.loads((resources.files("assurjax.scenes") / "triad_mechanism.toml").read_text())
    triad = next(g for g in raw["formation"] if g["group"] == "triad")
    triad["substeps"] = 10_000_000
    with raises(SceneError, "'substeps'", "at most 1000"):
        assurjax.scene_from_dict(raw, source="bad.toml")
    triad["substeps"] = 8
    triad["guess"][next(iter(triad["guess"]))] = [float("inf"), 0.0]
    with raises(SceneError, "'guess'", "finite"):
        assurjax.scene_from_dict(raw, source="bad.toml")


@pytest.mark.parametrize(
    "build, fragments",
    [
        (lambda: load_forms.Spring("A", "B", float("inf")), ["Spring", "stiffness", "must be finite, got inf"]),
        (lambda: load_forms.Spring("A", "B", 1.0, free_length=-1.0), ["free_length", "must be non-negative"]),
        (lambda: load_forms.Damper("A", "B", float("inf")), ["Damper", "coefficient", "finite"]),
        (lambda: load_forms.Couple("crank", float("nan")), ["Couple", "moment", "finite"]),
        (lambda: load_forms.MotorLine(float("nan"), 1.0), ["MotorLine", "stall", "finite"]),
        (lambda: load_forms.MotorLine(1.0, 0.0), ["no_load_speed", "must be positive"]),
        (lambda: load_forms.Table([0.0, 1.0], [0.0, 1.0], period=float("nan")), ["Table", "period", "finite"]),
        (lambda: load_forms.Polynomial([1.0, float("inf")]), ["Polynomial", "coefficients", "finite"]),
        (lambda: load_forms.PointForce("B", [float("nan"), 0.0]), ["PointForce", "force", "finite"]),
        (lambda: assurjax.JointFriction("A", -0.1, 0.01), ["JointFriction", "coefficient", "non-negative"]),
        (lambda: assurjax.SlideFriction("B", 0.1, 0.0), ["SlideFriction", "length", "must be positive"]),
        # shapes: each value is a number (a force a 2-vector), named with what was given
        (lambda: assurjax.JointFriction("A", [0.1, 0.2], 0.01), ["JointFriction", "coefficient", "a single number", "shape (2,)"]),
        (lambda: assurjax.JointFriction("A", 0.1, np.ones((1, 1))), ["JointFriction", "radius", "a single number", "shape (1, 1)"]),
        (lambda: assurjax.JointFriction("A", 0.1, 0.01, viscous=[0.0]), ["JointFriction", "viscous", "shape (1,)"]),
        (lambda: assurjax.SlideFriction("B", 0.1, [0.05, 0.1]), ["SlideFriction", "length", "a single number"]),
        (lambda: load_forms.Spring("A", "B", [1.0, 2.0]), ["Spring", "stiffness", "a single number"]),
        (lambda: load_forms.Damper("A", "B", [1.0, 2.0]), ["Damper", "coefficient", "a single number"]),
        (lambda: load_forms.RotaryDamper("A", [1.0, 2.0]), ["RotaryDamper", "coefficient", "a single number"]),
        (lambda: load_forms.MotorLine(1.0, [10.0, 20.0]), ["MotorLine", "no_load_speed", "a single number"]),
        (lambda: load_forms.Couple("crank", [1.0, 2.0]), ["Couple", "moment", "a single number", "shape (2,)"]),
        (lambda: load_forms.Drive([1.0, 2.0]), ["Drive", "value", "a single number"]),
        (lambda: load_forms.PointForce("B", [1.0, 2.0, 3.0]), ["PointForce", "force", "a 2-vector", "shape (3,)"]),
        (lambda: load_forms.PointForce("B", 1.0), ["PointForce", "force", "a 2-vector", "got a single number"]),
        (lambda: load_forms.Vector([1.0, 2.0], 0.0), ["Vector", "x", "a single number"]),
        (lambda: load_forms.Polynomial([[1.0, 2.0]]), ["Polynomial", "coefficients", "c0, c1", "shape (1, 2)"]),
    ],
)
def test_python_loads_reject_bad_values(build, fragments):
    with raises(MechanismError, *fragments):
        build()


@pytest.mark.parametrize(
    "load, fragments",
    [
        (load_forms.Drive(lambda q, w, t: jnp.stack([q, w])), ["Drive", "value", "must return a single number", "shape (2,)"]),
        (load_forms.Couple("coupler", load_forms.Vector(0.0, 1.0)), ["Couple", "moment", "must return a single number", "shape (2,)"]),
        (load_forms.PointForce("B", lambda q, w, t: jnp.zeros(3)), ["PointForce", "force", "must return a 2-vector", "shape (3,)"]),
        (load_forms.PointForce("B", load_forms.Polynomial([1.0, 2.0])), ["PointForce", "force", "must return a 2-vector", "a single number"]),
        (load_forms.PointForce("B", load_forms.Vector(lambda q, w, t: jnp.ones(2), 0.0)), ["PointForce", "force", "component x", "must return a single number"]),
    ],
)
def test_a_function_giving_the_wrong_shape_is_named_before_tracing(load, fragments):
    """A load value given as a function or form is traced once (its shape only) when a scene or model
    takes it: a wrong shape is named there, not found deep inside a compiled program."""
    watt = scene()
    with raises(MechanismError, *fragments):
        watt.with_loads(watt.loads + (load,))
    with raises(MechanismError, *fragments):
        assurjax.simulate(watt, loads=(load,), t1=0.01)


def test_simulation_keywords_and_scene_share_the_messages():
    with raises(SceneError, "[simulation], field 'samples'") as scene_error:
        scene(lambda d: d.update(simulation={"samples": 2_000_000}))
    with raises(assurjax.AssurjaxError, "setting 'samples'") as api_error:
        settings_from(None, samples=2_000_000)
    assert _tail(str(scene_error.value), "samples") == _tail(str(api_error.value), "samples")
    for bad in ({"rtol": float("nan")}, {"max_steps": "many"}, {"table_nodes": 10**9}, {"steps": 10**8}, {"dt": float("inf")}):
        with raises(assurjax.AssurjaxError, f"'{next(iter(bad))}'"):
            settings_from(None, **bad)


def test_traced_values_are_not_checked_so_jit_and_grad_work():
    mech = scene().mechanism

    def coupler_mass_times_stiffness(mass, stiffness):
        link = eqx.tree_at(lambda lk: lk.mass, mech.links["coupler"], mass)
        rebuilt = Mechanism(mech.ground, {**mech.links, "coupler": link}, mech.groups)
        return rebuilt.links["coupler"].mass * load_forms.Spring("A", "O4", stiffness).stiffness

    value, grads = jax.jit(jax.value_and_grad(coupler_mass_times_stiffness, argnums=(0, 1)))(2.0, 3.0)
    assert float(value) == 6.0 and [float(g) for g in grads] == [3.0, 2.0]


# -- numbers and requests checked where they are given -------------------------------------------


@pytest.mark.parametrize("make, message", [
    (lambda: assurjax.JointFriction(["A"], 0.1, 0.01), "JointFriction: the pair must be named by a string"),
    (lambda: assurjax.JointFriction("A", "0.1", 0.01), "JointFriction 'A': coefficient must be a number or an array of numbers, got '0.1'"),
    (lambda: assurjax.JointFriction("A", True, 0.01), "JointFriction 'A': coefficient must be a number or an array of numbers, got True"),
    (lambda: assurjax.SlideFriction("slider/ground", 0.1, "0.05"), "SlideFriction 'slider/ground': length must be a number"),
])
def test_friction_numbers_are_numbers(make, message):
    # NumPy reads "0.1" as 0.1 and True as 1.0: the scene loader refused them, the API took them
    with pytest.raises(MechanismError, match=message):
        make()


def test_requests_for_work_and_solvers_without_friction_are_refused_by_name():
    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(assurjax.AssurjaxError, match="inverse_dynamics: the times t: at most 1,000,000 states per call"):
        assurjax.inverse_dynamics(scene, lambda t: 2.0 * t, np.zeros(1_000_001))
    with pytest.raises(assurjax.AssurjaxError, match="kinematics: at most 1,000,000 states per call, got 2,000,000"):
        assurjax.kinematics(scene.mechanism, np.zeros((1000, 2000)))
    with pytest.raises(assurjax.AssurjaxError, match="reactions: at most 1,000,000 states per call"):
        assurjax.reactions(scene, (np.zeros(1_000_001), 0.0, 0.0))
    with pytest.raises(assurjax.AssurjaxError, match="saveat must be a 1-D array of at least one time"):
        assurjax.simulate(scene, saveat=[])
    with pytest.raises(assurjax.AssurjaxError, match="save_steps saves every solver step: max_steps must be at most 100000"):
        assurjax.simulate(scene, save_steps=True, max_steps=200_000)
    rough = scene.with_loads((assurjax.JointFriction("A", 0.1, 0.01),))
    with pytest.raises(assurjax.AssurjaxError, match="solver='seed_euler' .* has no joint friction"):
        assurjax.simulate(rough, solver="seed_euler")


def test_more_inputs_named_where_they_are_given():
    scene = assurjax.load_scene("slider_crank")
    for kwargs, message in ((dict(q=np.nan), "reduce: q must be finite"), (dict(q=None), "reduce: q must be a number"),
                            (dict(q=0.3, gravity=[0.0, -9.81, 0.0]), "reduce: gravity must be a 2-vector")):
        with pytest.raises(assurjax.AssurjaxError, match=message):
            assurjax.reduce(scene, **kwargs)
    for motion, message in ((lambda t: None, "motion q\\(t\\) must return a number, it returns None"),
                            (lambda t: "x", "motion q\\(t\\) must return a number, it returns 'x'"),
                            (lambda t: np.sin(t), "motion q\\(t\\) must be written with jax.numpy"),
                            (lambda t: 1.0 if t > 0.5 else 0.0, "motion q\\(t\\) must be written with jax.numpy")):
        with pytest.raises(assurjax.AssurjaxError, match=message):
            assurjax.inverse_dynamics(scene, motion, np.linspace(0.0, 1.0, 3))
    with pytest.raises(assurjax.AssurjaxError, match="inverse_dynamics: t must be a number"):
        assurjax.inverse_dynamics(scene, lambda t: 2.0 * t, None)
    with pytest.raises(assurjax.AssurjaxError, match="unknown adjoint 'foo'; choose one of .*'quadrature', 'sensitivity'"):
        synthesis.final_state(scene, 0.5, adjoint="foo")
    with pytest.raises(assurjax.AssurjaxError, match="standstill_time: adjoint='backsolve' solves no events"):
        synthesis.standstill_time(scene, adjoint="backsolve")
    with pytest.raises(assurjax.AssurjaxError, match="quadrature needs integers panels >= 1 and nodes from 2 to 64"):
        synthesis.final_state(scene, 0.5, adjoint="quadrature", panels=2.5)
    with pytest.raises(assurjax.AssurjaxError, match="panels \\* nodes at most 100,000"):
        synthesis.final_state(scene, 0.5, adjoint="quadrature", panels=10**7)
    with pytest.raises(assurjax.AssurjaxError, match="saveat: at most 100,000 times"):
        assurjax.simulate(scene, saveat=np.linspace(0.0, 1.0, 100_001))
    with pytest.raises(assurjax.AssurjaxError, match="saveat must be finite times"):
        assurjax.batch_simulate(scene, jax.tree.map(lambda x: np.stack([x, x]), scene.mechanism), saveat=[0.0, np.nan])


def test_inverse_dynamics_of_an_integer_motion_holds_it_there():
    # a crank held at q = 1 (an int, which raised): the effort holds it against gravity,
    # dV/dq by central differences of the potential energy sum m g y_com
    scene = assurjax.load_scene("watt_sixbar")
    held = assurjax.inverse_dynamics(scene, lambda t: 1, np.linspace(0.0, 1.0, 3)).driving
    mech, g = scene.mechanism, -float(scene.gravity[1])

    def potential(q):
        coms = assurjax.kinematics(mech, q, order=0).coms
        return sum(float(link.mass) * g * float(coms[name][1]) for name, link in mech.links.items())

    h = 1e-6
    np.testing.assert_allclose(held, (potential(1.0 + h) - potential(1.0 - h)) / (2 * h), rtol=1e-7)


def test_a_batch_counts_a_member_that_cannot_assemble_at_the_start_once():
    import dataclasses

    from assurjax.dynamics._results import LOCKUP, NO_EVENT, START_NOT_ASSEMBLED
    from assurjax.dynamics._solution import batch_summary

    @dataclasses.dataclass
    class Ends:  # the fields batch_summary reads
        result: np.ndarray
        event: np.ndarray
        status: str = ""
        jammed: np.ndarray | None = None

    # its event says lock-up (the check that found it); it was counted there as well
    summary = batch_summary(Ends(np.array([0, START_NOT_ASSEMBLED]), np.array([NO_EVENT, LOCKUP])))
    assert summary.status == "batch of 2: 1 reached t1, 1 cannot assemble at the start"


def test_position_analyses_name_what_they_are_given():
    """A point given as a string was read letter by letter (KeyError 'P'), a vector q failed
    in a stack, near as lists reached a linear solver, positions_tracked([]) an IndexError,
    coefficients(order=7) ran as order 2, a window of 1 rad bridged over the whole motion."""
    mech = assurjax.load_scene("triad_mechanism").mechanism
    assert set(assurjax.positions(mech, 0.3, points="P1").points) == {"P1"}
    calls = [
        (lambda: assurjax.positions(mech, 0.3, points=["Q"]), "positions: unknown point\\(s\\) \\['Q'\\]"),
        (lambda: assurjax.positions(mech, np.zeros(3)), "positions: q .* must be a single number"),
        (lambda: assurjax.positions(mech, 1e20), "positions: q .* must be at most 1e\\+12"),
        (lambda: assurjax.positions(mech, 0.3, near={"T": [0.1, 0.2]}), "positions: near\\['T'\\] must be a single number"),
        (lambda: assurjax.positions(mech, 0.3, near={"X": 0.1}), "positions: near names unknown link\\(s\\) \\['X'\\]"),
        (lambda: assurjax.pose_at(mech, [0.1, 0.2]), "q .* must be a single number"),
        (lambda: assurjax.positions_tracked(mech, []), "positions_tracked: qs must be a 1-D path"),
        (lambda: assurjax.positions_tracked(mech, 0.3), "positions_tracked: qs must be a 1-D path"),
        (lambda: assurjax.positions_tracked(mech, np.array([0.0, np.nan])), "positions_tracked: qs must be finite"),
        (lambda: assurjax.positions_tracked(mech, [0.1, 0.2], points=["Q"]), "positions_tracked: unknown point"),
        (lambda: assurjax.coefficients(mech, 0.3, order=7), "coefficients: order must be 0, 1 or 2"),
        (lambda: assurjax.bridged_coefficients(mech, 0.3, near=None), "bridged_coefficients: near must map"),
        (lambda: assurjax.bridged_coefficients(mech, 0.3, near={}, window=1.0), "bridged_coefficients: window .* at most 0.1"),
        (lambda: assurjax.bridged_coefficients(mech, 0.3, near={}, window=-1.0), "bridged_coefficients: window must be positive"),
    ]
    for call, message in calls:
        with pytest.raises(assurjax.AssurjaxError, match=message):
            call()


def python_four_bar(ground=None, crank=None, mass=1.0, joints=("A", "O4", "B"), links=None):
    """The four-bar above built in Python, with one part replaced."""
    links = links or {"crank": Link(crank or {"O2": [0.0, 0.0], "A": [0.3, 0.0]}, mass=mass, inertia=0.01),
                      "coupler": Link({"A": [0.0, 0.0], "B": [1.0, 0.0]}, mass=1.0, inertia=0.1),
                      "rocker": Link({"O4": [0.0, 0.0], "B": [0.8, 0.0]}, mass=1.0, inertia=0.05)}
    return Mechanism(ground or {"O2": [0.0, 0.0], "O4": [1.0, 0.0]}, links,
                     [groups.Crank("drive", ("crank",), "O2"), groups.RRR("dyad", ("coupler", "rocker"), joints, "left")])


PYTHON_MISTAKES = {
    # each was taken (a third coordinate dropped, "0.3" read as 0.3) or failed in JAX's words
    "a ground point in 3-D": (lambda: python_four_bar(ground={"O2": [0.0, 0.0], "O4": [1.0, 0.0, 7.0]}), "ground point 'O4' must be a 2-vector"),
    "a ground point a number": (lambda: python_four_bar(ground={"O2": [0.0, 0.0], "O4": 1.0}), "ground point 'O4' must be a 2-vector"),
    "a link point in 3-D": (lambda: python_four_bar(crank={"O2": [0.0, 0.0], "A": [0.3, 0.0, 0.0]}), "each point must be \\[x, y\\].*'A': \\(3,\\)"),
    "a coordinate as a word": (lambda: python_four_bar(crank={"O2": [0.0, 0.0], "A": ["0.3", 0.0]}), "numbers only, got \\['0.3', 0.0\\]"),
    "two masses": (lambda: python_four_bar(mass=[1.0, 2.0]), "link 'crank': mass must be a single number"),
    "an RRR with two joints": (lambda: python_four_bar(joints=("A", "O4")), "group 'dyad' \\(RRR\\): joints must be a tuple of 3 names"),
    "a dict for a link": (lambda: python_four_bar(links={"crank": {"O2": [0.0, 0.0], "A": [0.3, 0.0]}}), "link 'crank': expected an assurjax.Link, got dict"),
}


@pytest.mark.parametrize("case", list(PYTHON_MISTAKES))
def test_python_constructors_name_the_part_at_fault(case):
    build, message = PYTHON_MISTAKES[case]
    with pytest.raises(MechanismError, match=message):
        build()


def test_a_slot_through_the_cranks_pivot_is_a_mechanism():
    # a rotating slotted crank: its guide's point G sits on the pivot O, and the slot's line still
    # turns with the crank (the zero-length test of a crank's arms refused it): the block in it
    # lies where the rod's circle about H meets the slot's line
    links = {"slot": Link({"O": [0.0, 0.0], "G": [0.0, 0.0]}, com=[0.05, 0.0], mass=1.0, inertia=0.01),
             "rod": Link({"H": [0.0, 0.0], "J": [0.15, 0.0]}, mass=0.5, inertia=0.005),
             "block": Link({"J": [0.0, 0.0]}, mass=0.2, inertia=0.001)}
    mech = Mechanism({"O": [0.0, 0.0], "H": [0.0, 0.1]}, links,
                     [groups.Crank("c", ("slot",), "O"), groups.RRP("d", ("rod", "block"), ("H", "J"), "G", 1, jnp.array([1.0, 0.0]), 0.0)])
    q = 0.3
    u, h = np.array([np.cos(q), np.sin(q)]), np.array([0.0, 0.1])
    pose = assurjax.positions(mech, q)
    j = np.asarray(pose.points["J"])
    assert abs(np.hypot(*(j - h)) - 0.15) < 1e-12 and abs(u[0] * j[1] - u[1] * j[0]) < 1e-12  # on the circle and the slot


def test_a_mechanism_replaced_in_a_scene_is_checked():
    """A NaN mass set by eqx.tree_at and put in a scene ran and failed as a load's NaN (or a
    step budget), a negative one gave numbers: replace_mechanism checks the values as the
    Mechanism's own; traced values pass (a gradient through it)."""
    scene = assurjax.load_scene("slider_crank")
    with pytest.raises(MechanismError, match="link 'crank': mass must be finite"):
        scene.replace_mechanism(eqx.tree_at(lambda m: m.links["crank"].mass, scene.mechanism, np.nan))
    with pytest.raises(MechanismError, match="link 'crank': mass must be non-negative"):
        scene.replace_mechanism(eqx.tree_at(lambda m: m.links["crank"].mass, scene.mechanism, -0.5))
    traced = jax.jit(lambda m: scene.replace_mechanism(eqx.tree_at(lambda x: x.links["crank"].mass, scene.mechanism, m))
                     .mechanism.links["crank"].mass)
    assert float(traced(0.7)) == 0.7


@pytest.mark.parametrize("name", ["B[rocker]", "P/Q", "com:P"])
def test_a_point_may_not_take_a_name_the_package_gives_a_pair_or_a_centre(name):
    """Pairs of a joint of three links or more are named 'B[link]', prismatic pairs
    'slider/guide', centres of mass 'com:link': a point so named shared its name with one."""
    with raises(assurjax.AssurjaxError, f"'{name}'", "reserved"):
        scene(lambda d: d["links"]["coupler"]["points"].update({name: [0.5, 0.1]}))
