"""The jit of the package's compiled entry points: ``equinox.filter_jit`` with XLA
compiler options chosen by measurement.

XLA's CPU backend has two code generators for fused elementwise loops; the newer
("fusion emitters") compiles this package's programs -- thousands of scalar operations
of the position analysis and its derivatives -- more slowly, and runs them no faster
(vmapped simulations 2.5x slower); and it hands larger operations to a library
(YNNPACK), whose calls cost more than these programs' small arrays gain. Measured by
``benchmarks/bench_compile_options.py`` (results/compile_options.json). The options apply
to these programs only: the rest of a user's JAX session is left as it is.
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax._src import core as _jax_core

try:  # JAX's tracer of a vmap being traced (see any_mapped)
    from jax._src.interpreters.batching import BatchTracer as _BatchTracer
except ImportError:  # another JAX: every value counts as mapped, and none is flattened
    _BatchTracer = None

try:
    from jax._src.lib import version as _jaxlib_version
except ImportError:  # a JAX without it: take it as older than the library fusions below
    _jaxlib_version = (0, 0, 0)

# From jaxlib 0.8.1 on, XLA's CPU backend hands some larger elementwise operations and
# reductions to the YNNPACK library, each a call costing ~10-20 us more than XLA's own loop:
# the friction law's (K, K, 2) arrays in a mechanism with many friction elements (the
# strandbeest with friction in its 73 joints: one step 1.2-1.3 -> 1.0 ms). Turned off (an
# empty list of library fusion kinds); before 0.8.1 there is no such option.
NO_LIBRARY_FUSIONS = {"xla_cpu_experimental_ynn_fusion_type": ""} if tuple(_jaxlib_version) >= (0, 8, 1) else {}
COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False, **NO_LIBRARY_FUSIONS}

# Machine code optimized less (LLVM at -O0: fast instruction selection, no IR passes): XLA's
# code generation of the L-BFGS synthesis program 2.0 -> 0.7 s, its runs 4-5x slower. For
# programs compiled once and run briefly (see ``synthesis.optimize``'s ``compile_mode``).
QUICK_OPTIONS = {**COMPILER_OPTIONS, "xla_backend_optimization_level": 0}


def add_xla_flag(flag: str, setting: str) -> None:
    """Append ``flag`` to ``XLA_FLAGS`` unless it already names ``setting`` (the user's own
    value stands). XLA reads the variable once per process, when JAX first compiles."""
    flags = os.environ.get("XLA_FLAGS", "")
    if setting not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {flag}".strip()


# XLA's CPU runtime runs a loop's calls across threads once an array the loop carries passes
# this many bytes: the integration's stages (dynamics/_packed.py), the friction solve's
# reactions and its consistency bound's slopes (_friction.py) keep their arrays under it
THREADED_BYTES = 512


def stays_unthreaded(doubles: int) -> bool:
    """Whether an array of that many float64 values stays under THREADED_BYTES."""
    return 8 * doubles <= THREADED_BYTES


# XLA's CPU backend compiles a while loop that touches few bytes per iteration into one
# function instead of running its operations one at a time; a simulation's integration loop
# is over the default threshold. Above it, a compiled simulation runs 1.5-8x faster
# (benchmarks/bench_fast_loops.py). An XLA flag, read once per process at its first
# compile: offered (enable_fast_loops), never set for the user.
FAST_LOOPS_SETTING = "xla_cpu_small_while_loop_byte_threshold"
FAST_LOOPS_FLAG = f"--xla_backend_extra_options={FAST_LOOPS_SETTING}=1000000000"


def fast_loops() -> bool:
    """Whether this process runs with the threshold of :func:`enable_fast_loops` set."""
    return FAST_LOOPS_SETTING in os.environ.get("XLA_FLAGS", "")


def enable_fast_loops() -> None:
    """Let XLA compile each simulation's integration loop into one function: compiled
    simulations run 1.5-8x faster on a CPU without friction, 2-5x with it (single runs
    and batches); first calls take about as long without friction, 1.4-2x longer with it. Worth it
    where one compiled program runs many times (sweeps, synthesis, interactive use).
    Process-wide: it sets an XLA flag that JAX reads at its first computation, so call it
    right after ``import assurjax``, before anything runs (else
    :class:`assurjax.AssurjaxError`; restart the kernel). The dense systems of a right-hand
    side (friction's Newton fallback, a triad's statics) then solve without LAPACK, which
    would keep the loop out. Same as starting Python with
    ``XLA_FLAGS=--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000``.

    >>> import assurjax
    >>> assurjax.enable_fast_loops()
    """
    from ._errors import AssurjaxError

    if fast_loops():
        return
    try:
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:  # a JAX without it: the flag still applies if nothing has run yet
        backends_are_initialized = lambda: False  # noqa: E731
    if backends_are_initialized():
        raise AssurjaxError("enable_fast_loops() comes too late: JAX has already run a computation in this process and "
                            "reads XLA's flags only once; call it right after `import assurjax` (restart the kernel)")
    add_xla_flag(FAST_LOOPS_FLAG, FAST_LOOPS_SETTING)


def at_top_level() -> bool:
    """True outside any jit, vmap or grad trace: JAX takes compiler options only there."""
    try:
        return _jax_core.trace_state_clean()
    except AttributeError:  # a JAX without this helper: stay on the safe side
        return False


def jit(fun=None, *, compiler_options: dict = COMPILER_OPTIONS, **kwargs):
    """``equinox.filter_jit`` that compiles with ``compiler_options`` (default
    :data:`COMPILER_OPTIONS`) when called at the top level and is an ordinary nested jit
    inside a user's own ``jit``/``vmap``/``grad``. Usable as a decorator; other keyword
    arguments go to ``equinox.filter_jit``."""
    if fun is None:
        return lambda f: jit(f, compiler_options=compiler_options, **kwargs)
    top = eqx.filter_jit(fun, compiler_options=compiler_options, **kwargs)
    nested = eqx.filter_jit(fun, **kwargs)

    @functools.wraps(fun)
    def call(*args, **kw):
        return (top if at_top_level() else nested)(*args, **kw)

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


# Programs compiled two at a time (compile_side_by_side): each compiles its machine code on
# one thread. XLA splits that work over threads by default, which on two cores only adds
# overhead when two compiles already run (Watt six-bar's first simulate(): 1.95 -> 1.8 s;
# run times the same; measured by benchmarks/bench_overhead.py).
PAIRED_OPTIONS = {**COMPILER_OPTIONS, "xla_cpu_parallel_codegen_split_count": 1}


def jit_arrays(fun, static_argnums=()):
    """``jax.jit`` with :data:`PAIRED_OPTIONS`, for top-level entry points compiled in pairs
    (:func:`compile_side_by_side`) whose arguments are pytrees of arrays (the mechanism's
    parameters are arrays; names and modes sit in the tree's structure) plus hashable
    static arguments: a call costs a flatten of the arguments, where ``equinox.filter_jit``
    partitions each one (~0.1 ms for the Watt six-bar's model, ~0.7 ms for the strandbeest's)."""
    return jax.jit(fun, static_argnums=static_argnums, compiler_options=PAIRED_OPTIONS)


def chunk_rows(n: int, most: int) -> list[np.ndarray]:
    """The indices of n rows in the fewest chunks of at most ``most`` rows, all of one size
    (the last filled with the last row): one compiled program serves every chunk."""
    size = -(-n // -(-n // most))
    return [np.minimum(np.arange(start, start + size), n - 1) for start in range(0, n, size)]


class Static:
    """The leaves of a pytree that are not arrays (functions, Python numbers), with its
    structure: a static argument of ``jax.jit``, equal for equal trees (by structure and
    leaves), so that two mechanisms of one structure share their programs."""

    def __init__(self, tree):
        leaves, self.treedef = jax.tree.flatten(tree)
        self.leaves = tuple(leaves)
        self._hash = hash((self.treedef, self.leaves))

    @property
    def tree(self):
        return jax.tree.unflatten(self.treedef, self.leaves)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, Static) and self.treedef == other.treedef and self.leaves == other.leaves


def split_arrays(tree) -> tuple:
    """(the arrays of ``tree``, the rest as a :class:`Static`): ``combine(*parts)`` rebuilds it."""
    arrays, rest = eqx.partition(tree, eqx.is_array)
    return arrays, Static(rest)


def combine(arrays, rest: Static):
    return eqx.combine(arrays, rest.tree)


def moved_leaves(primals, tangents) -> tuple:
    """For a custom jvp rule (``equinox.filter_custom_jvp``, whose tangents are None where
    nothing moves): (the leaves of ``primals`` that move, their tangents, ``rebuild``:
    those leaves' values -> ``primals`` with them in place), for ``jax.jvp`` over them alone."""
    leaves, treedef = jax.tree.flatten(primals)
    leaf_tangents = treedef.flatten_up_to(tangents)
    moved = [k for k, tangent in enumerate(leaf_tangents) if tangent is not None]

    def rebuild(values):
        at = list(leaves)
        for k, value in zip(moved, values):
            at[k] = value
        return jax.tree.unflatten(treedef, at)

    return tuple(leaves[k] for k in moved), tuple(leaf_tangents[k] for k in moved), rebuild


class FlatLayout:
    """Where :func:`flattened_floats` put a pytree's parts: per array leaf (the flat array
    it went into, its shape), or None where it stays apart; and the rest (a :class:`Static`).
    Hashable: a static argument."""

    def __init__(self, treedef, places: tuple, rest: Static):
        self.treedef, self.places, self.rest = treedef, places, rest
        self._key = (treedef, places, rest)

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, FlatLayout) and self._key == other._key

    def rebuild(self, flats: tuple, others: tuple):
        """The pytree from the ``flats`` and ``others`` of :func:`flattened_floats`. Each flat
        array is cut by one split, whose transpose is one concatenation (slices of their own
        transposed to a padded array each, summed: the quadrature gradient of the Watt six-bar
        ~10 % dearer)."""
        sizes = [[int(np.prod(place[1])) for place in self.places if place is not None and place[0] == k]
                 for k in range(len(flats))]
        parts = [iter(jax.lax.split(flat, ks)) for flat, ks in zip(flats, sizes)]
        others = iter(others)
        leaves = [next(others) if place is None else next(parts[place[0]]).reshape(place[1]) for place in self.places]
        return combine(jax.tree.unflatten(self.treedef, leaves), self.rest)


def flattened_floats(tree, flat: bool = True) -> tuple:
    """(the float64 arrays of ``tree`` in flat arrays, its other arrays, their
    :class:`FlatLayout`): a region's loop-invariant arguments as one or two operands. Its
    kernel is handed a pointer per operand at every call (the press's frictionless vector
    field, 27 operands: one step 3.2-3.3 -> 2.9 us with the model's flat); XLA makes
    the flat arrays once, outside the integration's loops, where their parts do not change.
    Weakly typed arrays (a link's mass given as a number) go into a flat array of their own,
    which keeps them weak: made strong, a nested jit reading them traced again for them (the
    Watt six-bar's first simulate() 2.1 -> 2.9 s). ``flat=False``: every array apart (the
    same interface, nothing flattened; see :func:`any_mapped`)."""
    arrays, rest = split_arrays(tree)
    leaves, treedef = jax.tree.flatten(arrays)
    kinds = [None if not flat or jnp.result_type(v) != jnp.float64 else bool(getattr(v, "weak_type", False))
             for v in leaves]
    present = sorted({kind for kind in kinds if kind is not None})
    flats = tuple(jnp.concatenate([jnp.ravel(v) for v, kind in zip(leaves, kinds) if kind == weak]) for weak in present)
    places = tuple(None if kind is None else (present.index(kind), jnp.shape(v)) for v, kind in zip(leaves, kinds))
    return flats, tuple(v for v, kind in zip(leaves, kinds) if kind is None), FlatLayout(treedef, places, rest)


def any_mapped(tree) -> bool:
    """Whether an array of ``tree`` is mapped by a vmap being traced (where JAX has no tracer
    type by that name: True). Seen only outside the traced loops: a loop's body is traced
    apart from the vmap. A model mapped by a vmap (a sweep over its parameters) is not
    flattened (:func:`flattened_floats`): flat, per member, it made a sweep of 2000 Watt
    six-bars over a third of their parameters 0.36 -> 0.46 s (10 000 vmapped starts with
    the whole FieldArgs flat, q0 in it: 2.7 -> 4.3 s). A derivative taken inside the vmap
    (``jax.vmap(jax.grad(f))``) wraps the mapped values in its own tracers: their primal
    values are looked at (only they steer the loops; ``jax.jacfwd`` maps tangents alone)."""
    return any(_mapped(leaf) for leaf in jax.tree.leaves(tree))


def _mapped(value) -> bool:
    if _BatchTracer is None:
        return True
    while not isinstance(value, _BatchTracer) and isinstance(getattr(value, "primal", None), _jax_core.Tracer):
        value = value.primal
    return isinstance(value, _BatchTracer) and value.batch_dim is not None


def compile_side_by_side(first, first_args: tuple, second, second_args) -> None:
    """Compile two :func:`jit_arrays` programs that run one after the other (``second``
    takes ``second_args(output of first)``): the first in a thread while the second is
    traced and compiled. XLA compiles without holding Python's lock, so on two cores the
    second program's trace and compile hide behind the first's compile. The programs land
    in JAX's caches, where the calls that follow find them. ``first``'s outputs must not be
    weakly typed (their stand-ins here are NumPy arrays)."""
    lowered = first.lower(*first_args)  # traced here: tracing holds Python's lock
    failure = []

    def compile_first():
        try:
            lowered.compile()
        except BaseException as error:  # raised again below, in the caller's thread
            failure.append(error)

    worker = threading.Thread(target=compile_first, name="assurjax-compile")
    worker.start()
    try:
        stand_ins = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), lowered.out_info)
        second.lower(*second_args(stand_ins)).compile()
    finally:
        worker.join()
    if failure:
        raise failure[0]


