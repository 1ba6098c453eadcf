"""``LearnedKinDetector._scans_alone``: a batched call gives every scan the detections of that scan alone
(what a native vector env needs: the cascade runs on batches only)."""

import numpy as np
import pytest

from detectors.learned import LearnedKinDetector
from kin_envs import LidarSpec, World, scenes


def _scans(noise, seed, n_robots=16, n_obstacles=24):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    scan = World(scene, seed=seed).scan()
    return scan.ranges, scan.angles


def _one_by_one(det, ranges, angles):
    rows, tables = [], []
    for i in range(ranges.shape[0]):
        r, t = det._detect_table_trusted(ranges[i : i + 1], angles)
        rows.append(r + i)
        tables.append(t)
    return np.concatenate(rows), np.concatenate(tables)


# (0.01, 14): a scene where the batch's cascade drops a detection its one-scan call keeps
@pytest.mark.parametrize("noise,seed,cascade_drops", [(0.0, 3, False), (0.01, 4, False), (0.01, 14, True)])
def test_batch_inside_scans_alone_is_each_scan_alone(noise, seed, cascade_drops):
    det = LearnedKinDetector()
    if not det.cascade:
        pytest.skip("the shipped checkpoint has no cascade")
    ranges, angles = _scans(noise, seed)
    alone_row, alone_tab = _one_by_one(det, ranges, angles)
    with det._scans_alone() as same:
        assert same is det and det._alone
        row, tab = det._detect_table_trusted(ranges, angles)
        arrays = det.detect_arrays(ranges, angles)
    assert not det._alone
    np.testing.assert_array_equal(row, alone_row)
    np.testing.assert_array_equal(tab, alone_tab)
    assert "cascade_score" not in arrays.seg_values  # no cascade inside
    assert "cascade_score" in det.detect_arrays(ranges, angles).seg_values  # the batch's own call again
    outside = det._detect_table_trusted(ranges, angles)[0]
    assert (outside.shape != alone_row.shape) == cascade_drops
    np.testing.assert_array_equal(arrays.scan, alone_row)
    np.testing.assert_array_equal(arrays.range, alone_tab[:, 0].astype(arrays.range.dtype))


def test_scans_alone_restores_the_cascade_after_an_error():
    det = LearnedKinDetector()
    with pytest.raises(RuntimeError, match="inside"):
        with det._scans_alone():
            raise RuntimeError("inside")
    assert not det._alone
