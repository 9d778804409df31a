"""The way back: any mechanism as a sketch (its joints at one driving coordinate), and
any scene in the explicit TOML form (``[ground]``, ``[links]``, ``[[formation]]``)."""

from __future__ import annotations

import math
import re

import numpy as np

from .._errors import AssurjaxError
from .._mechanism import Mechanism, positions
from ..groups import GROUND
from ._sketch import Sketch, Slide


def _rotate(v, angle: float) -> tuple[float, float]:
    c, s = math.cos(angle), math.sin(angle)
    return (float(c * v[0] - s * v[1]), float(s * v[0] + c * v[1]))


def _slides(mech: Mechanism, angles: dict) -> list[Slide]:
    """The prismatic pairs of the formation, with their global directions at the pose."""
    owner = dict(mech.owner)

    def along(guide_point: str, direction) -> tuple[str, tuple]:
        guide = owner[guide_point]
        return guide, _rotate(np.asarray(direction), 0.0 if guide == GROUND else angles[guide])

    out = []
    for g in mech.groups:
        if g.kind == "slider":
            out.append(Slide(g.links[0], GROUND, _rotate(np.asarray(g.direction), 0.0)))
        elif g.kind in ("RRP", "PRR"):
            slider = g.links[1] if g.kind == "RRP" else g.links[0]
            out.append(Slide(slider, *along(g.guide_point, g.direction)))
        elif g.kind == "RPR":
            out.append(Slide(g.links[0], g.links[1], _rotate(np.asarray(g.direction), angles[g.links[1]])))
        elif g.kind == "PRP":
            out += [Slide(g.links[k], *along(g.guide_points[k], g.directions[k])) for k in range(2)]
    return out


def sketch_of(mechanism: Mechanism, q: float, *, name: str | None = None) -> Sketch:
    """The sketch of a mechanism drawn at the driving coordinate ``q`` (rad or m): every
    point where the position analysis puts it, the links as lists of their points, the
    prismatic pairs along their directions at that pose, masses, inertias and centres
    of mass as given. Its :meth:`~Sketch.mechanism` has the same kinds of groups and
    the same motion (the assembly modes are those of ``mechanism`` at ``q``).

    Example: ``sketch_of(load_scene("watt_sixbar").mechanism, 0.0)``."""
    pose = positions(mechanism, q)
    if not bool(np.all(np.asarray(pose.ok))):
        bad = [g.name for g, ok in zip(mechanism.groups, np.asarray(pose.ok)) if not ok]
        raise AssurjaxError(f"cannot draw '{mechanism.name}' at q = {float(q):.6g}: group(s) {bad} do not assemble there")
    joints = {p: np.asarray(x, dtype=float) for p, x in pose.points.items()}
    angles = {k: float(a) for k, a in pose.angles.items()}
    links = {}
    for link_name, link in mechanism.links.items():
        links[link_name] = {"joints": list(link.points), "mass": float(link.mass), "inertia": float(link.inertia),
                            "com": np.asarray(pose.coms[link_name], dtype=float)}
    return Sketch(joints, links, ground=list(mechanism.ground), slides=_slides(mechanism, angles),
                  driver=mechanism.driver.links[0], q0=float(q), name=name or mechanism.name)


# -- the explicit TOML form --------------------------------------------------------------


def _key(name: str) -> str:
    return name if re.fullmatch(r"[A-Za-z0-9_-]+", name) else '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)) or (isinstance(v, np.ndarray) and v.ndim > 0):
        return "[" + ", ".join(_value(x) for x in list(v)) + "]"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    x = float(v)
    return repr(x) if math.isfinite(x) else ("nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))


def _group_table(g) -> dict:
    """One ``[[formation]]`` table (the fields the scene parser reads)."""
    t = {"group": g.kind, "name": g.name}
    arr = lambda x: np.asarray(x, dtype=float).tolist()  # noqa: E731
    if g.kind == "crank":
        return t | {"link": g.links[0], "pivot": g.pivot}
    if g.kind == "slider":
        return t | {"link": g.links[0], "point": g.point, "guide_point": g.guide_point, "direction": arr(g.direction)}
    t |= {"links": list(g.links)}
    if g.kind in ("RRR", "RRP", "PRR", "RPR"):
        names = ("left", "right") if g.kind == "RRR" else ("forward", "backward")
        t |= {"joints": list(g.joints), "mode": names[0] if g.mode == 1 else names[1]}
        if g.kind != "RRR":
            t |= ({"guide_point": g.guide_point} if g.kind != "RPR" else {}) | {"direction": arr(g.direction), "offset": float(g.offset)}
        return t
    if g.kind == "PRP":
        return t | {"joint": g.joint, "guide_points": list(g.guide_points), "directions": arr(g.directions), "offsets": arr(g.offsets)}
    t |= {"joints": list(g.joints), "guess": {p: arr(x) for p, x in g.guess.items()}}
    if g.guess_q is not None:
        t["guess_q"] = float(g.guess_q)
    return t | {"substeps": g.substeps, "max_steps": g.max_steps}


def explicit_toml(scene) -> str:
    """A scene (or a bare mechanism) written in the explicit scene form, e.g. a scene built
    from a sketch: ``load_scene`` of the text gives back the same mechanism (every
    number is written with all its digits). Loads are not written (an error if any)."""
    from ..scene._scene import Scene

    if isinstance(scene, Mechanism):
        mech, head, sections = scene, {"name": scene.name}, {}
    elif isinstance(scene, Scene):
        if scene.loads:
            raise AssurjaxError(f"scene '{scene.name}': its loads cannot be written in the explicit form yet; write them by hand")
        mech = scene.mechanism
        head = {"name": scene.name, "description": scene.description, "gravity": np.asarray(scene.gravity).tolist()}
        sections = {"state": dict(scene.state), "simulation": dict(scene.simulation), "outputs": dict(scene.outputs)}
    else:
        raise AssurjaxError(f"explicit_toml takes a Scene or a Mechanism, got {type(scene).__name__}")
    lines = ["[scene]"] + [f"{k} = {_value(v)}" for k, v in head.items()]
    lines += ["", "[ground]"] + [f"{_key(p)} = {_value(np.asarray(x))}" for p, x in mech.ground.items()]
    order = {p: i for i, (p, _) in enumerate(mech.owner)}
    owner = dict(mech.owner)
    for name, link in mech.links.items():
        # points in the order that gives back the same owners (jax sorts dict keys)
        pts = sorted(link.points, key=lambda p: order[p] if owner[p] == name else -1)
        lines += ["", f"[links.{_key(name)}]", f"points = {_value({p: np.asarray(link.points[p]) for p in pts})}",
                  f"com = {_value(np.asarray(link.com))}", f"mass = {_value(link.mass)}", f"inertia = {_value(link.inertia)}"]
    for g in mech.groups:
        lines += ["", "[[formation]]"] + [f"{k} = {_value(v)}" for k, v in _group_table(g).items()]
    for section, values in sections.items():
        values = {k: v for k, v in values.items() if not (isinstance(v, (tuple, list)) and not v and section == "outputs")}
        if values:
            lines += ["", f"[{section}]"] + [f"{_key(k)} = {_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"
