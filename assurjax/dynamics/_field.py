"""The vector field of the reduced link: the one place the equation of motion is assembled.

The state is y = (q, w) plus, when asked for, the work W of every load outside the
potential energy, the work D removed by dissipative loads, and the link angles of a
tracked branch:

    dq/dt = w,
    dw/dt = (tau + tau_red - 0.5 dJ_red/dq w^2) / J_red     (:func:`reduced_acceleration`),
    dW/dt = (tau + tau_red outside V) w,    dD/dt = dissipated power,
    dtheta/dt = dtheta/dq w.

Every evaluation redoes the reduction at (q, w, t) (Durango et al.'s (2014) step v: velocity-dependent
loads are updated at every stage); when no load depends on velocity the velocity part
is never built. With a :class:`ReducedTable` the field interpolates it instead.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._friction import (FIXED_POINT_TOLERANCE, SUMMED_TERMS, FixedPoint, coulomb_limits, coulomb_signs, end_loads,
                         finish_friction_implicit, friction_wrenches, frictions_of, has_static, iterate_friction,
                         linearize_reactions, rates_and_slopes, signs_ahead, smoothed_only, solve_friction, static_model,
                         with_block_signs)
from .._jit import FlatLayout, flattened_floats, jit, moved_leaves, region
from .._kinematics import branch_coefficients
from .._kinetostatics._api import from_kinematics
from .._loads import dissipated_power, tables_in, with_pieces
from .._model import Model
from .._reduction import reduce_coefficients, reduce_with_kinematics, reduced_acceleration
from .._tracking import branch_mapping, branch_rates, stacked_branch
from .._values import all_finite
from ._table import ReducedTable


class State(NamedTuple):
    """The integrated state: ``q`` (rad or m), ``omega`` (rad/s or m/s), and optional
    quadratures ``work`` (J, loads outside V), ``dissipated`` (J), the tracked
    ``branch`` angles (rad, stacked in ``tracked_links`` order) and, with joint friction,
    the ``friction_rates`` d phi_k/dq of its elements (integrated, d/dt = d2 phi_k/dq2 w,
    so that a stop condition sees where one changes sign). Absent parts are None."""

    q: Array
    omega: Array
    work: Array | None = None
    dissipated: Array | None = None
    branch: Array | None = None
    friction_rates: Array | None = None


class FieldArgs(eqx.Module):
    """What the vector field and the events read besides the state: the ``model``, an
    optional ``table``, the start (``direction`` of motion, ``q0``) for the standstill
    margin, the signs of the user events at t0 and, with joint friction, the signs of
    the elements' d phi_k/dq frozen for the segment (None: read at each state)."""

    model: Model
    table: ReducedTable | None
    direction: Array
    q0: Array
    user_signs: tuple | None
    rate_signs: Array | None = None
    coeffs: object = None  # a stick segment's kinematic coefficients (its q stays; see frictional)
    # a slip segment's prismatic pairs' block-end signs (K, 2), frozen (_friction.with_block_signs), and the
    # floors of its event's margins s x - floor, which start > 0 (_stick._block_signs)
    end_signs: Array | None = None
    end_floor: Array | None = None
    # a slip segment's next knots of the loads' tables (_loads.next_knot), in q ahead in its direction and in t,
    # then its piece's bounds in omega (_loads.piece_around); and the tables' pieces it runs on
    # (_loads.pieces_at: those in q, then in t, then in omega)
    knots: Array | None = None
    pieces: Array | None = None
    bridge: float = eqx.field(static=True, default=0.0)  # singular-window bridging of a tracked branch (0: off)
    # the friction iteration's tolerance at each right-hand side (_friction.iteration_tolerance)
    friction_tolerance: float = eqx.field(static=True, default=FIXED_POINT_TOLERANCE)
    # NaN where some group cannot assemble: the lock-up controllers reject such steps (_settings.lockup_controller)
    nan_unassembled: bool = eqx.field(static=True, default=False)
    # the model handed to the field's regions as flat arrays (False where a vmap maps it, _jit.any_mapped)
    flat_model: bool = eqx.field(static=True, default=True)


