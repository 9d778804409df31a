"""The integrated state packed into one array for diffrax (dynamics/_packed.py): a round
trip gives the state back, and the vectors join the scalars only while the solver's
stages' buffer stays under THREADED_BYTES."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from assurjax._jit import THREADED_BYTES
from assurjax.dynamics._field import State
from assurjax.dynamics._packed import UNPACKED, packing_of


def _state(rates: int, branch: int | None = None) -> State:
    values = iter(np.linspace(0.1, 2.0, 3 + rates + (branch or 0)))
    take = lambda n: jnp.asarray([next(values) for _ in range(n)])  # noqa: E731
    return State(q=jnp.asarray(next(values)), omega=jnp.asarray(next(values)), work=jnp.asarray(next(values)),
                 friction_rates=take(rates), branch=None if branch is None else take(branch))


def _assert_same(a: State, b: State):
    for x, y in zip(a, b):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_small_vectors_join_the_scalars_and_come_back():
    y = _state(rates=4, branch=2)  # 3 scalars + 6 values: 7 stages x 9 x 8 bytes = 504
    assert 7 * 9 * 8 <= THREADED_BYTES
    packing = packing_of(y, "forward", diffrax.Tsit5())
    z = packing.pack(y)
    assert z.apart is None and z.values.shape == (9,)
    _assert_same(packing.unpack(z), y)
    empty = _state(rates=4, branch=0)  # a vector of no values takes no place
    packing = packing_of(empty, "forward", diffrax.Tsit5())
    assert packing.pack(empty).values.shape == (7,)
    _assert_same(packing.unpack(packing.pack(empty)), empty)


def test_vectors_past_the_threaded_size_are_stepped_apart():
    y = _state(rates=7)  # the Watt six-bar's seven rough pins: 7 stages x 10 x 8 bytes = 560
    assert 7 * 10 * 8 > THREADED_BYTES
    packing = packing_of(y, "forward", diffrax.Tsit5())
    z = packing.pack(y)
    assert z.values.shape == (3,) and len(z.apart) == 1
    _assert_same(packing.unpack(z), y)
    # a solver of fewer stages packs them
    assert packing_of(y, "forward", diffrax.Heun()).pack(y).apart is None


def test_saved_states_unpack_with_their_leading_axes():
    ys = [_state(rates=4)._replace(q=jnp.asarray(float(i))) for i in range(5)]
    packing = packing_of(ys[0], "forward", diffrax.Tsit5())
    stacked = jax.tree.map(lambda *v: jnp.stack(v), *[packing.pack(y) for y in ys])
    out = packing.unpack(stacked)
    np.testing.assert_array_equal(np.asarray(out.q), np.arange(5.0))
    np.testing.assert_array_equal(np.asarray(out.friction_rates), np.stack([np.asarray(y.friction_rates) for y in ys]))


def test_reverse_mode_adjoints_step_the_state_as_it_is():
    assert packing_of(_state(rates=4), "recursive", diffrax.Tsit5()) is UNPACKED


def test_field_arguments_flatten_and_come_back_with_their_types():
    """The vector field's arguments as flat arrays (_jit.flattened_floats): the tree back as
    it was, inside a jit too, weakly typed numbers still weak (a nested jit reading them
    would trace again for a strong type) and other dtypes handed apart."""
    import assurjax
    from assurjax._jit import flattened_floats
    from assurjax._model import as_model

    tree = {"mass": jnp.asarray(2.5), "points": jnp.arange(6.0).reshape(3, 2), "modes": jnp.asarray([1, -1]),
            "name": "crank", "table": np.linspace(0.0, 1.0, 4)}
    flats, others, layout = flattened_floats(tree)
    assert len(flats) == 2 and len(others) == 1 and others[0].dtype == tree["modes"].dtype

    def check(rebuilt, original):
        assert jax.tree.structure(rebuilt) == jax.tree.structure(original)
        for a, b in zip(jax.tree.leaves(rebuilt), jax.tree.leaves(original)):
            if isinstance(b, str):
                assert a == b
                continue
            assert jnp.result_type(a) == jnp.result_type(b)
            assert getattr(a, "weak_type", False) == getattr(b, "weak_type", False)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    check(layout.rebuild(flats, others), tree)
    traced = []  # and as a jit traces it
    jax.jit(lambda f, o: traced.append(layout.rebuild(f, o)) or 0.0)(flats, others)
    assert traced[0]["mass"].aval.weak_type and not traced[0]["points"].aval.weak_type
    model = as_model(assurjax.load_scene("press_with_friction"))
    flats, others, layout = flattened_floats(model)
    check(layout.rebuild(flats, others), model)
    flats, others, layout = flattened_floats(model, flat=False)  # every array apart
    assert flats == () and len(others) == len(jax.tree.leaves(model))
    check(layout.rebuild(flats, others), model)


def test_arrays_a_vmap_maps_are_told_from_those_it_closes_over():
    """_jit.any_mapped, which keeps a model mapped by a vmap (a sweep over its parameters)
    out of the field's flat arrays: the mapped argument is seen, an array closed over is
    not, nor anything inside a traced loop's body (traced apart from the vmap)."""
    from assurjax._jit import any_mapped

    closed, seen = jnp.ones(3), []

    def member(x):
        seen.append((any_mapped(x), any_mapped(closed), any_mapped({"a": closed, "b": x})))
        jax.lax.fori_loop(0, 2, lambda i, v: seen.append(any_mapped(v)) or v, x)
        return x

    jax.jit(jax.vmap(member))(jnp.ones((4, 2)))
    assert seen == [(True, False, True), False]
