"""Wander: drive on with a slowly drifting turn, turn away from anything close ahead (scan only)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from agents.base import Policy, SeedLike, check_action_type, env_layout, make_rng, steer_to_action
from kin_envs.envs.common import ObservationLayout

__all__ = ["Wanderer"]

_FRONT = math.radians(35.0)


class Wanderer(Policy):
    """Obstacle-avoiding random walk using only the newest scan in the observation.

    Args:
        layout: the env's observation layout (``env.unwrapped.layout``).
        action_type: ``"continuous"`` or ``"discrete"``.
        clearance: turn away when anything is this close within ±35° of the heading, m.
        speed: forward speed as a fraction of the top speed.
        seed: seed of the drift noise.
    """

    name: ClassVar[str] = "wander"

    def __init__(
        self,
        layout: ObservationLayout,
        action_type: str = "continuous",
        clearance: float = 0.35,
        speed: float = 1.0,
        seed: SeedLike = None,
    ) -> None:
        if not isinstance(layout, ObservationLayout):
            raise ValueError(f"{type(self).__name__}: layout must be an ObservationLayout, got {layout!r}")
        self.layout = layout
        self.action_type = check_action_type(action_type, type(self).__name__)
        if not (0.0 < clearance < layout.range_max):
            raise ValueError(f"{type(self).__name__}: clearance must be in (0, {layout.range_max}) m, "
                             f"got {clearance!r}")
        if not (0.0 < speed <= 1.0):
            raise ValueError(f"{type(self).__name__}: speed must be in (0, 1], got {speed!r}")
        self.clearance = clearance
        self.speed = speed
        self.reset(seed)

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any):
        layout, action_type = env_layout(env)
        return cls(layout, action_type, **kwargs)

    def reset(self, seed: SeedLike = None) -> None:
        self.rng = make_rng(seed, type(self).__name__)
        self._drift = 0.0
        self._avoid = 0.0  # committed avoidance direction (+1 left, -1 right), 0 = none

    def act(self, obs, info):
        return steer_to_action(*self.wander(self.layout.newest_scan(obs)), self.action_type)

    def wander(self, ranges: np.ndarray) -> tuple[float, float]:
        """``(v, w)`` normalised forward speed and turn from the ranges in metres."""
        angles = self.layout.angles
        if ranges[np.abs(angles) < _FRONT].min() < self.clearance:
            # commit to one side until the way is clear: re-deciding every step dithers in corners
            if self._avoid == 0.0:
                left = ranges[(angles > 0.3) & (angles < 1.9)].mean()
                right = ranges[(angles < -0.3) & (angles > -1.9)].mean()
                self._avoid = 1.0 if left >= right else -1.0
            return 0.0, 0.6 * self._avoid
        self._avoid = 0.0
        self._drift = float(np.clip(0.9 * self._drift + self.rng.normal(0.0, 0.1), -0.4, 0.4))
        return self.speed, self._drift
