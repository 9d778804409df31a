"""Drivers and class-II dyads: constraints, assembly modes, derivatives, branch continuity.

Small mechanisms are built in Python with random (seeded) geometry: random local
frames, random guide directions (not normalised) and offsets, chosen so that the
group always assembles. Every check is written here from the definitions of the
joints (rigid links, shared points, guide lines), never from package numbers:

- rigidity and revolutes: every point of every link, placed from that link's
  centre of mass and angle (cos/sin here, not the package's rotation vectors),
  coincides with the point the package reports;
- guides: the sliding point lies on its guide line at the declared offset and the
  slider's angle is the guide's angle;
- assembly modes: the sign each group's docstring promises;
- velocities and accelerations: central finite differences of positions.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax import Link, Mechanism, groups

TOL = 1e-12  # constraint residuals (m), lengths of order 1 m


# ----------------------------------------------------------------------------- helpers
def rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def heading(v):
    return np.arctan2(v[..., 1], v[..., 0])


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def dot(a, b):
    return np.sum(a * b, axis=-1)


def perp(v):
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotate_batch(angles, v):
    """Rotate the constant 2-vector v by each angle."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    return np.concatenate([c * v[0] - s * v[1], s * v[0] + c * v[1]], axis=-1)


def link(rng, points: dict, *, extra: str | None = None):
    """A Link whose named points are given relative to a random local frame: each value
    is a global-looking layout that gets a random rotation and shift, so that no
    joint sits on the local origin or the local x axis."""
    R, t = rot(rng.uniform(-np.pi, np.pi)), rng.uniform(-0.2, 0.2, 2)
    pts = {k: R @ np.asarray(v, float) + t for k, v in points.items()}
    if extra:
        pts[extra] = R @ rng.uniform(-0.3, 0.3, 2) + t
    com = np.mean(list(pts.values()), axis=0) + rng.uniform(-0.05, 0.05, 2)
    return Link(points={k: jnp.asarray(v) for k, v in pts.items()}, com=jnp.asarray(com), mass=jnp.asarray(1.0), inertia=jnp.asarray(0.01))


def random_direction(rng):
    """A guide direction of random angle and random (non-unit) length."""
    return rng.uniform(0.3, 3.0) * np.array([np.cos(a := rng.uniform(-np.pi, np.pi)), np.sin(a)])


def crank_link(rng, r):
    return link(rng, {"O": [0.0, 0.0], "A": [r, 0.0]}, extra="Q")


def crank(rng):
    return groups.Crank("crank", ("crank",), "O")


# Each builder returns (mechanism, check) where check(mechanism, q, pose) asserts the group's
# own guide and assembly-mode conditions (pose holds numpy arrays with a batch axis).
def crank_rrr(rng, mode):
    while True:  # a Grashof crank-rocker with margin: assembles at every crank angle
        r, d, l1, l2 = rng.uniform(0.1, 0.2), *rng.uniform(0.5, 1.0, 3)
        if r + max(d, l1, l2) < d + l1 + l2 - max(d, l1, l2) - 0.1:
            break
    origin, b = rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)
    ground = {"O": origin, "G": origin + d * np.array([np.cos(b), np.sin(b)])}
    links = {
        "crank": crank_link(rng, r),
        "coupler": link(rng, {"A": [0, 0], "J": [l1, 0]}, extra="P"),
        "rocker": link(rng, {"G": [0, 0], "J": [l2, 0]}),
    }
    dyad = groups.RRR("dyad", ("coupler", "rocker"), ("A", "G", "J"), mode)

    def check(mech, q, pose):
        # RRR docstring: mode +1 puts J left of the directed line E1 -> E2 (A -> G)
        side = cross(pose.points["G"] - pose.points["A"], pose.points["J"] - pose.points["A"])
        assert np.all(mode * side > 0)

    return Mechanism(ground, links, [crank(rng), dyad], name="crank_rrr"), check


