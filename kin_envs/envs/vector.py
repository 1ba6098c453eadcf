"""Native Gymnasium vector envs of the single-robot tasks (``KinSeek-v2``, ``KinFollow-v2``, and their v1).

``gymnasium.make_vec("kin_envs/KinSeek-v2", num_envs=K)`` (the registered ``vector_entry_point``)
returns a :class:`KinSeekVectorEnv`. It holds K ordinary envs (their scenes, tasks, RNGs and
frame stacks) but runs the expensive parts of a step once for all of them:

* the physics of the K worlds (:class:`kin_envs.core.multi.WorldBatch`: batched drive update,
  direct Chipmunk calls, contacts of all worlds at once);
* the lidars of all K worlds: one call of the raycasting kernel;
* the detector over all K learners' scans: one ``detect_batch`` call;
* observations and the fixed-shape info built as (K, ...) arrays, never per-env dicts to stack;
* with ``tracker=``, one :class:`detectors.KinTracker` update over the K learners
  (:class:`kin_envs.envs.tracks.VectorTracker`; a resetting sub-env's first frame runs on its own tracker,
  which the shared one adopts; track ids per sub-env).

Autoreset is Gymnasium's default ``NEXT_STEP`` (``metadata["autoreset_mode"]``): the step after a
sub-env terminates or truncates resets it (its action is ignored, reward 0, not done) and returns
its first observation and reset info. Everything returned (observations, rewards, terminations,
truncations and the stacked info with its ``_key`` masks) is what
``gymnasium.make_vec(..., vectorization_mode="sync")`` returns for the same seeds (tested, across
autoresets).
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from detectors.base import gc_paused
from kin_envs.core.multi import WorldBatch
from kin_envs.core.world import Scan
from kin_envs.envs._vector_glue import match_pad_worlds
from kin_envs.envs.base import LEARNER, SingleRobotEnv
from kin_envs.envs.common import detect_rows, detection_arrays, kin_truth_padded
from kin_envs.envs.info import DETECTION_FIELDS, INT_FIELDS, KIN_TRUTH_FIELDS, pad_rows
from kin_envs.envs.kin_follow import KinFollowEnv, KinFollowEnvV1
from kin_envs.envs.kin_seek import KinSeekEnv, KinSeekEnvV1
from kin_envs.envs.tracks import VectorTracker, track_info, track_rows

__all__ = [
    "KinFollowVectorEnv", "KinFollowVectorEnvV1", "KinSeekVectorEnv", "KinSeekVectorEnvV1", "KinVectorEnv",
    "stack_infos",
]

_KIN_KEYS = ("kin_truth", "kin_detections", "kin_tracks")


def stack_infos(infos: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack per-env infos with the same keys the way ``gymnasium.vector.VectorEnv._add_info``
    does (arrays of the first env's dtype, nested dicts recursively, ``_key`` masks all True)."""
    n = len(infos)
    out: dict[str, Any] = {}
    for key, v in infos[0].items():
        vals = [d[key] for d in infos]
        if isinstance(v, dict):
            out[key] = stack_infos(vals)
        elif type(v) in (int, float, bool) or isinstance(v, np.number):
            out[key] = np.array(vals, dtype=type(v))
        elif isinstance(v, np.ndarray):
            out[key] = np.stack(vals).astype(v.dtype, copy=False)
        else:
            arr = np.full(n, None, dtype=object)
            arr[:] = vals
            out[key] = arr
        out[f"_{key}"] = np.ones(n, dtype=np.bool_)
    return out


