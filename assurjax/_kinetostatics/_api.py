"""Joint reactions and driving effort, group by group in reverse formation order (level by
level, groups of one kind at one level in batches: :mod:`._batches`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import AssurjaxError
from .._listing import few
from .._values import check_state_count, check_values, concrete, found_words
from .._geometry import rotation
from .._jit import at_top_level, chunk_rows, jit
from .._kinematics import Coefficients, Kinematics, coefficients, first_failure, raise_if_not_assembled
from .._friction import (FIXED_POINT_STEPS, SUMMED_TERMS, coulomb_limits, coulomb_signs, friction_wrenches,
                         frictions_of, in_range, linearize_reactions, rates_and_slopes, signs_ahead, solve_friction,
                         static_model, states_per_call)
from .._loads import Drive, applied_wrenches, driver_effort, drives, unbindable
from .._mechanism import Mechanism, positions
from .._model import Model, as_model
from .._repr import value_pdoc
from ._class4 import class4_topology, solve_class4_special
from ._drivers import solve_crank, solve_slider
from ._dyads import solve_prp, solve_prr, solve_rpr, solve_rrp, solve_rrr
from ._layout import Pair, group_pairs, groups_for
from ._batches import apply_hand_backs, hand_backs, queue_hand_backs, solve_batch, solve_order
from ._system import Geometry, solve_dense


class SingularConfigurationError(AssurjaxError):
    """A group's equilibrium equations are singular (e.g. an RRR dyad with its links
    collinear): its reactions are not determined by statics alone."""

    def __init__(self, message: str, group: str | None = None):
        super().__init__(message)
        self.group = group


# group kind -> solver(group, pairs, geometry, known wrenches) -> (reactions, driving or None, ok):
# closed forms for the drivers and every dyad. A class-IV group with special Assur points
# uses solve_class4_special; any other group (the triad) solves its own 3 n x 3 n system
# with solve_dense.
SOLVERS = {
    "crank": solve_crank,
    "slider": solve_slider,
    "RRR": solve_rrr,
    "RRP": solve_rrp,
    "PRR": solve_prr,
    "RPR": solve_rpr,
    "PRP": solve_prp,
}

METHODS = ("modular", "dense", "global")


class Reactions(eqx.Module):
    """Joint reactions and the driving effort at one state or along a trajectory.

    ``forces[name]``: (..., 2) force (N, global x, y) of every pair. A revolute
    (named by its point, e.g. "A") gives the force ON the link placed later in the
    formation sequence BY the earlier one; a point carried by k > 2 links gives one
    reaction per later carrier, "<point>[<link>]", the force on it by the first
    carrier. A prismatic pair "<slider>/<guide link>" gives the force on the slider
    by the guide link, normal to the guide, acting at the slider's sliding point,
    and ``couples[name]`` (N m, counterclockwise) the couple on the slider.
    ``driving``: the driving torque (N m, crank, counterclockwise) or force (N,
    slider, along the guide) the driver must supply: the generalized force
    conjugate to q. ``ok``: (..., n_groups), False where a group cannot assemble
    or its equilibrium equations are singular (its values are then finite, never NaN,
    and not the statics': the unknown its zero determinant leaves open is set to 0).
    ``pairs``: who acts on whom, for every name.

    With joint friction, ``friction[name]`` (N m, or N for a prismatic pair) is the
    friction of the pair's element (Coulomb and viscous together): the couple on the
    later link of a revolute (the opposite acts on the earlier one), the force along the
    guide on the slider of a prismatic pair (at its sliding point; not part of
    ``forces``, which is normal to the guide); ``friction_power[name]`` (W, <= 0) the
    power it takes out of the motion. Both are empty without friction; at rest the power is 0.
    Within ~1e-8 (1 + |q|) of where a relative rate changes sign, its Coulomb sign is the one
    just ahead (the motion's as t -> 0+): the power there can be ~+1e-10 W.
    ``friction_ok``: (...,) False where the joint friction has no consistent solution with
    the motion's Coulomb signs: the friction self-locks the mechanism against that motion
    (no finite drive gives it: the statics' friction law has no root with det(I - S) > 0,
    S its slope), and the values reported there are not a drive that produces it. Held
    at rest, False where either break-away limit has none: the friction alone holds the
    mechanism against any drive that way, and ``driving`` is not the band's edge; and False
    where the friction values reported exceed some element's static limit. Along a
    Solution whose run the friction jammed (``sol.jammed``), False at the jam's state (its
    last sample): the motion has no dw/dt there, so the values read there are no statics.
    True without friction.
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    forces: dict[str, Array]
    couples: dict[str, Array]
    driving: Array
    ok: Array
    pairs: tuple[Pair, ...] = eqx.field(static=True)
    friction: dict[str, Array] = eqx.field(default_factory=dict)
    friction_power: dict[str, Array] = eqx.field(default_factory=dict)
    friction_ok: Array | None = None

    def __getitem__(self, name: str) -> Array:
        if name not in self.forces:
            raise AssurjaxError(f"no reaction at joint '{name}' was computed (available: {sorted(self.forces)})")
        return self.forces[name]

    def keys(self):
        return self.forces.keys()


def _solver(group, pairs, method: str):
    if method == "dense":
        return None
    if group.kind in SOLVERS:
        return SOLVERS[group.kind]
    if class4_topology(group, pairs) is not None:
        return solve_class4_special
    return None  # any other group: its own dense system


def _geometry(kin: Kinematics) -> Geometry:
    rotations = kin.rotations if kin.rotations is not None else {k: rotation(a) for k, a in kin.angles.items()}
    return Geometry(kin.points, kin.coms, rotations)


def _known_wrenches(mechanism: Mechanism, kin: Kinematics, wrenches) -> dict:
    """Applied force and moment about the COM plus d'Alembert's -m a_G and -J alpha."""
    known = {}
    for name, link in mechanism.links.items():
        f, m = wrenches[name]
        if kin.com_accelerations is not None:
            f = f - link.mass * kin.com_accelerations[name]
            m = m - link.inertia * kin.angular_accelerations[name]
        known[name] = (f, m)
    return known


def solve_group(mechanism: Mechanism, pairs, i: int, geom: Geometry, known: dict, method: str = "modular"):
    """Group i's (reactions by name, driving effort (the driver's; else None), whether its
    system is regular), from the known wrenches of its links."""
    group = mechanism.groups[i]
    solver = _solver(group, pairs[i], method)
    if solver is None:
        return solve_dense(group.links, pairs[i], geom, known, group if group.is_driver else None)
    return solver(group, pairs[i], geom, known)


def solve_groups(mechanism: Mechanism, geom: Geometry, known: dict, *, method: str = "modular", groups=None,
                 batched: bool = True):
    """The kinetostatic analysis proper: each group solving only its own equations with
    the loads handed back by the groups built on it, level by level from the outermost
    in, groups of one kind at one level together (:mod:`._batches`; ``batched=False``: one
    at a time, a reference); the driver last. Returns (reactions by name, driving effort,
    ok per group, the reactions as they were solved: [(pair names, forces (n, 2), couples
    (n,)) of a batch of n, or (name,), force (2,), couple of one group's pair])."""
    pairs = group_pairs(mechanism)
    wanted = range(len(mechanism.groups)) if groups is None else groups
    known, queued = dict(known), {}
    out, driving, stacks = {}, jnp.zeros(()), []
    oks = [jnp.array(True)] * len(mechanism.groups)
    for batch in solve_order(mechanism, pairs, wanted, batched):
        apply_hand_backs(known, queued, [link for i in batch for link in mechanism.groups[i].links])
        solved = None
        if len(batch) > 1:
            solved = solve_batch(mechanism, pairs, batch, geom, known,
                                 lambda i, g, k: solve_group(mechanism, pairs, i, g, k, method))
        if solved is None:
            each = [solve_group(mechanism, pairs, i, geom, known, method) for i in batch]
            each = [s + (hand_backs(geom, pairs[i], s[0]),) for i, s in zip(batch, each)]
            solved = each, [((name,), r.force, r.couple) for s in each for name, r in s[0].items()]
        for i, (found, effort, oks[i], back) in zip(batch, solved[0]):
            if effort is not None:
                driving = effort
            queue_hand_backs(queued, i, pairs[i], back)
            out.update(found)
        stacks.extend(solved[1])
    return out, driving, jnp.stack(oks), stacks


def stacked_at(stacks, names) -> tuple[Array, Array]:
    """(forces (P, 2), couples (P,)) of the pairs ``names`` from :func:`solve_groups`'
    stacked reactions: one concatenation and one gather, where a stack of P reactions each
    sliced from its batch was a copy per pair."""
    where = {name: (k, n) for k, (members, _, _) in enumerate(stacks) for n, name in enumerate(members)}
    used = sorted({where[name][0] for name in names})
    start = dict(zip(used, np.cumsum([0] + [len(stacks[k][0]) for k in used])))
    rows = np.array([start[where[name][0]] + where[name][1] for name in names])
    sizes = [len(stacks[k][0]) for k in used]
    return (jnp.concatenate([jnp.reshape(stacks[k][1], (n, 2)) for k, n in zip(used, sizes)])[rows],
            jnp.concatenate([jnp.broadcast_to(stacks[k][2], (n,)) for k, n in zip(used, sizes)])[rows])


def solve_global(mechanism: Mechanism, geom: Geometry, known: dict):
    """Reference: every equilibrium equation of the mechanism in one linear system
    (3 n x 3 n: 15 x 15 for the Watt six-bar)."""
    pairs = [p for ps in group_pairs(mechanism) for p in ps]
    found, driving, ok = solve_dense(list(mechanism.links), pairs, geom, known, mechanism.driver)
    return found, driving, jnp.broadcast_to(ok, (len(mechanism.groups),))


def _both_ways(model: Model, coeffs: Coefficients, kin: Kinematics, omega, t, method: str, groups):
    """The joint friction of a motion forward and of one backward at the kinematics ``kin``
    (their Coulomb signs those of the elements' relative rates just ahead each way times +1
    and -1, :func:`assurjax._friction.signs_ahead`; ``coeffs``: of order 2), stacked
    in that order: (friction values u (2, K), the rates per unit driving velocity (K,), the
    Coulomb signs each way (2, K), whether each has a consistent solution (2,), the
    reactions each gives: forces,
    couples, driving effort and ok, each with 2 in front, and the friction pairs' reactions
    linearized in u, of :func:`linearize_reactions`)."""
    mechanism, frictions = model.mechanism, frictions_of(model.loads)
    rates, slopes, _ = rates_and_slopes(mechanism, frictions, coeffs)

    def react(u, at_pairs=None):  # the pairs' reactions, for the friction law
        return from_kinematics(model, kin, t, extra=friction_wrenches(mechanism, kin, frictions, u), at_pairs=at_pairs)[:2]

    linear = linearize_reactions(react, frictions, len(frictions))

    def each_way(d):  # the friction of a motion in direction d, and the reactions it gives
        signs = coulomb_signs(frictions, rates, omega, signs_ahead(rates, slopes, d, coeffs.q) * d)
        u, consistent = solve_friction(mechanism, frictions, linear, kin, rates, signs, omega, iterate=False)
        return u, signs, consistent, from_kinematics(model, kin, t, method=method, groups=groups,
                                                     extra=friction_wrenches(mechanism, kin, frictions, u))

    us, signs, consistent, found = jax.vmap(each_way)(jnp.array([1.0, -1.0]))
    return us, rates, signs, consistent, found, linear


def _static_kinematics(mechanism, q):
    """Positions only, zero velocities and no inertia (the mechanism at rest)."""
    kin = coefficients(mechanism, q, order=0).kinematics(jnp.zeros_like(q))
    zeros = lambda d: jax.tree.map(jnp.zeros_like, d)  # noqa: E731
    return eqx.tree_at(
        lambda k: (k.velocities, k.com_velocities, k.angular_velocities),
        kin,
        (zeros(kin.points), zeros(kin.coms), zeros(kin.angles)),
        is_leaf=lambda x: x is None,
    )


def _single(model: Model, q, omega, alpha, t, method: str, groups, static: bool, rests: bool = True):
    """(forces, couples, driving, ok, friction, friction power, friction ok) at one state;
    ``rests``: whether some state of the batch may be held at rest (see :func:`reactions_at`)."""
    if static:
        statics = from_kinematics(model, _static_kinematics(model.mechanism, q), t, method=method, groups=groups)
        return statics + ({}, {}, jnp.array(True))
    coeffs = coefficients(model.mechanism, q, order=2)
    if not frictions_of(model.loads):
        return reactions_at(model, coeffs, omega, alpha, t, method=method, groups=groups) + ({}, {}, jnp.array(True))
    *reaction, u, rates, consistent = reactions_at(model, coeffs, omega, alpha, t, method=method, groups=groups, friction=True,
                                                   rests=rests)
    friction, power = {}, {}
    for k, element in enumerate(frictions_of(model.loads)):  # two elements on one pair add up
        friction[element.pair] = friction.get(element.pair, 0.0) + u[k]
        power[element.pair] = power.get(element.pair, 0.0) + u[k] * rates[k] * omega
    return tuple(reaction) + (friction, power, consistent)


def reactions_at(model: Model, coeffs: Coefficients, omega, alpha, t, *, method: str = "modular", groups=None,
                 friction: bool = False, rests: bool = True):
    """Reactions at one state from the kinematic coefficients (order 2) the dynamics
    already computed: (forces, couples, driving effort, ok per group). Affine in the
    driving acceleration ``alpha`` (d'Alembert forces are linear in it) and in the
    friction values, which are solved for first when the model has joint friction:
    their signs follow omega, at rest those of the motion that starts (sign(alpha): the
    right limit the dynamics integrates). Held at rest (omega = alpha = 0), any drive
    between the two break-away limits keeps the mechanism there: the drive of the model's
    driving loads (:func:`assurjax.driver_effort`, 0 without them) is reported, or the limit
    nearest it where it is outside them, with the friction values between those of the two
    limits in proportion
    (how static friction shares out between the pairs is not determined by statics), an
    element on its dead point clipped to its limit (:func:`_clipped_dead`); the
    limits of the static coefficients, where elements have them.
    ``friction=True`` (a model with friction): also the friction values u, the
    elements' relative rates per unit driving velocity (K,) and whether the friction has a
    consistent solution (held: both limits, and the values within their limits). ``rests``
    False: no state is held at rest, and the program leaves out the analysis of a held self-locked mechanism (1.6 s of the press's
    first call)."""
    kin = coeffs.kinematics(omega, alpha)
    if not frictions_of(model.loads):
        return from_kinematics(model, kin, t, method=method, groups=groups)
    direction = jnp.where(omega != 0, jnp.sign(omega), jnp.sign(alpha))
    # held at rest (direction 0): the limits of the static coefficients, where elements have them
    held_model = static_model(model, direction == 0)
    us, rates, signs, consistent, (forces, couples, driving, ok), linear = _both_ways(held_model, coeffs, kin, omega, t,
                                                                                      method, groups)
    # held: the drive the loads put on the driver (a Drive, a MotorLine at rest), or where it is
    # outside the band [tau_minus, tau_plus] (a held sample of a run needs none) its nearest edge
    drive = driver_effort(model.mechanism, model.loads, coeffs.q, omega, t, check=False)
    width = driving[1] - driving[0]  # <= 0: the band holds it
    share = jnp.clip((driving[1] - drive) / jnp.where(width != 0, width, 1.0), 0.0, 1.0)

    def pick(x):  # moving: that direction's; held: between the two limits (the reactions are affine in u)
        held = share * x[0] + (1.0 - share) * x[1]
        return jnp.where(direction > 0, x[0], jnp.where(direction < 0, x[1], held))

    def pick_flag(x):  # moving: that direction's; held: both limits'
        return jnp.where(direction > 0, x[0], jnp.where(direction < 0, x[1], x[0] & x[1]))

    u = pick(us)
    found = (jax.tree.map(pick, forces), jax.tree.map(pick, couples), pick(driving), pick_flag(ok))
    # held where a limit has no consistent friction (self-locked that way): the interpolation
    # above reads a limit that is none; there the friction carries the drive (_held_locked)
    fits = pick_flag(consistent)
    if rests:
        # held on an element's dead point (the same Coulomb sign both ways): see _clipped_dead
        bound = coulomb_limits(held_model.mechanism, kin, frictions_of(model.loads), *linear)
        clipped = _clipped_dead((direction == 0) & (signs[0] * signs[1] > 0), u, bound)
        # held: the set reported lies within every element's limit, or friction ok says not
        fits = fits & ((direction != 0) | _within_limits(clipped, bound(clipped)))
        locked = (direction == 0) & ~(consistent[0] & consistent[1])
        # a limit at the zero root (its pairs carry no load at rest: a wedge driven by nothing but
        # the drive) bounds no push: whether the friction holds one is the self-locking pattern's
        # test (the steep slider held inside its friction angle read 0 N everywhere, not its drive)
        trivial = jnp.all(us == 0, axis=-1)
        wedged = (direction == 0) & (trivial[0] | trivial[1])
        args = (held_model, kin, t, method, groups, drive, us, signs, consistent & ~trivial, linear)
        u, found, fits = _where_locked(locked, wedged, jnp.any(clipped != u), (clipped, found, fits), args)
    return found + (u, rates, fits) if friction else found


def _where_locked(locked, wedged, clipped, default, args):
    """``default`` (u, reactions, friction ok), or :func:`_held_locked`'s where ``locked``, and
    where ``wedged`` if its friction holds the drive there; the reactions solved afresh there and
    where ``clipped`` (``default``'s u is not that of its reactions: _clipped_dead). Computed only
    where some member of a batch is any (a cond on the batch, as finish_friction's)."""
    model, kin, t, method, groups = args[:5]

    def both():
        u, within = _held_locked(*args)
        take = locked | (wedged & within)
        u = jnp.where(take, u, default[0])
        found = from_kinematics(model, kin, t, method=method, groups=groups,
                                extra=friction_wrenches(model.mechanism, kin, frictions_of(model.loads), u))
        found = jax.tree.map(lambda a, b: jnp.where(take | clipped, a, b), found, default[1])
        return u, found, jnp.where(take, within, default[2])

    return jax.lax.cond(eqxi.unvmap_any(locked | wedged | clipped), both, lambda: default)


def _clipped_dead(dead, u, bound):
    """Held friction values ``u`` with those of the ``dead`` elements (on their dead point: the
    same Coulomb sign at both limits) clipped to their limits (``bound``: u -> limits). Between
    limits of opposite signs the mix of two values at their limits stays within the limit of
    the mix of their reactions (|a u1 - b u2| <= mu r |a F1 + b F2|); of one sign it need not
    (|F| is convex: pin B of an offset slider-crank held at its dead point read 113 % of its
    limit). Such an element's relative rate is 0: its friction does no work, so the drive
    stays. Its limit moves with its value (the reactions are affine in u): a fixed point,
    contracting by mu r |dF/du|; the other elements' values stay (friction ok tests the set)."""
    def clip():
        step = lambda _, v: jnp.where(dead, jnp.clip(u, -bound(v), bound(v)), u)  # noqa: E731
        return jax.lax.fori_loop(0, FIXED_POINT_STEPS, step, u)

    return jax.lax.cond(eqxi.unvmap_any(jnp.any(dead)), clip, lambda: u)


SELF_LOCK_STEPS = 60  # power iterations for the friction pattern a self-locked mechanism holds a push with


def _held_locked(model, kin, t, method, groups, drive, us, both_signs, consistent, linear):
    """(u, friction ok) held at rest under ``drive`` where a break-away limit has no
    consistent friction. On the drive's side (of the frictionless holding drive): where that
    limit is consistent, its friction scaled to the drive (the limit itself beyond it: the
    band's edge); where it is not (the friction alone holds any push that way), the friction's
    self-locking pattern v (v ~ law(v) with the reactions the friction itself makes; gravity
    and the loads left out) scaled to balance the drive. So ``driving`` is the drive and the
    pairs carry its load. Statics leaves the shares open: this is one set; friction ok says
    whether it lies within every element's static limit. ``us``, ``both_signs``, ``consistent``:
    :func:`_both_ways`'s, forward then backward."""
    mechanism, frictions = model.mechanism, frictions_of(model.loads)

    def solve(u):
        return from_kinematics(model, kin, t, method=method, groups=groups,
                               extra=friction_wrenches(mechanism, kin, frictions, u))

    free = solve(jnp.zeros(len(frictions)))[2]
    push = drive - free
    signs = jnp.where(push >= 0, both_signs[0], both_signs[1])  # those of a motion the way the drive pushes
    reactions0, basis = linear
    pattern = _self_locking_pattern(mechanism, kin, frictions, linear, signs.astype(free.dtype))[0]
    limit_ok = jnp.where(push >= 0, consistent[0], consistent[1])
    v = jnp.where(limit_ok, jnp.where(push >= 0, us[0], us[1]), pattern)
    per_unit = solve(v)[2] - free  # the driving effort is affine in u
    scale = push / jnp.where(per_unit != 0, per_unit, 1.0)
    u = jnp.where(limit_ok, jnp.clip(scale, 0.0, 1.0), scale) * v
    return u, _within_limits(u, coulomb_limits(mechanism, kin, frictions, reactions0, basis)(u)) & (per_unit != 0)


def _self_locking_pattern(mechanism, kin, frictions, linear, signs):
    """(v, own): the friction's self-locking pattern v ~ law(v) of the reactions the friction
    itself makes (gravity and the loads left out; max |v| = 1), by power iteration from the
    Coulomb ``signs``, and ``own``, u -> the Coulomb limits of those reactions."""
    reactions0, basis = linear
    own = coulomb_limits(mechanism, kin, frictions, jax.tree.map(jnp.zeros_like, reactions0), basis)

    def step(_, v):  # v <- law(v) of the friction's own reactions: the pattern self-locking grows
        w = signs * own(v)
        return w / jnp.maximum(jnp.max(jnp.abs(w)), 1e-300)

    return jax.lax.fori_loop(0, SELF_LOCK_STEPS, step, signs), own


def _within_limits(u, bound):
    """Whether the friction values u lie within their Coulomb limits ``bound`` (to round-off)."""
    return jnp.all(jnp.abs(u) <= bound * (1.0 + 1e-6) + 1e-12 * jnp.max(bound))


def from_kinematics(model, kin: Kinematics, t, *, method: str = "modular", groups=None, extra=None, batched: bool = True,
                    at_pairs=None):
    """Reactions at one state given its kinematics (order 2, or order 0 with zero
    velocities for statics): (forces, couples, driving effort, ok per group).
    ``model``: a :class:`assurjax.Model` or a Scene. ``extra``: link -> (force, moment
    about the COM) added to the applied loads (the friction wrenches). ``at_pairs``
    (names): only the (forces (P, 2), couples (P,), 0 on a revolute) of those pairs,
    stacked, by :func:`stacked_at`."""
    model = as_model(model)
    mechanism = model.mechanism
    wrenches = applied_wrenches(mechanism, model.gravity, model.loads, kin, t, check=False)
    for link, (f, m) in (extra or {}).items():
        wrenches[link] = (wrenches[link][0] + f, wrenches[link][1] + m)
    known = _known_wrenches(mechanism, kin, wrenches)
    geom = _geometry(kin)
    if method == "global":
        found, driving, ok = solve_global(mechanism, geom, known)
        stacks = [((name,), r.force, r.couple) for name, r in found.items()]
    else:
        found, driving, ok, stacks = solve_groups(mechanism, geom, known, method=method, groups=groups, batched=batched)
    if at_pairs is not None:
        return stacked_at(stacks, at_pairs)
    forces = {k: r.force for k, r in found.items()}
    couples = {k: r.couple for k, r in found.items() if k in _prismatic_names(mechanism)}
    return forces, couples, driving, ok & kin.ok


def _prismatic_names(mechanism):
    return {p.name for ps in group_pairs(mechanism) for p in ps if p.kind == "P"}


@jit
def _batch(model, q, omega, alpha, t, method, groups, static, rests=True):
    shape = q.shape
    single = lambda q, w, a, t: _single(model, q, w, a, t, method, groups, static, rests)  # noqa: E731
    flat = jax.vmap(single)(*(v.reshape(-1) for v in (q, omega, alpha, t)))
    *found, friction_ok = jax.tree.map(lambda x: x.reshape(shape + x.shape[1:]), flat)
    return (*found, friction_ok & in_range(model.loads))  # a traced value out of range (a negative mu): no statics


def _batched(model, state: tuple, *options, program=None):
    """``program`` (default :func:`_batch`) of the states (arrays of one shape) and ``options``,
    in chunks (``_jit.chunk_rows``) where the friction asks for them
    (``_friction.states_per_call``) and the call is outside any trace (inside one, each
    chunk's call would inline a copy)."""
    program = _batch if program is None else program
    n, chunk = state[0].size, states_per_call(frictions_of(model.loads))
    if chunk is None or n <= chunk or not at_top_level():
        return program(model, *state, *options)
    flat = [v.reshape(-1) for v in state]
    pieces = [program(model, *(v[rows] for v in flat), *options) for rows in chunk_rows(n, chunk)]
    return jax.tree.map(lambda *xs: jnp.concatenate(xs)[:n].reshape(state[0].shape + xs[0].shape[1:]), *pieces)


def may_rest(omega, alpha) -> bool:
    """Whether some state may be held at rest (omega = dw/dt = 0): True where they are traced."""
    omega, alpha = concrete(omega), concrete(alpha)
    return omega is None or alpha is None or bool(np.any((omega == 0) & (alpha == 0)))


def _state(state):
    """(q, omega, alpha, t) from a Solution-like object, a mapping or a tuple."""
    if isinstance(state, dict):
        get = state.get
    elif isinstance(state, (tuple, list)):
        if len(state) not in (3, 4):
            raise AssurjaxError(f"a state is (q, omega, domega/dt[, t]); got a sequence of {len(state)}")
        return tuple(state) + ((0.0,) if len(state) == 3 else ())
    else:
        get = lambda k, d=None: getattr(state, k, d)  # noqa: E731
    q, omega = get("q"), get("omega")
    alpha = next((v for v in (get("domega"), get("alpha"), get("wdot")) if v is not None), None)
    if q is None or omega is None or alpha is None:
        raise AssurjaxError("a state needs q, omega and domega (dw/dt); pass a Solution, a dict or a tuple (q, omega, domega[, t])")
    t = get("t")
    return q, omega, alpha, 0.0 if t is None else t


STATE_NAMES = ("q", "omega", "domega", "t")


def _checked_shape(state) -> tuple[int, ...]:
    """The common shape of (q, omega, domega, t); raise with their shapes where they do not
    broadcast together or hold too many states, or naming one that is not finite (t first:
    inverse_dynamics computes the others from it; traced values: shapes only)."""
    q, omega, alpha, t = state
    shapes = [np.shape(v) for v in state]
    try:
        shape = jnp.broadcast_shapes(*shapes)
    except ValueError:
        raise AssurjaxError("a state's q, omega, domega and t must broadcast together, got shapes "
                            + ", ".join(f"{n} {s}" for n, s in zip(STATE_NAMES, shapes))) from None
    # the count first: a scan of 3e8 broadcast states for NaN took 5 s and 5 GB before it was refused
    check_state_count(AssurjaxError, "reactions", shape)
    check_values(AssurjaxError, "state", t=t, q=q, omega=omega, domega=alpha)
    return shape


def _wanted_groups(mechanism: Mechanism, joints) -> tuple[int, ...] | None:
    if joints is None:
        return None
    pairs = group_pairs(mechanism)
    where = {p.name: p.group for ps in pairs for p in ps}
    joints = (joints,) if isinstance(joints, str) else tuple(joints)
    unknown = [j for j in joints if j not in where]
    if unknown:
        raise AssurjaxError(f"unknown joint(s) {few(unknown)} in mechanism '{mechanism.name}' (joints: {few(where)})")
    return groups_for(mechanism, pairs, {where[j] for j in joints} | {0})


def reactions(scene, state, *, joints: Iterable[str] | str | None = None, method: str = "modular", check: bool = True) -> Reactions:
    """Joint reactions and driving effort (kinetostatics, Durango et al. 2014 section 3.3 and Calle et al. 2014).

    **Arguments:**
    - ``scene``: a :class:`assurjax.Scene` or :class:`assurjax.Model` (mechanism,
      gravity, loads), or a bare :class:`assurjax.Mechanism` (no loads, no gravity).
    - ``state``: a Solution (its ``t``, ``q``, ``omega``, ``domega``), a dict with
      those keys, or a tuple ``(q, omega, domega[, t])``; arrays of any (common)
      shape give results with that shape in front. A Solution that saved points or
      links this mechanism lacks is refused (a motion of another mechanism).
    - ``joints``: only these joints (names as in :attr:`Reactions.forces`); only the
      groups they need are solved, plus the driver. Default: all.
    - ``method``: ``"modular"`` (group by group, closed forms and special Assur
      points where implemented), ``"dense"`` (group by group, each group's full
      3 n x 3 n system), ``"global"`` (one linear system for the whole mechanism;
      a reference).
    - ``check``: raise :class:`SingularConfigurationError` or
      :class:`assurjax.AssemblyError` naming the group at fault (outside jit).

    Loads: gravity and the scene's loads (:func:`assurjax.applied_wrenches`) plus
    the inertia force -m a_G and couple -J alpha of every link (d'Alembert), with
    accelerations from :func:`assurjax.kinematics`. The driving effort is what the
    driver must supply for the motion, whatever the scene's drive loads give; held at rest
    with joint friction (omega = dw/dt = 0), where statics leaves it open between the
    break-away limits, it is the drive of those loads while the band holds it, else the
    limit nearest it (docs/kinetostatics.md).

    **Example:**
    >>> scene = assurjax.load_scene("watt_sixbar")
    >>> r = assurjax.reactions(scene, (0.3, 1.0, 0.0))
    >>> r["A"].shape, r.driving.shape
    ((2,), ())
    """
    return _run(scene, _state(state), joints, method, check, static=False, source=state)


# A Solution's saved outputs by the kind of name they are keyed by: the only mark of its
# mechanism it carries (one that saved none passes unchecked)
SAVED_BY_POINT = ("points", "velocities", "accelerations")
SAVED_BY_LINK = ("angles", "coms", "com_velocities", "com_accelerations", "angular_velocities", "angular_accelerations")


def check_saved_names(mechanism: Mechanism, solution) -> None:
    """Raise where ``solution`` (a Solution, or an object like one) was simulated on a mechanism
    with other point names, or saved outputs of points or links that ``mechanism`` lacks: it
    is the motion of another mechanism (the Watt six-bar's reactions along a slider-crank's
    Solution were computed without a word)."""
    if isinstance(solution, (dict, tuple, list)):  # a bare state: no names to compare
        return
    simulated = getattr(solution, "mechanism_points", None)
    if simulated is not None and set(simulated) != set(mechanism.point_names):
        differences = [f"{what} the point(s) {few(names)}" for what, names in (
            ("with", [n for n in simulated if n not in mechanism.point_names]),
            ("without", [n for n in mechanism.point_names if n not in simulated])) if names]
        raise AssurjaxError(f"reactions: the Solution is not a motion of mechanism '{mechanism.name}': it was simulated "
                            f"on a mechanism {' and '.join(differences)} (simulate this scene; or, for its reactions "
                            "along that motion, pass (sol.q, sol.omega, sol.domega, sol.t))")
    known = {"point": set(mechanism.point_names), "link": set(mechanism.links)}
    for kind, fields in (("point", SAVED_BY_POINT), ("link", SAVED_BY_LINK)):
        for field in fields:
            saved = getattr(solution, field, None)
            unknown = [name for name in saved if name not in known[kind]] if isinstance(saved, Mapping) else []
            if unknown:
                raise AssurjaxError(f"reactions: the Solution is not a motion of mechanism '{mechanism.name}': it saved "
                                    f"{field} of the {kind}(s) {few(unknown)}, which that mechanism lacks (simulate this "
                                    "scene; or, for its reactions along that motion, pass (sol.q, sol.omega, "
                                    "sol.domega, sol.t))")


def inverse_dynamics(scene, motion, t, *, joints: Iterable[str] | str | None = None, method: str = "modular",
                     check: bool = True) -> Reactions:
    """Inverse dynamics along a prescribed motion: the driving effort (N m for a crank, N
    for a slider) and the joint reactions (N) that make the mechanism follow it, with
    every load of the scene (gravity, springs, dampers, joint friction).

    **Arguments:**
    - ``scene``: a Scene, Model or Mechanism.
    - ``motion``: the driving coordinate as a JAX function of time ``q(t)`` (rad or m;
      its velocity and acceleration are taken by jvp, exactly), or samples
      ``(q, omega, domega)`` at the times ``t`` (arrays of the same shape).
    - ``t``: times (s), any shape.
    - ``joints``, ``method``, ``check``: as in :func:`reactions`.

    Returns :class:`Reactions` with the shape of ``t`` in front; ``driving`` is the effort.

    **Example** (the Watt six-bar driven at a steady 2 rad/s):
    >>> r = assurjax.inverse_dynamics(scene, lambda t: 0.3 + 2.0 * t, np.linspace(0, 1, 101))
    >>> r.driving.shape
    (101,)
    """
    check_state_count(AssurjaxError, "inverse_dynamics: the times t", np.shape(t))  # before a scan of them
    check_values(AssurjaxError, "inverse_dynamics", t=t)
    t = jnp.asarray(t, dtype=float)
    if callable(motion):
        if (signature := unbindable(motion, 1)) is not None:  # as the loads' functions are checked
            raise AssurjaxError(f"inverse_dynamics: motion must be a function of the time alone, q(t); the one given "
                                f"takes {signature}")
        q, omega, alpha = _derivatives(_as_float(motion), t)
    else:
        if not isinstance(motion, (tuple, list)) or len(motion) != 3:
            raise AssurjaxError("motion must be a function q(t) or samples (q, omega, domega) at the times t")
        q, omega, alpha = (jnp.asarray(v, dtype=float) for v in motion)
    return reactions(scene, (q, omega, alpha, t), joints=joints, method=method, check=check)


def _as_float(motion):
    """``motion`` returning floats (an integer q(t), e.g. a crank held at q = 1, has no
    derivative to take), and refusing what is no number by name."""
    def q(t):
        try:
            value = motion(t)
        except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError) as e:
            raise AssurjaxError("inverse_dynamics: motion q(t) must be written with jax.numpy (jnp.sin, not np.sin, "
                                "and no Python if on t): its derivatives are taken by jax.jvp, which traces it "
                                f"({type(e).__name__})") from None
        if not hasattr(value, "dtype") and not isinstance(value, (int, float)) or isinstance(value, bool):
            raise AssurjaxError(f"inverse_dynamics: motion q(t) must return a number, it returns {value!r:.60}")
        if hasattr(value, "dtype") and not jnp.issubdtype(value.dtype, jnp.number):
            raise AssurjaxError(f"inverse_dynamics: motion q(t) must return a number, it returns an array of {value.dtype}")
        return jnp.asarray(value, dtype=float)

    return q


