"""Batches of mechanisms: stacking, random perturbation, vmapped kinematics, chunked sweeps and sharding.

Batch convention: a *batch of mechanisms* is one :class:`Mechanism` (or any
equinox pytree, e.g. a Scene) whose every array leaf carries a leading batch
axis of the same size; the static structure (groups, names, modes) is shared.
``stack_mechanisms`` and ``perturb`` build such batches; ``eqx.filter_vmap``
maps over them.

Scale: :func:`sweep` runs a function over a batch of any size in chunks (a host
loop, with a progress bar), so memory stays bounded by the chunk size; each
chunk's results are either written into preallocated numpy arrays or reduced.
With ``mesh=`` every chunk is split along its batch axis over the devices of a
:class:`jax.sharding.Mesh` (``NamedSharding(mesh, PartitionSpec("batch"))``);
the jitted function then runs on all devices at once, each device on its own
members (a ``shard_map`` of the vmapped function: no communication between devices).

Multi-host: call ``jax.distributed.initialize()`` on every process first, then
build the mesh over ``jax.devices()`` (all processes' devices) with
:func:`batch_mesh`; every process runs the same :func:`sweep` call. Results are
gathered to every host by ``np.asarray`` only for fully addressable arrays, so
on several hosts pass ``reduce=`` (a per-chunk reduction) or keep chunks per
host (``jax.make_array_from_process_local_data``); see the JAX guide on
multi-process computation.
"""

from __future__ import annotations

import numbers
import sys
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._errors import AssurjaxError
from ._listing import few
from ._jit import jit
from ._kinematics import Kinematics, _kinematics_batch
from ._mechanism import Mechanism, value_fields
from ._model import Model, check_has_inertia
from ._trees import SelectionError, map_keep_order, replace_selected
from ._values import check_state_count, check_value, check_values, value_problem

BATCH_AXIS = "batch"
MAX_COPIES = 10_000_000  # perturb: a batch of the Watt six-bar this large holds ~2.4 GB of arrays


# --------------------------------------------------------------------------- building batches


def stack_mechanisms(mechanisms: Sequence[Any]) -> Any:
    """Stack mechanisms (or scenes) of one structure into one batch (leading axis on every array).

    Raises :class:`AssurjaxError` when the structures differ (other groups,
    names or modes), naming the first mismatching index. Arrays are stacked by name;
    the batch keeps item 0's order of links and points.
    """
    mechanisms = list(mechanisms)
    if not mechanisms:
        raise AssurjaxError("stack_mechanisms: empty sequence")
    for i, m in enumerate(mechanisms):  # a number was returned as the "batch" ([1, 2] gave 1)
        if not isinstance(m, eqx.Module):
            raise AssurjaxError(f"stack_mechanisms: item {i} is {type(m).__name__} {m!r:.40}, not an assurjax Mechanism "
                                "(or Scene)")
    for i, m in enumerate(mechanisms):
        difference = structure_difference(m, mechanisms[0])
        if difference is None and _structure(m) != _structure(mechanisms[0]):  # stacked as one tree: names too
            difference = "its name or its order of points differs"
        if difference is not None:
            raise AssurjaxError(f"stack_mechanisms: item {i} has a different structure than item 0: {difference}")
    # by name, in item 0's order (eqx.combine of the partitioned arrays rebuilt every dict sorted)
    return map_keep_order(lambda x, *xs: jnp.stack([jnp.asarray(y) for y in (x, *xs)]) if eqx.is_array(x) else x,
                          *mechanisms)


def structure_difference(candidate: Any, reference: Any) -> str | None:
    """What differs between the static structures of ``candidate`` and ``reference`` (mechanisms,
    scenes or batches of them: the batch axis does not count), in words, or None."""
    if isinstance(candidate, Mechanism) and isinstance(reference, Mechanism):
        for what, names in (("groups", lambda m: m.group_names), ("links", lambda m: tuple(sorted(m.links))),
                            ("points", lambda m: tuple(sorted(m.point_names)))):
            if names(candidate) != names(reference):
                return f"its {what} are {few(names(candidate))}, not {few(names(reference))}"
        for g, h in zip(candidate.groups, reference.groups):
            if _structure(g) != _structure(h):
                return f"{g.describe()} differs from {h.describe()} (its kind, links, joints or mode)"
        # the mechanism's name is a label: a batch built from a sketch runs under a scene of another name
        same = _structure((candidate.ground, candidate.links)) == _structure((reference.ground, reference.links))
        return None if same else "its links carry other points"
    if _structure(candidate) != _structure(reference):
        return "its groups, links, points or modes differ"
    return None