class KinVectorEnv(VectorEnv):
    """K sub-envs of ``env_class`` stepped together; see the module docstring.

    Args:
        num_envs: number of sub-envs K.
        render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns a tuple of K frames).
        **kwargs: the single env's arguments (see its docstring), the same for every sub-env.
    """

    env_class: ClassVar[type[SingleRobotEnv]] = SingleRobotEnv
    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": 10,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, **kwargs: Any) -> None:
        self.envs: list[SingleRobotEnv] = []  # so that close() works if a check below raises
        where = self.env_class.config_class.env_id
        if not isinstance(num_envs, int | np.integer) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"{where} vector env: num_envs must be an integer >= 1, got {num_envs!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(
                f"{where} vector env: render_mode must be None or 'rgb_array', got {render_mode!r}"
            )
        first = self.env_class(render_mode=render_mode, **kwargs)
        if "detector" in kwargs or first.detector is not None:
            # one detector object for all sub-envs (a learned model is loaded once)
            kwargs = {**kwargs, "detector": first.detector}
        self.envs = [first] + [
            self.env_class(render_mode=render_mode, **kwargs) for _ in range(int(num_envs) - 1)
        ]
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.detector = first.detector
        self.layout = first.layout
        self.config = first.config
        self._tracks: VectorTracker | None = None
        self._in_reset = False
        if self.config.tracker is not None:
            # one tracker over the K learners; each sub-env keeps its own for its reset frame (adopted)
            shared = self.config.make_tracker(n_observers=self.num_envs, detector=self.detector)
            self._tracks = VectorTracker(shared)
            for i, e in enumerate(self.envs):
                e._track_rows = functools.partial(self._sub_track_rows, i)
                e._feeder = first._feeder  # one permissive detector (a learned model loaded once)
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._batch: WorldBatch | None = None
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)
        self._observations = np.zeros((self.num_envs, self.layout.dim), dtype=np.float32)
        self._n_robots = 0
        self._truth_slots = 0

    # -- API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset sub-envs: all, or those in ``options["reset_mask"]`` (a ``(K,)`` bool array).

        ``seed``: ``None``, an int (sub-env ``i`` gets ``seed + i``) or a list of K seeds, as
        ``SyncVectorEnv``.
        """
        k = self.num_envs
        if seed is None:
            seeds = [None] * k
        elif isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(k)]
        else:
            seeds = list(seed)
            if len(seeds) != k:
                raise ValueError(f"reset: seed must be None, an int or a list of {k} seeds, got {seed!r}")
        options = dict(options) if options else {}
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(k, dtype=np.bool_)
        elif not (
            isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == (k,) and mask.any()
        ):
            raise ValueError(
                f"reset: options['reset_mask'] must be a numpy bool array of shape ({k},) with at "
                f"least one True, got {mask!r}"
            )
        ids = np.flatnonzero(mask).tolist()
        if self._batch is None and len(ids) < k:
            raise ValueError("reset: the first reset must reset every sub-env (no reset_mask)")
        infos = []
        with gc_paused():  # K resets: one burst of objects, examined by the next collection
            for i in ids:
                obs, info = self._reset_sub(i, seed=seeds[i], options=options or None)
                self._observations[i] = obs
                infos.append(info)
        self._autoreset[ids] = False
        self._sync_batch(ids)
        info = stack_infos(infos)
        if len(ids) < k:  # stack_infos fills every listed sub-env; widen to K with masks
            info = _widen(info, ids, k)
        return self._observations.copy(), info

    def _reset_sub(self, i: int, **kwargs: Any):
        """Reset sub-env ``i`` (its first frame tracked by its own tracker, which the shared one adopts)."""
        self._in_reset = True
        try:
            out = self.envs[i].reset(**kwargs)
        finally:
            self._in_reset = False
        if self._tracks is not None:
            self._tracks.adopt(i, self.envs[i].tracker)
        return out

    def _sub_track_rows(self, i: int):
        """Sub-env ``i``'s confirmed kin tracks as detection rows (its ``_track_rows``: observation and
        rendering): its own tracker during its reset, the shared one's observer ``i`` otherwise."""
        if self._in_reset:
            return SingleRobotEnv._track_rows(self.envs[i])
        angles = self.config.track_angles(self.envs[i].world.scene.lidar.angles)
        row, cols = track_rows(self._tracks, self.config.max_tracks, angles)
        sel = row == i
        return np.zeros(int(sel.sum()), np.int64), {f: c[sel] for f, c in cols.items()}

    def _sync_batch(self, ids: list[int]) -> None:
        if self._batch is None or len(ids) == self.num_envs:
            self._batch = WorldBatch([e.world for e in self.envs])
        else:
            for i in ids:
                self._batch[i] = self.envs[i].world
        self._n_robots = self.envs[0].world.n_robots
        self._truth_slots = self._n_robots - 1

    def step(self, actions):
        if self._batch is None:
            raise RuntimeError(f"{self.config.env_id} vector env: call reset() before step()")
        k = self.num_envs
        acts = np.asarray(actions)
        if acts.shape[:1] != (k,):
            raise ValueError(
                f"{self.config.env_id} vector env: actions must have {k} rows (one per sub-env), "
                f"got shape {acts.shape}"
            )
        resets = np.flatnonzero(self._autoreset).tolist()
        active = ~self._autoreset
        on = np.flatnonzero(active).tolist()
        envs = self.envs
        wheels = self._wheel_speeds(acts, on)
        rewards = np.zeros(k, dtype=np.float64)
        terminations = np.zeros(k, dtype=np.bool_)
        truncations = np.zeros(k, dtype=np.bool_)
        per_env: list[dict[str, Any] | None] = [None] * k
        kin: dict[str, tuple[dict[str, np.ndarray], np.ndarray]] = {}
        task: dict[str, Any] | None = None
        if on:
            self._batch.step(wheels, active=None if not resets else active)
            combined, poses, _ = self._batch.scan_combined(
                envs[0]._scan_robots(), active=None if not resets else active
            )
            frames, kin = self._sense(on, combined, poses)
            task = self._finish_batch(on, frames, poses, rewards, terminations, truncations)
            if task is None:
                for r, i in enumerate(on):
                    obs, rew, term, trunc, info = envs[i]._finish_step(frames[r : r + 1])
                    self._observations[i] = obs
                    rewards[i], terminations[i], truncations[i] = rew, term, trunc
                    per_env[i] = info
        with gc_paused():
            for i in resets:
                obs, info = self._reset_sub(i)
                self._observations[i] = obs
                per_env[i] = info
        if resets:
            self._sync_batch(resets)
        info = self._assemble_info(per_env, on, resets, kin, task)
        self._autoreset = terminations | truncations
        return self._observations.copy(), rewards, terminations, truncations, info

    def _finish_batch(self, on, frames, poses, rewards, terminations, truncations) -> dict[str, Any] | None:
        """``_finish_step`` of the stepped sub-envs at once when their class has a ``_task_batch``:
        observations, rewards and ends written into the given arrays; returns the task's info as
        columns over ``on`` (``None``: no batched task, step them one by one)."""
        full = len(on) == self.num_envs
        envs = self.envs if full else [self.envs[i] for i in on]
        rows = slice(None) if full else np.asarray(on, dtype=np.int64)  # (a list index costs a conversion)
        task_batch = type(envs[0])._task_batch
        out = None if task_batch is None else task_batch(envs, poses[rows], self._batch.stepped_contacts)
        if out is None:
            return None
        terms, terminated, info = out
        steps = np.empty(len(on), np.int64)
        for r, e in enumerate(envs):
            e._steps += 1
            steps[r] = e._steps
        if self.layout.frame_stack == 1:
            self._observations[rows] = frames  # what ObservationBuilder.push returns then
        else:
            for r, e in enumerate(envs):
                self._observations[on[r]] = e._obs.push(frames[r : r + 1])[0]
        reward = np.zeros(len(on))
        for v in terms.values():  # float(sum(terms.values())): the same additions in the same order
            reward = reward + v
        rewards[rows] = reward
        terminated = np.asarray(terminated, dtype=np.bool_)
        terminations[rows] = terminated
        truncations[rows] = (steps >= self.config.max_steps) & ~terminated
        info["reward_terms"] = terms
        return info

    def _wheel_speeds(self, acts: np.ndarray, on: list[int]) -> np.ndarray:
        """``(K, n_robots, 2)`` wheel speeds, rad/s (rows of resetting sub-envs zero): what each
        sub-env's ``_wheel_speeds`` gives, with the learners' actions checked all at once."""
        k, n, envs = self.num_envs, self._n_robots, self.envs
        where = f"{self.config.env_id} vector env"
        adapter = envs[0]._actions
        if adapter.action_type == "continuous":
            try:
                a = np.asarray(acts, dtype=np.float64)
            except (TypeError, ValueError) as e:
                raise ValueError(f"{where}: actions must be numbers, shape ({k}, 2)") from e
            if a.shape != (k, 2):
                raise ValueError(f"{where}: actions must have shape ({k}, 2), got {a.shape}")
            if not np.isfinite(a if len(on) == k else a[on]).all():
                bad = ~np.isfinite(a[on]).all(axis=1)
                i = on[int(np.flatnonzero(bad)[0])]
                raise ValueError(f"{where}: actions[{i}] must be finite numbers, got {a[i].tolist()}")
            learner = np.clip(a, -1.0, 1.0)
        else:
            learner = np.zeros((k, 2))
            for i in on:
                learner[i] = adapter.one(acts[i], f"actions[{i}]")
        wheels = np.zeros((k, n, 2))
        wheels[:, 0] = learner
        if type(envs[0])._other_wheels is not SingleRobotEnv._other_wheels:
            for i in on:  # scripted robots: per sub-env (their own scans and RNG draws)
                wheels[i, 1:] = envs[i]._other_wheels(envs[i]._last_scan)
        wheels *= envs[0].world.scene.robot.max_wheel_speed
        return wheels

    def _sense(self, on: list[int], combined: Scan, poses: np.ndarray):
        """Detector, kin truth and observation frames of the stepped sub-envs, all at once."""
        k_on, n = len(on), self._n_robots
        m = combined.ranges.shape[0] // k_on  # rows scanned per world (the learner's is row 0)
        learner = slice(None, None, m)
        ranges = combined.ranges[learner]
        # (k_on * n, 3): robot r of stepped env e at e*n + r
        flat_poses = (poses if k_on == self.num_envs else poses[on]).reshape(-1, 3)
        world_of_robot = np.repeat(np.arange(k_on), n)
        observers = np.arange(k_on) * n
        angles = combined.angles
        dets = feed = None
        kin: dict[str, tuple[dict[str, np.ndarray], np.ndarray]] = {}
        if self.detector is not None:
            if first_feeder := self.envs[0]._feeder:
                (row, cols), feed = first_feeder.detect(ranges, angles, observers, flat_poses, world_of_robot,
                                                        combined.range_max)  # fmt: skip
            else:
                # matched to each world's robots and padded in one compiled call (detect_rows' general
                # path and pad_rows, bit for bit), unless the detector gives its rows out of order
                owner, tab = detection_arrays(self.detector, ranges, angles, True)
                glued = match_pad_worlds(owner, tab, flat_poses, n, self.config.max_detections)
                if glued is not None:
                    dets, kin["kin_detections"] = glued
                else:
                    row, cols = detect_rows(self.detector, ranges, angles, observers, flat_poses,
                                            robot_world=world_of_robot, trusted=True)  # fmt: skip
            if dets is None:
                ki = cols["kin_index"]
                cols["kin_index"] = np.where(ki >= 0, ki - row * n, -1)
                dets = (row, cols)
        # kin truth of all learners in one call: a virtual scan whose robot indices are global
        stacked = Scan(
            ranges=ranges, angles=angles, hit_kind=combined.hit_kind[learner],
            hit_index=combined.hit_index[learner] + observers[:, None].astype(np.int32),
            true_ranges=combined.true_ranges[learner], robots=observers,
            poses=combined.poses[learner], range_max=combined.range_max,
        )  # fmt: skip
        t_cols, t_count = kin_truth_padded(stacked, flat_poses, self._truth_slots)
        # global robot index -> the sub-env's own (filled slots only; empty ones keep the pad value)
        idx = t_cols["index"]
        filled = np.arange(idx.shape[1]) < t_count[:, None]
        np.subtract(idx, (np.arange(k_on) * n)[:, None], out=idx, where=filled)
        kin["kin_truth"] = (t_cols, t_count)
        obs_rows = dets
        if self._tracks is not None:
            on_a = np.asarray(on, np.int64)
            deltas = np.stack([self.envs[i].world.odometry_delta[LEARNER] for i in on])
            self._tracks.update(stacked, dets, on_a, deltas, self.envs[on[0]].world.config.control_dt, feed)
            cols, count = track_info(self._tracks, self.config.max_tracks)
            # every sub-env stepped (``on`` is then 0..K-1): track_info's fresh columns as they are
            kin["kin_tracks"] = ((cols, count) if len(on) == self.num_envs
                                 else ({f: c[on_a] for f, c in cols.items()}, count[on_a]))  # fmt: skip
            if self.config.obs_tracks:
                t_angles = self.config.track_angles(angles)
                t_row, t_c = track_rows(self._tracks, self.config.max_tracks, t_angles)
                pos = np.full(self.num_envs, -1, np.int64)
                pos[on_a] = np.arange(on_a.size)
                keep = pos[t_row] >= 0
                obs_rows = (pos[t_row[keep]], {f: c[keep] for f, c in t_c.items()})
        frames = self.envs[0]._obs.frame(ranges, obs_rows)
        if dets is not None and "kin_detections" not in kin:
            kin["kin_detections"] = pad_rows(*dets, k_on, self.config.max_detections)
        # what each sub-env keeps of this step (for the scripted kin and rendering)
        keep = self.render_mode is not None
        # a sub-env's own scan is read only by scripted robots (KinFollow's kin) and rendering
        need_scan = keep or type(self.envs[0])._other_wheels is not SingleRobotEnv._other_wheels
        if not need_scan:  # (rows of poses handed out by iteration: views at C speed)
            for env, p in zip(self.envs if len(on) == self.num_envs else [self.envs[i] for i in on],
                              poses if len(on) == self.num_envs else poses[on], strict=True):  # fmt: skip
                env._current_poses = p
                env._last_scan = None
            return frames, kin
        for r, i in enumerate(on):
            env = self.envs[i]
            env._current_poses = poses[i]
            sl = slice(r * m, (r + 1) * m)
            env._last_scan = Scan(
                ranges=combined.ranges[sl], angles=angles, hit_kind=combined.hit_kind[sl],
                hit_index=combined.hit_index[sl], true_ranges=combined.true_ranges[sl],
                robots=combined.robots[sl], poses=combined.poses[sl], range_max=combined.range_max,
            )  # fmt: skip
            if keep and dets is not None:
                sel = dets[0] == r
                env._last_detections = (
                    np.zeros(int(sel.sum()), dtype=np.int64),
                    {f: c[sel] for f, c in dets[1].items()},
                )
            else:
                env._last_detections = None
        return frames, kin

    def _assemble_info(self, per_env, on, resets, kin, task=None) -> dict[str, Any]:
        """The stacked info, equal to ``SyncVectorEnv``'s: kin entries written as (K, slots)
        arrays, the task entries from ``task``'s columns (the stepped sub-envs) and the reset
        sub-envs' infos, or stacked per key."""
        k = self.num_envs

        def rest(d):
            # nor the kin entries' "_count"s
            return {key: v for key, v in d.items() if key not in _KIN_KEYS and key[:-6] not in _KIN_KEYS}

        if task is None:
            info = stack_infos([rest(d) for d in per_env])
        else:
            reset_infos = [rest(per_env[i]) for i in resets]
            for d in reset_infos:
                if d.keys() != task.keys():
                    raise RuntimeError(
                        f"{self.config.env_id} vector env: a reset's info keys {sorted(d)} differ from a "
                        f"step's {sorted(task)}; _task_batch must give the keys _task gives"
                    )
            info = _merge_columns(task, on, resets, reset_infos, k)
        layout = [("kin_truth", KIN_TRUTH_FIELDS, self._truth_slots)]
        if self.detector is not None:
            layout.append(("kin_detections", DETECTION_FIELDS, self.config.max_detections))
        if self._tracks is not None:
            from detectors.tracking import TRACK_FIELDS

            layout.append(("kin_tracks", TRACK_FIELDS, self.config.max_tracks))
        full = not resets and len(on) == k  # every sub-env stepped: the (K, ...) columns as they come
        for key, fields, slots in layout:
            # the "_field" masks: rows of one block (each its own array to the caller)
            masks = iter(np.ones((len(fields) + 2, k), dtype=np.bool_))
            nested: dict[str, Any] = {}
            kc, kn = kin[key] if on else ({}, None)
            if full and all(_fresh_column(kc[f], f, (k, slots)) for f in fields) and kn.dtype == np.int64:
                # fresh arrays of this step (kernels' blocks, fancy-indexed copies) of the dtypes
                # stack_infos makes: what the copies below would hold
                for f in fields:
                    nested[f], nested[f"_{f}"] = kc[f], next(masks)
                count = kn
            else:
                cols = {
                    f: np.empty((k, slots), dtype=np.int64 if f in INT_FIELDS else np.float64) for f in fields
                }
                count = np.zeros(k, dtype=np.int64)
                if on:
                    for f, c in cols.items():
                        c[on] = kc[f]
                    count[on] = kn
                for i in resets:
                    for f, c in cols.items():
                        c[i] = per_env[i][key][f]
                    count[i] = per_env[i][f"{key}_count"]
                for f, c in cols.items():
                    nested[f], nested[f"_{f}"] = c, next(masks)
            info[key], info[f"_{key}"] = nested, next(masks)
            info[f"{key}_count"], info[f"_{key}_count"] = count, next(masks)
        return info

    def render(self):
        if self.render_mode is None:
            return None
        return tuple(e.render() for e in self.envs)

    def close_extras(self, **kwargs: Any) -> None:
        for e in self.envs:
            e.close()


