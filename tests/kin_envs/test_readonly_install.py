"""Issue 16 (point 8): ``import kin_envs`` (and a scan, and the detector) work from a read-only install
with an unwritable HOME: numba's cache falls back to a writable temporary directory."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0 and shutil.which("setpriv") is None,
                    reason="needs POSIX permissions (and a non-root user or setpriv)")
def test_import_from_a_read_only_install():
    # not pytest's tmp_path: its parents are private to the user, and the check may run as another one
    tmp_path = Path(tempfile.mkdtemp(prefix="kin-envs-readonly-"))
    tmp_path.chmod(0o755)
    pkg = tmp_path / "site"
    for name in ("kin_envs", "detectors", "agents"):  # the whole install (kin_envs checks agents is ours)
        shutil.copytree(ROOT / name, pkg / name, ignore=shutil.ignore_patterns("__pycache__"))
    home = tmp_path / "home"
    home.mkdir()
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    for p in [pkg, *pkg.rglob("*"), home]:
        p.chmod(p.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    code = (
        "import numpy as np, kin_envs, detectors, numba; from kin_envs import World, scenes\n"
        "scan = World(scenes.paper_scenario(1)).scan()\n"
        "r = detectors.GeometricKinDetector().detect(scan.ranges[0], scan.angles)\n"
        f"assert len(r.detections) == 1 and numba.config.CACHE_DIR.startswith({str(scratch)!r})\n"
        "print('ok', numba.config.CACHE_DIR)"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(HOME=str(home), PYTHONPATH=str(pkg), TMPDIR=str(scratch), PYTHONDONTWRITEBYTECODE="1",
               XDG_CACHE_HOME=str(home / ".cache"))
    cmd = [sys.executable, "-c", code]
    if os.geteuid() == 0:  # root writes anywhere: drop to an unprivileged user for the check
        scratch.chmod(0o777)
        cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *cmd]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        assert out.stdout.startswith("ok")
    finally:
        for p in [pkg, *pkg.rglob("*"), home]:
            p.chmod(p.stat().st_mode | stat.S_IWUSR)
        shutil.rmtree(tmp_path, ignore_errors=True)
