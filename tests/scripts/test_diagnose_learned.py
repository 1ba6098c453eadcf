"""scripts/diagnose_learned.py: the error breakdown on the benchmark's swarm generator (training seeds)."""

import json

import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("torch")


def test_breakdown_adds_up(tmp_path):
    mod = load_script("diagnose_learned")
    res = mod.main(["--scenes", "1", "--noise", "0.01", "--out", str(tmp_path), "--no-progress", "-q",
                    "--stages"])  # fmt: skip
    for b, r in res["1 %"].items():
        assert r["found"] + r["missed"] == r["counted_kin"]
        assert sum(r["fp_kinds"].values()) == r["fp"] and sum(r["miss_causes"].values()) == r["missed"]
        # the stage breakdown sees the same detections and kin, split by beams on target
        rows = res["stages"]["1 %"][b].values()
        assert sum(s["kin"] for s in rows) == r["counted_kin"] and sum(s["found"] for s in rows) == r["found"]
        assert sum(s["fp"] for s in rows) == r["fp"]  # (tp_det: binned by the detection's range)
        for s in rows:
            assert sum(s["causes"].values()) == s["kin"] - s["found"]
            assert sum(s["fp_kinds"].values()) == sum(s["fp_margin"].values()) == s["fp"]
    assert json.loads((tmp_path / "results.json").read_text()) == res
    assert (tmp_path / "run.json").is_file()


def test_refuses_benchmark_seeds(tmp_path, capsys):
    mod = load_script("diagnose_learned")
    with pytest.raises(SystemExit):
        mod.main(["--first-seed", "2010000000", "--out", str(tmp_path)])
    assert "reserved" in capsys.readouterr().err