def crank_rrp(rng, mode, kind="RRP"):
    r, e, rod = rng.uniform(0.1, 0.2), rng.uniform(-0.05, 0.05), rng.uniform(0.4, 0.6)
    direction = random_direction(rng)
    ground = {"O": rng.uniform(-0.5, 0.5, 2)}
    links = {
        "crank": crank_link(rng, r),
        "rod": link(rng, {"A": [0, 0], "J": [rod, 0]}, extra="P"),
        "slider": link(rng, {"J": [0, 0]}, extra="S"),
    }
    if kind == "RRP":
        dyad = groups.RRP("dyad", ("rod", "slider"), ("A", "J"), "O", mode, jnp.asarray(direction), jnp.asarray(e))
    else:
        dyad = groups.PRR("dyad", ("slider", "rod"), ("J", "A"), "O", mode, jnp.asarray(direction), jnp.asarray(e))

    def check(mech, q, pose):
        u = unit(direction)
        rel = pose.points["J"] - pose.points["O"]
        np.testing.assert_allclose(cross(u, rel), e, atol=TOL)  # on the guide, offset to the left
        np.testing.assert_allclose(wrap(pose.angles["slider"] - heading(u)), 0.0, atol=TOL)
        # RRP docstring: mode +1 puts J ahead (along u) of the foot of the perpendicular from E = A
        foot_to_j = dot(pose.points["J"] - pose.points["A"], u)
        assert np.all(mode * foot_to_j > 0)

    return Mechanism(ground, links, [crank(rng), dyad], name=f"crank_{kind.lower()}"), check


def crank_prr_moving_guide(rng, mode):
    """PRR whose guide is carried by the (rotating) crank; the rod is pinned to the ground at E."""
    r, d, e, rod = rng.uniform(0.1, 0.2), rng.uniform(0.3, 0.4), rng.uniform(-0.05, 0.05), rng.uniform(0.75, 0.9)
    direction = random_direction(rng)  # in the crank's frame
    origin, b = rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)
    ground = {"O": origin, "E": origin + d * np.array([np.cos(b), np.sin(b)])}
    links = {
        "crank": crank_link(rng, r),
        "slider": link(rng, {"J": [0, 0]}, extra="S"),
        "rod": link(rng, {"E": [0, 0], "J": [rod, 0]}),
    }
    dyad = groups.PRR("dyad", ("slider", "rod"), ("J", "E"), "A", mode, jnp.asarray(direction), jnp.asarray(e))

    def check(mech, q, pose):
        u = rotate_batch(pose.angles["crank"], unit(direction))
        np.testing.assert_allclose(cross(u, pose.points["J"] - pose.points["A"]), e, atol=TOL)
        np.testing.assert_allclose(wrap(pose.angles["slider"] - heading(u)), 0.0, atol=TOL)
        assert np.all(mode * dot(pose.points["J"] - pose.points["E"], u) > 0)

    return Mechanism(ground, links, [crank(rng), dyad], name="crank_prr_moving"), check


def crank_rpr(rng, mode):
    """Oscillating guide link (Whitworth / crank-shaper): the crank pin carries a block
    that slides along a guide link pivoted on the ground at G."""
    r, d, e = rng.uniform(0.1, 0.2), rng.uniform(0.3, 0.5), rng.uniform(-0.05, 0.05)
    direction = random_direction(rng)  # in the guide link's frame
    origin, b = rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)
    ground = {"O": origin, "G": origin + d * np.array([np.cos(b), np.sin(b)])}
    links = {
        "crank": crank_link(rng, r),
        "block": link(rng, {"A": [0, 0]}, extra="S"),
        "guide": link(rng, {"G": [0, 0]}, extra="K"),
    }
    dyad = groups.RPR("dyad", ("block", "guide"), ("A", "G"), mode, jnp.asarray(direction), jnp.asarray(e))

    def check(mech, q, pose):
        u = rotate_batch(pose.angles["guide"], unit(direction))
        rel = pose.points["A"] - pose.points["G"]
        np.testing.assert_allclose(cross(u, rel), e, atol=TOL)  # E1 at signed distance `offset` (left +)
        np.testing.assert_allclose(wrap(pose.angles["block"] - heading(u)), 0.0, atol=TOL)
        assert np.all(mode * dot(rel, u) > 0)  # RPR docstring: mode +1, E1 ahead of E2

    return Mechanism(ground, links, [crank(rng), dyad], name="crank_rpr"), check


