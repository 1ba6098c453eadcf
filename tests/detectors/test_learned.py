"""detectors.learned: the learned kin detector, its checkpoints and its training loop."""

import math
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # the only reason to skip: CI installs torch

from detectors.base import DetectionResult  # noqa: E402
from detectors.features import FEATURE_VERSION, FeatureConfig, feature_names  # noqa: E402
from detectors.learned import (  # noqa: E402
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    ModelConfig,
    SegmentNet,
    TrainConfig,
    check_thresholds,
    load_checkpoint,
    sample_weights,
    save_checkpoint,
    train_segment_net,
)
from kin_envs import LidarSpec, World, scenes  # noqa: E402

torch.set_num_threads(1)
N_FEATURES = len(feature_names())


@pytest.fixture(scope="module")
def shipped():
    return LearnedKinDetector()


def random_model(seed=0, n_features=N_FEATURES):
    torch.manual_seed(seed)
    m = SegmentNet(ModelConfig(n_features, (16, 8)))
    m.set_normalisation(np.zeros(n_features), np.ones(n_features), [0.03, 0.0], [0.01, 0.01])
    return m.eval()


def test_import_detectors_does_not_import_torch():
    code = (
        "import sys, detectors, detectors.features, kin_envs.detection.dataset, kin_envs; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_tiny_training_learns_a_separable_toy_set():
    rng = np.random.default_rng(0)
    n, f = 600, 6
    y = rng.integers(0, 2, n)
    x = rng.normal(size=(n, f)).astype(np.float32)
    x[:, 0] += 4.0 * y  # separable along feature 0
    target = np.where(y[:, None] == 1, np.stack([x[:, 1], x[:, 2]], 1) * 0.01, np.nan).astype(np.float32)
    data = {"x": x, "y": y, "target": target}
    cfg = TrainConfig(hidden=(16,), epochs=15, batch_size=64, lr=1e-2, patience=15)
    model, hist = train_segment_net(data, data, cfg, seed=0, progress=False)
    assert hist[-1]["train_loss"] < 0.5 * hist[0]["train_loss"]
    assert hist[-1]["val_accuracy"] >= 0.98 and hist[-1]["val_f1"] >= 0.98
    with torch.inference_mode():
        out = model(torch.from_numpy(x))
    assert ((out[:, 0] > 0).numpy() == (y == 1)).mean() >= 0.98
    # same seed, same model
    model2, _ = train_segment_net(data, data, cfg, seed=0, progress=False)
    for a, b in zip(model.state_dict().values(), model2.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)


def test_training_input_errors():
    x = np.zeros((4, 3), np.float32)
    ok = {"x": x, "y": np.zeros(4), "target": np.full((4, 2), np.nan)}
    with pytest.raises(ValueError, match="val"):
        train_segment_net(ok, {**ok, "y": np.zeros(3)}, TrainConfig(epochs=1), progress=False)
    with pytest.raises(ValueError, match="non-finite"):
        train_segment_net({**ok, "x": np.full((4, 3), np.nan, np.float32)}, ok, progress=False)
    with pytest.raises(ValueError, match="unknown key"):
        TrainConfig.from_dict({"epochs": 1, "lr_decay": 0.5})


def test_batch_larger_than_the_data_is_refused_and_ten_steps_train():
    """Issue 16 (point 9): a batch larger than the data was a ZeroDivisionError inside OneCycleLR
    (0.1 warm-up x 10 steps); now a ValueError naming batch_size, and 10 steps in all train."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 3)).astype(np.float32)
    d = {"x": x, "y": (x[:, 0] > 0).astype(np.float32), "target": np.full((40, 2), np.nan)}
    with pytest.raises(ValueError, match=r"batch_size=64 is larger than the 40 training segments"):
        train_segment_net(d, d, TrainConfig(hidden=(4,), epochs=10, batch_size=64), progress=False)
    _, hist = train_segment_net(d, d, TrainConfig(hidden=(4,), epochs=10, batch_size=40, patience=10),
                                progress=False)  # fmt: skip
    assert len(hist) == 10 and all(np.isfinite(h["train_loss"]) for h in hist)


def test_checkpoint_round_trip_gives_identical_outputs(tmp_path):
    path = save_checkpoint(tmp_path / "m.pt", random_model(), FeatureConfig(), info={"note": np.float64(1.5)})
    model, ck = load_checkpoint(path)
    x = torch.randn(50, N_FEATURES)
    with torch.inference_mode():
        torch.testing.assert_close(model(x), random_model()(x), rtol=0, atol=0)
    assert ck["feature_version"] == FEATURE_VERSION and ck["info"]["note"] == 1.5
    scan = World(scenes.detection_scene(4), seed=0).scan()
    a = LearnedKinDetector(path, threshold=0.0).detect_batch(scan.ranges, scan.angles)
    b = LearnedKinDetector(path, threshold=0.0).detect_batch(scan.ranges, scan.angles)
    assert [[(d.x, d.y, d.score) for d in r.detections] for r in a] == [
        [(d.x, d.y, d.score) for d in r.detections] for r in b
    ]


def rewrite(src, dst, **changes):
    ck = torch.load(src, weights_only=True)
    ck.update(changes)
    torch.save(ck, dst)
    return dst


def test_bad_checkpoints_are_refused_clearly(tmp_path):
    good = save_checkpoint(tmp_path / "good.pt", random_model(), FeatureConfig())
    missing = tmp_path / "missing.pt"
    with pytest.raises(FileNotFoundError, match="missing.pt.*does not exist"):
        LearnedKinDetector(missing)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(np.random.default_rng(0).bytes(2000))
    with pytest.raises(ValueError, match="junk.pt: not a readable torch checkpoint"):
        LearnedKinDetector(junk)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(ValueError, match="other.pt: not a learned kin detector checkpoint"):
        load_checkpoint(other)
    old = rewrite(good, tmp_path / "old.pt", feature_version=FEATURE_VERSION - 1)
    with pytest.raises(ValueError, match=f"old.pt.*feature version {FEATURE_VERSION - 1}.*retrain"):
        load_checkpoint(old)
    with pytest.raises(ValueError, match=f"old.pt.*feature version {FEATURE_VERSION - 1}.*retrain"):
        LearnedKinDetector(old)
    bad_thr = rewrite(good, tmp_path / "thr.pt", thresholds={"noise_edges": [0.01], "values": [0.5]})
    with pytest.raises(ValueError, match="thr.pt: inconsistent checkpoint.*thresholds"):
        load_checkpoint(bad_thr)
    small = random_model(n_features=10)
    wrong = rewrite(good, tmp_path / "wrong.pt", model_config=small.config.to_dict(),
                    state_dict=small.state_dict())  # fmt: skip
    with pytest.raises(ValueError, match=f"wrong.pt.*10 input features.*{N_FEATURES}"):
        load_checkpoint(wrong)
    ck = torch.load(good, weights_only=True)
    ck["state_dict"]["body.0.weight"] = torch.zeros(3, 3)
    torch.save(ck, tmp_path / "shape.pt")
    with pytest.raises(ValueError, match="shape.pt: inconsistent checkpoint"):
        load_checkpoint(tmp_path / "shape.pt")


def test_thresholds_per_noise_level(tmp_path):
    assert check_thresholds(None) == {"noise_edges": [], "values": [0.5]}
    for bad in ({"noise_edges": [0.01], "values": [0.5]}, {"noise_edges": [0.02, 0.01], "values": [0.5] * 3},
                {"noise_edges": [], "values": [1.5]}, {"edges": [], "values": [0.5]}):  # fmt: skip
        with pytest.raises(ValueError, match="thresholds"):
            check_thresholds(bad)
    # noise-free scans (estimate ~0) take the first threshold, 1 % noise the second
    thr = {"noise_edges": [0.003], "values": [0.2, 0.9]}
    path = save_checkpoint(tmp_path / "t.pt", random_model(), FeatureConfig(), thresholds=thr)
    assert load_checkpoint(path)[1]["thresholds"] == thr
    for sigma, expected in ((0.0, 0.2), (0.01, 0.9)):
        scan = World(scenes.detection_scene(5, lidar=LidarSpec(noise_sigma=sigma)), seed=0).scan(robots=[0])
        det = LearnedKinDetector(path)
        batch, feats, p, _ = det.predict_segments(scan.ranges, scan.angles)
        np.testing.assert_array_equal(det.segment_thresholds(feats), expected)
        res = det.detect(scan.ranges[0], scan.angles)
        assert len(res.detections) == int((p >= expected).sum())
        assert {r.metrics["threshold"] for r in res.reports} == {expected}
        # an explicit threshold overrides the calibrated ones
        fixed = LearnedKinDetector(path, threshold=0.5)
        np.testing.assert_array_equal(fixed.segment_thresholds(feats), 0.5)
        assert len(fixed.detect(scan.ranges[0], scan.angles).detections) == int((p >= 0.5).sum())


def test_sample_weights_and_weighted_training():
    from detectors.samples import category_code

    cats = np.array(
        [category_code(c) for c in ("kin", "kin_width_prism", "kin_width_box", "wall", "cylinder")]
    )
    y = np.array([1, 0, 0, 0, 0])
    w = sample_weights(y, cats, TrainConfig(pos_weight=2.0, hard_weight=4.0))
    np.testing.assert_array_equal(w, [2.0, 4.0, 4.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="hard_weight"):
        TrainConfig(hard_weight=0.0)
    # unit weights train exactly as no weights; heavier negatives push p(kin) down; bad weights refused
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 4)).astype(np.float32)
    y = rng.integers(0, 2, 200)
    x[:, 0] += 4.0 * y
    data = {"x": x, "y": y, "target": np.full((200, 2), np.nan, np.float32)}
    cfg = TrainConfig(hidden=(8,), epochs=5, batch_size=32, lr=1e-2, patience=5)

    def logits(d):
        model, _ = train_segment_net(d, d, cfg, progress=False)
        with torch.inference_mode():
            return model(torch.from_numpy(x))[:, 0]

    plain = logits(data)
    torch.testing.assert_close(logits({**data, "weight": np.ones(200)}), plain)
    assert logits({**data, "weight": np.where(y, 1.0, 3.0)}).mean() < plain.mean()
    with pytest.raises(ValueError, match="weight"):
        train_segment_net({**data, "weight": np.zeros(200)}, data, cfg, progress=False)


def test_detector_argument_and_input_errors(shipped):
    with pytest.raises(ValueError, match="threshold"):
        LearnedKinDetector(threshold=1.5)
    with pytest.raises(ValueError, match="device"):
        LearnedKinDetector(device="not-a-device")
    with pytest.raises(ValueError, match="positioning"):
        LearnedKinDetector(positioning="magic")
    spec = LidarSpec()
    r = np.full(spec.n_beams, 2.0)
    with pytest.raises(ValueError, match="2-D"):
        shipped.detect_batch(r, spec.angles)
    with pytest.raises(ValueError, match="angles"):
        shipped.detect_batch(r[None], spec.angles[:-1])
    bad = r.copy()
    bad[7] = -1.0
    with pytest.raises(ValueError, match=r"ranges\[1\].*ranges\[7\]"):
        shipped.detect_batch(np.stack([r, bad]), spec.angles)
    half = LidarSpec(n_beams=720)
    with pytest.raises(ValueError, match="0.500 deg apart.*1.000 deg"):
        shipped.detect(np.full(720, 2.0), half.angles)
    assert shipped.detect_batch(np.zeros((0, spec.n_beams)), spec.angles) == []


def test_reports_detections_and_batch_consistency(shipped):
    scan = World(scenes.detection_scene(21, lidar=LidarSpec(noise_sigma=0.005)), seed=1).scan()
    batch = shipped.detect_batch(scan.ranges, scan.angles)
    single = [shipped.detect(r, scan.angles) for r in scan.ranges]
    for res, one in zip(batch, single, strict=True):
        assert isinstance(res, DetectionResult)
        np.testing.assert_allclose(
            [(d.x, d.y, d.score) for d in res.detections], [(d.x, d.y, d.score) for d in one.detections],
            rtol=1e-5, atol=1e-6,
        )  # fmt: skip
        acc = [rep for rep in res.reports if rep.accepted]
        assert len(acc) == len(res.detections)
        for rep, det in zip(acc, res.detections, strict=True):
            assert rep.segment.first_beam == det.first_beam and rep.segment.n_beams == det.n_beams
            assert det.score == rep.metrics["p_kin"] >= rep.metrics["threshold"]
            assert det.range == pytest.approx(math.hypot(det.x, det.y))
        for rep in res.reports:
            if rep.stage == "diameter":  # dropped by the pre-gate: too many beams for a housing
                assert math.isnan(rep.metrics["p_kin"]) and rep.segment.n_beams > rep.metrics["max_beams"]
                assert rep.reason.startswith("pre-gate")
                continue
            if rep.reason.startswith("cascade"):  # dropped by the cascade's first stage
                assert rep.stage == "learned" and math.isnan(rep.metrics["p_kin"])
                continue
            assert rep.stage in ("accepted", "learned") and 0.0 <= rep.metrics["p_kin"] <= 1.0
            assert (rep.stage == "accepted") == (rep.metrics["p_kin"] >= rep.metrics["threshold"])
    quiet = LearnedKinDetector(reports=False).detect_batch(scan.ranges, scan.angles)
    assert all(not r.reports for r in quiet)
    assert [len(r.detections) for r in quiet] == [len(r.detections) for r in batch]


@pytest.mark.parametrize("distance", [0.5, 0.8, 1.2])
@pytest.mark.parametrize("number", [1, 2])
def test_shipped_model_on_the_paper_scenarios(shipped, number, distance):
    assert DEFAULT_CHECKPOINT.is_file() and DEFAULT_CHECKPOINT.stat().st_size < 5e6
    scene = scenes.paper_scenario(number, distance=distance)
    res = shipped.detect(World(scene, seed=0).scan(robots=[0]).ranges[0], scene.lidar.angles)
    kin = np.array([distance, 0.0])  # straight ahead
    err = [math.hypot(d.x - kin[0], d.y - kin[1]) for d in res.detections]
    assert min(err) < 0.02, err  # the kin, within 2 cm
    others = [d for d, e in zip(res.detections, err, strict=True) if e >= 0.1]
    if number == 1:
        assert not others  # Scenario I: every cylinder (3, 5, 9, 11 cm) rejected
    else:
        # Scenario II: only the same-radius cylinder (one scan cannot tell it from a kin) may be taken
        cyl = next(o for o in scene.obstacles if o.kind == "cylinder")
        for d in others:
            assert math.hypot(d.x - cyl.x, d.y - cyl.y) < 0.1, (d, "a prism or cuboid was accepted")


def test_every_detector_checks_batch_shapes_the_same_way():
    from detectors import GeometricKinDetector, KinDetector, LearnedKinDetector, validate_batch

    class PerScan(KinDetector):  # the interface's default detect_batch
        def detect(self, ranges, angles):
            raise AssertionError("not reached")

    angles = np.linspace(0, -2 * np.pi, 360, endpoint=False)
    for det in (PerScan(), GeometricKinDetector(), LearnedKinDetector()):
        with pytest.raises(ValueError, match=r"batched ranges must be 2-D \(B, n_beams\), got shape \(360,\)"):  # noqa: E501
            det.detect_batch(np.ones(360), angles)
        with pytest.raises(ValueError, match=r"angles must be 1-D with n_beams = 360"):
            det.detect_batch(np.ones((2, 360)), angles[:359])
    r, a = validate_batch([[1.0, 2.0, 3.0]], [0.0, -2.0, -4.0])
    assert r.dtype == a.dtype == np.float64 and r.shape == (1, 3)


def _scan_of_circles(circles, noise, rng, n=360, d_max=12.0):
    """One 360-beam scan (beam i at +i deg) of circles ``(x, y, radius)`` in an empty world,
    exact ray-circle ranges times ``1 + noise * N(0, 1)``."""
    ang = np.arange(n) * (2 * math.pi / n)
    ux, uy = np.cos(ang), np.sin(ang)
    r = np.full(n, np.inf)
    for cx, cy, rad in circles:
        b = ux * cx + uy * cy
        disc = b * b - (cx * cx + cy * cy - rad * rad)
        hit = (disc >= 0) & (b - np.sqrt(np.maximum(disc, 0)) > 0)
        r = np.where(hit, np.minimum(r, b - np.sqrt(np.maximum(disc, 0))), r)
    r = np.where(np.isfinite(r), r * (1 + noise * rng.standard_normal(n)), d_max)
    return r[None, :], ang


def test_pre_gate_keeps_every_housing_and_drops_wide_objects(shipped):
    from detectors.features import segment_batch

    rng = np.random.default_rng(7)
    r = shipped.feature_config.r
    # a lone housing anywhere from touching the lidar's minimum range to 10 m, 0-3 % noise: never dropped
    n_checked = 0
    for dist in (0.2, 0.25, 0.3, 0.5, 0.8, 1.2, 2.0, 3.5, 6.0, 10.0):
        for noise in (0.0, 0.01, 0.02, 0.03):
            for _ in range(5):
                bearing = rng.uniform(0, 2 * math.pi)
                centre = (dist * math.cos(bearing), dist * math.sin(bearing), r)
                ranges, ang = _scan_of_circles([centre], noise, rng)
                batch = segment_batch(ranges, ang, shipped.feature_config)
                bound = shipped.gate(batch)
                assert (batch.count <= bound).all(), (dist, noise, batch.count, bound)
                n_checked += batch.n_segments
    assert n_checked >= 150  # at 10 m a housing falls between beams now and then
    # a 60 cm cylinder at 1 m and 3 m (a bin, another robot's chassis) is dropped, a 7 cm one kept
    for dist in (1.0, 3.0):
        ranges, ang = _scan_of_circles([(dist, 0.0, 0.3), (0.0, dist, r)], 0.01, rng)
        batch = segment_batch(ranges, ang, shipped.feature_config)
        gated = batch.count > shipped.gate(batch)
        assert batch.n_segments == 2 and gated.sum() == 1 and batch.count[gated][0] > 10
    # the detector's outputs: dropped segments are "diameter" with p_kin NaN, the housing is detected
    ranges, ang = _scan_of_circles([(1.0, 0.0, 0.3), (0.0, 1.0, r)], 0.0, rng)
    arr = shipped.detect_arrays(ranges, ang)
    gated = np.isnan(arr.seg_values["p_kin"])
    assert gated.sum() == 1 and arr.seg_stage[gated][0] == 1
    assert arr.seg_count[gated][0] > arr.seg_values["max_beams"][gated][0]
    assert len(arr.x) == 1 and math.hypot(arr.x[0], arr.y[0] - 1.0) < 0.02
    off = LearnedKinDetector(pre_gate=False, cascade=False).detect_arrays(ranges, ang)
    assert "max_beams" not in off.seg_values and np.isfinite(off.seg_values["p_kin"]).all()
    np.testing.assert_array_equal(off.seg_values["p_kin"][~gated], arr.seg_values["p_kin"][~gated])
    with pytest.raises(ValueError, match="pre_gate"):
        LearnedKinDetector(pre_gate=1)


@pytest.mark.parametrize("hidden", [(16, 8), (40,), (24, 16, 8)])
def test_every_inference_path_runs_any_model_shape(tmp_path, hidden):
    torch.manual_seed(len(hidden))
    m = SegmentNet(ModelConfig(N_FEATURES, hidden))
    m.set_normalisation(np.zeros(N_FEATURES), np.ones(N_FEATURES), [0.03, 0.0], [0.01, 0.01])
    path = save_checkpoint(tmp_path / "m.pt", m.eval(), FeatureConfig())
    scene = scenes.random_arena(12, 20, seed=3).replace(lidar=LidarSpec(noise_sigma=0.01))
    scan = World(scene, seed=3).scan()
    r, a = scan.ranges, scan.angles
    ref = LearnedKinDetector(path, inference="torch", pre_gate=False).detect_arrays(r, a)
    assert ref.seg_scan.shape[0] > 300  # enough segments for "auto" to take the BLAS path
    for inference in ("numba", "blas", "auto"):
        arr = LearnedKinDetector(path, inference=inference, pre_gate=False).detect_arrays(r, a)
        np.testing.assert_allclose(arr.seg_values["p_kin"], ref.seg_values["p_kin"], rtol=0, atol=1e-5)
