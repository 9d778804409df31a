"""Reading and validating TOML scene files. Every error names the file and the field."""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from .._errors import AssurjaxError, MechanismError, SceneError
from .._listing import close_match, did_you_mean, few
from .._values import value_problem
from ..dynamics._settings import OUTPUT_KEYS, check_simulation_table, state_problem
from .._mechanism import Mechanism
from ..groups import GROUND, Link
from ..groups._base import MODES
from ..groups import _drivers, _prp, _rpr, _rrp, _rrr
from ..groups import _class4, _newton, _triad
from ._scene import Scene, Settings

BUNDLED = "assurjax.scenes"
# Entries of one table ([ground], [links], [[formation]], a link's points): 30 times the 81
# links of the largest mechanism the benchmarks build (the N-four-bar with N = 40), room for
# assurjax.n_four_bar(1000). Such a scene builds in ~1.5 s; 10^5 links ran for minutes.
MAX_ENTRIES = 2500


def bundled_scenes() -> list[str]:
    """Names of the scenes shipped with the package."""
    return sorted(p.name[:-5] for p in resources.files(BUNDLED).iterdir() if p.name.endswith(".toml"))


def scene_path(path_or_name: str | Path) -> Path:
    """A scene file's path: an existing file, or the name of a bundled scene (also where a
    folder of that name is here: the command's output folder is named after the scene)."""
    path = Path(path_or_name)
    bare = path.parts == (str(path_or_name),)  # a name, not a path ("roberts", not "./roberts")
    bundled_too = bare and path.is_dir() and (resources.files(BUNDLED) / f"{path_or_name}.toml").is_file()
    if path.suffix == ".toml" or (path.exists() and not bundled_too):
        if not path.is_file():
            raise SceneError(f"{path}: " + ("a directory, not a scene file" if path.is_dir() else "no such scene file") + _bundled_hint(path))
        return path
    bundled = resources.files(BUNDLED) / f"{path_or_name}.toml"
    if not bundled.is_file():
        raise SceneError(f"'{path_or_name}' is neither a scene file nor a bundled scene{did_you_mean([str(path_or_name)], bundled_scenes())} "
                         f"(bundled: {', '.join(bundled_scenes())})")
    return Path(str(bundled))


def _bundled_hint(path: Path) -> str:
    """Where a missing file's stem is a bundled scene's name: how to load that scene."""
    if path.suffix != ".toml" or path.stem not in bundled_scenes():
        return ""
    return f"; the bundled scene of that name is loaded by its bare name, '{path.stem}' (no '.toml', no folder)"


def load_scene(path_or_name: str | Path) -> Scene:
    """Read a scene from a TOML file or a bundled scene name (e.g. ``"watt_sixbar"``).

    Raises :class:`SceneError` naming the file, table and field at fault.
    """
    path = scene_path(path_or_name)
    try:
        data = tomllib.loads(read_utf8(path))
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    return scene_from_dict(data, source=str(path))


