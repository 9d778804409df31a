"""Applied loads: gravity, point forces, couples, springs, dampers, driving efforts.

Sign conventions (all in the global frame, SI units):

- Angles, angular velocities and moments are counterclockwise positive.
- A link's applied wrench is its resultant force F (N) and the moment M (N m)
  of all its applied loads about the link's centre of mass.
- A spring or damper between points a and b pulls a towards b (and b towards a)
  when stretched (spring) or lengthening (damper).
- A rotational damper on a joint puts c (w_b - w_a) on link a and the opposite
  on link b (it resists relative rotation).
- The driving effort is the generalized force conjugate to q: a torque (N m,
  counterclockwise positive) on a crank, a force (N) along the guide direction
  on a slider. It is not part of :func:`applied_wrenches`.

Points of application and carriers. A load's point is a named point of the
mechanism, or ``"com:<link>"``, the centre of mass of a moving link (e.g.
``"com:rod"``). A named point shared by several links (a joint) or by a link and
the ground belongs to all of them; the load acts on one of them, its **carrier**:
by default the point's owner (the ground for a fixed point, otherwise the first
link of the formation sequence that carries the point, the earlier link of the
joint), or the link named by ``link=`` (point loads) or ``links=(a, b)`` (spring
and damper ends; None or "" for the default). The motion does not depend on the
carrier (the point moves the same on every link carrying it), but the reaction at
that joint does: it differs by the load. A centre of mass is carried by its link only.

A load value may be a number (or array), one of the documented forms
(:class:`Polynomial`, :class:`Table`), or any JAX function ``f(q, omega, t)``.
User functions are assumed to depend on velocity unless the load is given
``velocity_dependent=False``; this only decides what the integrator can skip.
"""

from __future__ import annotations

import inspect
import weakref
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._errors import MechanismError
from ._listing import few
from ._trees import with_field
from ._values import check_value, concrete, found_words, shape_words
from ._geometry import cross, dot, safe_norm
from ._mechanism import COM_PREFIX, Mechanism, Pose
from ._repr import value_pdoc
from .groups._base import GROUND

# ---------------------------------------------------------------------------- value forms

VARIABLES = ("q", "omega", "t")


class Polynomial(eqx.Module):
    """c0 + c1 x + c2 x^2 + ... with x one of ``"q"``, ``"omega"``, ``"t"``."""

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    coefficients: Array
    variable: str = eqx.field(static=True, default="q")

    def __init__(self, coefficients, variable: str = "q"):
        if variable not in VARIABLES:
            raise MechanismError(f"Polynomial: variable must be one of {VARIABLES}, got {variable!r}")
        check_value(MechanismError, "Polynomial: coefficients", coefficients)
        if np.ndim(coefficients) != 1 or np.size(coefficients) == 0:
            raise MechanismError(f"Polynomial: coefficients must be a list of numbers c0, c1, ..., got {found_words(np.shape(coefficients))}")
        self.coefficients = jnp.asarray(coefficients, dtype=float)
        self.variable = variable

    def __call__(self, q, omega, t):
        x = {"q": q, "omega": omega, "t": t}[self.variable]
        return jnp.polyval(self.coefficients[::-1], x)


class Table(eqx.Module):
    """Piecewise-linear interpolation of ``values`` at increasing ``x`` (of ``variable``; an
    x given twice is a jump); constant beyond the ends, or wrapped with ``period`` (e.g. 2 pi
    for a crank angle; at least the x range)."""

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    x: Array
    values: Array
    variable: str = eqx.field(static=True, default="q")
    period: float | None = eqx.field(static=True, default=None)
    # (a, b): the table read as a + b x, its piece at a segment's start continued (with_pieces); None: as given
    piece: Array | None = eqx.field(default=None, repr=False)

    def __init__(self, x, values, variable: str = "q", period: float | None = None):
        if variable not in VARIABLES:
            raise MechanismError(f"Table: variable must be one of {VARIABLES}, got {variable!r}")
        check_value(MechanismError, "Table: x", x)
        check_value(MechanismError, "Table: values", values)
        self.x, self.values = jnp.asarray(x, dtype=float), jnp.asarray(values, dtype=float)
        if period is not None:
            check_value(MechanismError, "Table: period", period, positive=True)
        if self.x.ndim != 1 or self.x.shape != self.values.shape or self.x.shape[0] < 2:
            raise MechanismError(f"Table: x and values must be two 1-D arrays of the same length >= 2, got shapes {self.x.shape} and {self.values.shape}")
        points = concrete(self.x)  # checked where given, not under a trace
        if points is not None:
            if np.any(np.diff(points) < 0):
                raise MechanismError(f"Table: x must be increasing (a repeated x is a jump; the interval search reads x "
                                     f"sorted), got {points.tolist()}")
            # in x's own precision (float32: 2 pi rounds up past the period 2 pi given in float64)
            own = np.dtype(self.x.dtype)
            if period is not None and points[-1] - points[0] > (float(np.asarray(period, dtype=own))
                                                                 + 4 * float(np.spacing(own.type(points[-1])))):
                raise MechanismError(f"Table: the period {float(period):g} is shorter than the x range {points[-1] - points[0]:g}: "
                                     "a periodic table wraps x into [x[0], x[0] + period), so the values past it would never be read")
        self.variable, self.period = variable, period

    def __call__(self, q, omega, t):
        x = {"q": q, "omega": omega, "t": t}[self.variable]
        if self.piece is not None:
            return self.piece[0] + self.piece[1] * x
        if self.period is not None:
            x = self.x[0] + jnp.mod(x - self.x[0], self.period)
        return _interp(x, self.x, self.values)


