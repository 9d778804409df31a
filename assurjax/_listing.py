"""Lists of names in error messages, kept short: a mechanism may have a thousand links."""

from __future__ import annotations

from collections.abc import Iterable

SHOWN = 8  # names a message lists before it counts the rest


def few(names: Iterable) -> str:
    """``names`` as a list, ``['a', 'b']``; past SHOWN of them the first SHOWN and a count
    of the rest (a message listing 3000 links was 20 kB long)."""
    names = list(names)
    if len(names) <= SHOWN:
        return repr(names)
    return f"{names[:SHOWN]!r} and {len(names) - SHOWN} more"
