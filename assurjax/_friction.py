"""Coulomb friction in the joints, driven by the joint reactions: the extension of the
modular method that Durango et al. 2014 name (a successive-approximation force analysis).

- :class:`JointFriction` on a revolute: a friction circle of radius r and a
  coefficient mu give the couple -mu r |F| sign(w_rel) on the later link (the one the
  reaction F acts on), the opposite on the earlier one; w_rel = w_on - w_by. An
  optional viscous term -c w_rel adds to it.
- :class:`SlideFriction` on a prismatic pair: the normal force N and the couple M on
  the slider (at its sliding point) are carried by a block of length L whose ends
  press with N/2 -+ M/L; the friction force along the guide is
  -mu (|N/2 - M/L| + |N/2 + M/L|) sign(v_rel) on the slider, the opposite on the
  guide link, at the sliding point; v_rel is the slider's velocity relative to the
  guide link along the guide. Plus an optional viscous -c v_rel.

The friction values u (one per element) depend on the reactions, and the reactions on
u and on the driving acceleration: with the reactions affine in both (d'Alembert),
``solve_friction`` finds u from u = law(F(u)) (optimistix: fixed-point iteration, Newton's
method where that is slow). In a one-degree-of-freedom mechanism every relative rate is
(d phi/dq) w, so the signs follow sign(w) -- or, at rest, the direction the mechanism
would start to move in (stiction, see ``dynamics._stick``).
"""

from __future__ import annotations

import abc

from collections.abc import Callable
from typing import ClassVar, NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array

from ._errors import MechanismError
from ._values import check_value, concrete
from ._geometry import cross, dot, perp, rotation
from ._listing import few
from ._jit import moved_leaves, region, stays_unthreaded
from ._kinematics import by_name
from ._linalg import lu_determinant, lu_factor, lu_solve, plain_lu_factor, plain_lu_solve, small_solver
from ._loads import AbstractLoad
from ._mechanism import Mechanism
from ._trees import with_field
from .groups._base import GROUND


class AbstractFriction(AbstractLoad):
    """A friction element on one pair: its wrenches are linear in its value ``u``
    (a couple or a force), and ``law`` gives u from the pair's reaction.

    ``smoothing`` (a speed v_s > 0, or None): the regularized law, asked for, never put in
    the exact one's place: the Coulomb sign of the relative rate becomes tanh(rate / v_s),
    smooth in the state. A mechanism then creeps where the exact law holds it (no stiction,
    no stick and break-away events), and its motion tends to the exact law's as v_s -> 0,
    the steps shrinking with v_s (the equation stiffens). What it buys: where every element
    is smoothed, ``simulate`` integrates one smooth field in one diffrax solve, without the
    segments of stick and slip, which derivatives (and their compiles) pass faster."""

    pair: eqx.AbstractVar[str]
    coefficient: eqx.AbstractVar[Array]
    viscous: eqx.AbstractVar[Array]
    smoothing: eqx.AbstractVar[Array | None]
    static_coefficient: eqx.AbstractVar[Array | None]
    needs_reactions: ClassVar[bool] = True
    dissipative: ClassVar[bool] = True
    kind: ClassVar[str]

    def in_range(self) -> jax.Array:
        """Whether its values are in the ranges the constructor checks (a traced flag: a value
        traced there, under a sweep or vmap, is checked by the run that reads it)."""
        ok = [self.coefficient >= 0, self.viscous >= 0] + self._own_in_range()
        if self.smoothing is not None:
            ok.append(self.smoothing > 0)
        if self.static_coefficient is not None:  # below the kinetic one: static_in_order
            ok.append(self.static_coefficient >= 0)
        return jnp.all(jnp.stack([jnp.all(v) for v in ok]))

    def _own_in_range(self) -> list:
        return []

    def _set_law(self, pair: str, coefficient, viscous, smoothing, static_coefficient) -> None:
        """The fields every element has: its pair, mu and the viscous coefficient (checked >= 0),
        the optional smoothing speed (checked > 0; None: the exact law) and the optional static
        coefficient (checked >= mu, with the exact law only; None: mu at rest too)."""
        name = type(self).__name__
        if not isinstance(pair, str):
            raise MechanismError(f"{name}: the pair must be named by a string (a joint's or a prismatic pair's name), "
                                 f"got {pair!r}")
        for key, value in (("coefficient", coefficient), ("viscous", viscous)):
            check_value(MechanismError, f"{name} '{pair}': {key}", value, shape=(), nonnegative=True)
        if smoothing is not None:
            check_value(MechanismError, f"{name} '{pair}': smoothing", smoothing, shape=(), positive=True)
            smoothing = jnp.asarray(smoothing, dtype=float)
        if static_coefficient is not None:
            check_value(MechanismError, f"{name} '{pair}': static_coefficient", static_coefficient, shape=(),
                        nonnegative=True)
            if smoothing is not None:
                raise MechanismError(f"{name} '{pair}': static_coefficient needs the exact law (a smoothed element "
                                     "carries no friction at rest, so nothing for a static coefficient to hold)")
            static, kinetic = concrete(static_coefficient), concrete(coefficient)
            if static is not None and kinetic is not None and static < kinetic:
                raise MechanismError(f"{name} '{pair}': static_coefficient must be at least the (kinetic) coefficient "
                                     f"{float(kinetic):g}, got {float(static):g}")
            static_coefficient = jnp.asarray(static_coefficient, dtype=float)
        self.pair = pair
        self.coefficient, self.viscous = jnp.asarray(coefficient, dtype=float), jnp.asarray(viscous, dtype=float)
        self.smoothing = smoothing
        self.static_coefficient = static_coefficient
        self.velocity_dependent = True

    def check(self, mechanism: Mechanism) -> None:
        pairs = pairs_by_name(mechanism)
        if self.pair not in pairs or pairs[self.pair].kind != self.kind:
            known = sorted(name for name, p in pairs.items() if p.kind == self.kind)
            raise MechanismError(f"{type(self).__name__}: '{self.pair}' is not a {self.what} of the mechanism (its "
                                 f"{self.what}s: {few(known)})")

    @property
    def what(self) -> str:
        """The kind of pair, in words."""
        return "revolute joint" if self.kind == "R" else "prismatic pair"

    def wrenches(self, mechanism, kin, t):
        return []  # needs the reactions: see friction_wrenches

    @abc.abstractmethod
    def rate_terms(self, mechanism: Mechanism, x, dx) -> tuple[Array, Array]:
        """(the relative rate per unit driving velocity, the terms it is made of: their
        sizes are its round-off scale, and their derivatives' sizes its derivative's)."""

    @abc.abstractmethod
    def unit_wrenches(self, mechanism: Mechanism, kin) -> list[tuple[str, Array, Array]]:
        """(link, force, moment about its COM) of a unit value u = 1."""

    @abc.abstractmethod
    def limit_terms(self, mechanism: Mechanism, kin) -> tuple:
        """(a, b, n, 1/L, s) of the Coulomb magnitude (N m or N, >= 0) from the pair's
        reaction force F (2,) and couple M, one formula for every kind (see :func:`limits`):
        a |F| + b (|N/2 - M/L| + |N/2 + M/L|), N = F . n, the block ends' |.| read with the
        signs s (2,) where they are frozen; None for a term it lacks."""


