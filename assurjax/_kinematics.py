"""Velocities and accelerations as derivatives of the position map (Durango et al. 2014, step i).

``jax.jvp`` of q -> Pose with a unit driving velocity gives the kinematic
coefficients dx/dq; a second jvp gives d2x/dq2. Then v = dx/dq w and
a = d2x/dq2 w^2 + dx/dq alpha. There is no second hand-written velocity code path.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from ._errors import AssemblyError, AssurjaxError
from ._geometry import perp, rotation, wrap_angle
from ._jit import jit
from ._mechanism import Mechanism, Pose, check_mechanism, point_names, positions
from ._positions import checked_request, stacked_positions
from ._repr import value_pdoc
from ._values import check_state_count, check_value, check_values, concrete
from .groups._base import GROUND, AbstractGroup


class Kinematics(eqx.Module):
    """Positions (m, rad), velocities (m/s, rad/s) and accelerations (m/s^2, rad/s^2).

    Dicts are keyed by point name (``points``...) or link name (``coms``...,
    ``angles``...). Accelerations are None when not asked for (``order=1``).
    ``ok`` has one flag per group (False: cannot assemble at that q). With a
    batch of q every array gets the batch shape in front. ``rotations``: the links'
    (cos, sin) where the kinematics was built from :class:`Coefficients` (else None).
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    q: Array
    omega: Array
    alpha: Array
    points: dict[str, Array]
    velocities: dict[str, Array] | None
    accelerations: dict[str, Array] | None
    coms: dict[str, Array]
    com_velocities: dict[str, Array] | None
    com_accelerations: dict[str, Array] | None
    angles: dict[str, Array]
    angular_velocities: dict[str, Array] | None
    angular_accelerations: dict[str, Array] | None
    ok: Array
    rotations: dict[str, Array] | None = None  # read, where at hand, instead of cos and sin of an angle


def _many_outputs(mechanism: Mechanism, points, what: tuple[bool, bool]) -> bool:
    """More than two output arrays: then each group's frames are materialized once
    (see :func:`positions`); one or two outputs fuse best into one loop."""
    n_points = len(mechanism.point_names) if points is None else len(points)
    return n_points + len(mechanism.links) * (int(what[0]) + int(what[1])) > 2


def _stack(values: list) -> Array | None:
    return jnp.stack(values) if values else None


def _coordinates(mechanism: Mechanism, points: tuple[str, ...] | None, what: tuple[bool, bool], names: dict,
                 flag_singular: bool = False) -> tuple[Callable, Callable]:
    """(q -> ((points (n, 2), coms (m, 2), angles (m,)), (ok, reads)), (x, reads) -> singular).

    Each kind is stacked into one array: the vmapped function has a few outputs instead of
    one per name, and the dicts are built after the vmap. The names in stacking order are
    recorded in ``names`` at trace time. ``ok``: the groups' flags. ``singular`` (with
    ``flag_singular``): whether a group the outputs depend on sits exactly at a singular
    configuration (:func:`exactly_singular`; None where no such group declares a measure),
    from the positions ``reads``, outside the jvps (traced once)."""
    declared = _declared_needed(mechanism, points) if flag_singular else []
    materialize = _many_outputs(mechanism, points, what)
    if points is None and materialize:
        return _every_coordinates(mechanism, what, names, declared)
    return _some_coordinates(mechanism, points, what, names, declared, materialize)


def _every_coordinates(mechanism: Mechanism, what: tuple[bool, bool], names: dict, declared: list[int]):
    """:func:`_coordinates` of every point: the stacked analysis, no per-name arrays in between."""
    joints, turned = _measure_inputs(mechanism, declared)

    def coordinates(q):
        (xp, xc, xa, rot), ok, (names["points"], names["links"]) = stacked_positions(mechanism, q)
        names["coms"] = names["links"] if what[0] else ()
        names["angles"] = names["links"] if what[1] else ()
        return (xp, xc if what[0] else None, xa if what[1] else None), (ok, rot)

    def singular_at(x, rot):
        row = {k: i for i, k in enumerate(names["points"])}
        turn = {k: rot[i] for i, k in enumerate(names["links"]) if k in turned}
        return exactly_singular(mechanism, declared, {j: x[0][row[j]] for j in joints}, turn)

    return coordinates, singular_at