SMALL_TABLE = 64  # up to this many points a table's interval is found by comparing with each point


def _interp(x, xp, fp):
    """``jnp.interp(x, xp, fp)`` (constant beyond the ends; the same formula), its interval
    found without a loop: jnp.interp searches with a while loop, a call of its own at
    every right-hand side."""
    method = "compare_all" if xp.shape[0] <= SMALL_TABLE else "scan_unrolled"
    i = jnp.clip(jnp.searchsorted(xp, x, side="right", method=method), 1, xp.shape[0] - 1)
    dx, delta = xp[i] - xp[i - 1], x - xp[i - 1]
    flat = jnp.abs(dx) <= np.spacing(np.finfo(xp.dtype).eps)  # no NaN gradient on a zero-length interval
    f = jnp.where(flat, fp[i - 1], fp[i - 1] + (delta / jnp.where(flat, 1.0, dx)) * (fp[i] - fp[i - 1]))
    return jnp.where(x < xp[0], fp[0], jnp.where(x > xp[-1], fp[-1], f))


class Vector(eqx.Module):
    """A 2-vector whose components are values (numbers, forms or functions of (q, omega, t))."""

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    x: Any
    y: Any

    def __init__(self, x, y):
        self.x, self.y = _as_value(x, "Vector: x"), _as_value(y, "Vector: y")

    def __call__(self, q, omega, t):
        return jnp.stack([evaluate(self.x, q, omega, t), evaluate(self.y, q, omega, t)])


def evaluate(value, q, omega, t) -> Array:
    """A load value at (q, omega, t): numbers as they are, forms and functions called."""
    if callable(value):
        return jnp.asarray(value(q, omega, t), dtype=float)
    return jnp.asarray(value, dtype=float)


def _velocity_dependent(*values, flag: bool | None = None) -> bool:
    if flag is not None:
        return flag
    for v in values:
        if isinstance(v, Vector):
            if _velocity_dependent(v.x, v.y):
                return True
        elif isinstance(v, (Polynomial, Table)):
            if v.variable == "omega":
                return True
        elif callable(v):
            return True
    return False


ARGUMENTS = ("q", "omega", "t")  # a value function's arguments, in order


def reads(value, argument: str) -> bool:
    """Whether a load value may depend on ``argument`` ("omega" or "t"): a form in it, or a
    function whose traced program uses it (a structural test: a function that uses t and
    cancels it counts as reading it; one that cannot be traced counts too). Exact where a
    probe at some points is not: a drive switched on at t = 0.5 has d/dt = 0 at t = 0."""
    if isinstance(value, Vector):
        return reads(value.x, argument) or reads(value.y, argument)
    if isinstance(value, (Polynomial, Table)):
        return value.variable == argument
    if not callable(value):
        return False
    try:
        program = jax.make_jaxpr(lambda q, omega, t: evaluate(value, q, omega, t))(0.0, 0.0, 0.0).jaxpr
    except Exception:  # not traceable: whatever it reads, it fails where it is evaluated
        return True
    return any(_outputs_using(program, [v is program.invars[ARGUMENTS.index(argument)] for v in program.invars]))


def _outputs_using(program, inputs: list[bool]) -> list[bool]:
    """Which outputs of a jaxpr depend on the inputs flagged: an equation's outputs use what
    its inputs use, a nested program (jit, checkpoint, custom_jvp) read inside, any other
    (cond, scan, while) whole: each output uses every input."""
    used = {v for v, flag in zip(program.invars, inputs) if flag}

    def uses(v):
        return not isinstance(v, jax.extend.core.Literal) and v in used

    for eqn in program.eqns:
        flags = [uses(v) for v in eqn.invars]
        if not any(flags):
            continue
        inner = eqn.params.get("jaxpr", eqn.params.get("call_jaxpr"))
        inner = getattr(inner, "jaxpr", inner)  # a ClosedJaxpr's program
        if (isinstance(inner, jax.extend.core.Jaxpr) and len(inner.invars) == len(flags)
                and len(inner.outvars) == len(eqn.outvars)):
            used.update(v for v, flag in zip(eqn.outvars, _outputs_using(inner, flags)) if flag)
        else:
            used.update(eqn.outvars)
    return [uses(v) for v in program.outvars]


def _has_time_form(value, *, functions: bool = False) -> bool:
    """A form in t somewhere in ``value``; with ``functions``, a function too (it may read t)."""
    if isinstance(value, (Polynomial, Table)):
        return value.variable == "t"
    if isinstance(value, Vector):
        return _has_time_form(value.x, functions=functions) or _has_time_form(value.y, functions=functions)
    return functions and callable(value)


