"""The learned detector's cascade: stage-1 inputs equal the full features, survivors' outputs are
unchanged, the switches and the cascade file's checks (issue 14)."""

import json
import shutil

import numpy as np
import pytest

from detectors import _kernels as _k
from detectors.features import (
    CASCADE_FEATURES,
    cascade_features,
    feature_names,
    segment_batch,
    segment_features,
)
from kin_envs import LidarSpec, World, scenes

torch = pytest.importorskip("torch")

from detectors.learned import (  # noqa: E402
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    cascade_path,
    load_cascade,
)

SHIPPED_CASCADE = cascade_path(DEFAULT_CHECKPOINT)


def _arena(noise, seed, n_robots=24, n_obstacles=30):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    scan = World(scene, seed=seed).scan()
    return scan.ranges.astype(np.float64), scan.angles


@pytest.mark.parametrize("noise,seed", [(0.0, 1), (0.01, 2), (0.02, 3)])
def test_cascade_features_are_the_full_features_columns(noise, seed):
    ranges, angles = _arena(noise, seed)
    ranges[0, 5:9] = 0.0  # no-return readings next to segments
    batch = segment_batch(ranges, angles)
    full = segment_features(batch).x
    cols = [feature_names().index(c) for c in CASCADE_FEATURES]
    x = cascade_features(batch)
    assert x.shape == (batch.n_segments, len(CASCADE_FEATURES)) and batch.n_segments > 300
    np.testing.assert_array_equal(x, full[:, cols].astype(np.float64))
    which = np.arange(0, batch.n_segments, 3)
    np.testing.assert_array_equal(cascade_features(batch, which=which), x[which])


def test_shipped_cascade_is_on_by_default_and_met_its_retention():
    if not SHIPPED_CASCADE.is_file():
        pytest.skip("no shipped cascade")
    det = LearnedKinDetector()
    assert det.cascade
    cas = load_cascade(SHIPPED_CASCADE, det.checkpoint["weights_sha256"])
    val = cas["info"]["validation"]
    # scripts/fit_cascade.py's end-to-end check on training seeds other than the fitting ones
    assert val["kin_accepted_kept"] >= 0.999 and val["kin_accepted"] >= 5000
    assert cas["info"]["fit_seeds"][1] < cas["info"]["val_seeds"][0] or cas["info"]["val_seeds"][1] < (
        cas["info"]["fit_seeds"][0]
    )


@pytest.mark.skipif(not SHIPPED_CASCADE.is_file(), reason="no shipped cascade")
@pytest.mark.parametrize("pre_gate", [True, False])
def test_cascade_drops_segments_and_leaves_the_rest_alone(pre_gate):
    on = LearnedKinDetector(inference="blas", pre_gate=pre_gate)
    off = LearnedKinDetector(inference="blas", pre_gate=pre_gate, cascade=False)
    assert on.cascade and not off.cascade
    n_dropped = n_seg = n_acc = n_lost = 0
    for noise, seed in ((0.0, 4), (0.01, 5), (0.015, 6)):
        ranges, angles = _arena(noise, seed)
        a, b = on.detect_arrays(ranges, angles), off.detect_arrays(ranges, angles)
        np.testing.assert_array_equal(a.seg_first, b.seg_first)
        assert "cascade_score" in a.seg_values and "cascade_score" not in b.seg_values
        score, thr = a.seg_values["cascade_score"], on._cascade["threshold"]
        p_on, p_off = a.seg_values["p_kin"], b.seg_values["p_kin"]
        gated = a.seg_stage == _k.DIAMETER
        assert not gated.any() or pre_gate
        np.testing.assert_array_equal(np.isnan(score), gated)
        dropped = np.isnan(p_on) & ~gated
        np.testing.assert_array_equal(dropped, score < thr)
        np.testing.assert_array_equal(a.seg_stage[dropped], _k.LEARNED)
        # survivors: the same p(kin) (float32 network, rows in other BLAS blocks) and decisions
        keep = ~np.isnan(p_on)
        np.testing.assert_allclose(p_on[keep], p_off[keep], rtol=0, atol=1e-5)
        near = np.abs(p_off - b.seg_values["threshold"]) < 1e-5
        np.testing.assert_array_equal((a.seg_stage == 0)[keep & ~near], (b.seg_stage == 0)[keep & ~near])
        n_dropped += int(dropped.sum())
        n_seg += int((~gated).sum())
        acc_off = b.seg_stage == 0
        n_acc += int(acc_off.sum())
        n_lost += int((acc_off & dropped).sum())
    assert n_dropped > 0.3 * n_seg  # most of the clutter skips the network
    assert n_lost <= max(1, 0.002 * n_acc)  # what the full model accepts survives


def test_cascade_switches_and_file_checks(tmp_path):
    if not SHIPPED_CASCADE.is_file():
        pytest.skip("no shipped cascade")
    # a threshold below the fitted ones (a PR curve's permissive run) turns the default off
    assert not LearnedKinDetector(threshold=0.0).cascade
    with pytest.raises(ValueError, match="below"):
        LearnedKinDetector(threshold=0.0, cascade=True)
    with pytest.raises(ValueError, match="cascade must be"):
        LearnedKinDetector(cascade=1)
    # a checkpoint without a cascade file: default off, True refused
    ck = tmp_path / "m.pt"
    shutil.copy(DEFAULT_CHECKPOINT, ck)
    assert not LearnedKinDetector(ck).cascade
    with pytest.raises(ValueError, match="does not exist"):
        LearnedKinDetector(ck, cascade=True)
    # fitted to other weights: refused by name, or off with a warning by default
    card = json.loads(SHIPPED_CASCADE.read_text())
    cascade_path(ck).write_text(json.dumps({**card, "checkpoint_weights_sha256": "0" * 64}))
    with pytest.raises(ValueError, match="other checkpoint weights"):
        LearnedKinDetector(ck, cascade=True)
    with pytest.warns(UserWarning, match="cascade off"):
        assert not LearnedKinDetector(ck).cascade
    # malformed files
    for bad, match in (
        ({**card, "format": "x"}, "not a learned-detector cascade"),
        ({**card, "features": ["chord"]}, "features"),
        ({**card, "w1": [[1.0]]}, "network"),
        ({**card, "threshold": float("nan")}, "NaN"),
    ):
        path = tmp_path / "bad.cascade.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=match):
            LearnedKinDetector(cascade=path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="JSON"):
        LearnedKinDetector(cascade=path)


@pytest.mark.skipif(not SHIPPED_CASCADE.is_file(), reason="no shipped cascade")
def test_cascade_reports_name_the_stage():
    det = LearnedKinDetector()
    ranges, angles = _arena(0.01, 7)
    res = det.detect_batch(ranges[:4], angles)
    reps = [r for res_b in res for r in res_b.reports]
    dropped = [r for r in reps if r.reason.startswith("cascade:")]
    assert dropped and all(r.stage == "learned" and np.isnan(r.metrics["p_kin"]) for r in dropped)
    assert all(np.isfinite(r.metrics["cascade_score"]) for r in dropped)
