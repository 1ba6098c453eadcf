"""kin_envs.detection.dataset: labelling segments from a scan's ground truth, scene mix, loading."""

import json

import numpy as np
import pytest

from detectors.features import FEATURE_VERSION, FeatureConfig, feature_names, segment_batch
from detectors.fileio import sha256_file
from detectors.samples import DATASET_FORMAT_VERSION
from kin_envs import HitKind, World
from kin_envs.detection.dataset import (
    CATEGORIES,
    DATASET_FORMAT,
    DatasetConfig,
    label_scan,
    load_dataset,
    make_scene,
    scene_records,
)
from kin_envs.scenes import Arena, Box, Cylinder, Prism, Robot, Scene, Wall

CAT = {c: k for k, c in enumerate(CATEGORIES)}


def labelled(scene, rows=(0,)):
    world = World(scene, seed=0)
    scan = world.scan(robots=list(rows))
    batch = segment_batch(scan.ranges, scan.angles)
    segs, objs = label_scan(scan, scene, batch, world.poses)
    return scan, batch, segs, objs


def test_hand_built_scene_labels():
    # observer at the origin facing +y (so the kin straight ahead is at x=0 in the world)
    scene = Scene(
        robots=(Robot(0, 0, np.pi / 2), Robot(0.0, 0.8, 0.3)),
        obstacles=(
            Cylinder(x=0.8, y=0.0, radius=0.035),  # same radius as the housing: flagged
            Prism(x=-0.8, y=0.0, sides=6, width=0.07, theta=0.2),  # kin-width hexagon
            Cylinder(x=0.0, y=-0.8, radius=0.09),
            Box(x=0.6, y=0.6, width=0.07, depth=0.07, theta=0.4),
            Wall(x1=-1.2, y1=-1.0, x2=-1.2, y2=1.0),
        ),
        arena=Arena(3, 3, walls=True),
    )
    scan, batch, segs, objs = labelled(scene)
    by_cat = {c: np.flatnonzero(segs["category"] == CAT[c]) for c in CATEGORIES}
    kin = by_cat["kin"]
    assert len(kin) == 1 and segs["label"][kin[0]] == 1 and segs["obj_index"][kin[0]] == 1
    # the kin's centre in the observer frame (x forward, y left): straight ahead at 0.8 m
    np.testing.assert_allclose(segs["centre"][kin[0]], [0.8, 0.0], atol=1e-6)
    assert segs["distance"][kin[0]] == pytest.approx(0.8)
    assert segs["dominant_fraction"][kin[0]] == 1.0
    same = by_cat["same_radius_cylinder"]
    assert len(same) == 1 and segs["same_radius"][same[0]] and segs["label"][same[0]] == 0
    assert segs["obj_radius"][same[0]] == pytest.approx(0.035)
    prism = by_cat["kin_width_prism"]
    assert len(prism) == 1 and segs["obj_sides"][prism[0]] == 6 and segs["label"][prism[0]] == 0
    assert segs["obj_width"][prism[0]] == pytest.approx(0.07)
    assert len(by_cat["cylinder"]) == 1 and segs["obj_radius"][by_cat["cylinder"][0]] == pytest.approx(0.09)
    assert len(by_cat["kin_width_box"]) == 1
    assert len(by_cat["wall"]) >= 1 and len(by_cat["boundary"]) >= 1
    assert segs["label"].sum() == 1 and not segs["same_radius"][segs["label"] == 1].any()
    assert np.isnan(segs["centre"][segs["label"] == 0]).all()
    # the objects table: what the scan sees, kin with its beam count
    okin = objs["category"] == CAT["kin"]
    assert okin.sum() == 1 and objs["obj_index"][okin][0] == 1
    assert objs["n_beams"][okin][0] == scan.visible_robots(0)[1]
    assert objs["x"][okin][0] == pytest.approx(0.8) and objs["y"][okin][0] == pytest.approx(0.0, abs=1e-6)
    assert (objs["hit_kind"][objs["category"] == CAT["same_radius_cylinder"]] == HitKind.CYLINDER).all()


