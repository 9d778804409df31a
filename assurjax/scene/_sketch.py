"""The sketch form of a scene file: a ``[sketch]`` table instead of ``[ground]``,
``[links]`` and ``[[formation]]`` (see docs/sketch.md). Same vocabulary as
:class:`assurjax.structure.Sketch`::

    [sketch]
    driver = "crank"                 # the driving link (a crank or a slider)
    q0 = 0.3                         # optional: the driving coordinate of the drawing
    ground = ["O", "Z"]              # joints fixed to the frame
    joints = { O = [0, 0], M = [0.014, 0.004], ... }     # drawn global positions (m)
    [sketch.links]
    crank = ["O", "M"]               # a bar
    upper = { joints = ["Z", "P2", "P4"], density = 2.5 }   # a plate, kg/m^2
    [[sketch.slides]]
    link = "ram"
    on = "ground"
    direction = [1, 0]
"""

from __future__ import annotations

from .._errors import MechanismError, SceneError
from ..structure import Sketch, build

SKETCH_FIELDS = {"driver", "q0", "ground", "joints", "links", "slides"}
EXPLICIT_TABLES = ("ground", "links", "formation")


def mechanism_from_sketch(top, name: str, source: str):
    """(mechanism, drawn q0, the build's notes) from the ``[sketch]`` table of a scene (``top``: the
    top-level :class:`~assurjax.scene._load.Fields`)."""
    from ._load import Fields  # the loader imports this module

    both = [t for t in EXPLICIT_TABLES if top.has(t)]
    if both:
        raise SceneError(f"{source}: a scene has either a [sketch] or the explicit {['[ground]', '[links]', '[[formation]]']}, not both (found {both})")
    f = Fields(top.raw("sketch"), "[sketch]", source)
    f.reject_unknown(SKETCH_FIELDS)
    joints_table = Fields(f.raw("joints"), "[sketch.joints]", source)
    joints = {j: joints_table.vector(j) for j in joints_table.table}
    links = Fields(f.raw("links"), "[sketch.links]", source).table
    for link, value in links.items():
        if not isinstance(value, (list, dict)):
            raise SceneError(f"{source}: [sketch.links], link '{link}': expected a list of joint names or a table with 'joints', got {value!r}")
    slides = f.raw("slides", [])
    if not isinstance(slides, list) or not all(isinstance(s, dict) for s in slides):
        f.fail("slides", f"expected an array of tables [[sketch.slides]] with link, on, direction, got {slides!r}")
    ground = f.names("ground") if f.has("ground") else ()
    q0 = f.number("q0") if f.has("q0") else None
    try:
        sketch = Sketch(joints, links, ground=ground, slides=slides, driver=f.string("driver"), q0=q0, name=name)
        built = build(sketch)
    except MechanismError as e:
        raise SceneError(f"{source}: [sketch]: {e}") from None
    return built.mechanism, built.q0, built.notes