def field_args(model: Model, table: ReducedTable | None = None, *, direction=1.0) -> FieldArgs:
    """The arguments of the vector field evaluated on its own (no stop events).
    ``direction``: of the motion, for the Coulomb signs of joint friction (0: held at rest)."""
    zero = jnp.zeros(())
    return FieldArgs(model=model, table=table, direction=jnp.asarray(direction, dtype=float), q0=zero, user_signs=None)


def vector_field(t, y: State, args: FieldArgs) -> State:
    """dy/dt of the reduced link (see the module docstring)."""
    from ._packed import UNPACKED  # it builds on State

    return packed_vector_field(t, y, args, UNPACKED)


def packed_vector_field(t, z, args: FieldArgs, packing):
    """:func:`vector_field` on a state as diffrax steps it, ``packing`` (a
    ``dynamics._packed.Packing``) its layout; the rates packed alike. The region takes the
    packed state whole, unpacks it and packs the rates inside its kernel: unpacked outside,
    each field was a call of its own to make (the press's step 121 -> 97 calls without
    friction, 3.7-3.8 -> 3.3-3.4 us); and the model flattened (``_jit.flattened_floats``:
    3.3 -> 2.9 us)."""
    if args.table is not None:
        y = packing.unpack(z)
        return packing.pack(State(y.omega, args.table.acceleration(y.q, y.omega)))
    if not frictions_of(args.model.loads):
        return _field(t, z, *_invariant(args), packing)
    return _friction_field(t, z, args, packing=packing)


def _invariant(args: FieldArgs) -> tuple:
    """What the field's regions take besides (t, z): the model as flat arrays, then the rest
    of args. Not args whole: a batch over starts has per-member values there (q0, direction),
    which would make the flat arrays, the model in them, per member (10 000 vmapped Watt
    six-bars 2.7 -> 4.3 s with all of args flattened)."""
    return (*flattened_floats(args.model, args.flat_model), dataclasses.replace(args, model=None))


@eqx.filter_custom_jvp
def _friction_field(t, z, args: FieldArgs, *, packing):
    """:func:`packed_vector_field` with joint friction; differentiated as :func:`_implicit_field`."""
    invariant = _invariant(args)
    # with friction: the field with the iteration's root, where it is settled; else, rarely,
    # again with the solve's fallback (outside the region, see _friction_start). As a region
    # the field hands back only its rates, and the fallback redoes the analysis: a region's
    # kernel is handed a pointer to every buffer it reads or writes at each call (the
    # analysis's results: the press's step 103.0k -> 90.8k instructions, callgrind; the price,
    # a second region to compile, the fallback's: first calls 0.4-2 s longer; its Newton
    # part is one kernel, _friction._newton_fallback, as everywhere a solve ends). Where the
    # field is no region, the fallback takes the analysis from it: done again, it is compiled
    # twice (the strandbeest with friction in 73 joints: its first call 19.9 -> 28.3 s)
    if _settled_rates.fits(t, z, *invariant, packing):
        rates, settled = _settled_rates(t, z, *invariant, packing)
        return jax.lax.cond(eqxi.unvmap_any(~settled),
                            lambda: packing.pack(_solved_field(t, packing.unpack(z), args)), lambda: rates)
    y = packing.unpack(z)
    rates, at, start = _settled_field(t, y, args)
    return packing.pack(jax.lax.cond(eqxi.unvmap_any(~start.fixed.settled),
                                     lambda: _field_from(t, y, args, at, start), lambda: rates))


@_friction_field.def_jvp
def _friction_field_jvp(primals, tangents, *, packing):
    """The field's derivative: that of :func:`_implicit_field`, one path whose friction values
    take their derivatives from the implicit function theorem. Through the field as it runs
    (the iteration's region, then a cond whose other branch redoes the whole analysis with
    Newton's method) reverse mode kept both branches at every stage (see
    ``_friction._implicit_root``)."""
    values, value_tangents, rebuild = moved_leaves(primals, tangents)

    def field(*values):
        t, z, args = rebuild(values)
        return packing.pack(_implicit_field(t, packing.unpack(z), args))

    return jax.jvp(field, values, value_tangents)


