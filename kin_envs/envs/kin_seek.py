"""``kin_envs/KinSeek-v2``: find a static kin robot among look-alike distractors with the lidar."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from kin_envs.core import scenes
from kin_envs.core.scenes import Cylinder, RandomArenaConfig, Scene
from kin_envs.core.world import Scan
from kin_envs.envs.base import SingleRobotEnv
from kin_envs.envs.common import CommonConfig, check_bool, check_float, check_int

__all__ = ["KinSeekConfig", "KinSeekConfigV1", "KinSeekEnv", "KinSeekEnvV0", "KinSeekEnvV1", "DISTRACTORS"]

#: Distractor mix: cylinders, boxes, regular prisms, interior walls; half of the cylinders, boxes
#: and prisms are exactly the kin's 7 cm width. Other cylinders are >= 5 cm in radius.
DISTRACTORS = RandomArenaConfig(
    kind_weights=(0.35, 0.15, 0.35, 0.15),
    kin_width_prob=0.5,
    cylinder_radius=(0.05, 0.15),
    box_size=(0.05, 0.3),
    prism_width=(0.05, 0.25),
    wall_length=(0.4, 1.2),
)
#: Radii that replace kin-width cylinders unless ``kin_like_cylinders=True`` (shrinking keeps the
#: scene valid: a smaller circle cannot overlap anything the larger one did not).
_SMALL_CYLINDER_RADIUS = (0.015, 0.025)
_MAX_LAYOUT_TRIES = 200
_WEIGHTS = ("progress_weight", "success_bonus", "collision_penalty", "time_penalty")


@dataclass(frozen=True, kw_only=True)
class KinSeekConfig(CommonConfig):
    """Arguments of ``KinSeek-v2`` (see :class:`KinSeekEnv`)."""

    env_id: ClassVar[str] = "KinSeek-v2"
    default_tracker_feed: ClassVar[str] = "auto"

    arena_size: float = 4.0
    n_distractors: int = 6
    max_steps: int = 300
    success_distance: float = 0.3
    min_start_distance: float = 1.0
    kin_like_cylinders: bool = False
    progress_weight: float = 10.0
    success_bonus: float = 10.0
    collision_penalty: float = 0.1
    time_penalty: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        w = self.env_id
        check_float(w, "arena_size", self.arena_size, 2.0, 30.0)
        check_int(w, "n_distractors", self.n_distractors, 0, 200)
        check_int(w, "max_steps", self.max_steps, 1, 1_000_000)
        check_float(w, "success_distance", self.success_distance, 0.18, 2.0, lo_open=True)
        check_float(w, "min_start_distance", self.min_start_distance, self.success_distance,
                    self.arena_size * 0.9, lo_open=True)
        check_bool(w, "kin_like_cylinders", self.kin_like_cylinders)
        for name in ("progress_weight", "success_bonus", "collision_penalty", "time_penalty"):
            check_float(w, name, getattr(self, name), 0.0, 1e6)


class KinSeekEnv(SingleRobotEnv):
    """Find the kin robot using only the lidar, and get within ``success_distance`` of it.

    ## Description

    A square arena holds two robots of the paper's design (9 cm body, 7 cm lidar housing on top,
    RPLIDAR A1: 360 beams, 1°, 12 m) and ``n_distractors`` obstacles: cylinders (some thinner, some
    thicker than the kin's 7 cm housing, see ``kin_like_cylinders``), boxes and regular prisms
    (half of them exactly 7 cm wide, the paper's Scenario II look-alikes) and short interior walls.
    Robot 0 learns; robot 1, the *kin*, stands still. A lidar sees only the other robot's housing,
    so at 1° resolution the kin covers 3 or more beams only within about 1.3 m.

    ## Action Space

    ``action_type="continuous"`` (default): ``Box(-1, 1, (2,), float32)``, the left and right
    wheel speeds as fractions of ``max_wheel_speed`` (10 rad/s: 0.33 m/s forward, 4.1 rad/s
    turning). Values outside [-1, 1] are clipped; NaN/inf or a shape other than ``(2,)`` raise
    ``ValueError``.

    ``action_type="discrete"``: ``Discrete(5)``: 0 stop, 1 forward (full speed), 2 turn left and
    3 turn right (in place, half wheel speed), 4 back (half speed).

    ## Observation Space

    ``Box(0, 1, (frame_stack * frame_dim,), float32)`` (sin/cos slots of ``"topk"`` go down to
    -1). Each frame is the learner's scan as ``range / 12 m`` (1.0 = no return; beam ``i`` points
    ``i`` degrees clockwise from the heading), followed by the detector channel if
    ``obs_detections`` is set:

    * ``"topk"`` (or ``True``): ``obs_top_k`` slots, nearest detection first, each
      ``[present, range / 12, sin(bearing), cos(bearing)]``, empty slots zero;
    * ``"mask"``: 360 values, 1 on beams of a detected kin's segment.

    Frames are stacked oldest first; at reset every slot holds the first frame.
    ``env.unwrapped.layout`` (:class:`~kin_envs.envs.common.ObservationLayout`) describes this and
    ``layout.newest_scan(obs)`` recovers the ranges in metres.

    ## Rewards

    ``info["reward_terms"]`` holds the terms; the reward is their sum:

    * ``progress``: ``progress_weight * (d_prev - d)``, ``d`` the true centre distance to the kin.
      This shaping uses privileged state (the policy never sees ``d``); it is potential-based, so
      it does not change which policies are optimal.
    * ``success``: ``+success_bonus`` on the step that reaches the kin.
    * ``collision``: ``-collision_penalty`` on every step that ends touching an obstacle, wall or
      the kin.
    * ``time``: ``-time_penalty`` every step.

    ## Starting State

    A fresh random layout each episode (:func:`kin_envs.scenes.random_arena` with
    :data:`DISTRACTORS`, seeded from ``np_random``): nothing overlaps, everything keeps 5 cm
    clearance, headings are uniform, and the kin's centre is at least ``min_start_distance`` from
    the learner's. The kin may start hidden behind an obstacle or out of detection range.

    ## Episode End

    * Termination: the centre distance to the kin is ``<= success_distance`` (default 0.3 m;
      bodies touch at 0.18 m). The episode ends there, which is how the robot "stops" at the kin;
      ``info["is_success"]`` is True.
    * Truncation: ``max_steps`` steps (the time limit is internal; the registered spec has no
      ``TimeLimit`` wrapper).

    ## Info

    Every entry keeps one shape on every step (so vector envs can stack it). Per-kin entries are
    padded columns, valid slots first, nearest first, with a count (:mod:`kin_envs.envs.info`;
    ``kin_envs.envs.unpad_detections(info)`` / ``unpad_kin_truth(info)`` drop the empty slots):

    * ``kin_truth``: the kin the learner's lidar sees this step, 1 slot of ``index, range,
      bearing, x, y, n_beams``; ``kin_truth_count`` is 1 when it is seen, else 0;
    * ``kin_detections`` (absent with ``detector=None``): ``max_detections`` (16) slots of
      ``range, bearing, x, y, score, first_beam, last_beam, n_beams, kin_index`` (``kin_index`` =
      matched robot, -1 for a false detection); ``kin_detections_count`` (int) valid slots;
    * empty slots hold -1 (``index``, ``first_beam``, ``last_beam``, ``kin_index``) or 0;
    * ``reward_terms``, ``is_success``, ``kin_distance`` (true centre distance, m), ``collision``.

    Bearings are rad CCW in the robot's frame, x forward, y left.

    ## Vector env

    ``gymnasium.make_vec("kin_envs/KinSeek-v2", num_envs=K)`` builds the native vector env
    (:class:`kin_envs.envs.vector.KinVectorEnv`): it steps the K worlds and casts all their lidars
    and runs the detector over all K scans in one call each, with Gymnasium's ``NEXT_STEP``
    autoreset, and returns what ``vectorization_mode="sync"`` returns for the same seeds.

    ## Arguments

    ``gymnasium.make("kin_envs/KinSeek-v2", **kwargs)``; unknown names raise
    :class:`~kin_envs.envs.common.UnknownArgumentError` (a ``TypeError`` and ``ValueError``):

    * ``arena_size`` (4.0): arena side, m; ``n_distractors`` (6);
      ``max_steps`` (300, 0.1 s each); ``success_distance`` (0.3 m);
      ``min_start_distance`` (1.0 m); ``kin_like_cylinders`` (False: cylinders of exactly the
      kin's radius are replaced by thinner ones; True keeps them, the paper's unresolvable case);
    * reward weights ``progress_weight`` (10), ``success_bonus`` (10), ``collision_penalty``
      (0.1; raising it to 0.5 was measured to lower PPO's success from 0.85 to 0.65 without
      reducing its collisions), ``time_penalty`` (0.01);
    * sensing: ``noise_sigma`` (0, relative range noise), ``dropout_prob`` (0);
    * ``detector``: ``"geometric"`` (default, the paper's detector), ``"learned"``, ``None`` or a
      detector object; ``obs_detections`` (None), ``obs_top_k`` (3), ``frame_stack`` (1);
      ``max_detections`` (16): slots of ``info["kin_detections"]``;
    * ``action_type`` (``"continuous"``/``"discrete"``), ``control_dt`` (0.1 s);
    * ``render_mode`` (None, ``"rgb_array"``, ``"human"``), ``render_size`` (512 px),
      ``render_beams`` (True: the learner's beams and detections, green = real kin, red = false).

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
    * v1: fixed-shape info (padded ``kin_truth`` / ``kin_detections`` slots with
      ``kin_truth_count`` / ``kin_detections_count``), so that Gymnasium's vector envs, SB3's and
      RLlib's can stack it; ``max_detections`` argument; native vector entry point. Observations,
      rewards and dynamics are those of v0.
    * v0: initial version (variable-length info columns; still registered).
    """

    config_class: ClassVar[type] = KinSeekConfig
    roles: ClassVar[tuple[str, ...]] = ("learner", "kin")

    def _make_scene(self, rng: np.random.Generator) -> Scene:
        cfg = self.config
        for _ in range(_MAX_LAYOUT_TRIES):
            scene = scenes.random_arena(
                2, cfg.n_distractors, seed=rng, size=cfg.arena_size, config=DISTRACTORS,
                lidar=self._lidar,
            )
            a, b = scene.robots
            if math.hypot(a.x - b.x, a.y - b.y) >= cfg.min_start_distance:
                break
        else:
            raise ValueError(
                f"{cfg.env_id}: no layout with the kin >= min_start_distance="
                f"{cfg.min_start_distance} m away in {_MAX_LAYOUT_TRIES} tries; lower "
                "min_start_distance or enlarge arena_size"
            )
        if not cfg.kin_like_cylinders:
            scene = thin_kin_like_cylinders(scene, rng)
        return scene

    def _kin_distance(self) -> float:
        p = self._poses()
        return float(math.hypot(p[1, 0] - p[0, 0], p[1, 1] - p[0, 1]))

    def _after_reset(self, scan: Scan) -> None:
        self._prev_distance = self._kin_distance()

    def _task_info_at_reset(self) -> dict[str, Any]:
        return {"is_success": False, "kin_distance": self._prev_distance, "collision": False}

    def _zero_terms(self) -> dict[str, float]:
        return {"progress": 0.0, "success": 0.0, "collision": 0.0, "time": 0.0}

    def _task(self, scan: Scan):
        cfg = self.config
        d = self._kin_distance()
        success = d <= cfg.success_distance
        collision = bool(self.world.contacts[0])
        terms = {
            "progress": cfg.progress_weight * (self._prev_distance - d),
            "success": cfg.success_bonus if success else 0.0,
            "collision": -cfg.collision_penalty if collision else 0.0,
            "time": -cfg.time_penalty,
        }
        self._prev_distance = d
        return terms, success, {"is_success": success, "kin_distance": d, "collision": collision}

    @classmethod
    def _task_batch(cls, envs, poses: np.ndarray, contacts: np.ndarray):
        """:meth:`_task` of ``envs`` as columns (see ``SingleRobotEnv._task_batch``)."""
        cfg = envs[0].config
        if any(type(getattr(cfg, f)) is not float for f in _WEIGHTS):
            return None  # an int weight makes an int term in _task's info: per sub-env then
        rel = (poses[:, 1, :2] - poses[:, 0, :2]).tolist()
        d = np.array([math.hypot(x, y) for x, y in rel])  # math.hypot, as _kin_distance (not np.hypot)
        prev = np.array([e._prev_distance for e in envs])
        for e, x in zip(envs, d.tolist(), strict=True):
            e._prev_distance = x
        success = d <= cfg.success_distance
        collision = contacts[:, 0] != 0
        terms = {
            "progress": cfg.progress_weight * (prev - d),
            "success": np.where(success, cfg.success_bonus, 0.0),
            "collision": np.where(collision, -cfg.collision_penalty, 0.0),
            "time": np.full(len(envs), -cfg.time_penalty),
        }
        return terms, success, {"is_success": success, "kin_distance": d, "collision": collision}


def thin_kin_like_cylinders(scene: Scene, rng: np.random.Generator) -> Scene:
    """Replace cylinders of exactly the kin's housing radius with thinner ones (1.5–2.5 cm)."""
    r_kin = scene.robot.housing_radius
    obstacles = list(scene.obstacles)
    changed = False
    for j, o in enumerate(obstacles):
        if isinstance(o, Cylinder) and math.isclose(o.radius, r_kin):
            obstacles[j] = Cylinder(x=o.x, y=o.y, radius=float(rng.uniform(*_SMALL_CYLINDER_RADIUS)))
            changed = True
    if not changed:
        return scene
    # (a thinner cylinder at the same centre overlaps nothing the valid scene's did not: not checked again)
    fields = {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene)}
    return Scene._placed(**{**fields, "obstacles": tuple(obstacles)})


@dataclass(frozen=True, kw_only=True)
class KinSeekConfigV1(KinSeekConfig):
    env_id: ClassVar[str] = "KinSeek-v1"
    default_tracker_feed: ClassVar[str] = "accepted"


class KinSeekEnvV1(KinSeekEnv):
    """``kin_envs/KinSeek-v1``: :class:`KinSeekEnv` (the specification, v2) whose ``tracker=True`` feeds the
    tracker ``"accepted"`` (its Version History). Kept so that earlier results can be reproduced."""

    config_class: ClassVar[type] = KinSeekConfigV1


@dataclass(frozen=True, kw_only=True)
class _KinSeekConfigV0(KinSeekConfig):
    env_id: ClassVar[str] = "KinSeek-v0"
    default_tracker_feed: ClassVar[str] = "accepted"


class KinSeekEnvV0(KinSeekEnv):
    """``kin_envs/KinSeek-v0``: :class:`KinSeekEnv` with the v0 info layout (``kin_truth`` and
    ``kin_detections`` columns of variable length, no counts). Kept so that earlier results can be
    reproduced; Gymnasium's vector envs cannot stack this info: use ``KinSeek-v2``."""

    config_class: ClassVar[type] = _KinSeekConfigV0
    padded_info: ClassVar[bool] = False