def _is_table(value) -> bool:
    return isinstance(value, Table)


def tables_in(loads, variable: str) -> tuple[Table, ...]:
    """The piecewise-linear tables in ``variable`` among the loads' values: their knots are
    kinks of the loads (or jumps, at an x given twice). In the loads' tree order, which
    :func:`with_pieces` follows."""
    leaves = jax.tree.leaves(loads, is_leaf=_is_table)
    return tuple(v for v in leaves if isinstance(v, Table) and v.variable == variable)


def pieces_at(tables, x, direction):
    """(n, 2): (a, b) of each table's piece just ahead of x in ``direction`` (its value a + b x,
    continued past its knots: see :func:`with_pieces`)."""
    if not tables:
        return jnp.zeros((0, 2))
    ahead = x + direction * KNOT_ROUNDOFF * (1.0 + jnp.abs(x))
    rows = []
    for table in tables:
        read = lambda v, table=table: table(v, v, v)  # noqa: E731  (its variable is v, whichever it is)
        value, slope = jax.jvp(read, (ahead,), (jnp.ones_like(ahead),))
        rows.append(jnp.stack([value - slope * ahead, slope]))
    return jnp.stack(rows)


def with_pieces(loads, variable: str, pieces):
    """The loads with their tables in ``variable`` read as the linear pieces ``pieces`` (rows
    of :func:`pieces_at`, in :func:`tables_in`'s order): a segment's field continued past the
    knots analytically, as the friction's Coulomb signs are, so that the step that crosses
    the next knot (where the segment's event ends it) is that of one smooth field."""
    count = iter(range(pieces.shape[0]))

    def frozen(value):
        if isinstance(value, Table) and value.variable == variable:
            return with_field(value, "piece", pieces[next(count)])
        return value

    return jax.tree.map(frozen, loads, is_leaf=_is_table)


KNOT_ROUNDOFF = 1e-10  # a knot within this (1 + |x|) of x is the one just reached, not one ahead


def next_knot(tables, x, direction):
    """The nearest knot of ``tables`` (see :func:`tables_in`) strictly ahead of x in
    ``direction`` (+1 or -1), periodic tables wrapped; +-inf where there is none."""
    eps = KNOT_ROUNDOFF * (1.0 + jnp.abs(x))
    ups, downs = [], []
    for table in tables:
        knots, shift = table.x, jnp.zeros_like(x)
        if table.period is not None:  # x wrapped into [x0, x0 + period), the knots of three periods around it
            shift = x - (knots[0] + jnp.mod(x - knots[0], table.period))
            knots = jnp.concatenate([knots - table.period, knots, knots + table.period])
        ups.append(shift + jnp.min(jnp.where(knots + shift > x + eps, knots, jnp.inf)))
        downs.append(shift + jnp.max(jnp.where(knots + shift < x - eps, knots, -jnp.inf)))
    return jnp.where(direction > 0, jnp.min(jnp.stack(ups)), jnp.max(jnp.stack(downs)))


def piece_around(tables, x, side):
    """For a variable that may go either way in a segment (omega): (bounds (2,), pieces (n, 2)),
    the knots below and above the piece of ``tables`` just on ``side`` (+1 or -1) of x, each
    moved out by 2 KNOT_ROUNDOFF (1 + |x|), and that piece (:func:`pieces_at`). x on a knot just
    reached (located to the root finder's tolerance, on either side of it) is then inside the
    bounds, and the piece is the one it goes on into."""
    pad = jax.lax.stop_gradient(2 * KNOT_ROUNDOFF * (1.0 + jnp.abs(x)))  # an offset, not a function of x
    inside = x + side * pad
    bounds = jnp.stack([next_knot(tables, inside, -1.0) - pad, next_knot(tables, inside, 1.0) + pad])
    return bounds, pieces_at(tables, inside, side)


def _as_value(v, where: str, shape: tuple[int, ...] = ()):
    """A load value: a function or form as it is (its arguments checked here, what it
    returns by :func:`check_loads`), a number (or 2-vector, ``shape``) checked finite."""
    if callable(v):
        _check_arguments(v, where)
        return v
    check_value(MechanismError, where, v, shape=shape)
    return jnp.asarray(v, dtype=float)


def unbindable(fn, arity: int) -> inspect.Signature | None:
    """``fn``'s signature where it cannot be called with ``arity`` positional arguments (a
    function of the wrong arguments fails later, inside JAX's trace, with a bare TypeError),
    else None; None too where it has no signature to read (a builtin: its call shows)."""
    try:
        signature = inspect.signature(fn)
    except (TypeError, ValueError):
        return None
    try:
        signature.bind(*(0.0,) * arity)
    except TypeError:
        return signature
    return None


def _check_arguments(fn, where: str) -> None:
    """Raise naming ``where`` when ``fn`` cannot be called as f(q, omega, t)."""
    if (signature := unbindable(fn, 3)) is not None:
        raise MechanismError(f"{where}: a function must take (q, omega, t), the driving coordinate, its velocity "
                             f"and the time, as f(q, omega, t); the one given takes {signature}")


