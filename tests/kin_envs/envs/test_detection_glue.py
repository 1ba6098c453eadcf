"""kin_envs.envs.common: the one-observer detection glue (compiled match, the learned detector's table
entry) gives the general path's values, and nothing a caller keeps is reused by a later step."""

import numpy as np
import pytest

from kin_envs.envs.common import (
    DETECTION_FIELDS,
    _match_one_row,
    _match_one_row_numpy,
    detect_rows,
)


def _same_cols(a, b):
    assert a.keys() == b.keys()
    for k in b:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k], equal_nan=True), k


def test_compiled_match_is_the_numpy_match():
    rng = np.random.default_rng(0)
    for trial in range(300):
        n_robots = int(rng.integers(1, 6))
        poses = np.column_stack([rng.uniform(-2, 2, (n_robots, 2)), rng.uniform(-np.pi, np.pi, n_robots)])
        obs = int(rng.integers(n_robots))
        n_det = int(rng.integers(1, 6))
        tab = np.empty((n_det, 8))
        # detections near the other robots (matches), elsewhere (no match), equal ranges (stable sort)
        others = rng.integers(n_robots, size=n_det)
        c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
        dx, dy = poses[others, 0] - poses[obs, 0], poses[others, 1] - poses[obs, 1]
        x = c * dx + s * dy + rng.normal(scale=0.08, size=n_det)
        y = c * dy - s * dx + rng.normal(scale=0.08, size=n_det)
        tab[:, 0] = np.round(np.hypot(x, y), 1 if trial % 3 == 0 else 12)
        tab[:, 1] = np.arctan2(y, x)
        tab[:, 2], tab[:, 3] = x, y
        tab[:, 4] = rng.uniform(size=n_det)
        tab[:, 5] = rng.integers(360, size=n_det)
        tab[:, 6] = rng.integers(360, size=n_det)
        tab[:, 7] = rng.integers(1, 9, size=n_det)
        if trial % 10 == 1:
            tab[0, [0, 2, 3]] = np.nan  # a degenerate centre: sorted last, never matched
        if trial % 10 == 2 and n_robots > 2:
            poses[(obs + 1) % n_robots, :2] = poses[(obs + 2) % n_robots, :2]  # a tie: the first robot
        if trial % 10 == 3 and n_robots > 1:
            poses[(obs + 1) % n_robots, 0] = np.nan  # a NaN distance: np.argmin picks it, no match
        _same_cols(_match_one_row(tab, obs, poses), _match_one_row_numpy(tab, obs, poses))


@pytest.mark.parametrize("detector", ["geometric", "learned"])
def test_trusted_one_row_glue_equals_the_public_path(detector):
    if detector == "learned":
        pytest.importorskip("torch")
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import resolve_detector

    det = resolve_detector(detector)
    n_det = 0
    for seed in range(4):
        scene = scenes.random_arena(10, 8, seed=seed).replace(lidar=LidarSpec(noise_sigma=0.005))
        w = World(scene, seed=seed)
        scan, poses = w.scan(), w.poses
        for i in range(4):
            args = (scan.ranges[i : i + 1], scan.angles, scan.robots[i : i + 1], poses)
            row_t, cols_t = detect_rows(det, *args, trusted=True)
            row_p, cols_p = detect_rows(det, *args, trusted=False)
            assert np.array_equal(row_t, row_p)
            _same_cols(cols_t, cols_p)
            n_det += row_t.size
    assert n_det > 0


def test_kin_seek_infos_are_fresh_every_step():
    pytest.importorskip("torch")
    import gymnasium as gym

    env = gym.make("kin_envs/KinSeek-v2", detector="learned", noise_sigma=0.01, obs_detections="topk")
    obs, info = env.reset(seed=3)
    kept = []
    rng = np.random.default_rng(0)
    for _ in range(40):
        obs, _, term, trunc, info = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        kept.append((obs, info, obs.copy(), {k: v.copy() for k, v in info["kin_detections"].items()}))
        if term or trunc:
            env.reset()
    assert sum(int(i["kin_detections_count"]) for _, i, _, _ in kept) > 0
    for obs, info, obs_copy, det_copy in kept:  # later steps left every earlier observation / info alone
        assert np.array_equal(obs, obs_copy)
        for k in DETECTION_FIELDS:
            assert np.array_equal(info["kin_detections"][k], det_copy[k]), k
    a, b = kept[-2][1]["kin_detections"], kept[-1][1]["kin_detections"]
    for k in DETECTION_FIELDS:
        assert not np.shares_memory(a[k], b[k]), k
    env.close()


