"""Iterative Assur groups (class III triad, class IV group): closure, derivatives,
branch continuity, failure reporting, and an independent solution of the loop equations.

The references here are written from the definitions only, with numpy/scipy:

- the raw scene files are read with ``tomllib`` (link lengths and local points);
- the loop equations are written in global joint coordinates (lengths, and for the
  ternary links the dot and cross products of their two sides, which fix a rigid
  triangle including its orientation) and solved with ``scipy.optimize.fsolve``,
  tracked along the crank revolution from the scene's guess in small steps;
- rigidity: every point of every link, placed from the link's centre of mass and
  angle, coincides with the point the package reports (the revolute constraints);
- velocities, accelerations and design gradients against central finite differences.
"""

import tomllib
from importlib import resources

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import fsolve

import assurjax
from slow_cases import marked_slow

SCENES = ("triad_mechanism", "class4_seed003")
TOL = 1e-12  # closure residuals (m); links are 0.1 - 0.6 m long
Q_KIN = np.linspace(-3.0, 3.0, 7)  # one shape for every kinematics() call: one compile per scene


# ----------------------------------------------------------------------------- helpers
def raw_scene(name):
    return tomllib.loads((resources.files("assurjax.scenes") / f"{name}.toml").read_text())


def rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


class LoopEquations:
    """The loop equations of a scene's iterative group in global joint coordinates
    (numpy), with the crank angle q as parameter. Unknowns: the internal joints."""

    def __init__(self, name):
        raw = raw_scene(name)
        self.ground = {k: np.array(v) for k, v in raw["ground"].items()}
        self.links = {k: {p: np.array(v) for p, v in t["points"].items()} for k, t in raw["links"].items()}
        driver, group = raw["formation"]
        self.crank, self.pivot = driver["link"], driver["pivot"]
        self.kind, self.group_links, self.joints = group["group"], group["links"], group["joints"]
        self.guess = {p: np.array(v) for p, v in group["guess"].items()}
        self.q0 = raw["state"]["q0"]
        self.internal = self.joints[3:] if self.kind == "triad" else self.joints[2:]

    def crank_point(self, name, q):
        local = self.links[self.crank]
        return self.ground[self.pivot] + rot(q) @ (local[name] - local[self.pivot])

    def external(self, name, q):
        return self.ground[name] if name in self.ground else self.crank_point(name, q)

    def length(self, link, a, b):
        d = self.links[link][a] - self.links[link][b]
        return d @ d

    def rigid_triangle(self, link, o, a, b, po, pa, pb):
        """|oa|^2, oa.ob and oa x ob of the link, in global minus local form."""
        pts = self.links[link]
        la, lb = pts[a] - pts[o], pts[b] - pts[o]
        ga, gb = pa - po, pb - po
        return [ga @ ga - la @ la, ga @ gb - la @ lb, cross(ga, gb) - cross(la, lb)]

    def residual(self, x, q):
        pts = dict(zip(self.internal, x.reshape(-1, 2)))
        if self.kind == "triad":
            t, l1, l2, l3 = self.group_links
            e1, e2, e3, p1, p2, p3 = self.joints
            out = self.rigid_triangle(t, p1, p2, p3, pts[p1], pts[p2], pts[p3])
            for link, e, p in ((l1, e1, p1), (l2, e2, p2), (l3, e3, p3)):
                d = pts[p] - self.external(e, q)
                out.append(d @ d - self.length(link, e, p))
        else:
            l2, l3, l4, l5 = self.group_links
            b, g, c, d, e, f = self.joints
            out = self.rigid_triangle(l2, b, e, c, self.external(b, q), pts[e], pts[c])
            out += self.rigid_triangle(l4, g, d, f, self.external(g, q), pts[d], pts[f])
            for link, u, v in ((l3, c, d), (l5, e, f)):
                w = pts[u] - pts[v]
                out.append(w @ w - self.length(link, u, v))
        return np.array(out)

    def track(self, qs):
        """Solutions at the increasing angles ``qs`` (which contain q0), each step started
        from the previous solution extrapolated linearly: the branch of the guess."""
        qs = np.asarray(qs)
        i0 = int(np.argmin(abs(qs - self.q0)))
        assert abs(qs[i0] - self.q0) < 1e-12
        start = np.concatenate([self.guess[p] for p in self.internal])
        out = np.zeros((len(qs), start.size))
        out[i0] = fsolve(self.residual, start, args=(qs[i0],), xtol=1e-12)
        for direction in (1, -1):
            prev = prev2 = out[i0]
            for i in range(i0 + direction, len(qs) if direction > 0 else -1, direction):
                guess = 2 * prev - prev2 if prev2 is not prev else prev
                out[i] = fsolve(self.residual, guess, args=(qs[i],), xtol=1e-12)
                assert np.max(abs(self.residual(out[i], qs[i]))) < 1e-12
                prev2, prev = prev, out[i]
        return {p: out[:, 2 * k : 2 * k + 2] for k, p in enumerate(self.internal)}