def _some_coordinates(mechanism: Mechanism, points: tuple[str, ...] | None, what: tuple[bool, bool], names: dict,
                      declared: list[int], materialize: bool):
    """:func:`_coordinates` of ``points`` (None: all): only the groups they need, and the
    joints the measures of those groups read."""
    joints, turned = _measure_inputs(mechanism, declared)
    extra = () if points is None else tuple(j for j in joints if j not in points)

    def coordinates(q):
        pose = positions(mechanism, q, points=None if points is None else points + extra, materialize=materialize)
        names["points"] = tuple(pose.points) if points is None else points
        names["coms"] = tuple(pose.coms) if what[0] else ()
        names["angles"] = tuple(pose.angles) if what[1] else ()
        x = tuple(_stack([named[k] for k in names[kind]])
                  for named, kind in ((pose.points, "points"), (pose.coms, "coms"), (pose.angles, "angles")))
        return x, (pose.ok, (pose.points, pose.angles))

    def singular_at(x, reads):
        points, angles = reads
        turn = {k: rotation(angles[k]) for k in turned}  # a Pose has angles only
        return exactly_singular(mechanism, declared, points, turn)

    return coordinates, singular_at


def _declared_needed(mechanism: Mechanism, points: tuple[str, ...] | None) -> list[int]:
    """The groups declaring a singularity measure that ``points`` (None: all) depend on."""
    needed = None if points is None else set(mechanism.groups_needed(points))
    return [i for i in singular_groups(mechanism) if needed is None or i in needed]


def _measure_inputs(mechanism: Mechanism, groups: list[int]) -> tuple[tuple[str, ...], set[str]]:
    """What the measures of ``groups`` may read: their joints' positions and their links' (cos, sin)."""
    joints = tuple(dict.fromkeys(j for i in groups for j in mechanism.groups[i].joints))
    return joints, {k for i in groups for k in mechanism.groups[i].links}


def taylor(fn: Callable, q, order: int):
    """``fn(q) -> (x, aux)`` and its derivatives along the driving coordinate:
    (x, dx/dq, d2x/dq2, aux), None above ``order`` (0, 1 or 2).

    The package's only jvp of the position analysis (Durango et al. 2014 step i: with a unit
    driving velocity the velocities are the kinematic coefficients): kinematics,
    the reduction and the kinetostatics all take their coefficients from here.
    (With several drivers this becomes a jacfwd over q; nothing else changes.)"""
    one = jnp.ones_like(q)
    if order == 0:
        x, aux = fn(q)
        return x, None, None, aux
    if order == 1:
        x, dx, aux = jax.jvp(fn, (q,), (one,), has_aux=True)
        return x, dx, None, aux

    def first(q):
        x, dx, aux = jax.jvp(fn, (q,), (one,), has_aux=True)
        return (x, dx), aux

    (x, dx), (_, d2x), aux = jax.jvp(first, (q,), (one,), has_aux=True)
    return x, dx, d2x, aux


class Coefficients(eqx.Module):
    """Positions and kinematic coefficients of every point, centre of mass and link at
    one driving coordinate: ``x``, ``dx`` = dx/dq, ``d2x`` = d2x/dq2, each dicts by name
    (points (m), coms (m), angles (rad), rotations (cos, sin)); ``dx``/``d2x`` are None
    when not asked for. ``ok``: one flag per group (False: cannot assemble).

    Held as ``stacked``: for each order the arrays (points (P, 2), coms (L, 2), angles (L,),
    rotations (L, 2)) whose rows are named by ``names`` = (point names, link names); the
    dicts are views on them, so work on every link (the reduction) is a few array
    operations instead of a few per name. ``rotations`` are the links' (cos, sin) as the
    position analysis found them, and their derivatives: what needs a link's rotation
    reads it, where its cosine and sine, taken of its angle at each reader, were copied by
    XLA into every computation reading them (the press with friction: 21 sines and cosines
    per right-hand side, 3 needed)."""

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    q: Array
    stacked: tuple
    ok: Array
    names: tuple = eqx.field(static=True)

    @property
    def x(self) -> tuple:
        return self.named(0)

    @property
    def dx(self) -> tuple | None:
        return self.named(1)

    @property
    def d2x(self) -> tuple | None:
        return self.named(2)

    def named(self, order: int) -> tuple | None:
        """The order's (points, coms, angles, rotations) as dicts by name (leading batch axes kept)."""
        return by_name(self.stacked[order], self.names)

    def link_angles(self, order: int) -> dict | None:
        """The order's link angles (or their derivatives) alone as a dict by link name."""
        arrays = self.stacked[order]
        return None if arrays is None else _rows(arrays[2], self.names[1])

    def kinematics(self, omega, alpha=None, *, velocities: bool = True) -> Kinematics:
        """The :class:`Kinematics` at driving velocity ``omega`` and acceleration ``alpha``:
        v = dx/dq w, a = d2x/dq2 w^2 + dx/dq alpha (accelerations only with ``alpha``,
        velocities only with ``velocities``)."""
        omega = jnp.asarray(omega, dtype=float)
        x, dx, d2x = self.stacked
        vel = acc = None
        if dx is not None and velocities:
            vel = jax.tree.map(lambda d: d * omega, dx)
        if alpha is not None:
            acc = jax.tree.map(lambda dd, d: dd * omega**2 + d * alpha, d2x, dx)
        named = lambda arrays: (None, None, None) if arrays is None else by_name(arrays, self.names)[:3]  # noqa: E731
        (points, coms, angles), v, a = named(x), named(vel), named(acc)
        return Kinematics(
            q=self.q, omega=omega, alpha=jnp.zeros_like(self.q) if alpha is None else jnp.asarray(alpha, dtype=float),
            points=points, velocities=v[0], accelerations=a[0],
            coms=coms, com_velocities=v[1], com_accelerations=a[1],
            angles=angles, angular_velocities=v[2], angular_accelerations=a[2],
            ok=self.ok, rotations=by_name(x, self.names)[3],
        )