def _fresh_column(c: np.ndarray, field: str, shape: tuple[int, int]) -> bool:
    """``c`` can be handed out as the stacked info's ``field`` column as it is (its dtype and shape)."""
    return c.shape == shape and c.dtype == (np.int64 if field in INT_FIELDS else np.float64)


def _merge_columns(cols: dict[str, Any], on: list[int], resets: list[int], reset_infos: list[dict],
                   k: int) -> dict[str, Any]:  # fmt: skip
    """What :func:`stack_infos` gives for K infos when the rows ``on`` are given as columns (arrays of
    the dtype ``stack_infos`` makes, nested dicts alike) and the rows ``resets`` as per-env infos."""
    out: dict[str, Any] = {}
    for key, col in cols.items():
        vals = [d[key] for d in reset_infos]
        if isinstance(col, dict):
            out[key] = _merge_columns(col, on, resets, vals, k)
        elif not resets and len(on) == k:
            out[key] = col.copy()  # (the task's columns may share arrays: is_success, terminated)
        else:
            arr = np.empty(k, dtype=col.dtype)
            arr[on] = col
            if resets:
                arr[resets] = vals
            out[key] = arr
        out[f"_{key}"] = np.ones(k, dtype=np.bool_)
    return out


def _widen(info: dict[str, Any], ids: list[int], k: int) -> dict[str, Any]:
    """A stacked info of the sub-envs ``ids`` as K rows (others zero, masks False)."""
    out: dict[str, Any] = {}
    for key, v in info.items():
        if isinstance(v, dict):
            out[key] = _widen(v, ids, k)
            continue
        full = np.zeros((k, *v.shape[1:]), dtype=v.dtype) if v.dtype != object else np.full(k, None)
        full[ids] = v
        out[key] = full
    return out