def link_point_errors(mech, pose):
    """Largest distance between a link's point placed rigidly from the link's centre of
    mass and angle (numpy) and the package's global point: zero when every link is rigid
    and every shared point (revolute) coincides."""
    worst = 0.0
    for name, link in mech.links.items():
        angle = np.asarray(pose.angles[name])
        com = np.asarray(pose.coms[name])
        for p, local in link.points.items():
            arm = np.asarray(local) - np.asarray(link.com)
            placed = com + np.stack([np.cos(angle) * arm[0] - np.sin(angle) * arm[1], np.sin(angle) * arm[0] + np.cos(angle) * arm[1]], -1)
            worst = max(worst, float(np.max(np.abs(placed - np.asarray(pose.points[p])))))
    return worst


def with_leaf(mech, where, value):
    return eqx.tree_at(where, mech, jnp.asarray(value))


# ----------------------------------------------------------------------------- fixtures
CHUNK = 192  # every batch of q is cut into chunks of this size: one compile per mechanism structure


@pytest.fixture(scope="module")
def batch_positions():
    """positions() over a 1-D array of q; the mechanism is an argument and the batch is
    padded and chunked to a fixed size, so there is one compile per mechanism structure."""
    chunk = eqx.filter_jit(jax.vmap(assurjax.positions, in_axes=(None, 0)))

    def run(mech, qs):
        qs = np.asarray(qs, dtype=float)
        padded = np.concatenate([qs, np.full(-len(qs) % CHUNK, qs[0])])
        parts = [chunk(mech, jnp.asarray(padded[i : i + CHUNK])) for i in range(0, len(padded), CHUNK)]
        return jax.tree.map(lambda *xs: np.concatenate(xs)[: len(qs)], *parts)

    return run


# the triad's checks in the slow suite (~18 s), but for a failed member of a batch below (the default
# suite keeps to 10 min): class IV's run the same Newton solve and continuation
@pytest.fixture(scope="module", params=marked_slow(SCENES, ("triad_mechanism",)))
def scene(request):
    return assurjax.load_scene(request.param)


# ----------------------------------------------------------------------------- tests
def test_gruebler_and_kinds(scene):
    """Both groups fit the Gruebler count from shared point names (4 links, 6 revolutes
    each; with the crank: 5 moving links, 7 revolutes) and are registered kinds."""
    from assurjax._mechanism import gruebler

    mech = scene.mechanism
    assert gruebler(mech.ground, mech.links, mech.groups) == (1, 5, 7)
    kind = mech.groups[1].kind
    assert assurjax.groups.KINDS[kind] is type(mech.groups[1])


def test_closure_over_random_inputs(scene, batch_positions, rng):
    """Random crank angles, on the bundled geometry and on randomly perturbed ones
    (every local point and ground pivot moved by up to 2 mm): links rigid, joints closed."""
    mech = scene.mechanism
    qs = jnp.asarray(rng.uniform(-np.pi, np.pi, 16))
    designs = [mech]
    for _ in range(3):
        leaves, tree = jax.tree.flatten(mech)
        perturbed = [leaf + rng.uniform(-0.002, 0.002, np.shape(leaf)) if np.ndim(leaf) == 1 and np.shape(leaf) == (2,) else leaf for leaf in leaves]
        designs.append(jax.tree.unflatten(tree, perturbed))
    for design in designs:
        pose = batch_positions(design, qs)
        assert np.asarray(pose.ok).all()
        for i in range(len(qs)):
            single = jax.tree.map(lambda x: x[i], pose)
            assert link_point_errors(design, single) < TOL


