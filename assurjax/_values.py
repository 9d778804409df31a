"""Checks of numeric input values shared by the scene loader and the Python API, so
both reject a bad value with the same words (the caller adds where the value is)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# No quantity of a planar linkage in SI units comes near this; beyond it float64 arithmetic
# on the values (squared lengths, energies, Newton residuals) stops meaning anything.
MAGNITUDE_LIMIT = 1e12


def all_finite(tree) -> jax.Array:
    """True where every value in the pytree is finite (traced: for use inside jit)."""
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in jax.tree.leaves(tree)]))


def concrete(x) -> np.ndarray | None:
    """``x`` as a NumPy array, or None when it is a JAX tracer (checked where it is concrete)."""
    try:
        return np.asarray(x, dtype=float)
    except Exception:  # a tracer under jit/vmap/grad, or not numeric (the caller reports that)
        return None


def value_problem(x, *, positive: bool = False, nonnegative: bool = False, nonzero_vector: bool = False) -> str | None:
    """What is wrong with a concrete number or array ``x`` ("must be finite, got inf"...), or None.
    Tracers are not checked. ``nonzero_vector``: the last axis holds vectors that must not be zero."""
    v = concrete(x)
    if v is None:
        return None
    shown = x if np.ndim(x) == 0 else v.tolist() if v.size <= 8 else f"an array of shape {v.shape}"
    if not np.all(np.isfinite(v)):
        return f"must be finite, got {shown}"
    if np.any(np.abs(v) > MAGNITUDE_LIMIT):
        return f"must be at most {MAGNITUDE_LIMIT:g} in magnitude, got {shown}"
    if positive and not np.all(v > 0):
        return f"must be positive, got {shown}"
    if nonnegative and not np.all(v >= 0):
        return f"must be non-negative, got {shown}"
    if nonzero_vector and v.ndim >= 1 and np.any(np.linalg.norm(v, axis=-1) == 0):
        return f"must be a non-zero vector, got {shown}"
    return None


def check_value(error: type[Exception], where: str, x, **ranges) -> None:
    """Raise ``error("{where} {problem}")`` when :func:`value_problem` finds one."""
    problem = value_problem(x, **ranges)
    if problem is not None:
        raise error(f"{where} {problem}")
