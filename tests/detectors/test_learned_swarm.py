"""The shipped learned detector on swarm scenes (training-range seeds it was not trained on)."""

import numpy as np
import pytest

pytest.importorskip("torch")

from detectors import LearnedKinDetector  # noqa: E402
from kin_envs.core.lidar import LidarSpec  # noqa: E402
from kin_envs.detection.evaluation import evaluate  # noqa: E402
from kin_envs.detection.swarm_scenes import swarm_world  # noqa: E402


def _pairs(noise, n=6):
    out = []
    for s in range(500_000, 500_000 + n):  # training data uses seeds 0-2,999
        w = swarm_world(np.random.default_rng(s), lidar=LidarSpec(noise_sigma=noise))
        out.append((w.scan(), w.scene))
    return out


@pytest.fixture(scope="module")
def evaluations():
    det = LearnedKinDetector(reports=False)
    permissive = LearnedKinDetector(threshold=0.0, reports=False)
    return {
        noise: (
            evaluate(det, p, same_radius_separate=True),
            evaluate(permissive, p, same_radius_separate=True),
        )
        for noise in (0.0, 0.01)
        for p in [_pairs(noise)]
    }


def _near(ev, lo=0.3, hi=1.0):
    return next(m for a, b, m in ev.by_distance([lo, hi, 2.0]) if a == lo)


def test_kin_score_higher_than_false_positives(evaluations):
    # detections of >= 2 beams, the benchmark's ground truth: the shipped model is trained to give
    # 1-beam segments (never a counted kin there) a low score, kin or not
    for _, permissive in evaluations.values():
        dets = [d for d in permissive.detections if d.detection.n_beams >= 2]
        tp = [d.detection.score for d in dets if d.matched]
        fp = [d.detection.score for d in dets if not d.matched and not d.source.same_radius]
        assert np.median(tp) > 0.5 > np.median(fp)


def test_recall_does_not_drop_when_noise_drops(evaluations):
    r0, r1 = (_near(evaluations[n][0]).recall for n in (0.0, 0.01))
    # the issue: recall was lower without noise than with it; 0.05 allows the sampling error of 6 scenes
    assert r0 >= r1 - 0.05 and r0 > 0.9
    assert _near(evaluations[0.0][0]).f1 > 0.95  # noise-free swarm, 0.3-1 m