def test_independent_loop_equations_along_revolution(scene, batch_positions):
    """fsolve on the raw loop equations, tracked from the scene's guess over the whole
    revolution, against positions() (continuation from the reference per q) and
    positions_tracked() (one sweep, Newton from the secant-predicted angles): the same branch everywhere, to 1e-10 m."""
    ref = LoopEquations(scene.name)
    qs = ref.q0 + np.linspace(-np.pi, np.pi, 181)
    expected = ref.track(qs)
    pose = batch_positions(scene.mechanism, jnp.asarray(qs))
    swept = assurjax.positions_tracked(scene.mechanism, jnp.asarray(qs))
    assert np.asarray(pose.ok).all() and np.asarray(swept.ok).all()
    for p, xy in expected.items():
        np.testing.assert_allclose(np.asarray(pose.points[p]), xy, atol=1e-10)
        np.testing.assert_allclose(np.asarray(swept.points[p]), xy, atol=1e-10)


def test_branch_continuity_full_revolution(scene, batch_positions):
    """No jumps over a dense revolution: every step of every joint is below a Lipschitz
    bound, 2 x (largest speed of that joint from central differences) x dq, and the
    motion is periodic (q and q + 2 pi give the same pose)."""
    n = 1441
    qs = np.linspace(-np.pi, np.pi, n)
    h = 1e-6
    pose, plus, minus = (batch_positions(scene.mechanism, jnp.asarray(qs + d)) for d in (0.0, h, -h))
    assert np.asarray(pose.ok).all()
    dq = qs[1] - qs[0]
    for p in pose.points:
        x = np.asarray(pose.points[p])
        speed = np.linalg.norm(np.asarray(plus.points[p]) - np.asarray(minus.points[p]), axis=-1) / (2 * h)
        steps = np.linalg.norm(np.diff(x, axis=0), axis=-1)
        assert steps.max() <= 2.0 * speed.max() * dq + 1e-12, p
        np.testing.assert_allclose(x[0], x[-1], atol=1e-10)


@pytest.fixture(scope="module")
def kinematics_result(scene):
    return assurjax.kinematics(scene.mechanism, jnp.asarray(Q_KIN))


def test_velocities_and_accelerations_vs_finite_differences(scene, kinematics_result, batch_positions):
    """kinematics() (nested jvp through the implicit Newton solve) against central
    differences of positions: dx/dq to 1e-8, d2x/dq2 to 1e-6 (m per rad, rad per rad)."""
    kin = kinematics_result
    h = 1e-4
    x0, xp, xm = (batch_positions(scene.mechanism, jnp.asarray(Q_KIN + d)) for d in (0.0, h, -h))
    for p in kin.points:
        fd1 = (np.asarray(xp.points[p]) - np.asarray(xm.points[p])) / (2 * h)
        fd2 = (np.asarray(xp.points[p]) - 2 * np.asarray(x0.points[p]) + np.asarray(xm.points[p])) / h**2
        np.testing.assert_allclose(np.asarray(kin.velocities[p]), fd1, atol=1e-8)
        np.testing.assert_allclose(np.asarray(kin.accelerations[p]), fd2, atol=1e-6)
    for link in kin.angles:
        unwrap = lambda a: np.unwrap(np.stack([np.asarray(xm.angles[link]), np.asarray(x0.angles[link]), np.asarray(xp.angles[link])]), axis=0)  # noqa: E731
        am, a0, ap = unwrap(None)
        np.testing.assert_allclose(np.asarray(kin.angular_velocities[link]), (ap - am) / (2 * h), atol=1e-8)
        np.testing.assert_allclose(np.asarray(kin.angular_accelerations[link]), (ap - 2 * a0 + am) / h**2, atol=1e-6)


# Design variables per scene: (description, where-function into the mechanism, index in that leaf)
DESIGN = {
    "triad_mechanism": ("X", [
        ("ground O5 x", lambda m: m.ground["O5"], 0),
        ("L2 length", lambda m: m.links["L2"].points["P2"], 0),
        ("T: P3 y", lambda m: m.links["T"].points["P3"], 1),
        ("crank length", lambda m: m.links["crank"].points["A"], 0),
    ]),
    "class4_seed003": ("D", [
        ("link3 length", lambda m: m.links["link3"].points["D"], 0),
        ("link4: F y", lambda m: m.links["link4"].points["F"], 1),
        ("ground G x", lambda m: m.ground["G"], 0),
        ("link2: C y", lambda m: m.links["link2"].points["C"], 1),
    ]),
}


