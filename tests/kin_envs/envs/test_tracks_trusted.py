"""kin_envs.envs.tracks: the envs' tracker path on the tracker's trusted entry (points built in the update's
compiled call) and the one-copy info columns give bitwise what the public path gives (``update_batch`` on
``segment_points``, a copy per info field): every observation, reward and info, and the tracker's state."""

import gymnasium as gym
import numpy as np
import pytest

import kin_envs  # noqa: F401  (registers the ids)
from detectors.tracking import TRACK_FIELDS, KinTracker, segment_points
from kin_envs import aggregation_v2
from kin_envs.envs import tracks
from kin_envs.envs.info import pad_rows


def _public_update(tracker, scan, obs, row, x, y, scores, accepted, first, last, delta, dt, noise):
    """The path the envs took before the trusted entry: segment_points, then update_batch."""
    pts, own = segment_points(scan.ranges, scan.angles, row, first, last, scan.range_max)
    acc = np.ones(len(obs), bool) if accepted is None else accepted
    tracker.update_batch(np.asarray(obs, np.int64), np.c_[x, y], scores, delta, dt, pts, own, noise,
                         accepted=acc)  # fmt: skip


def _public_info(tracker, max_tracks):
    a = tracker.track_arrays(max_tracks)
    return {name: a["tracks"][:, :, j].astype(np.float64) for j, name in enumerate(TRACK_FIELDS)}, a["count"]


def _tracker_state(env):
    u = env.unwrapped
    tr = u._tracks.tracker if getattr(u, "_tracks", None) is not None else u.tracker
    return [getattr(tr, n) for n in ("_F", "_I", "_B", *KinTracker._FIELDS)] + [tr.poses, tr.odometer]