# a function's output shape, traced once per function (tracing it costs ~1 ms, at every call
# of a stage that takes the loads); functions that cannot be weakly referenced are traced each time
_OUTPUT_SHAPES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _output_shape(fn) -> tuple[int, ...]:
    try:
        return _OUTPUT_SHAPES[fn]
    except (KeyError, TypeError):  # not seen yet, or not hashable
        pass
    scalar = jax.ShapeDtypeStruct((), jnp.result_type(float))
    found = jax.eval_shape(lambda q, omega, t: evaluate(fn, q, omega, t), scalar, scalar, scalar).shape
    try:
        _OUTPUT_SHAPES[fn] = found
    except TypeError:
        pass
    return found


def _output_problem(value, shape: tuple[int, ...]) -> str | None:
    """What is wrong with what a function or form given as a load value returns (its shape,
    found by tracing it once without computing anything), or None; numbers are checked where
    they are given."""
    if not callable(value):
        return None
    if isinstance(value, Vector):
        for axis, component in (("x", value.x), ("y", value.y)):
            if (problem := _output_problem(component, ())) is not None:
                return f"Vector component {axis}, {problem}"
        found = (2,)
    else:
        found = _output_shape(value)
    return None if found == shape else f"a function of (q, omega, t), must return {shape_words(shape)}, it returns {found_words(found)}"


# ---------------------------------------------------------------------------- base class


class AbstractLoad(eqx.Module):
    """Every load says which links it acts on (``wrenches``), what it puts on the
    driver (``effort``), its potential energy and its dissipated power.

    Capabilities, declared by each class: ``velocity_dependent`` (depends on the
    driving velocity: the integrator builds velocities for it), ``conservative``
    (its work is minus the change of its ``potential``: it is in V, not in the work
    of the energy balance), ``dissipative`` (it only removes energy: ``dissipation``
    is its power loss), ``needs_reactions`` (its wrenches depend on the joint
    reactions: friction), ``time_dependent()`` (depends on time t)."""

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut
    repr_omit: ClassVar[tuple[str, ...]] = ("velocity_dependent",)  # a capability of the class, not a value given

    velocity_dependent: eqx.AbstractVar[bool]
    conservative: ClassVar[bool] = False
    dissipative: ClassVar[bool] = False
    needs_reactions: ClassVar[bool] = False

    def time_dependent(self) -> bool:
        """True when the load's values depend on time t (forms in t; functions are not
        inspected here: a table build probes them)."""
        return any(_has_time_form(v) for v in self._values().values())

    def may_depend_on_time(self) -> bool:
        """:meth:`time_dependent`, or some value is a function (not inspected: it may read t)."""
        return any(_has_time_form(v, functions=True) for v in self._values().values())

    def reads(self, argument: str) -> bool:
        """Whether some value of the load may depend on ``argument`` ("omega" or "t"), its
        functions' programs inspected (see :func:`reads`)."""
        return any(reads(v, argument) for v in self._values().values())

    value_shape: ClassVar[tuple[int, ...]] = ()  # of each value field: a number (a force: a 2-vector)

    def _values(self) -> dict[str, Any]:
        """The load's value fields by name (numbers, forms or functions)."""
        return {}

    def check(self, mechanism: Mechanism) -> None:
        """Raise :class:`MechanismError` naming an unknown point or link."""

    def wrenches(self, mechanism: Mechanism, kin, t) -> list[tuple[str, Array, Array]]:
        """(link, force (2,), moment about the link's COM) for each link loaded."""
        return []

    def effort(self, mechanism: Mechanism, q, omega, t) -> Array:
        """Generalized force on the driver (N m or N)."""
        return jnp.zeros(())

    def potential(self, mechanism: Mechanism, pose: Pose) -> Array:
        """Potential energy (J)."""
        return jnp.zeros(())

    def dissipation(self, mechanism: Mechanism, kin) -> Array:
        """Power dissipated (W, >= 0): what the load removes from the mechanism."""
        return jnp.zeros(())


def _com_link(point: str) -> str | None:
    """The link whose centre of mass ``point`` names (``"com:<link>"``), or None for a named point."""
    return point[len(COM_PREFIX):] if isinstance(point, str) and point.startswith(COM_PREFIX) else None


def _carriers(mechanism: Mechanism, point: str) -> list[str]:
    """Links carrying ``point`` (the ground first when it is a fixed point); a centre of mass: its link."""
    link = _com_link(point)
    if link is not None:
        return [link] if link in mechanism.links else []
    found = [GROUND] if point in mechanism.ground else []
    return found + [name for name, link in mechanism.links.items() if point in link.points]