class KinSeekVectorEnv(KinVectorEnv):
    """K ``KinSeek-v2`` envs stepped together (``gymnasium.make_vec("kin_envs/KinSeek-v2", K)``).

    ## Description

    The task of :class:`kin_envs.envs.kin_seek.KinSeekEnv` K times, with one batch of physics,
    one lidar call and one detector call per step for all K sub-envs (the module docstring says how).
    Returns exactly what
    ``make_vec("kin_envs/KinSeek-v2", K, vectorization_mode="sync")`` returns for the same seeds and
    actions (tested across autoresets).

    ## Action Space

    ``batch_space`` of the single env's: ``Box(-1, 1, (K, 2), float32)`` (normalised left / right
    wheel speeds per sub-env), or ``MultiDiscrete([5] * K)`` with ``action_type="discrete"``;
    ``single_action_space`` is one sub-env's.

    ## Observation Space

    ``batch_space`` of the single env's: float32 ``(K, D)``, row ``i`` sub-env ``i``'s observation as
    in ``KinSeekEnv`` (same bounds; ``D`` = 360 per frame plus the detector channel, times
    ``frame_stack``); ``single_observation_space`` is one row.

    ## Rewards

    ``(K,)`` float64: each sub-env's reward as in ``KinSeekEnv`` (0 on the step that autoresets it).

    ## Starting State

    ``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (or takes a list of K seeds), each starting
    as in ``KinSeekEnv``; ``options={"reset_mask": mask}`` (a ``(K,)`` bool array) resets only those
    sub-envs (the first reset resets all).

    ## Episode End

    ``(K,)`` terminations and truncations as in ``KinSeekEnv``. Autoreset is Gymnasium's ``NEXT_STEP``:
    the step after a sub-env ends resets it (its action ignored, reward 0, not done).

    ## Arguments

    ``num_envs`` (K >= 1), ``render_mode`` (``None`` or ``"rgb_array"``: ``render()`` returns K
    frames) and every argument of ``KinSeekEnv``, the same for all sub-envs (one detector object is
    shared). The info is the single env's, stacked with ``_key`` masks (``(K, slots)`` columns).

    ## Version History

    * v2: the native vector env of ``KinSeek-v2``, with the single env's version and behaviour.
    * v1: the native vector env of ``KinSeek-v1`` (:class:`KinSeekVectorEnvV1`).
    """

    env_class: ClassVar[type[SingleRobotEnv]] = KinSeekEnv