# ---------------------------------------------------------------------------- regions
# XLA's CPU runtime calls each kernel of a program on its own (a few hundred instructions of
# dispatch each), and a right-hand side of this package is hundreds of small kernels. A call
# tagged ``xla_cpu_small_call`` (the tag XLA gives a small while loop it hoists) is compiled
# into one kernel instead, its loops and branches included: a region. XLA keeps such a call
# (``inlineable=false``) and compiles it with its older, whole-computation code generator,
# which (1) aborts the process on a parameter the computation does not use: every input is
# read once into an extra result, the touch, and the arguments pass an optimization barrier,
# which XLA does not fold through (else it replaces a parameter by the constant a call site
# passes, and the parameter is unused again); (2) cannot call libraries (LAPACK, host
# callbacks): a region's body takes _linalg's plain LU, and a body holding such a call runs as
# an ordinary call; (3) emits no scatter, which a gather's transpose is: a region's derivatives
# are those of the ordinary call (custom_jvp); (4) cannot call XLA's collectives (no runtime
# symbol for them in its kernel: 'Failed to materialize symbols', __xla_cpu_runtime_AllReduce):
# a vmapped region holds tests over the whole batch (a while loop's batched predicate, equinox's
# unvmap_any), each an all-reduce once XLA partitions a batch sharded over devices, so a
# sharded sweep maps each device's members on their own (_sweep._sharded_vmap, a shard_map)
# and no collective reaches a region; a user's own jit over a sharded batch takes
# ASSURJAX_REGIONS=0 or a shard_map. Past REGION_LARGEST values in an array XLA's own
# kernels do better, and the region is an ordinary call too. Verified on the XLA of the JAX
# versions below (CPU): elsewhere, or with the environment variable ASSURJAX_REGIONS=0, every
# region is an ordinary nested jit (docs/design-notes.md, "Regions").
REGIONS_SETTING = "ASSURJAX_REGIONS"
REGIONS_JAX = ((0, 10),)  # (major, minor) of the JAX versions whose XLA was verified
_SMALL_CALL = {"inlineable": "false", "xla_cpu_small_call": "true"}
# primitives that become library or host calls on a CPU: a region's kernel cannot make them
_LIBRARY_CALLS = ("lu", "lu_pivots_to_permutation", "triangular_solve", "cholesky", "cholesky_update", "eigh", "eig",
                  "svd", "qr", "geqrf", "geqp3", "householder_product", "schur", "hessenberg", "tridiagonal",
                  "tridiagonal_solve", "fft", "top_k", "custom_call", "sort")