def point_problem(mechanism: Mechanism, point: str) -> str | None:
    """What is wrong with ``point`` as a load's point of application, or None."""
    if not isinstance(point, str):
        return f"expected a point name (a string), got {point!r}"
    link = _com_link(point)
    if link is not None:
        if link not in mechanism.links:
            return f"unknown link '{link}' in '{point}' (a centre of mass is 'com:<moving link>'; links: {few(sorted(mechanism.links))})"
        return None
    if point in mechanism.point_names:
        return None
    hint = ""
    if "com" in point.lower() or "centre" in point.lower() or "center" in point.lower():
        hint = f"; a link's centre of mass is written 'com:<link>', e.g. 'com:{next(iter(mechanism.links))}'"
    return f"unknown point '{point}' (known: {few(sorted(mechanism.point_names))}){hint}"


def carrier_problem(mechanism: Mechanism, point: str, link: str | None) -> str | None:
    """What is wrong with ``link`` as the carrier of a load at the known ``point``, or
    None (None: the default carrier)."""
    if link is None:
        return None
    carriers = _carriers(mechanism, point)
    if link != GROUND and link not in mechanism.links:
        return f"unknown link '{link}' (known: {few(sorted(mechanism.links))})"
    if link not in carriers:
        return f"link '{link}' does not carry point '{point}' (carried by {carriers})"
    return None


def joint_problem(mechanism: Mechanism, joint: str) -> str | None:
    """What is wrong with ``joint`` as a revolute between exactly two carriers, or None."""
    carriers = _carriers(mechanism, joint)
    if len(carriers) == 2:
        return None
    return (f"point '{joint}' must be a joint of exactly two links (or a link and the ground), "
            f"it is carried by {carriers or 'nothing'}")


def _check_point(mechanism: Mechanism, point: str, link: str | None, what: str, keyword: str) -> None:
    """Raise :class:`MechanismError` for an unknown point or a carrier not carrying it;
    ``keyword``: the argument that named the carrier (e.g. ``"link"``)."""
    problem = point_problem(mechanism, point)
    if problem is not None:
        raise MechanismError(f"{what}: {problem}")
    problem = carrier_problem(mechanism, point, link)
    if problem is not None:
        raise MechanismError(f"{what}, argument '{keyword}': {problem}")


def _carrier_argument(link: str | None) -> str | None:
    """A carrier argument: a link name, or None / "" for the default."""
    return link or None


def _two_ends(kind: str, a: str, b: str, links) -> tuple[tuple[str, str], tuple[str | None, str | None]]:
    """A two-point load's ends and their carriers (None for the default)."""
    links = (links,) if isinstance(links, str) else tuple(links)
    if len(links) != 2:
        raise MechanismError(f"{kind}: links must be (carrier of a, carrier of b), each a link name or None, got {links!r}")
    return (a, b), (_carrier_argument(links[0]), _carrier_argument(links[1]))


def _link_of(mechanism: Mechanism, point: str, link: str | None) -> str:
    """The carrier: ``link`` if given, else the centre of mass's link or the point's owner."""
    if link is not None:
        return link
    return _com_link(point) or dict(mechanism.owner)[point]


def _moment_about_com(kin, link: str, at: Array, force: Array) -> Array:
    return cross(at - kin.coms[link], force)


def _point_velocity(kin, point: str) -> Array:
    """Velocity (m/s) of a moving point or centre of mass; a fixed point's is zero."""
    link = _com_link(point)
    if link is not None:
        return kin.com_velocities[link]
    return kin.velocities[point] if point in kin.velocities else jnp.zeros(2)


def _point_position(mechanism: Mechanism, kin, point: str) -> Array:
    """A moving point from ``kin.points`` (a Kinematics or a Pose), a centre of mass from
    ``kin.coms``, a fixed one from the ground."""
    link = _com_link(point)
    if link is not None:
        return kin.coms[link]
    return kin.points[point] if point in kin.points else mechanism.ground[point]


# ---------------------------------------------------------------------------- loads


class PointForce(AbstractLoad):
    """A force (N, global frame) at a point of application.

    ``point``: a named point, or ``"com:<link>"`` for a link's centre of mass.
    ``force``: a 2-vector, or a function ``f(q, omega, t) -> (2,)``. ``link``: the
    carrier, the link the force acts on, when the point is shared by several links
    (a joint) or by a link and the ground. Default (None or ""): the point's owner,
    i.e. the ground for a fixed point, otherwise the first link of the formation
    sequence that carries it; a centre of mass is carried by its link. The motion
    is the same whichever carrier (the point has one velocity); the reaction at the
    joint differs by the force.

    **Example:**
    >>> assurjax.PointForce("B", [0.0, -50.0], link="slider")   # at the joint B, on the slider
    >>> assurjax.PointForce("com:rod", [10.0, 0.0])              # at the rod's centre of mass
    """

    point: str = eqx.field(static=True)
    force: Any
    link: str | None = eqx.field(static=True, default=None)
    velocity_dependent: bool = eqx.field(static=True, default=False)

    def __init__(self, point: str, force, *, link: str | None = None, velocity_dependent: bool | None = None):
        self.point, self.link = point, _carrier_argument(link)
        self.force = _as_value(force, f"PointForce on point '{point}': force", (2,))
        self.velocity_dependent = _velocity_dependent(force, flag=velocity_dependent)

    value_shape: ClassVar[tuple[int, ...]] = (2,)

    def _values(self):
        return {"force": self.force}

    def check(self, mechanism):
        _check_point(mechanism, self.point, self.link, f"force on point '{self.point}'", "link")

    def wrenches(self, mechanism, kin, t):
        link = _link_of(mechanism, self.point, self.link)
        if link == GROUND:
            return []
        f = evaluate(self.force, kin.q, kin.omega, t)
        return [(link, f, _moment_about_com(kin, link, _point_position(mechanism, kin, self.point), f))]


