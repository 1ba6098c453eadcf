"""detectors.fileio: atomic writes leave either the old file or the new one, never a partial one."""

import hashlib
import os
import stat

import pytest

from detectors.fileio import atomic_write, sha256_file, write_json


def test_atomic_write_replaces_and_cleans_up(tmp_path):
    p = tmp_path / "a.json"
    write_json(p, {"x": 1})
    assert p.read_text() == '{\n  "x": 1\n}\n'
    with pytest.raises(RuntimeError), atomic_write(p, "w") as f:
        f.write("partial")
        raise RuntimeError("interrupted")
    assert p.read_text() == '{\n  "x": 1\n}\n'  # the old file survives
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json"]  # no temporary left behind
    with atomic_write(p) as f:
        f.write(b"new")
    assert p.read_bytes() == b"new"
    assert sha256_file(p) == hashlib.sha256(b"new").hexdigest()
    mask = os.umask(0o022)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask  # not mkstemp's private 0600


def test_atomic_write_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"), atomic_write(tmp_path / "no" / "a"):
        pass
    with pytest.raises(ValueError, match="mode"), atomic_write(tmp_path / "a", "a"):
        pass