def read_utf8(path: Path) -> str:
    """The text of a scene file, which TOML requires to be UTF-8."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: not UTF-8 text: byte {raw[e.start]:#04x} at offset {e.start} ({e.reason}); save the file as UTF-8") from None


class Fields:
    """Typed access to one table of a scene, with errors that say where."""

    def __init__(self, table: Any, where: str, source: str):
        if not isinstance(table, dict):
            raise SceneError(f"{source}: {where} must be a table, got {type(table).__name__}")
        self.table, self.where, self.source = table, where, source
        self.used: set[str] = set()
        self.asked: set[str] = set()  # fields looked for (has): known too, for the suggestions

    def fail(self, key: str, message: str):
        raise SceneError(f"{self.source}: {self.where}, field '{key}': {message}")

    def has(self, key: str) -> bool:
        self.asked.add(key)
        return key in self.table

    def raw(self, key: str, default: Any = ...):
        self.used.add(key)
        if key not in self.table:
            if default is ...:
                close = close_match(key, self.table)
                hint = f" (the table has '{close}': misspelt?)" if close else ""
                raise SceneError(f"{self.source}: {self.where}: missing field '{key}'{hint}")
            return default
        return self.table[key]

    def string(self, key: str, default: Any = ...) -> str:
        v = self.raw(key, default)
        if not isinstance(v, str):
            self.fail(key, f"expected a string, got {v!r}")
        return v

    def names(self, key: str, count: int | None = None) -> tuple[str, ...]:
        v = self.raw(key)
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or (count is not None and len(v) != count):
            self.fail(key, f"expected a list of {count or 'some'} names, got {v!r}")
        return tuple(v)

    def number(self, key: str, default: Any = ..., *, positive: bool = False, nonnegative: bool = False) -> float:
        v = self.raw(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"expected a number, got {v!r}")
        self.check(key, v, positive=positive, nonnegative=nonnegative)
        return float(v)

    def integer(self, key: str, default: Any = ..., *, at_most: int) -> int:
        """A positive integer up to ``at_most`` (a bound on the work it asks for)."""
        v = self.raw(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            self.fail(key, f"expected a positive integer, got {v!r}")
        if v > at_most:
            self.fail(key, f"must be at most {at_most}, got {v}")
        return v

    def vector(self, key: str, default: Any = ..., *, size: int = 2, nonzero: bool = False) -> np.ndarray:
        v = self.raw(key, default)
        ok = isinstance(v, list) and len(v) == size and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        if not ok:
            self.fail(key, f"expected a list of {size} numbers, got {v!r}")
        self.check(key, v, nonzero_vector=nonzero)
        return np.asarray(v, dtype=float)

    def check(self, key: str, value, **ranges) -> None:
        """Finite, of sane magnitude and in range (the checks the Python API makes too)."""
        problem = value_problem(value, **ranges)
        if problem is not None:
            self.fail(key, problem)

    def boolean(self, key: str, default: Any = ...) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            self.fail(key, f"expected true or false, got {v!r}")
        return v

    def mode(self, key: str = "mode", default: Any = ...) -> int:
        v = self.raw(key, default)
        if isinstance(v, bool) or not isinstance(v, (str, int)) or v not in MODES:
            self.fail(key, f"expected 'left'/'right' (or 'forward'/'backward', '+'/'-', 1/-1), got {v!r}")
        return MODES[v]

    def reject_unknown(self, allowed: set[str] | None = None):
        """Refuse the fields not in ``allowed`` (default: those read), with the known field each
        most likely misspells and the known fields."""
        extra = sorted(set(self.table) - (allowed if allowed is not None else self.used))
        if extra:
            known = sorted(allowed if allowed is not None else self.used | self.asked)
            raise SceneError(f"{self.source}: {self.where}: unknown field(s) {extra}{did_you_mean(extra, known)}; "
                             f"rename or remove {'it' if len(extra) == 1 else 'them'} (known fields: {', '.join(known)})")


def _points(fields: Fields, key: str) -> dict[str, np.ndarray]:
    where = f"[{key}]" if fields.where == "the top level" else f"{fields.where}.{key}"
    table = Fields(fields.raw(key), where, fields.source)
    _check_entries(table.table, where, fields.source)
    return {name: table.vector(name) for name in table.table}


TABLES = {"ground": "[ground]", "links": "[links]", "formation": "[[formation]]", "loads": "[[loads]]"}


def _check_sizes(data, source: str) -> None:
    """The scene's tables of many entries bounded before anything is read."""
    for key, where in TABLES.items():
        if isinstance(data, dict) and isinstance(data.get(key), (dict, list, tuple)):
            _check_entries(data[key], where, source)


def _check_entries(table, where: str, source: str) -> None:
    """A table or array of at most MAX_ENTRIES entries, checked before any is read."""
    if len(table) > MAX_ENTRIES:
        raise SceneError(f"{source}: {where} has {len(table)} entries; at most {MAX_ENTRIES}")


def _link(name: str, table, source: str) -> Link:
    f = Fields(table, f"[links.{name}]", source)
    points = _points(f, "points")
    if not points:
        f.fail("points", "a link needs at least one named point")
    centroid = np.mean(list(points.values()), axis=0)
    link = Link(
        points={k: jnp.asarray(v) for k, v in points.items()},
        com=jnp.asarray(f.vector("com", list(centroid))),
        mass=jnp.asarray(f.number("mass", 0.0, nonnegative=True)),
        inertia=jnp.asarray(f.number("inertia", 0.0, nonnegative=True)),
    )
    f.reject_unknown()
    return link


def _guide(f: Fields, prefix: str = "") -> dict:
    return dict(
        guide_point=f.string(prefix + "guide_point"),
        direction=jnp.asarray(f.vector(prefix + "direction", [1.0, 0.0], nonzero=True)),
        offset=jnp.asarray(f.number(prefix + "offset", 0.0)),
    )


def _crank(f, name):
    return _drivers.Crank(name, (f.string("link"),), f.string("pivot"))


def _slider(f, name):
    return _drivers.Slider(name, (f.string("link"),), f.string("point"), f.string("guide_point"), jnp.asarray(f.vector("direction", [1.0, 0.0], nonzero=True)))


