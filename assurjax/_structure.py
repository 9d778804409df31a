"""Functions compared by what they compute, so that a fresh but identical lambda does not recompile.

Compiled entry points (``equinox.filter_jit``) key their cache on the Python functions they
are given, by identity: ``lambda pose: pose.points["P"][0]`` written again (a notebook cell run
twice, a loop) is a new object and costs a new trace and compile. :func:`by_structure` wraps a
function so that it compares equal to another with the same code and equal values of what
that code reads when traced: its closure, its defaults and the module globals it names
(functions among them compared the same way, tuples item by item, other values by value
when hashable). A JAX array or an equinox Module of immutable leaves is compared by
identity (and kept alive, so that its id is not reused). A value that can change in place
(a NumPy array, a list, a dict) makes the function compare by identity, as ``jax.jit``
would: it is never served a program traced with other values.
"""

from __future__ import annotations

import functools
import types
from collections.abc import Callable

import equinox as eqx
import jax
import numpy as np

_IMMUTABLE_LEAVES = (jax.Array, bool, int, float, complex, str, np.generic, types.FunctionType,
                     types.BuiltinFunctionType, types.MethodType)


def immutable(x) -> bool:
    """True when ``x`` cannot change after it is built: not a Module, or a Module all of
    whose leaves are immutable (a NumPy array inside could be changed in place)."""
    if not isinstance(x, eqx.Module):
        return True
    return all(isinstance(leaf, _IMMUTABLE_LEAVES) for leaf in jax.tree.leaves(x))


class _Mutable(Exception):
    """A value the function reads can change in place: compare the function by identity."""


class _Same:
    """A value compared by identity, held so that its id is not reused while a key lives."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value

    def __eq__(self, other):
        return isinstance(other, _Same) and other.value is self.value

    def __hash__(self):
        return id(self.value)


def _value_key(value, active: frozenset):
    """How a value the function reads takes part in the comparison. ``active``: the
    functions whose keys are being built (a function may reach itself)."""
    if isinstance(value, types.FunctionType):
        return _key(value, active)
    if isinstance(value, StructuralFunction):
        return value._key
    if isinstance(value, tuple):  # an optax transformation is a NamedTuple of closures
        return (type(value), tuple(_value_key(v, active) for v in value))
    if isinstance(value, (types.ModuleType, type)):
        return _Same(value)
    try:
        hash(value)
    except TypeError:
        if isinstance(value, (jax.Array, eqx.Module)) and immutable(value):
            return _Same(value)
        raise _Mutable from None
    return ("value", type(value), value)


def _cell_key(cell, active: frozenset):
    try:
        value = cell.cell_contents
    except ValueError:  # a local not yet assigned (a function defined before a name it reads)
        return ("empty",)
    return _value_key(value, active)


def _global_names(code: types.CodeType) -> set[str]:
    """The names ``code`` and the code nested in it (lambdas, comprehensions) may read as globals."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _global_names(const)
    return names


def _key(fn: types.FunctionType, active: frozenset = frozenset()):
    if id(fn) in active:  # a function that reaches itself (recursion): its code stands for it
        return ("recursive", fn.__code__)
    active = active | {id(fn)}
    cells = tuple(_cell_key(c, active) for c in (fn.__closure__ or ()))
    defaults = tuple(_value_key(d, active) for d in (fn.__defaults__ or ()))
    keyword_defaults = tuple(sorted((k, _value_key(v, active)) for k, v in (fn.__kwdefaults__ or {}).items()))
    names = fn.__globals__
    read = tuple(sorted((name, _value_key(names[name], active)) for name in _global_names(fn.__code__) if name in names))
    return (fn.__code__, defaults, keyword_defaults, id(names), cells, read)


class StructuralFunction:
    """A function that compares equal to another with the same code and equal values of what
    it reads (closure, defaults, the globals it names); by identity where one can change in place."""

    def __init__(self, fn: Callable):
        self.fn = fn
        try:
            self._key = _key(fn)
        except _Mutable:
            self._key = ("identity", _Same(fn))
        functools.update_wrapper(self, fn)

    def __call__(self, *args, **kwargs):
        return self.fn(*args, **kwargs)

    def __eq__(self, other):
        return isinstance(other, StructuralFunction) and self._key == other._key

    def __hash__(self):
        return hash(self._key)

    def __repr__(self):
        return f"by_structure({self.fn!r})"


def by_structure(fn):
    """``fn`` wrapped to compare by structure when it is a plain Python function (def or lambda),
    item by item when it is a NamedTuple (an optax ``GradientTransformation`` is one of
    closures: ``optax.adam(0.1)`` built again in a cell run twice); anything else (an equinox
    Module, a builtin, None) is returned unchanged."""
    if isinstance(fn, types.FunctionType):
        return StructuralFunction(fn)
    if isinstance(fn, tuple) and hasattr(fn, "_fields"):
        return type(fn)(*map(by_structure, fn))
    return fn
