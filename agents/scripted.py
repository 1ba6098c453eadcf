"""Scripted KinSeek baseline: steer to the nearest detected kin, wander otherwise, stop when close.

It reads the newest scan from the observation (for obstacle avoidance) and the detections from
``info["kin_detections"]`` (the env's detector), so the env needs a detector (the default
``"geometric"``). It uses no privileged state.

Example::

    env = gymnasium.make("kin_envs/KinSeek-v0")
    policy = ScriptedKinSeeker.for_env(env, seed=0)
    obs, info = env.reset(seed=0)
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
        if terminated or truncated:
            break
"""

from __future__ import annotations

import math

import numpy as np

from kin_envs.envs.common import DISCRETE_ACTION_NAMES, ObservationLayout

__all__ = ["ScriptedKinSeeker"]

_FRONT = math.radians(35.0)
_ACTION = {name: i for i, name in enumerate(DISCRETE_ACTION_NAMES)}


class ScriptedKinSeeker:
    """A reactive KinSeek policy.

    Args:
        layout: the env's observation layout (``env.unwrapped.layout``).
        action_type: ``"continuous"`` (normalised wheel speeds) or ``"discrete"``.
        stop_distance: stop when the detected kin's centre is this close, m.
        clearance: turn away when anything is this close within ±35° of the heading, m.
        memory: steps to keep steering toward a kin after it was last detected.
        seed: seed of the wandering noise.
    """

    def __init__(
        self,
        layout: ObservationLayout,
        action_type: str = "continuous",
        stop_distance: float = 0.25,
        clearance: float = 0.35,
        memory: int = 5,
        seed: int | None = None,
    ) -> None:
        if action_type not in ("continuous", "discrete"):
            raise ValueError(f"ScriptedKinSeeker: unknown action_type {action_type!r}")
        self.layout = layout
        self.action_type = action_type
        self.stop_distance = stop_distance
        self.clearance = clearance
        self.memory = memory
        self.reset(seed)

    @classmethod
    def for_env(cls, env, **kwargs) -> ScriptedKinSeeker:
        u = env.unwrapped
        return cls(u.layout, u.config.action_type, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)
        self._drift = 0.0
        self._avoid = 0.0  # committed avoidance direction (+1 left, -1 right), 0 = none
        self._target: tuple[float, float] | None = None
        self._age = 0

    def act(self, obs, info) -> np.ndarray | int:
        """Action for one step from the observation and the step's info dict."""
        if "kin_detections" not in info:
            raise ValueError("ScriptedKinSeeker needs info['kin_detections']: make the env "
                             "with a detector (detector='geometric')")
        dets = info["kin_detections"]
        if len(dets["range"]):
            # the most circle-like detection (lowest shape error): look-alike prisms and boxes
            # that pass the detector's threshold still fit a circle worse than a real housing
            j = int(np.argmin(dets["score"]))
            self._target, self._age = (float(dets["range"][j]), float(dets["bearing"][j])), 0
        elif self._target is not None:
            self._age += 1
            if self._age > self.memory:
                self._target = None
        ranges = self.layout.newest_scan(obs)
        if self._target is not None:
            v, w = self._seek(*self._target)
        else:
            v, w = self._wander(ranges, self.layout.angles)
        return self._to_action(v, w)

    __call__ = act

    def _seek(self, r: float, bearing: float) -> tuple[float, float]:
        if r <= self.stop_distance:
            return 0.0, 0.0
        w = float(np.clip(1.5 * bearing, -1.0, 1.0))
        v = 0.0 if abs(bearing) > 0.5 else math.cos(bearing) * min(1.0, r / 0.5)
        return v, w

    def _wander(self, ranges: np.ndarray, angles: np.ndarray) -> tuple[float, float]:
        if ranges[np.abs(angles) < _FRONT].min() < self.clearance:
            if self._avoid == 0.0:
                left = ranges[(angles > 0.3) & (angles < 1.9)].mean()
                right = ranges[(angles < -0.3) & (angles > -1.9)].mean()
                self._avoid = 1.0 if left >= right else -1.0
            return 0.0, 0.6 * self._avoid
        self._avoid = 0.0
        self._drift = float(np.clip(0.9 * self._drift + self.rng.normal(0.0, 0.1), -0.4, 0.4))
        return 1.0, self._drift

    def _to_action(self, v: float, w: float):
        """Normalised forward ``v`` and turn ``w`` (both in [-1, 1]) → the env's action."""
        if self.action_type == "discrete":
            if abs(w) > 0.3 or (v == 0.0 and w != 0.0):
                return _ACTION["turn_left"] if w > 0 else _ACTION["turn_right"]
            return _ACTION["forward"] if v > 0.0 else _ACTION["stop"]
        wheels = np.array([v - w, v + w])
        peak = np.abs(wheels).max()
        return (wheels / peak if peak > 1.0 else wheels).astype(np.float32)