def by_name(arrays, names) -> tuple | None:
    """(points (..., P, 2), coms (..., L, 2), angles (..., L), rotations (..., L, 2)) as
    dicts by name."""
    if arrays is None:
        return None
    points, links = names
    return (_rows(arrays[0], points, vectors=True), _rows(arrays[1], links, vectors=True), _rows(arrays[2], links),
            _rows(arrays[3], links, vectors=True))


def _rows(array, names, *, vectors: bool = False) -> dict:
    """The rows of a stacked array by name (leading batch axes kept; ``vectors``: rows are 2-vectors)."""
    return {k: array[..., i, :] if vectors else array[..., i] for i, k in enumerate(names)}


def coefficients(mechanism: Mechanism, q, *, order: int = 2, near=None) -> Coefficients:
    """Positions and first/second kinematic coefficients of every point, centre of mass
    and link angle at ``q`` (see :func:`taylor`). ``near``: link angles (rad) selecting
    the branch (see :func:`assurjax.positions`)."""
    if order not in (0, 1, 2) or isinstance(order, bool):
        raise AssurjaxError(f"coefficients: order must be 0, 1 or 2, got {order!r}")
    checked_request(mechanism, q, None, near, "coefficients")
    names = {}

    def coords(q):
        stacked, ok, names["rows"] = stacked_positions(mechanism, q, near)
        return stacked, ok

    q = jnp.asarray(q, dtype=float)
    x, dx, d2x, ok = taylor(coords, q, order)
    return Coefficients(q=q, stacked=(x, dx, d2x), ok=ok, names=names["rows"])


# Bridging a singular window: nodes at q + s d0 outside it, and the weights of the cubic
# through them evaluated at q (Lagrange on symmetric nodes; the weights sum to 1).
BRIDGE_NODES = (-3.0, -2.0, 2.0, 3.0)
BRIDGE_WEIGHTS = (-0.4, 0.9, 0.9, -0.4)
BRIDGE_WINDOW = 5e-3  # d0 (rad or m of q): rounding noise ~eps/d0^3 at the nodes, truncation ~d0^4


def singular_groups(mechanism: Mechanism) -> list[int]:
    """The groups that declare a singularity measure (``AbstractGroup.singularity``)."""
    return [i for i, g in enumerate(mechanism.groups) if type(g).singularity is not AbstractGroup.singularity]


# |singularity measure| (a sine or cosine) below which a closed form sits on its square
# root's clamp: there its coefficients are finite but not the motion's (a simulation
# refuses to start there; kinematics and reduce give NaN rates)
START_SINGULAR_MEASURE = 1e-9


