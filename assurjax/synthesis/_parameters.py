"""Parameters of a mechanism (or scene) as one flat vector, and derivatives with respect to them.

A :class:`assurjax.Mechanism` is an equinox Module whose arrays are its
parameters: point coordinates (m), centres of mass (m), masses (kg), inertias
(kg m^2), guide directions and offsets; a Scene adds gravity and load values.
``select`` picks some of them (a function returning nodes of the pytree, as for
``eqx.tree_at``); by default every floating-point array is a parameter.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .._errors import AssurjaxError
from .._trees import SelectionError, picked, replace_selected, stand_ins


def _selected(tree: Any, select: Callable | None):
    """(selected parameters as a pytree, function putting such a pytree back into ``tree``)."""
    if select is None:
        params, static = eqx.partition(tree, eqx.is_inexact_array)
        return params, lambda p: eqx.combine(p, static)
    try:
        params = select(tree)
    except (KeyError, AttributeError, IndexError) as e:
        raise AssurjaxError(f"select: the selection does not exist in this mechanism or scene ({type(e).__name__}: {e})") from None
    for leaf in jax.tree.leaves(params):
        if not eqx.is_inexact_array(leaf):
            raise AssurjaxError(f"select: every selected parameter must be a floating-point array, got {type(leaf).__name__}")
    # put back in the tree's own order of links and points: eqx.tree_at read the selection on a
    # copy rebuilt in alphabetical order (the press's masses by m.links.values(): rod's and ram's swapped)
    def put_back(p):
        return replace_selected(select, tree, lambda _: jax.tree.leaves(p))

    try:  # the selection put back once: it must name whole arrays of the tree
        put_back(params)
    except (TypeError, ValueError, SelectionError) as e:
        raise AssurjaxError("select must pick whole arrays of the mechanism or scene (a point, a mass), not parts or "
                            "copies of them (e.g. m.ground['D'][0]: select m.ground['D'], and keep a coordinate "
                            f"with Design's fixed=) ({type(e).__name__}: {e})") from None
    return params, put_back


def flatten_parameters(tree: Any, *, select: Callable | None = None) -> tuple[jax.Array, Callable[[jax.Array], Any]]:
    """The selected parameters as one flat vector, and ``unflatten(vector) -> tree``.

    **Example:**
    >>> theta, rebuild = flatten_parameters(mech, select=lambda m: m.links["link4"].points["P"])
    >>> rebuild(theta + 1e-3)  # the mechanism with P moved by 1 mm along x and y
    """
    params, put_back = _selected(tree, select)
    flat, unravel = ravel_pytree(params)
    return flat, lambda v: put_back(unravel(v))


def parameter_names(tree: Any, *, select: Callable | None = None) -> list[str]:
    """A readable name for every entry of :func:`flatten_parameters`' vector,
    e.g. ``".links['link4'].points['P'][1]"``."""
    params, _ = _selected(tree, select)
    names = []
    for (path, leaf), base in zip(jax.tree_util.tree_flatten_with_path(params)[0], _selected_paths(tree, select, params)):
        shape = np.shape(leaf)
        names += [base] if not shape else [base + str(list(i)) .replace(", ", "][") for i in np.ndindex(shape)]
    return names


def _selected_paths(tree: Any, select: Callable | None, params: Any) -> list[str]:
    """Where each selected array sits in the whole tree: ``select`` run on the tree with its
    arrays replaced by their paths (found by identity, an array used in two places was named
    by the other). Without a select, or where it cannot run on stand-ins, by identity."""
    leaves = jax.tree_util.tree_flatten_with_path(params)[0]
    if select is not None:
        slots = stand_ins(tree)  # in the tree's own order (a copy rebuilt sorted named the press's rod mass 'ram')
        where = {id(s): jax.tree_util.keystr(path) for path, s in jax.tree_util.tree_flatten_with_path(slots)[0]}
        try:
            found = picked(select, slots)
        except Exception:  # noqa: BLE001 (a select that computes on its arrays: named by identity below)
            found = []
        if len(found) == len(leaves):
            return [where[id(f)] for f in found]
    where = {id(leaf): jax.tree_util.keystr(path) for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]}
    return [where.get(id(leaf), jax.tree_util.keystr(path)) for path, leaf in leaves]


def jacobian(
    fn: Callable[[Any], Any],
    tree: Any,
    *,
    select: Callable | None = None,
    mode: str = "reverse",
) -> jax.Array:
    """d fn(tree) / d parameters as an array of shape ``fn_shape + (n_parameters,)``.

    ``fn`` maps the mechanism (or scene) to an array; ``mode`` is ``"reverse"``
    (one backward pass per output entry: best for few outputs, e.g. a scalar
    objective) or ``"forward"`` (one jvp per parameter: best for few parameters,
    and the only choice through diffrax's ForwardMode adjoint). The columns follow
    :func:`parameter_names`.
    """
    flat, unflatten = flatten_parameters(tree, select=select)
    g = lambda v: jnp.asarray(fn(unflatten(v)))  # noqa: E731
    if mode == "reverse":
        return jax.jit(jax.jacrev(g))(flat)
    if mode == "forward":
        return jax.jit(jax.jacfwd(g))(flat)
    raise AssurjaxError(f"mode must be 'reverse' or 'forward', got {mode!r}")


def gradient(fn: Callable[[Any], Any], tree: Any, *, select: Callable | None = None) -> Any:
    """d fn / d parameters of a scalar ``fn``, as a pytree shaped like the selection
    (like ``eqx.filter_grad``, but for any selection)."""
    params, put_back = _selected(tree, select)
    return jax.jit(jax.grad(lambda p: fn(put_back(p))))(params)