class JointFriction(AbstractFriction):
    """Coulomb friction (and optional viscous damping) in a revolute joint.

    ``joint``: the joint's name as in :attr:`assurjax.Reactions.forces` (a point name,
    or ``"P[link]"`` where more than two links share a point); ``coefficient``: mu;
    ``radius``: the friction-circle radius r (m, the pin radius); ``viscous``: c
    (N m s/rad). Couple on the later link: -mu r |F| sign(w_rel) - c w_rel.
    ``smoothing``: a speed v_s (rad/s) for the regularized law, sign(w_rel) replaced by
    tanh(w_rel / v_s) (no stiction: at rest it carries no Coulomb friction); None, the
    default: the exact law, with stiction. ``static_coefficient``: mu_s >= mu, the
    coefficient that holds the joint at rest (where a mechanism sticks, and what it takes
    to break away); None, the default: mu. See :class:`AbstractFriction`.

    >>> assurjax.JointFriction("A", 0.1, radius=0.01, static_coefficient=0.15)
    """

    pair: str = eqx.field(static=True)
    coefficient: Array
    radius: Array
    viscous: Array
    smoothing: Array | None
    static_coefficient: Array | None
    velocity_dependent: bool = eqx.field(static=True, default=True)
    kind: ClassVar[str] = "R"

    def __init__(self, joint: str, coefficient, radius, *, viscous=0.0, smoothing=None, static_coefficient=None):
        self._set_law(joint, coefficient, viscous, smoothing, static_coefficient)
        check_value(MechanismError, f"JointFriction '{joint}': radius", radius, shape=(), nonnegative=True)
        self.radius = jnp.asarray(radius, dtype=float)

    def _own_in_range(self) -> list:
        return [self.radius >= 0]

    def rate_terms(self, mechanism, x, dx):
        p = pairs_by_name(mechanism)[self.pair]
        return _relative_turn(_angle(dx, p.on), _angle(dx, p.by))

    def unit_wrenches(self, mechanism, kin):
        p = pairs_by_name(mechanism)[self.pair]
        zero = jnp.zeros(2)
        return [(link, zero, jnp.asarray(s)) for link, s in ((p.on, 1.0), (p.by, -1.0)) if link != GROUND]

    def limit_terms(self, mechanism, kin):
        return self.coefficient * self.radius, None, None, None, None


class SlideFriction(AbstractFriction):
    """Coulomb friction (and optional viscous damping) in a prismatic pair.

    ``pair``: its name ``"<slider>/<guide link>"`` (as in :attr:`assurjax.Reactions.forces`);
    ``coefficient``: mu; ``length``: the block length L (m) centred at the sliding
    point; ``viscous``: c (N s/m). Force on the slider along the guide:
    -mu (|N/2 - M/L| + |N/2 + M/L|) sign(v_rel) - c v_rel. ``smoothing``: a speed v_s
    (m/s) for the regularized law, tanh(v_rel / v_s) for sign(v_rel), and
    ``static_coefficient`` (mu_s >= mu, at rest), as in :class:`JointFriction`.

    >>> assurjax.SlideFriction("block/ground", 0.15, length=0.05)
    """

    pair: str = eqx.field(static=True)
    coefficient: Array
    length: Array
    viscous: Array
    smoothing: Array | None
    static_coefficient: Array | None
    velocity_dependent: bool = eqx.field(static=True, default=True)
    # the signs of the block ends' loads N/2 -+ M/L frozen for a slip segment (0: not frozen,
    # |.|), set by the simulation (with_block_signs); None: the law as written
    block_signs: Array | None = eqx.field(default=None, repr=False)
    kind: ClassVar[str] = "P"

    def __init__(self, pair: str, coefficient, length, *, viscous=0.0, smoothing=None, static_coefficient=None):
        self._set_law(pair, coefficient, viscous, smoothing, static_coefficient)
        check_value(MechanismError, f"SlideFriction '{pair}': length", length, shape=(), positive=True)
        self.length = jnp.asarray(length, dtype=float)

    def _own_in_range(self) -> list:
        return [self.length > 0]

    def _direction(self, kin, p):  # the slider's x axis lies along the guide
        return rotation(kin.angles[p.on]) if kin.rotations is None else kin.rotations[p.on]

    def rate_terms(self, mechanism, x, dx):
        p = pairs_by_name(mechanism)[self.pair]
        at = _point(mechanism, x, p.point)
        (on, on_terms), (by, by_terms) = _material_rate(x, dx, p.on, at), _material_rate(x, dx, p.by, at)
        return dot(on - by, x[3][p.on]), jnp.stack([on_terms, by_terms])

    def unit_wrenches(self, mechanism, kin):
        p = pairs_by_name(mechanism)[self.pair]
        e = self._direction(kin, p)
        at = kin.points[p.point] if p.point in kin.points else mechanism.ground[p.point]
        out = []
        for link, s in ((p.on, 1.0), (p.by, -1.0)):
            if link != GROUND:
                out.append((link, s * e, cross(at - kin.coms[link], s * e)))
        return out

    def limit_terms(self, mechanism, kin):
        p = pairs_by_name(mechanism)[self.pair]
        return None, self.coefficient, perp(self._direction(kin, p)), 1.0 / self.length, self.block_signs


# ---------------------------------------------------------------------------- helpers


def repeated_pair(loads) -> tuple[int, int, str] | None:
    """(i, j, what is wrong) where element j of ``loads`` is a second friction element on the
    pair element i already has (both acted, their friction added up), or None."""
    first: dict[str, int] = {}
    for j, load in enumerate(loads):
        if isinstance(load, AbstractFriction) and (i := first.setdefault(load.pair, j)) != j:
            return i, j, (f"two friction elements on the {load.what} '{load.pair}' ({type(loads[i]).__name__} and "
                          f"{type(load).__name__}): both would act, their friction adding up; give each pair one element")
    return None


def pairs_by_name(mechanism: Mechanism) -> dict:
    from ._kinetostatics._layout import group_pairs  # the kinetostatics imports the loads

    return {p.name: p for pairs in group_pairs(mechanism) for p in pairs}


ROUNDOFF = 1e-13  # a relative rate within this fraction of its terms' size is their round-off


def without_roundoff(rate, size):
    """A pair's relative rate per unit driving velocity (or its slope along q), exactly 0
    where it is round-off of the terms it is the sum of (the two links' rates; ``size``:
    the sum of their magnitudes). A pair whose links turn or slide together (e.g. the pin
    of a PRP dyad whose guides turn together) never slips, so it has no Coulomb sign, where
    round-off gave it one (1e-16: the full friction couple, a wrong motion by 0.04 rad/s^2
    on a random drawing checked against the joint-based reference). Its derivative stays
    the value's own: a rate passing through 0 keeps the slope that orders its switch."""
    exact = jnp.where(jnp.abs(rate) <= ROUNDOFF * size, 0.0, rate)
    return rate + jax.lax.stop_gradient(exact - rate)


