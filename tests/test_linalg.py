"""The LAPACK-free linear algebra of a right-hand side (assurjax._linalg) against numpy's
(LAPACK) and lineax's LU: solves, transposed solves, determinants, derivatives."""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np

from assurjax._linalg import PlainLU, lu_determinant, plain_lu_factor, plain_lu_solve

SIZES = (1, 2, 4, 7)


def _matrices(rng, n, count=10):
    """Random matrices with zeros that force row exchanges."""
    return [rng.normal(size=(n, n)) * (rng.random((n, n)) > 0.3) + 0.1 * np.eye(n) for _ in range(count)]


def test_solves_against_numpy():
    rng = np.random.default_rng(3)
    factor = jax.jit(plain_lu_factor)
    solve = jax.jit(plain_lu_solve, static_argnames="transpose")
    for n in SIZES:
        for a in _matrices(rng, n):
            b = rng.normal(size=n)
            factors = factor(jnp.asarray(a))
            bound = 1e-14 * np.linalg.cond(a) * np.abs(np.linalg.solve(a, b)).max() * n
            assert np.abs(np.asarray(solve(factors, jnp.asarray(b))) - np.linalg.solve(a, b)).max() <= bound
            assert np.abs(np.asarray(solve(factors, jnp.asarray(b), transpose=True)) - np.linalg.solve(a.T, b)).max() <= bound


def test_determinant_against_numpy():
    """Random matrices (row exchanges change the sign) and singular ones."""
    rng = np.random.default_rng(7)
    det = jax.jit(lambda a: lu_determinant(plain_lu_factor(a)))
    for n in SIZES:
        for a in _matrices(rng, n) + [rng.normal(size=(n, n)) * (rng.random((n, n)) > 0.3) for _ in range(10)]:
            assert abs(float(det(jnp.asarray(a))) - np.linalg.det(a)) <= 1e-13 * max(1.0, abs(np.linalg.det(a)))
    assert float(det(jnp.array([[0.0, 1.0], [1.0, 0.0]]))) == -1.0
    assert float(det(jnp.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))) == 1.0
    assert float(det(jnp.array([[1.0, 2.0], [2.0, 4.0]]))) == 0.0


def test_plain_lu_solver_in_lineax():
    """PlainLU through lineax (2 x 2 by Cramer's rule, larger by elimination): values,
    forward and reverse derivatives (lineax's rules call its transpose) as lineax's LU."""
    rng = np.random.default_rng(11)
    for n in (2, 4):
        a, b = jnp.asarray(_matrices(rng, n, 1)[0]), jnp.asarray(rng.normal(size=n))

        def solution(solver):
            return lambda m, v: lx.linear_solve(lx.MatrixLinearOperator(m), v, solver).value

        plain, lapack = solution(PlainLU()), solution(lx.LU())
        np.testing.assert_allclose(plain(a, b), lapack(a, b), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(jax.jacfwd(plain)(a, b), jax.jacfwd(lapack)(a, b), rtol=1e-12, atol=1e-13)
        grad = lambda f: jax.grad(lambda m, v: jnp.sum(jnp.sin(f(m, v))), argnums=(0, 1))(a, b)  # noqa: E731
        for g_plain, g_lapack in zip(grad(plain), grad(lapack)):
            np.testing.assert_allclose(g_plain, g_lapack, rtol=1e-12, atol=1e-13)
