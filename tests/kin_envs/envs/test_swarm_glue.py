"""The swarm step's compiled ground truth (``kin_truth_padded``: counted, sorted and padded in one pass over
the lidar's arrays) against the numpy path it replaces (``kin_truth_rows`` + ``pad_rows``, the oracle), bit
for bit, on random swarm steps and on synthetic scans built to reach its edges (ties, overfull rows, a
``range_max`` between float32 values, non-finite poses); and ``row_infos``' extra per-row values."""

from __future__ import annotations

import numpy as np
import pytest

from kin_envs.core.lidar import HitKind
from kin_envs.core.world import Scan
from kin_envs.envs.aggregation import AggregationEnv
from kin_envs.envs.common import kin_truth_padded, kin_truth_rows
from kin_envs.envs.info import DETECTION_FIELDS, KIN_TRUTH_FIELDS, pad_rows, row_infos

from .test_swarm_step_equivalence import assert_same_ordered


def _bits(a: np.ndarray) -> np.ndarray:
    return a.view(np.uint64 if a.dtype == np.float64 else np.int64)


def assert_same_truth(scan: Scan, poses: np.ndarray, slots: int) -> np.ndarray:
    """``kin_truth_padded`` is ``pad_rows(*kin_truth_rows(...))``: keys in order, dtypes, shapes, bits;
    returns the counts."""
    ref, ref_count = pad_rows(*kin_truth_rows(scan, poses), scan.ranges.shape[0], slots)
    got, count = kin_truth_padded(scan, poses, slots)
    assert list(got) == list(KIN_TRUTH_FIELDS) == list(ref)
    assert count.dtype == ref_count.dtype and np.array_equal(count, ref_count)
    for f in ref:
        assert got[f].dtype == ref[f].dtype and got[f].shape == ref[f].shape, f
        assert np.array_equal(_bits(got[f]), _bits(ref[f])), f
    return count


@pytest.mark.parametrize("n_robots,seed", [(2, 0), (9, 1), (64, 2), (256, 3)])
def test_kin_truth_padded_is_the_numpy_path_on_swarm_steps(n_robots, seed):
    env = AggregationEnv(n_robots=n_robots, detector=None, noise_sigma=0.01, dropout_prob=0.05)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    full = 0
    for _ in range(8 if n_robots < 256 else 3):
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        scan = env.world.scan()
        for slots in (1, 3, 16, 255):
            count = assert_same_truth(scan, scan.poses, slots)
            full += int((count == slots).sum())
    if n_robots >= 64:
        assert full > 0  # rows with more seen robots than slots were compared (the nearest kept)


def _synthetic_scan(rng, n_robots: int, n_beams: int, range_max, ties: bool) -> tuple[Scan, np.ndarray]:
    """Random beams on random robots (and other kinds), ranges around ``range_max``; with ``ties``, robots
    on a few rings around observer 0 (equal centre distances, so equal sort keys across robot indices)."""
    poses = np.column_stack([rng.uniform(-5, 5, (n_robots, 2)), rng.uniform(-np.pi, np.pi, n_robots)])
    if ties:
        r = rng.choice([0.5, 1.25], n_robots)
        a = rng.choice(np.linspace(0, 2 * np.pi, 8, endpoint=False), n_robots)
        poses[:, 0], poses[:, 1] = r * np.cos(a), r * np.sin(a)
        poses[0, :2] = 0.0
        poses[1:, 0] = np.where(np.abs(poses[1:, 0]) < 1e-12, 0.0, poses[1:, 0])
    shape = (n_robots, n_beams)
    kind = rng.choice([HitKind.NONE, HitKind.ROBOT, HitKind.ROBOT, HitKind.BOX], shape).astype(np.int8)
    index = np.where(kind == HitKind.ROBOT, rng.integers(0, n_robots, shape), -1).astype(np.int32)
    near = np.float32(range_max)
    ranges = rng.choice(
        [near, np.nextafter(near, np.float32(0)), np.nextafter(near, np.float32(np.inf)), np.float32(1.0)],
        shape,
    ).astype(np.float32)
    scan = Scan(ranges=ranges, angles=np.zeros(n_beams), hit_kind=kind, hit_index=index, true_ranges=ranges,
                robots=np.arange(n_robots), poses=poses, range_max=range_max)  # fmt: skip
    return scan, poses


