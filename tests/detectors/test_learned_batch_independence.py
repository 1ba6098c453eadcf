"""The learned detector gives a scan the same detections alone as in a batch: its cascade runs on every
call (until session 16 one-scan calls went without, and a native vector env's batch differed from K single
envs)."""

import numpy as np
import pytest

from detectors.learned import LearnedKinDetector
from kin_envs import LidarSpec, World, scenes


def _scans(noise, seed, n_robots=16, n_obstacles=24):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    scan = World(scene, seed=seed).scan()
    return scan.ranges, scan.angles


# (0.01, 14): a scene where the cascade drops a detection the full network accepts (the old one-scan path
# without the cascade kept it)
@pytest.mark.parametrize("noise,seed,cascade_drops", [(0.0, 3, False), (0.01, 4, False), (0.01, 14, True)])
def test_a_scan_alone_gets_its_detections_in_the_batch(noise, seed, cascade_drops):
    det = LearnedKinDetector()
    if not det.cascade:
        pytest.skip("the shipped checkpoint has no cascade")
    ranges, angles = _scans(noise, seed)
    row, tab = det._detect_table_trusted(ranges, angles)
    arrays = det.detect_arrays(ranges.astype(np.float64), angles)
    one_rows, one_tabs, n_off = [], [], 0
    off = LearnedKinDetector(cascade=False)
    for i in range(ranges.shape[0]):
        r, t = det._detect_table_trusted(ranges[i : i + 1], angles)
        one_rows.append(r + i)
        one_tabs.append(t)
        a = det.detect_arrays(ranges[i : i + 1].astype(np.float64), angles)
        assert "cascade_score" in a.seg_values  # the cascade ran on the one scan
        np.testing.assert_array_equal(a.range, arrays.range[arrays.scan == i])
        np.testing.assert_array_equal(a.score, arrays.score[arrays.scan == i])
        n_off += off._detect_table_trusted(ranges[i : i + 1], angles)[0].shape[0]
    np.testing.assert_array_equal(row, np.concatenate(one_rows))
    np.testing.assert_array_equal(tab, np.concatenate(one_tabs))
    assert (n_off > row.shape[0]) == cascade_drops  # what the cascade-free one-scan call used to keep