def _assert_same(a, b, path="out"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b, strict=True)):
            _assert_same(u, v, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, path
        assert a.tobytes() == b.tobytes(), path
        assert a.flags.c_contiguous == b.flags.c_contiguous, path
    else:
        assert a == b or (a != a and b != b), (path, a, b)


def _make(kind, detector, feed):
    kw = {"detector": detector, "tracker": {"feed": feed}, "noise_sigma": 0.01}
    if kind == "aggregation_v2":
        return aggregation_v2.parallel_env(n_robots=10, max_cycles=25, obs_tracks=True, obs_detections="topk",
                                           **kw)  # fmt: skip
    # small, no noise: the kin comes into view and the geometric detector accepts it
    kw.update(obs_tracks=True, obs_detections="topk", arena_size=2.5, noise_sigma=0.0)
    if kind == "vector":
        return gym.make_vec("kin_envs/KinSeek-v2", num_envs=4, **kw)
    return gym.make(f"kin_envs/{kind}", **kw)


def _run(kind, detector, feed, steps=36):
    env = _make(kind, detector, feed)
    rng = np.random.default_rng(4)
    out = [env.reset(seed=11)]
    for _ in range(steps):
        if kind == "aggregation_v2":
            res = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
            if not env.agents:
                env.reset(seed=int(rng.integers(1000)))
        else:
            res = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            if kind != "vector" and (res[2] or res[3]):
                env.reset(seed=int(rng.integers(1000)))
        out += [res, _tracker_state(env)]
    env.close()
    return out


@pytest.mark.parametrize("kind", ["aggregation_v2", "KinSeek-v2", "KinFollow-v2", "vector"])
@pytest.mark.parametrize("detector, feed", [("geometric", "accepted"), ("geometric", "permissive"),
                                            ("geometric", "auto"), ("learned", "accepted"),
                                            ("learned", "permissive"), ("learned", "auto")])  # fmt: skip
def test_env_tracker_path_is_bitwise_the_public_path(kind, detector, feed, monkeypatch):
    new = _run(kind, detector, feed)
    assert any(np.count_nonzero(state[2][0]) for state in new[2::2])  # tracks to compare: some were alive
    monkeypatch.setattr(tracks, "_update", _public_update)
    monkeypatch.setattr(tracks, "track_info", _public_info)
    if kind == "vector":
        import kin_envs.envs.vector as vector

        monkeypatch.setattr(vector, "track_info", _public_info)
    old = _run(kind, detector, feed)
    _assert_same(new, old)


def test_track_info_is_a_copy_per_field():
    """One transposed copy: each field a C-contiguous float64 array of the per-field copy's values, none
    sharing memory with the tracker's arrays or with another field."""
    env = aggregation_v2.parallel_env(n_robots=8, detector="geometric", tracker=True)
    env.reset(seed=2)
    for _ in range(12):
        env.step({a: np.ones(2, np.float32) for a in env.agents})
    tr = env.tracker
    cols, count = tracks.track_info(tr, 4)
    ref, ref_count = _public_info(tr, 4)
    _assert_same((cols, count), (ref, ref_count))
    assert list(cols) == list(TRACK_FIELDS)
    for name, c in cols.items():
        assert c.flags.c_contiguous and c.dtype == np.float64 and c.shape == (8, 4), name
        assert not np.shares_memory(c, tr.track_arrays(4)["tracks"])
    cols["x"][:] = 123.0  # writing one field leaves the others
    assert not np.any(cols["y"] == 123.0)


def _births_numpy(alive, tid, tobs, first, next_local):
    """The vector tracker's birth numbering as numpy did it before the compiled ``_births``."""
    rows = np.flatnonzero(alive & (tid >= first))
    rows = rows[np.argsort(tid[rows], kind="stable")]
    o = tobs[rows]
    order = np.argsort(o, kind="stable")
    o_s = o[order]
    start = np.searchsorted(o_s, o_s)
    lid = np.empty(rows.size, np.int64)
    lid[order] = next_local[o_s] + np.arange(rows.size) - start
    np.add.at(next_local, o, 1)
    return o, tid[rows], lid


@pytest.mark.parametrize("seed", range(6))
def test_vector_births_are_the_numpy_numbering(seed):
    rng = np.random.default_rng(seed)
    cap, k = int(rng.integers(1, 300)), int(rng.integers(1, 20))
    alive = rng.random(cap) < 0.6
    tid = rng.permutation(cap * 2)[:cap].astype(np.int64)  # distinct ids, in any row order
    tobs = rng.integers(0, k, cap).astype(np.int64)
    first = int(rng.integers(0, cap * 2))
    nl_a = rng.integers(0, 50, k).astype(np.int64)
    nl_b = nl_a.copy()
    got = tracks._births(alive, tid, tobs, first, nl_a)
    want = _births_numpy(alive, tid, tobs, first, nl_b)
    _assert_same(list(got), list(want))
    _assert_same(nl_a, nl_b)


def _feed_from_segments(feed, ranges, angles, observers, poses, robot_world):
    """The permissive feed as it was built before the fused call: the shipped detections from the detector's
    ``BatchDetections`` (``_detect_arrays_trusted``), the candidates from its per-segment arrays."""
    from detectors._kernels import ACCEPTED, SHAPE
    from detectors.features import scan_noise_of
    from kin_envs.envs.common import detect_rows

    class Given:
        def _detect_arrays_trusted(self, ranges, angles):
            return b

    n = angles.shape[0]
    b = feed.detector._detect_arrays_trusted(ranges, angles)
    dets = detect_rows(Given(), ranges, angles, observers, poses, robot_world, trusted=True)
    st, F = b.seg_stage, b.seg_values["F"]
    idx = np.flatnonzero(((st == ACCEPTED) | (st == SHAPE)) & (F < feed._f_perm))
    rc, bearing, f = b.seg_values["r_c"][idx], b.seg_values["theta_c"][idx], F[idx]
    row, first = b.seg_scan[idx], b.seg_first[idx]
    last = (first + b.seg_count[idx] - 1) % n
    est, count = scan_noise_of(ranges, angles)
    est = np.where(count >= 5, est, np.nan)
    noise = np.where(np.isnan(est), feed.range_noise, est)
    return dets, (row, rc * np.cos(bearing), rc * np.sin(bearing), feed._f_perm / (feed._f_perm + f),
                  st[idx] == ACCEPTED, first, last, noise)  # fmt: skip


@pytest.mark.parametrize("kind", ["aggregation_v2", "vector"])
def test_permissive_feed_is_the_detector_arrays_feed(kind, monkeypatch):
    """The geometric detector's one-call permissive feed (``_detect_table_feed_trusted``: the shipped
    detections' table and the segments whose fit reached the permissive threshold from one compiled call) is
    bitwise the feed built from its ``BatchDetections`` of every segment: the shipped detections and every
    candidate array (noisy swarm and vector env scans, with SHAPE-stage candidates among them); the swarm's
    ``detect_padded`` gives ``pad_rows`` of those detections too."""
    seen = {"calls": 0, "shape": 0, "accepted": 0}
    detect = tracks.PermissiveFeed.detect

    def checked(self, ranges, angles, observers, poses, robot_world=None, range_max=np.inf):
        out = detect(self, ranges, angles, observers, poses, robot_world, range_max)
        _assert_same(out, _feed_from_segments(self, ranges, angles, observers, poses, robot_world))
        acc = out[1][4]
        seen["calls"] += 1
        seen["shape"] += int(np.count_nonzero(~acc))
        seen["accepted"] += int(np.count_nonzero(acc))
        return out

    detect_padded = tracks.PermissiveFeed.detect_padded

    def checked_padded(self, ranges, angles, observers, poses, slots, hits=None, range_max=np.inf):
        dets, padded, feed = detect_padded(self, ranges, angles, observers, poses, slots, hits, range_max)
        ref_dets, ref_feed = _feed_from_segments(self, ranges, angles, observers, poses, None)
        _assert_same((dets, padded, feed), (ref_dets, pad_rows(*ref_dets, len(ranges), slots), ref_feed))
        seen["calls"] += 1
        seen["shape"] += int(np.count_nonzero(~feed[4]))
        seen["accepted"] += int(np.count_nonzero(feed[4]))
        return dets, padded, feed

    monkeypatch.setattr(tracks.PermissiveFeed, "detect", checked)
    monkeypatch.setattr(tracks.PermissiveFeed, "detect_padded", checked_padded)
    if kind == "vector":
        env = gym.make_vec("kin_envs/KinSeek-v2", num_envs=4, detector="geometric", tracker=True,
                           noise_sigma=0.01, arena_size=2.5)  # fmt: skip
        env.reset(seed=5)
        rng = np.random.default_rng(1)
        for _ in range(20):
            env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    else:
        env = aggregation_v2.parallel_env(n_robots=12, detector="geometric", tracker=True, noise_sigma=0.005)
        env.reset(seed=5)
        rng = np.random.default_rng(1)
        for _ in range(20):
            env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    env.close()
    assert seen["calls"] >= 20 and seen["shape"] > 0 and seen["accepted"] > 0, seen