def _derivatives(motion, t):
    """q, dq/dt, d2q/dt2 of a function of time, by nested jvps, at every time."""

    def rates(t):
        def first(t):
            q, w = jax.jvp(motion, (t,), (jnp.ones_like(t),))
            if jnp.shape(q) != ():  # read while it is traced here anyway
                raise AssurjaxError(f"inverse_dynamics: motion q(t) must return a single number at a time t, it returns {found_words(jnp.shape(q))}")
            return q, w

        (q, w), (_, a) = jax.jvp(first, (t,), (jnp.ones_like(t),))
        return q, w, a

    flat = jax.vmap(rates)(t.reshape(-1))
    return tuple(jnp.asarray(v, dtype=float).reshape(t.shape) for v in flat)


def static_torque(scene, q, *, t=0.0, check: bool = True) -> Array:
    """The driving torque (N m; N for a slider) that holds the mechanism at rest at
    ``q`` (w = dw/dt = 0) against gravity and the scene's loads: the balancing
    torque of gravity-balancing studies. Any shape of ``q``. Joint friction is left out:
    with it, any drive within the friction's break-away band (:func:`breakaway_band`) holds
    the mechanism, and ``reactions(scene, (q, 0.0, 0.0))`` gives the scene's own drive there, or
    without one the drive nearest 0 (with the friction values)."""
    return static_reactions(scene, q, t=t, check=check).driving


