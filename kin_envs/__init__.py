"""kin-envs: a fast 2D multi-robot lidar world for kin detection research.

``import kin_envs`` is light: it never imports torch or pygame. It registers the Gymnasium ids
(``kin_envs/KinSeek-v1``, ``kin_envs/KinFollow-v1``, and their v0) with string entry points and
exposes the PettingZoo swarm as ``kin_envs.aggregation_v1`` (and ``aggregation_v0``).
"""

from kin_envs import aggregation_v0, aggregation_v1, scenes
from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.core.scenes import RobotSpec, Scene
from kin_envs.core.world import Contact, Scan, World, WorldConfig
from kin_envs.envs import register_envs as _register_envs

_register_envs()

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
    "aggregation_v0",
    "aggregation_v1",
    "scenes",
]
