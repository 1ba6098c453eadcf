"""detectors.metrics on hand-made cases with known matches, PR curves and AP."""

import math

import numpy as np
import pytest

from detectors.metrics import (
    average_precision,
    frame_increments,
    increments,
    match,
    pr_curve,
    pr_from_increments,
    prf1,
)


def test_perfect_ranking_has_ap_one():
    # two kin, both found with the highest scores; a false positive ranked last
    c = pr_curve([0.9, 0.8, 0.1], [0, 0, 0], [[1, 0], [2, 0], [5, 5]], [0, 0], [[1.02, 0], [2, 0.05]])
    assert c.ap == pytest.approx(1.0)
    np.testing.assert_allclose(c.recall, [0.5, 1.0, 1.0])
    np.testing.assert_allclose(c.precision, [1.0, 1.0, 2 / 3])
    assert c.peak_f1 == pytest.approx(1.0)


def test_false_positive_ranked_first():
    # curve (0, 0), (0.5, 1/2), (1, 2/3): AP = 0.5 * 0.25 + 0.5 * (0.5 + 2/3) / 2 = 5/12
    c = pr_curve([0.9, 0.8, 0.7], [0, 0, 1], [[5, 5], [1, 0], [1, 1]], [0, 1], [[1, 0], [1, 1]])
    np.testing.assert_allclose(c.recall, [0.0, 0.5, 1.0])
    assert c.ap == pytest.approx(5 / 12)


def test_missed_object_caps_ap_at_recall():
    c = pr_curve([0.9], [0], [[1, 0]], [0, 0], [[1, 0], [3, 0]])
    assert c.ap == pytest.approx(0.5)
    assert c.peak_f1 == pytest.approx(2 / 3)


def test_no_detections_ap_zero_and_no_objects_nan():
    assert pr_curve([], [], np.zeros((0, 2)), [0], [[1, 0]]).ap == 0.0
    assert math.isnan(pr_curve([0.5], [0], [[1, 0]], [], np.zeros((0, 2))).ap)


def test_double_detection_is_a_false_positive_and_gate_is_inclusive():
    m = match([[1.0, 0.0], [1.05, 0.0], [1.3, 0.0]], [[1.0, 0.1]], gate=0.1)
    assert m.tp.tolist() == [True, False, False]
    assert m.fp.tolist() == [False, True, True]
    assert m.distance[0] == pytest.approx(0.1)


def test_hungarian_rematching_at_lower_threshold():
    # A (0.9) lies within the gate of both objects, B (0.5) only of the first: greedy would leave
    # B unmatched; re-matching at B's threshold gives two true positives
    det = [[1.05, 0.0], [0.96, 0.0]]
    gt = [[1.0, 0.0], [1.12, 0.0]]
    dtp, dfp = frame_increments([0.9, 0.5], det, gt, gate=0.1)
    assert dtp.tolist() == [1, 1] and dfp.tolist() == [0, 0]
    c = pr_curve([0.9, 0.5], [0, 0], det, [0, 0], gt, gate=0.1)
    assert c.ap == pytest.approx(1.0)


def test_dont_care_objects_and_ignored_detections():
    # the second object is "don't care": detecting it is neither TP nor FP, missing it no FN
    c = pr_curve([0.9, 0.8], [0, 0], [[1, 0], [2, 0]], [0, 0], [[1, 0], [2, 0]], gt_ignore=[False, True])
    assert c.n_gt == 1 and c.tp[-1] == 1 and c.fp[-1] == 0 and c.ap == pytest.approx(1.0)
    # a counted match beats a don't-care one
    m = match([[1.0, 0.0]], [[1.05, 0.0], [1.0, 0.0]], gt_ignore=[False, True])
    assert m.gt.tolist() == [0] and m.tp.tolist() == [True]
    # a det_ignore detection counts when it matches, is left out otherwise
    m = match([[1, 0], [4, 0]], [[1, 0]], det_ignore=[True, True])
    assert m.tp.tolist() == [True, False] and m.fp.tolist() == [False, False]


def test_tied_scores_form_one_point():
    c = pr_curve([0.5, 0.5], [0, 0], [[9, 9], [1, 0]], [0], [[1, 0]])
    assert c.thresholds.tolist() == [0.5]
    assert c.ap == pytest.approx(0.5)  # (0, 0.5) -> (1, 0.5)


def test_increments_with_weights_repeat_frames():
    s, dtp, dfp = [0.9, 0.4], [1, 0], [0, 1]
    a = pr_from_increments(s, dtp, dfp, 2).ap
    b = pr_from_increments(s, dtp, dfp, 4, weights=[2, 2]).ap
    assert a == pytest.approx(b) == pytest.approx(0.5)


def test_average_precision_direct_and_errors():
    assert average_precision([0.5, 1.0], [1.0, 0.5]) == pytest.approx(0.5 + 0.375)
    with pytest.raises(ValueError, match="non-decreasing"):
        average_precision([1.0, 0.5], [1.0, 1.0])
    with pytest.raises(ValueError, match="gate"):
        match([[0, 0]], [[0, 0]], gate=0.0)
    with pytest.raises(ValueError, match="det_xy"):
        match([[0, 0, 0]], [[0, 0]])


def test_prf1():
    assert prf1(8, 2, 8) == pytest.approx((0.8, 0.5, 16 / 26))
    p, r, f = prf1(0, 0, 0)
    assert math.isnan(p) and math.isnan(r) and math.isnan(f)


def test_fast_path_agrees_with_rematching():
    # random frames: the per-object fast path (one object per candidate) and the Hungarian
    # re-matching must give the same increments; compare against a brute-force prefix loop
    rng = np.random.default_rng(0)
    for _ in range(300):
        ng, nd = int(rng.integers(0, 4)), int(rng.integers(0, 7))
        g = rng.uniform(0, 1.0, (ng, 2))
        d = (g[rng.integers(0, ng, nd)] if ng else rng.uniform(0, 1, (nd, 2))) + rng.normal(0, 0.06, (nd, 2))
        s = rng.integers(0, 4, nd).astype(float)  # ties on purpose
        gi, di = rng.random(ng) < 0.3, rng.random(nd) < 0.3
        dtp, dfp = frame_increments(s, d, g, 0.1, gi, di)
        order = np.argsort(-s, kind="stable")
        for k in range(1, nd + 1):
            m = match(d[order[:k]], g, 0.1, gi, di[order[:k]])
            assert dtp[order[:k]].sum() == m.tp.sum()
            assert dfp[order[:k]].sum() == m.fp.sum()


def test_increments_over_frames_agree_with_per_frame_rematching():
    rng = np.random.default_rng(1)
    n_frames = 60
    gf = rng.integers(0, n_frames, 120)
    g = rng.uniform(0, 2.0, (120, 2))
    pick = rng.integers(0, 120, 300)
    df = np.where(rng.random(300) < 0.7, gf[pick], rng.integers(0, n_frames, 300))
    d = np.where((rng.random(300) < 0.7)[:, None], g[pick], rng.uniform(0, 2, (300, 2)))
    d = d + rng.normal(0, 0.05, d.shape)
    s = rng.integers(0, 20, 300).astype(float)
    gi, di = rng.random(120) < 0.2, rng.random(300) < 0.2
    dtp, dfp = increments(s, df, d, gf, g, 0.1, gi, di)
    for f in range(n_frames):
        dm, gm = df == f, gf == f
        a, b = frame_increments(s[dm], d[dm], g[gm], 0.1, gi[gm], di[dm])
        assert dtp[dm].tolist() == a.tolist() and dfp[dm].tolist() == b.tolist()
