"""The small dense systems solved inside a right-hand side, with or without LAPACK.

``jax.scipy.linalg`` and lineax's ``LU`` call LAPACK: on a CPU each call is a call of its
own (microseconds even for a 2 x 2 system), and XLA compiles an integration loop into one
function (:func:`assurjax.enable_fast_loops`) only if no library call is inside. Here: LU
with partial pivoting, its solves and the determinant in plain array operations, and
:class:`PlainLU`, a lineax solver on them (a 2 x 2 system by Cramer's rule: an iterative
group's Newton steps, at every call site of its position analysis). With fast loops the
dense systems of a right-hand side use them; by default LAPACK's, which compile faster.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import lineax as lx
from jaxtyping import Array

from ._jit import fast_loops, in_region


def lu_factor(a: Array) -> tuple[Array, Array]:
    """a's LU factors (U on and above the diagonal of the first) and its pivots, for
    :func:`lu_solve`: LAPACK's, or plain ones with :func:`assurjax.enable_fast_loops` (a
    loop holding a LAPACK call is not compiled into one function). LAPACK's compile faster
    (the triad with friction's first call 1.3 s shorter), so they stay the default."""
    return plain_lu_factor(a) if fast_loops() or in_region() else jsl.lu_factor(a)


def lu_solve(factors: tuple[Array, Array], b: Array) -> Array:
    """x with a x = b from :func:`lu_factor`."""
    return plain_lu_solve(factors, b) if fast_loops() or in_region() else jsl.lu_solve(factors, b)


def small_solver() -> lx.AbstractLinearSolver:
    """lineax's solver for a small system inside a right-hand side (the friction's Newton
    fallback): :class:`PlainLU` with fast loops, lineax's LU otherwise (see :func:`lu_factor`)."""
    return PlainLU() if fast_loops() or in_region() else lx.LU()


def plain_lu_factor(a: Array) -> tuple[Array, Array]:
    """(lu, perm) with a[perm] = L U: L unit lower (below lu's diagonal), U upper (on and
    above it); partial pivoting. A zero pivot is left in place (its solves give inf/NaN)."""
    n = a.shape[0]
    rows = jnp.arange(n)

    def eliminate(j, carry):
        lu, perm = carry
        pivot = jnp.argmax(jnp.where(rows >= j, jnp.abs(lu[:, j]), -1.0))
        lu = jnp.where((rows == j)[:, None], lu[pivot], jnp.where((rows == pivot)[:, None], lu[j], lu))
        perm = jnp.where(rows == j, perm[pivot], jnp.where(rows == pivot, perm[j], perm))
        head = lu[j, j]
        factors = jnp.where(rows > j, lu[:, j] / jnp.where(head == 0, 1.0, head), 0.0)
        lu = lu - factors[:, None] * jnp.where(rows > j, lu[j], 0.0)[None, :]
        return lu.at[:, j].set(jnp.where(rows > j, factors, lu[:, j])), perm

    return jax.lax.fori_loop(0, n, eliminate, (a, rows))


def _substitute(t: Array, b: Array, *, lower: bool, unit: bool) -> Array:
    """x with t x = b, t triangular (only its lower or upper part read)."""
    n = t.shape[0]
    cols = jnp.arange(n)

    def row(step, x):
        i = step if lower else n - 1 - step
        known = cols < i if lower else cols > i
        rest = b[i] - jnp.sum(jnp.where(known, t[i], 0.0) * x)
        return x.at[i].set(rest if unit else rest / t[i, i])

    return jax.lax.fori_loop(0, n, row, jnp.zeros_like(b))


def solve_2x2(a: Array, b: Array) -> Array:
    """x with a x = b for a 2 x 2 matrix, by Cramer's rule (an iterative group's Newton step:
    fewer operations to compile than elimination's, and it is called at many sites)."""
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    return jnp.stack([a[1, 1] * b[0] - a[0, 1] * b[1], a[0, 0] * b[1] - a[1, 0] * b[0]]) / det


def plain_lu_solve(factors: tuple[Array, Array], b: Array, *, transpose: bool = False) -> Array:
    """x with a x = b (or a^T x = b) from ``plain_lu_factor(a)``."""
    lu, perm = factors
    if not transpose:
        y = _substitute(lu, b[perm], lower=True, unit=True)
        return _substitute(lu, y, lower=False, unit=False)
    # a^T = U^T L^T P
    z = _substitute(lu.T, b, lower=True, unit=False)
    w = _substitute(lu.T, z, lower=False, unit=True)
    return jnp.zeros_like(w).at[perm].set(w)


def lu_determinant(factors: tuple[Array, Array]) -> Array:
    """det(a) from ``plain_lu_factor(a)`` (``jnp.linalg.det`` calls LAPACK)."""
    lu, perm = factors
    swaps = jnp.sum(perm[:, None] > perm[None, :], where=jnp.tri(lu.shape[0], dtype=bool, k=-1).T)
    return jnp.prod(jnp.diagonal(lu)) * jnp.where(swaps % 2 == 0, 1.0, -1.0)


class PlainLU(lx.AbstractLinearSolver):
    """lineax's ``LU`` without LAPACK, for the small square systems of a right-hand side
    (an iterative group's Newton steps and implicit derivatives, the friction's fallback):
    operators on one 1-D array. ``finite``: a solution that is not finite (a singular
    system, or non-finite input) is returned as 0, which lineax then counts a success: for
    an implicit derivative at a failed solve (its value flagged not ok), where lineax raises
    from inside the program, whatever the caller's ``throw``, and one failed member of a
    vmapped batch stopped the whole batch."""

    finite: bool = eqx.field(static=True, default=False)

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        if not (_is_vector(operator.in_structure()) and _is_vector(operator.out_structure())
                and operator.in_size() == operator.out_size()):
            raise ValueError("PlainLU solves square systems on one 1-D array only")
        matrix = operator.as_matrix()
        factors = matrix if matrix.shape == (2, 2) else plain_lu_factor(matrix)
        return factors, eqxi.Static(False)

    def compute(self, state, vector, options: dict[str, Any]):
        del options
        factors, transpose = state
        if isinstance(factors, tuple):
            x = plain_lu_solve(factors, vector, transpose=transpose.value)
        else:
            x = solve_2x2(factors.T if transpose.value else factors, vector)
        if self.finite:
            x = jnp.where(jnp.all(jnp.isfinite(x)), x, 0.0)
        return x, lx.RESULTS.successful, {}

    def transpose(self, state, options: dict[str, Any]):
        factors, transpose = state
        return (factors, eqxi.Static(not transpose.value)), {}

    def conj(self, state, options: dict[str, Any]):
        return state, {}  # real systems only

    def assume_full_rank(self):
        return True


def _is_vector(structure) -> bool:
    return isinstance(structure, jax.ShapeDtypeStruct) and len(structure.shape) == 1
