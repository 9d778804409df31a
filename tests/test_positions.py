"""The position analysis by levels of the formation graph (batches, chains) against the
group-by-group reference, and the strandbeest scene against an independent closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax import _positions
from assurjax._tracking import branch_angles

# Jansen's holy numbers (cm), written out again here: the test does not read the generator's copy
A, B, C, D, E, F, G, H, I, J, K, L, M = 38.0, 41.5, 39.3, 40.1, 55.8, 39.4, 36.7, 65.7, 49.0, 50.0, 61.9, 7.8, 15.0


def analysis_fn(mech, batched: bool, near_given: bool):
    """q[, near] -> (x, dx/dq, d2x/dq2) of every link frame and the ok flags, by the
    batched analysis or the group-by-group reference (batched=False)."""
    wanted = tuple(range(len(mech.groups)))

    def frames(q, near):
        table, oks = _positions.analysis(mech, q, wanted, near if near_given else None, batched=batched)
        origins, rots = table.stacked()
        order = np.asarray([table.index(k) for k in sorted(mech.links)])
        return (origins[order], rots[order]), jnp.stack([oks[i] for i in wanted])

    def derivatives(q, near):
        f = lambda q: frames(q, near)  # noqa: E731
        first = lambda q: jax.jvp(f, (q,), (jnp.ones_like(q),), has_aux=True)[:2]  # noqa: E731
        (x, dx), (_, d2x) = jax.jvp(first, (q,), (jnp.ones_like(q),))
        return x, dx, d2x, f(q)[1]

    return jax.jit(jax.vmap(derivatives, in_axes=(0, None)))


def compare(mech, qs, near=None):
    got = analysis_fn(mech, True, near is not None)(qs, near)
    ref = analysis_fn(mech, False, near is not None)(qs, near)
    np.testing.assert_array_equal(np.asarray(got[3]), np.asarray(ref[3]))
    # to round-off: the six-bar chain's second-order coefficients (~0.3) once differed by 1.5e-13
    # (5e-13 relative), as the compiler fused the scan's arithmetic otherwise than the groups' one by one
    for a, b in zip(jax.tree.leaves(got[:3]), jax.tree.leaves(ref[:3])):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-13)


def test_plan_chains_the_n_four_bar():
    """The windows form one chain (a scan) after the driver, whatever N."""
    for n in (4, 12):
        mech = assurjax.n_four_bar(n).mechanism
        wanted = tuple(range(n + 1))
        items = _positions.plan(mech, wanted, {i: _positions.Options() for i in wanted})
        assert [type(x).__name__ for x in items] == ["Batch", "Chain"]
        assert [s.groups for s in items[1].steps] == [(i,) for i in range(1, n + 1)]


def test_plan_batches_the_strandbeest_by_level_and_kind():
    """25 groups in 5 solves: the driver, then per level the dyads of one assembly mode."""
    mech = assurjax.load_scene("strandbeest").mechanism
    wanted = tuple(range(len(mech.groups)))
    items = _positions.plan(mech, wanted, {i: _positions.Options() for i in wanted})
    assert len(items) == 5 and sorted(len(x.groups) for x in items) == [1, 4, 4, 8, 8]
    assert sorted(i for x in items for i in x.groups) == list(wanted)


# both in the slow suite (~16 s and ~11 s): the N-four-bar's chain runs by default in test_stress.py (its
# tracked motion against the exact solution), the default suite keeps to 10 min
@pytest.mark.slow
@pytest.mark.parametrize("tracked", [False, True])
def test_chain_matches_group_by_group(tracked):
    """N-four-bar (a scan over the windows), fixed modes and with a branch predictor:
    positions and both kinematic coefficients equal the group-by-group values."""
    mech = assurjax.n_four_bar(6).mechanism
    qs = jnp.linspace(0.3, 2.8, 7)
    near = branch_angles(mech, assurjax.positions(mech, 1.5)) if tracked else None
    compare(mech, qs, near)


def test_batches_match_group_by_group():
    mech = assurjax.strandbeest(1).mechanism  # 2 legs, mirrored: batches of 2
    compare(mech, jnp.linspace(-3.0, 3.0, 5))


# in the slow suite (~21 s and ~15 s): the iterative groups' continuation is checked by default in
# tests/test_iterative_groups.py (closure, branch continuity), the default suite keeps to 10 min
@pytest.mark.slow
@pytest.mark.parametrize("name", ["triad_mechanism", "class4_seed003"])
def test_iterative_groups_match_group_by_group(name):
    """Continuation of the iterative groups from their guess, batched or not."""
    scene = assurjax.load_scene(name)
    compare(scene.mechanism, scene.state["q0"] + jnp.linspace(-2.0, 2.0, 5))


def test_iterative_group_alone_needs_a_start():
    """A triad solved outside the position analysis, without a predictor, says what it needs."""
    from assurjax.groups import Placement

    mech = assurjax.load_scene("triad_mechanism").mechanism
    q = jnp.asarray(0.0)
    driver_only, _ = _positions.analysis(mech, q, (0,), None)  # the triad's inputs are placed
    placed = Placement(mech.all_links(), dict(mech.owner), driver_only)
    with pytest.raises(assurjax.MechanismError, match="needs starting angles"):
        mech.groups[1].solve(mech.all_links(), placed, q)


def circle_circle(c1, r1, c2, r2):
    """Both intersections of two circles (numpy, batched over the leading axis)."""
    d = c2 - c1
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    along = (dist**2 + r1**2 - r2**2) / (2 * dist)
    h = np.sqrt(r1**2 - along**2)
    base = c1 + along * d / dist
    n = np.stack([-d[..., 1], d[..., 0]], -1) / dist
    return base + h * n, base - h * n


def jansen_feet(theta, side):
    """Foot point (cm) of a Jansen leg, crank pin at angle theta, pivot on ``side`` (-1 left, +1 right)."""
    pick = lambda cond, p, q: np.where(cond(p, q)[..., None], p, q)  # noqa: E731
    higher = lambda p, q: p[..., 1] > q[..., 1]  # noqa: E731
    lower = lambda p, q: p[..., 1] < q[..., 1]  # noqa: E731
    outer = lambda p, q: side * p[..., 0] > side * q[..., 0]  # noqa: E731
    crank = M * np.stack([np.cos(theta), np.sin(theta)], -1)
    pivot = np.broadcast_to([side * A, -L], crank.shape)
    c = pick(higher, *circle_circle(crank, J, pivot, B))
    d = pick(lower, *circle_circle(crank, K, pivot, C))
    e = pick(outer, *circle_circle(pivot, D, c, E))
    f = pick(outer, *circle_circle(e, F, d, G))
    return pick(lower, *circle_circle(f, H, d, I))


def test_strandbeest_feet_closed_form():
    """Every foot of the 8-leg scene over a revolution: circle intersections in numpy."""
    scene = assurjax.load_scene("strandbeest")
    feet = scene.outputs["points"]
    q = np.linspace(-np.pi, np.pi, 61)
    kin = assurjax.kinematics(scene.mechanism, q, order=0, points=feet, coms=False, angles=False)
    for p in range(4):
        for side, tag in ((-1, "L"), (1, "R")):
            expected = jansen_feet(q + np.pi / 2 * p, side) / 100.0
            np.testing.assert_allclose(np.asarray(kin.points[f"G{tag}{p}"]), expected, atol=1e-12)
    # the walking gait: each foot spends a long stretch of the cycle on a near-flat ground line
    y = np.asarray(kin.points["GL0"])[:, 1]
    assert np.mean(y < y.min() + 0.01) > 0.3


def test_points_subset_solves_the_needed_part_of_a_chain():
    """points= keeps only the windows a point depends on (a shorter chain), same values;
    the groups not solved report ok."""
    mech = assurjax.n_four_bar(8).mechanism
    part = assurjax.positions(mech, 1.1, points=["B5"])
    whole = assurjax.positions(mech, 1.1)
    solved = {"rocker0"} | {f"coupler{i}" for i in range(5)} | {f"rocker{i}" for i in range(1, 6)}  # windows 0..4
    assert list(part.points) == ["B5"] and set(part.angles) == solved
    np.testing.assert_allclose(np.asarray(part.points["B5"]), np.asarray(whole.points["B5"]), rtol=0, atol=1e-15)
    assert bool(np.all(np.asarray(part.ok)))


@pytest.mark.parametrize("name", ["slider_crank", "triad_mechanism", "strandbeest"])
def test_coefficients_carry_the_links_rotations_and_their_derivatives(name):
    """The kinematic coefficients' rotations (read by the statics and the slider friction
    instead of cos and sin of an angle) are (cos, sin) of the link angles, and their first
    and second derivatives along q are those of (cos theta(q), sin theta(q)) by the chain
    rule from the angles' own coefficients: for names placed one by one (slider-crank), an
    iterative group (triad) and the stacked analysis of a large mechanism (strandbeest)."""
    from assurjax._kinematics import coefficients

    mechanism = assurjax.load_scene(name).mechanism
    assert_rotations_follow_angles(coefficients(mechanism, jnp.asarray(0.7)))


def assert_rotations_follow_angles(c):
    """``c``'s rotations are (cos, sin) of its angles, their derivatives those of
    (cos theta(q), sin theta(q)) by the chain rule from the angles' coefficients."""
    (_, _, theta, rot), (_, _, d_theta, d_rot), (_, _, d2_theta, d2_rot) = c.stacked
    cos, sin = np.cos(theta), np.sin(theta)
    np.testing.assert_allclose(rot, np.stack([cos, sin], axis=-1), atol=1e-12)
    np.testing.assert_allclose(d_rot, np.stack([-sin, cos], axis=-1) * d_theta[:, None], atol=1e-10)
    expected = (np.stack([-sin, cos], axis=-1) * d2_theta[:, None] - np.stack([cos, sin], axis=-1) * (d_theta**2)[:, None])
    np.testing.assert_allclose(d2_rot, expected, atol=1e-8)


def test_crank_turn_and_its_derivatives_in_closed_form():
    """The crank's (cos q, sin q), computed once with derivatives from itself (a custom jvp):
    its value, first and second derivatives in forward and reverse mode against -sin, cos and
    -cos, -sin; a non-finite angle stays non-finite."""
    from assurjax.groups._drivers import turn

    for q in (0.7, -2.9, 31.4):
        c, s = np.cos(q), np.sin(q)
        np.testing.assert_allclose(np.asarray(turn(q)), [c, s], rtol=0, atol=2e-16)  # divided by an exact one
        for first in (jax.jacfwd(turn)(q), jax.jacrev(turn)(q)):
            np.testing.assert_allclose(np.asarray(first), [-s, c], rtol=0, atol=1e-15)
        for second in (jax.jacfwd(jax.jacfwd(turn))(q), jax.jacrev(jax.jacfwd(turn))(q)):
            np.testing.assert_allclose(np.asarray(second), [-c, -s], rtol=0, atol=1e-15)
    assert not np.any(np.isfinite(np.asarray(turn(jnp.inf))))
