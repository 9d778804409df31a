"""Kinetostatics: joint reactions and driving effort, checked against independent routes.

- Newton-Euler equilibrium of every link, summed here from the returned reactions,
  the applied loads and the inertia terms (not from the solver's matrices).
- Virtual work: the driving torque equals J_red dw/dt + 0.5 dJ_red/dq w^2 - tau_red
  from the power-equivalent reduction (seed 000 eqs. 1-6).
- The joint-coordinate reference tests/joint_reference.py (numpy/scipy, Lagrange
  multipliers) for the Watt six-bar of seed 000.
- Statics: the holding torque at rest is dV/dq (central finite differences of the
  potential energy).
"""

import os
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax._geometry import cross, rotation
from assurjax._kinetostatics import SingularConfigurationError, joint_names, reactions, static_reactions, static_torque
from assurjax._kinematics import _kinematics_single
from assurjax._kinetostatics import _api as kinetostatics_api
from assurjax._kinetostatics._api import from_kinematics
from assurjax._kinetostatics._batches import solve_order
from assurjax._kinetostatics._layout import group_pairs
from assurjax._reduction import reduce_single

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402
from scene_texts import SLIDER_DRIVEN  # noqa: E402
from slow_cases import marked_slow  # noqa: E402

N_STATES = 4

# the in-line slider-crank written with its dyad listed from the prismatic end
PRR_SLIDER_CRANK = """
[scene]
name = "slider_crank_prr"
gravity = [0.0, -9.81]
[ground]
O = [0.0, 0.0]
[links.crank]
points = { O = [0.0, 0.0], A = [0.1, 0.0] }
com = [0.05, 0.0]
mass = 0.5
inertia = 0.001
[links.rod]
points = { A = [0.0, 0.0], B = [0.3, 0.0] }
com = [0.12, 0.01]
mass = 1.0
inertia = 0.0075
[links.slider]
points = { B = [0.0, 0.0] }
com = [0.02, 0.03]
mass = 0.8
inertia = 0.002
[[formation]]
group = "crank"
name = "crank"
link = "crank"
pivot = "O"
[[formation]]
group = "PRR"
name = "slider_rod"
links = ["slider", "rod"]
joints = ["B", "A"]
guide_point = "O"
direction = [1.0, 0.2]
offset = 0.02
mode = "forward"
[state]
q0 = 0.5
"""

# the slider-driven rocker of tests/joint_reference.py (slider_driven): the driver is a slider

# a four-bar whose output dyad is exactly collinear (A, B, O4 on the x axis) at q = 0,
# where |A O4| = 4 is at its largest and equals coupler + rocker: it assembles for every q
TOGGLE_FOUR_BAR = """
[scene]
name = "toggle"
gravity = [0.0, -9.81]
[ground]
O2 = [0.0, 0.0]
O4 = [-3.0, 0.0]
[links.crank]
points = { O2 = [0.0, 0.0], A = [1.0, 0.0] }
mass = 1.0
inertia = 0.1
[links.coupler]
points = { A = [0.0, 0.0], B = [1.0, 0.0] }
mass = 1.0
inertia = 0.1
[links.rocker]
points = { O4 = [0.0, 0.0], B = [3.0, 0.0] }
mass = 1.0
inertia = 0.1
[[formation]]
group = "crank"
link = "crank"
pivot = "O2"
[[formation]]
group = "RRR"
name = "dyad"
links = ["coupler", "rocker"]
joints = ["A", "O4", "B"]
mode = "left"
"""


def _two_cylinder() -> dict:
    """The bundled slider-crank with a second connecting rod and piston on another pin of its
    crank, on a guide of another direction and offset: two RRP dyads at one level, solved as
    one batch."""
    import tomllib

    data = tomllib.loads((Path(assurjax.__file__).parent / "scenes" / "slider_crank.toml").read_text())
    data["scene"]["name"] = "two_cylinder"
    data["links"]["crank"]["points"]["C"] = [-0.05, 0.08]
    data["links"]["rod2"] = dict(points={"C": [0.0, 0.0], "D": [0.35, 0.0]}, com=[0.17, 0.01], mass=1.2, inertia=0.009)
    data["links"]["piston2"] = dict(points={"D": [0.0, 0.0]}, com=[0.0, 0.0], mass=0.7, inertia=0.0)
    data["formation"].append(dict(data["formation"][1], name="second", links=["rod2", "piston2"], joints=["C", "D"],
                                  direction=[0.0, 1.0], offset=0.02))
    return data