def breakaway_band(scene, q, *, t=0.0, check: bool = True) -> tuple[Array, Array]:
    """The break-away band of the mechanism held at rest at ``q``: (lower, upper), the
    driving torques (N m; N for a slider) at which a motion from rest starts backward
    (-q) and forward (+q) against gravity, the scene's loads other than its drives (a
    ``Drive``, a ``MotorLine``: the band's drive stands in their place) and the joint
    friction (its Coulomb signs those of each start, its coefficients the static ones where
    elements have them). Any drive within the band holds the
    mechanism (stiction); ``simulate`` sticks and breaks away by the same limits. Without
    friction both are :func:`static_torque`. Where no drive starts the mechanism one way
    (the friction self-locks that start: driven just past the edge, the forward dynamics
    has no consistent friction, or does not move that way), that edge is infinite:
    ``upper`` +inf, ``lower`` -inf. Without inertia at ``q`` (a drawing without masses) there
    is no dw/dt to test: the statics decide, as ``reactions`` at rest reads them (an edge
    whose friction is consistent bounds the band). Just past an edge the mechanism starts; where a pair
    self-locks harder the harder it is pushed, a much larger drive can hold it again (the
    drives that hold need not be one interval: the band is the one about the frictionless
    holding drive).
    Any shape of ``q`` (and ``t``, broadcast with it); ``check``: as in :func:`reactions`.
    Differentiable (``jax.grad``, ``jax.jacfwd``); where an element's ``static_coefficient``
    equals its ``coefficient`` the band depends on the static one alone, so the derivative
    in ``coefficient`` is 0 there and all of it goes to ``static_coefficient``.

    **Example** (the torque a motor needs to start a mechanism from rest, either way):
    >>> lower, upper = assurjax.breakaway_band(scene, jnp.linspace(0.0, 3.14, 50))
    """
    if isinstance(scene, Mechanism):  # a bare mechanism's band was silently (-0, -0)
        raise AssurjaxError("breakaway_band: takes a scene (a Scene or a Model), with its loads and gravity, whose "
                            "friction makes the band; got a Mechanism")
    model = as_model(scene, what="breakaway_band")
    if not frictions_of(model.loads):
        torque = static_torque(model, q, t=t, check=check)
        return torque, torque
    shape = _checked_shape((q, 0.0, 0.0, t))
    q, t = (jnp.broadcast_to(jnp.asarray(v, dtype=float), shape) for v in (q, t))
    lower, upper, ok = _batched(static_model(model), (q, t), program=_band)  # at rest: the static coefficients
    if check:
        raise_if_singular(model.mechanism, ok, q)
    valid = in_range(model.loads)  # a traced value out of range (a negative mu): no band, as for a NaN one
    return jnp.where(valid, lower, jnp.nan), jnp.where(valid, upper, jnp.nan)


