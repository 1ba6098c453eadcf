"""scripts/fit_cascade.py: a tiny run fits, writes and validates a cascade; seed misuse is refused."""

import json

import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("torch")


def test_tiny_run_writes_a_cascade_the_detector_loads(tmp_path):
    from detectors.learned import LearnedKinDetector

    script = load_script("fit_cascade")
    res = script.main(
        ["--scenes", "4", "--val-scenes", "3", "--epochs", "3", "--batch-size", "256", "--out", str(tmp_path),
         "--no-progress", "-q"]
    )
    v = res["validation"]["totals"]
    assert v["scenes"] == 3 and v["segments"] > 0 and 0 < v["cascaded"] <= v["segments"] - v["gated"]
    assert v["kin_accepted_lost"] <= v["kin_accepted"] and res["shipped"] is None
    assert sum(c["segments"] for c in res["validation"]["per_noise"].values()) == v["segments"]
    card = json.loads((tmp_path / "learned.cascade.json").read_text())
    assert card["info"]["validation"]["segments"] == v["segments"] and len(card["b1"]) == 16
    det = LearnedKinDetector(cascade=tmp_path / "learned.cascade.json")
    assert det.cascade and det._cascade["threshold"] == res["threshold"]
    assert "accepted kin segments kept" in (tmp_path / "results.md").read_text()
    assert (tmp_path / "run.json").is_file()


def test_seed_misuse_is_refused(tmp_path):
    script = load_script("fit_cascade")
    with pytest.raises(SystemExit):
        script.main(
            ["--scenes", "5", "--val-scenes", "5", "--val-first-seed", "200402", "--out", str(tmp_path)]
        )
    with pytest.raises(ValueError, match="reserved"):
        script.main(["--scenes", "2", "--first-seed", "2000000000", "--out", str(tmp_path)])


def test_windows_are_fitted_and_validated(tmp_path):
    """A checkpoint with candidate windows (the shipped weights with window settings): the windows'
    stage-1 inputs join the fit, and the validation counts the windows' detections (kin ones in the
    retention) from the detector run end to end, with and without the cascade."""
    from detectors.learned import LearnedKinDetector
    from tests.detectors.test_learned_windows import window_checkpoint

    ck = window_checkpoint(tmp_path, values=[0.3] * 5, cascade=False)
    script = load_script("fit_cascade")
    res = script.main(
        ["--checkpoint", str(ck), "--scenes", "6", "--val-scenes", "6", "--epochs", "3", "--batch-size",
         "256", "--out", str(tmp_path / "out"), "--no-progress", "-q"]
    )  # fmt: skip
    v = res["validation"]["totals"]
    assert res["fit"]["windows"] > 0 and v["windows"] > 0 and v["window_accepted"] > 0
    assert v["window_kin_accepted"] <= v["window_accepted"] and v["window_kin_accepted"] <= v["kin_accepted"]
    assert v["window_kin_accepted_lost"] <= v["kin_accepted_lost"]
    assert "Candidate windows (validation)" in (tmp_path / "out" / "results.md").read_text()
    det = LearnedKinDetector(ck, cascade=tmp_path / "out" / "learned.cascade.json")
    assert det.windows and det.cascade