def _scenes():
    from assurjax.scene._load import scene_from_dict
    import tomllib

    scenes = {name: assurjax.load_scene(name) for name in assurjax.bundled_scenes()}
    scenes["slider_crank_prr"] = scene_from_dict(tomllib.loads(PRR_SLIDER_CRANK), source="prr")
    scenes["slider_driven"] = scene_from_dict(tomllib.loads(SLIDER_DRIVEN), source="slider_driven")
    scenes["two_cylinder"] = scene_from_dict(_two_cylinder(), source="two_cylinder")
    return scenes


SCENES = _scenes()


def _states(scene, seed):
    rng = np.random.default_rng(seed)
    q0 = scene.state["q0"]
    span = 0.05 if scene.mechanism.driver.kind == "slider" else 0.3
    q = q0 + rng.uniform(-span, span, N_STATES)
    w, a = rng.normal(size=N_STATES) * 2.0, rng.normal(size=N_STATES) * 3.0
    t = rng.uniform(0.0, 1.0, N_STATES)
    return q, w, a, t


class Solved(NamedTuple):
    forces: dict
    couples: dict
    driving: object
    ok: object
    pairs: tuple

    def __getitem__(self, name):
        return self.forces[name]


def _by_moments(scene, kin, t):
    """The modular solve traced with the class-IV normal components always taken from
    moments about the closure links' joints (the branch for near-parallel normals)."""
    from assurjax._kinetostatics import _class4

    saved, _class4.NORMALS_BY_FORCES = _class4.NORMALS_BY_FORCES, 2.0
    try:
        return from_kinematics(scene, kin, t, method="modular")
    finally:
        _class4.NORMALS_BY_FORCES = saved


def evaluate(scene, state, methods=("modular",), reduction=True):
    """Kinematics, the reactions by each method and the reduction (unless not asked) at a
    batch of states, in one compiled function (one compile per scene keeps the suite fast)."""
    pairs = tuple(p for ps in group_pairs(scene.mechanism) for p in ps)

    def one(q, w, a, t):
        kin = _kinematics_single(scene.mechanism, q, w, a, None, 2)
        found = {m: _by_moments(scene, kin, t) if m == "by_moments" else from_kinematics(scene, kin, t, method=m) for m in methods}
        return kin, found, reduce_single(scene.mechanism, scene.gravity, scene.loads, q, w, t) if reduction else None

    kin, found, red = jax.jit(jax.vmap(one))(*(jnp.asarray(v, dtype=float) for v in state))
    return kin, {m: Solved(*found[m], pairs) for m in methods}, red


PRISMATIC_DYADS = ("RRP", "PRR", "RPR", "PRP")  # the dyads with prismatic pairs, all solved in closed form


def _has_prismatic_dyad(scene):
    return any(g.kind in PRISMATIC_DYADS for g in scene.mechanism.groups)


class _Solved(dict):
    """Per scene, computed when a test first asks for it: states, kinematics, reactions and reduction."""

    def __missing__(self, name):
        scene = SCENES[name]
        state = _states(scene, list(SCENES).index(name))
        prismatic = _has_prismatic_dyad(scene)  # closed forms against their 6 x 6 systems
        methods = ("modular", "dense", "global") if name == "watt_sixbar" else ("modular", "dense") if prismatic else ("modular",)
        kin, found, red = evaluate(scene, state, methods)
        self[name] = (scene, state, found, kin, red)
        return self[name]


@pytest.fixture(scope="module")
def solved():
    return _Solved()


def _scene_params(names):
    """The scenes as parameters; in the slow suite the strandbeest (25 groups, ~15 s of
    compilation), class IV's (~13 s; its statics checked by default against the 12 x 12 solve),
    the four-bar of roberts (as the Watt six-bar's), the two-cylinder (its batches checked
    by default below) and the triad (~10 s): the default suite keeps to 10 min."""
    return marked_slow(names, ("strandbeest", "class4_seed003", "roberts", "two_cylinder", "triad_mechanism"))


def _single(tree, i):
    return jax.tree.map(lambda x: x[i] if hasattr(x, "shape") and x.ndim > 0 else x, tree)


