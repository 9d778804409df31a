"""A small cache of what ``simulate()`` derives from its scene and options alone.

A warm ``simulate()`` runs its compiled program in well under a millisecond; rebuilding
and re-checking the Model, re-validating the settings and rebuilding a table on every
call cost several times that. Entries are keyed by the options' values (with their types:
``1``, ``1.0`` and ``True`` are equal keys but not equally valid settings) and by the
identity of the objects given (scene, mechanism, loads, table, event functions). Objects
keyed by identity are kept alive by their entry, so that their ``id`` stays theirs, and an
equinox Module is keyed only when every leaf is immutable (jax arrays, numbers, strings,
functions): a frozen Module of such leaves cannot change after it is built. Anything else
(a NumPy array, a mutable leaf, an object of another kind) makes the call uncacheable: it
then takes the full path every time.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping

import equinox as eqx
import jax
import numpy as np

from .._structure import immutable

MAX_ENTRIES = 64  # distinct (scene, options) combinations kept; the least recently used goes first

_ATOMS = (type(None), type(...), bool, int, float, complex, str)


class _Unkeyable(Exception):
    pass


class CallCache:
    """Values computed from a key (see :func:`call_key`), least recently used dropped first."""

    def __init__(self, max_entries: int = MAX_ENTRIES):
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self.max_entries = max_entries

    def get(self, values: tuple, compute):
        """``compute()``, or its value from an earlier call with the same ``values``."""
        key, refs = call_key(values)
        if key is None:
            return compute()
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
        if entry is not None and all(a is b for a, b in zip(entry[0], refs)):
            return entry[1]
        value = compute()  # raises for bad input: nothing is stored
        if all(immutable(r) for r in refs):
            with self._lock:
                self._entries[key] = (refs, value)
                while len(self._entries) > self.max_entries:
                    self._entries.popitem(last=False)
        return value

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)


def call_key(values: tuple) -> tuple[tuple | None, list]:
    """(a hashable key of ``values``, the objects in it keyed by identity), or (None, [])
    when some value cannot be keyed."""
    refs: list = []
    try:
        return tuple(_frozen(v, refs) for v in values), refs
    except _Unkeyable:
        return None, []


def _frozen(x, refs: list):
    if type(x) in _ATOMS or isinstance(x, np.generic):
        return type(x), x
    if type(x) in (tuple, list):
        return type(x), tuple(_frozen(v, refs) for v in x)
    if isinstance(x, Mapping):  # a scene's read-only settings tables (their values may be lists)
        return dict, tuple(sorted((k, _frozen(v, refs)) for k, v in x.items()))
    if isinstance(x, (eqx.Module, jax.Array)) or callable(x):
        refs.append(x)
        return "id", id(x)
    raise _Unkeyable