def test_swarm_matching_in_one_compiled_call_is_the_numpy_path():
    # detect_rows for a swarm step (one world, rows in order): the compiled per-row sort and match
    # equal the (D, N) distance-matrix path, bit for bit, on random arenas (and on NaN centres)
    from detectors import GeometricKinDetector
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import _match_rows, _match_rows_numpy, detection_arrays

    n_det = n_matched = 0
    for seed in range(4):
        scene = scenes.random_arena(24, 20, seed=seed).replace(lidar=LidarSpec(noise_sigma=0.005 * seed))
        scan = World(scene, seed=seed).scan()
        owner, tab = detection_arrays(GeometricKinDetector(), scan.ranges, scan.angles)
        if seed == 3 and len(tab) > 2:
            tab[1, 2] = np.nan  # a NaN centre: unmatched, sorted as np.lexsort does
            tab[2, 0] = np.nan
        got = _match_rows(tab, owner, scan.robots, scan.poses)
        ref = _match_rows_numpy(tab, owner, scan.robots, scan.poses, None)
        _same_cols(got, ref)
        n_det += len(tab)
        n_matched += int((ref["kin_index"] >= 0).sum())
    assert n_det > 20 and n_matched > 10


def _oracle_padded(tab, owner, observers, poses, n_rows, slots):
    """The previous path as the oracle: the (D, N) distance-matrix match (np.lexsort by row then range,
    np.argmin over every robot) and pad_rows."""
    from kin_envs.envs.common import _match_rows_numpy
    from kin_envs.envs.info import pad_rows

    cols = _match_rows_numpy(tab, owner, observers, poses, None)
    row = np.sort(owner, kind="stable")
    return (row, cols), pad_rows(row, cols, n_rows, slots)


def _same_padded(got, ref):
    (row, cols), (padded, count) = got
    (row_r, cols_r), (padded_r, count_r) = ref
    assert row.dtype == row_r.dtype and np.array_equal(row, row_r)
    _same_cols(cols, cols_r)
    _same_cols(padded, padded_r)
    assert count.dtype == count_r.dtype and np.array_equal(count, count_r)


def _random_glue_case(rng, trial):
    """Detections of a random swarm step, built to reach the match's edges: centres near robots (some
    exactly at the tolerance), robots sharing an x or a whole position, NaN / inf centres and ranges,
    rows out of order, empty and overfull rows."""
    from kin_envs.envs.common import KIN_MATCH_TOLERANCE as tol

    n_rob = int(rng.integers(2, 80))
    n_rows = int(rng.integers(1, n_rob + 1))
    side = float(rng.uniform(0.5, 12.0))
    poses = np.column_stack([rng.uniform(-side, side, (n_rob, 2)), rng.uniform(-4, 4, n_rob)])
    if trial % 5 == 0:
        poses[1:4, 0] = poses[0, 0]  # equal x (ties in the sort by x)
    if trial % 7 == 0:
        poses[2, :2] = poses[1, :2]  # equal distances: the first robot wins
    if trial % 9 == 0:
        poses[:, :2] = np.round(poses[:, :2], 1)  # centres on a 0.1 m lattice: distances exactly 0.1
    observers = rng.permutation(n_rob)[:n_rows]
    n_det = int(rng.integers(0, 30 * n_rows + 1)) if trial % 13 else 0
    owner = np.sort(rng.integers(n_rows, size=n_det)) if trial % 3 else rng.integers(n_rows, size=n_det)
    obs = observers[owner]
    target = rng.integers(n_rob, size=n_det)
    # world centres at a distance around the tolerance from a robot, some exactly on the x or y axis
    ang = np.where(rng.uniform(size=n_det) < 0.3, rng.integers(4, size=n_det) * np.pi / 2,
                   rng.uniform(-np.pi, np.pi, n_det))
    near = [rng.uniform(0, 2, n_det), np.ones(n_det), np.full(n_det, 1 + 1e-15), np.full(n_det, 1 - 1e-15)]
    dist = tol * np.choose(rng.integers(4, size=n_det), near)
    wx = poses[target, 0] + dist * np.cos(ang)
    wy = poses[target, 1] + dist * np.sin(ang)
    c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
    dx, dy = wx - poses[obs, 0], wy - poses[obs, 1]
    tab = np.empty((n_det, 8))
    tab[:, 2], tab[:, 3] = c * dx + s * dy, c * dy - s * dx
    tab[:, 0] = np.round(np.hypot(tab[:, 2], tab[:, 3]), 1 if trial % 4 == 0 else 12)  # equal ranges
    tab[:, 1] = np.arctan2(tab[:, 3], tab[:, 2])
    tab[:, 4] = rng.uniform(size=n_det)
    tab[:, 5] = rng.integers(360, size=n_det)
    tab[:, 6] = rng.integers(360, size=n_det)
    tab[:, 7] = rng.integers(1, 9, size=n_det)
    if n_det > 3 and trial % 6 == 1:
        tab[0, [0, 2]] = np.nan  # NaN range sorted last; NaN centre never matched
        tab[1, 3] = np.inf
        tab[2, 2] = -np.inf
    slots = int(rng.integers(1, 21))
    return tab, owner, observers, poses, n_rows, slots