def _structure(tree: Any) -> tuple:
    """The tree structures of the arrays and of the rest (names, modes) of ``tree``."""
    arrays, static = eqx.partition(tree, eqx.is_array)
    return jax.tree.structure(arrays), jax.tree.structure(static)


def broadcast_batch(mechanism: Any, n: int) -> Any:
    """``n`` copies of one mechanism as a batch (every array gets a leading axis of size ``n``)."""
    return map_keep_order(lambda x: _broadcast(x, n), mechanism)


def _broadcast(x, n: int):
    return jnp.broadcast_to(x, (n,) + jnp.shape(x)) if eqx.is_array(x) else x


def batch_size(batch: Any) -> int:
    """The common leading-axis size of every array of a batch."""
    sizes = {np.shape(x)[0] if np.ndim(x) else None for x in jax.tree.leaves(batch) if eqx.is_array(x) or isinstance(x, np.ndarray)}
    if len(sizes) != 1 or None in sizes:
        raise AssurjaxError(f"not a batch: every array needs the same leading batch axis, found leading sizes {sorted(map(str, sizes))}")
    return sizes.pop()


def check_batch_values(mechanisms: Mechanism, where: str) -> None:
    """Finite points, and finite non-negative masses and inertias, in every member of a batch
    of mechanisms (a stacked one is built past the Mechanism's own checks: a NaN mass set by
    ``eqx.tree_at`` ran as a solver failure, a negative one until the step budget ran out)."""
    def check(what: str, x, **ranges):
        if value_problem(x, **ranges) is None:
            return
        member = next(i for i in range(np.shape(x)[0]) if value_problem(np.asarray(x)[i], **ranges) is not None)
        raise AssurjaxError(f"{where}: batch member {member}: {what} {value_problem(np.asarray(x)[member], **ranges)}")

    for what, value, _, ranges in value_fields(mechanisms):  # the shapes carry the batch's axis
        check(what, value, **ranges)


def take(batch: Any, index) -> Any:
    """Item ``index`` (or a slice) of a batch."""
    return map_keep_order(lambda x: x[index] if eqx.is_array(x) or isinstance(x, np.ndarray) else x, batch)


def point_coordinates(mechanism: Mechanism):
    """Default selection for :func:`perturb`: every ground and link point coordinate (m)."""
    return (mechanism.ground, *(link.points for link in mechanism.links.values()))