BEYOND_EDGE = 1e-9  # a start is tested with the drive past a band's edge by this much (times 1 + the edges' sizes)
EDGE_SPACINGS = 1e3  # and by at least this many float spacings (float32)


@jit
def _band(model: Model, q, t):
    """(lower, upper, ok per group) of :func:`breakaway_band` with joint friction, at states (arrays of one shape).
    Each edge: the drive of a start that way at dw/dt = 0 (inverse dynamics with that start's
    Coulomb signs); it stands where the forward dynamics, driven just past it, starts the
    mechanism that way (the test ``simulate`` breaks away by): at dw/dt = 0 the friction can
    have a root that a start has not (a slider pushed through a rod steeper than its friction
    angle: zero force, zero friction, while any push wedges it)."""
    from ..dynamics._field import State, frictional  # the dynamics build on the kinetostatics

    undriven = tuple(load for load in model.loads if not drives(load))
    # as the other analyses of many states: Newton's method alone up to SUMMED_TERMS elements
    # (both of the solve's loops in one batched program stalled XLA's CPU runtime, see solve_friction)
    iterate = len(frictions_of(model.loads)) > SUMMED_TERMS

    def one(q, t):
        coeffs = coefficients(model.mechanism, q, order=2)  # the forward dynamics read its d2x too
        kin, at_rest = coeffs.kinematics(jnp.zeros(()), jnp.zeros(())), jnp.zeros(())
        us, rates, signs, consistent, (_, _, driving, ok), linear = _both_ways(model, coeffs, kin, at_rest, t,
                                                                               "modular", None)
        # in float32 1e-9 is below the float spacing: the test ran at the edge, where the sign of
        # dw/dt is rounding (10 of 13 edges of the slider-crank's band came out infinite)
        beyond = max(BEYOND_EDGE, EDGE_SPACINGS * float(jnp.finfo(driving.dtype).eps))
        # (1 + the edges' sizes: relative to the edges alone, a float32 edge came out infinite, the
        # push within the rounding of the torques it balances; for a milligram mechanism the push
        # is then far past its band, which tests the same: whether a push beyond the edge starts it)
        past = beyond * (1.0 + jnp.abs(driving[0]) + jnp.abs(driving[1]))

        def starts(edge, way):  # the forward dynamics at rest, driven just past the edge; and J_red
            driven = Model(model.mechanism, model.gravity, undriven + (Drive(edge + way * past),))
            f = frictional(driven, t, State(q, at_rest), way, iterate=iterate, coeffs=coeffs)
            return f.consistent & (way * f.alpha > 0), f.red.inertia

        (forward, inertia), (backward, _) = starts(driving[0], 1.0), starts(driving[1], -1.0)
        # no inertia at q (a drawing without masses): no dw/dt to test (it was 0/0, every edge
        # infinite); a quasi-static band needs none: the statics' own test, as reactions at rest reads it
        massless = inertia == 0
        statics = _bounds_by_statics(model, kin, us, rates, signs, consistent, linear, massless)
        forward, backward = jnp.where(massless, statics, jnp.stack([forward, backward]))
        # an edge NaN (a NaN coefficient, traced) stays NaN, not an infinite edge
        return (jnp.where(backward | jnp.isnan(driving[1]), driving[1], -jnp.inf),
                jnp.where(forward | jnp.isnan(driving[0]), driving[0], jnp.inf), ok[0])

    flat = jax.vmap(one)(q.reshape(-1), t.reshape(-1))
    return jax.tree.map(lambda x: x.reshape(q.shape + x.shape[1:]), flat)