def test_match_and_pad_in_one_call_is_the_distance_matrix_and_pad_rows():
    # _match_pad_kernel (x-sorted candidate window, counting sort by row, padding) against the previous
    # distance-matrix match and pad_rows, bit for bit, on random steps that reach the match's edges
    from kin_envs.envs.common import (
        _INT_PADS,
        _NO_HITS,
        _ROBOT_HIT,
        KIN_MATCH_TOLERANCE,
        _detection_cols,
        _match_pad_kernel,
    )

    rng = np.random.default_rng(1)
    n_matched = 0
    for trial in range(400):
        tab, owner, observers, poses, n_rows, slots = _random_glue_case(rng, trial)
        if trial % 11 == 5:
            poses[int(rng.integers(len(poses))), int(rng.integers(2))] = [np.nan, np.inf, -np.inf][trial % 3]
        args = (tab, owner, observers, poses, KIN_MATCH_TOLERANCE**2, n_rows, slots, _INT_PADS)
        row, flo, ints, pf, pi, count = _match_pad_kernel(*args, *_NO_HITS, _ROBOT_HIT)
        got = (row, _detection_cols(flo, ints)), (_detection_cols(pf, pi), count)
        with np.errstate(invalid="ignore"):  # inf - inf in the distance matrix of non-finite poses
            ref = _oracle_padded(tab, owner, observers, poses, n_rows, slots)
        _same_padded(got, ref)
        k = ref[0][1]["kin_index"]
        n_matched += int((k >= 0).sum())
    assert n_matched > 2000  # the cases do match (and miss) robots


def test_match_and_pad_refuses_rows_outside_the_scan():
    from kin_envs.envs.common import _INT_PADS, _NO_HITS, _ROBOT_HIT, _match_pad_kernel

    tab = np.zeros((1, 8))
    poses = np.zeros((3, 3))
    rest = (poses, 0.01, 2, 4, _INT_PADS, *_NO_HITS, _ROBOT_HIT)
    with pytest.raises(ValueError, match="scan rows"):
        _match_pad_kernel(tab, np.array([2]), np.array([0, 1]), *rest)
    with pytest.raises(ValueError, match="scan rows"):
        _match_pad_kernel(tab, np.array([-1]), np.array([0, 1]), *rest)


def _random_hits(rng, tab, owner, observers, poses, n_rows, n_beams=360):
    """Lidar hit arrays for :func:`_match_pad_kernel`'s candidates: every detection's first beam (when in
    range) names a robot: the nearest to its centre (what a real scan gives, mostly), a random one, the
    observer, an index out of range, or no robot at all (another hit kind); other beams hold noise."""
    kind = rng.choice(np.array([0, 2, 3, 1], dtype=np.int8), size=(n_rows, n_beams), p=[0.4, 0.2, 0.2, 0.2])
    index = rng.integers(-1, len(poses), size=(n_rows, n_beams)).astype(np.int32)
    obs = observers[owner]
    c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
    wx = poses[obs, 0] + c * tab[:, 2] - s * tab[:, 3]
    wy = poses[obs, 1] + s * tab[:, 2] + c * tab[:, 3]
    with np.errstate(invalid="ignore"):
        d2 = (wx[:, None] - poses[None, :, 0]) ** 2 + (wy[:, None] - poses[None, :, 1]) ** 2
        d2[np.arange(len(obs)), obs] = np.inf
    nearest = np.argmin(d2, axis=1) if len(obs) else np.zeros(0, dtype=np.int64)
    pick = rng.choice(5, size=len(obs), p=[0.6, 0.2, 0.1, 0.05, 0.05])
    cand = np.choose(pick, [nearest, rng.integers(len(poses), size=len(obs)), obs,
                            np.full(len(obs), -1), np.full(len(obs), len(poses) + 2)])
    beam = tab[:, 5].astype(np.int64)
    ok = (beam >= 0) & (beam < n_beams)
    kind[owner[ok], beam[ok]] = np.where(rng.uniform(size=int(ok.sum())) < 0.9, 1, 3)
    index[owner[ok], beam[ok]] = cand[ok]
    return kind, index


