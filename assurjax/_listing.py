"""Lists of names in error messages, kept short: a mechanism may have a thousand links."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

SHOWN = 8  # names a message lists before it counts the rest


def few(names: Iterable) -> str:
    """``names`` as a list, ``['a', 'b']``; past SHOWN of them the first SHOWN and a count
    of the rest (a message listing 3000 links was 20 kB long)."""
    names = list(names)
    if len(names) <= SHOWN:
        return repr(names)
    return f"{names[:SHOWN]!r} and {len(names) - SHOWN} more"


def close_match(word: str, candidates: Iterable) -> str | None:
    """The candidate most like ``word`` (difflib's ratio at least 0.6: a misspelling, a
    plural, a letter left out), or None."""
    close = difflib.get_close_matches(word, [c for c in candidates if isinstance(c, str)], n=1)
    return close[0] if close else None


def did_you_mean(unknown: Iterable, known: Iterable) -> str:
    """A note naming, for each unknown name, the known one it most likely misspells, e.g.
    ``" ('mas': did you mean 'mass'?)"``; "" when none is close."""
    known = [k for k in known if isinstance(k, str)]
    guesses = [f"'{u}': did you mean '{m}'?" for u in unknown if isinstance(u, str) and (m := close_match(u, known)) is not None]
    return f" ({'; '.join(guesses)})" if guesses else ""