def _rrr_group(f, name):
    return _rrr.RRR(name, f.names("links", 2), f.names("joints", 3), f.mode())


def _rrp_group(cls):
    def parse(f, name):
        g = _guide(f)
        return cls(name, f.names("links", 2), f.names("joints", 2), g["guide_point"], f.mode(), g["direction"], g["offset"])

    return parse


def _rpr_group(f, name):
    return _rpr.RPR(name, f.names("links", 2), f.names("joints", 2), f.mode(), jnp.asarray(f.vector("direction", [1.0, 0.0], nonzero=True)), jnp.asarray(f.number("offset", 0.0)))


def _prp_group(f, name):
    directions = f.raw("directions", [[1.0, 0.0], [0.0, 1.0]])
    if not (isinstance(directions, list) and len(directions) == 2 and all(_numbers(d, 2) for d in directions)):
        f.fail("directions", f"expected two 2-vectors, got {directions!r}")
    f.check("directions", directions, nonzero_vector=True)
    arr = np.asarray(directions, dtype=float)
    offsets = f.raw("offsets", [0.0, 0.0])
    if not _numbers(offsets, 2):
        f.fail("offsets", f"expected two numbers, got {offsets!r}")
    f.check("offsets", offsets)
    return _prp.PRP(name, f.names("links", 2), f.string("joint"), f.names("guide_points", 2), jnp.asarray(arr), jnp.asarray(offsets, dtype=float))


def _as_toml(value):
    """``value`` with what Python, NumPy and JAX write for TOML's numbers and lists made
    those (np.int64, np.float32, tuples, arrays); anything else as it is, for the checks to name."""
    if isinstance(value, dict):
        return {k: _as_toml(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_as_toml(v) for v in value]
    if hasattr(value, "shape") and hasattr(value, "dtype") and np.dtype(value.dtype).kind in "biuf":  # NumPy, JAX
        try:
            value = np.asarray(value)
        except Exception:  # a traced value: left for the checks to name
            return value
        return value.item() if value.ndim == 0 else [_as_toml(v) for v in value]
    return value


def _numbers(v, size: int) -> bool:
    return isinstance(v, list) and len(v) == size and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)


# kind -> parser(fields, group name) -> group. Other modules register their kinds here.
GROUP_PARSERS: dict[str, Callable] = {
    "crank": _crank,
    "slider": _slider,
    "RRR": _rrr_group,
    "RRP": _rrp_group(_rrp.RRP),
    "PRR": _rrp_group(_rrp.PRR),
    "RPR": _rpr_group,
    "PRP": _prp_group,
    "triad": _triad.parse_triad,
    "class4": _class4.parse_class4,
}

# Scene tables other modules parse: name -> parser(raw value, mechanism, source) -> parsed value.
LOAD_PARSER: list[Callable] = []


def _group(index: int, table, source: str):
    kind = table.get("group") if isinstance(table, dict) else None
    where = f"[[formation]] #{index + 1}"
    if not isinstance(kind, str) or kind not in GROUP_PARSERS:
        raise SceneError(f"{source}: {where}, field 'group': unknown group kind {kind!r} (known: {', '.join(GROUP_PARSERS)})")
    name = table.get("name", f"{kind}{index + 1}" if index else "driver")
    f = Fields(table, f"{where} ({kind} '{name}')", source)
    f.raw("group")
    f.string("name", name)
    group = GROUP_PARSERS[kind](f, name)
    f.reject_unknown()
    return group


