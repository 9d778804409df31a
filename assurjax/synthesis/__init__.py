"""Differentiable design: sensitivities, bounded design parametrizations and optax synthesis loops.

**Example** (straight-line synthesis, seed 001):

>>> import optax, assurjax
>>> from assurjax import synthesis as syn
>>> mech = syn.roberts_like(syn.roberts_lengths() * 1.05)
>>> design = syn.Design(mech, lambda m: (m.ground["D"], m.links["link4"].points["P"]), absolute=0.03)
>>> def objective(m):
...     line = syn.straight_line_deviation(m, "P", stroke=0.26, q0=1.23)
...     return line.smooth, {"ok": line.ok, "deviation": line.deviation}
>>> result = syn.optimize(design, objective, optax.adam(1e-2), 200, has_aux=True)
>>> result.status, result.history.loss[-1]
"""

from ._design import Design as Design
from ._linkages import (
    four_bar as four_bar,
    roberts_lengths as roberts_lengths,
    roberts_like as roberts_like,
    triangle_point as triangle_point,
)
from ._objectives import (
    StraightLine as StraightLine,
    assembly_margin as assembly_margin,
    coupler_curve as coupler_curve,
    driving_torque as driving_torque,
    precision_point_error as precision_point_error,
    smooth_max as smooth_max,
    straight_line_deviation as straight_line_deviation,
    transmission_angles as transmission_angles,
)
from ._optimize import History as History, SynthesisResult as SynthesisResult, assembles as assembles, optimize as optimize
from ._parameters import (
    flatten_parameters as flatten_parameters,
    gradient as gradient,
    jacobian as jacobian,
    parameter_names as parameter_names,
)
