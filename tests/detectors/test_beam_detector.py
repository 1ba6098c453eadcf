"""detectors.beam_detector: cut-outs, voting, checkpoints and the shipped beam detector."""

import json
import math

import numpy as np
import pytest

from detectors.base import DetectionResult
from detectors.beam_detector import (
    DEFAULT_BEAM_CHECKPOINT,
    BeamConfig,
    BeamKinDetector,
    BeamModel,
    beam_inputs,
    group_votes,
    load_beam_checkpoint,
    save_beam_checkpoint,
)
from kin_envs import LidarSpec, World, scenes

ANGLES = LidarSpec().angles


def random_model(config=None, seed=0):
    c = config or BeamConfig(half_window=3, hidden=(8,), curvature_offsets=1, curvature_scales=1)
    rng = np.random.default_rng(seed)
    dims = [c.n_inputs, *c.hidden, 3]
    w = [
        (rng.normal(size=(a, b)).astype(np.float32), rng.normal(size=b).astype(np.float32))
        for a, b in zip(dims, dims[1:], strict=False)
    ]
    return BeamModel(c, w, np.zeros(c.n_inputs), np.ones(c.n_inputs))


@pytest.fixture(scope="module")
def shipped():
    return BeamKinDetector()


def test_cutouts_treat_zero_nan_inf_and_max_as_no_return():
    cfg = BeamConfig(half_window=2, curvature_offsets=0, curvature_scales=1)
    angles = np.linspace(0.0, -0.2, 12)
    r = np.full((1, 12), 2.0)
    r[0, 3], r[0, 4], r[0, 5], r[0, 6] = 0.0, np.nan, np.inf, 12.0
    x, row, beam = beam_inputs(r, angles, cfg)
    assert x.shape == (8, cfg.n_inputs) and cfg.n_inputs == 4 + 1 + 3
    assert beam.tolist() == [0, 1, 2, 7, 8, 9, 10, 11]  # no cut-out for a beam without return
    sat = math.asinh(100.0)
    # beam 2's right neighbours (3, 4) are no return; its left ones are equal ranges (0)
    assert np.allclose(x[2, :4], [0, 0, sat, sat]) and np.isclose(x[2, 5], 2.0)
    assert x[2, 4] == 0.0  # no curvature without the neighbour's return
    # returns on a circle of the housing's radius read curvature 1 in magnitude
    t = np.linspace(-0.6, 0.6, 5)
    cx = 1.0
    px, py = cx - 0.035 * np.cos(t), 0.035 * np.sin(t)
    rr = np.hypot(px, py)[None]
    xc, _, _ = beam_inputs(rr, np.arctan2(py, px), cfg, circular=False)
    assert np.isclose(abs(xc[2, 4]), 1.0, atol=1e-6)
    with pytest.raises(ValueError, match="angles"):
        beam_inputs(r, angles[:-1], cfg)


def test_grouping_splits_distinct_centres_bridges_gaps_and_the_seam():
    n = 20
    p = np.zeros((1, n))
    cx, cy = np.zeros((1, n)), np.zeros((1, n))
    p[0, 2:5] = 0.9  # one kin ...
    cx[0, 2:5] = 1.0
    p[0, 5:7] = 0.8  # ... touching another, 18 cm away: two detections
    cx[0, 5:7], cy[0, 5:7] = 1.0, 0.18
    p[0, [10, 12]] = 0.7  # a one-beam gap is bridged
    cx[0, [10, 12]] = 2.0
    p[0, [18, 19, 0]] = 0.6  # across the 359/0 seam
    cx[0, [18, 19, 0]] = 3.0
    row, xy, score, beams = group_votes(p, cx, cy, BeamConfig(min_votes=1))
    assert row.tolist() == [0, 0, 0, 0]
    order = np.argsort(xy[:, 0] + xy[:, 1])
    assert np.allclose(xy[order], [[1, 0], [1, 0.18], [2, 0], [3, 0]])
    assert np.allclose(score[order], [0.9, 0.8, 0.7, 0.6])
    assert beams[order].tolist() == [[2, 4, 3], [5, 6, 2], [10, 12, 2], [18, 0, 3]]
    p[0, 5] = 0.0  # the second kin now has one vote: dropped by min_votes=2 (the default)
    assert group_votes(p, cx, cy)[0].size == 3
    # worst case: every beam votes for a centre far from its neighbour's -> one group per beam
    n = 360
    far = np.tile(np.arange(n, dtype=float), (3, 1))
    row, _, _, _ = group_votes(np.ones((3, n)), far, np.zeros((3, n)), BeamConfig(min_votes=1))
    assert row.size == 3 * n


