"""Differentiable design: sensitivities, bounded design parametrizations and optax synthesis loops.

:func:`optimize` runs any optax method (L-BFGS and other line searches included) in one
compiled program, with continuation stages, restarts and multi-start; it compiles once per
problem structure (new start values, bounds, options and schedule values reuse the program).

**Example** (straight-line synthesis, Fanghella et al. 2019, by the driving dimension x_P):

>>> import jax.numpy as jnp, optax, assurjax
>>> from assurjax import synthesis as syn
>>> lengths = syn.roberts_lengths() * jnp.array([1.05, 0.95, 1.08, 0.93, 1.02, 0.97])
>>> design, objective = syn.straight_line_problem(lengths)   # lengths + stroke centre, bounded
>>> result = syn.optimize(design, objective, optax.lbfgs, 80, has_aux=True, rtol=1e-6, restarts=2,
...                       schedule={"sharpness": [100.0, 1000.0, 1e4]})
>>> result.history.aux["deviation"].min()   # m, well below the Roberts linkage's 0.67 mm
"""

from ._design import Design as Design
from ._sensitivity import (
    SensitivityOptions as SensitivityOptions,
    final_state_sensitivity as final_state_sensitivity,
    standstill_time_sensitivity as standstill_time_sensitivity,
)
from ._dynamic import final_state as final_state, standstill_time as standstill_time
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
from ._problems import (
    ROBERTS_Q0 as ROBERTS_Q0,
    StandstillObjective as StandstillObjective,
    StraightLineObjective as StraightLineObjective,
    add_point_mass as add_point_mass,
    standstill_time_problem as standstill_time_problem,
    straight_line_problem as straight_line_problem,
)
from ._optimize import (
    History as History,
    StartResults as StartResults,
    SynthesisResult as SynthesisResult,
    assembles as assembles,
    optimize as optimize,
)
from ._parameters import (
    flatten_parameters as flatten_parameters,
    gradient as gradient,
    jacobian as jacobian,
    parameter_names as parameter_names,
)