def slider_prp(rng, mode=None):
    """Slider driver + PRP: the driven slider carries one guide, the ground the other."""
    d0, d1, d2 = random_direction(rng), random_direction(rng), random_direction(rng)
    while abs(cross(unit(d1), unit(d2))) < 0.3:  # well away from parallel guides
        d2 = random_direction(rng)
    e1, e2 = rng.uniform(-0.05, 0.05, 2)
    ground = {"O": rng.uniform(-0.5, 0.5, 2), "G": rng.uniform(-0.5, 0.5, 2)}
    links = {
        "carriage": link(rng, {"B": [0, 0]}, extra="K"),
        "s1": link(rng, {"J": [0, 0]}, extra="S1"),
        "s2": link(rng, {"J": [0, 0]}, extra="S2"),
    }
    driver = groups.Slider("driver", ("carriage",), "B", "O", jnp.asarray(d0))
    dyad = groups.PRP("dyad", ("s1", "s2"), "J", ("B", "G"), jnp.asarray(np.stack([d1, d2])), jnp.asarray([e1, e2]))

    def check(mech, q, pose):
        # Slider docstring: B = O + q unit(direction), the carriage's x axis along the guide
        u0 = unit(d0)
        np.testing.assert_allclose(pose.points["B"], pose.points["O"] + q[:, None] * u0, atol=TOL)
        np.testing.assert_allclose(wrap(pose.angles["carriage"] - heading(u0)), 0.0, atol=TOL)
        u1 = rotate_batch(pose.angles["carriage"], unit(d1))
        u2 = unit(d2)
        np.testing.assert_allclose(cross(u1, pose.points["J"] - pose.points["B"]), e1, atol=TOL)
        np.testing.assert_allclose(cross(np.broadcast_to(u2, u1.shape), pose.points["J"] - pose.points["G"]), e2, atol=TOL)
        np.testing.assert_allclose(wrap(pose.angles["s1"] - heading(u1)), 0.0, atol=TOL)
        np.testing.assert_allclose(wrap(pose.angles["s2"] - heading(u2)), 0.0, atol=TOL)

    return Mechanism(ground, links, [driver, dyad], name="slider_prp"), check


BUILDERS = {
    "RRR": crank_rrr,
    "RRP": crank_rrp,
    "PRR": lambda rng, mode: crank_rrp(rng, mode, kind="PRR"),
    "PRR-moving-guide": crank_prr_moving_guide,
    "RPR": crank_rpr,
    "PRP+slider": slider_prp,
}
CASES = [(kind, mode) for kind in BUILDERS for mode in ((None,) if kind == "PRP+slider" else (1, -1))]
N_GEOMETRIES = 4
N_Q = 64


@eqx.filter_jit
def batch_positions(mech, q):
    return jax.vmap(lambda q: assurjax.positions(mech, q))(q)


def numpy_pose(pose):
    return jax.tree.map(np.asarray, pose)


def sample_q(rng, mech, n):
    if mech.driver.kind == "slider":
        return rng.uniform(-0.5, 0.5, n)
    return rng.uniform(-np.pi, np.pi, n)


def rigid_residual(mech, pose):
    """Largest distance between a point placed from each link that carries it (from the
    link's centre of mass and angle) and the point as reported."""
    worst = 0.0
    for name, lk in mech.links.items():
        com_local = np.asarray(lk.com)
        for p, local in lk.points.items():
            placed = pose.coms[name] + rotate_batch(pose.angles[name], np.asarray(local) - com_local)
            worst = max(worst, np.abs(placed - pose.points[p]).max())
    return worst


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("kind,mode", CASES)
def test_constraints_and_assembly_mode(kind, mode, rng):
    for _ in range(N_GEOMETRIES):
        mech, check = BUILDERS[kind](rng, mode)
        q = sample_q(rng, mech, N_Q)
        pose = numpy_pose(batch_positions(mech, jnp.asarray(q)))
        assert pose.ok.all()
        assert rigid_residual(mech, pose) < TOL
        for p, xy in mech.ground.items():
            np.testing.assert_allclose(pose.points[p], np.broadcast_to(np.asarray(xy), pose.points[p].shape), atol=0)
        if mech.driver.kind == "crank":  # Crank docstring: q is the angle of the crank's local x axis
            np.testing.assert_allclose(wrap(pose.angles["crank"] - q), 0.0, atol=TOL)
        check(mech, q, pose)


