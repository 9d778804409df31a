"""The [[loads]] tables of a scene file (see docs/scene-format.md, "Loads").

No code is evaluated: a load value is a number, or one of the documented forms
``{ polynomial = [c0, c1, ...], variable = "q" }`` and
``{ x = [...], values = [...], variable = "q", period = 6.283185307179586 }``.
"""

from __future__ import annotations

from .. import _friction, _loads
from .._errors import MechanismError, SceneError
from .._listing import did_you_mean
from .._mechanism import Mechanism
from .._values import value_problem
from ._load import Fields

FORM_KEYS = {"polynomial", "x", "values", "variable", "period"}
TABLE_KEYS = ("x", "values", "period")  # a polynomial has none of them


def _value(f: Fields, key: str, default=...):
    """A number, a polynomial or a table."""
    v = f.raw(key, default)
    if isinstance(v, bool):
        f.fail(key, f"expected a number or a table, got {v!r}")
    if isinstance(v, (int, float)):
        f.check(key, v)
        return float(v)
    if not isinstance(v, dict):
        f.fail(key, f"expected a number, {{ polynomial = [...] }} or {{ x = [...], values = [...] }}, got {v!r}")
    extra = sorted(set(v) - FORM_KEYS)
    if extra:
        f.fail(key, f"unknown entries {extra}{did_you_mean(extra, FORM_KEYS)} (allowed: {sorted(FORM_KEYS)})")
    variable = v.get("variable", "q")
    if not isinstance(variable, str) or variable not in _loads.VARIABLES:
        f.fail(key, f"variable must be one of {list(_loads.VARIABLES)}, got {variable!r}")
    if "polynomial" in v:
        stray = [k for k in TABLE_KEYS if k in v]  # were dropped without a word
        if stray:
            f.fail(key, f"'polynomial' does not go with {stray}: a polynomial takes 'polynomial' and 'variable', "
                        "a table 'x', 'values', 'variable' and 'period'")
        coefficients = v["polynomial"]
        if not _numbers(coefficients) or not coefficients:
            f.fail(key, f"polynomial must be a non-empty list of numbers (c0, c1, ...), got {coefficients!r}")
        _check_entry(f, key, "polynomial", coefficients)
        return _loads.Polynomial(coefficients, variable)
    x, values, period = v.get("x"), v.get("values"), v.get("period")
    if not (_numbers(x) and _numbers(values) and len(x) == len(values) >= 2):
        f.fail(key, f"a table needs lists 'x' and 'values' of the same length >= 2, got x = {x!r}, values = {values!r}")
    _check_entry(f, key, "x", x)
    _check_entry(f, key, "values", values)
    if any(b <= a for a, b in zip(x, x[1:])):
        f.fail(key, "table 'x' must be strictly increasing")
    if period is not None and (isinstance(period, bool) or not isinstance(period, (int, float))):
        f.fail(key, f"period must be a positive number, got {period!r}")
    if period is not None:
        _check_entry(f, key, "period", period, positive=True)
    return _loads.Table(x, values, variable, None if period is None else float(period))


def _check_entry(f: Fields, key: str, entry: str, value, **ranges) -> None:
    problem = value_problem(value, **ranges)
    if problem is not None:
        f.fail(key, f"{entry} {problem}")


def _numbers(v) -> bool:
    return isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)


def _point(f: Fields, key: str, mechanism: Mechanism) -> str:
    """A point of application: a named point or "com:<link>"."""
    p = f.string(key)
    problem = _loads.point_problem(mechanism, p)
    if problem is not None:
        f.fail(key, problem)
    return p


def _link(f: Fields, key: str, mechanism: Mechanism) -> str:
    link = f.string(key)
    if link not in mechanism.links:
        f.fail(key, f"unknown link '{link}' (known: {sorted(mechanism.links)})")
    return link


def _carrier(f: Fields, point: str, mechanism: Mechanism) -> str | None:
    """The optional ``link`` carrying a point load ("" or absent: the default)."""
    link = f.string("link", "") or None
    problem = _loads.carrier_problem(mechanism, point, link)
    if problem is not None:
        f.fail("link", problem)
    return link


def _two_points(f: Fields, mechanism: Mechanism) -> tuple[str, str]:
    a, b = f.names("points", 2)
    for p in (a, b):
        problem = _loads.point_problem(mechanism, p)
        if problem is not None:
            f.fail("points", problem)
    if a == b:
        f.fail("points", f"both ends are point '{a}'")
    return a, b


def _two_carriers(f: Fields, points: tuple[str, str], mechanism: Mechanism) -> tuple[str | None, str | None]:
    """The optional ``links = [carrier of a, carrier of b]`` ("" or absent: the default)."""
    if not f.has("links"):
        return None, None
    links = tuple(link or None for link in f.names("links", 2))
    for k, (p, link) in enumerate(zip(points, links)):
        problem = _loads.carrier_problem(mechanism, p, link)
        if problem is not None:
            f.fail("links", f"entry {k + 1} (end '{p}'): {problem}")
    return links


