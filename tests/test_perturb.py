"""perturb and the batch utilities keep every link's values on that link, whatever the order the
links are listed in (JAX rebuilds a dict sorted by key; a selection read in the given order and
put back into a sorted copy landed on other links)."""

import jax
import numpy as np
import pytest

import assurjax
from assurjax import AssurjaxError


@pytest.fixture(scope="module")
def unsorted_scenes():
    """The bundled scenes whose links are not listed in alphabetical order (JAX rebuilds a
    dict sorted by key: perturb put the press's rod mass on its ram, strandbeest's link points
    on other links, and batch_kinematics then raised a bare KeyError)."""
    scenes = {name: assurjax.load_scene(name) for name in assurjax.bundled_scenes()}
    unsorted = {name: s.mechanism for name, s in scenes.items() if list(s.mechanism.links) != sorted(s.mechanism.links)}
    assert {"press_with_friction", "quick_return", "strandbeest", "tangent_drive"} <= set(unsorted)
    return unsorted


def _link_values(m):
    """Every link value by link and point name (order-blind), and the ground's."""
    values = {("ground", p): np.asarray(v) for p, v in m.ground.items()}
    for name, link in m.links.items():
        values.update({(name, p): np.asarray(v) for p, v in link.points.items()})
        values.update({(name, f): np.asarray(getattr(link, f)) for f in ("mass", "inertia", "com")})
    return values


def _members_equal(batch, m, n, skip=()):
    """Every member of ``batch`` equals ``m``: its link order, and its values by name (but ``skip``)."""
    import equinox as eqx
    from assurjax._sweep import take

    assert list(batch.links) == list(m.links) and bool(eqx.tree_equal(take(batch, n - 1), m) or skip)
    got = _link_values(batch)
    assert got.keys() == _link_values(m).keys()
    for k, v in _link_values(m).items():
        if k[1] not in skip:
            np.testing.assert_array_equal(got[k], np.broadcast_to(v, (n,) + v.shape), err_msg=str(k))


def test_perturb_with_no_spread_copies_the_mechanism_whatever_its_order_of_links(unsorted_scenes):
    """perturb(relative=0) of every bundled scene with unsorted links: each member equals the
    original, link by link by name (the press's rod and ram swapped masses: q(0.3 s) 1.84398
    against 1.83935 alone), for the default select and a select by position."""
    for name, m in unsorted_scenes.items():
        _members_equal(assurjax.perturb(m, jax.random.key(0), 2, relative=0.0), m, 2)
    m = unsorted_scenes["press_with_friction"]
    masses = lambda m: tuple(link.mass for link in m.links.values())  # noqa: E731
    _members_equal(assurjax.perturb(m, jax.random.key(0), 2, relative=0.0, select=masses), m, 2)
    # stacking keeps the order and the values by name
    _members_equal(assurjax.stack_mechanisms([m, m, m]), m, 3)


def test_perturbing_masses_moves_each_link_within_its_spread_of_its_own(unsorted_scenes):
    m = unsorted_scenes["press_with_friction"]  # masses crank 0.5, rod 1.0, ram 0.8
    spread, n = 0.05, 40
    batch = assurjax.perturb(m, jax.random.key(1), n, relative=spread,
                             select=lambda m: tuple(link.mass for link in m.links.values()))
    for name, link in m.links.items():
        ratio = np.asarray(batch.links[name].mass) / float(link.mass) - 1.0
        assert ratio.shape == (n,) and np.all(np.abs(ratio) <= spread) and np.ptp(ratio) > spread, name
    _members_equal(batch, m, n, skip=("mass",))  # nothing else moved
    # the default select: every point within its spread of its own, nothing else moved
    q = unsorted_scenes["quick_return"]
    batch = assurjax.perturb(q, jax.random.key(2), n, relative=spread)
    got = _link_values(batch)
    for (link, p), v in _link_values(q).items():
        if p not in ("mass", "inertia", "com"):
            assert np.all(np.abs(got[link, p] - v) <= spread * np.abs(v) + 1e-15), (link, p)
    _members_equal(batch, q, n, skip=set(q.ground) | {p for link in q.links.values() for p in link.points})



def test_perturb_select_must_pick_arrays_of_the_mechanism(unsorted_scenes):
    m = unsorted_scenes["press_with_friction"]
    with pytest.raises(AssurjaxError, match="perturb: select must return whole arrays of the mechanism"):
        assurjax.perturb(m, jax.random.key(0), 2, select=lambda m: m.links["rod"].mass * 2)
    with pytest.raises(AssurjaxError, match="the same array more than once"):
        assurjax.perturb(m, jax.random.key(0), 2, select=lambda m: (m.links["rod"].mass, m.links["rod"].mass))
    with pytest.raises(AssurjaxError, match="perturb: select failed on the mechanism \\(KeyError"):
        assurjax.perturb(m, jax.random.key(0), 2, select=lambda m: m.links["nope"].mass)



@pytest.mark.slow  # compiles a vmapped simulation with friction and a single one (~1 min on a busy 2-core machine)
def test_a_batch_of_unperturbed_presses_runs_as_the_press_alone():
    """batch_simulate of perturb(relative=0) over the masses equals the press's own run (the
    swapped masses gave q(0.3 s) = 1.84398 against 1.83935 alone), and names no failed group."""
    scene = assurjax.load_scene("press_with_friction")
    batch = assurjax.perturb(scene.mechanism, jax.random.key(0), 2, relative=0.0,
                             select=lambda m: tuple(link.mass for link in m.links.values()))
    kw = dict(t1=0.3, samples=4, stop=None, points=(), angles=(), rtol=1e-9, atol=1e-9)
    sols = assurjax.batch_simulate(scene, batch, progress=False, **kw)
    one = assurjax.simulate(scene, **kw)
    assert sols.failed_group == (None, None)
    # two programs at one tolerance: a borderline step apart, not bit for bit (the swap: 4.6e-3)
    np.testing.assert_allclose(sols.q, np.broadcast_to(one.q, sols.q.shape), rtol=0, atol=1e-7)