def test_design_gradients_vs_finite_differences(scene, batch_positions):
    """eqx.filter_grad of a point coordinate and of its kinematic coefficient (reverse mode
    over a jvp, through the implicit solve) w.r.t. the link dimensions, against central
    differences of the same quantities (positions, and kinematics() velocities)."""
    point, variables = DESIGN[scene.name]
    i = 4  # q = Q_KIN[4] = 1.0 rad

    def objectives(mech):
        coords = lambda q: assurjax.positions(mech, q, points=[point]).points[point]  # noqa: E731
        x, dx = jax.jvp(coords, (jnp.asarray(Q_KIN[i]),), (jnp.asarray(1.0),))
        return jnp.stack([x[0] + 0.5 * x[1], dx[0] - dx[1]])

    def measured(mech):  # the same two quantities from the already compiled functions
        x = batch_positions(mech, Q_KIN).points[point][i]
        dx = np.asarray(assurjax.kinematics(mech, jnp.asarray(Q_KIN)).velocities[point])[i]
        return np.array([x[0] + 0.5 * x[1], dx[0] - dx[1]])

    weighted_grad = eqx.filter_jit(eqx.filter_grad(lambda m, w: w @ objectives(m)))  # one compile for both
    grads = [weighted_grad(scene.mechanism, jnp.eye(2)[k]) for k in range(2)]
    h = 1e-6
    for label, where, index in variables:
        leaf = np.asarray(where(scene.mechanism))
        step = np.zeros_like(leaf)
        step[index] = h
        fd = (measured(with_leaf(scene.mechanism, where, leaf + step)) - measured(with_leaf(scene.mechanism, where, leaf - step))) / (2 * h)
        for k in range(2):
            got = float(np.asarray(where(grads[k]))[index])
            assert got == pytest.approx(fd[k], rel=1e-6, abs=1e-8), (label, k)


CANNOT_ASSEMBLE = {
    "triad_mechanism": ("triad", lambda m: m.links["L2"].points["P2"], 3.0),
    "class4_seed003": ("class4", lambda m: m.links["link5"].points["F"], 5.0),
}


def test_cannot_assemble_is_reported(scene, batch_positions):
    """A binary link made far too long: ok False for that group, finite values, and
    kinematics() raises AssemblyError naming the group."""
    group, where, factor = CANNOT_ASSEMBLE[scene.name]
    broken = with_leaf(scene.mechanism, where, factor * np.asarray(where(scene.mechanism)))
    pose = batch_positions(broken, jnp.asarray(Q_KIN))
    ok = np.asarray(pose.ok)
    assert ok[:, 0].all() and not ok[:, 1].any()
    for leaf in jax.tree.leaves(pose):
        assert np.isfinite(np.asarray(leaf)).all()
    with pytest.raises(assurjax.AssemblyError, match=group) as info:
        assurjax.kinematics(broken, jnp.asarray(Q_KIN))
    assert info.value.group == group


def limited_triad():
    """The triad on a crank of 0.25 m: a limit position at q* = 1.4309 rad."""
    raw = raw_scene("triad_mechanism")
    raw["links"]["crank"]["points"]["A"] = [0.25, 0.0]
    return assurjax.scene_from_dict(raw).mechanism


