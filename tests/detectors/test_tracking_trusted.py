"""detectors.tracking: the envs' trusted entry (``KinTracker._update_segments_trusted``: the candidates'
points built from the scan in the update's compiled call) is bitwise ``update_batch`` on
``segment_points``."""

import math

import numpy as np
import pytest

from detectors.tracking import KinTracker, TrackerParams, segment_points

DT = 0.1
N_BEAMS = 360


def _scan_frames(seed, n_obs=4, n_frames=14, dtype=np.float64):
    """Frames of ``n_obs`` observers, each seeing a few round objects at nearly fixed robot-frame positions:
    ``(obs, rows, x, y, scores, accepted, delta, ranges, angles, first, last)``; some segments wrap at the
    seam (an object at bearing ~0), some readings inside a segment are no return (inf, 0, NaN, >= range_max),
    some observers see nothing, some candidates score below ``min_score``."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(-math.pi, math.pi, N_BEAMS, endpoint=False)
    # each observer's objects: (range, bearing); bearing 0 sits at the seam's far side (beam 180) and
    # bearing -pi at beam 0: a segment centred there wraps
    objs = [[(rng.uniform(0.4, 3.0), rng.uniform(-math.pi, math.pi)) for _ in range(rng.integers(0, 6))]
            for _ in range(n_obs)]  # fmt: skip
    objs[0].append((1.2, -math.pi + 0.01))  # wraps at the seam
    for _ in range(n_frames):
        # and clutter: a few objects seen once (each starts a track: the arrays grow)
        seen = [o_ + [(rng.uniform(0.4, 3.0), rng.uniform(-math.pi, math.pi)) for _ in range(rng.integers(4))]
                for o_ in objs]  # fmt: skip
        ranges = np.full((n_obs, N_BEAMS), np.inf)
        ranges[:, ::7] = rng.uniform(4.0, 6.0, ranges[:, ::7].shape)  # walls here and there
        obs, rows, x, y, sc, first, last = [], [], [], [], [], [], []
        for o in range(n_obs):
            for r, b in seen[o]:
                if rng.random() < 0.15:  # missed this frame
                    continue
                r1, b1 = r + rng.normal(0, 0.01), b + rng.normal(0, 0.005)
                centre = int(round((b1 + math.pi) / (2 * math.pi) * N_BEAMS)) % N_BEAMS
                half = int(rng.integers(1, 5))
                beams = (centre + np.arange(-half, half + 1)) % N_BEAMS
                ranges[o, beams] = r1 + rng.normal(0, 0.005, beams.size)
                if rng.random() < 0.3:  # a no-return reading inside the segment
                    ranges[o, beams[rng.integers(beams.size)]] = [np.inf, 0.0, np.nan, 20.0][rng.integers(4)]
                obs.append(o)
                rows.append(o)
                x.append(r1 * math.cos(b1))
                y.append(r1 * math.sin(b1))
                sc.append(rng.uniform(0.0, 1.0))
                first.append(beams[0])
                last.append(beams[-1])
        sc = np.array(sc, np.float64)
        i8 = np.int64
        yield (np.array(obs, i8), np.array(rows, i8), np.array(x, np.float64), np.array(y, np.float64), sc,
               sc > 0.6, rng.normal(0, 0.01, (n_obs, 3)), ranges.astype(dtype), angles, np.array(first, i8),
               np.array(last, i8))  # fmt: skip


def _state(tr):
    return [getattr(tr, name) for name in ("_F", "_I", "_B", *KinTracker._FIELDS)] + [
        tr.poses, tr.odometer, np.array([tr.time, tr._next_id, tr._frame])]


def _same(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("seed, params, feed, dtype, read", [
    (0, {}, "accepted", np.float64, 1),
    (1, {"min_score": 0.3}, "flags", np.float64, 1),  # candidates dropped (their points stay in place)
    (2, {"max_points": 8}, "flags", np.float32, 2),  # the outline ring on; float32 scans; every other read
    (3, {"frame_fit_warm_start": 0.0, "min_score": 0.2}, "accepted", np.float64, 1),  # fits from behind
    (4, {}, "noise", np.float64, 0),  # never read: no decision in the update's call
])  # fmt: skip
def test_trusted_entry_is_bitwise_update_batch_on_segment_points(seed, params, feed, dtype, read):
    """Same state (every array, poses, odometer, time, ids), same ``track_arrays`` and the same growth of the
    arrays (from the smallest capacity) as the public path, frame after frame."""
    pr = TrackerParams(**params)
    if params.get("max_points"):
        pr = TrackerParams(**params, shape_clamp=1.0)
    n_obs = 4
    a, b = KinTracker(pr, n_observers=n_obs), KinTracker(pr, n_observers=n_obs)
    cap0 = a._alive.shape[0]
    rng = np.random.default_rng(seed + 100)
    for f, (obs, rows, x, y, sc, acc, delta, ranges, angles, first, last) in enumerate(
        _scan_frames(seed, n_obs, dtype=dtype)
    ):
        noise = rng.uniform(0.0, 0.02, n_obs) if feed == "noise" else None
        flags = acc if feed == "flags" else None
        pts, own = segment_points(ranges, angles, rows, first, last, 12.0)
        a.update_batch(obs, np.c_[x, y], sc, delta, DT, pts, own, noise,
                       accepted=np.ones(obs.size, bool) if flags is None else flags)  # fmt: skip
        b._update_segments_trusted(obs, rows, x, y, sc, flags, delta, DT, ranges, angles, first, last, 12.0,
                                   noise)  # fmt: skip
        for u, v in zip(_state(a), _state(b), strict=True):
            assert _same(u, v)
        if read and f % read == 0:
            ta, tb = a.track_arrays(4), b.track_arrays(4)
            assert all(_same(ta[k], tb[k]) for k in ("tracks", "mask", "count"))
    assert len(b) > 3
    assert b._alive.shape[0] > cap0  # grown on the way (the compiled room check)


def test_trusted_entry_raises_the_public_error_and_leaves_the_public_state():
    """A bad value (the envs' arrays are trusted for shape and dtype, not for values) raises update_batch's
    error, and the tracker is left as update_batch leaves it (its arrays grown for the frame, no value
    changed: the frame, poses, time and ids as before)."""
    obs, rows, x, y, sc, acc, delta, ranges, angles, first, last = next(_scan_frames(5))
    pts, own = segment_points(ranges, angles, rows, first, last, 12.0)
    ones = np.ones(obs.size, bool)
    a, b = KinTracker(n_observers=4), KinTracker(n_observers=4)
    a.update_batch(obs, np.c_[x, y], sc, delta, DT, pts, own, accepted=ones)
    b._update_segments_trusted(obs, rows, x, y, sc, None, delta, DT, ranges, angles, first, last, 12.0)
    frame = (b._frame, b.time, b._next_id, b.poses.copy())
    bad_x, bad_delta = x.copy(), delta.copy()
    bad_x[0], bad_delta[1, 2] = np.nan, np.inf
    for xx, dd, what in ((bad_x, delta, "must be finite"), (x, bad_delta, "odom_delta")):
        with pytest.raises(ValueError, match=what) as ea:
            a.update_batch(obs, np.c_[xx, y], sc, dd, DT, pts, own, accepted=ones)
        with pytest.raises(ValueError, match=what) as eb:
            b._update_segments_trusted(obs, rows, xx, y, sc, None, dd, DT, ranges, angles, first, last, 12.0)
        assert str(ea.value) == str(eb.value)
        assert all(_same(u, v) for u, v in zip(_state(a), _state(b), strict=True))
    assert (b._frame, b.time, b._next_id) == frame[:3] and _same(b.poses, frame[3])
