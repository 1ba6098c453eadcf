"""aggregation_v2 / v0 steps: the compiled detection glue (sort, match and pad in one call), the per-agent
info dicts from ``row_infos`` and the compiled kin counts give exactly the previous code's episodes
(observations, rewards, ends, infos with their dtypes, shapes and key order), and every step hands out
fresh arrays. The previous code is kept here as the oracle."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from kin_envs.envs.aggregation import AggregationEnv, AggregationEnvV0
from kin_envs.envs.common import detect_rows, kin_truth_rows, split_rows
from kin_envs.envs.info import DETECTION_FIELDS, pad_rows, row_infos

from .helpers import assert_same


class _Previous:
    """``_sense`` and ``_kin_counts`` as they were before the compiled glue (session 8 of issue 14)."""

    def _kin_counts(self):
        p = self._last_scan.poses
        dx = p[:, None, 0] - p[None, :, 0]
        dy = p[:, None, 1] - p[None, :, 1]
        n = np.count_nonzero(dx * dx + dy * dy <= self.config.kin_radius**2, axis=1) - 1
        return np.minimum(n, self.config.max_kin_counted), n

    def _sense(self, first: bool = False):
        scan = self.world.scan()
        self._last_scan = scan
        poses, n = scan.poses, scan.ranges.shape[0]
        truth = kin_truth_rows(scan, poses)
        dets = feed = None
        if self._feeder is not None:
            dets, feed = self._feeder.detect(scan.ranges, scan.angles, scan.robots, poses,
                                             range_max=scan.range_max)  # fmt: skip
        elif self.detector is not None:
            dets = detect_rows(self.detector, scan.ranges, scan.angles, scan.robots, poses, trusted=True)
        self._last_detections = dets
        entries = {}
        if self.tracker is not None:
            from kin_envs.envs.tracks import track_info, track_update

            delta = np.zeros((n, 3)) if first else self.world.odometry_delta
            track_update(self.tracker, scan, dets, delta, self.world.config.control_dt, feed)
            entries["kin_tracks"] = track_info(self.tracker, self.config.max_tracks)
        if self.padded_info:
            entries["kin_truth"] = pad_rows(*truth, n, self.config.max_kin_truth)
            if dets is not None:
                entries["kin_detections"] = pad_rows(*dets, n, self.config.max_detections)
            infos = {a: {} for a in self.possible_agents}
            for key, (cols, count) in entries.items():
                names, key_count = tuple(cols), f"{key}_count"
                rows = zip(*map(list, cols.values()), strict=True)
                for info, vals, c in zip(infos.values(), rows, count.tolist(), strict=True):
                    info[key] = dict(zip(names, vals, strict=True))
                    info[key_count] = c
        else:
            truth_rows = split_rows(*truth, n)
            det_rows = split_rows(*dets, n) if dets is not None else None
            infos = {}
            for i, a in enumerate(self.possible_agents):
                info = {"kin_truth": truth_rows[i]}
                if det_rows is not None:
                    info["kin_detections"] = det_rows[i]
                if "kin_tracks" in entries:
                    cols, count = entries["kin_tracks"]
                    info["kin_tracks"] = {f: c[i] for f, c in cols.items()}
                    info["kin_tracks_count"] = int(count[i])
                infos[a] = info
        return self._obs.frame(scan.ranges, dets), infos


class _PreviousV1(_Previous, AggregationEnv):
    pass


class _PreviousV0(_Previous, AggregationEnvV0):
    pass


def assert_same_ordered(a, b, path: str = "") -> None:
    """:func:`assert_same` plus the same key order in every dict."""
    if isinstance(a, dict):
        assert list(a) == list(b), f"{path}: key order {list(a)} != {list(b)}"
        for k in a:
            assert_same_ordered(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, list | tuple):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same_ordered(x, y, f"{path}[{i}]")
    assert_same(a, b, path)


def _episode_pair(new_cls, old_cls, seed: int, **kw) -> tuple[int, int]:
    """Run both envs through a whole episode and a reset with the same seed and actions, comparing every
    output; returns (steps, detections seen)."""
    new, old = new_cls(**kw), old_cls(**kw)
    assert_same_ordered(new.reset(seed=seed), old.reset(seed=seed))
    rng = np.random.default_rng(seed)
    steps = n_det = 0
    while new.agents:
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in new.agents}
        out = new.step(acts)
        assert_same_ordered(out, old.step(acts), f"step {steps}")
        infos = out[4]
        if new.padded_info and new.detector is not None:
            n_det += sum(int(i["kin_detections_count"]) for i in infos.values())
        steps += 1
    assert_same_ordered(new.reset(seed=seed + 1), old.reset(seed=seed + 1))
    return steps, n_det


@pytest.mark.parametrize("detector", [None, "geometric", "learned"])
def test_v1_episodes_are_the_previous_codes(detector):
    if detector == "learned":
        pytest.importorskip("torch")
    n_det = 0
    for n_robots, seed in ((2, 0), (9, 1), (64, 2), (64, 3)):
        steps, d = _episode_pair(AggregationEnv, _PreviousV1, seed, n_robots=n_robots, detector=detector,
                                 noise_sigma=0.01, max_cycles=25)  # fmt: skip
        assert steps == 25
        n_det += d
    if detector is not None:
        assert n_det > 500  # detections were compared, not only empty slots


@pytest.mark.parametrize(
    "kw",
    [
        {"obs_detections": "topk", "max_detections": 3, "max_kin_truth": 2},  # overfull rows
        {"obs_detections": "mask", "frame_stack": 2, "action_type": "continuous"},
        {"tracker": True},
        {"tracker": {"feed": "permissive"}, "max_detections": 4},  # the feeder's rows through pad_rows
    ],
)
def test_v1_options_give_the_previous_episodes(kw):
    _episode_pair(AggregationEnv, _PreviousV1, 5, n_robots=12, detector="geometric", noise_sigma=0.01,
                  max_cycles=15, **kw)  # fmt: skip


@pytest.mark.parametrize("detector", [None, "geometric"])
def test_v0_episodes_are_the_previous_codes(detector):
    _episode_pair(AggregationEnvV0, _PreviousV0, 4, n_robots=16, detector=detector, noise_sigma=0.01,
                  max_cycles=15, **({"tracker": True} if detector else {}))  # fmt: skip


def test_swarm_infos_and_observations_are_fresh_every_step():
    # nothing handed out by a step is written by a later one, and consecutive steps share no memory
    env = AggregationEnv(n_robots=16, detector="geometric", noise_sigma=0.01, max_cycles=30,
                         obs_detections="topk")  # fmt: skip
    kept = [env.reset(seed=7)]
    copies = [copy.deepcopy(kept[0])]
    rng = np.random.default_rng(0)
    while env.agents:
        out = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        kept.append(out)
        copies.append(copy.deepcopy(out))
    for out, snapshot in zip(kept, copies, strict=True):
        assert_same_ordered(out, snapshot)
    a, b = kept[-2][-1]["robot_3"], kept[-1][-1]["robot_3"]
    for key in ("kin_truth", "kin_detections"):
        for f in a[key]:
            assert not np.shares_memory(a[key][f], b[key][f]), (key, f)
    assert sum(o[-1]["robot_0"]["kin_detections_count"] for o in kept[1:]) + sum(
        o[-1]["robot_5"]["kin_detections_count"] for o in kept[1:]) > 0


def test_row_infos_is_the_per_row_loop():
    rng = np.random.default_rng(0)
    n, slots = 7, 4
    ints = ("first_beam", "kin_index")
    det = {f: rng.integers(-1, 9, (n, slots)) if f in ints else rng.normal(size=(n, slots))
           for f in DETECTION_FIELDS}  # fmt: skip
    truth = {"index": rng.integers(0, 9, (n, 2)), "range": rng.normal(size=(n, 2))}
    entries = {"kin_truth": (truth, rng.integers(0, 3, n)), "kin_detections": (det, rng.integers(0, 5, n))}
    got = row_infos(entries)
    assert len(got) == n
    for i, info in enumerate(got):
        ref = {}
        for key, (cols, count) in entries.items():
            ref[key] = {f: c[i] for f, c in cols.items()}
            ref[f"{key}_count"] = int(count[i])
        assert_same_ordered(info, ref)
        assert type(info["kin_detections_count"]) is int
        assert np.shares_memory(info["kin_detections"]["range"], det["range"])  # views, not copies
    with pytest.raises(ValueError, match="at least one entry"):
        row_infos({})
