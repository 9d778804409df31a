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


def _cell_key(value, active: frozenset = frozenset()):
    """How a closure value takes part in the comparison: functions by structure, tuples (an
    optax transformation is a NamedTuple of closures) item by item, other values by value
    when hashable, else by identity. ``active``: the functions whose keys are being built."""
    if isinstance(value, types.FunctionType):
        return _key(value, active)
    if isinstance(value, StructuralFunction):
        return value._key
    if isinstance(value, tuple):
        return (type(value), tuple(_cell_key(v, active) for v in value))
    try:
        hash(value)
    except TypeError:
        return ("id", id(value))
    return ("value", type(value), value)


def _key(fn: types.FunctionType, active: frozenset = frozenset()):
    if id(fn) in active:  # a closure that holds itself (a recursive inner function): its code stands for it
        return ("recursive", fn.__code__)
    active = active | {id(fn)}
    cells = tuple(_cell_key(c.cell_contents, active) for c in (fn.__closure__ or ()))
    defaults = fn.__defaults__ and tuple(_cell_key(d, active) for d in fn.__defaults__)
    return (fn.__code__, defaults, id(fn.__globals__), cells)


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


def transformation_by_structure(method):
    """An optax ``GradientTransformation`` (a NamedTuple of closures: ``optax.adam(0.1)``
    built anew in a cell run again) with its functions compared by structure; a factory
    (``optax.adam``) or anything else unchanged."""
    if isinstance(method, tuple) and hasattr(method, "_replace") and {"init", "update"} <= set(method._fields):
        return method._replace(init=by_structure(method.init), update=by_structure(method.update))
    return method