def _force(f, mechanism):
    point = _point(f, "point", mechanism)
    raw = f.raw("force")
    if not (isinstance(raw, list) and len(raw) == 2):
        f.fail("force", f"expected [fx, fy] (numbers or value forms), got {raw!r}")
    components = [_value(Fields({"fx": raw[0], "fy": raw[1]}, f.where + ", field 'force'", f.source), k) for k in ("fx", "fy")]
    force = components if all(isinstance(c, float) for c in components) else _loads.Vector(*components)
    return _loads.PointForce(point, force, link=_carrier(f, point, mechanism))


def _couple(f, mechanism):
    return _loads.Couple(_link(f, "link", mechanism), _value(f, "moment"))


def _spring(f, mechanism):
    a, b = _two_points(f, mechanism)
    return _loads.Spring(a, b, f.number("stiffness", nonnegative=True), f.number("free_length", 0.0, nonnegative=True),
                         links=_two_carriers(f, (a, b), mechanism))


def _damper(f, mechanism):
    a, b = _two_points(f, mechanism)
    return _loads.Damper(a, b, f.number("coefficient", nonnegative=True), links=_two_carriers(f, (a, b), mechanism))


def _rotary_damper(f, mechanism):
    joint = _point(f, "joint", mechanism)
    problem = _loads.joint_problem(mechanism, joint)
    if problem is not None:
        f.fail("joint", problem)
    return _loads.RotaryDamper(joint, f.number("coefficient", nonnegative=True))


def _drive(f, mechanism):
    return _loads.Drive(_value(f, "value"))


def _motor(f, mechanism):
    return _loads.MotorLine(f.number("stall"), f.number("no_load_speed", positive=True))  # a negative stall torque drives backwards


# each friction entry's own required fields: one kind's given to the other was reported only missing
FRICTION_FIELDS = {"joint_friction": ("joint", "radius"), "slide_friction": ("pair", "length")}
FRICTION_OF = {"joint_friction": "a revolute joint", "slide_friction": "a prismatic pair"}


def _check_friction_fields(f: Fields, kind: str) -> None:
    """Raise where the entry lacks a field of its kind and gives the other kind's instead."""
    other = next(k for k in FRICTION_FIELDS if k != kind)
    given = [k for k in FRICTION_FIELDS[other] if k in f.table]
    missing = [k for k in FRICTION_FIELDS[kind] if k not in f.table]
    if given and missing:
        own = " and ".join(f"'{k}'" for k in FRICTION_FIELDS[kind])
        theirs = " and ".join(f"'{k}'" for k in given)
        raise SceneError(f"{f.source}: {f.where}: missing field '{missing[0]}': a {kind} takes {own}, the friction "
                         f"of {FRICTION_OF[kind]}; given {theirs}, a {other}'s (type = \"{other}\", the friction of "
                         f"{FRICTION_OF[other]})")


def _joint_friction(f, mechanism):
    _check_friction_fields(f, "joint_friction")
    return _friction.JointFriction(f.string("joint"), f.number("coefficient", nonnegative=True),
                                   f.number("radius", nonnegative=True), viscous=f.number("viscous", 0.0, nonnegative=True),
                                   smoothing=_smoothing(f), static_coefficient=_static(f))


def _slide_friction(f, mechanism):
    _check_friction_fields(f, "slide_friction")
    return _friction.SlideFriction(f.string("pair"), f.number("coefficient", nonnegative=True),
                                   f.number("length", positive=True), viscous=f.number("viscous", 0.0, nonnegative=True),
                                   smoothing=_smoothing(f), static_coefficient=_static(f))


def _static(f):
    """The static coefficient, where the entry gives one (None: the coefficient at rest too);
    the element checks it against mu and the law (its error named by the entry, parse_loads)."""
    return f.number("static_coefficient", nonnegative=True) if f.has("static_coefficient") else None


def _smoothing(f):
    """The regularized law's speed, where the entry asks for it (None: the exact law)."""
    return f.number("smoothing", positive=True) if f.has("smoothing") else None


PARSERS = {
    "force": _force,
    "couple": _couple,
    "spring": _spring,
    "damper": _damper,
    "rotary_damper": _rotary_damper,
    "drive": _drive,
    "motor": _motor,
    "joint_friction": _joint_friction,
    "slide_friction": _slide_friction,
}


def parse_loads(raw, mechanism: Mechanism, source: str) -> tuple:
    """The scene's [[loads]] array of tables as a tuple of load objects."""
    if not isinstance(raw, list):
        raise SceneError(f"{source}: [[loads]] must be an array of tables, got {type(raw).__name__}")
    loads = []
    for i, table in enumerate(raw):
        kind = table.get("type") if isinstance(table, dict) else None
        where = f"[[loads]] #{i + 1}"
        if not isinstance(kind, str) or kind not in PARSERS:
            raise SceneError(f"{source}: {where}, field 'type': unknown load type {kind!r} (known: {', '.join(PARSERS)})")
        f = Fields(table, f"{where} ({kind})", source)
        f.raw("type")
        try:  # the load's own checks (its constructor's, and against the mechanism), named by the entry
            load = PARSERS[kind](f, mechanism)
            f.reject_unknown()
            load.check(mechanism)
        except MechanismError as e:
            raise SceneError(f"{source}: {where} ({kind}): {e}") from None
        loads.append(load)
    return tuple(loads)