def perturb(
    mechanism: Any,
    key: jax.Array,
    n: int,
    *,
    relative: float = 0.05,
    absolute: float = 0.0,
    select: Callable[[Any], Any] | None = None,
) -> Any:
    """A batch of ``n`` randomly perturbed copies of ``mechanism``.

    Every selected array ``x`` becomes ``x * (1 + relative * u1) + absolute * u2``
    with ``u1``, ``u2`` independent and uniform in [-1, 1]; unselected arrays are
    broadcast. ``select`` picks a pytree of arrays (default: every point
    coordinate, so every link length moves by up to about ``relative``).
    Perturbed copies may fail to assemble: check ``Kinematics.ok``. ``n``: at most
    10 million. ``select`` is read on the mechanism as given (a selection by position,
    ``tuple(link.mass for link in m.links.values())``, follows its order of links) and
    must return whole arrays of it; the batch keeps that order.
    """
    if not (isinstance(n, numbers.Integral) and 0 < n <= MAX_COPIES):
        raise AssurjaxError(f"perturb: n must be a positive integer, at most {MAX_COPIES}, got {n!r}")
    for name, spread in (("relative", relative), ("absolute", absolute)):  # half-widths of uniform spreads
        check_value(AssurjaxError, f"perturb: {name}", spread, shape=(), nonnegative=True)
    if not isinstance(mechanism, Mechanism) and select is None:
        raise AssurjaxError(f"perturb: expected an assurjax.Mechanism (a scene's: scene.mechanism), got "
                            f"{type(mechanism).__name__}; other pytrees need a select")
    if not (isinstance(key, jax.Array) and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
            or np.shape(key) == (2,) and jnp.issubdtype(jnp.result_type(key), jnp.unsignedinteger)):
        raise AssurjaxError(f"perturb: key must be a JAX random key (jax.random.key(0) or jax.random.PRNGKey(0)), got {key!r}")
    select = point_coordinates if select is None else select
    try:
        select(mechanism)
    except (KeyError, AttributeError, IndexError, TypeError) as e:
        raise AssurjaxError(f"perturb: select failed on the mechanism ({type(e).__name__}: {e})") from None

    def perturbed(leaves):
        keys = jax.random.split(key, 2 * len(leaves))
        new = []
        for i, x in enumerate(leaves):
            x = jnp.asarray(x, dtype=float)
            u1 = jax.random.uniform(keys[2 * i], (n,) + x.shape, minval=-1.0, maxval=1.0, dtype=x.dtype)
            u2 = jax.random.uniform(keys[2 * i + 1], (n,) + x.shape, minval=-1.0, maxval=1.0, dtype=x.dtype)
            new.append(x * (1.0 + relative * u1) + absolute * u2)
        return new

    # the selection is read and put back on the mechanism in its own order of links and points:
    # eqx.tree_at read it on a copy rebuilt in alphabetical order, and put the values read here
    # on other links (the press's rod and ram swapped masses, strandbeest's links their points)
    try:
        return replace_selected(select, mechanism, perturbed, others=lambda x: _broadcast(x, n))
    except (SelectionError, KeyError, AttributeError, IndexError, TypeError) as e:
        raise AssurjaxError(f"perturb: select must return whole arrays of the mechanism, picked by name or position "
                            f"(e.g. m.links['rod'].mass), not values computed from them ({type(e).__name__}: {e})") from None


# --------------------------------------------------------------------------- sharding


