"""Shared fixtures. Keep this small: helpers that only one test file needs live in that file."""

import os
import textwrap

import numpy as np
import pytest

import assurjax

# The command line keeps compiled programs on disk by default; tests leave no files behind.
os.environ.setdefault("ASSURJAX_NO_CACHE", "1")


@pytest.fixture
def rng():
    """A seeded generator: random inputs that are the same on every run."""
    return np.random.default_rng(20240501)


@pytest.fixture(scope="session")
def roberts_scene():
    return assurjax.load_scene("roberts")


@pytest.fixture
def write_scene(tmp_path):
    """Write a TOML scene given as a (dedented) string; returns its path."""

    def write(text: str, name: str = "scene.toml"):
        path = tmp_path / name
        path.write_text(textwrap.dedent(text))
        return path

    return write