def finite_differences(mech, q, h):
    """Central first and second differences of all positions and (unwrapped) angles."""
    plus, mid, minus = (numpy_pose(batch_positions(mech, jnp.asarray(q + s))) for s in (h, 0.0, -h))
    first, second = {}, {}
    for field in ("points", "coms", "angles"):
        a, b, c = getattr(plus, field), getattr(mid, field), getattr(minus, field)
        if field == "angles":  # keep the three values on one branch of the angle
            a = {k: b[k] + wrap(a[k] - b[k]) for k in a}
            c = {k: b[k] + wrap(c[k] - b[k]) for k in c}
        first[field] = {k: (a[k] - c[k]) / (2 * h) for k in a}
        second[field] = {k: (a[k] - 2 * b[k] + c[k]) / h**2 for k in a}
    return first, second


@pytest.mark.parametrize("kind,mode", CASES)
def test_velocities_and_accelerations_match_finite_differences(kind, mode, rng):
    mech, _ = BUILDERS[kind](rng, mode)
    q = sample_q(rng, mech, 16)
    omega, alpha = rng.uniform(-3, 3, q.shape), rng.uniform(-5, 5, q.shape)
    kin = assurjax.kinematics(mech, q, omega, alpha)
    d1, _ = finite_differences(mech, q, 1e-6)
    _, d2 = finite_differences(mech, q, 1e-4)
    pairs = {
        "points": (kin.velocities, kin.accelerations),
        "coms": (kin.com_velocities, kin.com_accelerations),
        "angles": (kin.angular_velocities, kin.angular_accelerations),
    }
    for field, (vel, acc) in pairs.items():
        for k in d1[field]:
            w = omega.reshape(-1, *([1] * (d1[field][k].ndim - 1)))
            a = alpha.reshape(w.shape)
            np.testing.assert_allclose(np.asarray(vel[k]), d1[field][k] * w, atol=2e-7, err_msg=f"velocity of {field} {k}")
            expected = d2[field][k] * w**2 + d1[field][k] * a
            np.testing.assert_allclose(np.asarray(acc[k]), expected, rtol=1e-5, atol=1e-5, err_msg=f"acceleration of {field} {k}")


def second_difference_jump(mech, q):
    """Largest second difference of any point along a fine sweep of q (m): O(dq^2) when the
    motion is smooth, of the order of a link length when the branch flips."""
    pose = numpy_pose(batch_positions(mech, jnp.asarray(q)))
    assert pose.ok.all()
    return max(np.abs(np.diff(x, n=2, axis=0)).max() for x in pose.points.values())


@pytest.mark.parametrize("kind,mode", [c for c in CASES if c[0] != "PRP+slider"])
def test_full_rotation_stays_on_one_branch(kind, mode, rng):
    mech, check = BUILDERS[kind](rng, mode)
    q = np.linspace(-np.pi, 3 * np.pi, 4001)  # two full turns
    dq = q[1] - q[0]
    assert second_difference_jump(mech, q) < 200 * dq**2  # ~2e-3 m; a flip moves points by ~0.1 m
    pose = numpy_pose(batch_positions(mech, jnp.asarray(q)))
    check(mech, q, pose)  # the assembly-mode sign holds all the way round
    # periodic: after a full turn the mechanism is back where it was
    n = (len(q) - 1) // 2
    for k, x in pose.points.items():
        np.testing.assert_allclose(x[n:], x[: n + 1], atol=1e-9, err_msg=k)


# crank angles swept: a full turn, or the range where the mechanism assembles
SWEEPS = {
    "watt_sixbar": (-np.pi, np.pi),
    "slider_crank": (-np.pi, np.pi),
    "quick_return": (-np.pi, np.pi),
    "tangent_drive": (0.35, np.pi - 0.35),  # the slide runs off to infinity where slot and guide are parallel
    "roberts": (0.05, np.pi / 2 - 0.02),  # flat (change point) at 0, toggle at 90 deg
}


@pytest.mark.parametrize("name", sorted(SWEEPS))
def test_bundled_sweep_is_continuous(name):
    mech = assurjax.load_scene(name).mechanism
    q = np.linspace(*SWEEPS[name], 4001)
    dq = q[1] - q[0]
    assert second_difference_jump(mech, q) < 400 * dq**2


