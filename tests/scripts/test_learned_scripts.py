"""scripts/make_dataset.py and scripts/train_classifier.py: a tiny end-to-end run in subprocesses."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def run(script, *args, check=True):
    cmd = [sys.executable, str(ROOT / "scripts" / script), *map(str, args), "--no-progress"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    if check and out.returncode != 0:
        raise AssertionError(f"{script} failed ({out.returncode}):\n{out.stdout}\n{out.stderr}")
    return out


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("segments")
    run("make_dataset.py", "--out", out, "--scenes", 4, "--shard-scenes", 3, "--first-seed", 10)
    return out


def test_make_dataset_writes_shards_and_manifest(dataset):
    from detectors.features import FEATURE_VERSION
    from kin_envs.detection.dataset import load_dataset

    manifest = json.loads((dataset / "manifest.json").read_text())
    assert manifest["feature_version"] == FEATURE_VERSION
    assert manifest["seeds"] == {"first": 10, "count": 4}
    assert [s["n_scenes"] for s in manifest["shards"]] == [3, 1]
    assert manifest["command"][-1] == "--no-progress" and "--scenes" in manifest["command"]
    counts = manifest["counts"]
    assert counts["kin"] > 0 and counts["kin"] + counts["non_kin"] == counts["segments"]
    segs, objs, _ = load_dataset(dataset)
    assert segs["label"].shape[0] == counts["segments"] and int(segs["label"].sum()) == counts["kin"]
    assert set(np.unique(segs["seed"]).tolist()) == {10, 11, 12, 13}
    assert (objs["n_beams"] >= 1).all()


def test_train_classifier_tiny_budget(dataset, tmp_path):
    torch = pytest.importorskip("torch")  # the only reason to skip: CI installs torch
    ckpt = tmp_path / "tiny.pt"
    cfg = json.dumps({"epochs": 1, "hidden": [8], "batch_size": 256})
    run("train_classifier.py", "--data", dataset, "--out", tmp_path / "train", "--checkpoint", ckpt,
        "--config", cfg, "--eval-scenes", 1, "--val-fraction", 0.25, "--calibrate")  # fmt: skip
    side = json.loads(ckpt.with_suffix(".json").read_text())
    thr = side["thresholds"]
    assert len(thr["values"]) == len(thr["noise_edges"]) + 1 == 5 and all(0 < v < 1 for v in thr["values"])
    assert side["epochs_run"] == 1 and side["seed"] == 0 and side["train_config"]["hidden"] == [8]
    assert side["positioning"] in ("regression", "fit") and "--config" in side["command"]
    for name in ("train_log.csv", "validation.json", "eval.json", "eval.md", "config.json"):
        assert (tmp_path / "train" / name).is_file(), name
    assert (tmp_path / "train" / "train_log.csv").read_text().startswith("epoch,train_loss")
    ev = json.loads((tmp_path / "train" / "eval.json").read_text())
    assert ev["first_seed"] == 1_000_000 and set(ev["detectors"]) == {"learned", "learned_fit", "geometric"}

    torch.set_num_threads(1)
    from detectors.learned import LearnedKinDetector
    from kin_envs import World, scenes

    det = LearnedKinDetector(ckpt)
    assert det.positioning == side["positioning"]
    assert det.checkpoint["thresholds"]["values"] == thr["values"]
    scan = World(scenes.paper_scenario(1), seed=0).scan()
    assert len(det.detect_batch(scan.ranges, scan.angles)) == 2


def test_train_classifier_several_datasets_and_easy_share(dataset, tmp_path):
    """Two ``--data`` directories are trained on together; seeds must not overlap; ``--keep-easy``
    and the calibration options are recorded and validated."""
    pytest.importorskip("torch")
    bench = tmp_path / "bench"
    run("make_dataset.py", "--out", bench, "--scenes", 3, "--first-seed", 40, "--config",
        '{"bench_swarm_prob": 0.5, "lookalike_prob": 0.5}')  # fmt: skip
    ckpt = tmp_path / "two.pt"
    cfg = json.dumps({"epochs": 1, "hidden": [8], "batch_size": 256})
    run("train_classifier.py", "--data", dataset, bench, "--out", tmp_path / "train", "--checkpoint", ckpt,
        "--config", cfg, "--val-fraction", 0.3, "--calibrate", "--keep-easy", 0.5,
        "--calib-families", 0, 3, 4, 5, "--min-kin-beams", 2, "--focus-weight", 2)  # fmt: skip
    side = json.loads(ckpt.with_suffix(".json").read_text())
    assert [d["seeds"]["first"] for d in side["data"]] == [10, 40] and side["keep_easy"] == 0.5
    assert side["min_kin_beams"] == 2
    assert side["focus"] == {"weight": 2.0, "beams": [2, 3], "range_m": [1.0, 2.0]}
    n_train = side["split"]["train_segments"]
    total = sum(d["counts"]["segments"] - d["counts"]["same_radius_cylinder"] for d in side["data"])
    assert 0 < n_train < total - side["split"]["val_segments"]  # some easy negatives were dropped
    out = run("train_classifier.py", "--data", dataset, dataset, "--out", tmp_path / "t2", check=False)
    assert out.returncode != 0 and "overlap" in out.stderr
    out = run("train_classifier.py", "--data", dataset, "--out", tmp_path / "t3", "--keep-easy", 0,
              check=False)  # fmt: skip
    assert out.returncode == 2 and "--keep-easy" in out.stderr
    out = run("train_classifier.py", "--data", dataset, "--out", tmp_path / "t4", "--focus-weight", 0,
              check=False)  # fmt: skip
    assert out.returncode == 2 and "--focus-weight" in out.stderr


def test_few_beam_labels_and_focus_weights():
    from tests.scripts.helpers import load_script

    mod = load_script("train_classifier")
    label = np.array([1, 1, 1, 0, 1], np.int8)
    n_beams = np.array([1, 2, 3, 1, 1])
    assert mod.few_beam_labels(label, n_beams, 1).tolist() == [1, 1, 1, 0, 1]
    out = mod.few_beam_labels(label, n_beams, 2)
    assert out.tolist() == [0, 1, 1, 0, 0] and out.dtype == np.int8
    w = mod.focus_weights(np.array([1, 2, 1, 1, 1], np.float32), np.array([2, 3, 4, 2, 2]),
                          np.array([1.5, 1.0, 1.5, 2.0, 0.9]), 3.0, (2, 3), (1.0, 2.0))  # fmt: skip
    assert w.tolist() == [3, 6, 1, 1, 1] and w.dtype == np.float32


def test_scripts_reject_bad_configs(dataset, tmp_path):
    pytest.importorskip("torch")
    out = run("make_dataset.py", "--out", tmp_path, "--config", '{"n_kin": [1, 2], "colour": 3}', check=False)
    assert out.returncode == 2 and "unknown key" in out.stderr
    out = run(
        "train_classifier.py", "--data", dataset, "--out", tmp_path, "--config", '{"epoch": 1}', check=False
    )
    assert out.returncode == 2 and "unknown key" in out.stderr
    out = run("train_classifier.py", "--data", tmp_path / "none", "--out", tmp_path, check=False)
    assert out.returncode != 0 and "manifest" in out.stderr


def test_train_classifier_batch_larger_than_the_data(dataset, tmp_path):
    pytest.importorskip("torch")
    cfg = json.dumps({"epochs": 10, "hidden": [4], "batch_size": 10**6})
    out = run("train_classifier.py", "--data", dataset, "--out", tmp_path, "--config", cfg, check=False)
    assert out.returncode == 2 and "batch_size=1000000 is larger than the" in out.stderr
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_make_dataset_backend_flags_need_ray(tmp_path):
    out = run("make_dataset.py", "--out", tmp_path / "x", "--scenes", 2, "--num-cpus", 2, check=False)
    assert out.returncode == 2 and "--address and --num-cpus need --backend ray" in out.stderr


@pytest.mark.distributed
def test_make_dataset_ray_backend_gives_the_local_shards(dataset, tmp_path):
    pytest.importorskip("ray", reason="the distributed tests run in .venv-ray (make test-distributed)")
    ray_out = tmp_path / "ray"
    run("make_dataset.py", "--out", ray_out, "--scenes", 4, "--shard-scenes", 3, "--first-seed", 10,
        "--backend", "ray", "--num-cpus", 2)  # fmt: skip
    shards = sorted(p.name for p in dataset.glob("*.npz"))
    assert shards == sorted(p.name for p in ray_out.glob("*.npz")) and len(shards) == 2
    for name in shards:
        a, b = np.load(dataset / name), np.load(ray_out / name)
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key])
    ma, mb = (json.loads((d / "manifest.json").read_text()) for d in (dataset, ray_out))
    assert ma["counts"] == mb["counts"] and ma["seeds"] == mb["seeds"] and ma["shards"] == mb["shards"]


# --- issue 16 (point 1): a dataset never lies -------------------------------------------------------


def test_rerun_into_a_dataset_needs_overwrite_and_never_mixes_runs(dataset, tmp_path):
    import shutil

    from kin_envs.detection.dataset import load_dataset

    out = tmp_path / "ds"
    shutil.copytree(dataset, out)
    refused = run("make_dataset.py", "--out", out, "--scenes", 2, "--first-seed", 50, check=False)
    assert refused.returncode == 2 and "--overwrite" in refused.stderr
    run("make_dataset.py", "--out", out, "--scenes", 2, "--shard-scenes", 1, "--first-seed", 50,
        "--overwrite")
    names = sorted(p.name for p in out.iterdir())  # run.json: the command that wrote this dataset
    assert names == ["manifest.json", "run.json", "shard_00000.npz", "shard_00001.npz"]
    assert json.loads((out / "run.json").read_text())["seed"] == 50
    segs, _, manifest = load_dataset(out)
    assert manifest["seeds"] == {"first": 50, "count": 2}
    assert len(segs["label"]) == manifest["counts"]["segments"]
    (out / "notes.txt").write_text("mine")
    kept = run("make_dataset.py", "--out", out, "--scenes", 1, "--overwrite", check=False)
    assert kept.returncode == 2 and "notes.txt" in kept.stderr and (out / "manifest.json").exists()


def test_damaged_or_swapped_shards_are_named(dataset, tmp_path):
    import shutil

    from kin_envs.detection.dataset import load_dataset

    out = tmp_path / "ds"
    shutil.copytree(dataset, out)
    shard = out / "shard_00001.npz"
    good = shard.read_bytes()
    shard.write_bytes(good[: len(good) // 2])  # cut off mid-write
    with pytest.raises(ValueError, match=r"shard_00001\.npz.*SHA-256"):
        load_dataset(out)
    shard.write_bytes((out / "shard_00000.npz").read_bytes())  # a shard from another run
    with pytest.raises(ValueError, match=r"shard_00001\.npz"):
        load_dataset(out)
    # a manifest edited to match a truncated shard: the reader still names the file
    manifest = json.loads((out / "manifest.json").read_text())
    from detectors.fileio import sha256_file

    shard.write_bytes(good[: len(good) // 2])
    manifest["shards"][1]["sha256"] = sha256_file(shard)
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"shard_00001\.npz: unreadable dataset shard"):
        load_dataset(out)