@pytest.mark.parametrize("ties", [False, True])
@pytest.mark.parametrize("range_max", [12.0, 12.1, 12.2, np.float64(12.2)])
def test_kin_truth_padded_is_the_numpy_path_on_synthetic_scans(ties, range_max):
    # 12.1 and 12.2 lie between float32 values (12.2 rounds down to one): numpy casts a Python float to
    # the ranges' dtype (NEP 50) but compares in float64 against a numpy float64; the kernel follows both
    rng = np.random.default_rng(11)
    for _ in range(30):
        n_robots, n_beams = int(rng.integers(2, 40)), int(rng.integers(1, 50))
        scan, poses = _synthetic_scan(rng, n_robots, n_beams, range_max, ties)
        for slots in (1, 2, 5, 64):
            assert_same_truth(scan, poses, slots)


def test_kin_truth_padded_ties_keep_the_robot_index_order():
    # four robots at one distance from observer 0: equal keys, kept in ascending robot index
    poses = np.array([[0, 0, 0.3], [0, 1, 0], [1, 0, 0], [0, -1, 0], [-1, 0, 0]], dtype=np.float64)
    index = np.array([[4, 2, 3, 1, 4, 2]], dtype=np.int32)
    kind = np.full(index.shape, HitKind.ROBOT, dtype=np.int8)
    ranges = np.ones(index.shape, dtype=np.float32)
    scan = Scan(ranges=ranges, angles=np.zeros(6), hit_kind=kind, hit_index=index, true_ranges=ranges,
                robots=np.array([0]), poses=poses[:1])  # fmt: skip
    got, count = kin_truth_padded(scan, poses, 3)
    assert got["index"].tolist() == [[1, 2, 3]] and count.tolist() == [3]
    assert got["n_beams"].tolist() == [[1, 2, 1]]
    assert_same_truth(scan, poses, 3)


def test_kin_truth_padded_non_finite_poses_take_the_numpy_path():
    rng = np.random.default_rng(5)
    scan, poses = _synthetic_scan(rng, 12, 30, 12.0, False)
    poses[3, 0] = np.nan
    assert_same_truth(scan, poses, 4)  # bit for bit (NaN ranges included)
    got, _ = kin_truth_padded(scan, poses, 4)
    assert np.isnan(got["range"]).any()


def test_kin_truth_padded_rejects_a_robot_hit_out_of_range():
    rng = np.random.default_rng(6)
    scan, poses = _synthetic_scan(rng, 5, 10, 12.0, False)
    scan.hit_kind[2, 4], scan.hit_index[2, 4], scan.ranges[2, 4] = HitKind.ROBOT, 5, 1.0
    with pytest.raises(ValueError, match="hit_index"):
        kin_truth_padded(scan, poses, 4)


def test_row_infos_extra_values_follow_the_entries():
    rng = np.random.default_rng(1)
    n = 5
    det = {f: rng.integers(-1, 9, (n, 3)) if f == "kin_index" else rng.normal(size=(n, 3))
           for f in DETECTION_FIELDS}  # fmt: skip
    truth = {"index": rng.integers(0, 9, (n, 2)), "range": rng.normal(size=(n, 2))}
    entries = {"kin_truth": (truth, rng.integers(0, 3, n)), "kin_detections": (det, rng.integers(0, 4, n))}
    terms = [{"kin": float(i)} for i in range(n)]
    got = row_infos(entries, reward_terms=iter(terms), n_kin=list(range(n)))
    for i, info in enumerate(got):
        ref = {}
        for key, (cols, count) in entries.items():
            ref[key] = {f: c[i] for f, c in cols.items()}
            ref[f"{key}_count"] = int(count[i])
        ref["reward_terms"] = terms[i]
        ref["n_kin"] = i
        assert_same_ordered(info, ref)
        assert info["reward_terms"] is terms[i]
        assert np.shares_memory(info["kin_truth"]["range"], truth["range"])
    # the inner dicts of different rows and keys are distinct objects
    assert len({id(i["kin_detections"]) for i in got} | {id(i["kin_truth"]) for i in got}) == 2 * n