def newton_euler_residuals(scene, kin, r, t):
    """Per link (force x, force y, moment about the COM) of all loads, inertia terms
    and reactions: zero for a link in dynamic equilibrium."""
    mech = scene.mechanism
    wrenches = assurjax.applied_wrenches(mech, scene.gravity, scene.loads, kin, t)
    res = {}
    for name, link in mech.links.items():
        f, m = wrenches[name]
        res[name] = [f - link.mass * kin.com_accelerations[name], m - link.inertia * kin.angular_accelerations[name]]

    def apply(link, at, force, couple):
        if link in res:
            res[link][0] = res[link][0] + force
            res[link][1] = res[link][1] + couple + cross(at - kin.coms[link], force)

    for pair in r.pairs:
        at = kin.points[pair.point]
        force = r.forces[pair.name]
        couple = r.couples.get(pair.name, jnp.zeros(()))
        apply(pair.on, at, force, couple)
        apply(pair.by, at, -force, -couple)
    driver = mech.driver
    link = driver.links[0]
    if driver.kind == "crank":
        apply(link, kin.coms[link], jnp.zeros(2), r.driving)
    else:
        u = jnp.stack([jnp.cos(kin.angles[link]), jnp.sin(kin.angles[link])])
        apply(link, kin.points[driver.point], r.driving * u, jnp.zeros(()))
    return np.array([[*np.asarray(f), float(m)] for f, m in res.values()])


@pytest.mark.parametrize("name", _scene_params(SCENES))
def test_every_link_in_equilibrium(solved, name):
    scene, (q, w, a, t), found, kin, _ = solved[name]
    r = found["modular"]
    assert np.all(np.asarray(r.ok))
    for i in range(N_STATES):
        residual = newton_euler_residuals(scene, _single(kin, i), _single(r, i), t[i])
        assert np.max(np.abs(residual)) < 1e-10, (name, i, residual)


@pytest.mark.parametrize("name", _scene_params(SCENES))
def test_driving_effort_is_the_virtual_work_of_the_reduction(solved, name):
    scene, (q, w, a, t), found, _, red = solved[name]
    r = found["modular"]
    expected = red.inertia * a + 0.5 * red.dinertia * w**2 - red.torque
    np.testing.assert_allclose(r.driving, expected, rtol=0, atol=1e-10)


def test_group_by_group_equals_dense_and_global_solves(solved):
    _, _, found, _, _ = solved["watt_sixbar"]
    r = found["modular"]
    for method in ("dense", "global"):
        other = found[method]
        for joint in r.forces:
            np.testing.assert_allclose(other[joint], r[joint], rtol=0, atol=1e-9, err_msg=f"{method} {joint}")
        np.testing.assert_allclose(other.driving, r.driving, rtol=0, atol=1e-9)


# the strandbeest's in the slow suite (~10 s of compiles), as test_friction.py's batches with friction
@pytest.mark.parametrize("name, batches", [pytest.param("two legs", [2, 2], marks=pytest.mark.slow), ("two_cylinder", [2])])
def test_groups_of_one_kind_at_one_level_are_solved_together(name, batches):
    """The two-legged strandbeest's legs (RRR dyads) and the two cylinders' slider dyads
    (RRP) are solved in batches (one vmap per kind of group and level): every link stays in
    equilibrium, and the reactions equal those of the groups solved one at a time (round-off)
    and of the mechanism's single dense system."""
    scene = assurjax.strandbeest(1) if name == "two legs" else SCENES[name]
    mech = scene.mechanism
    assert sorted(len(b) for b in solve_order(mech, group_pairs(mech), range(len(mech.groups))) if len(b) > 1) == batches
    q, w, a, t = _states(scene, 7)
    ways = {"batched": ("modular", True), "one at a time": ("modular", False), "global": ("global", True)}

    def one(q, w, a, t):
        kin = _kinematics_single(mech, q, w, a, None, 2)
        return kin, {way: from_kinematics(scene, kin, t, method=m, batched=b) for way, (m, b) in ways.items()}

    kin, found = jax.jit(jax.vmap(one))(*(jnp.asarray(v, dtype=float) for v in (q, w, a, t)))
    pairs = tuple(p for ps in group_pairs(mech) for p in ps)
    r = Solved(*found["batched"], pairs)
    assert np.all(np.asarray(r.ok))
    for i in range(N_STATES):
        residual = newton_euler_residuals(scene, _single(kin, i), _single(r, i), t[i])
        assert np.max(np.abs(residual)) < 1e-10, (i, residual)
    for way, tol in (("one at a time", 1e-12), ("global", 1e-9)):
        other = Solved(*found[way], pairs)
        for joint in r.forces:
            np.testing.assert_allclose(r[joint], other[joint], rtol=0, atol=tol, err_msg=f"{way} {joint}")
        for joint in r.couples:
            np.testing.assert_allclose(r.couples[joint], other.couples[joint], rtol=0, atol=tol, err_msg=f"{way} {joint}")
        np.testing.assert_allclose(r.driving, other.driving, rtol=0, atol=tol)


