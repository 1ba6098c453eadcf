"""detectors.learned's operating point: thresholds by expected beams, duplicates, old checkpoints."""

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from detectors.learned import (  # noqa: E402
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    check_thresholds,
    duplicates,
    expected_beams,
    load_checkpoint,
    save_checkpoint,
)
from kin_envs import LidarSpec, World, scenes  # noqa: E402

torch.set_num_threads(1)


def test_expected_beams_of_a_housing():
    step = math.radians(1.0)
    # a 3.5 cm housing whose nearest point is at 0.965 m (centre 1 m) spans 2 asin(0.035) = 4.01 deg
    assert expected_beams(1.0 - 0.035, step) == pytest.approx(math.degrees(2 * math.asin(0.035)))
    e = expected_beams(np.array([0.3, 1.0, 2.0]), step)
    assert (np.diff(e) < 0).all() and e[-1] == pytest.approx(1.97, abs=0.01)
    assert expected_beams(0.0, step) == pytest.approx(180.0)  # touching: half a turn


def test_threshold_table_is_validated():
    good = {"noise_edges": [0.003], "values": [0.4, 0.5], "beam_edges": [2.0, 4.0],
            "table": [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]}  # fmt: skip
    assert check_thresholds(good) == good
    bad_tables = (
        {"beam_edges": [2.0, 4.0]},  # without its table
        {"beam_edges": [4.0, 2.0], "table": [[0.1, 0.2, 0.3]] * 2},  # not increasing
        {"beam_edges": [2.0, 4.0], "table": [[0.1, 0.2]] * 2},  # too few columns
        {"beam_edges": [2.0, 4.0], "table": [[0.1, 0.2, 0.3]]},  # too few rows (noise bins)
        {"beam_edges": [2.0, 4.0], "table": [[0.1, 0.2, 1.3]] * 2},  # not a probability
    )
    for extra in bad_tables:
        with pytest.raises(ValueError, match="thresholds"):
            check_thresholds({"noise_edges": [0.003], "values": [0.4, 0.5], **extra})


def test_thresholds_follow_the_table_by_noise_and_expected_beams(tmp_path):
    """Every segment's threshold is the table's cell of its scan-noise bin and of the beams a housing
    would return at its range; an explicit threshold still overrides; the weights are untouched."""
    model, ck = load_checkpoint(DEFAULT_CHECKPOINT)
    table = [[0.11, 0.12, 0.13, 0.14], [0.91, 0.92, 0.93, 0.94]]
    thr = {"noise_edges": [0.003], "values": [0.12, 0.92], "beam_edges": [2.0, 4.0, 8.0], "table": table}
    path = save_checkpoint(tmp_path / "t.pt", model, ck["feature_config"], positioning=ck["positioning"],
                           angular_resolution=ck["angular_resolution"], thresholds=thr)  # fmt: skip
    # the shipped cascade is tied to the shipped file: off for the comparison of p(kin)
    det, old = LearnedKinDetector(path, reports=False), LearnedKinDetector(reports=False, cascade=False)
    for row, sigma in enumerate((0.0, 0.01)):
        world = World(scenes.detection_scene(7, lidar=LidarSpec(noise_sigma=sigma)), seed=1)
        scan = world.scan()
        batch, feats, p, _ = det.predict_segments(scan.ranges, scan.angles)
        d_min = np.array([scan.ranges[s, (f + np.arange(c)) % scan.ranges.shape[1]].min()
                          for s, f, c in zip(batch.scan, batch.first, batch.count, strict=True)])  # fmt: skip
        col = np.searchsorted([2.0, 4.0, 8.0], expected_beams(d_min, math.radians(1.0)), side="right")
        got = det.segment_thresholds(feats)
        np.testing.assert_allclose(got, np.asarray(table[row])[col])
        assert len(set(col.tolist())) >= 3  # the scene has segments in several columns
        np.testing.assert_array_equal(p, old.predict_segments(scan.ranges, scan.angles)[2])
        arrays = det.detect_arrays(scan.ranges, scan.angles)
        np.testing.assert_allclose(arrays.seg_values["threshold"][np.isfinite(p)], got[np.isfinite(p)])
        np.testing.assert_array_equal(
            LearnedKinDetector(path, threshold=0.5).segment_thresholds(feats), 0.5
        )


