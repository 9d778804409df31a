"""assurjax: differentiable dynamics of planar one-degree-of-freedom linkages built from Assur groups.

float64 is switched on when the package is imported (accuracy first). To work in
float32, set the environment variable ``ASSURJAX_FLOAT32=1`` before importing, or
call ``jax.config.update("jax_enable_x64", False)`` after importing.
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
from .groups import Link as Link
from .scene._load import bundled_scenes as bundled_scenes, load_scene as load_scene, scene_from_dict as scene_from_dict
from .scene._scene import Scene as Scene

__version__ = "0.1.0"