def _bounds_by_statics(model, kin, us, rates, signs, consistent, linear, wanted):
    """(2,): whether each limit of :func:`_both_ways` (forward, backward) bounds the drives that
    hold the mechanism at rest, by statics alone (for a mechanism without inertia, ``wanted``):
    a limit with consistent friction does (not self-locked that way); one at the zero root (a
    wedge: its pairs carry no load but the friction's own) does where the friction's
    self-locking pattern cannot hold a push, whatever its size (the test of ``reactions`` at
    rest, :func:`_held_locked`, whose scaled pattern's limits scale with it)."""
    mechanism, frictions = model.mechanism, frictions_of(model.loads)
    trivial = jnp.all(us == 0, axis=-1)

    def holds(signs):  # the pattern, its drive by virtual work at rest (-rates . v)
        v, own = _self_locking_pattern(mechanism, kin, frictions, linear, signs.astype(rates.dtype))
        return _within_limits(v, own(v)) & (jnp.sum(rates * v) != 0)

    # computed only where some member of a batch needs it (a cond, as _where_locked's)
    wedged = jax.lax.cond(eqxi.unvmap_any(wanted & jnp.any(trivial)), lambda: jax.vmap(holds)(signs),
                          lambda: jnp.zeros(2, dtype=bool))
    return (consistent & ~trivial) | (trivial & ~wedged)


