"""scripts/calibrate_thresholds.py: per-noise thresholds re-chosen on the benchmark's swarm generator."""

import numpy as np
import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("torch")


def test_threshold_choice_on_a_hand_made_case():
    """Two expected-beams columns whose kin and look-alikes separate at different scores: one
    threshold cannot serve both, the table finds each column's own (the lowest grid value above the
    column's negatives); the greedy matching gives one kin to the higher-scored of two candidates."""
    mod = load_script("calibrate_thresholds")
    # column 0 (few expected beams): kin 0.9, negatives 0.5; column 1: kin 0.3, negatives 0.2
    score = np.array([0.9, 0.9, 0.5, 0.5, 0.3, 0.3, 0.2, 0.2])
    eb = np.array([1.0, 1.0, 1.0, 1.0, 5.0, 5.0, 5.0, 5.0])
    kin_xy = np.array([[1.0, 0.0], [1.5, 0.0], [0.5, 0.0], [0.6, 0.0]])
    xy = np.array([[1.0, 0.0], [1.5, 0.0], [1.2, 0.5], [1.4, 0.5],
                   [0.5, 0.0], [0.6, 0.0], [0.5, 0.5], [0.7, 0.5]])  # fmt: skip
    cand = {"frame": np.zeros(8, np.int64), "score": score, "xy": xy, "range": np.hypot(*xy.T), "eb": eb,
            "same_radius": np.zeros(8, bool)}  # fmt: skip
    kin = {"frame": np.zeros(4, np.int64), "xy": kin_xy, "range": np.hypot(*kin_xy.T),
           "care": np.ones(4, bool)}  # fmt: skip
    m = mod.greedy_match(cand, kin)
    np.testing.assert_array_equal(m, [0, 1, -1, -1, 2, 3, -1, -1])
    bins = [(0.0, 3.0)]
    t, best = mod.choose(cand, m, kin, bins, [2.0])
    np.testing.assert_allclose(t, [0.51, 0.21])
    assert best == pytest.approx(1.0)
    t1, best1 = mod.choose(cand, m, kin, bins, [])  # one threshold: 0.21 (all kin, 2 false positives)
    np.testing.assert_allclose(t1, [0.21])
    assert best1 == pytest.approx(8 / 10)
    # two candidates on one kin: the higher-scored takes it, the other is a false positive; a candidate
    # on a "don't care" kin and one on a same-radius cylinder are ignored (-2)
    cand2 = {"frame": np.zeros(4, np.int64), "score": np.array([0.6, 0.8, 0.7, 0.9]),
             "xy": np.array([[1.0, 0.01], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]),
             "same_radius": np.array([False, False, False, True])}  # fmt: skip
    kin2 = {"frame": np.zeros(2, np.int64), "xy": np.array([[1.0, 0.0], [2.0, 0.0]]),
            "care": np.array([True, False])}  # fmt: skip
    np.testing.assert_array_equal(mod.greedy_match(cand2, kin2), [-1, 0, -2, -2])


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
    assert "table" not in th  # per noise level by default
    new, old = LearnedKinDetector(out, reports=False), LearnedKinDetector(reports=False)
    assert new.checkpoint["thresholds"]["values"] == th["values"]  # loaded from the checkpoint
    assert new.checkpoint["npz"] == str(tmp_path / "cal.npz")  # its torch-free form, written beside it
    assert new.checkpoint["weights_sha256"] == old.checkpoint["weights_sha256"]
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
    with pytest.raises(SystemExit):
        mod.main([str(DEFAULT_CHECKPOINT), "--out", str(tmp_path / "c.npz")])
    assert "give the .pt path" in capsys.readouterr().err


def test_by_beams_table_is_deterministic_and_read_by_the_detector(tmp_path):
    from detectors.learned import LearnedKinDetector

    mod = load_script("calibrate_thresholds")
    args = ["--scenes", "1", "--no-progress", "-q", "--by-beams", "--beam-edges", "2", "4"]
    a = mod.main([str(_shipped()), "--out", str(tmp_path / "a.pt"), *args])
    b = mod.main([str(_shipped()), "--out", str(tmp_path / "b.pt"), *args])
    assert a["table"] == b["table"] and a["values"] == b["values"]  # same inputs, same thresholds
    assert a["beam_edges"] == [2.0, 4.0] and len(a["table"]) == 5 and all(len(r) == 3 for r in a["table"])
    assert LearnedKinDetector(tmp_path / "a.pt").checkpoint["thresholds"]["table"] == a["table"]


def _shipped():
    from detectors.learned import DEFAULT_CHECKPOINT

    return DEFAULT_CHECKPOINT