def test_watt_sixbar_matches_circle_intersections():
    """The Watt six-bar against two circle intersections written here (left of A->O4, C->D)."""
    mech = assurjax.load_scene("watt_sixbar").mechanism
    q = np.linspace(-np.pi, np.pi, 73)
    pose = numpy_pose(batch_positions(mech, jnp.asarray(q)))

    def left_intersection(c1, r1, c2, r2):
        d = c2 - c1
        L = np.linalg.norm(d, axis=-1, keepdims=True)
        a = (L**2 + r1**2 - r2**2) / (2 * L)
        h = np.sqrt(r1**2 - a**2)
        return c1 + a * d / L + h * perp(d) / L

    A = np.stack([np.cos(q), np.sin(q)], -1)
    O4 = np.array([1.6, 0.0])
    B = left_intersection(A, 1.5, np.broadcast_to(O4, A.shape), 1.5)
    C, D = (A + B) / 2, (O4 + B) / 2
    E = left_intersection(C, 1.0, D, 1.0)
    for name, x in {"A": A, "B": B, "C": C, "D": D, "E": E}.items():
        np.testing.assert_allclose(pose.points[name], x, atol=1e-12, err_msg=name)


def _count_equations(jaxpr) -> int:
    """Equations of a jaxpr, those of nested jaxprs (jit, cond, ...) included."""
    count = 0
    for eqn in jaxpr.eqns:
        count += 1
        for param in eqn.params.values():
            for sub in param if isinstance(param, (list, tuple)) else [param]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    count += _count_equations(inner)
    return count


def test_points_subset_solves_only_needed_groups():
    """Asking for a point of an early group traces none of the later groups."""
    mech = assurjax.load_scene("watt_sixbar").mechanism
    jaxpr_all = jax.make_jaxpr(lambda q: assurjax.positions(mech, q))(0.3).jaxpr
    jaxpr_a = jax.make_jaxpr(lambda q: assurjax.positions(mech, q, points=["A"]))(0.3).jaxpr
    assert _count_equations(jaxpr_a) < _count_equations(jaxpr_all) / 3
    full = assurjax.positions(mech, 0.3)
    part = assurjax.positions(mech, 0.3, points=["A", "B"])
    assert set(part.points) == {"A", "B"}
    for k in part.points:
        np.testing.assert_allclose(part.points[k], full.points[k], atol=0)


def test_vmapped_positions_of_many_crank_angles():
    mech = assurjax.load_scene("slider_crank").mechanism
    q = np.linspace(0.0, 2 * np.pi, 10_000)
    pose = numpy_pose(batch_positions(mech, jnp.asarray(q)))
    # in-line slider-crank: x_B = r cos q + sqrt(l^2 - r^2 sin^2 q)
    r, rod = 0.1, 0.3
    np.testing.assert_allclose(pose.points["B"][:, 0], r * np.cos(q) + np.sqrt(rod**2 - (r * np.sin(q)) ** 2), atol=1e-13)
    np.testing.assert_allclose(pose.points["B"][:, 1], 0.0, atol=1e-13)


def test_kinematics_batch_shape_and_order():
    mech = assurjax.load_scene("slider_crank").mechanism
    q = np.linspace(0.0, 1.0, 6).reshape(2, 3)
    kin = assurjax.kinematics(mech, q, order=1)
    assert kin.points["B"].shape == (2, 3, 2)
    assert kin.velocities["B"].shape == (2, 3, 2)
    assert kin.accelerations is None and kin.angular_accelerations is None
    kin0 = assurjax.kinematics(mech, q, order=0)
    assert kin0.velocities is None
    # each batch entry against the in-line slider-crank closed form at its own q (order kept)
    r, rod = 0.1, 0.3
    root = np.sqrt(rod**2 - (r * np.sin(q)) ** 2)
    for k in (kin, kin0):
        np.testing.assert_allclose(k.points["B"][..., 0], r * np.cos(q) + root, atol=1e-13)
    np.testing.assert_allclose(kin.velocities["B"][..., 0], -r * np.sin(q) - r**2 * np.sin(q) * np.cos(q) / root, atol=1e-12)


def test_groups_with_an_assembly_mode_declare_two_modes():
    """A group class with a ``mode`` field declares ``two_modes`` (the tracked branch then
    tries both roots), and no other does."""
    import dataclasses
    import inspect

    classes = [c for _, c in inspect.getmembers(groups, inspect.isclass) if issubclass(c, groups.AbstractGroup)]
    assert any(c.two_modes for c in classes)
    for c in classes:
        assert c.two_modes == ("mode" in {f.name for f in dataclasses.fields(c)}), c.__name__