class Couple(AbstractLoad):
    """A couple (N m, counterclockwise positive) on the moving ``link``: a number or
    ``f(q, omega, t)``. It has no point of application: ``link`` is its carrier.

    **Example:**
    >>> assurjax.Couple("rocker", -2.0)   # 2 N m clockwise on the rocker
    """

    link: str = eqx.field(static=True)
    moment: Any
    velocity_dependent: bool = eqx.field(static=True, default=False)

    def __init__(self, link: str, moment, *, velocity_dependent: bool | None = None):
        self.link = link
        self.moment = _as_value(moment, f"Couple on link '{link}': moment")
        self.velocity_dependent = _velocity_dependent(moment, flag=velocity_dependent)

    def _values(self):
        return {"moment": self.moment}

    def check(self, mechanism):
        if self.link not in mechanism.links:
            raise MechanismError(f"couple: unknown link '{self.link}' (known: {few(sorted(mechanism.links))})")

    def wrenches(self, mechanism, kin, t):
        return [(self.link, jnp.zeros(2), evaluate(self.moment, kin.q, kin.omega, t))]


class _TwoPoint(AbstractLoad):
    """Shared geometry of springs and dampers between points a and b, and their
    carriers ``links`` (one per end, None for the default; see :class:`PointForce`)."""

    points: tuple[str, str] = eqx.field(static=True)
    links: tuple[str | None, str | None] = eqx.field(static=True)

    def check(self, mechanism):
        for k, (p, link) in enumerate(zip(self.points, self.links)):
            _check_point(mechanism, p, link, f"{type(self).__name__.lower()} {self.points[0]}-{self.points[1]}", f"links[{k}]")
        if self.points[0] == self.points[1]:
            raise MechanismError(f"{type(self).__name__.lower()}: both ends are point '{self.points[0]}'")

    def _ends(self, mechanism, kin):
        (a, b), (la, lb) = self.points, self.links
        pa, pb = _point_position(mechanism, kin, a), _point_position(mechanism, kin, b)
        return pa, pb, _link_of(mechanism, a, la), _link_of(mechanism, b, lb)

    def _pull(self, mechanism, kin, tension):
        """Wrenches of a tension (N, > 0 pulls the ends together) along the line a-b."""
        pa, pb, la, lb = self._ends(mechanism, kin)
        d = pb - pa
        u = d / jnp.where(safe_norm(d) > 0, safe_norm(d), 1.0)
        out = []
        for link, at, f in ((la, pa, tension * u), (lb, pb, -tension * u)):
            if link != GROUND:
                out.append((link, f, _moment_about_com(kin, link, at, f)))
        return out

    def _rate(self, mechanism, kin):
        """Length (m) and lengthening rate (m/s) of the line a-b."""
        pa, pb, _, _ = self._ends(mechanism, kin)
        d = pb - pa
        length = safe_norm(d)
        dv = _point_velocity(kin, self.points[1]) - _point_velocity(kin, self.points[0])
        return length, dot(d, dv) / jnp.where(length > 0, length, 1.0)


class Spring(_TwoPoint):
    """Linear spring between points a and b: tension k (L - L0) (N), potential
    k (L - L0)^2 / 2 (J). ``stiffness`` k in N/m, ``free_length`` L0 in m.

    ``a``, ``b``: named points or ``"com:<link>"`` (a centre of mass). ``links``:
    the carrier of each end, the link that end acts on when its point is a joint;
    None or "" for the default, the point's owner (the ground for a fixed point,
    otherwise the first link of the formation sequence that carries it). The motion
    does not depend on the carriers; the reaction at a joint end does.

    **Example:**
    >>> assurjax.Spring("O", "B", 200.0, 0.3, links=(None, "slider"))   # B end on the slider, not the rod
    """

    stiffness: Array
    free_length: Array
    velocity_dependent: bool = eqx.field(static=True, default=False)
    conservative: ClassVar[bool] = True

    def __init__(self, a: str, b: str, stiffness, free_length=0.0, *, links: tuple[str | None, str | None] = (None, None)):
        self.points, self.links = _two_ends("Spring", a, b, links)
        check_value(MechanismError, "Spring: stiffness", stiffness, shape=(), nonnegative=True)
        check_value(MechanismError, "Spring: free_length", free_length, shape=(), nonnegative=True)
        self.stiffness, self.free_length = jnp.asarray(stiffness, dtype=float), jnp.asarray(free_length, dtype=float)
        self.velocity_dependent = False

    def _length(self, mechanism, config):
        """L (m) in ``config``: a Kinematics or a Pose (both have ``points``)."""
        a, b = self.points
        return safe_norm(_point_position(mechanism, config, b) - _point_position(mechanism, config, a))

    def wrenches(self, mechanism, kin, t):
        return self._pull(mechanism, kin, self.stiffness * (self._length(mechanism, kin) - self.free_length))

    def potential(self, mechanism, pose):
        return 0.5 * self.stiffness * (self._length(mechanism, pose) - self.free_length) ** 2