def _relative_turn(on, by):
    """A revolute's relative rate d(theta_on - theta_by)/dq and its terms (..., 2), from its
    links' dtheta/dq (scalars, or one per element: see :func:`stacked_rate_terms`)."""
    return on - by, jnp.stack([on, by], axis=-1)


def _angle(dx, link):
    return jnp.zeros(()) if link == GROUND else dx[2][link]


def _point(mechanism, x, name):
    return x[0][name] if name in x[0] else mechanism.ground[name]


def _material_rate(x, dx, link, at):
    """d/dq of the material point of ``link`` now at ``at``: dG/dq + dtheta/dq (P - G) turned
    by 90 degrees; and those two terms (2, 2) (they cancel at a point the link turns about)."""
    if link == GROUND:
        return jnp.zeros(2), jnp.zeros((2, 2))
    terms = jnp.stack([dx[1][link], dx[2][link] * perp(at - x[1][link])])
    return terms[0] + terms[1], terms


def stacked_rate_terms(mechanism: Mechanism, frictions, names):
    """For many elements: stacked (x, dx) (the kinematic coefficients' arrays, rows named
    by ``names``, see :class:`assurjax.Coefficients`) -> the elements' relative rates per
    unit driving velocity (K,) and their terms (K, m), zero-padded (see
    :meth:`AbstractFriction.rate_terms`). The revolutes' by gathering from the link angles,
    the others element by element: a rate each was a call of its own (the strandbeest with
    friction in its 73 joints: 146 calls per right-hand side, with the terms' sizes)."""
    pairs, links = pairs_by_name(mechanism), {name: i for i, name in enumerate(names[1])}
    revolute = [k for k, f in enumerate(frictions) if f.kind == "R"]
    others = [k for k, f in enumerate(frictions) if f.kind != "R"]

    def rows(side):  # link rows of the revolutes' on / by links; the ground's: a zero appended
        return np.array([len(links) if link == GROUND else links[link]
                         for link in (getattr(pairs[frictions[k].pair], side) for k in revolute)], dtype=int)

    on, by, order = rows("on"), rows("by"), np.argsort(revolute + others)

    def rate_terms(x, dx):
        angles = jnp.concatenate([dx[2], jnp.zeros(1)])
        rates, terms = _relative_turn(angles[on], angles[by])
        if not others:
            return rates, terms
        x_named, dx_named = by_name(x, names), by_name(dx, names)
        found = [frictions[k].rate_terms(mechanism, x_named, dx_named) for k in others]
        width = max([terms.shape[1]] + [t.size for _, t in found])
        padded = [jnp.pad(terms, ((0, 0), (0, width - terms.shape[1])))] + [
            jnp.pad(t.ravel(), (0, width - t.size))[None] for _, t in found]
        return (jnp.concatenate([rates, jnp.stack([r for r, _ in found])])[order],
                jnp.concatenate(padded)[order])

    return rate_terms


def rates_and_slopes(mechanism, frictions, coeffs):
    """The elements' d phi_k/dq and d2 phi_k/dq2 (K,) from the kinematic coefficients, each
    exactly 0 where it is round-off (``_friction.without_roundoff``: a pair that never slips
    has neither a Coulomb sign nor a slope that would give it one just ahead); and the
    slopes as computed."""
    if not frictions:  # a frictionless run in segments (at its loads' knots): no element
        return (jnp.zeros((0,), dtype=jnp.result_type(coeffs.q)),) * 3
    if len(frictions) > SUMMED_TERMS:  # one array of terms: one sum, where one per element was a call each
        rates_at, inputs = stacked_rate_terms(mechanism, frictions, coeffs.names), coeffs.stacked
        size = lambda terms: jnp.sum(jnp.abs(terms), axis=-1)  # noqa: E731
    else:
        def rates_at(x, dx):
            found = [f.rate_terms(mechanism, x, dx) for f in frictions]
            return jnp.stack([rate for rate, _ in found]), [terms for _, terms in found]

        inputs = (coeffs.x, coeffs.dx, coeffs.d2x)
        size = lambda terms: jnp.stack([jnp.sum(jnp.abs(t)) for t in terms])  # noqa: E731

    # d/dq of the rates and of their terms: along q, x moves by dx and dx by d2x (at a dead
    # point of a sub-chain its rates and their terms vanish together, the slopes' terms do not)
    (rates, terms), (slopes, dterms) = jax.jvp(rates_at, inputs[:2], inputs[1:])
    return without_roundoff(rates, size(terms)), without_roundoff(slopes, size(dterms)), slopes


LOOKAHEAD = 1e-8  # rad or m of q (times 1 + |q|): where a motion reads the Coulomb signs it starts with


def signs_ahead(rates, slopes, direction, q):
    """The signs of the elements' d phi_k/dq just ahead of q in the direction of motion: a
    rate 0 to round-off (a switch just located, a start on one, a dead point) takes the sign
    it goes on with. At a slider-crank's dead point the slider's rate is 0, yet a start either
    way slides it at once, and its friction loads the pins: the break-away limits there are
    those of the starts, as the forward dynamics meets them."""
    return jnp.sign(rates + slopes * direction * LOOKAHEAD * (1.0 + jnp.abs(q)))


def frictions_of(loads) -> tuple[AbstractFriction, ...]:
    """The loads that need the joint reactions (the friction elements)."""
    return tuple(load for load in loads if load.needs_reactions)


def smoothed_only(frictions) -> bool:
    """Whether every element has the regularized law (see :class:`AbstractFriction`): then
    nothing sticks and no Coulomb sign switches, and a simulation needs no segments."""
    return bool(frictions) and all(f.smoothing is not None for f in frictions)


def has_exact_law(loads) -> bool:
    """Whether some friction element has the exact Coulomb law (with stiction: a run of such a
    model goes in segments of stick and slip, and can be held at rest)."""
    frictions = frictions_of(loads)
    return bool(frictions) and not smoothed_only(frictions)


def has_static(loads) -> bool:
    """Whether some friction element has a static coefficient of its own."""
    return any(getattr(load, "static_coefficient", None) is not None for load in loads)


def in_range(loads) -> jax.Array:
    """Whether every friction element's values are in range (:meth:`AbstractFriction.in_range`)."""
    frictions = frictions_of(loads)
    return jnp.all(jnp.stack([f.in_range() for f in frictions])) if frictions else jnp.asarray(True)


def static_in_order(loads):
    """Whether every static coefficient is at least its element's kinetic one (traced; the
    constructor checks concrete values)."""
    ordered = [jnp.all(f.static_coefficient >= f.coefficient) for f in frictions_of(loads)
               if f.static_coefficient is not None]
    return jnp.all(jnp.stack(ordered)) if ordered else jnp.asarray(True)