def _implicit_field(t, y: State, args: FieldArgs) -> State:
    """The friction field as one path: the analysis, then the friction values from
    ``_friction.solve_friction`` (the values of the field's own solve, their derivatives by
    the implicit function theorem)."""
    at = _evaluated_at(y, args)
    model = segment_model(args)
    start = _start(model, t, at, args.direction, kinematic_coefficients(model, at, args.bridge), args.rate_signs, True,
                   args.friction_tolerance, implicit=True)
    return _checked(y, args, *_rates(t, at, args, _finish(model, at, start)))


@region
def _field(t, z, flats, others, layout: FlatLayout, rest: FieldArgs, packing):
    y, args = packing.unpack(z), _rebuilt(flats, others, layout, rest)
    at = _evaluated_at(y, args)
    return packing.pack(_checked(y, args, *_rates(t, at, args, None)))


@region
def _settled_rates(t, z, flats, others, layout: FlatLayout, rest: FieldArgs, packing):
    rates, _, start = _settled(t, packing.unpack(z), _rebuilt(flats, others, layout, rest))
    return packing.pack(rates), start.fixed.settled


def _rebuilt(flats, others, layout: FlatLayout, rest: FieldArgs) -> FieldArgs:
    """The field's arguments from what :func:`packed_vector_field` hands its regions."""
    return dataclasses.replace(rest, model=layout.rebuild(flats, others))


@jit
def _settled_field(t, y: State, args: FieldArgs):
    return _settled(t, y, args)


def _settled(t, y: State, args: FieldArgs):
    """The field with the iteration's root (taken where it is settled), the state it was
    evaluated at and the friction analysis."""
    at, model = _evaluated_at(y, args), segment_model(args)
    start = _start(model, t, at, args.direction, kinematic_coefficients(model, at, args.bridge),
                   args.rate_signs, True, args.friction_tolerance)
    settled = _assembled(start, start.fixed.value, jnp.array(True), at)
    return _checked(y, args, *_rates(t, at, args, settled)), at, start


def _solved_field(t, y: State, args: FieldArgs) -> State:
    at = _evaluated_at(y, args)
    return _checked(y, args, *_rates(t, at, args, frictional(segment_model(args), t, at, args.direction, args.bridge,
                                                             args.rate_signs)))


def _field_from(t, y: State, args: FieldArgs, at: State, start) -> State:
    return _checked(y, args, *_rates(t, at, args, _finish(segment_model(args), at, start)))


def segment_model(args: FieldArgs) -> Model:
    """The model of a slip segment's field: its block-end signs frozen, its loads' tables read
    as their pieces at its start (each continued past the next knot, where an event ends it)."""
    model = args.model if args.end_signs is None else with_block_signs(args.model, args.end_signs)
    if args.pieces is None:
        return model
    loads, read = model.loads, 0
    for variable in ("q", "t", "omega"):
        count = len(tables_in(model.loads, variable))
        if count:
            loads, read = with_pieces(loads, variable, args.pieces[read:read + count]), read + count
    return eqx.tree_at(lambda m: m.loads, model, loads)


def block_loads(model: Model, t, y: State, direction, bridge: float, rate_signs):
    """(K, 2): the loads on the prismatic pairs' block ends (``_friction.end_loads``) in the
    motion at y in ``direction`` with the Coulomb signs ``rate_signs`` (as :func:`frictional`),
    at the fixed-point iteration's root: one region, without the solve's fallback (Newton's
    method in a cond, which made the press's first call with these loads in the events 1.9x
    and its warm run 1.45x); where the iteration has not settled its root is near enough to
    tell where a load changes sign."""
    t, direction = jnp.asarray(t, dtype=float), jnp.asarray(direction, dtype=float)
    return _block_loads(model, t, y, direction, bridge, rate_signs)


@region
def _block_loads(model: Model, t, y: State, direction, bridge: float, rate_signs):
    start = _start(model, t, y, direction, kinematic_coefficients(model, y, bridge), rate_signs, True)
    return end_loads(model.mechanism, start.kin, frictions_of(model.loads), start.linear, start.fixed.value)


