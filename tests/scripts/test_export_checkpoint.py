"""scripts/export_checkpoint.py: a .pt's torch-free form for the learned detector, and --check."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from detectors.learned import DEFAULT_CHECKPOINT, LearnedKinDetector, load_npz_checkpoint, npz_path
from tests.scripts.helpers import SCRIPTS, load_script

mod = load_script("export_checkpoint")


def test_shipped_npz_is_current():
    assert mod.check(DEFAULT_CHECKPOINT) is None
    assert mod.main(["--check", "-q"]) == []


def test_export_and_check(tmp_path, capsys):
    pytest.importorskip("torch")
    a = tmp_path / "a.pt"
    shutil.copy(DEFAULT_CHECKPOINT, a)
    with pytest.raises(SystemExit) as e:
        mod.main(["--check", str(a)])
    assert e.value.code == 1 and "a.npz does not exist" in mod.check(a)
    assert mod.main([str(a), "-q"]) == [tmp_path / "a.npz"]
    assert mod.main(["--check", str(a), "-q"]) == []
    ck = load_npz_checkpoint(tmp_path / "a.npz")
    assert ck["weights_sha256"] == load_npz_checkpoint(npz_path(DEFAULT_CHECKPOINT))["weights_sha256"]
    assert LearnedKinDetector(a).checkpoint["npz"] == str(tmp_path / "a.npz")
    # the .pt changed (here: other bytes, same weights) -> the npz is stale until exported again
    a.write_bytes(a.read_bytes() + b"\0")
    assert "made from other bytes" in mod.check(a)
    out = tmp_path / "sub" / "b.npz"
    out.parent.mkdir()
    assert mod.main([str(DEFAULT_CHECKPOINT), "--out", str(out), "-q"]) == [out]
    assert load_npz_checkpoint(out)["source"]["file"] == DEFAULT_CHECKPOINT.name
    with pytest.raises(SystemExit) as e:
        mod.main([str(a), str(DEFAULT_CHECKPOINT), "--out", str(out)])
    assert e.value.code == 2 and "--out takes exactly one checkpoint" in capsys.readouterr().err


def test_bad_checkpoints_are_named(tmp_path):
    pytest.importorskip("torch")
    missing = tmp_path / "missing.pt"
    with pytest.raises(FileNotFoundError, match="missing.pt does not exist"):
        mod.main([str(missing), "-q"])
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt: not a readable torch checkpoint"):
        mod.main([str(junk), "-q"])
    assert not (tmp_path / "junk.npz").exists()
    assert "junk.npz does not exist" in mod.check(junk)


def test_missing_checkpoint_is_one_line_and_exit_2(tmp_path):
    # as every script's bad input: a message naming the file, exit status 2, no traceback
    pytest.importorskip("torch")
    missing = tmp_path / "missing.pt"
    p = subprocess.run([sys.executable, str(SCRIPTS / "export_checkpoint.py"), str(missing)],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert f"export_checkpoint.py: error: learned detector checkpoint {missing} does not exist" in p.stderr
    assert "Traceback" not in p.stderr and not (tmp_path / "missing.npz").exists()