def test_a_tracked_sweep_ends_with_the_branch():
    """A triad on a crank of 0.25 m has a limit position at q* = 1.4309 rad. Past it the
    tracked sweep's Newton solves landed on another assembly (P2 jumping 0.22 m between
    samples 0.29 degrees apart, the median move 3 mm) and said ok; now the samples past it
    are flagged, where the position analysis on its own (continued from the guess) finds no
    assembly either, and those before it move continuously and close their loops."""
    mechanism = limited_triad()
    qs = jnp.linspace(1.3, 1.6, 61)
    tracked = assurjax.positions_tracked(mechanism, qs)
    alone = jax.vmap(lambda q: assurjax.positions(mechanism, q))(qs)
    ok = np.asarray(tracked.ok).all(-1)
    np.testing.assert_array_equal(ok, np.asarray(alone.ok).all(-1))
    assert 10 < np.count_nonzero(ok) < qs.size and not ok[np.argmin(ok):].any()  # from the limit on
    moves = np.linalg.norm(np.diff(np.asarray(tracked.points["P2"])[ok], axis=0), axis=-1)
    assert moves.max() < 10 * np.median(moves)
    ref = LoopEquations("triad_mechanism")
    ref.links["crank"]["A"] = np.array([0.25, 0.0])
    for i in np.flatnonzero(ok):  # the loop equations, written apart, hold where it is ok
        x = np.concatenate([np.asarray(tracked.points[p])[i] for p in ref.internal])
        assert np.max(np.abs(ref.residual(x, float(qs[i])))) < TOL


@pytest.mark.slow  # ~8 s of compiles (two more sweep lengths); the default suite keeps the sweep past the limit above
def test_a_tracked_sweep_closing_in_on_the_limit_or_starting_past_it():
    """The same triad: steps that shrink towards the limit (0.105, 0.0105, then 0.0002 rad,
    q* - 1.4e-4 left) stay on the position analysis' own branch, every sample ok; a sweep
    that starts where the branch does not exist has none to track (it went on another
    assembly, 2.3 rad away from the position analysis' own where both said ok)."""
    mechanism = limited_triad()
    near_limit = jnp.asarray([1.0, 1.105, 1.21, 1.315, 1.42, 1.4305])
    shrinking = assurjax.positions_tracked(mechanism, near_limit)
    assert np.asarray(shrinking.ok).all()
    alone = jax.vmap(lambda q: assurjax.positions(mechanism, q))(near_limit)
    np.testing.assert_allclose(np.asarray(shrinking.angles["T"]), np.asarray(alone.angles["T"]), rtol=0, atol=1e-12)
    from_beyond = assurjax.positions_tracked(mechanism, jnp.arange(2.0, 0.0, -np.radians(5)))
    assert not np.asarray(from_beyond.ok)[:, 1].any()


@pytest.mark.slow  # an eight-bar's positions and tracked sweep (~10 s of compiles)
def test_a_crank_that_cannot_turn_fully_is_followed_the_long_way_round():
    """An eight-bar drawn with its crank at q0 = pi/4 (a triad, then a dyad) assembles up to
    q ~ 4.0806, more than pi past the drawing. The continuation from the drawing went the
    short way (q - q0 wrapped to (-pi, pi]), backwards through the range where it does not
    assemble: 'cannot assemble' past q0 + pi, and simulate stopped there with a lock-up that
    is not one. Now it goes the other way round where the short way fails: the same pose as
    a tracked sweep from the drawing in small steps, and not ok past the real limit."""
    joints = dict(O2=(0, 0), A=(0.1, 0.1), P1=(0.35, 0.4), P2=(0.6, 0.45), P3=(0.5, 0.7), O4=(0.7, 0.0),
                  O6=(0.2, 0.9), C=(0.8, 0.3), D=(1.0, 0.5), O8=(1.1, 0.1))
    links = {"crank": ["O2", "A"], "T": ["P1", "P2", "P3"], "arm1": ["A", "P1"], "arm2": ["O4", "P2", "C"],
             "arm3": ["O6", "P3"], "l7": ["C", "D"], "l8": ["D", "O8"]}
    sketch = assurjax.Sketch(joints=joints, links={k: {"joints": v, "mass": 0.3, "inertia": 0.002} for k, v in links.items()},
                             ground=["O2", "O4", "O6", "O8"], driver="crank")
    mechanism, q0 = sketch.mechanism(), np.pi / 4
    qs = jnp.asarray(q0 + np.array([3.10, 3.15, 3.25, 3.30]))
    alone = jax.vmap(lambda q: assurjax.positions(mechanism, q))(qs)
    assert np.asarray(alone.ok).all(-1).tolist() == [True, True, True, False]  # the limit at ~4.0806
    tracked = assurjax.positions_tracked(mechanism, jnp.linspace(q0, float(qs[2]), 400))
    assert np.asarray(tracked.ok).all()
    for name in ("T", "arm2", "l8"):
        np.testing.assert_allclose(float(alone.angles[name][2]), float(tracked.angles[name][-1]), rtol=0, atol=1e-10)


