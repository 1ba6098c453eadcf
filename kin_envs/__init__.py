"""kin-envs: a fast 2D multi-robot lidar world for kin detection research.

``import kin_envs`` is light: it never imports torch or pygame. It registers the Gymnasium ids
(``kin_envs/KinSeek-v2``, ``kin_envs/KinFollow-v2``, and their v1 and v0) with string entry points and
exposes the PettingZoo swarm as ``kin_envs.aggregation_v2`` (and ``aggregation_v1``, ``aggregation_v0``).

The library reports through the ``kin_envs`` logger (``logging``; silent unless the application
configures logging). It first checks that the top-level packages ``detectors`` and ``agents`` are
kin-envs' own (:mod:`kin_envs._toplevel`: unrelated distributions of the same names exist).
"""

import logging

__kin_envs_package__ = True

from kin_envs._toplevel import check_all as _check_toplevel  # noqa: E402

_check_toplevel()  # before anything imports detectors: a foreign one would fail later, confusingly

from pathlib import Path as _Path  # noqa: E402

import detectors as _detectors  # noqa: E402
from detectors._numba_cache import guard_dependencies as _guard  # noqa: E402

# before any kin_envs kernel is decorated: its numba cache goes stale when a jitted source changes
_guard(_Path(__file__).resolve().parent, also=[_Path(_detectors.__file__).resolve().parent])
logging.getLogger(__name__).addHandler(logging.NullHandler())

from kin_envs import aggregation_v0, aggregation_v1, aggregation_v2, scenes  # noqa: E402
from kin_envs.core.lidar import HitKind, LidarSpec  # noqa: E402
from kin_envs.core.scenes import RobotSpec, Scene  # noqa: E402
from kin_envs.core.world import Contact, Scan, World, WorldConfig  # noqa: E402
from kin_envs.envs import register_envs as _register_envs  # noqa: E402
from kin_envs.envs.recording import record_episode  # noqa: E402

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
    "aggregation_v2",
    "record_episode",
    "scenes",
]
