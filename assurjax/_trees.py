"""Pytree maps that keep every dict's key order.

JAX flattens a dict in sorted key order and rebuilds it in that order, so
``jax.tree.map`` (and ``eqx.tree_at``, ``eqx.partition``, ``eqx.combine``, which
go through it) return a Mechanism whose ``links``, ``ground`` and points are in
alphabetical order, whatever the order they were given in. A selection read on
the mechanism as given (``tuple(link.mass for link in m.links.values())``) and
put back into such a rebuilt copy is then paired with other links. The maps here
rebuild every plain dict in the key order of the first tree they map over, and
:func:`replace_selected` reads the selection on the tree in that order too.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import jax


def _is_dict(x) -> bool:
    return type(x) is dict


def map_keep_order(f: Callable, tree: Any, *rest: Any) -> Any:
    """``jax.tree.map(f, tree, *rest)`` with every dict rebuilt in ``tree``'s key order (the
    other trees' dicts are read by key)."""

    def node(x, *xs):
        if _is_dict(x):
            return {k: map_keep_order(f, v, *(y[k] for y in xs)) for k, v in x.items()}
        return f(x, *xs)

    return jax.tree.map(node, tree, *rest, is_leaf=_is_dict)


class _Slot:
    """One leaf of a tree, standing in for it while a selection is read (a unique object:
    two equal arrays, or one array object met twice, are told apart)."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


class SelectionError(Exception):
    """``select`` did not return whole leaves of the tree (its message says how)."""


def stand_ins(tree: Any) -> Any:
    """``tree`` with every leaf replaced by a unique stand-in (dicts in ``tree``'s order)."""
    return map_keep_order(_Slot, tree)


def picked(select: Callable[[Any], Any], slots: Any) -> list:
    """The stand-ins that ``select`` returns from :func:`stand_ins`' tree, in
    ``jax.tree.leaves`` order; :class:`SelectionError` for anything else, or one picked twice."""
    found = jax.tree.leaves(select(slots))
    if not all(isinstance(s, _Slot) for s in found):
        raise SelectionError("select must return parts of the tree itself (whole arrays, e.g. m.links['rod'].mass), "
                             "not values computed from them")
    if len({id(s) for s in found}) != len(found):
        raise SelectionError("select returns the same array more than once")
    return found


def replace_selected(select: Callable[[Any], Any], tree: Any, new: Callable[[list], list],
                     others: Callable[[Any], Any] = lambda x: x) -> Any:
    """``tree`` with the leaves that ``select(tree)`` returns replaced, in ``tree``'s own key order.

    ``new``: the selected leaves (in the order ``jax.tree.leaves(select(tree))`` gives them)
    -> their replacements, as many; ``others`` maps every leaf not selected. ``select`` is
    called once, on a copy of ``tree`` whose leaves are stand-ins: it must pick parts of the
    tree by its structure (names, fields, positions), not by values. Raises the exceptions
    ``select`` raises, and :class:`SelectionError` when it returns anything but distinct
    leaves of the tree.
    """
    slots = stand_ins(tree)
    found = picked(select, slots)
    values = list(new([s.value for s in found]))
    if len(values) != len(found):
        raise SelectionError(f"{len(values)} replacements for {len(found)} selected arrays")
    chosen = {id(s): i for i, s in enumerate(found)}
    return map_keep_order(lambda s: values[chosen[id(s)]] if id(s) in chosen else others(s.value), slots)


def with_field(module: Any, name: str, value: Any) -> Any:
    """A copy of an equinox module with one field replaced, its other fields the same objects
    (eqx.tree_at cannot reach a field that is None where others are: None is one object)."""
    out = copy.copy(module)
    object.__setattr__(out, name, value)
    return out
