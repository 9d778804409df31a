"""The public names and the API reference agree."""

from __future__ import annotations

import re
import types
from pathlib import Path

import assurjax

API = Path(__file__).resolve().parents[1] / "docs" / "api"


def test_every_public_name_has_an_entry_in_the_api_reference():
    """__all__ lists what the package's own imports export, and each has a '::: assurjax.X'
    entry (JointFriction, SlideFriction, inverse_dynamics, Sketch and RESULTS had none)."""
    exported = {name for name, value in vars(assurjax).items() if not name.startswith("_")
                and not isinstance(value, types.ModuleType) and getattr(value, "__module__", "").startswith("assurjax")}
    assert exported <= set(assurjax.__all__)
    assert all(hasattr(assurjax, name) for name in assurjax.__all__)
    text = "\n".join(page.read_text() for page in API.glob("*.md"))
    documented = set(re.findall(r"^::: assurjax\.(\w+)", text, flags=re.M))
    assert set(assurjax.__all__) - documented == set()