class KinFollowVectorEnv(KinVectorEnv):
    """K ``KinFollow-v2`` envs stepped together (``gymnasium.make_vec("kin_envs/KinFollow-v2", K)``).

    ## Description

    The task of :class:`kin_envs.envs.kin_follow.KinFollowEnv` K times, with one batch of physics,
    one lidar call and one detector call per step for all K sub-envs (the module docstring says how).
    Returns exactly what
    ``make_vec("kin_envs/KinFollow-v2", K, vectorization_mode="sync")`` returns for the same seeds and
    actions (tested across autoresets).

    ## Action Space

    ``batch_space`` of the single env's: ``Box(-1, 1, (K, 2), float32)`` (normalised left / right
    wheel speeds per sub-env), or ``MultiDiscrete([5] * K)`` with ``action_type="discrete"``;
    ``single_action_space`` is one sub-env's.

    ## Observation Space

    ``batch_space`` of the single env's: float32 ``(K, D)``, row ``i`` sub-env ``i``'s observation as
    in ``KinFollowEnv`` (same bounds; ``D`` = 360 per frame plus the detector channel, times
    ``frame_stack``); ``single_observation_space`` is one row.

    ## Rewards

    ``(K,)`` float64: each sub-env's reward as in ``KinFollowEnv`` (0 on the step that autoresets it).

    ## Starting State

    ``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (or takes a list of K seeds), each starting
    as in ``KinFollowEnv``; ``options={"reset_mask": mask}`` (a ``(K,)`` bool array) resets only those
    sub-envs (the first reset resets all).

    ## Episode End

    ``(K,)`` terminations and truncations as in ``KinFollowEnv``. Autoreset is Gymnasium's ``NEXT_STEP``:
    the step after a sub-env ends resets it (its action ignored, reward 0, not done).

    ## Arguments

    ``num_envs`` (K >= 1), ``render_mode`` (``None`` or ``"rgb_array"``: ``render()`` returns K
    frames) and every argument of ``KinFollowEnv``, the same for all sub-envs (one detector object is
    shared). The info is the single env's, stacked with ``_key`` masks (``(K, slots)`` columns).

    ## Version History

    * v2: the native vector env of ``KinFollow-v2``, with the single env's version and behaviour.
    * v1: the native vector env of ``KinFollow-v1`` (:class:`KinFollowVectorEnvV1`).
    """

    env_class: ClassVar[type[SingleRobotEnv]] = KinFollowEnv


class KinSeekVectorEnvV1(KinSeekVectorEnv):
    """``gymnasium.make_vec("kin_envs/KinSeek-v1", num_envs=K)``: :class:`KinSeekVectorEnv` over
    :class:`kin_envs.envs.kin_seek.KinSeekEnvV1` (``tracker=True`` feeds the tracker ``"accepted"``)."""

    env_class: ClassVar[type[SingleRobotEnv]] = KinSeekEnvV1


class KinFollowVectorEnvV1(KinFollowVectorEnv):
    """``gymnasium.make_vec("kin_envs/KinFollow-v1", num_envs=K)``: :class:`KinFollowVectorEnv` over
    :class:`kin_envs.envs.kin_follow.KinFollowEnvV1` (``tracker=True`` feeds the tracker ``"accepted"``)."""

    env_class: ClassVar[type[SingleRobotEnv]] = KinFollowEnvV1