def test_kin_merged_with_the_wall_behind_is_not_kin():
    # a kin 3 cm in front of a wall: one segment (steps < d_th), mostly wall beams -> negative
    scene = Scene(
        robots=(Robot(0, 0, 0), Robot(1.0, 0.0, 0.0)),
        obstacles=(Wall(x1=1.09, y1=-0.5, x2=1.09, y2=0.5, thickness=0.05),),
        arena=Arena(4, 4, walls=False),
    )
    scan, batch, segs, objs = labelled(scene)
    assert batch.n_segments == 1
    assert segs["label"][0] == 0 and segs["category"][0] == CAT["wall"]
    assert 0 < scan.visible_robots(0)[1] < batch.count[0] / 2
    assert (objs["category"] == CAT["kin"]).sum() == 1  # still a visible kin for kin-level metrics


def test_scene_records_columns_and_determinism():
    cfg = DatasetConfig(max_observers=3)
    a, oa, ia = scene_records(5, cfg)
    b, ob, _ = scene_records(5, cfg)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    n = a["label"].shape[0]
    assert a["x"].shape == (n, len(feature_names())) and a["frames"].shape == (n, 4)
    assert set(np.unique(a["observer"])) <= set(ia["observers"].tolist()) and len(ia["observers"]) <= 3
    assert (a["seed"] == 5).all() and (a["noise"] == ia["noise"]).all()
    # a fixed noise level keeps the layout (paired evaluation across noise levels)
    s1, _, _ = make_scene(9, cfg, noise=0.0)
    s2, _, i2 = make_scene(9, cfg, noise=0.02)
    assert s1.robots == s2.robots and s1.obstacles == s2.obstacles and i2["noise"] == 0.02


def test_dataset_config_validation():
    with pytest.raises(ValueError, match="unknown key"):
        DatasetConfig.from_dict({"n_kin": [1, 2], "colour": 1})
    with pytest.raises(ValueError, match="noise"):
        DatasetConfig(noise=(0.02, 0.01))
    with pytest.raises(ValueError, match="detection_prob"):
        DatasetConfig(detection_prob=1.5)
    assert DatasetConfig.from_dict(DatasetConfig().to_dict()) == DatasetConfig()


