"""scripts/train_classifier.py writes to outputs/ by default; the shipped model only with
--replace-shipped."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from detectors.fileio import sha256_file
from tests.scripts.helpers import load_script

tc = load_script("train_classifier")
SHIPPED = tc.SHIPPED_CHECKPOINT


def test_shipped_checkpoint_location():
    assert SHIPPED.is_file() and SHIPPED.parent.name == "checkpoints"
    assert SHIPPED.parent.parent.name == "detectors"


def test_checkpoint_in_the_shipped_folder_is_refused(tmp_path, capsys):
    before = sha256_file(SHIPPED)
    for ckpt in (SHIPPED, SHIPPED.parent / "mine.pt"):
        with pytest.raises(SystemExit) as e:
            tc.main(["--data", str(tmp_path / "none"), "--out", str(tmp_path), "--checkpoint", str(ckpt)])
        assert e.value.code == 2
        assert "--replace-shipped" in capsys.readouterr().err
    assert not (SHIPPED.parent / "mine.pt").exists() and sha256_file(SHIPPED) == before
    assert not (tmp_path / "run.json").exists()  # refused before any output


def test_replace_shipped_is_explicit_and_exclusive(tmp_path):
    assert tc.checkpoint_path(tmp_path, None, replace_shipped=True) == SHIPPED
    assert tc.checkpoint_path(tmp_path, SHIPPED, replace_shipped=True) == SHIPPED
    assert tc.checkpoint_path(tmp_path, None, replace_shipped=False) == tmp_path / "learned.pt"
    with pytest.raises(ValueError, match="do not also give --checkpoint"):
        tc.checkpoint_path(tmp_path, tmp_path / "x.pt", replace_shipped=True)
    with pytest.raises(ValueError, match=r"x\.npz: give the \.pt path"):  # the npz goes beside the .pt
        tc.checkpoint_path(tmp_path, tmp_path / "x.npz", replace_shipped=False)


def test_replace_shipped_run_records_the_shipped_checkpoint(tmp_path):
    pytest.importorskip("torch")
    before = sha256_file(SHIPPED)
    with pytest.raises(SystemExit, match="no such|not found|does not exist|manifest"):
        tc.main(["--data", str(tmp_path / "none"), "--out", str(tmp_path), "--replace-shipped",
                 "--no-progress"])  # fmt: skip
    # (it once recorded, and would have written, OUT/learned.pt)
    assert Path(json.loads((tmp_path / "run.json").read_text())["checkpoint"]) == SHIPPED
    assert sha256_file(SHIPPED) == before


def test_default_output_is_under_outputs(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit, match="no such|not found|does not exist|manifest"):
        tc.main(["--data", str(tmp_path / "none"), "--no-progress"])
    run = json.loads((tmp_path / "outputs" / "train_classifier" / "run.json").read_text())
    assert Path(run["checkpoint"]) == Path("outputs/train_classifier/learned.pt")
    assert run["args"]["replace_shipped"] is False and "--data" in run["command"]