def exactly_singular(mechanism: Mechanism, groups: list[int], x: Mapping, turn: Mapping) -> Array:
    """True where one of ``groups`` (indices declaring a measure) sits exactly at a
    singular configuration: |measure| <= START_SINGULAR_MEASURE, read from the points
    ``x`` and the links' (cos, sin) ``turn`` (their derivatives are not needed). None
    without ``groups``."""
    if not groups:
        return None
    zero = jnp.zeros(2)
    dx, dturn = (dict.fromkeys(named, zero) for named in (x, turn))
    at = [jnp.abs(mechanism.groups[i].singularity(x, dx, turn, dturn)[0]) <= START_SINGULAR_MEASURE for i in groups]
    return functools.reduce(jnp.logical_or, at)


def nan_where(flag, tree):
    """``tree`` (leaves with the flag's shape in front) with NaN where ``flag`` (None:
    unchanged), elsewhere bit for bit (times 1)."""
    if flag is None:
        return tree
    # a quotient XLA computes once per sample; a select it would copy, with the measures
    # behind the flag, into the loop of every output element
    one = 1.0 / jnp.where(flag, jnp.nan, 1.0)
    return jax.tree.map(lambda v: v * one.reshape(one.shape + (1,) * (v.ndim - one.ndim)), tree)


def singularity_measures(mechanism: Mechanism, coeffs: Coefficients, groups) -> Array:
    """(measure, its q-derivative) of each of ``groups`` (indices; see
    :func:`singular_groups`) at the coefficients' q: (len(groups), 2); of order-0
    coefficients the derivatives are 0 (not computed)."""
    (x, _, _, turn) = coeffs.x
    if coeffs.dx is None:
        dx, dturn = ({name: jnp.zeros(2) for name in named} for named in (x, turn))
    else:
        dx, dturn = coeffs.dx[0], coeffs.dx[3]
    return jnp.stack([jnp.stack(mechanism.groups[i].singularity(x, dx, turn, dturn)) for i in groups])


def singular_distance(mechanism: Mechanism, coeffs: Coefficients) -> Array | None:
    """Distance in q (rad or m) to the nearest singular configuration of a group that
    declares one (``singularity``): |m| / |dm/dq| of its measure m; None if none does."""
    (x, _, _, turn), (dx, _, _, dturn) = coeffs.x, coeffs.dx
    measures = [g.singularity(x, dx, turn, dturn) for g in mechanism.groups]
    distances = [jnp.abs(m) / jnp.maximum(jnp.abs(dm), 1e-300) for m, dm in filter(None, measures)]
    return jnp.min(jnp.stack(distances)) if distances else None


def bridged_coefficients(mechanism: Mechanism, q, *, near: dict, window: float = BRIDGE_WINDOW) -> Coefficients:
    """:func:`coefficients` (order 2) on a tracked branch (``near``: link angles), bridged
    across singular configurations.

    Near a stretched, folded or coincident-joint dyad (RRR), a rod square to its guide
    (RRP/PRR) or a guide square to the line of its pins (RPR) the closed forms lose their
    inputs' precision: positions err by ~eps/delta, the first coefficients by
    ~eps/delta^2 and the second by ~eps/delta^3 (delta: distance in q to the singular
    point), although the motion on the branch is smooth there. Within ``window`` of
    such a point (estimated from the groups' ``singularity`` measures) the
    coefficients are the cubic through four evaluations at q +- 2 and 3 windows:
    error ~window^4 from truncation and ~eps/window^3 from the nodes' rounding,
    instead of the unbounded noise. Outside it, or where a node cannot assemble (a
    limit position: the branch ends, nothing to bridge), they are the plain ones. The
    nodes take the root nearest to the branch angles carried along the first
    coefficients."""
    if not isinstance(near, Mapping):
        raise AssurjaxError("bridged_coefficients: near must map the tracked links to their angles (rad), e.g. "
                            f"assurjax.branch_angles(mechanism, pose); got {type(near).__name__}")
    check_value(AssurjaxError, "bridged_coefficients: window", window, shape=(), positive=True)
    if concrete(window) is not None and float(window) > 0.1:
        raise AssurjaxError(f"bridged_coefficients: window is a half-width in q (rad or m) next to a singular point, "
                            f"at most 0.1, got {float(window):g}")
    q = jnp.asarray(q, dtype=float)
    plain = coefficients(mechanism, q, order=2, near=near)
    distance = singular_distance(mechanism, plain)
    if distance is None:
        return plain

    def interpolate():
        steps = window * jnp.asarray(BRIDGE_NODES)
        predicted = {k: near[k] + plain.dx[2][k] * steps for k in near}
        nodes = jax.vmap(lambda s, n: coefficients(mechanism, q + s, order=2, near=n))(steps, predicted)
        weights = jnp.asarray(BRIDGE_WEIGHTS)
        combine = lambda v: jnp.tensordot(weights, v, axes=1)  # noqa: E731
        (points, coms, angles, _), dx, d2x = nodes.stacked
        angles = angles[0] + wrap_angle(angles - angles[0])  # continuous across +-pi
        stacked = _rotations_of_angles(jax.tree.map(combine, (points, coms, angles)), jax.tree.map(combine, dx[:3]),
                                       jax.tree.map(combine, d2x[:3]))
        bridged = Coefficients(q=q, stacked=stacked, ok=jnp.ones_like(plain.ok), names=plain.names)  # every node assembles
        # a node that cannot assemble: the branch ends there (a limit position), nothing to bridge
        crossing = jnp.all(nodes.ok)
        return jax.tree.map(lambda b, p: jnp.where(crossing, b, p), bridged, plain)

    # a NaN distance (coincident joints exactly) counts as inside the window
    return jax.lax.cond(~(distance >= window), interpolate, lambda: plain)


