"""Readable reprs of the package's modules: the values of scalars and small arrays
(``mass=1.5``, ``com=[0.15, 0.0]``, where equinox prints ``mass=weak_f64[]``), and a
long table (the links of a big mechanism, the loads of a big scene) cut to its first
entries and a count.

Only printing changes: the classes set ``__pdoc__ = value_pdoc``, the hook of
wadler_lindig (which ``equinox.Module.__repr__``, ``eqx.tree_pformat`` and ``eqx.tree_pprint``
use); the pytrees, their equality, jit and pickling are untouched. Traced arrays (under
jit or vmap) and big arrays print as equinox prints them (``f64[201]``).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import wadler_lindig as wl

SMALL_ARRAY = 8  # arrays of up to this many elements print their values
LONG_TABLE = 8  # a dict or tuple of more entries prints its first SHOWN ones and a count
SHOWN = 3


def _number(x) -> str:
    if isinstance(x, (bool, np.bool_)) or x.dtype.kind != "f":
        return str(x)
    # numpy's print precision (8 digits by default), at most the dtype's own (float32: 0.3, not 0.30000001)
    digits = min(np.get_printoptions()["precision"], np.finfo(x.dtype).precision + 1)
    text = f"{float(x):.{digits}g}"
    return text if any(c in text for c in ".ein") else text + ".0"  # 1.0, not 1: a float stays a float


def _numbers(value: np.ndarray) -> str:
    if value.ndim == 0:
        return _number(value[()])
    return "[" + ", ".join(_numbers(row) for row in value) + "]"


def _array_doc(obj) -> wl.AbstractDoc | None:
    if not isinstance(obj, (jax.Array, np.ndarray, np.generic)) or isinstance(obj, jax.core.Tracer):
        return None
    if obj.size > SMALL_ARRAY or obj.dtype.kind not in "biuf":
        return None
    try:
        value = np.asarray(obj)
    except Exception:  # e.g. a deleted (donated) buffer: leave it to the default
        return None
    return wl.TextDoc(_numbers(value))


def _more(shown: int, total: int) -> wl.AbstractDoc:
    return wl.TextDoc(f"... ({total - shown} more, {total} in all)")


def _table_doc(obj, **kwargs) -> wl.AbstractDoc | None:
    """A dict (each entry ``key: value`` on one line where the value starts), or a plain
    tuple/list of more than LONG_TABLE entries; of more than LONG_TABLE entries the first
    SHOWN and a count."""
    if isinstance(obj, dict) and len(obj) > 0:
        items = list(obj.items())
        docs = [wl.pdoc(k, **kwargs) + wl.TextDoc(": ") + wl.pdoc(v, **kwargs)
                for k, v in (items[:SHOWN] if len(items) > LONG_TABLE else items)]
        if len(items) <= LONG_TABLE:
            return wl.bracketed(begin=wl.TextDoc("{"), docs=docs, sep=wl.comma, end=wl.TextDoc("}"), indent=kwargs["indent"])
        begin, end = "{", "}"
    elif isinstance(obj, (tuple, list)) and not hasattr(obj, "_fields") and len(obj) > LONG_TABLE:
        docs = [wl.pdoc(v, **kwargs) for v in obj[:SHOWN]]
        begin, end = ("(", ")") if isinstance(obj, tuple) else ("[", "]")
    else:
        return None
    return wl.bracketed(begin=wl.TextDoc(begin), docs=docs + [_more(SHOWN, len(obj))], sep=wl.comma,
                        end=wl.TextDoc(end), indent=kwargs["indent"])


class _ValuesFirst:
    """wadler_lindig ``custom``: small arrays by value, long tables cut, then the given custom
    (equinox's: big arrays as ``f64[201]``)."""

    def __init__(self, inner, kwargs):
        self.inner, self.kwargs = inner, kwargs

    def __call__(self, obj):
        doc = _array_doc(obj)
        if doc is None:
            doc = _table_doc(obj, **self.kwargs)
        if doc is None and self.inner is not None:
            doc = self.inner(obj)
        return doc


def _with_values(kwargs: dict) -> dict:
    custom = kwargs.get("custom")
    if isinstance(custom, _ValuesFirst):
        return kwargs
    kwargs = dict(kwargs)
    kwargs["custom"] = _ValuesFirst(custom, kwargs)  # the tables' entries are printed with it too
    return kwargs


def value_pdoc(self, **kwargs) -> wl.AbstractDoc:
    """``__pdoc__`` of a dataclass (an equinox Module): its fields as equinox prints them, but
    scalars and small arrays by value and long tables cut."""
    kwargs = _with_values(kwargs)
    omit = getattr(type(self), "repr_omit", ())
    fields = [(f.name, getattr(self, f.name, None)) for f in dataclasses.fields(self) if f.repr and f.name not in omit]
    return wl.bracketed(begin=wl.TextDoc(type(self).__name__ + "("), docs=wl.named_objs(fields, **kwargs),
                        sep=wl.comma, end=wl.TextDoc(")"), indent=kwargs["indent"])