class Damper(_TwoPoint):
    """Linear viscous damper between points a and b: tension c dL/dt (N),
    ``coefficient`` c in N s/m; dissipates c (dL/dt)^2 (W). Ends and ``links``
    (their carriers) as for :class:`Spring`.

    **Example:**
    >>> assurjax.Damper("H", "com:ram", 50.0)   # from the frame point H to the ram's centre of mass
    """

    coefficient: Array
    velocity_dependent: bool = eqx.field(static=True, default=True)
    dissipative: ClassVar[bool] = True

    def __init__(self, a: str, b: str, coefficient, *, links: tuple[str | None, str | None] = (None, None)):
        self.points, self.links = _two_ends("Damper", a, b, links)
        check_value(MechanismError, "Damper: coefficient", coefficient, shape=(), nonnegative=True)
        self.coefficient = jnp.asarray(coefficient, dtype=float)
        self.velocity_dependent = True

    def wrenches(self, mechanism, kin, t):
        _, rate = self._rate(mechanism, kin)
        return self._pull(mechanism, kin, self.coefficient * rate)

    def dissipation(self, mechanism, kin):
        _, rate = self._rate(mechanism, kin)
        return self.coefficient * rate**2


class RotaryDamper(AbstractLoad):
    """Viscous damper on the revolute ``joint`` (a point name shared by exactly two
    links, or a link and the ground): couple c (w_b - w_a) on link a, the opposite
    on link b; ``coefficient`` c in N m s/rad; dissipates c (w_b - w_a)^2 (W).
    Both links carry it, a the point's owner (the ground for a fixed point, otherwise
    the earlier in the formation sequence), b the other: there is no carrier to pick.

    **Example:**
    >>> assurjax.RotaryDamper("O4", 2.0)
    """

    joint: str = eqx.field(static=True)
    coefficient: Array
    velocity_dependent: bool = eqx.field(static=True, default=True)
    dissipative: ClassVar[bool] = True

    def __init__(self, joint: str, coefficient):
        self.joint = joint
        check_value(MechanismError, "RotaryDamper: coefficient", coefficient, shape=(), nonnegative=True)
        self.coefficient = jnp.asarray(coefficient, dtype=float)
        self.velocity_dependent = True

    def check(self, mechanism):
        problem = joint_problem(mechanism, self.joint)
        if problem is not None:
            raise MechanismError(f"rotary damper: {problem}")

    def _relative(self, mechanism, kin):
        a, b = _carriers(mechanism, self.joint)
        w = lambda link: jnp.zeros(()) if link == GROUND else kin.angular_velocities[link]  # noqa: E731
        return a, b, w(b) - w(a)

    def wrenches(self, mechanism, kin, t):
        a, b, rel = self._relative(mechanism, kin)
        m = self.coefficient * rel
        return [(link, jnp.zeros(2), s * m) for link, s in ((a, 1.0), (b, -1.0)) if link != GROUND]

    def dissipation(self, mechanism, kin):
        _, _, rel = self._relative(mechanism, kin)
        return self.coefficient * rel**2


class Drive(AbstractLoad):
    """The driving effort on the driver: torque (N m, crank) or force (N along the
    guide, slider), a number or ``f(q, omega, t)``. Its carrier is the driver link
    (it enters as the generalized force conjugate to q).

    **Example:**
    >>> assurjax.Drive(assurjax.Polynomial([0.5, 0.1], variable="t"))   # 0.5 + 0.1 t N m
    """

    value: Any
    velocity_dependent: bool = eqx.field(static=True, default=False)

    def __init__(self, value, *, velocity_dependent: bool | None = None):
        self.value = _as_value(value, "Drive: value")
        self.velocity_dependent = _velocity_dependent(value, flag=velocity_dependent)

    def _values(self):
        return {"value": self.value}

    def effort(self, mechanism, q, omega, t):
        return evaluate(self.value, q, omega, t)


class MotorLine(AbstractLoad):
    """A motor's linear torque-speed line on the driver:
    tau = stall (1 - omega / no_load_speed). ``stall`` in N m (N for a linear motor),
    ``no_load_speed`` in rad/s (m/s). The line is not clipped: beyond the no-load
    speed the motor brakes. Its carrier is the driver link, as for :class:`Drive`.

    **Example:**
    >>> assurjax.MotorLine(1.5, 10.0)
    """

    stall: Array
    no_load_speed: Array
    velocity_dependent: bool = eqx.field(static=True, default=True)

    def __init__(self, stall, no_load_speed):
        check_value(MechanismError, "MotorLine: stall", stall, shape=())
        check_value(MechanismError, "MotorLine: no_load_speed", no_load_speed, shape=(), positive=True)
        self.stall, self.no_load_speed = jnp.asarray(stall, dtype=float), jnp.asarray(no_load_speed, dtype=float)
        self.velocity_dependent = True

    def effort(self, mechanism, q, omega, t):
        return self.stall * (1.0 - omega / self.no_load_speed)