def _rotations_of_angles(x, dx, d2x):
    """The three orders' (points, coms, angles) with the links' rotations and their
    derivatives taken from the angles (interpolated coefficients: no frames to read)."""
    rot = rotation(x[2])
    turned = perp(rot)
    return (x + (rot,), dx + (turned * dx[2][..., None],),
            d2x + (turned * d2x[2][..., None] - rot * (dx[2] ** 2)[..., None],))


def branch_coefficients(mechanism: Mechanism, q, *, near=None, bridge: float = 0.0) -> Coefficients:
    """Order-2 coefficients on the fixed modes (``near`` None) or a tracked branch,
    bridged across singular windows of half-width ``bridge`` when it is positive."""
    if near is not None and bridge > 0:
        return bridged_coefficients(mechanism, q, near=near, window=bridge)
    return coefficients(mechanism, q, order=2, near=near)


def _stacked_single(mechanism: Mechanism, q, omega, alpha, points, order: int, what=(True, True)):
    """Positions, velocities and accelerations at one q as stacked arrays, and their names."""
    names: dict = {}
    coordinates, singular_at = _coordinates(mechanism, points, what, names, flag_singular=order > 0)
    x, dx, d2x, (ok, reads) = taylor(coordinates, q, order)
    singular = singular_at(x, reads)
    if singular is not None:  # where a group cannot assemble its clamped closed form reads as singular: ok says so already
        singular = singular & jnp.all(ok)
    vel = None if dx is None else jax.tree.map(lambda d: d * omega, dx)
    acc = None if d2x is None else jax.tree.map(lambda dd, d: dd * omega**2 + d * alpha, d2x, dx)
    return names, dict(q=q, omega=omega, alpha=alpha, x=x, v=vel, a=acc, ok=ok, singular=singular)


def _unstack(names: dict, arrays: dict, batch_ndim: int) -> Kinematics:
    """The stacked arrays (with ``batch_ndim`` leading batch axes) as a Kinematics of dicts."""

    def split(stacked, kind):
        if stacked is None:
            return {}
        index = (slice(None),) * batch_ndim
        return {k: stacked[index + (i,)] for i, k in enumerate(names[kind])}

    def fields(triple):
        if triple is None:
            return None, None, None
        return split(triple[0], "points"), split(triple[1], "coms"), split(triple[2], "angles")

    x, v, a = fields(arrays["x"]), fields(arrays["v"]), fields(arrays["a"])
    # exactly at a singular configuration the rates are unbounded (the driving coordinate does
    # not carry the motion); masked name by name: on the stacked arrays XLA fuses the whole
    # analysis differently, and slower
    v, a = nan_where(arrays["singular"], (v, a))
    return Kinematics(
        q=arrays["q"], omega=arrays["omega"], alpha=arrays["alpha"],
        points=x[0], velocities=v[0], accelerations=a[0],
        coms=x[1], com_velocities=v[1], com_accelerations=a[1],
        angles=x[2], angular_velocities=v[2], angular_accelerations=a[2],
        ok=arrays["ok"],
    )


def _kinematics_single(mechanism: Mechanism, q, omega, alpha, points, order: int, what=(True, True)) -> Kinematics:
    """Kinematics at one q (unbatched); see :func:`kinematics`."""
    names, arrays = _stacked_single(mechanism, q, omega, alpha, points, order, what)
    return _unstack(names, arrays, 0)