def write_tiny(tmp_path, feature_version=FEATURE_VERSION):
    segs, objs, _ = scene_records(1)
    np.savez_compressed(tmp_path / "s.npz", **{f"seg_{k}": v for k, v in segs.items()},
                        **{f"obj_{k}": v for k, v in objs.items()})  # fmt: skip
    manifest = {
        "format": DATASET_FORMAT,
        "format_version": DATASET_FORMAT_VERSION,
        "feature_version": feature_version,
        "feature_config": FeatureConfig().to_dict(),
        "feature_names": feature_names(),
        "shards": [{"file": "s.npz", "n_segments": len(segs["label"]), "n_objects": len(objs["row"]),
                    "sha256": sha256_file(tmp_path / "s.npz")}],
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    return segs


def test_load_dataset_round_trip_and_errors(tmp_path):
    segs = write_tiny(tmp_path)
    s, o, m = load_dataset(tmp_path)
    np.testing.assert_array_equal(s["x"], segs["x"])
    with pytest.raises(FileNotFoundError, match="manifest"):
        load_dataset(tmp_path / "nowhere")
    write_tiny(tmp_path, feature_version=FEATURE_VERSION + 1)
    with pytest.raises(ValueError, match="feature version"):
        load_dataset(tmp_path)
    write_tiny(tmp_path)
    (tmp_path / "s.npz").unlink()
    with pytest.raises(FileNotFoundError, match="s.npz"):
        load_dataset(tmp_path)


def test_benchmark_generator_families():
    """``bench_swarm_prob`` / ``lookalike_prob`` draw scenes from the benchmark's generators
    (families 4 / 5), with the scene's noise and dropout applied to a noise-free scan as the
    benchmark does; both 0 leave every older config's scenes unchanged."""
    from kin_envs.detection.benchmark import LookalikeConfig

    old = scene_records(11, DatasetConfig())[0]
    same = scene_records(11, DatasetConfig(bench_swarm_prob=0.0, lookalike_prob=0.0))[0]
    assert all(np.array_equal(old[k], same[k], equal_nan=True) for k in ("x", "label", "category"))
    cfg = DatasetConfig(lookalike_prob=1.0, zero_noise_prob=0.0, noise=(0.01, 0.01))
    segs, objs, info = scene_records(3, cfg)
    assert info["family"] == 5 and (segs["family"] == 5).all() and info["noise"] == 0.01
    lo, hi = LookalikeConfig().distance
    kin = segs["label"] == 1
    assert kin.any() and ((segs["distance"][kin] > lo - 0.05) & (segs["distance"][kin] < hi + 0.05)).all()
    a = scene_records(3, cfg)[0]
    assert np.array_equal(a["x"], segs["x"])  # deterministic
    segs, _, info = scene_records(4, DatasetConfig(bench_swarm_prob=1.0, zero_noise_prob=1.0))
    assert info["family"] == 4 and len(info["observers"]) == DatasetConfig().max_observers
    assert segs["label"].sum() > 0
    scan = info["scan"]  # noise-free: every valid reading is the true range
    valid = scan.ranges < scan.range_max
    assert info["noise"] == 0.0 and np.allclose(scan.ranges[valid], scan.true_ranges[valid])
    with pytest.raises(ValueError, match="bench_swarm_prob"):
        DatasetConfig(bench_swarm_prob=0.7, lookalike_prob=0.5)
    with pytest.raises(ValueError, match="lookalike_prob"):
        DatasetConfig(lookalike_prob=1.5)


# --- candidate windows (issue 11, round 6) -------------------------------------------------------------


def test_window_labels_rule():
    """Kin when >= 2 beams of the window hit one housing and they are most of its beams."""
    from kin_envs.detection.dataset import window_labels

    rows = {  # (hit_kind of the plurality, its beams, the window's beams) -> label
        (HitKind.ROBOT, 2, 2): 1, (HitKind.ROBOT, 2, 3): 1, (HitKind.ROBOT, 4, 7): 1,
        (HitKind.ROBOT, 2, 4): 0, (HitKind.ROBOT, 1, 1): 0, (HitKind.ROBOT, 1, 2): 0,
        (HitKind.ROBOT, 3, 6): 0, (HitKind.WALL, 5, 5): 0, (HitKind.PRISM, 3, 4): 0,
    }  # fmt: skip
    keys = list(rows)
    segs = {
        "hit_kind": np.array([k for k, _, _ in keys], np.int8),
        "n_beams": np.array([n for _, _, n in keys], np.int16),
        "dominant_fraction": np.array([d / n for _, d, n in keys], np.float32),
    }
    assert window_labels(segs).tolist() == list(rows.values())


def test_scene_records_windows_are_labelled_by_their_beams():
    """``windows=WindowConfig()`` appends the candidate windows of the too-wide segments as rows with
    ``window`` 1: each one's label is the benchmark's rule counted beam by beam from the scan's ground
    truth (a loop), its features are those of the window batch, kin windows carry the kin's centre; the
    segment rows are unchanged."""
    from detectors.features import segment_features
    from detectors.windows import WindowConfig

    cfg = DatasetConfig(bench_swarm_prob=1.0, noise=(0.0, 0.0), zero_noise_prob=1.0, max_observers=8)
    plain, objs0, _ = scene_records(110_003, cfg)
    segs, objs, info = scene_records(110_003, cfg, windows=WindowConfig())
    win = info["windows"]
    w = segs["window"] == 1
    assert w.sum() == win.n_windows > 0 and (segs["window"][~w] == 0).all()
    for k in plain:  # the segments first, as without windows
        np.testing.assert_array_equal(segs[k][~w], plain[k])
    for k in objs0:
        np.testing.assert_array_equal(objs[k], objs0[k])
    scan, n = info["scan"], info["scan"].ranges.shape[1]
    labels = []
    for i in range(win.n_windows):
        r = int(win.batch.scan[i])
        beams = (int(win.batch.first[i]) + np.arange(int(win.batch.count[i]))) % n
        robots = scan.hit_index[r, beams][scan.hit_kind[r, beams] == HitKind.ROBOT].tolist()
        best = max((robots.count(x) for x in set(robots)), default=0)
        labels.append(int(best >= 2 and 2 * best > beams.size))
    assert segs["label"][w].tolist() == labels and sum(labels) > 0
    np.testing.assert_array_equal(segs["x"][w], segment_features(win.batch, FeatureConfig()).x)
    kin = w & (segs["label"] == 1)
    assert np.isfinite(segs["centre"][kin]).all() and np.isnan(segs["centre"][w & (segs["label"] == 0)]).all()
    assert (segs["category"][kin] == CAT["kin"]).all()