# ---------------------------------------------------------------------------- totals


def check_loads(mechanism: Mechanism, loads) -> None:
    """Raise :class:`MechanismError` for a load on an unknown point or link, a function value
    that cannot be called as f(q, omega, t) or returns the wrong shape, and two friction
    elements on one pair."""
    from ._friction import repeated_pair  # the friction module imports this one

    loads = tuple(loads)  # read twice
    for i, load in enumerate(loads):
        if not isinstance(load, AbstractLoad):
            raise MechanismError(f"load #{i + 1}: expected an assurjax load (PointForce, Couple, Spring, ...), got {type(load).__name__}")
        load.check(mechanism)
        for name, value in type(load)._values(load).items():  # through the class: no bound-method module
            if (problem := _called_problem(value, load.value_shape)) is not None:
                raise MechanismError(f"load #{i + 1} ({type(load).__name__}): {name}, {problem}")
    if (repeated := repeated_pair(loads)) is not None:
        first, second, problem = repeated
        raise MechanismError(f"loads #{first + 1} and #{second + 1}: {problem}")


def _called_problem(value, shape: tuple[int, ...]) -> str | None:
    """:func:`_output_problem`, with a function that fails when called as f(q, omega, t) (one
    whose signature could not be read where it was given) reported instead of raising."""
    try:
        return _output_problem(value, shape)
    except TypeError as e:
        return f"a function of (q, omega, t), fails when called as f(q, omega, t): {e}"


def _check_inputs(mechanism: Mechanism, loads, *, gravity=None) -> None:
    """The public load functions' checks: the loads (:func:`check_loads`) and the gravity."""
    check_loads(mechanism, loads)
    if gravity is not None:
        check_value(MechanismError, "gravity", gravity, shape=(2,))


def any_velocity_dependent(loads) -> bool:
    """True when some load (or driving effort) depends on the driving velocity."""
    return any(load.velocity_dependent for load in loads)


def applied_wrenches(mechanism: Mechanism, gravity, loads, kin, t=0.0, *, check: bool = True) -> dict[str, tuple[Array, Array]]:
    """Resultant applied force (N) and moment about the COM (N m, counterclockwise
    positive) on every moving link, from gravity (m/s^2, a 2-vector) and every
    load except the driving effort.

    ``kin`` is a single-configuration :class:`assurjax.Kinematics` (``order >= 1``
    when a load depends on velocity). ``check``: the loads' points and links and the
    gravity checked first (:class:`assurjax.MechanismError` naming what is unknown)."""
    loads = tuple(loads)  # read twice: a generator once
    if check:
        _check_inputs(mechanism, loads, gravity=gravity)
    g = jnp.asarray(gravity, dtype=float)
    out = {name: [link.mass * g, jnp.zeros(())] for name, link in mechanism.links.items()}
    for load in loads:
        for link, f, m in load.wrenches(mechanism, kin, t):
            out[link][0] = out[link][0] + f
            out[link][1] = out[link][1] + m
    return {name: (f, m) for name, (f, m) in out.items()}


def drives(load) -> bool:
    """Whether a load acts on the driver (a ``Drive``, a ``MotorLine``: it has an effort of its own)."""
    return type(load).effort is not AbstractLoad.effort


def driver_effort(mechanism: Mechanism, loads, q, omega, t=0.0, *, check: bool = True) -> Array:
    """Torque (N m, crank) or force (N, slider) that the driving loads put on the driver; 0 if
    none. ``check``: the loads checked first, as in :func:`applied_wrenches`."""
    loads = tuple(loads)
    if check:
        _check_inputs(mechanism, loads)
    total = jnp.zeros(())
    for load in loads:
        total = total + load.effort(mechanism, q, omega, t)
    return total


def potential_energy(mechanism: Mechanism, gravity, loads, pose: Pose, *, check: bool = True) -> Array:
    """Potential energy (J) of gravity (-sum m g . r_G, zero at the origin) and springs.
    ``check``: the loads and the gravity checked first, as in :func:`applied_wrenches`."""
    loads = tuple(loads)
    if check:
        _check_inputs(mechanism, loads, gravity=gravity)
    g = jnp.asarray(gravity, dtype=float)
    v = jnp.zeros(())
    for name, link in mechanism.links.items():
        v = v - link.mass * dot(g, pose.coms[name])
    for load in loads:
        v = v + load.potential(mechanism, pose)
    return v


def dissipated_power(mechanism: Mechanism, loads, kin, *, check: bool = True) -> Array:
    """Power (W, >= 0) removed by the dampers at the configuration ``kin`` (with velocities).
    ``check``: the loads checked first, as in :func:`applied_wrenches`."""
    loads = tuple(loads)
    if check:
        _check_inputs(mechanism, loads)
    total = jnp.zeros(())
    for load in loads:
        total = total + load.dissipation(mechanism, kin)
    return total