@jit
def _kinematics_batch(mechanism, q, omega, alpha, points, order, what=(True, True)):
    names: dict = {}

    def single(q, w, a):
        found, arrays = _stacked_single(mechanism, q, w, a, points, order, what)
        names.update(found)
        return {k: v for k, v in arrays.items() if k not in ("q", "omega", "alpha")}  # no copies of the inputs

    shape = q.shape
    flat = jax.vmap(single)(q.reshape(-1), omega.reshape(-1), alpha.reshape(-1))
    flat = jax.tree.map(lambda x: x.reshape(shape + x.shape[1:]), flat)
    return _unstack(names, dict(flat, q=q, omega=omega, alpha=alpha), len(shape))  # split per name outside the loop


def kinematics(
    mechanism: Mechanism,
    q,
    omega=1.0,
    alpha=0.0,
    *,
    points: Iterable[str] | None = None,
    order: int = 2,
    coms: bool = True,
    angles: bool = True,
    check: bool = True,
) -> Kinematics:
    """Positions, velocities and accelerations of every named point, centre of mass and link.

    **Arguments:**
    - ``q``: driving coordinate (rad for a crank, m for a slider); any shape.
    - ``omega``, ``alpha``: driving velocity and acceleration (broadcast against q).
      With ``omega=1`` the velocities are the kinematic coefficients dx/dq.
    - ``points``: only these points (and the groups they need) are computed.
    - ``order``: 0 positions, 1 adds velocities, 2 adds accelerations.
    - ``coms``, ``angles``: set False to skip the centres of mass or the link angles
      (their dicts are then empty); the angles cost an atan2 per link.
    - ``check``: outside jit, raise :class:`AssemblyError` naming the group that
      cannot assemble; inside jit read ``Kinematics.ok`` instead.

    **Singular configurations:** exactly at a dead centre of a group the outputs depend
    on (an RRR dyad stretched or folded, an RRP/PRR rod square to its guide, an RPR guide
    square to the line of its pins: the group's ``singularity`` measure within 1e-9 of
    zero, where :func:`assurjax.simulate` refuses to start) the rates are unbounded: the
    driving coordinate does not carry the motion there. Every velocity and acceleration
    of such a sample is NaN; its positions are right and ``ok`` stays True. A step away
    they are finite and large (a stretched dyad's ~1/sqrt of the distance in q). With
    ``points``, only the groups those points need count: a point on the crank keeps its
    velocity.

    **Example:**
    >>> mech = assurjax.load_scene("roberts").mechanism
    >>> kin = assurjax.kinematics(mech, jnp.linspace(1.0, 1.5, 5))  # it assembles up to pi/2, its dyad stretched there
    >>> kin.points["P"].shape
    (5, 2)
    """
    if order not in (0, 1, 2):
        raise AssurjaxError(f"kinematics: order must be 0, 1 or 2, got {order!r}")
    check_mechanism(mechanism, "kinematics")
    check_values(AssurjaxError, "kinematics", q=q, omega=omega, alpha=alpha)
    check_state_count(AssurjaxError, "kinematics", np.shape(q))
    q = jnp.asarray(q, dtype=float)
    for name, value in (("omega", omega), ("alpha", alpha)):
        if not broadcasts_to(np.shape(value), q.shape):
            raise AssurjaxError(f"kinematics: {name} of shape {np.shape(value)} does not broadcast to q's shape {q.shape}")
    omega, alpha = (jnp.broadcast_to(jnp.asarray(v, dtype=q.dtype), q.shape) for v in (omega, alpha))
    pts = None if points is None else point_names(mechanism, points, "kinematics")
    kin = _kinematics_batch(mechanism, q, omega, alpha, pts, order, (bool(coms), bool(angles)))
    if check:
        raise_if_not_assembled(mechanism, kin.ok, q)
    return kin


def broadcasts_to(shape: tuple[int, ...], target: tuple[int, ...]) -> bool:
    try:
        return np.broadcast_shapes(shape, target) == target
    except ValueError:
        return False


