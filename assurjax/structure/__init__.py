"""Structure: mechanisms from a designer's sketch.

Joints where they are drawn, links as lists of joints, ground joints, sliding pairs
and the driver (:class:`Sketch`); Gruebler's count and the Assur decomposition into
the package's group kinds (:func:`decompose`); the explicit mechanism whose
assembly modes and starting guesses reproduce the drawing (:func:`build`); assembly
diagnostics over a sweep (:func:`assembly_report`); and the way back, from any
mechanism to a sketch (:func:`sketch_of`) and to the explicit scene form
(:func:`explicit_toml`). See docs/sketch.md.
"""

from ._build import Built as Built, build as build, check_drawing as check_drawing, to_scene as to_scene
from ._decompose import Decomposition as Decomposition, GroupPlan as GroupPlan, decompose as decompose, gruebler as gruebler
from ._sketch import LinkSpec as LinkSpec, Sketch as Sketch, Slide as Slide
from ._export import explicit_toml as explicit_toml, sketch_of as sketch_of
from ._diagnostics import AssemblyReport as AssemblyReport, GroupFailure as GroupFailure, assembly_report as assembly_report