# the most values an array inside a region may hold: a region is for many small operations;
# on larger arrays XLA's own kernels do better (the strandbeest, arrays of 274 values and with
# friction 10,804: its first simulate() 17 % and 39 % longer as a region, and no faster warm)
REGION_LARGEST = 256
_REGION_STATE = threading.local()


def regions_enabled() -> bool:
    """Whether regions compile into one kernel in this process (see above)."""
    if os.environ.get(REGIONS_SETTING, "1") == "0":
        return False
    try:
        version = tuple(int(part) for part in jax.__version__.split(".")[:2])
        return version in REGIONS_JAX and jax.default_backend() == "cpu"
    except (ValueError, RuntimeError):
        return False


def in_region() -> bool:
    """True while a region's body is traced (its linear algebra must not call LAPACK)."""
    return getattr(_REGION_STATE, "depth", 0) > 0


@contextlib.contextmanager
def _tracing_region():
    _REGION_STATE.depth = getattr(_REGION_STATE, "depth", 0) + 1
    try:
        yield
    finally:
        _REGION_STATE.depth -= 1


def _largest(jaxpr) -> int:
    sizes = [int(np.prod(v.aval.shape)) for eqn in jaxpr.eqns for v in eqn.outvars if hasattr(v.aval, "shape")]
    return max(sizes + [max((_largest(sub) for eqn in jaxpr.eqns for sub in _subjaxprs(eqn)), default=0)])