def test_checkpoint_round_trip_and_refusals(tmp_path):
    m = random_model()
    path = save_beam_checkpoint(tmp_path / "m.npz", m, threshold=0.4, info={"a": np.int64(1)})
    m2, header = load_beam_checkpoint(path)
    x = np.random.default_rng(1).normal(size=(5, m.config.n_inputs)).astype(np.float32)
    assert all(np.array_equal(a, b) for a, b in zip(m.forward(x), m2.forward(x), strict=True))
    assert header["threshold"] == 0.4 and header["info"] == {"a": 1}
    with pytest.raises(FileNotFoundError):
        load_beam_checkpoint(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.npz.*not a readable"):
        load_beam_checkpoint(tmp_path / "junk.npz")
    # wrong weight shape: the file names itself and the layer
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["W1"] = arrays["W1"][:, :2]
    np.savez(tmp_path / "shape.npz", **arrays)
    with pytest.raises(ValueError, match=r"shape.npz: inconsistent.*layer 1 must have W \(8, 3\)"):
        load_beam_checkpoint(tmp_path / "shape.npz")
    header = json.loads(arrays["header"].tobytes())
    header["format_version"] = 99
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(tmp_path / "version.npz", **arrays)
    with pytest.raises(ValueError, match="format version 99"):
        load_beam_checkpoint(tmp_path / "version.npz")
    with pytest.raises(ValueError, match="BeamModel: layer 0"):
        BeamModel(m.config, [(np.zeros((3, 8)), np.zeros(8)), m.weights[1]], m.x_mean, m.x_std)
    with pytest.raises(ValueError, match="threshold"):
        save_beam_checkpoint(tmp_path / "t.npz", m, threshold=1.5)
    with pytest.raises(ValueError, match="unknown key"):
        BeamConfig.from_dict({"window": 3})


def test_shipped_checkpoint_is_small_and_loads(shipped):
    assert DEFAULT_BEAM_CHECKPOINT.stat().st_size < 5_000_000
    assert 0.0 < shipped.threshold < 1.0


def test_input_errors_and_batch_consistency(shipped):
    world = World(scenes.random_arena(8, 20, seed=1))
    scan = world.scan()
    batch = shipped.detect_batch(scan.ranges, scan.angles)
    assert len(batch) == scan.ranges.shape[0] and all(isinstance(r, DetectionResult) for r in batch)
    for k in range(scan.ranges.shape[0]):
        single = shipped.detect(scan.ranges[k], scan.angles)
        # float32 matmuls may round differently with the batch size: equal to 1e-6 m
        assert np.allclose([d.x for d in single.detections], [d.x for d in batch[k].detections], atol=1e-6)
    bad = scan.ranges.copy()
    bad[2, 7] = -1.0
    with pytest.raises(ValueError, match=r"ranges\[2, 7\]"):
        shipped.detect_batch(bad, scan.angles)
    with pytest.raises(ValueError, match="angles"):
        shipped.detect_batch(scan.ranges, scan.angles[:-1])
    with pytest.raises(ValueError, match="threshold"):
        BeamKinDetector(threshold=2.0)
    # real RPLIDAR "no return" values change nothing when they replace max range
    r = scan.ranges[0].astype(np.float64)
    none = r >= 12.0
    outs = []
    for v in (12.0, 0.0, np.inf, np.nan):
        rr = r.copy()
        rr[none] = v
        outs.append(np.array([(d.x, d.y, d.score) for d in shipped.detect(rr, scan.angles).detections]))
    assert all(o.shape == outs[0].shape and np.allclose(o, outs[0], atol=1e-6) for o in outs)


@pytest.mark.parametrize("number", [1, 2])
@pytest.mark.parametrize("distance", [0.5, 0.8, 1.2])
def test_shipped_beam_detector_finds_the_kin_of_the_paper_scenes(shipped, number, distance):
    """The kin is found within 2 cm. (Unlike the segment classifier, the beam detector also accepts
    some distractors here - 7 cm prisms, the 3 cm cylinder: see the README's comparison.)"""
    scene = scenes.paper_scenario(number, distance=distance)
    scan = World(scene).scan(robots=[0])
    dets = shipped.detect(scan.ranges[0], scan.angles).detections
    kin = scene.robots[1]
    assert any(math.hypot(d.x - kin.x, d.y - kin.y) < 0.02 for d in dets)


def test_corrupt_beam_checkpoint_is_refused(tmp_path):
    path = save_beam_checkpoint(tmp_path / "m.npz", random_model(), threshold=0.5)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["W0"] = arrays["W0"].copy()
    arrays["W0"][0, 0] += 1e-3
    np.savez(tmp_path / "flipped.npz", **arrays)
    with pytest.raises(ValueError, match=r"flipped\.npz.*SHA-256"):
        load_beam_checkpoint(tmp_path / "flipped.npz")


def test_score_ordering_kin_above_lookalikes(shipped):
    """Kin detections score higher than detections on anything else (noise-free swarm-like scans)."""
    from kin_envs.detection.evaluation import evaluate

    pairs = []
    for s in range(3):
        scene = scenes.detection_scene(999_000 + s)
        pairs.append((World(scene).scan(robots=[0]), scene))
    ev = evaluate(BeamKinDetector(threshold=0.0), pairs, same_radius_separate=True)
    tp = [d.detection.score for d in ev.detections if d.matched]
    fp = [d.detection.score for d in ev.detections if not d.matched and not d.source.same_radius]
    assert tp and np.median(tp) > np.median(fp) if fp else tp


def test_envs_take_detector_beam():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    from kin_envs import aggregation_v2

    env = gym.make("kin_envs/KinSeek-v2", detector="beam", obs_detections="topk")
    check_env(env.unwrapped, skip_render_check=True)
    swarm = aggregation_v2.parallel_env(n_robots=4, detector="beam")
    swarm.reset(seed=0)
    _, _, _, _, infos = swarm.step({a: swarm.action_space(a).sample() for a in swarm.agents})
    assert len(infos) == 4


def test_beam_training_with_ten_steps_in_all():
    """Issue 16 (point 9): 10 optimiser steps in all (e.g. one batch per epoch, 10 epochs) were a
    ZeroDivisionError inside OneCycleLR; they train."""
    pytest.importorskip("torch")
    from detectors.beam_detector import BeamConfig, beam_inputs
    from detectors.beam_training import BeamTrainConfig, train_beam_model

    rng = np.random.default_rng(0)
    angles = -np.arange(360) * (2 * np.pi / 360)
    x, _, _ = beam_inputs(rng.uniform(0.5, 3.0, (1, 360)), angles, BeamConfig())
    y = (rng.random(len(x)) < 0.3).astype(np.float32)
    t = np.zeros((len(x), 2), np.float32)
    w = np.ones(len(x), np.float32)
    _, log = train_beam_model(x, y, t, w, BeamConfig(), BeamTrainConfig(epochs=10, batch_size=len(x)))
    assert len(log) == 10