def _touching_case(rng, trial):
    """A clustered swarm: robots on a jittered lattice whose spacing is about the robots' diameter (touching
    or overlapping, some exactly touching pairs, a shared position), detection centres near robots (0 to
    0.12 m) and exactly or nearly at the midpoint of two robots (equal distances: the first robot wins)."""
    n_side = int(rng.integers(2, 9))
    gap = float(rng.choice([0.18, 0.15, 0.12, 0.2])) if trial % 4 else 0.18
    gx, gy = np.meshgrid(np.arange(n_side) * gap, np.arange(n_side) * gap)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    if trial % 3:
        xy = xy + rng.normal(scale=0.01, size=xy.shape)
    n_rob = len(xy)
    poses = np.column_stack([xy, rng.uniform(-4, 4, n_rob)])
    if trial % 5 == 0:
        poses[1, :2] = poses[0, :2]  # two robots at one position
    n_rows = int(rng.integers(1, n_rob + 1))
    observers = rng.permutation(n_rob)[:n_rows]
    n_det = int(rng.integers(0, 20 * n_rows + 1))
    owner = np.sort(rng.integers(n_rows, size=n_det))
    obs = observers[owner]
    a, b = rng.integers(n_rob, size=n_det), rng.integers(n_rob, size=n_det)
    ang = rng.uniform(-np.pi, np.pi, n_det)
    dist = rng.uniform(0, 0.12, n_det)
    wx = poses[a, 0] + dist * np.cos(ang)
    wy = poses[a, 1] + dist * np.sin(ang)
    mid = rng.uniform(size=n_det) < 0.3  # midpoints of two robots, some off by an ulp or two
    eps = rng.choice([0.0, 0.0, 1e-16, -1e-16, 1e-12], size=n_det)
    wx = np.where(mid, (poses[a, 0] + poses[b, 0]) / 2 + eps, wx)
    wy = np.where(mid, (poses[a, 1] + poses[b, 1]) / 2, wy)
    c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
    dx, dy = wx - poses[obs, 0], wy - poses[obs, 1]
    tab = np.empty((n_det, 8))
    tab[:, 2], tab[:, 3] = c * dx + s * dy, c * dy - s * dx
    tab[:, 0] = np.round(np.hypot(tab[:, 2], tab[:, 3]), 12)
    tab[:, 1] = np.arctan2(tab[:, 3], tab[:, 2])
    tab[:, 4] = rng.uniform(size=n_det)
    tab[:, 5] = rng.integers(-2, 362, size=n_det)  # a few beams outside the scan: no candidate
    tab[:, 6] = rng.integers(360, size=n_det)
    tab[:, 7] = rng.integers(1, 9, size=n_det)
    return tab, owner, observers, poses, n_rows, int(rng.integers(1, 21))


def test_lidar_candidates_give_the_distance_matrix_match():
    # _match_pad_kernel with the lidar's hit arrays (a candidate robot per detection, taken when it is
    # provably the nearest) against the distance-matrix oracle and against the kernel without hits, bit for
    # bit: random steps (the edge cases above) and clustered swarms with touching and overlapping robots,
    # midpoints of two robots (ties), with candidates that are right, wrong, the observer or out of range
    from kin_envs.envs.common import (
        _INT_PADS,
        _NO_HITS,
        _ROBOT_HIT,
        KIN_MATCH_TOLERANCE,
        _detection_cols,
        _match_pad_kernel,
    )

    rng = np.random.default_rng(7)
    n_matched = n_tied = 0
    for trial in range(600):
        case = _touching_case(rng, trial) if trial % 2 else _random_glue_case(rng, trial)
        tab, owner, observers, poses, n_rows, slots = case
        if trial % 2 == 0 and trial % 11 == 4:
            poses[int(rng.integers(len(poses))), 0] = np.nan  # non-finite poses: the brute force, hits unused
        kind, index = _random_hits(rng, tab, owner, observers, poses, n_rows)
        args = (tab, owner, observers, poses, KIN_MATCH_TOLERANCE**2, n_rows, slots, _INT_PADS)
        row, flo, ints, pf, pi, count = _match_pad_kernel(*args, kind, index, _ROBOT_HIT)
        got = (row, _detection_cols(flo, ints)), (_detection_cols(pf, pi), count)
        with np.errstate(invalid="ignore"):
            ref = _oracle_padded(tab, owner, observers, poses, n_rows, slots)
        _same_padded(got, ref)
        row, flo, ints, pf, pi, count = _match_pad_kernel(*args, *_NO_HITS, _ROBOT_HIT)
        _same_padded(got, ((row, _detection_cols(flo, ints)), (_detection_cols(pf, pi), count)))
        k = ref[0][1]["kin_index"]
        n_matched += int((k >= 0).sum())
        if trial % 2 and len(tab):  # detections at equal distance from two robots, within the tolerance
            obs = observers[owner]
            c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
            wx = poses[obs, 0] + c * tab[:, 2] - s * tab[:, 3]
            wy = poses[obs, 1] + s * tab[:, 2] + c * tab[:, 3]
            d2 = (wx[:, None] - poses[None, :, 0]) ** 2 + (wy[:, None] - poses[None, :, 1]) ** 2
            d2[np.arange(len(obs)), obs] = np.inf
            d2.sort(axis=1)
            n_tied += int(((d2[:, 0] == d2[:, 1]) & (d2[:, 0] <= KIN_MATCH_TOLERANCE**2)).sum())
    assert n_matched > 5000 and n_tied > 50  # matches, misses and ties were all compared