def scene_from_dict(data: dict, *, source: str = "<scene>") -> Scene:
    """Build a Scene from the parsed TOML tables (see docs/scene-format.md); built in
    Python, NumPy numbers, tuples and arrays are taken as TOML's numbers and lists."""
    _check_sizes(data, source)
    top = Fields(_as_toml(data), "the top level", source)
    top.reject_unknown({"scene", "ground", "links", "formation", "state", "simulation", "outputs", "loads", "sketch"})
    head = Fields(top.raw("scene", {}), "[scene]", source)
    name = head.string("name", Path(source).stem)
    description = head.string("description", "")
    gravity = head.vector("gravity", [0.0, 0.0])
    head.reject_unknown()

    if top.has("sketch"):  # the sketch form (scene/_sketch.py): q0 defaults to the drawing's
        from ._sketch import mechanism_from_sketch

        mechanism, drawn_q0, notes = mechanism_from_sketch(top, name, source)
    else:
        mechanism, drawn_q0, notes = _explicit_mechanism(top, name, source), 0.0, ()

    state = Fields(top.raw("state", {}), "[state]", source)
    state_values = dict(
        q0=state.number("q0", drawn_q0), omega0=state.number("omega0", 0.0), t0=state.number("t0", 0.0), t1=state.number("t1", 1.0)
    )
    state.reject_unknown()
    if (problem := state_problem(**state_values)) is not None:
        state.fail(*problem)
    mechanism = _newton.resolve_guess_q(mechanism, state_values["q0"])  # iterative groups' guesses refer to q0
    simulation = Fields(top.raw("simulation", {}), "[simulation]", source)
    try:
        sim_values = check_simulation_table(simulation.table)
    except AssurjaxError as e:
        raise SceneError(f"{source}: {e}") from None
    outputs = Fields(top.raw("outputs", {}), "[outputs]", source)
    try:
        check_simulation_table(outputs.table, "[outputs]", OUTPUT_KEYS)
    except AssurjaxError as e:
        raise SceneError(f"{source}: {e}") from None
    out_values = _outputs(outputs, mechanism)

    loads = ()
    _check_load_types(top.raw("loads", []), source)
    for parse in LOAD_PARSER:
        loads = parse(top.raw("loads", []), mechanism, source)
    if top.has("loads") and not LOAD_PARSER:
        raise SceneError(f"{source}: [[loads]] are not supported by this installation")
    _check_one_friction_per_pair(loads, source)
    return Scene(
        mechanism=mechanism,
        gravity=jnp.asarray(gravity),
        loads=tuple(loads),
        state=Settings(state_values),
        simulation=Settings(sim_values),
        outputs=Settings(out_values),
        name=name,
        description=description,
        source=source,
        notes=notes,
    )


def _check_load_types(raw, source: str) -> None:
    """Each [[loads]] entry gives its type (else the parser read a missing one as the unknown
    type None)."""
    if not isinstance(raw, list):  # the parser says what it must be
        return
    for i, table in enumerate(raw):
        if isinstance(table, dict) and "type" not in table:
            Fields(table, f"[[loads]] #{i + 1}", source).raw("type")  # raises: missing field 'type'


def _check_one_friction_per_pair(loads, source: str) -> None:
    from .._friction import repeated_pair

    if (repeated := repeated_pair(loads)) is not None:
        first, second, problem = repeated
        raise SceneError(f"{source}: [[loads]] #{first + 1} and #{second + 1}: {problem}")


def _explicit_mechanism(top: Fields, name: str, source: str) -> Mechanism:
    """The mechanism of the explicit form: [ground], [links], [[formation]]."""
    ground = _points(top, "ground") if top.has("ground") else {}
    links_table = Fields(top.raw("links"), "[links]", source)
    if GROUND in links_table.table:
        links_table.fail(GROUND, "the name 'ground' is reserved; put fixed points in [ground]")
    links = {name_: _link(name_, t, source) for name_, t in links_table.table.items()}
    formation = top.raw("formation")
    if not isinstance(formation, list) or not formation:
        raise SceneError(f"{source}: [[formation]] must be a non-empty array of tables, the driver first")
    groups = [_group(i, t, source) for i, t in enumerate(formation)]
    try:
        return Mechanism(ground, links, groups, name=name)
    except MechanismError as e:
        raise SceneError(f"{source}: {e}") from None


def _outputs(f: Fields, mechanism: Mechanism) -> dict:
    points = f.names("points") if f.has("points") else ()
    known_points = set(mechanism.point_names)
    for p in points:
        if p not in known_points:
            f.fail("points", f"unknown point '{p}' (known: {few(sorted(known_points))})")
    angles = f.names("angles") if f.has("angles") else ()
    for a in angles:
        if a not in mechanism.links:
            f.fail("angles", f"unknown link '{a}' (known: {few(sorted(mechanism.links))})")
    reactions = f.names("reactions") if f.has("reactions") else ()
    if reactions:
        from .._kinetostatics import joint_names  # imported only when a scene asks for reactions

        known_joints = joint_names(mechanism)
        for j in reactions:
            if j not in known_joints:
                f.fail("reactions", f"unknown joint '{j}' (joints: {few(known_joints)})")
    coms = f.names("coms") if f.has("coms") else ()
    for link in coms:
        if link not in mechanism.links:
            f.fail("coms", f"unknown link '{link}' (known: {few(sorted(mechanism.links))})")
    values = dict(points=points, angles=angles, reactions=reactions, energies=f.boolean("energies", True))
    extra = {k: v for k, v in f.table.items() if k not in values}  # velocities, accelerations, coms: type-checked above
    return {**values, **extra}


# The [[loads]] tables (imported last: the parser uses Fields above).
from ._loads_table import parse_loads as _parse_loads  # noqa: E402

LOAD_PARSER.append(_parse_loads)
