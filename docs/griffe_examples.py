"""Griffe extension for the API reference: the docstrings' doctest-style examples
(lines starting with ``>>>`` or ``...``) become fenced Python code blocks, so they are
shown as code and their brackets are not read as Markdown links."""

from __future__ import annotations

import griffe


def fence_examples(text: str) -> str:
    """Wrap every run of ``>>>``/``...`` lines (and their indented output) in ```python fences."""
    out, inside = [], False
    for line in text.splitlines():
        stripped = line.lstrip()
        is_code = stripped.startswith((">>>", "..."))
        if is_code and not inside:
            out.append("```python")
            inside = True
        elif inside and not is_code:
            out.append("```")
            inside = False
        out.append(stripped[4:] if is_code and len(stripped) > 3 and stripped[3] == " " else (stripped[3:] if is_code else line))
    if inside:
        out.append("```")
    return "\n".join(out)


class FenceExamples(griffe.Extension):
    def on_object(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = fence_examples(obj.docstring.value)