def end_margins(t, y: State, args: FieldArgs):
    """Per block end of a slip segment (K, 2): its load times its frozen sign, less the floor
    of its start (> 0 there), positive until the load changes sign; inf where not frozen or
    without Coulomb friction.

    Without derivatives in the state or the parameters: the field is continuous where a load
    changes sign, so the time of such a cut enters a derivative times f- - f+ = 0 (unlike a
    Coulomb switch's, whose time carries the saltation). Differentiated, the analysis was
    one more copy of its derivative at each step and in the root find (the press's
    derivative's first call 2x). A unit slope in t is left to the margins, so that the root
    find's implicit derivative of the cut's time is 0 / 1, not 0 / 0."""
    model, at, y, direction, rate_signs = constant((segment_model(args), t, y, args.direction, args.rate_signs))
    loads = block_loads(model, at, y, direction, args.bridge, rate_signs)
    coulomb = jnp.stack([f.coefficient for f in frictions_of(model.loads)]) > 0
    margins = jnp.where(coulomb[:, None] & (args.end_signs != 0), args.end_signs * loads - args.end_floor, jnp.inf)
    margins = jnp.where(jnp.isnan(margins), jnp.inf, margins)  # a jam: the field stops the run
    return margins + (t - jax.lax.stop_gradient(t))


def constant(tree):
    """``tree`` with its float arrays cut off from derivatives (jax.lax.stop_gradient), so that
    what is computed from it traces no derivative at all."""
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_inexact_array(x) else x, tree)


def _evaluated_at(y: State, args: FieldArgs) -> State:
    """The state the field is evaluated at: y, or with ``nan_unassembled`` 0 where y is not
    finite. A stage after one that met NaN is evaluated at a finite state and its NaN put
    back (:func:`_checked`): reverse mode through a rejected step then meets no NaN
    derivative (0 * NaN)."""
    if not args.nan_unassembled:
        return y
    finite = all_finite(y)
    return jax.tree.map(lambda v: jnp.where(finite, v, 0.0), y)


def _checked(y: State, args: FieldArgs, rates: State, ok) -> State:
    """The rates, NaN with ``nan_unassembled`` where y is not finite or a group cannot assemble."""
    if not args.nan_unassembled:
        return rates
    assembles = all_finite(y) & jnp.all(ok)
    return jax.tree.map(lambda v: jnp.where(assembles, v, jnp.nan), rates)


def _rates(t, y: State, args: FieldArgs, f: Frictional | None):
    """(dy/dt, the groups' ok flags) of :func:`vector_field` without a table; ``f``: the
    friction analysis at the state, where the model has friction."""
    model = segment_model(args)
    slopes = None
    if f is not None:
        # the Coulomb signs of the segment (its direction of motion, the signs of the rates
        # d phi_k/dq), frozen until w returns to 0 or a rate changes sign (events end the
        # segment there): the field stays smooth inside a segment
        red, kin, alpha, friction_power, consistent, slopes = f.red, f.kin, f.alpha, f.power, f.consistent, f.raw_slopes
        # direction 0: held at rest by the friction (a stick segment): nothing moves; at rest
        # (w = 0) an acceleration not in the direction of motion, or no consistent friction:
        # held too (0: friction only resists, see rest_side; a segment from rest ends there at
        # once, see _settings.LockupController); moving, no consistent friction (a jam): NaN,
        # so that the solver stops there instead of running away
        if smoothed_only(frictions_of(model.loads)):  # no rest to hold: one smooth field, NaN where it jams
            alpha = jnp.where(consistent, alpha, jnp.nan)
        else:
            moving = args.direction != 0
            starts = consistent & (alpha * args.direction > 0)
            alpha = jnp.where(moving, jnp.where(y.omega != 0, jnp.where(consistent, alpha, jnp.nan),
                                                jnp.where(starts, alpha, 0.0)), 0.0)
            friction_power = jnp.where(moving, friction_power, 0.0)
    else:
        red, kin = _reduce(model, t, y, args.bridge)
        alpha, friction_power = red.acceleration(y.omega), jnp.zeros(())
    rates = State(
        q=y.omega,
        omega=alpha,
        work=None if y.work is None else red.work_force * y.omega + friction_power,
        dissipated=None if y.dissipated is None else dissipated_power(model.mechanism, model.loads, kin, check=False) - friction_power,
        branch=None if y.branch is None else stacked_branch(model.mechanism, branch_rates(red, near(model, y), y.omega)),
        friction_rates=None if y.friction_rates is None else slopes * y.omega,
    )
    return rates, red.ok