def static_reactions(scene, q, *, t=0.0, joints=None, check: bool = True) -> Reactions:
    """All reactions of the mechanism held at rest at ``q`` (see :func:`static_torque`)."""
    return _run(scene, (q, 0.0, 0.0, t), joints, "modular", check, static=True)


def _run(scene, state, joints, method, check, *, static, source=None):
    """The reactions along ``state``; ``source``: what the state was read from (a Solution's
    saved names are checked against the mechanism)."""
    if method not in METHODS:
        raise AssurjaxError(f"method must be one of {METHODS}, got {method!r}")
    model = as_model(scene, what="static_reactions" if static else "reactions")
    mechanism = model.mechanism
    check_saved_names(mechanism, source)
    groups = _wanted_groups(mechanism, joints)
    shape = _checked_shape(state)
    q = jnp.asarray(state[0], dtype=float)
    q, omega, alpha, t = (jnp.broadcast_to(jnp.asarray(v, dtype=float), shape) for v in (q,) + tuple(state[1:]))
    forces, couples, driving, ok, friction, friction_power, friction_ok = _batched(model, (q, omega, alpha, t), method, groups,
                                                                                  static, may_rest(omega, alpha))
    if joints is not None:
        names = (joints,) if isinstance(joints, str) else tuple(joints)
        forces = {k: forces[k] for k in names}
        couples = {k: v for k, v in couples.items() if k in names}
    pairs = tuple(p for ps in group_pairs(mechanism) for p in ps)
    jam_state = at_jam_state(source, shape)
    if jam_state is not None:
        friction_ok = friction_ok & ~jam_state
    result = Reactions(forces=forces, couples=couples, driving=driving, ok=ok, pairs=pairs, friction=friction,
                       friction_power=friction_power, friction_ok=friction_ok)
    if check:
        if method == "global" and not isinstance(ok, jax.core.Tracer) and not np.asarray(ok).all():
            # one system for all: its flag says the mechanism is singular, not where. The system is
            # block-triangular in the formation sequence, singular where some group's block is:
            # the group-by-group solve's flags name that group
            ok = _batched(model, (q, omega, alpha, t), "modular", groups, static, may_rest(omega, alpha))[3]
        raise_if_singular(mechanism, ok, q)
    return result