def static_model(model, held=True):
    """The model (a :class:`assurjax.Model`) with the law of a mechanism at rest: each
    friction element's coefficient its static one (``static_coefficient``), where it has one.
    That law decides whether a mechanism sticks and when it breaks away. ``held``: a flag
    (traced or not) telling where the state is at rest: the static coefficients there, the
    kinetic ones elsewhere. The same model where no element has a static coefficient. A
    static coefficient below the kinetic one (traced: the constructor refuses a concrete one)
    is NaN, as the analyses make of a NaN coefficient: a rest law weaker than the motion's made
    a mechanism break away and stop again at once, so that it seemed held."""
    if not has_static(model.loads):
        return model

    def at_rest(load):
        if getattr(load, "static_coefficient", None) is None:
            return load
        static = jnp.where(load.static_coefficient >= load.coefficient, load.static_coefficient, jnp.nan)
        coefficient = static if held is True else jnp.where(held, static, load.coefficient)
        return eqx.tree_at(lambda f: f.coefficient, load, coefficient)

    return eqx.tree_at(lambda m: m.loads, model, tuple(at_rest(load) for load in model.loads))


def coulomb_signs(frictions, rates, omega, exact):
    """The elements' Coulomb signs (K,): ``exact`` (those of the exact law, from the rates'
    signs and the direction of motion), and tanh(rate w / v_s) for the smoothed elements
    (``rates``: per unit driving velocity, ``omega``: the driving velocity)."""
    smooth = np.array([f.smoothing is not None for f in frictions])
    if not smooth.any():
        return exact
    speeds = jnp.stack([f.smoothing if f.smoothing is not None else jnp.ones(()) for f in frictions])
    return jnp.where(smooth, jnp.tanh(rates * omega / speeds), exact)


def friction_wrenches(mechanism: Mechanism, kin, frictions, u) -> dict:
    """link -> (force, moment about the COM) of friction values ``u`` (one per element)."""
    out: dict = {}
    for k, element in enumerate(frictions):
        for link, f, m in element.unit_wrenches(mechanism, kin):
            f0, m0 = out.get(link, (jnp.zeros(2), jnp.zeros(())))
            out[link] = (f0 + u[k] * f, m0 + u[k] * m)
    return out


SUMMED_TERMS = 8  # up to this many elements, the law element by element; beyond, stacked


def limits(terms, force, couple):
    """Coulomb magnitudes from the pairs' forces (..., 2) and couples (...):
    a |F| + b (|N/2 - M/L| + |N/2 + M/L|) with N = F . n, ``terms`` = (a, b, n, 1/L, s) of
    :meth:`AbstractFriction.limit_terms` (one element's, or stacked): mu r |F| on a
    revolute (no b term), the block's two ends on a prismatic pair (no a term), each end's
    |.| as s times its load where its sign s is frozen (a slip segment's analytic branch:
    an event ends the segment where that load changes sign, see :func:`with_block_signs`)."""
    a, b, normal, inverse_length, signs = terms
    out = 0.0 if a is None else a * jnp.sqrt(jnp.sum(force * force, axis=-1) + 1e-300)
    if b is None:
        return out
    ends = block_end_loads(force, couple, normal, inverse_length)
    return out + b * jnp.sum(_frozen_abs(ends, signs), axis=-1)


def block_end_loads(force, couple, normal, inverse_length):
    """(..., 2): the loads N/2 - M/L and N/2 + M/L on a prismatic pair's block's two ends."""
    half, end = 0.5 * jnp.sum(force * normal, axis=-1), couple * inverse_length
    return jnp.stack([half - end, half + end], axis=-1)


def _frozen_abs(ends, signs):
    """|ends|, or signs * ends where a sign is frozen (nonzero)."""
    return jnp.abs(ends) if signs is None else jnp.where(signs != 0, signs * ends, jnp.abs(ends))


def has_blocks(frictions) -> bool:
    """Whether some element is a prismatic pair's (its block ends' loads have kinks)."""
    return any(f.kind == "P" for f in frictions)


def with_block_signs(model, signs):
    """The model with its prismatic pairs' block-end signs frozen: ``signs`` (K, 2), one row
    per friction element (the revolutes' rows unread), 0 where not frozen. Frozen for a slip
    segment, the law is analytic inside it: where an end's load passes through 0 (one end of
    the block lifts) |.| has a kink that no Coulomb switch marks, and a step across it is
    differentiated with one side's slope (a derivative off by ~sqrt(tol)); the segment's
    event ends it there instead (``dynamics._events.margins``)."""
    k = 0
    loads = []
    for load in model.loads:
        if isinstance(load, AbstractFriction):
            if load.kind == "P":
                load = with_field(load, "block_signs", signs[k])
            k += 1
        loads.append(load)
    return eqx.tree_at(lambda m: m.loads, model, tuple(loads))


def end_loads(mechanism: Mechanism, kin, frictions, reactions, u):
    """(K, 2): the block ends' loads (:func:`block_end_loads`) of each element at the friction
    values u (0 on a revolute), from the reactions affine in u (``reactions``: at u = 0 and
    their K tangents, see :func:`linearize_reactions`)."""
    reactions0, basis = reactions
    if len(frictions) > SUMMED_TERMS:  # stacked at the elements' pairs
        (forces0, couples0), (forces_b, couples_b) = reactions0, basis
        terms = _stacked_terms(mechanism, kin, frictions)
        return block_end_loads(_affine(forces0, forces_b, u), _affine(couples0, couples_b, u), terms[2], terms[3])
    (forces0, couples0), (forces_b, couples_b) = by_pair(reactions0), by_pair(basis)
    rows = []
    for f in frictions:
        if f.kind != "P":
            rows.append(jnp.zeros(2))
            continue
        _, _, normal, inverse_length, _ = f.limit_terms(mechanism, kin)
        rows.append(block_end_loads(_affine(forces0[f.pair], forces_b[f.pair], u),
                                    _affine(couples0[f.pair], couples_b[f.pair], u), normal, inverse_length))
    return jnp.stack(rows)


def _stacked_terms(mechanism: Mechanism, kin, frictions) -> tuple:
    """The elements' (a, b, n, 1/L, s) stacked ((K,), (K,), (K, 2), (K,), (K, 2)), 0 where an element lacks a term."""
    parts = [f.limit_terms(mechanism, kin) for f in frictions]

    def stacked(i, zero):
        found = [p[i] for p in parts]
        return None if all(v is None for v in found) else jnp.stack([zero if v is None else v for v in found])

    return stacked(0, 0.0), stacked(1, 0.0), stacked(2, jnp.zeros(2)), stacked(3, 0.0), stacked(4, jnp.zeros(2))


