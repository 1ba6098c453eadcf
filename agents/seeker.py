"""Kin-seeker: steer to a detected kin (the env's detector channel), wander otherwise, stop when close.

Detections come from ``info["kin_detections"]`` (the env's detector, any observation mode) or,
when the info lacks them, from the observation's ``"topk"`` detector channel. The scan in the
observation drives the obstacle avoidance while wandering. No privileged state is used.

Example::

    env = gymnasium.make("kin_envs/KinSeek-v2")
    policy = KinSeeker.for_env(env, seed=0)
    obs, info = env.reset(seed=0)
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
        if terminated or truncated:
            break
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from agents.base import SeedLike, steer_to_action
from agents.wander import Wanderer
from kin_envs.envs import unpad_detections
from kin_envs.envs.common import ObservationLayout

__all__ = ["KinSeeker", "detections_from", "SELECT_MODES"]

SELECT_MODES = ("score", "nearest")


def detections_from(layout: ObservationLayout, obs, info) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(range, bearing, score)`` arrays of this step's detections, nearest first, or ``None`` when
    neither the info nor the observation carries any (the env has no detector channel).
    ``score`` is NaN when read from the observation (the ``"topk"`` slots hold no score)."""
    dets = unpad_detections(info) if info else None  # padded (v1) or variable-length (v0)
    if dets is not None:
        return dets["range"], dets["bearing"], dets["score"]
    if layout.detections != "topk":
        return None
    start = (layout.frame_stack - 1) * layout.frame_dim + layout.n_beams
    slots = np.asarray(obs, dtype=np.float64)[start : start + 4 * layout.top_k].reshape(layout.top_k, 4)
    slots = slots[slots[:, 0] > 0.5]
    return (slots[:, 1] * layout.range_max, np.arctan2(slots[:, 2], slots[:, 3]),
            np.full(len(slots), np.nan))


class KinSeeker(Wanderer):
    """A reactive kin-seeking policy (the scripted KinSeek baseline).

    Args:
        layout: the env's observation layout (``env.unwrapped.layout``).
        action_type: ``"continuous"`` (normalised wheel speeds) or ``"discrete"``.
        stop_distance: stop when the detected kin's centre is this close, m.
        clearance: turn away when anything is this close within ±35° of the heading, m (wandering).
        memory: steps to keep steering toward a kin after it was last detected.
        select: which detection to steer to: ``"score"`` the highest ``Detection.score`` (most
            kin-like; for the geometric detector the most circle-like: look-alike prisms and boxes
            fit a circle worse than a real housing) or ``"nearest"``.
        seed: seed of the wandering noise.
    """

    name: ClassVar[str] = "seeker"

    def __init__(
        self,
        layout: ObservationLayout,
        action_type: str = "continuous",
        stop_distance: float = 0.25,
        clearance: float = 0.35,
        memory: int = 5,
        select: str = "score",
        seed: SeedLike = None,
    ) -> None:
        who = type(self).__name__
        if not (isinstance(stop_distance, int | float) and 0.0 <= stop_distance < layout.range_max):
            raise ValueError(
                f"{who}: stop_distance must be in [0, {layout.range_max}) m, got {stop_distance!r}"
            )
        if not (isinstance(memory, int) and memory >= 0):
            raise ValueError(f"{who}: memory must be an integer >= 0, got {memory!r}")
        if select not in SELECT_MODES:
            raise ValueError(f"{who}: select must be one of {SELECT_MODES}, got {select!r}")
        self.stop_distance = stop_distance
        self.memory = memory
        self.select = select
        super().__init__(layout, action_type, clearance=clearance, seed=seed)

    def reset(self, seed: SeedLike = None) -> None:
        super().reset(seed)
        self._target: tuple[float, float] | None = None
        self._age = 0

    def act(self, obs, info):
        """Action for one step from the observation and the step's info dict."""
        found = detections_from(self.layout, obs, info)
        if found is None:
            raise ValueError(
                f"{type(self).__name__} needs info['kin_detections'] (or a 'topk' detector channel "
                "in the observation): make the env with a detector (detector='geometric')"
            )
        rng_, bearing, score = found
        if len(rng_):
            j = 0 if self.select == "nearest" or np.isnan(score).any() else int(np.argmax(score))
            self._target, self._age = (float(rng_[j]), float(bearing[j])), 0
        elif self._target is not None:
            self._age += 1
            if self._age > self.memory:
                self._target = None
        if self._target is not None:
            v, w = self.seek(*self._target)
        else:
            v, w = self.wander(self.layout.newest_scan(obs))
        return steer_to_action(v, w, self.action_type)

    def seek(self, r: float, bearing: float) -> tuple[float, float]:
        """Turn toward the target, drive when roughly facing it, slowing down near it."""
        if r <= self.stop_distance:
            return 0.0, 0.0
        w = float(np.clip(1.5 * bearing, -1.0, 1.0))
        v = 0.0 if abs(bearing) > 0.5 else math.cos(bearing) * min(1.0, r / 0.5)
        return v, w
