"""scripts/train_beam_detector.py: a tiny end-to-end run (data, training, calibration, checkpoint)."""

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from detectors.beam_detector import BeamKinDetector, load_beam_dataset  # noqa: E402
from tests.scripts.helpers import load_script  # noqa: E402

script = load_script("train_beam_detector")


def test_tiny_run_writes_a_loadable_calibrated_checkpoint(tmp_path):
    out = tmp_path / "run"
    run = script.main([
        "--out", str(out), "--scenes", "8", "--shard-scenes", "4", "--val-fraction", "0.25",
        "--model-config", '{"hidden": [8]}', "--config", '{"epochs": 1}', "--no-progress",
    ])  # fmt: skip
    manifest = json.loads((out / "data" / "manifest.json").read_text())
    assert [s["n_scenes"] for s in manifest["shards"]] == [4, 4] and all(
        "sha256" in s for s in manifest["shards"]
    )
    records, _ = load_beam_dataset(out / "data")
    assert records["seed"].min() == 0 and records["seed"].max() == 7
    det = BeamKinDetector(out / "beam.npz")
    assert 0.0 <= det.threshold <= 1.0 and run["installed"] is False
    assert det.model.config.hidden == (8,)
    assert json.loads((out / "run.json").read_text())["sha256"] == run["sha256"]
    scan = np.full((2, 360), 1.0)
    assert len(det.detect_batch(scan, records["angles"])) == 2


def test_benchmark_seeds_are_refused(tmp_path):
    with pytest.raises(ValueError, match="reserved for evaluation"):
        script.main(["--out", str(tmp_path), "--scenes", "2", "--first-seed", "999999", "--no-progress"])
