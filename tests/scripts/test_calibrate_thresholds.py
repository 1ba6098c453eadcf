"""scripts/calibrate_thresholds.py: per-noise thresholds re-chosen on the benchmark's swarm generator."""

import numpy as np
import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("torch")


def test_recalibrated_copy_keeps_the_weights(tmp_path):
    from detectors.learned import DEFAULT_CHECKPOINT, LearnedKinDetector
    from kin_envs import World, scenes

    mod = load_script("calibrate_thresholds")
    out = tmp_path / "cal.pt"
    th = mod.main([str(DEFAULT_CHECKPOINT), "--out", str(out), "--scenes", "1", "--no-progress", "-q"])
    assert len(th["values"]) == len(th["noise_edges"]) + 1 == 5
    assert all(0.1 <= v <= 0.9 for v in th["values"]) and th["values"][1] == pytest.approx(
        0.5 * (th["values"][0] + th["values"][2])
    )
    assert set(th["info"]["per_level"]) == {"0.0", "0.005", "0.01", "0.02"}
    assert th["values"][0] <= th["values"][2]  # the noise-free threshold never above the 0.5 % one
    new, old = LearnedKinDetector(out, reports=False), LearnedKinDetector(reports=False)
    assert new.checkpoint["thresholds"]["values"] == th["values"]  # loaded from the checkpoint
    scan = World(scenes.paper_scenario(2, distance=0.8), seed=0).scan()
    _, _, p_new, _ = new.predict_segments(scan.ranges, scan.angles)
    _, _, p_old, _ = old.predict_segments(scan.ranges, scan.angles)
    np.testing.assert_array_equal(p_new, p_old)  # same weights


def test_refuses_benchmark_seeds_and_the_shipped_folder(tmp_path, capsys):
    from detectors.learned import DEFAULT_CHECKPOINT
    from kin_envs.detection.benchmark import BENCHMARK_SEEDS

    mod = load_script("calibrate_thresholds")
    with pytest.raises(SystemExit):
        mod.main([str(DEFAULT_CHECKPOINT), "--out", str(tmp_path / "c.pt"), "--first-seed",
                  str(BENCHMARK_SEEDS.start)])  # fmt: skip
    assert "reserved" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mod.main([str(DEFAULT_CHECKPOINT), "--out", str(DEFAULT_CHECKPOINT.with_name("x.pt"))])
    assert "shipped" in capsys.readouterr().err
