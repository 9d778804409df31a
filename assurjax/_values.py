"""Checks of numeric input values shared by the scene loader and the Python API, so
both reject a bad value with the same words (the caller adds where the value is)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

# No quantity of a planar linkage in SI units comes near this; beyond it float64 arithmetic
# on the values (squared lengths, energies, Newton residuals) stops meaning anything.
MAGNITUDE_LIMIT = 1e12

# The shortest length (m) or direction vector the package takes: the square of a shorter one
# underflows to a subnormal, which JAX's CPU flushes to zero (a guide direction of length
# 1.4e-160 placed every slider at its guide point, ok=True, with NaN derivatives)
MIN_LENGTH = 1e-100


def all_finite(tree) -> jax.Array:
    """True where every value in the pytree is finite (traced: for use inside jit)."""
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in jax.tree.leaves(tree)]))


def concrete(x) -> np.ndarray | None:
    """``x`` as a NumPy array, or None when it is a JAX tracer (checked where it is concrete)."""
    try:
        return np.asarray(x, dtype=float)
    except Exception:  # a tracer under jit/vmap/grad, or not numeric (the caller reports that)
        return None


def shape_words(shape: tuple[int, ...]) -> str:
    """A wanted ``shape`` in words: "a single number", "a 2-vector (x, y)", "an array of shape (3,)"."""
    return "a single number" if shape == () else "a 2-vector (x, y)" if shape == (2,) else f"an array of shape {shape}"


def shape_problem(x, shape: tuple[int, ...]) -> str | None:
    """What is wrong with the shape of ``x`` (a number, an array or a tracer) for ``shape``, or None."""
    try:
        found = np.shape(x)
    except Exception:  # not array-like: value_problem says so
        return None
    return None if found == shape else f"must be {shape_words(shape)}, got {found_words(found)}"


def found_words(shape: tuple[int, ...]) -> str:
    """A given array's ``shape`` in words: "a single number", "an array of shape (2,)"."""
    return "a single number" if shape == () else f"an array of shape {shape}"


def value_problem(x, *, shape: tuple[int, ...] | None = None, positive: bool = False, nonnegative: bool = False,
                  nonzero_vector: bool = False) -> str | None:
    """What is wrong with a concrete number or array ``x`` ("must be finite, got inf"...), or None.
    ``shape``: the shape it must have (checked on tracers too; their values are not checked).
    ``nonzero_vector``: the last axis holds vectors at least MIN_LENGTH long (not zero)."""
    if type(x) in (int, float) and shape in (None, ()) and _plain_number_ok(x, positive, nonnegative):
        return None  # the common case, decided without NumPy (~25 us less per value)
    if shape is not None and (problem := shape_problem(x, shape)) is not None:
        return problem
    v = _as_numbers(x)
    if v is None:  # a traced value is checked where it is concrete; anything else is no number
        return numbers_problem(x)
    shown = x if np.ndim(x) == 0 else v.tolist() if v.size <= 8 else f"an array of shape {v.shape}"
    if not np.all(np.isfinite(v)):
        return f"must be finite, got {shown}"
    if np.any(np.abs(v) > MAGNITUDE_LIMIT):
        return f"must be at most {MAGNITUDE_LIMIT:g} in magnitude, got {shown}"
    if positive and not np.all(v > 0):
        return f"must be positive, got {shown}"
    if nonnegative and not np.all(v >= 0):
        return f"must be non-negative, got {shown}"
    if nonzero_vector and v.ndim >= 1 and np.any(np.hypot.reduce(v, axis=-1) < MIN_LENGTH):
        return f"must be a non-zero vector at least {MIN_LENGTH:g} long (a shorter one underflows), got {shown}"
    return None


def numbers_problem(x) -> str | None:
    """What is wrong with ``x`` where numbers go (a string, a flag, an object), or None:
    numbers, and traced values (checked where they are concrete). Called before NumPy or
    JAX reads ``x``, whose own error ("could not convert string to float") names no field."""
    if _traced(x) or _as_numbers(x) is not None:
        return None
    return f"must be a number or an array of numbers, got {x!r:.60}"


# States one analysis call takes (kinematics, reactions, inverse dynamics): each state's
# results are a few hundred bytes to kilobytes, and a call holds them all at once
STATES_LIMIT = 1_000_000


def check_state_count(error: type[Exception], where: str, shape: tuple[int, ...]) -> None:
    """Raise ``error`` where an analysis along states of this ``shape`` asks for more than
    STATES_LIMIT of them (the request is bounded, not left to run out of memory)."""
    count = math.prod(shape)
    if count > STATES_LIMIT:
        raise error(f"{where}: at most {STATES_LIMIT:,} states per call, got {count:,} (shape {tuple(shape)}); "
                    "split them over several calls")


def _as_numbers(x) -> np.ndarray | None:
    """``x`` as a float NumPy array, read once; None for a tracer and for what holds anything
    but numbers: strings, flags, objects (NumPy would read "0.1" as 0.1 and True as 1.0)."""
    try:
        raw = np.asarray(x)
    except Exception:  # a tracer (np.asarray refuses it), or nothing NumPy can read
        return None
    flags = isinstance(x, (list, tuple)) and any(isinstance(e, (bool, np.bool_)) for e in x)  # [True, 0.3]: floats
    return None if flags or raw.dtype.kind not in "iuf" else raw.astype(float)


def _traced(x) -> bool:
    """Whether ``x`` holds a JAX tracer (a value under jit, vmap or grad)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def _plain_number_ok(x: float, positive: bool, nonnegative: bool) -> bool:
    # the magnitude test also fails for nan and inf, and compares a huge int exactly (no conversion to float)
    return abs(x) <= MAGNITUDE_LIMIT and (x > 0 or not positive) and (x >= 0 or not nonnegative)


def check_values(error: type[Exception], where: str, *, shape: tuple[int, ...] | None = None, **values) -> None:
    """Raise ``error("{where}: {name} {problem}")`` for the first of ``values`` (by name) that
    :func:`value_problem` finds wrong: not finite, of absurd size, or not of ``shape``."""
    for name, x in values.items():
        if (problem := value_problem(x, shape=shape)) is not None:
            raise error(f"{where}: {name} {problem}")


def check_value(error: type[Exception], where: str, x, **ranges) -> None:
    """Raise ``error("{where} {problem}")`` when :func:`value_problem` finds one."""
    problem = value_problem(x, **ranges)
    if problem is not None:
        raise error(f"{where} {problem}")