_FITS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # by the traced body's jaxpr


def _fits_region(traced) -> bool:
    """No array past REGION_LARGEST values and no library call: none in the jaxpr's primitives,
    and none in the body as lowered (a custom call, whatever primitive made it)."""
    jaxpr = traced.jaxpr.jaxpr
    if jaxpr not in _FITS:
        _FITS[jaxpr] = (_largest(jaxpr) <= REGION_LARGEST and not _holds_library_call(jaxpr)
                        and "custom_call" not in traced.lower().as_text())
    return _FITS[jaxpr]


def _holds_library_call(jaxpr) -> bool:
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name in _LIBRARY_CALLS or "callback" in name:
            return True
        for sub in _subjaxprs(eqn):
            if _holds_library_call(sub):
                return True
    return False


def _subjaxprs(eqn):
    for value in eqn.params.values():
        for item in value if isinstance(value, (tuple, list)) else (value,):
            if isinstance(item, _jax_core.ClosedJaxpr):
                yield item.jaxpr
            elif isinstance(item, _jax_core.Jaxpr):
                yield item


def region(fun):
    """``fun`` as a nested jit that XLA's CPU backend compiles into one kernel where it is
    called inside a traced program (see above); at the top level, or where regions are off,
    an ordinary :func:`jit`. Its arguments and results are pytrees (arrays and static parts)."""
    plain = jit(fun)
    outputs = {}  # the non-array part of each traced body's result, by its inputs' structure

    def body(arrays, rest: Static):
        with _tracing_region():
            out = fun(*combine(arrays, rest))
        out_arrays, outputs[rest] = split_arrays(out)
        # every input read once: the first entry of each, summed in one fusion (see above)
        firsts = [jnp.ravel(a)[0].astype(float) for a in jax.tree.leaves(arrays)]
        return out_arrays, jnp.sum(jnp.stack(firsts)) if firsts else jnp.zeros(())

    compiled = jax.jit(body, static_argnums=1)

    def arrays_of(arrays, rest: Static):  # fun's array results, by the ordinary nested jit
        return split_arrays(plain(*combine(arrays, rest)))[0]

    # derivatives by the ordinary jit: its transpose may hold operations a region's kernel
    # cannot make (a gather's transpose is a scatter)
    @functools.partial(jax.custom_jvp, nondiff_argnums=(1,))
    def tagged(arrays, rest: Static):
        # no argument a constant XLA could fold into the computation (see above)
        out_arrays, touch = compiled(jax.lax.optimization_barrier(arrays), rest)
        # the read kept beside the results (an optimization barrier: XLA keeps every operand)
        return jax.lax.optimization_barrier((out_arrays, _tag(touch)))[0]

    @tagged.defjvp
    def _(rest, primals, tangents):
        return jax.jvp(lambda a: arrays_of(a, rest), primals, tangents)

    def fits(*args) -> bool:
        """Whether a call with these arguments compiles into one kernel (see ``call``)."""
        if at_top_level() or in_region() or not regions_enabled():
            return False
        arrays, rest = split_arrays(args)
        if any(a.size == 0 for a in jax.tree.leaves(arrays)):
            return False  # an empty input has no entry to read
        return _fits_region(compiled.trace(arrays, rest))  # JAX's trace, reused by the call

    @functools.wraps(fun)
    def call(*args):
        if not fits(*args):
            return plain(*args)
        arrays, rest = split_arrays(args)
        return combine(tagged(arrays, rest), outputs[rest])

    call.fits = fits
    return call


def _tag(value):
    from jax.experimental.xla_metadata import set_xla_metadata

    return set_xla_metadata(value, **_SMALL_CALL)
