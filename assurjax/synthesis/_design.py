"""A design: which parameters of a mechanism (or scene) move, and within which bounds."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import AssurjaxError
from .._structure import by_structure
from ._parameters import _selected


class Design(eqx.Module):
    """The parameters ``select(base)`` of ``base`` (a Mechanism, a Scene, or any
    pytree, e.g. ``(mechanism, q_points)``), free between ``lower`` and ``upper``.

    Optimizers work on unconstrained variables ``z`` (a pytree shaped like the
    selection); the bounded reparametrization

        x = lower + (upper - lower) * sigmoid(z)

    keeps every parameter strictly inside its bounds whatever step the optimizer
    takes. Entries whose lower and upper bounds are both infinite are left
    unbounded (x = z). ``lower``/``upper`` are absolute bounds: pytrees like the
    selection or numbers (broadcast); ``relative``/``absolute`` give bounds
    ``x0 -/+ (relative |x0| + absolute)`` around the start values x0 instead.
    ``fixed``: a pytree of booleans like the selection (or one boolean): the
    entries that stay at their start values whatever ``z`` (their gradient is 0).

    Bounds and start values are arrays: a new Design with other bounds or start
    values (same ``select`` code) runs through :func:`optimize`'s compiled program
    without recompiling.

    **Example:**
    >>> design = Design(mech, lambda m: (m.links["link4"].points["P"], m.ground["D"]), relative=0.2, absolute=0.01)
    >>> z = design.init()
    >>> design.build(z)  # the mechanism at z
    """

    base: Any
    lower: Any
    upper: Any
    fixed: Any
    select: Callable = eqx.field(static=True)

    def __init__(self, base: Any, select: Callable, lower: Any = None, upper: Any = None, *, relative: float | None = None,
                 absolute: float | None = None, fixed: Any = False):
        self.base, self.select = base, by_structure(select)
        x0, _ = _selected(base, select)
        if not jax.tree.leaves(x0):  # optimize failed on it with an IndexError
            raise AssurjaxError("Design: select returns no array: there is nothing to optimize")
        if relative is not None or absolute is not None:
            if lower is not None or upper is not None:
                raise AssurjaxError("Design: give either lower/upper or relative/absolute bounds, not both")
            width = jax.tree.map(lambda x: (relative or 0.0) * jnp.abs(x) + (absolute or 0.0), x0)
            lower = jax.tree.map(lambda x, w: x - w, x0, width)
            upper = jax.tree.map(lambda x, w: x + w, x0, width)
        self.lower = _bound(x0, lower, -jnp.inf, "lower")
        self.upper = _bound(x0, upper, jnp.inf, "upper")
        try:
            per_leaf = jax.tree.map(lambda x: fixed, x0) if isinstance(fixed, bool) else fixed
            self.fixed = jax.tree.map(lambda x, f: jnp.broadcast_to(jnp.asarray(f, dtype=bool), x.shape), x0, per_leaf)
        except ValueError as e:
            raise AssurjaxError(f"Design: fixed must be a boolean or a pytree of booleans shaped like the selection ({e})") from None
        check_inside(x0, self.lower, self.upper, self.fixed)

    def start(self) -> Any:
        """The selected parameter values of the base design (the start values)."""
        return _selected(self.base, self.select)[0]

    def values(self, z: Any) -> Any:
        """The bounded parameter values at the unconstrained variables ``z`` (fixed entries at their start values)."""
        free = jax.tree.map(_to_bounded, z, self.lower, self.upper)
        return jax.tree.map(lambda f, x, x0: jnp.where(f, x0, x), self.fixed, free, self.start())

    def unconstrained(self, values: Any) -> Any:
        """The unconstrained variables of given parameter values (inverse of :meth:`values`)."""
        return jax.tree.map(_to_unconstrained, values, self.lower, self.upper)

    def init(self) -> Any:
        """The unconstrained variables of the base design."""
        return self.unconstrained(_selected(self.base, self.select)[0])

    def build(self, z: Any) -> Any:
        """The mechanism (or scene) with the selected parameters at ``z``."""
        return eqx.tree_at(self.select, self.base, self.values(z))

    def with_values(self, values: Any) -> Any:
        """The mechanism (or scene) with the selected parameters set to ``values``."""
        return eqx.tree_at(self.select, self.base, values)


def _bound(x0, bound, default, which: str):
    if bound is None:
        return jax.tree.map(lambda x: jnp.full_like(x, default), x0)
    if isinstance(bound, (int, float)) or (eqx.is_array_like(bound) and np.ndim(bound) == 0):
        return jax.tree.map(lambda x: jnp.full_like(x, bound), x0)
    try:
        return jax.tree.map(lambda x, b: jnp.broadcast_to(jnp.asarray(b, dtype=x.dtype), x.shape), x0, bound)
    except ValueError as e:
        raise AssurjaxError(f"Design: {which} bounds must be a number or a pytree shaped like the selection ({e})") from None


def check_inside(x0, lower, upper, fixed):
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(x0)[0]]
    for name, x, lo, hi, f in zip(paths, jax.tree.leaves(x0), jax.tree.leaves(lower), jax.tree.leaves(upper), jax.tree.leaves(fixed)):
        free = ~np.asarray(f)
        x, lo, hi = np.asarray(x)[free], np.asarray(lo)[free], np.asarray(hi)[free]
        where = f"selected parameter {name or '(the selection)'}"
        if np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise AssurjaxError(f"Design: {where}: bounds must be numbers or +-inf (no bound), got lower {lo}, upper {hi}")
        if not np.all(np.isfinite(x)):
            raise AssurjaxError(f"Design: {where}: the starting value must be finite, got {x}")
        if np.any(lo > hi) or np.any(~np.isinf(lo) & ~np.isinf(hi) & (lo == hi)):
            raise AssurjaxError(f"Design: {where}: empty bounds (lower {lo} must be below upper {hi})")
        if np.any(x <= lo) or np.any(x >= hi):
            raise AssurjaxError(f"Design: {where}: the starting value {x} is not strictly inside its bounds [{lo}, {hi}]")


def _kinds(lo, hi):
    """Which map each entry uses: a box (sigmoid), a one-sided bound (softplus) or none."""
    has_lo, has_hi = jnp.isfinite(lo), jnp.isfinite(hi)
    return has_lo & has_hi, has_lo & ~has_hi, ~has_lo & has_hi


def _to_bounded(z, lo, hi):
    box, only_lo, only_hi = _kinds(lo, hi)
    lo_, hi_ = jnp.where(jnp.isfinite(lo), lo, 0.0), jnp.where(jnp.isfinite(hi), hi, 0.0)
    width = jnp.where(box, hi_ - lo_, 1.0)
    x = jnp.where(box, lo_ + width * jax.nn.sigmoid(z), z)
    x = jnp.where(only_lo, lo_ + jax.nn.softplus(z), x)
    return jnp.where(only_hi, hi_ - jax.nn.softplus(z), x)


def _inverse_softplus(y):
    y = jnp.maximum(y, 1e-300)
    return y + jnp.log(-jnp.expm1(-y))


def _to_unconstrained(x, lo, hi):
    box, only_lo, only_hi = _kinds(lo, hi)
    lo_, hi_ = jnp.where(jnp.isfinite(lo), lo, 0.0), jnp.where(jnp.isfinite(hi), hi, 0.0)
    # the logit of (x - lo) / (hi - lo) as the log of the two gaps (that ratio, clipped to
    # [1e-12, 1 - 1e-12], moved a start of 1e-4 in [0, 1e9] to 1e-3)
    tiny = jnp.finfo(jnp.result_type(x, float)).tiny
    below, above = jnp.maximum(x - lo_, tiny), jnp.maximum(hi_ - x, tiny)
    z = jnp.where(box, jnp.log(below) - jnp.log(above), x)
    z = jnp.where(only_lo, _inverse_softplus(x - lo_), z)
    return jnp.where(only_hi, _inverse_softplus(hi_ - x), z)