def batch_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-axis mesh named ``"batch"`` over ``devices`` (default: every device of every process)."""
    devices = jax.devices() if devices is None else list(devices)
    return Mesh(np.asarray(devices), (BATCH_AXIS,))


def shard_batch(batch: Any, mesh: Mesh) -> Any:
    """Place a batch on ``mesh``, split along its leading axis (which must divide by the device count)."""
    sharding = NamedSharding(mesh, PartitionSpec(BATCH_AXIS))
    n = batch_size(batch)
    if n % mesh.size:
        raise AssurjaxError(f"shard_batch: batch size {n} is not a multiple of the {mesh.size} devices of the mesh")
    return map_keep_order(lambda x: jax.device_put(x, sharding) if eqx.is_array(x) or isinstance(x, np.ndarray) else x, batch)


# --------------------------------------------------------------------------- chunked sweeps


def _progress_bar(total: int, progress: bool | None, desc: str, unit: str = "item"):
    """A tqdm bar; by default (``progress=None``) shown only when stderr is a terminal."""
    from tqdm.auto import tqdm

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, disable=disable, desc=desc, unit=unit)


def _pad(chunk: Any, size: int) -> Any:
    """Pad a chunk to ``size`` items by repeating its last item (one compiled shape for every chunk)."""

    def pad(x):
        if not (eqx.is_array(x) or isinstance(x, np.ndarray)):
            return x
        missing = size - x.shape[0]
        return x if missing == 0 else np.concatenate([np.asarray(x), np.repeat(np.asarray(x)[-1:], missing, axis=0)])

    return map_keep_order(pad, chunk)


def sweep(
    fn: Callable[[Any], Any],
    batch: Any,
    *,
    chunk_size: int | None = None,
    reduce: Callable[[Any, Any], Any] | None = None,
    mesh: Mesh | None = None,
    progress: bool | None = None,
    desc: str = "sweep",
) -> Any:
    """Apply ``fn`` to every item of ``batch`` (vmapped, jitted), ``chunk_size`` items at a time.

    **Arguments:**
    - ``fn``: item -> pytree of arrays (one item: a batch with its leading axis removed).
    - ``batch``: a pytree whose arrays share a leading batch axis (numpy arrays
      stay on the host until their chunk runs), or an int ``n``: then ``fn``
      receives the item index (an int array), e.g. to draw a random item with
      ``jax.random.fold_in(key, i)`` without materializing the batch.
    - ``chunk_size``: items per compiled call (default: all at once). The last
      chunk is padded, so one compilation serves every chunk.
    - ``reduce``: ``(carry, chunk_result) -> carry`` folded on the host over the
      chunks (carry starts as None); the sweep returns the final carry. Without it
      the results are written into preallocated numpy arrays of the full batch size.
    - ``mesh``: shard every chunk's batch axis over this mesh's devices
      (``chunk_size`` is rounded up to a multiple of the device count).
    - ``progress``: tqdm bar (default: only when stderr is a terminal).
    """
    if not callable(fn):
        raise AssurjaxError(f"sweep: fn must be a function of one item of the batch, got {fn!r:.60}")
    if isinstance(batch, (bool, float, complex, np.floating)):
        raise AssurjaxError(f"sweep: batch must be a pytree of arrays with a leading batch axis or a whole number of "
                            f"items, got {batch!r}")
    n = int(batch) if isinstance(batch, (int, np.integer)) else batch_size(batch)
    if n <= 0:
        raise AssurjaxError(f"sweep: empty batch (size {n})")
    if chunk_size is not None and (isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer))
                                   or chunk_size <= 0):
        raise AssurjaxError(f"sweep: chunk_size must be a positive integer, got {chunk_size!r}")
    if isinstance(batch, (int, np.integer)) and chunk_size is None and n > MAX_COPIES:
        raise AssurjaxError(f"sweep: {n:,} items in one call; give a chunk_size (at most {MAX_COPIES:,} items a call)")
    size = n if chunk_size is None else min(int(chunk_size), n, MAX_COPIES)
    if mesh is not None:
        size = -(-size // mesh.size) * mesh.size
    run = _compiled_vmap(fn) if mesh is None else _sharded_vmap(fn, mesh)
    out, carry = None, None
    with _progress_bar(n, progress, desc) as bar:
        for start in range(0, n, size):
            stop = min(start + size, n)
            if isinstance(batch, (int, np.integer)):
                chunk = np.arange(start, start + size)  # padded indices beyond n are computed and dropped
            else:
                chunk = _pad(take(batch, slice(start, stop)), size)
            if mesh is not None:
                chunk = shard_batch(chunk, mesh)
            result = jax.tree.map(lambda x: np.asarray(x)[: stop - start], run(chunk))
            if reduce is not None:
                carry = reduce(carry, result)
            else:
                if out is None:
                    _check_results_size(n, result)
                    out = jax.tree.map(lambda x: np.empty((n,) + x.shape[1:], x.dtype), result)
                jax.tree.map(lambda o, r: o.__setitem__(slice(start, stop), r), out, result)
            bar.update(stop - start)
    return carry if reduce is not None else out


RESULTS_BYTES_LIMIT = 2**34  # a sweep's results, kept whole on the host (without reduce)


def _check_results_size(n: int, chunk_result) -> None:
    per_item = sum(x[:1].nbytes for x in jax.tree.leaves(chunk_result) if np.ndim(x))
    if n * per_item > RESULTS_BYTES_LIMIT:
        raise AssurjaxError(f"sweep: {n:,} items of {per_item:,} bytes of results each would need "
                            f"{n * per_item / 2**30:.3g} GiB on the host (at most {RESULTS_BYTES_LIMIT / 2**30:g}): "
                            "fold them with reduce=, or sweep fewer items a call")


_COMPILED: dict = {}


def _cached(cache: dict, key, build):
    """``cache[key]``, built by ``build()`` on the first call (an unhashable key: built every time)."""
    try:
        return cache[key]
    except (KeyError, TypeError):
        made = build()
        try:
            cache[key] = made
        except TypeError:
            pass
        return made


def _compiled_vmap(fn):
    """One jitted vmap per function object (so repeated sweeps do not retrace)."""
    return _cached(_COMPILED, fn, lambda: jit(eqx.filter_vmap(fn)))


_SHARDED: dict = {}


def _sharded_vmap(fn, mesh: Mesh):
    """One jitted ``shard_map`` of the vmapped ``fn`` over ``mesh``'s batch axis per function
    and mesh: every device runs the vmapped function on its own members, as an unsharded
    sweep of fewer items. A vmap's tests over its whole batch (a while loop's predicate, equinox's
    ``unvmap_any``) stay on each device; partitioned by XLA from a sharded batch (a plain jit)
    each became an all-reduce at every step of the loop, and inside a region
    (``_jit.region``: one kernel, which cannot call XLA's collectives on a CPU) a crash: the
    sharded sweep with joint friction raised ``INTERNAL: Failed to materialize symbols``."""
    return _cached(_SHARDED, (fn, mesh), lambda: jit(_shard_mapped(fn, mesh)))


def _shard_mapped(fn, mesh: Mesh):
    """``fn`` vmapped over each device's members of a chunk sharded over ``mesh`` (see :func:`_sharded_vmap`)."""
    spec = PartitionSpec(BATCH_AXIS)

    def run(chunk):
        arrays, static = eqx.partition(chunk, eqx.is_array)
        results = {}

        def local(arrays):  # one device's members
            out = eqx.filter_vmap(fn)(eqx.combine(arrays, static))
            out_arrays, results["static"] = eqx.partition(out, eqx.is_array)
            return out_arrays

        # every array of the chunk and of the results carries the batch axis (filter_vmap's
        # in_axes and out_axes): the members split, nothing replicated to check
        out_arrays = jax.shard_map(local, mesh=mesh, in_specs=(spec,), out_specs=spec, check_vma=False)(arrays)
        return eqx.combine(out_arrays, results["static"])

    return run


# --------------------------------------------------------------------------- batched kinematics


def batch_kinematics(
    mechanisms: Mechanism,
    q,
    omega=1.0,
    alpha=0.0,
    *,
    points: Sequence[str] | None = None,
    order: int = 2,
    q_per_mechanism: bool = False,
    chunk_size: int | None = None,
    mesh: Mesh | None = None,
    progress: bool | None = None,
) -> Kinematics:
    """Kinematics of a batch of mechanisms (leading axis ``B`` on every array).

    ``q`` (rad or m) is shared by every mechanism (any shape), or, with
    ``q_per_mechanism=True``, has shape ``(B, ...)``: one set per mechanism; at most a
    million configurations in all (B x those of q), as :func:`assurjax.kinematics` takes.
    Results have shape ``(B,) + q_shape + ...`` as numpy arrays; ``ok`` flags per
    mechanism, q and group (never raises for a mechanism that cannot assemble). Same
    conventions as :func:`assurjax.kinematics`.

    **Example:**
    >>> batch = assurjax.perturb(mech, jax.random.key(0), 100, relative=0.02)
    >>> kin = assurjax.batch_kinematics(batch, jnp.linspace(0, 1, 50), points=["P"], order=0)
    >>> kin.points["P"].shape
    (100, 50, 2)
    """
    if order not in (0, 1, 2):
        raise AssurjaxError(f"order must be 0, 1 or 2, got {order}")
    n = batch_size(mechanisms)
    pts = None if points is None else tuple(points)
    if pts is not None:
        unknown = [p for p in pts if p not in dict(mechanisms.owner)]
        if unknown:
            raise AssurjaxError(f"unknown point(s) {unknown}; the mechanisms have {list(mechanisms.point_names)}")
    check_values(AssurjaxError, "batch_kinematics", q=q, omega=omega, alpha=alpha)
    q = np.asarray(q, dtype=float)
    if q_per_mechanism and (q.ndim == 0 or q.shape[0] != n):
        raise AssurjaxError(f"q_per_mechanism=True needs q with a leading axis of {n} (the batch size), got shape {q.shape}")
    # kinematics' bound on one call, over the whole batch: its results are returned at once
    check_state_count(AssurjaxError, "batch_kinematics", q.shape if q_per_mechanism else (n,) + q.shape)
    q_items = q if q_per_mechanism else np.broadcast_to(q, (n,) + q.shape)
    rates = {}
    for name, value in (("omega", omega), ("alpha", alpha)):
        try:
            rates[name] = np.broadcast_to(np.asarray(value, dtype=float), q_items.shape)
        except ValueError:
            raise AssurjaxError(f"batch_kinematics: {name} of shape {np.shape(value)} does not fit q's "
                                f"{q_items.shape} (a number, or one value per configuration)") from None
    omega, alpha = rates["omega"], rates["alpha"]
    fn = _kinematics_item(pts, order)
    return sweep(fn, (mechanisms, q_items, omega, alpha), chunk_size=chunk_size, mesh=mesh, progress=progress, desc="kinematics")


_KIN_ITEMS: dict = {}


def _kinematics_item(points, order):
    """The per-item kinematics function, cached so that :func:`sweep` compiles it once."""
    key = (points, order)
    if key not in _KIN_ITEMS:

        def item(args):
            mechanism, q, omega, alpha = args
            return _kinematics_batch(mechanism, q, omega, alpha, points, order)

        _KIN_ITEMS[key] = item
    return _KIN_ITEMS[key]


# --------------------------------------------------------------------------- batched simulation


VARY_LOADS = ("to vary the loads (a friction coefficient, a drive) across a batch, sweep simulate_core with "
              "assurjax.sweep over their values")


def _check_one_scene(scene, mechanisms) -> None:
    """batch_simulate takes one scene (its loads shared by every member) and a batch of
    mechanisms: a stack of scenes in either place is named as such."""
    from ._friction import frictions_of
    from .scene._scene import Scene

    if isinstance(mechanisms, Scene):
        raise AssurjaxError("batch_simulate: mechanisms takes a batch of Mechanisms (from scene.mechanism, e.g. by "
                            f"assurjax.perturb), got a Scene; every member runs under the scene's loads: {VARY_LOADS}")
    stacked = [] if jnp.shape(scene.gravity) == (2,) else [f"gravity of shape {tuple(jnp.shape(scene.gravity))}"]
    stacked += [f"the friction coefficient of '{f.pair}' of shape {tuple(jnp.shape(f.coefficient))}"
                for f in frictions_of(scene.loads) if jnp.ndim(f.coefficient)]
    if stacked:
        raise AssurjaxError(f"batch_simulate: the scene is a stack of scenes ({stacked[0]}): it takes one scene and a "
                            f"batch of its mechanisms; {VARY_LOADS}")


def batch_simulate(
    scene,
    mechanisms: Mechanism,
    *,
    q0=None,
    omega0=None,
    t1=None,
    saveat=None,
    chunk_size: int | None = None,
    mesh: Mesh | None = None,
    progress: bool | None = None,
    **settings,
):
    """Forward dynamics of a batch of mechanisms (leading axis ``B`` on every array)
    under one scene's loads, gravity and initial state (vmapped ``simulate_core``).

    ``q0``, ``omega0`` (rad, rad/s or m, m/s) and ``t1`` (s) override the scene's
    state; ``saveat``: save times (s). ``settings``: fields of
    :class:`assurjax.SimulationSettings` (``solver``, ``rtol``, ``atol``,
    ``standstill``, ``samples``, ``points``, ``angles``, ``max_steps``...) over the
    scene's ``[simulation]`` and ``[outputs]``. Always the exact reduction (a scene's
    ``reduction`` 'table' or 'auto' too; the keyword ``reduction='table'`` is refused): one
    table per mechanism would not pay off, and each would need its own checks.
    As :func:`assurjax.simulate`'s batches: at most 100 million saved states (mechanisms x
    samples) a call, a fixed step ``dt`` no longer than the span, and a span no default step
    budget covers refused unless something can end it (a standstill stop, events) or
    ``max_steps`` is given.
    Returns an untrimmed Solution of numpy arrays with the batch axis in front:
    read ``valid``, ``event``, ``t_stop``, ``result`` and ``failed_group`` (a tuple: the
    group each member could not assemble, or None) per mechanism (a batch member that
    locks up or fails does not stop the others).
    """
    from .dynamics._settings import (check_single_start, check_span_covered, check_step_within_span, fixed_step_from,
                                     settings_from)
    from .dynamics._solve import check_saved_total, check_steps_request, checked_saveat, refuse_traced, simulate_core
    from .dynamics._solution import batch_summary
    from .dynamics._stick import batch_settings, jammed_members

    refuse_traced("batch_simulate", mechanisms=jax.tree.leaves(mechanisms), q0=q0, omega0=omega0, t1=t1, saveat=saveat,
                  **settings)
    _check_one_scene(scene, mechanisms)
    state = scene.state
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    t0, t1 = state.get("t0", 0.0), state.get("t1", 1.0) if t1 is None else t1
    check_single_start(q0, omega0, t0, t1)
    difference = structure_difference(mechanisms, scene.mechanism)  # its outputs and loads name the scene's parts
    if difference is not None:
        raise AssurjaxError(f"batch_simulate: the mechanisms are not of the scene's structure: {difference} (build the "
                            "batch from scene.mechanism, e.g. with assurjax.perturb)")
    batch_size(mechanisms)  # a ragged batch is named before its values are read
    check_batch_values(mechanisms, "batch_simulate")
    check_has_inertia(mechanisms)
    if settings.get("reduction") == "table":
        raise AssurjaxError("batch_simulate: reduction='table' would need a table per mechanism, built and checked "
                            "apart (the batch's tables ran unchecked through positions a member cannot assemble in): "
                            "batch_simulate runs the exact reduction; simulate() tabulates a batch of starts")
    options = settings_from(scene, **settings)
    # a scene's 'table' or 'auto' too; never differentiated (host arrays): no cuts at the kinks of the
    # friction and the loads (Settings.kink_events)
    options = batch_settings(options._replace(reduction="exact", kink_events=False), scene.loads)
    if options.save_steps:  # as simulate's batches
        raise AssurjaxError("batch_simulate: save_steps saves up to max_steps states per run: it is for single runs, "
                            "not batches (use samples or saveat)")
    step = fixed_step_from(scene, settings.get("dt"))
    gravity, loads = scene.gravity, scene.loads
    if options.steps is not None:  # as simulate's (friction, events, saveat and dt refused)
        check_steps_request(options, scene.model, saveat, step)
    if saveat is not None:  # as simulate's
        saveat = checked_saveat(saveat, t0, t1)
    if step is not None:  # as simulate's: a step longer than the span would be clipped to one step of it
        check_step_within_span(step, t0, t1)
    if options.steps is None and settings.get("max_steps") is None and "max_steps" not in scene.simulation:
        check_span_covered(t0, t1, options)  # as simulate's and final_state's (t1 = 1e9 was run)
    check_saved_total(batch_size(mechanisms), "mechanisms", saveat, options)  # as simulate's batches of starts
    ts = None if saveat is None else jnp.asarray(saveat, dtype=float)
    key = (options, None if ts is None else tuple(np.asarray(ts).tolist()), float(q0), float(omega0), float(t0), float(t1),
           None if step is None else float(step))
    if key not in _SIM_ITEMS:

        def item(args):
            mechanism, loads_, gravity_ = args
            return simulate_core(mechanism, gravity_, loads_, q0, omega0, t0, t1, ts, step, settings=options)

        _SIM_ITEMS[key] = item
    n = batch_size(mechanisms)
    batch = (mechanisms, broadcast_batch(loads, n), broadcast_batch(gravity, n))
    sols = sweep(_SIM_ITEMS[key], batch, chunk_size=chunk_size, mesh=mesh, progress=progress, desc="simulate")
    mechanism, loads, gravity = jax.tree.map(lambda x: x[0], batch)  # Model() checks one model's shapes
    models = eqx.tree_at(lambda m: (m.mechanism, m.loads, m.gravity), Model(mechanism, gravity, loads), batch)
    return batch_summary(sols, jammed_members(sols, models, models_batched=True), mechanism.group_names)


_SIM_ITEMS: dict = {}
