"""The simulator core: scenes, world, lidar. Knows nothing about Gymnasium, PettingZoo, pygame or torch."""

from kin_envs.core import scenes
from kin_envs.core.lidar import HitKind, LidarSpec, cast_scan, scan_shapes
from kin_envs.core.scenes import RobotSpec, Scene
from kin_envs.core.world import Contact, Scan, World, WorldConfig

__all__ = [
    "Contact",
    "HitKind",
    "LidarSpec",
    "RobotSpec",
    "Scan",
    "Scene",
    "World",
    "WorldConfig",
    "cast_scan",
    "scan_shapes",
    "scenes",
]