class Frictional(NamedTuple):
    """What :func:`frictional` gives: the reduction and its kinematics, dw/dt, the
    friction power (W, <= 0), whether the friction is consistent, and the elements'
    rates d phi_k/dq and their slopes d2 phi_k/dq2 (K,), both without round-off (what signs
    are read from), and the slopes as computed (what the integrated rates follow: a right-hand
    side needs no cleaning, and then XLA drops its terms)."""

    red: object
    kin: object
    alpha: Array
    power: Array
    consistent: Array
    rates: Array
    slopes: Array
    raw_slopes: Array


def frictional(model: Model, t, y: State, direction, bridge: float = 0.0, rate_signs=None, *, iterate: bool = True,
               coeffs=None) -> Frictional:
    """The reduction, its kinematics, dw/dt and the friction power of a model with
    friction in its joints: the reduced equation with the friction's generalized force
    sum_k u_k dphi_k/dq, u from ``solve_friction`` with the Coulomb signs
    ``rate_signs`` (the signs of d phi_k/dq; None or 0: read at the state) times the
    ``direction`` of motion (sign(w); 0: at rest, the direction of the frictionless
    generalized force, see :func:`rest_analysis`), and whether the friction has a
    consistent solution with those signs (see ``solve_friction``). ``iterate=False``:
    Newton's method alone (batched analyses, see ``solve_friction``). ``coeffs``: the
    kinematic coefficients at y.q, where the caller has them (a stick segment, whose q stays:
    its field and events then leave the position analysis out)."""
    # arrays: the nested jit below would take Python numbers as static and trace per value
    t, direction = jnp.asarray(t, dtype=float), jnp.asarray(direction, dtype=float)
    if coeffs is not None:
        return _finish(model, y, _friction_start_at(model, t, y, direction, coeffs, rate_signs, iterate))
    return _finish(model, y, _friction_start(model, t, y, direction, bridge, rate_signs, iterate))


def kinematic_coefficients(model: Model, y: State, bridge: float = 0.0):
    """The kinematic coefficients at y.q that :func:`frictional` reads (``coeffs``)."""
    return branch_coefficients(model.mechanism, y.q, near=near(model, y), bridge=bridge)


# A region (one kernel, _jit.region): a simulation with friction solves it in several places
# (the solver's stages, its first step's size, each segment's start, the outputs); traced once
# and reused, where each trace costs ~0.4 s. The rare Newton fallback stays outside it, in a
# cond after it: a region's kernel is handed every buffer of its computation at each call,
# taken or not (the press's step 13.9 -> 10.0 us).
@region
def _friction_start(model: Model, t, y: State, direction, bridge: float, rate_signs, iterate: bool) -> _Start:
    return _start(model, t, y, direction, kinematic_coefficients(model, y, bridge), rate_signs, iterate)


@region
def _friction_start_at(model: Model, t, y: State, direction, coeffs, rate_signs, iterate: bool) -> _Start:
    return _start(model, t, y, direction, coeffs, rate_signs, iterate)


class _Start(NamedTuple):
    """The friction analysis up to its fallback: the reduction and its kinematics, the rates
    (cleaned, their slopes cleaned and raw), the statics linear in u (and its inertial part),
    the Coulomb signs times the direction, and the iteration's outcome, or with ``iterate``
    off Newton's (u, ok)."""

    red: object
    kin: object
    rates: Array
    slopes: Array
    raw_slopes: Array
    linear: object
    inertial: object
    signs: Array
    fixed: FixedPoint | None
    solved: tuple | None


