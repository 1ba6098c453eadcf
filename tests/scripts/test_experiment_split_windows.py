"""scripts/experiment_split_windows.py (issue 11, rounds 5-6): candidate windows inside segments too wide
for the pre-gate, and the window path through make_dataset.py and train_classifier.py."""

import json

import numpy as np
import pytest

from tests.scripts.helpers import load_script
from tests.scripts.test_learned_scripts import run


def test_runs_and_counts(tmp_path):
    pytest.importorskip("torch")
    mod = load_script("experiment_split_windows")
    res = mod.main(["--scenes", "1", "--noise", "0.01", "--window-threshold", "0.995", "--out", str(tmp_path),
                    "--anchor-stats", "--shipped-round6", "--no-progress", "-q"])  # fmt: skip
    for name in ("shipped", "shipped + r5 windows >= 0.995", "shipped + r6 windows >= 0.995"):
        for r in res[name]["1 %"].values():
            assert r["found"] + r["missed"] == r["counted_kin"]
            assert sum(r["fp_kinds"].values()) == r["fp"]
    c = res["shipped + r5 windows >= 0.995"]["counts"]
    assert c["windows"] > 0 and c["wide"] > 0 and c["accepted"] <= c["windows"]
    c6 = res["shipped + r6 windows >= 0.995"]["counts"]
    assert c6["wide"] == c["wide"] and c6["windows"] < c["windows"]
    st = res["anchor_stats"]["1 %"]["configs"]
    assert st["round 6"]["windows_per_scan"] < st["round 5"]["windows_per_scan"]  # the noise-robust anchor
    for cfg in st.values():
        for b in cfg["merged_kin"].values():
            assert b["with_window"] <= b["in_wide"] <= b["merged"]
    assert json.loads((tmp_path / "results.json").read_text()) == res
    assert (tmp_path / "run.json").is_file() and (tmp_path / "results.md").is_file()


def test_refuses_benchmark_seeds(tmp_path, capsys):
    mod = load_script("experiment_split_windows")
    with pytest.raises(SystemExit):
        mod.main(["--first-seed", "2010000000", "--out", str(tmp_path)])
    assert "reserved" in capsys.readouterr().err


def test_calibrate_window_thresholds_hand_made():
    """The best-F1 grid threshold per noise bin, the pooled one where a bin has too few kin windows."""
    mod = load_script("train_classifier")
    # bin 0 (sigma < 0.004): kin at p 0.9, non-kin at 0.6 -> any threshold in (0.6, 0.9] is perfect
    # bin 1: 10 kin windows only -> the pooled threshold
    p = np.r_[np.full(60, 0.9), np.full(300, 0.6), np.full(10, 0.95), np.full(10, 0.3)]
    y = np.r_[np.ones(60, bool), np.zeros(300, bool), np.ones(10, bool), np.zeros(10, bool)]
    sigma = np.r_[np.zeros(360), np.full(20, 0.01)]
    out = mod.calibrate_window_thresholds(p, y, sigma, [0.004])
    assert 0.6 < out["values"][0] <= 0.9 and out["info"][0]["f1"] == 1.0
    assert out["values"][1] == out["pooled"] and out["info"][1] == {"windows": 20, "kin": 10, "f1": None}
    assert out["pooled_f1"] == 1.0 and out["kin"] == 70 and out["windows"] == 380


def test_window_dataset_training_and_experiment(tmp_path):
    """make_dataset.py --windows writes window rows; train_classifier.py weights the kin windows and
    stores calibrated window thresholds; the experiment loads that checkpoint as 'new + windows'."""
    pytest.importorskip("torch")
    from kin_envs.detection.dataset import load_dataset

    data = tmp_path / "win"
    run("make_dataset.py", "--out", data, "--scenes", 4, "--first-seed", 110_000, "--windows", '{"sag": 0.3}',
        "--config", '{"bench_swarm_prob": 1.0, "max_observers": 8}')  # fmt: skip
    manifest = json.loads((data / "manifest.json").read_text())
    assert manifest["windows"]["anchor"] == "local" and manifest["windows"]["sag"] == 0.3
    segs, _, _ = load_dataset(data)
    w = segs["window"] == 1
    assert w.sum() == manifest["counts"]["windows"] > 0
    assert int(segs["label"][w].sum()) == manifest["counts"]["kin_windows"]
    ckpt = tmp_path / "new.pt"
    cfg = json.dumps({"epochs": 1, "hidden": [8], "batch_size": 256})
    run("train_classifier.py", "--data", data, "--out", tmp_path / "train", "--checkpoint", ckpt,
        "--config", cfg, "--val-fraction", 0.5, "--calibrate", "--window-kin-weight", 5)  # fmt: skip
    side = json.loads(ckpt.with_suffix(".json").read_text())
    wt = side["window_thresholds"]
    assert side["window_kin_weight"] == 5.0 and side["windows"] == [manifest["windows"]]
    assert len(wt["values"]) == len(wt["noise_edges"]) + 1 and all(0 < v < 1 for v in wt["values"])
    assert (tmp_path / "train" / "window_validation.json").is_file()
    mod = load_script("experiment_split_windows")
    res = mod.main(["--scenes", "1", "--noise", "0", "--window-threshold", "--new-checkpoint", str(ckpt),
                    "--out", str(tmp_path / "exp"), "--no-progress", "-q"])  # fmt: skip
    assert set(res) == {"shipped", "new", "new + windows"}
    assert res["new + windows"]["counts"]["windows"] > 0
