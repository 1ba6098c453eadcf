"""Swarm aggregator: drive to the nearest detected robot, wander when none is detected."""

from __future__ import annotations

from typing import ClassVar

from agents.base import SeedLike
from agents.seeker import KinSeeker
from kin_envs.envs.common import ObservationLayout

__all__ = ["Aggregator"]


class Aggregator(KinSeeker):
    """A per-robot aggregation controller for ``aggregation_v2`` (one instance per agent).

    It is the kin-seeker steering to the *nearest* detection and stopping ``stop_distance`` from it
    (inside the env's 0.6 m ``kin_radius``, but clear of contact, which the env penalises).
    Robots that stopped next to each other become targets for the others, so pairs grow into
    clusters. Needs the env's detector (``info["kin_detections"]`` or ``obs_detections="topk"``).
    """

    name: ClassVar[str] = "aggregator"

    def __init__(
        self,
        layout: ObservationLayout,
        action_type: str = "continuous",
        stop_distance: float = 0.35,
        clearance: float = 0.3,
        memory: int = 5,
        seed: SeedLike = None,
    ) -> None:
        super().__init__(layout, action_type, stop_distance=stop_distance, clearance=clearance,
                         memory=memory, select="nearest", seed=seed)