def coulomb_limits(mechanism: Mechanism, kin, frictions, reactions0, basis):
    """u -> the elements' Coulomb magnitudes (K,), from the reactions affine in u:
    ``reactions0`` (forces, couples) at u = 0 and their ``basis`` (K tangents), see
    :func:`linearize_reactions`.

    For a few elements, element by element (the reactions by pair) with u . basis as a
    chain of products and sums: XLA fuses it with its neighbours, where a dot this small is
    a call of its own (~0.3 us on a CPU, at each Newton step), and stacked arrays cost more
    per step (Watt six-bar +12-14 %). For many, stacked (the reactions come stacked at the
    elements' pairs, :func:`linearize_reactions`), one dot and one vectorised formula:
    element by element the program grows with K (the strandbeest with friction in its 73
    joints: 333 s to a first simulate() with chains over every pair, 35 s element by
    element, 22 s stacked)."""
    if len(frictions) > SUMMED_TERMS:  # stacked at the elements' pairs
        (forces0, couples0), (forces_b, couples_b) = reactions0, basis
        terms = _stacked_terms(mechanism, kin, frictions)
        return lambda u: limits(terms, _affine(forces0, forces_b, u), _affine(couples0, couples_b, u))
    terms = [f.limit_terms(mechanism, kin) for f in frictions]

    def coulomb(u):  # read by pair here: inside the solver's loop, where the slices fuse
        (forces0, couples0), (forces_b, couples_b) = by_pair(reactions0), by_pair(basis)
        return jnp.stack([limits(t, _affine(forces0[f.pair], forces_b[f.pair], u),
                                 _affine(couples0[f.pair], couples_b[f.pair], u) if f.pair in couples0 else 0.0)
                          for f, t in zip(frictions, terms)])

    return coulomb


def _affine(value, tangents, u):
    """value + sum_j u_j tangents[j]: for up to SUMMED_TERMS elements a chain of products
    and sums (see :func:`coulomb_limits`), past them one dot."""
    if u.shape[0] > SUMMED_TERMS:
        return value + jnp.tensordot(u, tangents, axes=1)
    return value + sum(u[j] * tangents[j] for j in range(u.shape[0]))


def _static_slopes(mechanism: Mechanism, kin, frictions, reactions, inertial, u):
    """|dlaw_k/du_j| (K, K) at a fixed driving acceleration, or bounds of them, from the
    reactions' K tangents at a fixed acceleration (the ``reactions``' tangents less their
    part through it, ``inertial``): on a revolute a |dF|, whatever its reaction; on a
    prismatic pair exact at the reactions of u, b |(s1 + s2)/2 n . dF + (s2 - s1)/L dM| with
    s1,2 = sign(N/2 -+ M/L): its block's couple counts only where one end lifts. Row by row
    for up to SUMMED_TERMS elements: a stacked (K, K, 2) array over 512 bytes makes XLA's
    CPU runtime spread a simulation's step over threads (the quick-return's right-hand side
    with friction in its 7 pairs: 16 us stacked, 7.4 row by row, 6 without this test)."""
    (forces0, couples0), (forces_b, couples_b) = by_pair(reactions[0]), by_pair(reactions[1])
    (forces_a, couples_a), dalpha = by_pair(per_unit_acceleration(inertial[0])), inertial[1]
    k = len(frictions)

    def at_pair(values, tangents, per_unit, pair):  # (value at u, tangents at a fixed acceleration)
        tangent = tangents.get(pair, jnp.zeros(k))
        return _affine(values.get(pair, 0.0), tangent, u), tangent - jnp.multiply.outer(dalpha, per_unit.get(pair, 0.0))

    def rows(terms, force, d_force, couple, d_couple):  # one element's (K,) or stacked (K, K)
        a, b, normal, inverse_length, frozen = (None if v is None else jnp.asarray(v) for v in terms)
        out = 0.0
        if a is not None:
            out = out + a[..., None] * jnp.sqrt(jnp.sum(d_force * d_force, axis=-1))
        if b is not None:
            ends = block_end_loads(force, couple, normal, inverse_length)
            signs = jnp.sign(ends) if frozen is None else jnp.where(frozen != 0, frozen, jnp.sign(ends))
            s1, s2 = signs[..., 0], signs[..., 1]
            along = jnp.sum(d_force * normal[..., None, :], axis=-1)
            out = out + b[..., None] * jnp.abs(0.5 * (s1 + s2)[..., None] * along
                                               + ((s2 - s1) * inverse_length)[..., None] * d_couple)
        return out

    if k > SUMMED_TERMS:  # stacked at the elements' pairs (see linearize_reactions); rows: the elements
        def at_u(value, tangents, per_unit):  # (value at u (K, ...), tangents at a fixed acceleration (K, K, ...))
            return _affine(value, tangents, u), jnp.moveaxis(tangents - jnp.multiply.outer(dalpha, per_unit), 0, 1)

        force, couple = at_u(forces0, forces_b, forces_a), at_u(couples0, couples_b, couples_a)
        return rows(_stacked_terms(mechanism, kin, frictions), *force, *couple)
    pairs = [(at_pair(forces0, forces_b, forces_a, f.pair), at_pair(couples0, couples_b, couples_a, f.pair))
             for f in frictions]
    return jnp.stack([rows(f.limit_terms(mechanism, kin), *force, *couple) for f, (force, couple) in zip(frictions, pairs)])


def per_unit_acceleration(tangents):
    """The reactions per unit dw/dt: the first of the K + 1 tangents that ``inertial`` carries
    (see :func:`solve_friction`)."""
    return jax.tree.map(lambda b: b[0], tangents)


def _ostrowski(magnitudes):
    """Ostrowski's bound of a square matrix's spectral radius from its entries' magnitudes:
    every eigenvalue lies within sqrt(R_i C_i) of some diagonal entry (R_i, C_i: row i's and
    column i's other entries summed)."""
    diagonal = magnitudes[np.arange(len(magnitudes)), np.arange(len(magnitudes))]
    rows, columns = jnp.sum(magnitudes, axis=1) - diagonal, jnp.sum(magnitudes, axis=0) - diagonal
    return jnp.max(diagonal + jnp.sqrt(rows * columns))


def spectral_bound(magnitudes):
    """A bound of the spectral radius of any matrix whose entries are at most ``magnitudes``
    (K, K) in size (Perron-Frobenius): Ostrowski's, and for up to SUMMED_TERMS elements the
    square root of that of the square (rho(B)^2 = rho(B^2)). Unlike the largest row sum it is
    not spoilt by the elements' different units (a prismatic pair's force answers a pin's
    couple per metre, the pin's couple the force times metres: their product is what counts);
    the square's is nearer (on the quick-return with friction everywhere 0.3 against 0.5-1.1;
    its spectral radius 0.14-0.19)."""
    if stays_unthreaded(magnitudes.size):  # made once for its readers, where each made its own
        magnitudes = jax.lax.optimization_barrier(magnitudes)
    bound = _ostrowski(magnitudes)
    if magnitudes.shape[0] <= SUMMED_TERMS:  # K^3 products
        square = sum(jnp.outer(magnitudes[:, j], magnitudes[j]) for j in range(magnitudes.shape[0]))
        bound = jnp.minimum(bound, jnp.sqrt(_ostrowski(square)))
    return bound


# Fixed-point steps before Newton takes over: within them the iteration converges to 1e-12
# only while it contracts by ~0.4 per step or better, so its error stays below the tolerance.
FIXED_POINT_STEPS = 32
CONTINUATION_STEPS = 4  # steps in mu of the friction's last fallback (solve_friction's robust_newton)


# The iteration's tolerance (relative and absolute, per element): this, and inside a
# simulation's integration a fraction of the integration's own (see iteration_tolerance)
FIXED_POINT_TOLERANCE = 1e-12
INTEGRATION_FRACTION = 1e-2