@pytest.mark.parametrize("name", _scene_params(n for n, s in SCENES.items() if _has_prismatic_dyad(s)))
def test_prismatic_dyad_closed_forms_equal_their_dense_solves(solved, name):
    _, _, found, _, _ = solved[name]
    r, dense = found["modular"], found["dense"]
    for joint in r.forces:
        np.testing.assert_allclose(r[joint], dense[joint], rtol=1e-12, atol=1e-9, err_msg=joint)
    for joint in r.couples:
        np.testing.assert_allclose(r.couples[joint], dense.couples[joint], rtol=1e-12, atol=1e-9, err_msg=joint)
    np.testing.assert_allclose(r.driving, dense.driving, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(r.ok, dense.ok)


def test_every_prismatic_dyad_kind_is_covered():
    kinds = {g.kind for s in SCENES.values() for g in s.mechanism.groups}
    assert set(PRISMATIC_DYADS) <= kinds


def _dyad_geometry(kind, slant):
    """(scene, group index, geometry) of a dyad, singular at slant = 0 (closed form's
    determinant zero): RRP/PRR the rod normal to the guide, RPR E1 - E2 normal to the
    guide (|E1 E2| = |offset|), PRP the two guides parallel."""
    from assurjax._kinetostatics._system import Geometry

    if kind in ("RRP", "PRR"):  # rod A-B, slider at B on a guide along x
        geom = Geometry(points={"A": jnp.array([slant, 0.3]), "B": jnp.zeros(2)},
                        coms={"rod": jnp.array([0.5 * slant, 0.15]), "slider": jnp.array([0.02, -0.01])},
                        rots={"slider": rotation(0.0), "rod": rotation(np.pi / 2)})
        return ("slider_crank" if kind == "RRP" else "slider_crank_prr"), 1, geom
    if kind == "RPR":  # block at A in the arm's slot along x, arm pivot O4 (an offset slot)
        geom = Geometry(points={"A": jnp.array([slant, 0.3]), "O4": jnp.zeros(2)},
                        coms={"block": jnp.array([slant + 0.01, 0.3]), "arm": jnp.array([0.2, 0.25])},
                        rots={"block": rotation(0.0), "arm": rotation(0.0)})
        return "quick_return", 1, geom
    # PRP: the block's guide (on the crank) turned by slant from the slide's (on the ground)
    geom = Geometry(points={"J": jnp.array([0.3, 0.2])},
                    coms={"block": jnp.array([0.31, 0.2]), "slide": jnp.array([0.25, 0.22])},
                    rots={"block": rotation(slant), "slide": rotation(0.0)})
    return "tangent_drive", 1, geom


@pytest.mark.parametrize("kind", PRISMATIC_DYADS)
def test_prismatic_dyad_singular_geometry_is_flagged(kind):
    """At the singular geometry the reactions are not determined by statics: the closed
    form's determinant and the dyad's 6 x 6 system both vanish; nearby both agree."""
    from assurjax._kinetostatics._api import SOLVERS
    from assurjax._kinetostatics._system import solve_dense

    for slant, singular in ((0.0, True), (0.3, False)):
        name, index, geom = _dyad_geometry(kind, slant)
        mech = SCENES[name].mechanism
        group, pairs = mech.groups[index], group_pairs(mech)[index]
        assert group.kind == kind
        a, b = group.links
        known = {a: (jnp.array([1.0, -2.0]), jnp.array(0.3)), b: (jnp.array([0.5, 1.0]), jnp.array(-0.2))}
        closed, _, ok = SOLVERS[kind](group, pairs, geom, known)
        dense, _, ok_dense = solve_dense(group.links, pairs, geom, known)
        assert bool(ok) == bool(ok_dense) == (not singular), (slant, bool(ok), bool(ok_dense))
        assert set(closed) == {p.name for p in pairs}
        assert all(np.all(np.isfinite(np.asarray(v))) for r in (closed, dense) for x in r.values() for v in x)
        if not singular:
            for joint in closed:
                np.testing.assert_allclose(closed[joint].force, dense[joint].force, rtol=0, atol=1e-12, err_msg=joint)
                np.testing.assert_allclose(closed[joint].couple, dense[joint].couple, rtol=0, atol=1e-12, err_msg=joint)


def test_prr_is_rrp_listed_from_the_other_end(solved):
    """Same mechanism, dyad listed either way: B's reaction flips (the later link
    changes), everything else is the same."""
    from assurjax.scene._load import scene_from_dict
    import tomllib

    data = tomllib.loads(PRR_SLIDER_CRANK)
    data["formation"][1] = dict(group="RRP", name="rod_slider", links=["rod", "slider"], joints=["A", "B"], guide_point="O",
                                direction=[1.0, 0.2], offset=0.02, mode="forward")
    rrp = scene_from_dict(data, source="rrp")
    _, state, found, _, _ = solved["slider_crank_prr"]
    prr = found["modular"]
    other = reactions(rrp, state)
    np.testing.assert_allclose(other["B"], -prr["B"], atol=1e-10)
    for joint in ("O", "A", "slider/ground"):
        np.testing.assert_allclose(other[joint], prr[joint], atol=1e-10)
    np.testing.assert_allclose(other.couples["slider/ground"], prr.couples["slider/ground"], atol=1e-10)


def test_slider_driver_matches_the_joint_reference(solved):
    """Reactions and driving force of a slider-driven rocker against the reference's
    inverse dynamics at the same (q, w, dw/dt). The reference gives P on the ground by
    the slider (and its couple), B on the slider by the rod, C on the rod by the
    rocker, O3 on the rocker by the ground."""
    _, (q, w, a, t), found, _, _ = solved["slider_driven"]
    r = found["modular"]
    flip = {"slider/ground": ("P", -1), "B": ("B", -1), "C": ("C", -1), "O3": ("O3", 1)}
    for k in range(N_STATES):
        model = jr.slider_driven(float(q[k]), float(w[k]))
        s = model.system
        z = s.newton(float(q[k]), s.to_internal(model.initial.coords))
        z = z[0] if isinstance(z, tuple) else z
        tau, lam, _, _ = s.inverse_dynamics(z, float(w[k]), float(a[k]))
        forces, couples = s.reactions(z, lam)
        assert abs(float(r.driving[k]) - tau) < 1e-10
        for ours, (theirs, sign) in flip.items():
            np.testing.assert_allclose(r[ours][k], sign * forces[theirs], rtol=0, atol=1e-10, err_msg=ours)
        assert abs(float(r.couples["slider/ground"][k]) + couples["P"]) < 1e-10


def _reference_watt(q, w):
    """Joint-reference multipliers at (q, w): (wdot, {joint: force on body_i by body_j})."""
    model = jr.watt_sixbar(float(q), float(w))
    s = model.system
    z = s.newton(float(q), s.to_internal(model.initial.coords))
    z = z[0] if isinstance(z, tuple) else z  # (z, Jf)
    wdot, _, _, lam, _ = s.accelerations(z, float(w))
    forces, _ = s.reactions(z, lam)
    return wdot, forces


def test_watt_reactions_match_the_joint_reference_along_its_motion():
    """Along the reference's own fall from rest at theta2 = 0 (its q, w, dw/dt).
    The reference gives O2 on the ground by the crank, A on the crank by the
    coupler, E on link5 by link6: each is minus ours (on the later link)."""
    scene = SCENES["watt_sixbar"]
    run = jr.watt_sixbar(0.0, 0.0).simulate(1.5, t_eval=np.linspace(0.0, 1.5, 16))
    solution_like = SimpleNamespace(t=run.t, q=run.q, omega=run.w, domega=run.wdot)  # what a Solution carries
    r = reactions(scene, solution_like, joints=["O2", "A", "E"])
    for joint in ("O2", "A", "E"):
        np.testing.assert_allclose(r[joint], -run.reactions[joint], rtol=0, atol=1e-6, err_msg=joint)
    np.testing.assert_allclose(r.driving, run.tau_needed, atol=1e-9)  # free fall: no driving torque needed
    np.testing.assert_allclose(r.driving, 0.0, atol=1e-9)


@pytest.mark.slow
def test_watt_reactions_along_the_package_simulation(monkeypatch):
    """assurjax.simulate from rest at theta2 = 0 until standstill, then the reactions
    along the Solution (vmapped) against the reference at the same (q, w).
    Simulating traces no kinetostatics."""
    scene = SCENES["watt_sixbar"]

    def traced(*args, **kwargs):
        raise AssertionError("simulate traced the kinetostatics")

    with monkeypatch.context() as patch:
        patch.setattr(kinetostatics_api, "solve_groups", traced)
        sol = assurjax.simulate(scene, samples=12, rtol=1.01e-8)  # a program no other test compiled
    r = reactions(scene, sol, joints=("O2", "A", "E"))
    for k in range(0, len(sol.t), 3):
        wdot, ref = _reference_watt(sol.q[k], sol.omega[k])
        assert abs(float(sol.domega[k]) - wdot) < 1e-8
        for joint in ("O2", "A", "E"):
            np.testing.assert_allclose(r[joint][k], -ref[joint], rtol=0, atol=1e-6, err_msg=joint)


@pytest.mark.parametrize("name", ["watt_sixbar"])
def test_static_torque_is_the_derivative_of_the_potential(name):
    scene = SCENES[name]
    mech = scene.mechanism
    q = scene.state["q0"] + np.array([0.2, 0.9])
    tau = static_torque(scene, q)
    h = 1e-5

    def potential(qq):
        pose = assurjax.pose_at(mech, qq)
        return float(assurjax.potential_energy(mech, scene.gravity, scene.loads, pose))

    dv = np.array([(potential(x + h) - potential(x - h)) / (2 * h) for x in q])
    np.testing.assert_allclose(tau, dv, rtol=1e-7, atol=1e-7)


def test_unknown_joint_is_a_clear_error():
    scene = SCENES["watt_sixbar"]
    with pytest.raises(assurjax.AssurjaxError, match=r"unknown joint\(s\) \['Z'\].*watt_sixbar"):
        reactions(scene, (0.3, 0.0, 0.0), joints=["A", "Z"])
    r = reactions(scene, (0.3, 0.0, 0.0), joints=["A"])
    with pytest.raises(assurjax.AssurjaxError, match="no reaction at joint 'E'"):
        r["E"]
    assert set(joint_names(scene.mechanism)) == {"O2", "A", "O4", "B", "C", "D", "E"}


def test_singular_dyad_is_a_clear_error_not_nan():
    from assurjax.scene._load import scene_from_dict
    import tomllib

    scene = scene_from_dict(tomllib.loads(TOGGLE_FOUR_BAR), source="toggle")
    with pytest.raises(SingularConfigurationError, match="group 'dyad' \\(RRR\\).*singular") as info:
        static_torque(scene, 0.0)
    assert info.value.group == "dyad"
    r = static_reactions(scene, jnp.array([0.0, 0.4]), check=False)  # flags instead of raising
    assert np.asarray(r.ok).tolist() == [[True, False], [True, True]]
    assert all(np.all(np.isfinite(np.asarray(v))) for v in r.forces.values())
    # the same system, solved whole, is singular too, and the error names the same group (the
    # whole mechanism's system named its first group, the crank)
    for method in ("dense", "global"):
        with pytest.raises(SingularConfigurationError, match="group 'dyad' \\(RRR\\).*singular") as info:
            reactions(scene, (0.0, 0.0, 0.0), method=method)
        assert info.value.group == "dyad"


def test_reactions_where_a_group_does_not_close_say_so():
    """Where a group cannot assemble its statics is void, not singular: the AssemblyError of
    the kinematics, naming the group (it was a SingularConfigurationError). The Roberts
    linkage's dyad reaches only while |B D| <= 0.30 (closed form: q = 2 puts B 0.35 m from D),
    and the error says so with those lengths."""
    roberts = assurjax.load_scene("roberts")
    bd = np.hypot(-0.12 + 0.18 * np.cos(2.0) - 0.12, 0.18 * np.sin(2.0))  # B = A + 0.18 (cos q, sin q), D = (0.12, 0)
    why = f": |B D| = {bd:.4g} m > 0.12 + 0.18 m (links link4, link3 too short)"
    with pytest.raises(assurjax.AssemblyError, match="group 'dyad43' \\(RRR\\) cannot assemble at q = 2") as info:
        static_reactions(roberts, 2.0)
    assert info.value.group == "dyad43"
    assert f"at q = 2{why}" in str(info.value)  # one configuration: no count
    # a batch counts its failures against its size: q = 2 and 2.1 fail, 0.5 closes
    with pytest.raises(assurjax.AssemblyError, match=r"at q = 2 \(2 of 3 configurations fail\): ") as info:
        assurjax.kinematics(roberts.mechanism, np.array([0.5, 2.0, 2.1]))
    assert why in str(info.value)


def test_a_request_for_too_many_states_is_refused_before_its_values_are_read():
    """3e8 states (a broadcast view: no memory) were scanned for NaN first, 5 s and 5 GB
    before the bound refused them; the bound comes first (a NaN view gives the bound's error)."""
    scene = assurjax.load_scene("slider_crank")
    many = np.broadcast_to(np.nan, (300_000_000,))
    with pytest.raises(assurjax.AssurjaxError, match="at most 1,000,000 states per call"):
        reactions(scene, (many, 0.0, 0.0))
    with pytest.raises(assurjax.AssurjaxError, match="at most 1,000,000 states per call"):
        assurjax.inverse_dynamics(scene, lambda t: t, many)


# ----------------------------------------------------------------------------- seed 003
# Loads of seed 003 (N, N m). Each force's line of action is fixed by its direction and
# its arm about the point the seed takes moments about, on the side the seed's moment
# equations give (eq. 6: F2 counterclockwise about B; eq. 2: F3 clockwise about S3;
# eq. 8: F4 counterclockwise about G; eq. 4: F5 counterclockwise about S5); M3 and M4
# enter eqs. 2 and 8 as clockwise couples. See docs/kinetostatics.md.
SEED003_FORCES = {  # link: (force, reference point, +1 counterclockwise / -1 clockwise, arm h in m)
    "link2": ((10.0, 40.0), "B", 1, 0.139783),
    "link3": ((25.0, 30.0), "S3", -1, 0.323089),
    "link4": ((-30.0, -10.0), "G", 1, 0.132458),
    "link5": ((40.0, 0.0), "S5", 1, 0.146102),
}
SEED003_COUPLES = {"link3": -3.0, "link4": -2.0}
SEED003_F12 = np.array([-87.7031, -70.1672])
SEED003_F64 = np.array([38.7031, 10.1672])


def _intersection(p1, d1, p2, d2):
    s = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)
    return p1 + s[0] * d1


