"""Functions compared by what they compute, so that a fresh but identical lambda does not recompile.

Compiled entry points (``equinox.filter_jit``) key their cache on the Python functions they
are given, by identity: ``lambda pose: pose.points["P"][0]`` written again (a notebook cell run
twice, a loop) is a new object and costs a new trace and compile. :func:`by_structure` wraps a
function so that it compares equal to another with the same code, the same defaults, the same
module globals and equal closure values (closure values that cannot be hashed, e.g. arrays,
are compared by identity: such functions still recompile, never silently reuse a wrong program).
"""

from __future__ import annotations

import functools
import types
from collections.abc import Callable


def _cell_key(value):
    """How a closure value takes part in the comparison: by value when hashable, else by identity."""
    if isinstance(value, types.FunctionType):
        return _key(value)
    if isinstance(value, StructuralFunction):
        return value._key
    try:
        hash(value)
    except TypeError:
        return ("id", id(value))
    return ("value", type(value), value)


def _key(fn: types.FunctionType):
    cells = tuple(_cell_key(c.cell_contents) for c in (fn.__closure__ or ()))
    return (fn.__code__, fn.__defaults__ and tuple(map(_cell_key, fn.__defaults__)), id(fn.__globals__), cells)


class StructuralFunction:
    """A function that compares equal to another with the same code and equal closure values."""

    def __init__(self, fn: Callable):
        self.fn = fn
        self._key = _key(fn)
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
    """``fn`` wrapped to compare by structure when it is a plain Python function (def or lambda);
    anything else (an equinox Module, a builtin, None) is returned unchanged."""
    if isinstance(fn, types.FunctionType):
        return StructuralFunction(fn)
    return fn
