"""scripts/validate_pre_gate.py: a tiny run writes its tables and refuses the benchmark's seeds."""

import json

import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("torch")


def test_tiny_run_counts_what_the_gate_drops(tmp_path):
    script = load_script("validate_pre_gate")
    res = script.main(["--scenes", "3", "--out", str(tmp_path), "--no-progress", "-q"])
    t = res["totals"]
    assert t["segments"] > 0 and 0 <= t["gated"] <= t["segments"] and t["gated_beams"] <= t["beams"]
    assert t["kin_accepted_gated"] <= min(t["kin_accepted"], t["kin_gated"])
    assert sum(c["segments"] for c in res["per_noise"].values()) == t["segments"]
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["totals"]["segments"] == t["segments"] and saved["bounds"]["margin_beams"] == 2
    assert "accepted kin dropped" in (tmp_path / "results.md").read_text()
    assert (tmp_path / "run.json").is_file()


def test_benchmark_seeds_are_refused(tmp_path):
    script = load_script("validate_pre_gate")
    with pytest.raises(ValueError, match="reserved"):
        script.main(["--scenes", "2", "--first-seed", "2000000000", "--out", str(tmp_path)])