def iteration_tolerance(rtol: float, atol: float) -> float:
    """The fixed-point tolerance of the friction solve inside an integration at (rtol, atol):
    INTEGRATION_FRACTION of the tighter, as diffrax's implicit solvers take their nonlinear
    solve's tolerance from the step-size controller. The solve's error, below c / (1 - c) of
    it where the iteration contracts by c (~0.03 on the press), is then ~3e-4 of what the
    steps are allowed, and the iteration stops ~1.5 steps sooner at the default 1e-8 (8.9 ->
    7.3 law evaluations per right-hand side of the press). Not below FIXED_POINT_TOLERANCE:
    nearer the round-off of the law's evaluation the iteration would not settle, and every
    right-hand side would go on to Newton's method."""
    return max(FIXED_POINT_TOLERANCE, INTEGRATION_FRACTION * min(rtol, atol))


# Analyses along many states (simulate's output samples, reactions along a motion) with more
# than SUMMED_TERMS elements: each state's friction solve carries the statics' (K + 1) x K x 2
# tangents (86 kB with the strandbeest's 73 joints), and one vmap over all the states works past
# the CPU's caches (2-3x the cost per state of a vmap over 64). They go this many at a time
# through one program compiled for a chunk, called once per chunk. (simulate's output samples
# solve their friction one after another, dynamics._solution._serial_friction, in these chunks.)
STATES_PER_CALL = 64


def states_per_call(frictions) -> int | None:
    """States per call of an analysis along many states with these friction elements (None:
    all in one call), see STATES_PER_CALL."""
    return STATES_PER_CALL if len(frictions) > SUMMED_TERMS else None


def linearize_reactions(react, frictions, directions: int):
    """(reactions at v = 0, their tangents along the ``directions`` unit vectors) of
    ``react(v)`` -> (forces, couples) by pair, affine in v (the friction values, and in the
    forward dynamics dw/dt first): one kinetostatic solve and one more per tangent.

    Up to SUMMED_TERMS ``frictions``, the elements' pairs' reactions as
    :class:`PairReactions` (packed into one array) while their tangents stay under
    THREADED_BYTES, else by pair (the Watt six-bar's seven pins packed: its step 1.5x
    dearer). Past SUMMED_TERMS, ``react(v, at_pairs=...)`` reads their pairs' reactions
    stacked, (forces (K, 2), couples (K,)): the sums made of them afterwards are then one
    operation each, where by pair they were one each per pair (the strandbeest with friction
    in its 73 joints: 146 calls per right-hand side)."""
    kinds = {f.pair: f.kind for f in frictions}
    width = sum(3 if kind == "P" else 2 for kind in kinds.values())  # a force, and a prismatic pair's couple
    packs = len(frictions) <= SUMMED_TERMS and stays_unthreaded(directions * width)
    unravel = []

    def packed(v):
        forces, couples = react(v)
        values, unpack = ravel_pytree(({p: f for p, f in forces.items() if p in kinds},
                                       {p: c for p, c in couples.items() if p in kinds}))
        unravel.append(unpack)  # shapes only: no tracer is kept
        return values

    if len(frictions) > SUMMED_TERMS:
        read = lambda v: react(v, at_pairs=tuple(f.pair for f in frictions))  # noqa: E731
    else:
        read = packed if packs else react
    reactions0, linear = jax.linearize(read, jnp.zeros(directions))
    tangents = jax.vmap(linear)(np.eye(directions))  # a literal: jnp.eye is an iota XLA computes at each call
    if not packs:
        return reactions0, tangents
    return PairReactions(reactions0, unravel[0]), PairReactions(tangents, unravel[0])


class PairReactions(eqx.Module):
    """The friction elements' pairs' reactions (forces, couples by pair) packed into one
    array, ``values`` (..., n), leading axes for tangents: the fixed-point loop and the
    Newton fallback's cond take it as one operand, where they took one per pair and force,
    each materialized by XLA as a call of its own (the press, four elements: 710 -> 644
    kernel calls per step). Arithmetic on it goes through ``jax.tree.map``; the law reads
    it by pair with :func:`by_pair`, inside the loop, where the slices fuse."""

    values: Array
    unravel: Callable = eqx.field(static=True)


def by_pair(reactions):
    """(forces, couples) by pair of :class:`PairReactions` (with its leading axes); reactions
    already by pair, or stacked at the elements (past SUMMED_TERMS), as they are."""
    if not isinstance(reactions, PairReactions):
        return reactions
    unravel = reactions.unravel
    for _ in range(reactions.values.ndim - 1):
        unravel = jax.vmap(unravel)
    return unravel(reactions.values)


def solve_friction(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, *, inertial=None,
                   iterate: bool = True, tolerance: float = FIXED_POINT_TOLERANCE):
    """Friction values u with u = law(reactions(u)), the reactions being affine in u:
    ``reactions`` = (forces and couples at u = 0, their K tangents), see
    :func:`linearize_reactions`. ``inertial``: where those tangents also carry u's effect
    through the driving acceleration (the forward dynamics), that part: (the reactions'
    tangents along (dw/dt, u), K + 1 of them, the first per unit dw/dt (only it is read,
    :func:`per_unit_acceleration`), and d(dw/dt)/du (K,)), for the consistency test below;
    None where the acceleration is given (a prescribed motion). The tangents go whole, not that
    first one sliced out: the Newton fallback's cond takes them as operands, which XLA
    materializes, and each slice of its own recomputed its share of the statics (the press's
    step 27.5 -> 25.2 us, same results). ``kin``: the positions the limits are read on; ``rates``:
    (K,) relative rates per unit driving velocity (for the viscous terms); ``signs``: (K,)
    the Coulomb signs, those of the relative rates (rates times the sign of w or, at rest,
    the direction of the motion tested). Returns (u, ok); ok is False where no solution is
    found or it is not consistent (Painleve: the friction would drive the motion it opposes).

    The law's slope dlaw/du is small wherever friction is moderate (~mu r / a link's
    length), so the fixed-point iteration u <- law(u) converges in a handful of cheap
    steps (optimistix's FixedPointIteration; no Jacobian, no linear solve): the
    right-hand side with friction costs half what Newton's method did. Where it does
    not converge quickly (strong friction, a short slider block), Newton's method
    (optimistix) from the same start, with the consistency test below.
    Where Newton's root is not consistent, Newton's method once more, continued in mu from
    0 (strong friction can give the law several roots).

    Consistent (Painleve): the effective inertia is positive, M_eff = J_red det(I - dlaw/du)
    / det(I - S) with S the law's slope at a fixed acceleration (the determinant lemma: u
    acts on the acceleration through one rank-one term), and the statics alone is not
    self-locked, det(I - S) > 0 (at det(I - S) = 0 a prescribed motion needs an unbounded
    drive: a slider driven through a rod steeper than its friction angle allows). Both
    determinants are 1 at mu = 0, and both are tested: det(I - dlaw/du) > 0 alone (the test
    until this was found) also passed roots where both are negative, a self-locked
    slider-crank driven on with a negative effective inertia, its crank slowing the more,
    the harder it is driven. Newton's method tests det(I - S) = det(I - dlaw/du) (1 + y),
    y = d(dw/dt)/du . (I - dlaw/du)^-1 dlaw/d(dw/dt) (Sherman-Morrison: one solve with the
    factors of det(I - dlaw/du), no second Jacobian). A converged iteration has dlaw/du's
    spectral radius below 1, so det(I - dlaw/du) > 0; it is taken where
    :func:`spectral_bound` of S's entries (or bounds of them, :func:`_static_slopes`) is
    below 1 as well, which makes det(I - S) > 0; elsewhere Newton's method decides, from
    the iteration's root.

    ``iterate=False``: Newton's method alone, for the solves batched within one analysis
    (the reactions' two directions, vmapped states of up to SUMMED_TERMS elements): with
    both loops in the batched reactions program XLA's CPU runtime stalled in 3 of 5 runs of
    ``assurjax run press_with_friction`` (its concurrency-optimized scheduler on). A batch
    of simulations (``simulate`` with an array of starts) keeps the iteration: 14 runs of
    16 starts did not stall; so do ``simulate``'s output samples, solved one after another
    (``dynamics._solution.outputs``), and vmapped states of more elements, where Newton's
    Jacobian costs most (``dynamics._field.acceleration_and_reduction``).

    ``tolerance``: the iteration's (see :func:`iteration_tolerance`). u's derivatives come
    from the implicit function theorem, not through the solvers (see :func:`_implicit_root`)."""
    return _implicit_root((mechanism, frictions, reactions, kin, rates, signs, omega, inertial, tolerance),
                          find=_iterated_root if iterate else _newton_root)