def test_min_separation_is_the_smallest_pair_distance():
    from kin_envs.envs.common import _min_separation2

    rng = np.random.default_rng(3)
    for trial in range(300):
        n = int(rng.integers(1, 40))
        poses = np.column_stack([rng.uniform(-3, 3, (n, 2)), np.zeros(n)])
        if trial % 3 == 0:
            poses[:, :2] = np.round(poses[:, :2], 1)  # equal x, equal distances
        if trial % 7 == 0 and n > 2:
            poses[2, :2] = poses[0, :2]
        order = np.argsort(poses[:, 0])
        got = _min_separation2(poses, poses[order, 0].copy(), order)
        d2 = (poses[:, None, 0] - poses[None, :, 0]) ** 2 + (poses[:, None, 1] - poses[None, :, 1]) ** 2
        d2[np.arange(n), np.arange(n)] = np.inf
        assert got == pytest.approx(d2.min(), rel=1e-12, abs=0) if n > 1 else got == np.inf


@pytest.mark.parametrize("detector", ["geometric", "learned"])
def test_detect_rows_padded_is_detect_rows_then_pad_rows(detector):
    if detector == "learned":
        pytest.importorskip("torch")
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import detect_rows_padded, resolve_detector
    from kin_envs.envs.info import pad_rows

    det = resolve_detector(detector)
    n_det = 0
    for seed, n in enumerate((2, 16, 64)):
        scene = scenes.random_arena(n, n // 4, seed=seed).replace(lidar=LidarSpec(noise_sigma=0.01))
        w = World(scene, seed=seed)
        scan = w.scan()
        for slots in (1, 16):
            args = (det, scan.ranges, scan.angles, scan.robots, w.poses)
            row, cols = detect_rows(*args, trusted=True)
            got = detect_rows_padded(*args, slots, trusted=True)
            _same_padded(got, ((row, cols), pad_rows(row, cols, n, slots)))
            with_hits = detect_rows_padded(*args, slots, trusted=True, hits=(scan.hit_kind, scan.hit_index))
            _same_padded(with_hits, ((row, cols), pad_rows(row, cols, n, slots)))
            again = detect_rows_padded(*args, slots, trusted=True)  # fresh arrays on every call
            for a, b in zip(got[1][0].values(), again[1][0].values(), strict=True):
                assert not np.shares_memory(a, b)
            n_det += row.size
    assert n_det > 50


def test_rank_sort_is_the_stable_sort_by_range():
    # the match-and-pad kernel's per-row sort (ranks counted without branches; NaN rows and rows longer than
    # _RANK_SORT_MAX insertion-sorted) against numpy's stable argsort (NaN last), on rows with ties,
    # -0.0 / 0.0, inf and NaN ranges, from empty to past the bound
    from kin_envs.envs.common import _RANK_SORT_MAX, _rank_sort_by_range

    rng = np.random.default_rng(11)
    lengths = [0, 1, 2, 3, 15, _RANK_SORT_MAX - 1, _RANK_SORT_MAX, _RANK_SORT_MAX + 1, 150]
    for trial in range(300):
        m = lengths[trial % len(lengths)]
        lo = int(rng.integers(0, 5))
        tab = np.zeros((lo + m + 3, 8))
        keys = rng.uniform(0, 3, m)
        if trial % 3 == 0:
            keys = np.round(keys, 1)  # ties
        if trial % 5 == 0 and m > 2:
            keys[:2] = [-0.0, 0.0]
            keys[-1] = np.inf
        if trial % 7 == 0 and m > 1:
            keys[rng.integers(m, size=2)] = np.nan
        tab[lo : lo + m, 0] = keys
        order = np.arange(tab.shape[0])
        rng.shuffle(order[lo : lo + m])
        ref = order.copy()
        seg = ref[lo : lo + m]
        ref[lo : lo + m] = seg[np.argsort(tab[seg, 0], kind="stable")]
        scratch = min(m, _RANK_SORT_MAX)
        _rank_sort_by_range(tab, order, lo, lo + m, np.empty(scratch), np.empty(scratch, dtype=np.int64))
        assert np.array_equal(order, ref), (trial, m)


def test_padded_only_match_gives_the_same_padded_columns():
    # _match_pad_kernel(flat=False) (what a step that reads no flat columns asks for: rows past their slots
    # neither matched nor copied) gives flat=True's padded blocks and counts, bit for bit, with and without
    # the lidar's candidates, on the random edge cases (overfull rows included)
    from kin_envs.envs.common import _INT_PADS, _NO_HITS, _ROBOT_HIT, KIN_MATCH_TOLERANCE, _match_pad_kernel

    rng = np.random.default_rng(5)
    n_over = 0
    for trial in range(300):
        case = _touching_case(rng, trial) if trial % 2 else _random_glue_case(rng, trial)
        tab, owner, observers, poses, n_rows, slots = case
        hits = _random_hits(rng, tab, owner, observers, poses, n_rows) if trial % 3 else _NO_HITS
        args = (tab, owner, observers, poses, KIN_MATCH_TOLERANCE**2, n_rows, slots, _INT_PADS, *hits,
                _ROBOT_HIT)  # fmt: skip
        full = _match_pad_kernel(*args, True)
        lean = _match_pad_kernel(*args, False)
        assert lean[0].shape == (0,) and lean[1].shape == (5, 0) and lean[2].shape == (4, 0)
        for a, b in zip(full[3:], lean[3:], strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
        n_over += int((np.bincount(owner, minlength=n_rows) > slots).sum())
    assert n_over > 20  # rows past their slots were compared


class _DetectOnly:
    """A user's detector object with ``detect`` alone (the envs' slowest reading path)."""

    def __init__(self, inner):
        self.inner = inner

    def detect(self, ranges, angles):
        return self.inner.detect(ranges, angles)


@pytest.mark.parametrize("detector", ["geometric", "learned", "beam", "detect-only"])
def test_one_row_match_and_pad_is_detect_rows_then_pad_rows(detector):
    # detect_one_padded (KinSeek / KinFollow v1 every step) against the previous path, detect_rows then
    # pad_rows and each padded field's one row, bit for bit: the flat columns, the padded slots and the
    # count, with and without the lidar's candidates and the flat columns, over-full and empty rows
    if detector == "learned":
        pytest.importorskip("torch")
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import detect_one_padded, resolve_detector
    from kin_envs.envs.info import pad_rows

    det = resolve_detector("geometric" if detector == "detect-only" else detector)
    if detector == "detect-only":
        det = _DetectOnly(det)
    n_det = n_empty = n_over = 0
    for seed in range(3):
        scene = scenes.random_arena(24, 4, seed=seed, size=5.0).replace(lidar=LidarSpec(noise_sigma=0.01))
        w = World(scene, seed=seed)
        scan, poses = w.scan(), w.poses
        empty = np.full_like(scan.ranges[:1], scan.range_max)  # no return anywhere: no detection
        for i in range(25):
            r = slice(i % 24, i % 24 + 1)
            ranges = scan.ranges[r] if i < 24 else empty
            row, cols = detect_rows(det, ranges, scan.angles, scan.robots[r], poses, trusted=True)
            for slots in (1, 16):
                padded, count = pad_rows(row, cols, 1, slots)
                ref_padded = {k: v[0] for k, v in padded.items()}
                for hits in (None, (scan.hit_kind[r], scan.hit_index[r])):
                    for flat in (True, False):
                        got_flat, got, got_count = detect_one_padded(
                            det, ranges, scan.angles, int(scan.robots[r][0]), poses, slots, hits=hits,
                            flat=flat,
                        )  # fmt: skip
                        _same_cols(got, ref_padded)
                        assert type(got_count) is int and got_count == int(count[0])
                        if flat:
                            assert np.array_equal(got_flat[0], row) and got_flat[0].dtype == row.dtype
                            _same_cols(got_flat[1], cols)
                        else:
                            assert got_flat is None
            n_det += row.size
            n_empty += row.size == 0
            n_over += row.size > 1  # past the one slot of slots=1
    assert n_empty > 0 and n_det > 40 and n_over > 5


@pytest.mark.parametrize("detector", ["geometric", "learned"])
def test_envs_without_flat_detections_give_the_same_outputs(detector):
    # with nothing reading the flat detections (no tracker, no detection channel, no rendering) the envs skip
    # them: every output equals the same env's with rendering on (flat columns kept), bit for bit and in the
    # same key order, through an episode end
    if detector == "learned":
        pytest.importorskip("torch")
    import gymnasium as gym

    from kin_envs.envs.aggregation import AggregationEnv

    from .test_swarm_step_equivalence import assert_same_ordered

    lean = gym.make("kin_envs/KinSeek-v2", detector=detector, noise_sigma=0.01, max_steps=60)
    full = gym.make("kin_envs/KinSeek-v2", detector=detector, noise_sigma=0.01, max_steps=60,
                    render_mode="rgb_array")  # fmt: skip
    assert not lean.unwrapped._flat_dets and full.unwrapped._flat_dets
    rng = np.random.default_rng(2)
    n_det = 0
    for episode in range(2):
        assert_same_ordered(lean.reset(seed=episode), full.reset(seed=episode))
        done = False
        while not done:
            a = rng.uniform(-1, 1, 2).astype(np.float32)
            out = lean.step(a)
            assert_same_ordered(out, full.step(a))
            assert lean.unwrapped._last_detections is None
            n_det += out[4]["kin_detections_count"]
            done = out[2] or out[3]
    swarm = [AggregationEnv(n_robots=16, detector=detector, noise_sigma=0.01, max_cycles=25, render_mode=m)
             for m in (None, "rgb_array")]  # fmt: skip
    assert_same_ordered(swarm[0].reset(seed=4), swarm[1].reset(seed=4))
    while swarm[0].agents:
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in swarm[0].agents}
        out = swarm[0].step(acts)
        assert_same_ordered(out, swarm[1].step(acts))
        n_det += sum(i["kin_detections_count"] for i in out[4].values())
    assert n_det > 20



def test_learned_table_matched_in_the_driver_is_the_two_calls():
    # the learned detector's table matched and padded inside its own compiled call (_padded_in_detector:
    # kin_envs.envs._detector_pad.learned_match_pad, what a step that reads no flat columns takes) against
    # the two calls it fuses, detection_arrays then _match_pad(flat=False), bit for bit: one scan (no
    # cascade) and batches (cascade), with and without the lidar's candidates, over-full and empty rows, and
    # settings that change the driver's arguments (duplicates kept, a fixed threshold)
    from detectors import LearnedKinDetector
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import _match_pad, _one_observer, _padded_in_detector, detection_arrays

    dets = [LearnedKinDetector(reports=False), LearnedKinDetector(reports=False, suppress_duplicates=False),
            LearnedKinDetector(reports=False, threshold=0.3)]  # fmt: skip
    n_det = n_empty = n_over = 0
    for seed, n in enumerate((2, 8, 64)):
        scene = scenes.random_arena(n, max(2, n // 4), seed=seed, size=max(3.0, n**0.5 * 0.9))
        w = World(scene.replace(lidar=LidarSpec(noise_sigma=0.01 * seed)), seed=seed)
        scan, poses = w.scan(), w.poses
        no_return = np.full_like(scan.ranges, scan.range_max)
        # (ranges, their rows of the scan): the whole batch, the batch with no return, one scan, the last scan
        batches = [(scan.ranges, slice(0, n)), (no_return, slice(0, n)), (scan.ranges[:1], slice(0, 1)),
                   (scan.ranges[n - 1 :], slice(n - 1, n))]  # fmt: skip
        for det in dets:
            for ranges, rows in batches:
                one = len(ranges) == 1
                observers = _one_observer(int(scan.robots[rows][0])) if one else scan.robots
                for slots in (1, 16):
                    for hits in (None, (scan.hit_kind[rows], scan.hit_index[rows])):
                        got = _padded_in_detector(det, ranges, scan.angles, observers, poses, slots, hits)
                        owner, tab = detection_arrays(det, ranges, scan.angles, True)
                        ref = _match_pad(owner, tab, observers, poses, len(ranges), slots, hits, False)[3:]
                        assert len(got) == 3
                        for a, b in zip(got, ref, strict=True):
                            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
                        n_det += len(owner)
                        n_empty += len(owner) == 0
                        n_over += int((np.bincount(owner, minlength=len(ranges)) > slots).sum())
    assert n_det > 500 and n_empty > 10 and n_over > 20


def test_learned_one_scan_call_with_cached_arguments_follows_the_settings():
    # LearnedKinDetector._detect_table_then keeps a one-scan call's arguments (a single-robot env's step): the
    # same values as the two calls (detection_arrays, then _match_pad) when the settings change on the same
    # detector between calls (threshold, duplicates, pre-gate; the cache is rebuilt), for a scan whose network
    # rows outgrow the kept work arrays (they grow), and for scans the cache does not serve (a float64 or
    # strided copy of the scan: the checked path)
    from detectors import LearnedKinDetector
    from detectors import learned as L
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs.common import _match_pad, _one_observer, _padded_in_detector, detection_arrays

    scene = scenes.random_arena(12, 4, seed=3).replace(lidar=LidarSpec(noise_sigma=0.01))
    w = World(scene, seed=3)
    scan, poses = w.scan(), w.poses
    n = scan.angles.shape[0]
    comb = np.where(np.arange(n) % 2 == 0, 1.0, 1.5).astype(np.float32)[None, :]  # 180 one-beam segments
    det = LearnedKinDetector(reports=False)
    settings = [{}, {"threshold": 0.3}, {"suppress_duplicates": False}, {"pre_gate": False},
                {"threshold": None}, {"suppress_duplicates": True, "pre_gate": True}]  # fmt: skip
    n_det = n_fast = 0
    for change in settings:
        for k, v in change.items():
            setattr(det, k, v)
        for i in (0, 5, 11, 5):
            r = slice(i, i + 1)
            rows = [scan.ranges[r], np.ascontiguousarray(scan.ranges[r], dtype=np.float64),
                    np.repeat(scan.ranges[r], 2, axis=1)[:, ::2], comb]  # fmt: skip
            for ranges in rows:
                hits = (scan.hit_kind[r], scan.hit_index[r])
                observers = _one_observer(int(scan.robots[i]))
                got = _padded_in_detector(det, ranges, scan.angles, observers, poses, 16, hits)
                owner, tab = detection_arrays(det, ranges, scan.angles, True)
                ref = _match_pad(owner, tab, observers, poses, 1, 16, hits, False)[3:]
                for a, b in zip(got, ref, strict=True):
                    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
                n_det += len(owner)
                fast = det._then_fast
                n_fast += fast is not None and fast[3] is getattr(L._WORK, "ws", None)
    assert n_det > 50 and n_fast > 20


def test_detector_pad_falls_back_without_the_compiled_table():
    # a learned detector whose table does not come from the fused driver (BLAS inference) and a detector
    # without the hook take the two calls: the envs' lean entries (flat=False) give the padded columns of
    # their flat=True path (which never takes the hook)
    pytest.importorskip("threadpoolctl")
    from detectors import LearnedKinDetector
    from kin_envs import LidarSpec, World, scenes
    from kin_envs.envs import common as C

    scene = scenes.random_arena(16, 4, seed=4).replace(lidar=LidarSpec(noise_sigma=0.01))
    w = World(scene, seed=4)
    scan, poses = w.scan(), w.poses
    hits = (scan.hit_kind, scan.hit_index)
    n_det = 0
    for det in (LearnedKinDetector(reports=False, inference="blas"), C.resolve_detector("geometric")):
        assert C._padded_in_detector(det, scan.ranges, scan.angles, scan.robots, poses, 16, hits) is None
        args = (det, scan.ranges, scan.angles, scan.robots, poses, 16)
        lean = C.detect_rows_padded(*args, trusted=True, hits=hits, flat=False)
        full = C.detect_rows_padded(*args, trusted=True, hits=hits, flat=True)
        assert lean[0] is None
        _same_cols(lean[1][0], full[1][0])
        assert np.array_equal(lean[1][1], full[1][1])
        for i in range(16):
            r = slice(i, i + 1)
            one = (det, scan.ranges[r], scan.angles, i, poses, 16)
            lean = C.detect_one_padded(*one, hits=(hits[0][r], hits[1][r]), flat=False)
            full = C.detect_one_padded(*one, hits=(hits[0][r], hits[1][r]), flat=True)
            _same_cols(lean[1], full[1])
            assert lean[0] is None and lean[2] == full[2]
            n_det += lean[2]
    assert n_det > 5
