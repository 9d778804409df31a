"""Parameters of which some cases run only in the slow suite (``pytest -m slow``)."""

import pytest


def marked_slow(names, slow):
    """``names`` as pytest parameters, those in ``slow`` marked slow."""
    return [pytest.param(n, marks=pytest.mark.slow) if n in slow else n for n in names]