def finish_friction_implicit(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, fixed: FixedPoint, *,
                             inertial=None):
    """(u, ok) of :func:`finish_friction`, with u's derivatives by the implicit function
    theorem (see :func:`_implicit_root`): not through Newton's method, nor through ``fixed``."""
    return _implicit_root((mechanism, frictions, reactions, kin, rates, signs, omega, inertial, fixed),
                          find=_finished_root)


def _iterated_root(inputs):
    mechanism, frictions, reactions, kin, rates, signs, omega, inertial, tolerance = inputs
    fixed = iterate_friction(mechanism, frictions, reactions, kin, rates, signs, omega, inertial=inertial,
                             tolerance=tolerance)
    return finish_friction(mechanism, frictions, reactions, kin, rates, signs, omega, fixed, inertial=inertial)


def _newton_root(inputs):
    mechanism, frictions, reactions, kin, rates, signs, omega, inertial, _ = inputs
    u0 = _law(mechanism, frictions, reactions, kin, rates, signs, omega)(jnp.zeros(len(frictions)))
    return _robust_newton(mechanism, frictions, reactions, kin, rates, signs, omega, inertial, u0, friction_atol(u0, NEWTON_TOLERANCE))


def _finished_root(inputs):
    mechanism, frictions, reactions, kin, rates, signs, omega, inertial, fixed = inputs
    return finish_friction(mechanism, frictions, reactions, kin, rates, signs, omega, fixed, inertial=inertial)


@eqx.filter_custom_jvp
def _implicit_root(inputs, *, find):
    """``find(inputs)``: the friction values u with u = law(u) and whether they are
    consistent, found by the solvers (the iteration, Newton's method in a cond); their
    derivatives du = (I - dlaw/du)^-1 dlaw/dp dp by the implicit function theorem, the same
    whichever solver found u (optimistix applied the same formula to each solver on its
    own). Differentiated through, the fallback's cond took both its branches (Newton's
    method and its continuation) at every stage; with this, and the vector field
    differentiated as one path (``dynamics._field._friction_field``), the slider-crank's
    jitted reverse-mode d q(0.8 s)/d mu 53.0 -> 44.7 s to its first call and 49 -> 29 ms
    warm, the same derivative (benchmarks/bench_friction_gradients.py)."""
    return find(inputs)


@_implicit_root.def_jvp
def _implicit_root_jvp(primals, tangents, *, find):
    (inputs,), (inputs_tangents,) = primals, tangents
    u, ok = _implicit_root(inputs, find=find)
    values, value_tangents, rebuild = moved_leaves(inputs, inputs_tangents)

    def residual(u, *values):  # u - law(u), at the inputs with the moving leaves at ``values``
        mechanism, frictions, reactions, kin, rates, signs, omega = rebuild(values)[:7]
        return u - _law(mechanism, frictions, reactions, kin, rates, signs, omega)(u)

    _, moved_by = jax.jvp(lambda *v: residual(u, *v), values, value_tangents)
    jacobian = jax.jacfwd(residual)(u, *values)  # I - dlaw/du
    # where no root was found (a jam: u is NaN) the tangent is 0 beside a NaN value. Tested on
    # primal values only: a test of the tangents themselves would not be linear in them. So in
    # reverse mode a NaN cotangent (a step rejected at a jam: 0 x NaN) still reaches the solve:
    # an LU solve, not lineax's, whose transpose raises on it from inside the program
    # (jax.grad of a run that jams stopped on an 'INTERNAL: CpuCallback error')
    finite = jnp.all(jnp.isfinite(jacobian)) & jnp.all(jnp.isfinite(u))
    jacobian = jnp.where(finite, jacobian, jnp.eye(len(u)))
    du = lu_solve(lu_factor(jacobian), jnp.where(finite, -moved_by, 0.0))
    return (u, ok), (jnp.where(finite, du, 0.0), None)


class FixedPoint(NamedTuple):
    """The outcome of :func:`iterate_friction`: its start u0 = law(0), its root, whether it
    converged, and whether that root is taken as it is (``settled``: consistent by the bound)."""

    u0: Array
    value: Array
    converged: Array
    settled: Array


def iterate_friction(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, *,
                     inertial=None, tolerance: float = FIXED_POINT_TOLERANCE) -> FixedPoint:
    """The fixed-point iteration of :func:`solve_friction` and its consistency bound: the
    part of the solve that runs at every right-hand side (:func:`finish_friction` the rest).
    ``tolerance``: the iteration's, see :func:`iteration_tolerance`."""
    law = _law(mechanism, frictions, reactions, kin, rates, signs, omega)
    u0 = law(jnp.zeros(len(frictions)))
    # up to SUMMED_TERMS elements the iterate as K scalars, not one (K,) array: XLA's loop
    # writes the array's entries one by one and copies it whole at the next step, a load the
    # CPU cannot take from those stores while they are in flight (the press's step 8.5-8.8 ->
    # 8.1-8.5 us, same results, though 3.2k instructions more: see docs/design-notes.md)
    split, join = (tuple, jnp.stack) if len(frictions) <= SUMMED_TERMS else (jnp.asarray, jnp.asarray)
    # atol: see friction_atol (in N or N m alone, a press scaled to 1e-12 kg erred by 2e-3 rad at any rtol)
    fixed = optx.fixed_point(lambda u, _: split(law(join(u))), optx.FixedPointIteration(rtol=tolerance, atol=friction_atol(u0, tolerance)),
                             split(u0), max_steps=FIXED_POINT_STEPS, throw=False)
    value = join(fixed.value)
    converged = fixed.result == optx.RESULTS.successful
    # det(I - S) > 0 where a bound of S's spectral radius is below 1 (S at a fixed acceleration)
    settled = converged if inertial is None else converged & (
        spectral_bound(_static_slopes(mechanism, kin, frictions, reactions, inertial, value)) < 1.0)
    return FixedPoint(u0, value, converged, settled)