@pytest.fixture(scope="module")
def seed003():
    """The bundled class-IV scene with the seed's loads on points added on their lines of action."""
    import dataclasses
    import tomllib

    from assurjax.scene._load import scene_from_dict, scene_path

    base = SCENES["class4_seed003"]
    q0 = base.state["q0"]
    pose = assurjax.pose_at(base.mechanism, q0)
    p = {k: np.asarray(v) for k, v in pose.points.items()}
    ref = dict(p, S3=_intersection(p["B"], p["C"] - p["B"], p["G"], p["D"] - p["G"]),
               S5=_intersection(p["B"], p["E"] - p["B"], p["G"], p["F"] - p["G"]))
    data = tomllib.loads(scene_path("class4_seed003").read_text())
    origin = {"link2": "B", "link3": "C", "link4": "G", "link5": "E"}
    at = {}
    for link, (force, about, sign, arm) in SEED003_FORCES.items():
        u = np.asarray(force) / np.linalg.norm(force)
        at[link] = ref[about] - sign * arm * np.array([-u[1], u[0]])  # moment about `about`: sign * arm * |F|
        angle = float(pose.angles[link])
        c, s = np.cos(angle), np.sin(angle)
        local = np.array([[c, s], [-s, c]]) @ (at[link] - p[origin[link]])
        data["links"][link]["points"]["P_" + link] = [float(local[0]), float(local[1])]
    scene = scene_from_dict(data, source="class4_seed003_loaded")
    loads = tuple(assurjax.PointForce("P_" + link, f, link=link) for link, (f, *_) in SEED003_FORCES.items())
    loads += tuple(assurjax.Couple(link, m) for link, m in SEED003_COUPLES.items())
    scene = dataclasses.replace(scene, loads=loads)
    rng = np.random.default_rng(3)
    state = (q0 + np.r_[0.0, rng.uniform(-0.2, 0.2, 2)], np.r_[0.0, rng.normal(size=2)], np.r_[0.0, rng.normal(size=2)], np.zeros(3))
    _, found, _ = evaluate(scene, state, ("modular", "dense", "by_moments"), reduction=False)
    return scene, ref, at, found


