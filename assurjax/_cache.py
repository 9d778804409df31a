"""JAX's persistent compilation cache, for the command line and notebooks.

Compiling a simulation takes seconds (the second-order position analysis inlined in
the solver's stages, outputs and events); the compiled program depends only on the
mechanism's structure and the settings, so later processes can load it from disk.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

MIN_COMPILE_SECONDS = 0.3  # cache what took longer than this to compile


def default_cache_dir() -> Path:
    """``$ASSURJAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/assurjax/jax`` (``~/.cache/assurjax/jax``)."""
    if os.environ.get("ASSURJAX_CACHE_DIR"):
        return Path(os.environ["ASSURJAX_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "assurjax" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Keep compiled simulations on disk so that a new process (a restarted notebook
    kernel, the next ``assurjax run``) loads them instead of compiling again.

    ``path``: the cache directory (default :func:`default_cache_dir`). Returns it.
    Global to the process (it sets JAX's ``jax_compilation_cache_dir``).
    """
    directory = Path(path) if path is not None else default_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return directory