def finish_friction(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, fixed: FixedPoint, *,
                    inertial=None):
    """(u, ok) of :func:`solve_friction` from the iteration's outcome: its root where it is
    settled, else Newton's method (from u0 where the iteration failed, from its root where
    only the bound did)."""
    def fallback():
        return _newton_fallback(mechanism, frictions, reactions, kin, rates, signs, omega, fixed, inertial)

    # on whether any member of a batch failed (unbatched: under vmap a cond on a per-member
    # test runs both branches for every member, and Newton's was most of a batched
    # right-hand side: slider-crank 1.55 -> 1.1 us, Watt six-bar 3.5 -> 1.6 us per state)
    return jax.lax.cond(eqxi.unvmap_any(~fixed.settled), fallback, lambda: (fixed.value, jnp.array(True)))


# A region (one kernel): XLA compiles it faster than the many small kernels of Newton's
# method and its continuation, at each site that finishes a friction solve outside the
# field's region (the field's fallback, a stick segment's field and break-away event, the
# outputs): first calls with friction 3-17 % shorter (the press 7.1 -> 6.1 s); the Watt
# six-bar under a drive ramped in time 23.3-23.8 -> 18.7-19.3 s, its warm run 4-6 % slower
# (bench_friction_first_calls.py)
@region
def _newton_fallback(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, fixed: FixedPoint, inertial):
    u, ok = _robust_newton(mechanism, frictions, reactions, kin, rates, signs, omega, inertial,
                           jnp.where(fixed.converged, fixed.value, fixed.u0), friction_atol(fixed.u0, NEWTON_TOLERANCE))
    return jnp.where(fixed.settled, fixed.value, u), fixed.settled | ok


# The round-off floor of an element's friction value, per unit of the largest (see friction_atol)
ROUNDOFF_SPACINGS = 100.0
NEWTON_TOLERANCE = 1e-12  # Newton's method's (relative, and absolute in the friction's size)


def friction_atol(u0, tolerance):
    """The friction solves' absolute tolerance (N or N m) at a ``tolerance``: in units of the
    friction's size up to 1 (the largest friction value with no friction in the statics,
    |law(0)|; 1 where all are 0, then u = 0), and at least ROUNDOFF_SPACINGS float spacings of
    that size. In N or N m alone, a press scaled to 1e-12 of its masses erred by 1.9e-3 rad;
    capped at 1 N m, a slider-crank with 1e5 x the masses reported a jam at 0.15 s (an element
    with a small reaction beside large ones has their round-off, which no relative tolerance of
    its own covers); scaled by the size above 1 as well, batches drifted 1.6e-8 rad from single
    runs (the press's Coulomb switches amplify a looser solve)."""
    size = jnp.max(jnp.abs(u0))
    size = jnp.where(size > 0, size, 1.0)
    return tolerance * jnp.minimum(size, 1.0) + ROUNDOFF_SPACINGS * jnp.finfo(u0.dtype).eps * size


def _law(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega):
    """The friction law u -> law(u) of :func:`solve_friction` (``scale``: of its Coulomb terms)."""
    coulomb = coulomb_limits(mechanism, kin, frictions, *reactions)
    viscous = _viscous(frictions, rates, omega)

    def law(u, scale=1.0):
        return -scale * coulomb(u) * signs - viscous

    return law


def _viscous(frictions, rates, omega):
    return jnp.stack([f.viscous for f in frictions]) * rates * omega


def _robust_newton(mechanism: Mechanism, frictions, reactions, kin, rates, signs, omega, inertial, u0, atol):
    """Newton's method from u0 on the law of :func:`solve_friction`; where its root is not
    consistent, Newton's method again, continued in mu from 0 (where u = -viscous) in
    CONTINUATION_STEPS steps, each from the last root: the root on the branch of moderate
    friction. With strong friction the law has several roots, and Newton's method from u0 can
    land on one that is not consistent while this one is (a slider-crank, mu = 5 on a 5 mm
    block: a consistent root at dw/dt = -279 rad/s^2, Newton from u0 at one at -2513, with
    det(I - dlaw/du) < 0, which stopped the run as a jam). The attempts are one scan, so that
    the program holds one Newton's method (two: first calls 35 % longer). ``atol``: its
    absolute tolerance, :func:`friction_atol`. Returns (u, ok)."""
    law = _law(mechanism, frictions, reactions, kin, rates, signs, omega)
    viscous = _viscous(frictions, rates, omega)

    def law_along(u, s, scale):  # the law at u with the reactions moved by s per unit dw/dt
        moved = jax.tree.map(lambda r, a: r + s * a, reactions[0], per_unit_acceleration(inertial[0]))
        return -scale * coulomb_limits(mechanism, kin, frictions, moved, reactions[1])(u) * signs

    def newton(start, scale=1.0):
        def residual(u, _):
            return u - law(u, scale)

        sol = optx.root_find(residual, optx.Newton(rtol=NEWTON_TOLERANCE, atol=atol, linear_solver=small_solver()), start,
                             max_steps=64, throw=False)
        value = sol.value
        # Painleve's paradox: where the effective inertia is not positive the friction feeds the
        # reactions faster than inertia resists: no consistent motion has the assumed signs, the
        # mechanism jams (K x K Jacobians: a few forward passes of the linear law)
        factors = plain_lu_factor(jax.jacfwd(residual)(value, None))
        consistent = lu_determinant(factors) > 0
        if inertial is not None:  # and the statics alone not self-locked (see solve_friction)
            along = jax.jvp(lambda s: law_along(value, s, scale), (0.0,), (1.0,))[1]
            consistent &= 1.0 + jnp.sum(inertial[1] * plain_lu_solve(factors, along)) > 0
        return value, (sol.result == optx.RESULTS.successful) & consistent

    n = CONTINUATION_STEPS

    def attempt(carry, i):
        u, ok, last, go = carry

        def run():
            start = jnp.where(i == 0, u0, jnp.where(i == 1, -viscous, last))
            v, found = newton(start, jnp.where(i == 0, 1.0, i / n))
            # attempt 0 stands where consistent; the continuation ends at its last step or where it fails (a jam)
            done = jnp.where(i == 0, found, ~found | (i == n))
            keep = go & ((i == 0) | (i == n))
            return jnp.where(keep, v, u), jnp.where(keep, found, ok), jnp.where(go, v, last), go & ~done

        # a scan (reverse mode goes through it) whose attempts run only while some member needs them
        return jax.lax.cond(eqxi.unvmap_any(go), run, lambda: carry), None

    init = (u0, jnp.asarray(False), u0, jnp.asarray(True))
    (u, ok, _, _), _ = jax.lax.scan(attempt, init, jnp.arange(n + 1))
    return u, ok
