"""assurjax.jit: the package's compiled entry points carry XLA compiler options at the
top level and must still work inside a user's own jit / vmap / grad (JAX refuses
compiler options on nested jits)."""

import jax
import jax.numpy as jnp
import numpy as np

import assurjax as aj


def test_package_functions_inside_a_users_jit_and_grad():
    mech = aj.load_scene("watt_sixbar").mechanism
    qs = jnp.linspace(0.0, 1.0, 5)
    top = aj.kinematics(mech, qs).points["E"]
    nested = jax.jit(lambda q: aj.kinematics(mech, q, check=False).points["E"])(qs)
    np.testing.assert_allclose(nested, top, rtol=0, atol=1e-14)
    # a derivative through the nested jit against a central difference of the top-level call
    grad = jax.grad(lambda q: aj.kinematics(mech, q, order=0, check=False).points["E"][0])(0.3)
    h = 1e-6
    diff = (aj.kinematics(mech, 0.3 + h, order=0).points["E"][0] - aj.kinematics(mech, 0.3 - h, order=0).points["E"][0]) / (2 * h)
    assert abs(grad - diff) < 1e-8


def test_jit_as_decorator_with_static_arguments():
    @aj.jit
    def scaled(x, factor: int):
        return x * factor

    np.testing.assert_array_equal(scaled(jnp.arange(3.0), 2), [0.0, 2.0, 4.0])
    np.testing.assert_array_equal(jax.jit(lambda x: scaled(x, 3))(jnp.ones(2)), [3.0, 3.0])
