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

import contextlib
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


@contextlib.contextmanager
def checks_without_callbacks():
    """While a program is traced inside, equinox's runtime checks (diffrax's test that
    ``saveat`` times are sorted and inside [t0, t1]) turn a failed check into NaN
    instead of calling back into Python: JAX's persistent cache does not keep programs
    with host callbacks, and with it a new process loads a compiled simulation in
    ~1.3 s instead of compiling it for ~3 s. Use it only where the checked conditions
    are verified on the host first. Process-wide while inside (equinox reads one
    module-level setting at trace time); a no-op if equinox changes that setting's name."""
    module = eqx._errors if hasattr(eqx, "_errors") else None
    if module is None or not hasattr(module, "EQX_ON_ERROR"):
        yield
        return
    previous, module.EQX_ON_ERROR = module.EQX_ON_ERROR, "nan"
    try:
        yield
    finally:
        module.EQX_ON_ERROR = previous