def at_jam_state(solution, shape) -> np.ndarray | None:
    """Where ``solution``'s samples (broadcast to ``shape``) are the state where the joint
    friction jammed its run (at its ``t_final``): the motion has no dw/dt there, and the
    statics read from the saved one stand for none. None where no run jammed (or the
    jam is not known: a bare state, or a Solution from jit/vmap)."""
    jammed = getattr(solution, "jammed", None)  # None for a bare state (a dict, a tuple)
    if jammed is None or not np.any(jammed):
        return None
    t, t_final, jammed = np.asarray(solution.t), np.asarray(solution.t_final), np.asarray(jammed, dtype=bool)
    at_end = (t >= t_final[..., None]) & jammed[..., None] if t.ndim > t_final.ndim else (t >= t_final) & jammed
    return np.broadcast_to(at_end, shape)


def raise_if_singular(mechanism: Mechanism, ok, q) -> None:
    """Raise naming the first group whose equations are singular (no-op under tracing)."""
    failure = first_failure(mechanism, ok, q)
    if failure is None:
        return
    group, q_bad, how_many = failure
    # a group that does not close there says so (kinematics' error), where its statics is not singular but void
    pose = positions(mechanism, q_bad)
    raise_if_not_assembled(mechanism, pose.ok, q_bad, pose=pose)
    raise SingularConfigurationError(
        f"{group.describe()}: its equilibrium equations are singular at q = {q_bad:.6g}{how_many}. A singular group (e.g. a dyad with "
        "its links collinear) cannot carry a general load: its reactions are not determined by statics",
        group=group.name,
    )
