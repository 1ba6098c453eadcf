"""kin-envs: a fast 2D multi-robot lidar world for kin detection research.

``import kin_envs`` is light: it never imports torch or pygame.
"""

from kin_envs import scenes
from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.core.scenes import RobotSpec, Scene
from kin_envs.core.world import Contact, Scan, World, WorldConfig

__version__ = "0.1.0"
__all__ = [
    "Contact",
    "HitKind",
    "LidarSpec",
    "RobotSpec",
    "Scan",
    "Scene",
    "World",
    "WorldConfig",
    "scenes",
]