@pytest.mark.parametrize("variant", ["modular", "by_moments"])
def test_class4_special_points_agree_with_the_12x12_solve(seed003, variant):
    _, _, _, found = seed003
    special, dense = found[variant], found["dense"]
    assert np.all(np.asarray(special.ok))
    for joint in ("A", "B", "G", "C", "D", "E", "F"):
        np.testing.assert_allclose(special[joint], dense[joint], rtol=0, atol=1e-10, err_msg=joint)
    np.testing.assert_allclose(special.driving, dense.driving, atol=1e-10)


def test_seed003_group_statics_and_the_papers_numbers(seed003):
    """At the seed's configuration, at rest: the group as a whole is in equilibrium
    with F12 (at B, on link 2 by link 1) and F64 (at G, on link 4 by the frame).
    The paper's own F12 + F64 + F2 + F3 + F4 + F5 is (-4, 0) N, not zero: its
    numbers cannot both hold for the stated loads, whatever the geometry."""
    scene, ref, at, found = seed003
    r = found["modular"]  # state 0: the seed's configuration, at rest
    f12, f64 = np.asarray(r["B"][0]), np.asarray(r["G"][0])
    applied = sum(np.asarray(f) for f, *_ in SEED003_FORCES.values())
    np.testing.assert_allclose(f12 + f64 + applied, 0.0, atol=1e-10)
    cross2 = lambda a, b: a[0] * b[1] - a[1] * b[0]  # noqa: E731
    moment_about_g = cross2(ref["B"] - ref["G"], f12) + sum(cross2(at[k] - ref["G"], f) for k, (f, *_) in SEED003_FORCES.items())
    assert abs(moment_about_g + sum(SEED003_COUPLES.values())) < 1e-10
    np.testing.assert_allclose(SEED003_F12 + SEED003_F64 + applied, [-4.0, 0.0], atol=1e-9)
    # the reconstruction carries the seed's special-point distances to within 2 mm (Table I)
    mm = lambda a, b: 1000 * np.linalg.norm(ref[a] - ref[b])  # noqa: E731
    for (a, b), value in {("B", "S3"): 248.060, ("D", "S3"): 481.985, ("F", "S5"): 436.292, ("E", "S5"): 155.112}.items():
        assert abs(mm(a, b) - value) < 2.0


