"""Base class of the single-agent Gymnasium tasks: robot 0 learns, other robots are scripted.

A subclass supplies a config dataclass (a :class:`~kin_envs.envs.common.CommonConfig`), a scene
generator, the other robots' wheel commands, and the task's reward / termination. This class
owns everything else: the one RNG, the world, the observation, the info channel and rendering.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from kin_envs.core.scenes import Scene
from kin_envs.core.world import Scan, World, WorldConfig
from kin_envs.envs.common import (
    ActionAdapter,
    CommonConfig,
    ObservationBuilder,
    ObservationLayout,
    check_render_mode,
    config_from_kwargs,
    detect_one_padded,
    detect_rows,
    kin_truth_rows,
    resolve_detector,
    split_rows,
)
from kin_envs.envs.info import pad_rows

__all__ = ["SingleRobotEnv"]

#: Pose indices in ``world.poses``: the learning robot is always robot 0.
LEARNER = 0


class SingleRobotEnv(gym.Env):
    """Common machinery; see :class:`~kin_envs.envs.kin_seek.KinSeekEnv` for the specification."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}
    config_class: ClassVar[type[CommonConfig]] = CommonConfig
    #: per-robot role names for rendering
    roles: ClassVar[tuple[str, ...]] = ("learner", "kin")
    #: True: fixed-shape info (padded slots + counts); False: the v0 ids' variable-length info
    padded_info: ClassVar[bool] = True

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        self.config = config_from_kwargs(self.config_class, kwargs)
        where = self.config.env_id
        self.render_mode = check_render_mode(render_mode, self.metadata["render_modes"], where)
        self.detector = resolve_detector(self.config.detector, where)
        self.tracker = self.config.make_tracker(detector=self.detector)
        self._feeder = None  # the permissive feed: the detector call that also feeds the tracker
        if self.tracker is not None:
            from kin_envs.envs.tracks import make_feeder

            noise = self.tracker.params.range_noise
            self._feeder = make_feeder(self.config.tracker_feed, self.detector, noise)
        self._feed = None
        # the step's detections, padded for the info (fixed-shape info, no permissive feed: see _detect)
        self._padded_dets: tuple[dict[str, np.ndarray], int] | None = None
        # the flat detections are read only by the tracker, the observation's detection channel and rendering
        self._flat_dets = (
            self.tracker is not None or self.config.obs_detections is not None or self.render_mode is not None
        )
        self._lidar = self.config.lidar_spec()
        self._world_config = WorldConfig(control_dt=self.config.control_dt)
        self.layout = ObservationLayout(
            n_beams=self._lidar.n_beams,
            range_max=self._lidar.range_max,
            angles=self._lidar.angles,
            frame_stack=self.config.frame_stack,
            detections=self.config.obs_detections,
            top_k=self.config.obs_top_k,
        )
        self._obs = ObservationBuilder(self.layout)
        self._actions = ActionAdapter(self.config.action_type, where)
        self.observation_space = self._obs.make_space()
        self.action_space = self._actions.make_space()
        self.world: World | None = None
        self._renderer = None
        self._last_scan: Scan | None = None
        self._last_detections = None
        self._wheels: np.ndarray | None = None
        self._current_poses: np.ndarray | None = None
        self._steps = 0

    def _poses(self) -> np.ndarray:
        """``world.poses`` now (read once per step; the vector env sets it from its batch read)."""
        return self._current_poses

    # -- hooks for subclasses -----------------------------------------------------------------
    def _make_scene(self, rng: np.random.Generator) -> Scene:
        raise NotImplementedError

    def _scan_robots(self) -> list[int] | None:
        """Robots to scan each step (row 0 must be the learner); ``None`` = all."""
        return [LEARNER]

    def _after_reset(self, scan: Scan) -> None:
        """Task state at the start of an episode."""

    def _other_wheels(self, scan: Scan) -> np.ndarray:
        """Normalised wheel speeds ``(n_robots - 1, 2)`` of the scripted robots."""
        return np.zeros((self.world.n_robots - 1, 2))

    def _task(self, scan: Scan) -> tuple[dict[str, float], bool, dict[str, Any]]:
        """Reward terms, ``terminated`` and extra info after a step."""
        raise NotImplementedError

    def _zero_terms(self) -> dict[str, float]:
        raise NotImplementedError

    #: ``_task`` of several sub-envs at once, for the native vector env: a classmethod
    #: ``(envs, poses, contacts) -> (terms, terminated, info)`` of columns over ``envs`` (poses
    #: ``(k, n_robots, 3)`` and contacts ``(k, n_robots)`` of this step) that updates each env's task
    #: state as its ``_task`` would and gives bit-identical values; ``None``: ``_task`` per sub-env.
    _task_batch = None

    # -- Gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; ``options`` is accepted and ignored."""
        super().reset(seed=seed)
        scene = self._make_scene(self.np_random)
        self.world = World(scene, seed=self.np_random, config=self._world_config)
        self._steps = 0
        scan = self.world.scan(self._scan_robots())
        poses = self._current_poses = self.world.poses
        self._after_reset(scan)
        dets = self._detect(scan, poses)
        if self.tracker is not None:
            self.tracker.reset()
            self._track(scan, dets, np.zeros(3))
        frame = self._sense(scan, dets)
        obs = self._obs.reset(frame)[0]
        info = self._kin_info(scan, dets, poses)
        info.update(self._task_info_at_reset())
        info["reward_terms"] = self._zero_terms()
        if self.render_mode == "human":
            self.render()
        return obs, info

    def _task_info_at_reset(self) -> dict[str, Any]:
        return {}

    def step(self, action):
        self._wheel_speeds(action)  # checks reset() was called
        self.world.step(wheel_speeds=self._wheels)
        scan = self.world.scan(self._scan_robots())
        poses = self._current_poses = self.world.poses
        dets = self._detect(scan, poses)
        if self.tracker is not None:
            self._track(scan, dets, self.world.odometry_delta[LEARNER])
        obs, reward, terminated, truncated, info = self._finish_step(self._sense(scan, dets))
        info.update(self._kin_info(scan, dets, poses))
        return obs, reward, terminated, truncated, info

    # The step in phases, so that the native vector env (kin_envs.envs.vector) can run the
    # physics, the lidar and the detector of all its sub-envs in one call each, between them.
    def _wheel_speeds(self, action) -> np.ndarray:
        """Phase 1: ``(n_robots, 2)`` wheel speeds (rad/s) of this step, kept in ``_wheels``."""
        if self.world is None:
            raise RuntimeError(f"{self.config.env_id}: call reset() before step()")
        learner = self._actions.one(action)
        wheels = np.vstack([learner[None, :], self._other_wheels(self._last_scan)])
        self._wheels = wheels * self.world.scene.robot.max_wheel_speed
        return self._wheels

    def _detect(self, scan: Scan, poses: np.ndarray):
        """The learner's detections as flat ``(row, cols)`` (:func:`detect_rows`), or ``None`` (no detector,
        or nothing reads them: ``_flat_dets``). The fixed-shape info's padded detections, matched and padded
        in the same compiled call (:func:`detect_one_padded`), are kept in ``_padded_dets`` for
        :meth:`_kin_info`."""
        self._padded_dets = None
        if self.detector is None:
            return None
        if self._feeder is not None:
            dets, self._feed = self._feeder.detect(scan.ranges[:1], scan.angles, scan.robots[:1], poses,
                                                   range_max=scan.range_max)  # fmt: skip
            return dets
        if self.padded_info:
            # the lidar's robot hits settle the match without a search (the same values)
            if scan.ranges.shape[0] == 1:  # the learner's row alone (KinSeek): no row views made
                ranges, hits = scan.ranges, (scan.hit_kind, scan.hit_index)
            else:
                ranges, hits = scan.ranges[:1], (scan.hit_kind[:1], scan.hit_index[:1])
            dets, cols, count = detect_one_padded(
                self.detector, ranges, scan.angles, int(scan.robots[0]), poses, self.config.max_detections,
                hits=hits, flat=self._flat_dets,
            )  # fmt: skip
            self._padded_dets = cols, count
            return dets
        return detect_rows(self.detector, scan.ranges[:1], scan.angles, scan.robots[:1], poses, trusted=True)

    def _track(self, scan: Scan, dets, odom_delta: np.ndarray) -> None:
        """Advance the tracker with this frame's detections (all accepted: the detector's operating
        point; or the permissive candidates, ``tracker={"feed": "permissive"}``), their segments' scan
        points and the learner's odometry increment."""
        from kin_envs.envs.tracks import track_update

        track_update(self.tracker, _rows(scan, 1), dets, odom_delta[None, :], self.world.config.control_dt,
                     self._feed)  # fmt: skip

    def _track_rows(self):
        """The tracker's confirmed kin tracks as detection rows (for ``obs_tracks``)."""
        from kin_envs.envs.tracks import track_rows

        angles = self.config.track_angles(self.world.scene.lidar.angles)
        return track_rows(self.tracker, self.config.max_tracks, angles)

    def _sense(self, scan: Scan, dets) -> np.ndarray:
        """Phase 2: remember the scan and detections; the learner's observation frame ``(1, d)``."""
        self._last_scan = scan
        self._last_detections = dets
        if self.config.obs_tracks:
            return self._obs.frame(scan.ranges[:1], self._track_rows())
        return self._obs.frame(scan.ranges[:1], dets)

    def _finish_step(self, frame: np.ndarray):
        """Phase 3: observation, reward, ends and the task's info (without the kin entries)."""
        self._steps += 1
        obs = self._obs.push(frame)[0]
        terms, terminated, info = self._task(self._last_scan)
        reward = float(sum(terms.values()))
        info["reward_terms"] = terms
        truncated = bool(self._steps >= self.config.max_steps and not terminated)
        if self.render_mode == "human":
            self.render()
        return obs, reward, bool(terminated), truncated, info

    def _kin_info(self, scan: Scan, dets, poses: np.ndarray) -> dict[str, Any]:
        """``kin_truth`` and ``kin_detections`` (padded with counts, or ragged for v0)."""
        truth_row, truth = kin_truth_rows(_rows(scan, 1), poses)
        if not self.padded_info:
            info = {"kin_truth": truth}
            if dets is not None:
                info["kin_detections"] = dets[1]
            return info
        cols, count = pad_rows(truth_row, truth, 1, self.world.n_robots - 1)
        info = {"kin_truth": {k: v[0] for k, v in cols.items()}, "kin_truth_count": int(count[0])}
        if self._padded_dets is not None:
            info["kin_detections"], info["kin_detections_count"] = self._padded_dets
            self._padded_dets = None  # handed out: never given twice
        elif dets is not None:
            cols, count = pad_rows(dets[0], dets[1], 1, self.config.max_detections)
            info["kin_detections"] = {k: v[0] for k, v in cols.items()}
            info["kin_detections_count"] = int(count[0])
        if self.tracker is not None:
            from kin_envs.envs.tracks import track_info

            cols, count = track_info(self.tracker, self.config.max_tracks)
            info["kin_tracks"] = {name: c[0] for name, c in cols.items()}
            info["kin_tracks_count"] = int(count[0])
        return info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn(
                f"{self.config.env_id}: render() called without a render_mode; pass "
                "render_mode='rgb_array' or 'human' to the constructor"
            )
            return None
        if self.world is None:
            raise RuntimeError(f"{self.config.env_id}: call reset() before render()")
        from kin_envs.envs.rendering import Renderer

        if self._renderer is None or (self._renderer.scene.arena != self.world.scene.arena):
            if self._renderer is not None:
                self._renderer.close()
            self._renderer = Renderer(
                self.world.scene,
                self.render_mode,
                self.config.render_size,
                self.metadata["render_fps"],
                title=self.config.env_id,
            )
        elif self._renderer.scene is not self.world.scene:
            self._renderer.set_scene(self.world.scene)
        beams, dets = [], []
        scan = self._last_scan
        if self.config.render_beams and scan is not None:
            beams.append((scan.poses[0], scan.ranges[0], scan.angles, scan.range_max))
            if self._last_detections is not None:
                dets.append((scan.poses[0], split_rows(*self._last_detections, 1)[0]))
        tracks = []
        if self.tracker is not None and scan is not None:
            tracks.append((scan.poses[0], self._track_rows()[1]))
        return self._renderer.render(self.world, self.roles, beams, dets, tracks)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _rows(scan: Scan, k: int) -> Scan:
    """The first ``k`` rows of a scan (the learner's)."""
    if scan.ranges.shape[0] == k:
        return scan
    return Scan(
        ranges=scan.ranges[:k],
        angles=scan.angles,
        hit_kind=scan.hit_kind[:k],
        hit_index=scan.hit_index[:k],
        true_ranges=scan.true_ranges[:k],
        robots=scan.robots[:k],
        poses=scan.poses[:k],
        range_max=scan.range_max,
    )
