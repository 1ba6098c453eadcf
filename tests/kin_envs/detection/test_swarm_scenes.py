"""kin_envs.detection.swarm_scenes and beam_dataset: swarm layouts, per-beam labels, training seeds."""

import numpy as np
import pytest

from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.detection.beam_dataset import beam_records
from kin_envs.detection.dataset import DatasetConfig, scene_records
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds
from kin_envs.detection.swarm_scenes import SwarmSceneConfig, swarm_scene, swarm_world


def test_swarm_scene_is_seeded_and_has_clusters_and_robots_at_walls():
    a = swarm_scene(np.random.default_rng(3))
    b = swarm_scene(np.random.default_rng(3))
    assert a.to_dict() == b.to_dict()
    cfg = SwarmSceneConfig()
    assert cfg.n_robots[0] <= len(a.robots) <= cfg.n_robots[1]
    touching = walls = 0
    for k in range(6):
        s = swarm_scene(np.random.default_rng(k))
        xy = np.array([(r.x, r.y) for r in s.robots])
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        d[np.diag_indices_from(d)] = np.inf
        rb = s.robot.body_radius
        touching += int((d.min(axis=1) < 2 * rb + 0.06).sum())
        hx = s.arena.half_extents[0]
        walls += int((np.abs(xy).max(axis=1) > hx - rb - 0.06).sum())
    assert touching > 0 and walls > 0


def test_swarm_world_moves_robots_and_labels_follow_them():
    rng = np.random.default_rng(0)
    world = swarm_world(rng, SwarmSceneConfig(steps=(5, 5)), LidarSpec())
    start = np.array([(r.x, r.y) for r in world.scene.robots])
    assert np.abs(world.poses[:, :2] - start).max() > 0.01  # driven, so labels must use world.poses
    rec = beam_records(7, DatasetConfig(swarm_prob=1.0, max_observers=3, zero_noise_prob=1.0))
    assert rec["ranges"].shape == rec["label"].shape and rec["centre"].shape == (*rec["ranges"].shape, 2)
    assert (rec["family"] == 3).all() and rec["label"].any()
    lab = rec["label"] > 0
    # a kin beam's return lies on the housing circle around its labelled centre
    ang = LidarSpec().angles
    rows, beams = np.nonzero(lab)
    r = rec["ranges"][rows, beams]
    px, py = r * np.cos(ang[beams]), r * np.sin(ang[beams])
    c = rec["centre"][rows, beams]
    assert np.allclose(np.hypot(px - c[:, 0], py - c[:, 1]), 0.035, atol=2e-3)
    assert np.isnan(rec["centre"][~lab]).all()


def test_dataset_swarm_family_and_dropout():
    cfg = DatasetConfig(swarm_prob=1.0, dropout_share=1.0, dropout=(0.05, 0.05), max_observers=2)
    segs, objs, info = scene_records(11, cfg)
    assert info["family"] == 3 and info["dropout"] == 0.05
    assert (segs["family"] == 3).all()
    # old configs draw exactly what they drew before (no extra random numbers)
    a, _, ia = scene_records(5, DatasetConfig(max_observers=2))
    assert ia["family"] in (0, 1) and ia["dropout"] == 0.0


def test_training_seeds_are_disjoint_from_evaluation_seeds():
    assert TRAINING_SEEDS.stop <= 1_000_000  # the evaluation sweep and the benchmark start here
    check_training_seeds([0, 999_999], within=TRAINING_SEEDS)
    check_training_seeds(TRAINING_SEEDS, within=TRAINING_SEEDS)
    with pytest.raises(ValueError, match="reserved for evaluation"):
        check_training_seeds([1_000_000], within=TRAINING_SEEDS)
    with pytest.raises(ValueError, match="training seed -1 "):
        check_training_seeds(range(-1, 5), within=TRAINING_SEEDS)
    with pytest.raises(ValueError, match="training seed 1000000 "):
        check_training_seeds(range(999_990, 1_000_001), within=TRAINING_SEEDS)
    check_training_seeds([1_000_000])  # without ``within`` only the benchmark's seeds are refused
    with pytest.raises(ValueError, match="training seed"):
        beam_records(1_000_123)


def test_bad_swarm_config():
    with pytest.raises(ValueError, match="unknown key"):
        SwarmSceneConfig.from_dict({"robots": 3})
    with pytest.raises(ValueError, match="probability"):
        SwarmSceneConfig(cluster_prob=2.0)
    assert HitKind.ROBOT is not None