def test_scene_asking_for_an_unknown_reaction_is_a_scene_error():
    import tomllib

    from assurjax.scene._load import scene_from_dict, scene_path

    data = tomllib.loads(scene_path("watt_sixbar").read_text())
    data["outputs"]["reactions"] = ["O2", "Z"]
    with pytest.raises(assurjax.SceneError, match=r"\[outputs\], field 'reactions': unknown joint 'Z'"):
        scene_from_dict(data, source="watt.toml")


def test_reactions_are_differentiable_in_the_design():
    """d(reaction)/d(mass of the coupler) by jax.grad against central differences."""
    import equinox as eqx

    scene = SCENES["watt_sixbar"]

    @jax.jit
    def reaction_e(mass):
        mech = eqx.tree_at(lambda m: m.links["link3"].mass, scene.mechanism, mass)
        kin = _kinematics_single(mech, jnp.asarray(0.5), jnp.asarray(1.0), jnp.asarray(0.5), None, 2)
        forces, _, driving, _ = from_kinematics(scene.replace_mechanism(mech), kin, 0.0)
        return forces["O2"][1] + forces["E"][0] + driving

    m, h = jnp.asarray(1.5), 1e-5
    fd = (reaction_e(m + h) - reaction_e(m - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(reaction_e)(m), fd, rtol=1e-7)
