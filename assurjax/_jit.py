"""The jit of the package's compiled entry points: ``equinox.filter_jit`` with XLA
compiler options chosen by measurement.

XLA's CPU backend has two code generators for fused elementwise loops; the newer
("fusion emitters") compiles this package's programs -- thousands of scalar operations
of the position analysis and its derivatives -- more slowly, and runs them no faster
(vmapped simulations 2.5x slower). Measured by ``benchmarks/bench_compile_options.py``
(results/compile_options.json). The options apply to these programs only: the rest of
a user's JAX session is left as it is.
"""

from __future__ import annotations

import functools

import equinox as eqx
from jax._src import core as _jax_core

COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def _at_top_level() -> bool:
    """True outside any jit, vmap or grad trace: JAX takes compiler options only there."""
    try:
        return _jax_core.trace_state_clean()
    except AttributeError:  # a JAX without this helper: stay on the safe side
        return False


def jit(fun=None, **kwargs):
    """``equinox.filter_jit`` that compiles with :data:`COMPILER_OPTIONS` when called at
    the top level and is an ordinary nested jit inside a user's own ``jit``/``vmap``/``grad``.
    Usable as a decorator; keyword arguments go to ``equinox.filter_jit``."""
    if fun is None:
        return lambda f: jit(f, **kwargs)
    top = eqx.filter_jit(fun, compiler_options=COMPILER_OPTIONS, **kwargs)
    nested = eqx.filter_jit(fun, **kwargs)

    @functools.wraps(fun)
    def call(*args, **kw):
        return (top if _at_top_level() else nested)(*args, **kw)

    return call
