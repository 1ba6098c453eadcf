"""``kin_envs/KinFollow-v2``: keep within a distance band of a wandering kin robot."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from kin_envs.core import scenes
from kin_envs.core.scenes import Scene
from kin_envs.core.world import Scan
from kin_envs.envs.base import SingleRobotEnv
from kin_envs.envs.common import CommonConfig, check_bool, check_float, check_int
from kin_envs.envs.kin_seek import DISTRACTORS, thin_kin_like_cylinders

__all__ = [
    "KinFollowConfig", "KinFollowConfigV1", "KinFollowEnv", "KinFollowEnvV0", "KinFollowEnvV1",
    "wander_command",
]

_MAX_LAYOUT_TRIES = 1000
_FRONT = math.radians(35.0)


@dataclass(frozen=True, kw_only=True)
class KinFollowConfig(CommonConfig):
    """Arguments of ``KinFollow-v2`` (see :class:`KinFollowEnv`)."""

    env_id: ClassVar[str] = "KinFollow-v2"
    default_tracker_feed: ClassVar[str] = "auto"

    arena_size: float = 5.0
    n_distractors: int = 4
    max_steps: int = 400
    band_min: float = 0.4
    band_max: float = 0.8
    lost_distance: float = 2.0
    kin_speed: float = 0.5
    kin_like_cylinders: bool = False
    in_band_reward: float = 0.1
    distance_weight: float = 0.2
    collision_penalty: float = 0.5
    lost_penalty: float = 5.0

    def __post_init__(self) -> None:
        super().__post_init__()
        w = self.env_id
        check_float(w, "arena_size", self.arena_size, 2.0, 30.0)
        check_int(w, "n_distractors", self.n_distractors, 0, 200)
        check_int(w, "max_steps", self.max_steps, 1, 1_000_000)
        check_float(w, "band_min", self.band_min, 0.18, 5.0)
        check_float(w, "band_max", self.band_max, self.band_min, 10.0, lo_open=True)
        check_float(w, "lost_distance", self.lost_distance, self.band_max, 100.0, lo_open=True)
        check_float(w, "kin_speed", self.kin_speed, 0.0, 1.0)
        check_bool(w, "kin_like_cylinders", self.kin_like_cylinders)
        for name in ("in_band_reward", "distance_weight", "collision_penalty", "lost_penalty"):
            check_float(w, name, getattr(self, name), 0.0, 1e6)


class KinFollowEnv(SingleRobotEnv):
    """Follow a wandering kin robot: stay ``band_min``–``band_max`` from it, without collisions.

    ## Description

    The arena, robots and distractors are those of ``KinSeek-v1``. Robot 1, the kin, wanders at
    ``kin_speed`` times the top speed with a scripted controller that sees only its own lidar scan
    (:func:`wander_command`: drive on with a slowly drifting turn rate, turn in place toward the
    more open side when something is within 0.45 m ahead; it avoids the learner too). Robot 0
    learns to keep the kin at a centre distance inside the band.

    ## Action Space

    As ``KinSeek-v1``: ``Box(-1, 1, (2,), float32)`` normalised (left, right) wheel speeds, or
    ``Discrete(5)`` (stop, forward, turn left, turn right, back) with ``action_type="discrete"``.

    ## Observation Space

    As ``KinSeek-v1``: the learner's scan as ``range / 12 m``, optional detector channel
    (``obs_detections``), ``frame_stack`` frames, float32.

    ## Rewards

    Terms in ``info["reward_terms"]``, summing to the reward; ``d`` is the true centre distance
    (privileged, used only for the reward):

    * ``in_band``: ``+in_band_reward`` when ``band_min <= d <= band_max``;
    * ``out_of_band``: ``-distance_weight * (distance to the band, m)`` otherwise;
    * ``collision``: ``-collision_penalty`` on each step that ends touching anything;
    * ``lost``: ``-lost_penalty`` on the step the kin gets farther than ``lost_distance``.

    ## Starting State

    A fresh random layout (:func:`kin_envs.scenes.random_arena`, seeded from ``np_random``) in
    which the two robots start ``band_min``–``band_max`` apart, with uniform random headings.

    ## Episode End

    * Termination: ``d > lost_distance`` (the kin is lost).
    * Truncation: ``max_steps`` steps (internal time limit).

    ## Info

    ``kin_truth`` / ``kin_truth_count``, ``kin_detections`` / ``kin_detections_count`` (unless
    ``detector=None``; fixed shapes, padded slots) and ``reward_terms`` as in ``KinSeek-v1``;
    also ``kin_distance`` (``d``, m), ``in_band`` and ``collision`` (bools).

    ## Arguments

    ``arena_size`` (5.0 m), ``n_distractors`` (4), ``max_steps`` (400), ``band_min`` (0.4 m),
    ``band_max`` (0.8 m), ``lost_distance`` (2.0 m), ``kin_speed`` (0.5 of 0.33 m/s),
    ``kin_like_cylinders`` (False), reward weights ``in_band_reward`` (0.1),
    ``distance_weight`` (0.2 per m), ``collision_penalty`` (0.5), ``lost_penalty`` (5), and the
    common arguments of ``KinSeek-v1`` (``noise_sigma``, ``dropout_prob``, ``detector``,
    ``obs_detections``, ``obs_top_k``, ``max_detections``, ``frame_stack``, ``action_type``, ``control_dt``,
    ``render_mode``, ``render_size``, ``render_beams``). Unknown names raise
    :class:`~kin_envs.envs.common.UnknownArgumentError`.

    Multi-frame tracking (opt-in): ``tracker=True`` or a dict of ``detectors.TrackerParams`` fields and
    ``"kin_model"`` (the track classifier: ``"learned"``, the default shipped one, ``"hand"``, the
    hand-tuned fusion of the cues, or a path to a track-classifier JSON; ``"feed"``: ``"accepted"`` (v1's
    default), ``"permissive"`` (the sequence benchmark's feed) or ``"auto"`` (v2's default: permissive where
    it costs no second detector call), see ``CommonConfig``; a bad key or value raises naming it) adds
    ``info["kin_tracks"]`` (``max_tracks`` = 16 padded slots of ``detectors.tracking.TRACK_FIELDS``, robot
    frame) and ``info["kin_tracks_count"]``; ``obs_tracks=True`` fills the observation's detection channel
    from the confirmed kin tracks instead of the raw detections (needs ``obs_detections``).

    ## Version History

    * v2: ``tracker=True`` feeds the tracker ``"auto"`` (v1: ``"accepted"``): with the shipped geometric
      detector its permissive candidates, from the same call (with the detector's accepted detections only,
      its tracks found no more kin than its raw detections under range noise: the kin tracked in 10 % of
      KinFollow frames at 1 % noise, against 91 % with the permissive feed); any other detector as in v1.
      Without a tracker v2 is v1. (The learned detector's detections no longer depend on the batch a scan
      comes in, since session 16, in v1 too.)
    * v1: fixed-shape info as ``KinSeek-v1`` (padded slots with counts), ``max_detections``,
      native vector entry point (``gymnasium.make_vec``). Observations, rewards and dynamics are
      those of v0.
    * v0: initial version (variable-length info columns; still registered).
    """

    config_class: ClassVar[type] = KinFollowConfig
    roles: ClassVar[tuple[str, ...]] = ("learner", "kin")

    def _make_scene(self, rng: np.random.Generator) -> Scene:
        cfg = self.config
        for _ in range(_MAX_LAYOUT_TRIES):
            scene = scenes.random_arena(
                2, cfg.n_distractors, seed=rng, size=cfg.arena_size, config=DISTRACTORS,
                lidar=self._lidar,
            )
            a, b = scene.robots
            if cfg.band_min <= math.hypot(a.x - b.x, a.y - b.y) <= cfg.band_max:
                break
        else:
            raise ValueError(
                f"{cfg.env_id}: no layout with the robots {cfg.band_min}-{cfg.band_max} m apart "
                f"in {_MAX_LAYOUT_TRIES} tries; use fewer distractors or a wider band"
            )
        if not cfg.kin_like_cylinders:
            scene = thin_kin_like_cylinders(scene, rng)
        return scene

    def _scan_robots(self):
        return None  # both: the kin steers by its own scan

    def _after_reset(self, scan: Scan) -> None:
        self._kin_state = np.zeros(2)  # (drifting turn rate, committed avoidance direction)

    def _other_wheels(self, scan: Scan) -> np.ndarray:
        spec = self.world.scene.robot
        v, omega = wander_command(
            scan.ranges[1], scan.angles, self._kin_state, self.np_random,
            speed=self.config.kin_speed * spec.max_speed, turn_rate=0.5 * spec.max_turn_rate,
            blocked=bool(self.world.contacts[1]),
        )
        wheels = self.world.unicycle_to_wheel_speeds(np.array([[v, omega]]))
        return wheels / spec.max_wheel_speed

    def _distance(self) -> float:
        p = self._poses()
        return float(math.hypot(p[1, 0] - p[0, 0], p[1, 1] - p[0, 1]))

    def _zero_terms(self) -> dict[str, float]:
        return {"in_band": 0.0, "out_of_band": 0.0, "collision": 0.0, "lost": 0.0}

    def _task_info_at_reset(self):
        d = self._distance()
        return {"kin_distance": d, "in_band": True, "collision": False}

    def _task(self, scan: Scan):
        cfg = self.config
        d = self._distance()
        gap = max(cfg.band_min - d, d - cfg.band_max, 0.0)
        collision = bool(self.world.contacts[0])
        lost = d > cfg.lost_distance
        terms = {
            "in_band": cfg.in_band_reward if gap == 0.0 else 0.0,
            "out_of_band": -cfg.distance_weight * gap,
            "collision": -cfg.collision_penalty if collision else 0.0,
            "lost": -cfg.lost_penalty if lost else 0.0,
        }
        return terms, lost, {"kin_distance": d, "in_band": gap == 0.0, "collision": collision}


def wander_command(
    ranges: np.ndarray,
    angles: np.ndarray,
    state: np.ndarray,
    rng: np.random.Generator,
    speed: float,
    turn_rate: float,
    clearance: float = 0.45,
    blocked: bool = False,
) -> tuple[float, float]:
    """The wandering kin's controller: ``(v m/s, omega rad/s)`` from its own scan.

    ``state`` (2,) is updated in place: ``[drifting turn rate, committed avoidance direction]``.
    Committing to one turn direction until the way ahead is clear avoids dithering in corners.
    """
    front = ranges[np.abs(angles) < _FRONT]
    if blocked or front.min() < clearance:
        if state[1] == 0.0:
            left = ranges[(angles > 0.3) & (angles < 1.9)].mean()
            right = ranges[(angles < -0.3) & (angles > -1.9)].mean()
            state[1] = 1.0 if left >= right else -1.0
        return 0.0, float(state[1] * turn_rate)
    state[1] = 0.0
    state[0] = float(np.clip(0.85 * state[0] + rng.normal(0.0, 0.15), -0.5, 0.5))
    return speed, float(state[0] * turn_rate)


@dataclass(frozen=True, kw_only=True)
class KinFollowConfigV1(KinFollowConfig):
    env_id: ClassVar[str] = "KinFollow-v1"
    default_tracker_feed: ClassVar[str] = "accepted"


class KinFollowEnvV1(KinFollowEnv):
    """``kin_envs/KinFollow-v1``: :class:`KinFollowEnv` (the specification, v2) whose ``tracker=True`` feeds
    the tracker ``"accepted"`` (its Version History). Kept so that earlier results can be reproduced."""

    config_class: ClassVar[type] = KinFollowConfigV1


@dataclass(frozen=True, kw_only=True)
class _KinFollowConfigV0(KinFollowConfig):
    env_id: ClassVar[str] = "KinFollow-v0"
    default_tracker_feed: ClassVar[str] = "accepted"


class KinFollowEnvV0(KinFollowEnv):
    """``kin_envs/KinFollow-v0``: :class:`KinFollowEnv` with the v0 info layout (``kin_truth`` and
    ``kin_detections`` columns of variable length, no counts). Kept so that earlier results can be
    reproduced; Gymnasium's vector envs cannot stack this info: use ``KinFollow-v2``."""

    config_class: ClassVar[type] = _KinFollowConfigV0
    padded_info: ClassVar[bool] = False