def test_old_checkpoints_without_a_table_keep_their_thresholds(tmp_path):
    """A checkpoint with per-noise thresholds only (every checkpoint before the table) loads and
    thresholds exactly as before: one value per scan-noise bin."""
    model, ck = load_checkpoint(DEFAULT_CHECKPOINT)
    thr = {"noise_edges": [0.003], "values": [0.2, 0.9]}
    path = save_checkpoint(tmp_path / "old.pt", model, ck["feature_config"], thresholds=thr)
    assert "table" not in load_checkpoint(path)[1]["thresholds"]
    det = LearnedKinDetector(path, reports=False)
    scan = World(scenes.detection_scene(5), seed=0).scan()
    _, feats, _, _ = det.predict_segments(scan.ranges, scan.angles)
    np.testing.assert_array_equal(det.segment_thresholds(feats), 0.2)


def test_duplicates_keep_the_best_of_neighbours_within_the_radius():
    scan = np.array([0, 0, 0, 1, 1, 2, 2, 2])
    xy = np.array([[1.0, 0.0], [1.03, 0.0], [2.0, 0.0],  # scan 0: a split pair, then a far one
                   [1.0, 0.0], [1.2, 0.0],  # scan 1: 20 cm apart, both kept
                   [0.18, 0.0], [0.5, 0.5], [0.18, 0.02]])  # scan 2: first and last pair (wrap)  # fmt: skip
    score = np.array([0.6, 0.9, 0.8, 0.9, 0.9, 0.99, 0.7, 0.97])
    np.testing.assert_array_equal(duplicates(scan, xy, score, 0.07), [1, -1, -1, -1, -1, -1, -1, 5])
    # a chain of three within the radius keeps one; ties keep the earlier
    chain = duplicates(np.zeros(3, int), [[1.0, 0.0], [1.03, 0.0], [1.06, 0.0]], [0.5, 0.5, 0.5], 0.07)
    np.testing.assert_array_equal(chain, [-1, 0, 0])
    assert duplicates(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), 0.07).size == 0


def test_a_housing_split_in_two_is_one_detection():
    """Robots pressed against the observer (centres ~0.178 m) have the middle of their housing
    below the lidar's 0.15 m minimum range, so the housing is two segments, both accepted: with
    suppression one detection each, the kin still found, and the dropped segment says why
    (a swarm scene of the benchmark's generator, training seed)."""
    from detectors.metrics import match
    from kin_envs.detection.benchmark import SPLITS, Condition, _frames, _sample

    fr = _frames([_sample(SPLITS["swarm"], 610_000)], Condition(0.0), 0)
    raw = LearnedKinDetector(reports=False, suppress_duplicates=False).detect_batch(fr.ranges, fr.angles)
    new = LearnedKinDetector(reports=True).detect_batch(fr.ranges, fr.angles)
    dropped = found_raw = found_new = 0
    for f, (a, b) in enumerate(zip(raw, new, strict=True)):
        k = fr.kin["frame"] == f
        kin_xy, care = fr.kin["xy"][k], fr.kin["care"][k]
        kept = {(d.first_beam, d.n_beams) for d in b.detections}
        assert kept <= {(d.first_beam, d.n_beams) for d in a.detections}
        for d in a.detections:
            if (d.first_beam, d.n_beams) not in kept:  # within 7 cm of a kept, higher-scored one
                dropped += 1
                near = [e for e in b.detections if math.hypot(d.x - e.x, d.y - e.y) < 0.07]
                assert near and near[0].score >= d.score
        for dets, n in ((a.detections, "raw"), (b.detections, "new")):
            m = match(np.array([[d.x, d.y] for d in dets]).reshape(-1, 2), kin_xy, 0.1, ~care)
            if n == "raw":
                found_raw += int(m.tp.sum())
            else:
                found_new += int(m.tp.sum())
        n_dup = sum(r.reason.startswith("duplicate") for r in b.reports)
        assert n_dup == len(a.detections) - len(b.detections)
    assert dropped >= 3 and found_new == found_raw  # duplicates gone, no kin lost
    with pytest.raises(ValueError, match="suppress_duplicates"):
        LearnedKinDetector(suppress_duplicates=1)