# both in the slow suite (~10 s each): test_a_guess_drawn_at_a_dead_centre_is_no_error keeps the
# failed-solve flag (Newton's 0/0 start, no error raised from the program) checked by default
@pytest.mark.parametrize("name", marked_slow(SCENES, ("class4_seed003", "triad_mechanism")))
def test_a_failed_member_does_not_stop_a_batch(name):
    """A NaN crank angle in a vmapped batch (or a Newton start at a dead centre, whose first
    step is 0/0) stopped the whole batch with an error raised by lineax from inside the
    program (the implicit derivative's solve at the failed root); now that member is not ok,
    and the others are those of single calls, velocities included."""
    scene = assurjax.load_scene(name)
    qs = jnp.array([0.1, jnp.nan, 0.4])
    kin = jax.jit(jax.vmap(lambda q: assurjax.kinematics(scene.mechanism, q)))(qs)
    assert np.asarray(kin.ok).all(-1).tolist() == [True, False, True]
    for i in (0, 2):
        single = assurjax.kinematics(scene.mechanism, qs[i])
        for p in scene.mechanism.groups[1].internal_points():
            np.testing.assert_allclose(np.asarray(kin.velocities[p])[i], np.asarray(single.velocities[p]), rtol=0, atol=1e-14)


def test_a_guess_drawn_at_a_dead_centre_is_no_error():
    """A triad drawn with its three binary links parallel (a dead centre: it assembles at
    q = 0 only, where no velocity exists, the three pins' conditions being inconsistent):
    Newton's first step from it is 0/0. It was an error raised from inside the program at
    every q; now a flag: not ok there (as a velocity of 0 beside ok True would be wrong), no
    error elsewhere, and the drawing is where the solve stays."""
    from assurjax.groups import Crank, Link, Triad

    ground = {"O2": [-0.5, -0.5], "O5": [1.0, 0.0], "O6": [2.0, 0.0]}
    links = {"crank": Link({"O2": [0.0, 0.0], "A": [0.5, 0.0]}, mass=1.0),
             "T": Link({"P1": [0.0, 1.0], "P2": [1.0, 1.0], "P3": [2.0, 1.5]}, mass=1.0),
             "L1": Link({"A": [0.0, -0.5], "P1": [0.0, 1.0]}, mass=1.0),
             "L2": Link({"O5": [1.0, 0.0], "P2": [1.0, 1.0]}, mass=1.0),
             "L3": Link({"O6": [2.0, 0.0], "P3": [2.0, 1.5]}, mass=1.0)}
    guess = {"P1": jnp.array([0.0, 1.0]), "P2": jnp.array([1.0, 1.0]), "P3": jnp.array([2.0, 1.5])}
    mechanism = assurjax.Mechanism(ground, links, [Crank("crank", ("crank",), "O2"),
                                                   Triad("triad", ("T", "L1", "L2", "L3"), ("A", "O5", "O6", "P1", "P2", "P3"),
                                                         guess, guess_q=0.0)])
    pose = assurjax.positions(mechanism, 0.0, near={"L1": 0.0, "T": 0.0})
    assert np.asarray(pose.ok).tolist() == [True, False]
    for p, xy in guess.items():
        np.testing.assert_allclose(np.asarray(pose.points[p]), np.asarray(xy), rtol=0, atol=1e-12)
    kin = assurjax.kinematics(mechanism, jnp.array([0.0, -0.1]), check=False)
    assert not np.asarray(kin.ok)[:, 1].any()
    for leaf in jax.tree.leaves(kin):
        assert np.isfinite(np.asarray(leaf)).all()


# Another assembly of each group at q0 (found by multi-start fsolve on the loop equations),
# rounded to 1 cm: a guess, not an expected value.
OTHER_BRANCH = {
    "triad_mechanism": {"P1": [0.32, 0.19], "P2": [0.09, 0.47], "P3": [0.52, 0.47]},
    "class4_seed003": {"C": [-0.13, 0.01], "D": [0.47, 0.11], "E": [0.12, 0.44], "F": [0.33, 0.23]},
}


