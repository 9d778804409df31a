"""Kinetostatics: joint reactions and the driving effort, group by group in reverse
formation order (Durango et al. 2014 section 3.3; class-IV group with special Assur points, Calle et al. 2014)."""

from ._api import (
    Reactions as Reactions,
    breakaway_band as breakaway_band,
    inverse_dynamics as inverse_dynamics,
    SingularConfigurationError as SingularConfigurationError,
    reactions as reactions,
    static_reactions as static_reactions,
    static_torque as static_torque,
)
from ._layout import Pair as Pair, joint_names as joint_names