def first_failure(mechanism: Mechanism, ok, q):
    """(group, q, a note of how many configurations fail: "" for a single one, else
    " (k of n configurations fail)") of the first False flag in ``ok`` (last axis: groups),
    or None when all are True or the flags are traced."""
    if isinstance(ok, jax.core.Tracer):
        return None
    ok = np.asarray(ok)
    if ok.all():
        return None
    bad = np.argwhere(~ok)[0]
    q_bad = float(np.asarray(q)[tuple(bad[:-1])]) if np.ndim(q) else float(q)
    if ok.ndim < 2:
        return mechanism.groups[bad[-1]], q_bad, ""
    failing, total = int((~ok).any(-1).sum()), int(np.prod(ok.shape[:-1]))
    return mechanism.groups[bad[-1]], q_bad, f" ({failing} of {total} configurations fail)"


def raise_if_not_assembled(mechanism: Mechanism, ok, q, *, pose: Pose | None = None, where: str = "",
                           advice: Callable[[tuple[str, ...]], str] | None = None) -> None:
    """Raise :class:`AssemblyError` naming the first group that cannot assemble, at which q, the
    condition it violates there with the lengths (:func:`assurjax.structure.assembly_report`'s
    words) and what to do (no-op under tracing). ``pose``: the Pose at a single ``q`` if at hand;
    ``where``: a prefix (a scene file); ``advice``: the links to check -> what to do."""
    from .structure._diagnostics import links_to_check, violated_condition  # the structure package imports this module

    failure = first_failure(mechanism, ok, q)
    if failure is None:
        return
    group, q_bad, how_many = failure
    reason = violated_condition(mechanism, group, q_bad, pose if not how_many else None)
    links = links_to_check(mechanism, group)
    if advice is None:
        moving = [link for link in links if link != GROUND]
        named = f"link(s) {', '.join(moving)}" + (" and the ground points" if GROUND in links else "")
        todo = (f"check the points (m) of {named}, or use a q where it assembles "
                "(assurjax.structure.assembly_report(mechanism, q) shows where)")
    else:
        todo = advice(links)
    raise AssemblyError(f"{where}{group.describe()} cannot assemble at q = {q_bad:.6g}{how_many}"
                        f"{': ' + reason if reason else ''}; {todo}", group=group.name)


def with_reason(error: AssemblyError, mechanism: Mechanism, q) -> AssemblyError:
    """``error`` (naming its group, at the single concrete ``q``) with the condition that group
    violates there appended, when it does not assemble there (a singular start does)."""
    names = [g.name for g in mechanism.groups]
    if error.group not in names or np.ndim(q) or isinstance(q, jax.core.Tracer):
        return error
    from .structure._diagnostics import violated_condition  # the structure package imports this module

    i = names.index(error.group)
    pose = positions(mechanism, float(q))
    if bool(np.asarray(pose.ok)[..., i].all()) or not bool(np.asarray(pose.ok)[..., :i].all()):
        return error
    reason = violated_condition(mechanism, mechanism.groups[i], float(q), pose)
    return error if reason is None else AssemblyError(f"{error}; there {reason}", group=error.group)


def pose_at(mechanism: Mechanism, q) -> Pose:
    """The Pose at one q, with a clear error if some group cannot assemble (why: the condition
    it violates, with the lengths)."""
    check_mechanism(mechanism, "pose_at")
    pose = positions(mechanism, q)  # its own jit; checks q
    raise_if_not_assembled(mechanism, pose.ok, q, pose=pose)
    return pose


def inverse_kinematics(
    mechanism: Mechanism,
    quantity: Callable[[Pose], Array] | tuple[str, str | int],
    value,
    q0,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    max_steps: int = 64,
) -> tuple[Array, Pose]:
    """Turn a driven quantity into the driving one (Fanghella et al.'s (2019) driving dimension).

    Finds q near ``q0`` (on the mechanism's assembly modes) with
    ``quantity(pose) == value`` by Newton's method (optimistix). ``quantity`` is a
    point coordinate ``(point, "x" | "y")`` (e.g. ``("P", "x")`` with
    ``value=0.05`` for x_P = 50 mm) or a function of the :class:`Pose`, e.g.
    ``lambda pose: pose.points["P"][0]``. The solve is compiled once per
    mechanism structure and quantity: a function written again with the same
    code (a notebook cell run twice, a lambda in a loop) reuses it, and ``value``
    and ``q0`` are traced (new numbers do not recompile). Returns (q, pose);
    raises :class:`AssemblyError` when the target is out of reach (under jit, vmap or grad,
    where nothing can be raised: q is NaN there, the pose not ok).
    Differentiable by the implicit function theorem (one Newton step at the root
    carries the gradient: no host callback in a differentiated program).
    """
    from ._structure import by_structure

    if isinstance(quantity, tuple):
        quantity = _point_coordinate(mechanism, quantity)
    elif not callable(quantity):
        raise AssurjaxError(f"inverse kinematics: quantity must be (point, 'x' | 'y') or a function of the pose, got {quantity!r}")
    check_values(AssurjaxError, "inverse kinematics", shape=(), value=value, q0=q0)
    _check_newton_settings(rtol=rtol, atol=atol, max_steps=max_steps)
    value = jnp.asarray(value, dtype=float)
    q, ok = _inverse_jit(mechanism, by_structure(quantity), value, jnp.asarray(q0, dtype=float), rtol, atol, max_steps)
    if isinstance(ok, jax.core.Tracer):  # under jit, vmap or grad: no error can be raised, the result says it
        q = jnp.where(ok, q, jnp.nan)
        return q, positions(mechanism, q)
    if not bool(ok):
        raise AssemblyError(
            f"inverse kinematics: no configuration near q0 = {float(q0):.6g} reaches the target value {float(value):.6g} "
            "(out of reach on this assembly branch, or a group cannot assemble on the way)"
        )
    return q, pose_at(mechanism, q)