def test_guess_selects_the_branch(scene, batch_positions):
    """A guess near another assembly gives that assembly at q0 and follows it nearby
    (against fsolve tracked from the same guess), distinct from the bundled branch."""
    ref = LoopEquations(scene.name)
    ref.guess = {p: np.array(v) for p, v in OTHER_BRANCH[scene.name].items()}
    group = scene.mechanism.groups[1]
    other = eqx.tree_at(lambda m: m.groups[1].guess, scene.mechanism, {p: jnp.asarray(v) for p, v in ref.guess.items()})
    qs = ref.q0 + np.linspace(-0.2, 0.2, 5)
    expected = ref.track(qs)
    pose = batch_positions(other, jnp.asarray(qs))
    bundled = batch_positions(scene.mechanism, jnp.asarray(qs))
    assert np.asarray(pose.ok).all()
    for p, xy in expected.items():
        np.testing.assert_allclose(np.asarray(pose.points[p]), xy, atol=1e-10)
    assert max(np.abs(np.asarray(pose.points[p]) - np.asarray(bundled.points[p])).max() for p in group.internal_points()) > 0.05


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda t: t.replace('guess = { P1 = [0.32, 0.19], P2 = [0.59, 0.43], P3 = [0.61, 0.0] }', 'guess = { P1 = [0.32, 0.19], P2 = [0.59, 0.43] }'), "guess"),
        (lambda t: t.replace('guess = { P1 = [0.32, 0.19], P2 = [0.59, 0.43], P3 = [0.61, 0.0] }', 'guess = { P1 = [0.32, 0.19], P2 = [0.59, 0.43], P3 = "here" }'), "guess"),
        (lambda t: t.replace('joints = ["A", "O5", "O6", "P1", "P2", "P3"]', 'joints = ["A", "O5", "P1", "P2", "P3"]'), "joints"),
        (lambda t: t.replace('name = "triad"\n', 'name = "triad"\nsubsteps = 0\n'), "substeps"),
    ],
)
def test_scene_errors_name_the_field(write_scene, edit, field):
    text = (resources.files("assurjax.scenes") / "triad_mechanism.toml").read_text()
    edited = edit(text)
    assert edited != text
    with pytest.raises(assurjax.SceneError, match=field) as info:
        assurjax.load_scene(write_scene(edited))
    assert "triad" in str(info.value)


@pytest.mark.slow
def test_hundred_thousand_crank_angles_in_one_call(batch_positions):
    """positions() of 100 000 crank angles in one vmapped call: all assembled, and a
    sample agrees with the independent loop equations tracked from the scene's guess
    (fsolve along a dense path through q0 that contains the sampled angles: the same
    branch, not just some root)."""
    scene = assurjax.load_scene("triad_mechanism")
    qs = np.linspace(-np.pi, np.pi, 100_000)
    pose = batch_positions(scene.mechanism, jnp.asarray(qs))
    assert np.asarray(pose.ok).all()
    ref = LoopEquations(scene.name)
    idx = np.arange(0, len(qs), 5000)
    path = np.union1d(ref.q0 + np.linspace(-2 * np.pi, 2 * np.pi, 361), qs[idx])  # covers [-pi, pi] from q0
    expected = ref.track(path)
    at = np.searchsorted(path, qs[idx])
    for p in ref.internal:
        np.testing.assert_allclose(np.asarray(pose.points[p][idx]), expected[p][at], atol=1e-10, err_msg=p)


def test_seed003_special_points_match_the_seed():
    """The reconstructed class-IV scene against seed 003's Table I: link dimensions exact,
    special-point distances within the 2 mm misfit of the reconstruction (the seed's data
    are not exactly consistent; see the scene file)."""
    scene = assurjax.load_scene("class4_seed003")
    pose = assurjax.pose_at(scene.mechanism, scene.state["q0"])
    pts = {k: np.asarray(v) for k, v in pose.points.items()}
    dist = lambda a, b: 1000 * np.linalg.norm(a - b)  # noqa: E731  (mm)
    for (a, b), mm in {("A", "G"): 275, ("A", "B"): 100, ("B", "E"): 500, ("E", "F"): 300, ("G", "D"): 300, ("F", "G"): 150, ("F", "D"): 180}.items():
        assert dist(pts[a], pts[b]) == pytest.approx(mm, abs=1e-6)
    special = {k: np.asarray(v) for k, v in scene.mechanism.groups[1].special_points(pose.points).items()}
    # the seed's definitions, written here: S3 on lines BC and GD, S5 on lines BE and GF
    for s, (p, q) in {"S3": ("B", "C"), "S5": ("B", "E")}.items():
        assert abs(cross(pts[q] - pts[p], special[s] - pts[p])) < 1e-12
    assert abs(cross(pts["D"] - pts["G"], special["S3"] - pts["G"])) < 1e-12
    assert abs(cross(pts["F"] - pts["G"], special["S5"] - pts["G"])) < 1e-12
    for (s, p), mm in {("S3", "B"): 248.060, ("S3", "D"): 481.985, ("S5", "F"): 436.292, ("S5", "E"): 155.112}.items():
        assert dist(special[s], pts[p]) == pytest.approx(mm, abs=2.0)