def _start(model: Model, t, y: State, direction, coeffs, rate_signs, iterate: bool,
           tolerance: float = FIXED_POINT_TOLERANCE, implicit: bool = False) -> _Start:
    mechanism, frictions = model.mechanism, frictions_of(model.loads)
    # the coefficients as whole arrays: their many readers (the reduction, the rates, the
    # statics) would otherwise make XLA compute each point apart (Watt six-bar RHS 4.2 -> 3.8 us)
    coeffs = eqx.tree_at(lambda c: c.stacked, coeffs, jax.lax.optimization_barrier(coeffs.stacked))
    red, kin = reduce_coefficients(mechanism, model.gravity, model.loads, coeffs, y.omega, t, work=y.work is not None,
                                   rates=y.branch is not None)

    rates, slopes, raw_slopes = rates_and_slopes(mechanism, frictions, coeffs)
    direction = jnp.where(direction != 0, direction, rest_side(red.force))
    ahead = signs_ahead(rates, slopes, direction, y.q)  # read at the state: those the motion goes on with
    signs = ahead if rate_signs is None else jnp.where(rate_signs != 0, rate_signs, ahead)
    alpha0 = _acceleration(red, rates, jnp.zeros(len(frictions)), y.omega)
    linear, inertial = _linear_reactions(model, coeffs, t, y.omega, alpha0, rates / red.inertia)
    signs = coulomb_signs(frictions, rates, y.omega, signs * direction)
    if implicit or not iterate:  # solved whole: Newton's method alone, or the iteration and its fallback
        solved = solve_friction(mechanism, frictions, linear, kin, rates, signs, y.omega, inertial=inertial,
                                iterate=iterate, tolerance=tolerance)
        return _Start(red, kin, rates, slopes, raw_slopes, linear, inertial, signs, None, solved)
    fixed = iterate_friction(mechanism, frictions, linear, kin, rates, signs, y.omega, inertial=inertial,
                             tolerance=tolerance)
    return _Start(red, kin, rates, slopes, raw_slopes, linear, inertial, signs, fixed, None)


def _finish(model: Model, y: State, start: _Start) -> Frictional:
    if start.fixed is None:
        u, ok = start.solved
    else:
        u, ok = finish_friction_implicit(model.mechanism, frictions_of(model.loads), start.linear, start.kin,
                                         start.rates, start.signs, y.omega, start.fixed, inertial=start.inertial)
    return _assembled(start, u, ok, y)


def _assembled(start: _Start, u, ok, y: State) -> Frictional:
    red, rates = start.red, start.rates
    return Frictional(red, start.kin, _acceleration(red, rates, u, y.omega), jnp.sum(rates * u) * y.omega, ok, rates,
                      start.slopes, start.raw_slopes)


def _acceleration(red, rates, u, omega):
    """dw/dt with the friction values u: their generalized force sum_k u_k dphi_k/dq added."""
    return reduced_acceleration(red.inertia, red.dinertia, red.force + jnp.sum(rates * u), omega)


def rest_side(force):
    """The only direction a mechanism at rest can start to move in: that of the generalized
    force without friction (tau + tau_red; +1 where it is 0). Coulomb friction only resists:
    the friction of a motion in direction s has s sum_k u_k dphi_k/dq <= 0, so
    J_red s dw/dt <= s (tau + tau_red): the other direction cannot accelerate away."""
    return jnp.where(force >= 0, 1.0, -1.0)


def start_kinematics(model: Model, t, y: State, bridge: float = 0.0):
    """What a segment of stick and slip starts from, without a friction solve: the only
    direction a motion from rest can take (:func:`rest_side` of the generalized force at
    w = 0), and the elements' d phi_k/dq and d2 phi_k/dq2 at the state's q. Whether it does
    start, the segment's own vector field tells (its first step stays at rest where the
    friction holds it). Also the kinematic coefficients at q, which a stick segment's field
    and events read (:func:`frictional`'s ``coeffs``)."""
    mechanism = model.mechanism
    coeffs = kinematic_coefficients(model, y, bridge)
    red, _ = reduce_coefficients(mechanism, model.gravity, model.loads, coeffs, jnp.zeros_like(y.omega), t)
    rates, slopes, _ = rates_and_slopes(mechanism, frictions_of(model.loads), coeffs)
    return rest_side(red.force), rates, slopes, coeffs


