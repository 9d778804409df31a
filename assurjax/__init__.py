"""assurjax: differentiable dynamics of planar one-degree-of-freedom linkages built from Assur groups.

float64 is switched on when the package is imported (accuracy first). To work in
float32, set the environment variable ``ASSURJAX_FLOAT32=1`` before importing, or
call ``jax.config.update("jax_enable_x64", False)`` after importing. Positions are
then accurate to about 1e-6 of the mechanism's size (the Roberts linkage: < 1e-6 m).
"""

import os as _os

import jax as _jax

if _os.environ.get("ASSURJAX_FLOAT32", "") not in ("1", "true", "yes"):
    _jax.config.update("jax_enable_x64", True)

from . import groups as groups
from ._errors import (
    AssemblyError as AssemblyError,
    AssurjaxError as AssurjaxError,
    MechanismError as MechanismError,
    SceneError as SceneError,
)
from ._kinematics import (
    Kinematics as Kinematics,
    inverse_kinematics as inverse_kinematics,
    kinematics as kinematics,
    pose_at as pose_at,
)
from ._mechanism import Mechanism as Mechanism, Pose as Pose, positions as positions
from ._examples import n_four_bar as n_four_bar, strandbeest as strandbeest
from ._tracking import branch_angles as branch_angles, positions_tracked as positions_tracked
from ._reduction import Reduction as Reduction, reduce as reduce
from ._kinetostatics import (
    Reactions as Reactions,
    breakaway_band as breakaway_band,
    inverse_dynamics as inverse_dynamics,
    SingularConfigurationError as SingularConfigurationError,
    joint_names as joint_names,
    reactions as reactions,
    static_reactions as static_reactions,
    static_torque as static_torque,
)
from ._model import Model as Model
from ._friction import JointFriction as JointFriction, SlideFriction as SlideFriction
from ._kinematics import Coefficients as Coefficients, bridged_coefficients as bridged_coefficients, coefficients as coefficients
from .dynamics import (
    RESULTS as RESULTS,
    ReducedTable as ReducedTable,
    SeedEulerSolution as SeedEulerSolution,
    Settings as SimulationSettings,
    Solution as Solution,
    build_table as build_table,
    build_table_core as build_table_core,
    settings_from as settings_from,
    simulate as simulate,
    simulate_core as simulate_core,
    simulate_seed_euler as simulate_seed_euler,
)
from ._cache import enable_compilation_cache as enable_compilation_cache
from ._jit import enable_fast_loops as enable_fast_loops
from ._jit import jit as jit
from ._loads import (
    AbstractLoad as AbstractLoad,
    Couple as Couple,
    Damper as Damper,
    Drive as Drive,
    MotorLine as MotorLine,
    PointForce as PointForce,
    Polynomial as Polynomial,
    RotaryDamper as RotaryDamper,
    Spring as Spring,
    Table as Table,
    Vector as Vector,
    applied_wrenches as applied_wrenches,
    dissipated_power as dissipated_power,
    driver_effort as driver_effort,
    potential_energy as potential_energy,
)
from .groups import Link as Link
from .scene._load import bundled_scenes as bundled_scenes, load_scene as load_scene, scene_from_dict as scene_from_dict
from .scene._scene import Scene as Scene
from ._sweep import (
    batch_kinematics as batch_kinematics,
    batch_mesh as batch_mesh,
    batch_simulate as batch_simulate,
    perturb as perturb,
    shard_batch as shard_batch,
    stack_mechanisms as stack_mechanisms,
    sweep as sweep,
)
from . import structure as structure
from .structure import Sketch as Sketch, Slide as Slide

# the public names (the lazily imported submodules synthesis and viz among them)
__all__ = [
    "AbstractLoad", "applied_wrenches", "AssemblyError", "AssurjaxError", "batch_kinematics", "batch_mesh",
    "batch_simulate", "branch_angles", "breakaway_band", "bridged_coefficients", "build_table",
    "build_table_core", "bundled_scenes", "Coefficients", "coefficients", "Couple", "Damper",
    "dissipated_power", "Drive", "driver_effort", "enable_compilation_cache", "enable_fast_loops", "groups",
    "inverse_dynamics", "inverse_kinematics", "jit", "joint_names", "JointFriction", "Kinematics",
    "kinematics", "Link", "load_scene", "Mechanism", "MechanismError", "Model", "MotorLine", "n_four_bar",
    "perturb", "PointForce", "Polynomial", "Pose", "pose_at", "positions", "positions_tracked",
    "potential_energy", "reactions", "Reactions", "reduce", "ReducedTable", "Reduction", "RESULTS",
    "RotaryDamper", "Scene", "scene_from_dict", "SceneError", "SeedEulerSolution", "settings_from",
    "shard_batch", "simulate", "simulate_core", "simulate_seed_euler", "SimulationSettings",
    "SingularConfigurationError", "Sketch", "Slide", "SlideFriction", "Solution", "Spring",
    "stack_mechanisms", "static_reactions", "static_torque", "strandbeest", "structure", "sweep",
    "synthesis", "Table", "Vector", "viz",
]

__version__ = "0.1.0"

_LAZY_SUBMODULES = ("synthesis", "viz")  # optax and matplotlib load on first use, not with the package


def __getattr__(name: str):
    """``assurjax.synthesis`` and ``assurjax.viz`` are imported on first access."""
    if name in _LAZY_SUBMODULES:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY_SUBMODULES))