# equinox warns that a JAX array becomes a static field before the group refuses it
@pytest.mark.filterwarnings("ignore:A JAX array is being set as static")
def test_an_iterative_group_built_in_python_checks_its_guess(scene):
    """A guess point of 3 coordinates failed deep in JAX, a scalar was broadcast to (x, x),
    a JAX array as guess_q was an 'unhashable type' error, NaN ran."""
    group = scene.mechanism.groups[1]
    first = group.internal_points()[0]
    for guess, guess_q, message in (({**group.guess, first: jnp.zeros(3)}, group.guess_q, "must be a 2-vector"),
                                    ({**group.guess, first: jnp.asarray(0.3)}, group.guess_q, "must be a 2-vector"),
                                    (group.guess, jnp.asarray(0.1), "guess_q must be a plain number"),
                                    (group.guess, float("nan"), "guess_q must be finite")):
        with pytest.raises(assurjax.MechanismError, match=message):
            type(group)(group.name, group.links, group.joints, guess, guess_q=guess_q)


def test_a_drawing_far_away_or_singular_is_built_as_drawn():
    """The bundled triad drawn 1000 m from the origin said 'cannot assemble' at every q but the
    drawn one (Newton's steps never got below 100 eps where the angles carry 1e-13); a triad
    drawn with its three arms aimed at one point (a singular configuration, an exact root)
    was built 0.76 m off its drawing on another assembly, said ok. Now the far one assembles
    where the near one does, the same pose moved, and the singular one is not ok there (no
    velocity exists there; the solve from the drawing stays on it)."""
    mech = assurjax.load_scene("triad_mechanism").mechanism
    drawn = assurjax.positions(mech, 0.3).points
    links = {name: list(link.points) for name, link in mech.links.items()}
    qs = (0.3, 0.4, 0.5, 0.8)
    for offset in (0.0, 1000.0):
        joints = {k: (float(v[0]) + offset, float(v[1]) + offset) for k, v in drawn.items()}
        moved = assurjax.Sketch(joints, links, ground=list(mech.ground), driver="crank", q0=0.3).mechanism()
        for q in qs:
            pose = assurjax.positions(moved, q)
            assert np.asarray(pose.ok).all(), (offset, q)
            np.testing.assert_allclose(np.asarray(pose.points["P2"]) - offset, np.asarray(assurjax.positions(mech, q).points["P2"]),
                                       rtol=0, atol=1e-9)
    aim = np.array([0.5, 2.0])  # the three 0.4 m arms point at it
    inner = {"P1": np.array([0.2, 0.5]), "P2": np.array([0.7, 0.6]), "P3": np.array([0.5, 0.2])}
    outer = {k: p - 0.4 * (aim - p) / np.hypot(*(aim - p)) for k, p in inner.items()}
    joints = {"O2": (outer["P1"][0] - 0.1, outer["P1"][1]), "A": tuple(outer["P1"]), "O5": tuple(outer["P2"]),
              "O6": tuple(outer["P3"]), **{k: tuple(v) for k, v in inner.items()}}
    sketch = assurjax.Sketch(joints, {"crank": ["O2", "A"], "T": ["P1", "P2", "P3"], "L1": ["A", "P1"], "L2": ["O5", "P2"],
                                      "L3": ["O6", "P3"]}, ground=["O2", "O5", "O6"], driver="crank")
    pose = assurjax.positions(sketch.mechanism(), sketch.scene().state["q0"])
    assert not np.asarray(pose.ok)[1]