def _linear_reactions(model: Model, coeffs, t, omega, alpha0, dalpha):
    """The reactions affine in the friction values u: (at u = 0, their K tangents), where
    u acts through its wrenches and through dw/dt = alpha0 + dalpha . u; and that part
    through dw/dt (the reactions' K + 1 tangents, the first per unit dw/dt, and dalpha: the
    consistency test; the tangents whole, see ``solve_friction``). dw/dt enters the
    statics as d'Alembert wrenches (-m dG/dq, -J dtheta/dq per unit), so all K + 1
    directions are wrenches on the kinematics at dw/dt = 0: none is a K-fold copy of the
    accelerations (in a simulation such a copy over 512 bytes makes XLA's CPU runtime
    schedule the whole step's calls across threads: the Watt six-bar's right-hand side 7.2 -> 3.9 us)."""
    mechanism, frictions = model.mechanism, frictions_of(model.loads)
    base = coeffs.kinematics(omega, jnp.zeros(()))
    _, dcoms, dangles, _ = coeffs.dx
    inertial = {name: (-link.mass * dcoms[name], -link.inertia * dangles[name]) for name, link in mechanism.links.items()}

    def react(v, at_pairs=None):  # v = (dw/dt, u)
        extra = friction_wrenches(mechanism, base, frictions, v[1:])
        for name, (f, m) in inertial.items():
            f0, m0 = extra.get(name, (0.0, 0.0))
            extra[name] = (f0 + v[0] * f, m0 + v[0] * m)
        return from_kinematics(model, base, t, extra=extra, at_pairs=at_pairs)[:2]

    reactions0, basis = linearize_reactions(react, frictions, len(frictions) + 1)
    at_zero = jax.tree.map(lambda r, b: r + alpha0 * b[0], reactions0, basis)
    return (at_zero, jax.tree.map(lambda b: b[1:] + jnp.multiply.outer(dalpha, b[0]), basis)), (basis, dalpha)


def rest_analysis(model: Model, t, y: State, bridge: float = 0.0, coeffs=None):
    """(dw/dt of the motion a mechanism at rest would start, the direction s of that motion
    (:func:`rest_side`), the elements' d phi_k/dq and d2 phi_k/dq2) at the state's q: what a
    segment of stick and slip starts from. It breaks away where s dw/dt > 0, with the
    friction of a motion in direction s; dw/dt is 0 where that friction has no consistent
    solution (jammed). One friction solve: the other direction cannot start. ``coeffs``: see
    :func:`frictional`. With the static coefficients (``static_coefficient``), where elements
    have them: they hold a mechanism at rest."""
    # the signs as an array of zeros (read at the state), as the output samples and the stick
    # segments pass them, so that these calls share one trace of _friction_start (~0.3 s of a
    # first call; the right-hand side traces its own region, _settled_field)
    model = static_model(model)
    unset = jnp.zeros(len(frictions_of(model.loads)))
    f = frictional(model, t, y._replace(omega=jnp.zeros_like(y.omega)), 0.0, bridge, unset, coeffs=coeffs)
    return jnp.where(f.consistent, f.alpha, 0.0), rest_side(f.red.force), f.rates, f.slopes


def rest_jams(model: Model, t, y: State):
    """Whether a mechanism at rest jams there, and whether the values read were finite (with
    a NaN, a load's, no jam is claimed). It jams where the motion that alone can start
    (:func:`rest_side`) has no consistent friction (:func:`rest_analysis` reads its dw/dt as
    0, as if held) and no friction within its static limits holds it at rest either. (A
    slider pushed from the wrong side against a rod steeper than its friction angle: holding
    it needs more friction than the guide gives, and sliding away it would wedge.)

    Decided for one friction element: at rest the element's value u* = -Q / (d phi/dq) is the
    one that balances the generalized force Q, and it holds where |u*| is within the Coulomb
    limit of the reactions u* itself gives (the statics of the friction's linearization, its
    part through dw/dt taken out); a limit that grows with u, a self-locking pair, holds any
    push past some size, so the drives that hold need not be one interval. Several elements
    share a holding force in ways statics leaves open: the caller claims no jam there (such a
    rest stays held)."""
    frictions = frictions_of(model.loads)
    if len(frictions) != 1:
        raise ValueError(f"rest_jams decides for one friction element, got {len(frictions)}")
    model = static_model(model)  # rest is held by the static limits
    at_rest = y._replace(omega=jnp.zeros_like(y.omega))
    coeffs = kinematic_coefficients(model, at_rest)
    start = _start(model, jnp.asarray(t, dtype=float), at_rest, jnp.zeros(()), coeffs, jnp.zeros(1), False)
    starts = start.solved[1]  # the start's friction by Newton's method, as the batched analyses decide a jam
    (at_zero, _), (basis, _) = start.linear, start.inertial
    alpha0 = _acceleration(start.red, start.rates, jnp.zeros(1), at_rest.omega)
    statics = (jax.tree.map(lambda r, b: r - alpha0 * b[0], at_zero, basis), jax.tree.map(lambda b: b[1:], basis))
    force, rate = start.red.force, start.rates[0]
    balancing = -force / jnp.where(rate == 0, 1.0, rate)
    limit = coulomb_limits(model.mechanism, start.kin, frictions, *statics)(balancing[None])[0]
    held = jnp.where(rate == 0, force == 0, jnp.abs(balancing) <= limit)
    return ~(starts | held), all_finite((force, limit))