NEWTON_STEPS_LIMIT = 10_000  # Newton meets its target in tens of steps; 10^9 steps ran over 12 min out of reach


def _check_newton_settings(**settings) -> None:
    """rtol and atol as simulate's (positive, finite, below 1); max_steps a positive integer up
    to NEWTON_STEPS_LIMIT (0 ended as 'out of reach')."""
    from .dynamics._settings import SIMULATION_KEYS, setting_problem  # dynamics imports this module

    for key, value in settings.items():
        problem = setting_problem(key, value) if key != "max_steps" else None
        if key == "max_steps" and not (SIMULATION_KEYS[key][0](value) and value <= NEWTON_STEPS_LIMIT):
            problem = f"expected a positive integer, at most {NEWTON_STEPS_LIMIT}, got {value!r}"
        if problem is not None:
            raise AssurjaxError(f"inverse kinematics: keyword '{key}': {problem}")


class _PointCoordinate(eqx.Module):
    """The quantity ``pose.points[point][axis]`` (hashable: one compiled solve per point and axis)."""

    point: str = eqx.field(static=True)
    axis: int = eqx.field(static=True)

    def __call__(self, pose: Pose) -> Array:
        return pose.points[self.point][self.axis]


def _point_coordinate(mechanism: Mechanism, spec) -> _PointCoordinate:
    point, axis = spec if len(spec) == 2 else (None, None)
    axis = {"x": 0, "y": 1, 0: 0, 1: 1}.get(axis)
    if point not in mechanism.point_names or axis is None:
        raise AssurjaxError(f"inverse kinematics: quantity {spec!r} must be (point, 'x' | 'y') with a point of "
                            f"mechanism '{mechanism.name}' (known: {sorted(mechanism.point_names)})")
    return _PointCoordinate(point, axis)


@jit
def _inverse_jit(mechanism, quantity, value, q0, rtol, atol, max_steps):
    frozen, fixed_value = jax.lax.stop_gradient((mechanism, value))

    def residual(q, m, v):
        return quantity(positions(m, q)) - v

    sol = optx.root_find(lambda q, _: residual(q, frozen, fixed_value), optx.Newton(rtol=rtol, atol=atol), jax.lax.stop_gradient(q0),
                         max_steps=max_steps, throw=False)
    root = jax.lax.stop_gradient(sol.value)
    # gradients by the implicit function theorem, carried by one Newton step from the root
    # (dq = -dr/dtheta / dr/dq) instead of the adjoint's checked linear solve (a host callback)
    miss, slope = jax.jvp(lambda q: residual(q, mechanism, value), (root,), (jnp.ones_like(root),))
    slope = jax.lax.stop_gradient(slope)
    q = root - miss / jnp.where(slope == 0, 1.0, slope)
    pose = positions(frozen, root)
    # reached: the target met to the dtype's round-off (float32: 1e-4 of it), whether or not Newton's
    # steps met their own tolerance (rtol = atol = 1e-12 are beyond float32's reach)
    reach = max(1e-9, 1e3 * float(jnp.finfo(root.dtype).eps)) * (1 + jnp.abs(fixed_value))
    ok = jnp.all(pose.ok) & (jnp.abs(jax.lax.stop_gradient(miss)) < reach)
    return q, ok & (slope != 0)
