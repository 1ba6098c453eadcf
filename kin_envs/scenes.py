"""Public alias of :mod:`kin_envs.core.scenes` (``from kin_envs import scenes``)."""

from kin_envs.core.scenes import *  # noqa: F403
from kin_envs.core.scenes import (  # noqa: F401
    PAPER_DISTANCES,
    SCENARIO_I_LAYOUT,
    SCENARIO_II_LAYOUT,
    __all__,  # noqa: F401
    obstacle_from_dict,
)