def rest_direction(alpha, side):
    """+1 / -1: the direction a mechanism at rest starts to move in; 0: it sticks.
    ``alpha``, ``side``: the first two values of :func:`rest_analysis`."""
    return jnp.where(alpha * side > 0, side, 0.0)


def start_direction(model: Model, t0, y0: State):
    """The direction of motion at the start: sign(w0), or from rest the break-away
    direction (0 when the friction holds the mechanism)."""
    alpha, side = rest_analysis(model, t0, y0)[:2]
    return jnp.where(y0.omega != 0, jnp.sign(y0.omega), rest_direction(alpha, side))


def arrival_acceleration(model: Model, t, q, omega, q0, omega0, t0):
    """dw/dt at (t, q, omega) on the way there from (t0, q0, omega0), before any reversal:
    with friction, the Coulomb signs are those of the start's direction of motion (the
    left limit at a standstill, where the law switches)."""
    y = State(q, omega)
    if not frictions_of(model.loads):
        return _reduce(model, t, y)[0].acceleration(omega)
    start = start_direction(model, t0, State(q0, omega0))
    return frictional(model, t, y, jnp.where(start != 0, start, 1.0)).alpha


def acceleration_at(model: Model, t, y: State):
    """dw/dt at a state, friction included; at rest with friction, 0 while it sticks,
    else the acceleration of the direction it breaks away in."""
    return acceleration_and_reduction(model, t, y)[0]


def acceleration_and_reduction(model: Model, t, y: State, bridge: float = 0.0, iterate: bool | None = None):
    """(:func:`acceleration_at`, the reduction and the Kinematics it was computed on): one
    analysis for dw/dt and the energies of an output sample. ``iterate``: how the friction is
    solved (``solve_friction``); None: for a vmapped analysis, Newton's method alone up to
    SUMMED_TERMS elements, past them the iteration (4x cheaper than Newton's K x K Jacobian and LU)."""
    frictions = frictions_of(model.loads)
    if not frictions:
        red, kin = _reduce(model, t, y, bridge)
        return red.acceleration(y.omega), red, kin
    # moving, the friction of its direction; at rest, of the direction it would break away in.
    # The signs as an array of zeros (read at the state), as a simulation's right-hand side
    # passes them: with a state of the same parts and the iteration, the two calls share one
    # trace (see _solution.outputs)
    f = frictional(model, t, y, jnp.sign(y.omega), bridge, jnp.zeros(len(frictions)),
                   iterate=len(frictions) > SUMMED_TERMS if iterate is None else iterate)
    red, kin, a, consistent = f.red, f.kin, f.alpha, f.consistent
    if has_static(model.loads):  # at rest the static coefficients decide whether it starts (solved only there)
        starts = jax.lax.cond(eqxi.unvmap_any(y.omega == 0), lambda: rest_direction(*rest_analysis(model, t, y, bridge)[:2]) != 0,
                              lambda: jnp.asarray(True))
    else:
        starts = rest_direction(jnp.where(consistent, a, 0.0), rest_side(red.force)) != 0
    return jnp.where(y.omega != 0, a, jnp.where(starts, a, 0.0)), red, kin


def near(model: Model, y: State) -> dict | None:
    """The tracked angles of a state as link -> angle (the groups' predictor), or None."""
    return branch_mapping(model.mechanism, y.branch)


def _reduce(model: Model, t, y: State, bridge: float = 0.0):
    return reduce_with_kinematics(model.mechanism, model.gravity, model.loads, y.q, y.omega, t, near=near(model, y),
                                  work=y.work is not None, bridge=bridge)
