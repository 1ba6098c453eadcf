"""Unrelated distributions named ``detectors`` / ``agents`` are detected at import (kin_envs._toplevel).

Each case builds a fake foreign distribution (package folder plus ``.dist-info``) in a temporary
directory put first on ``sys.path`` of a subprocess, as pip would install it into the environment.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _fake_dist(site: Path, name: str, init: str | None = "FOREIGN = True\n") -> None:
    """A distribution ``name`` 9.9 providing the top-level package ``name`` (its ``__init__``: ``init``)."""
    pkg = site / name
    pkg.mkdir(exist_ok=True)
    if init is not None:
        (pkg / "__init__.py").write_text(init)
    info = site / f"{name}-9.9.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 9.9\n")
    (info / "top_level.txt").write_text(f"{name}\n")
    (info / "RECORD").write_text(f"{name}/__init__.py,,\n")


def _run(site: Path, code: str) -> subprocess.CompletedProcess:
    env_path = f"{site}:{ROOT}"
    # cwd: not the checkout (``python -c`` puts the cwd first on sys.path)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=site, env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"})


@pytest.mark.parametrize("name", ["detectors", "agents"])
def test_shadowing_foreign_package_is_named(tmp_path, name):
    _fake_dist(tmp_path, name)
    out = _run(tmp_path, "import kin_envs")
    assert out.returncode != 0
    assert "ImportError" in out.stderr
    assert f"top-level package {name!r} is not kin-envs' own" in out.stderr
    assert "lacks kin-envs' marker" in out.stderr
    assert f"the distribution(s) '{name}'" in out.stderr and "pip uninstall " + name in out.stderr


def test_merged_folder_with_our_init_is_detected(tmp_path):
    # pip installed kin-envs over the foreign dist: our files (and __init__) win, the foreign dist remains
    shutil.copytree(ROOT / "detectors", tmp_path / "detectors", ignore=shutil.ignore_patterns("__pycache__"))
    _fake_dist(tmp_path, "detectors", init=None)
    out = _run(tmp_path, "import kin_envs")
    assert out.returncode != 0
    assert "merged folders" in out.stderr and "'detectors'" in out.stderr


def test_our_submodules_refuse_a_foreign_init(tmp_path):
    # the foreign dist was installed last: its __init__ replaced ours, our modules are still there
    shutil.copytree(ROOT / "detectors", tmp_path / "detectors", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "detectors" / "__init__.py").write_text("FOREIGN = True\n")
    out = _run(tmp_path, "import detectors.geometric")
    assert out.returncode != 0
    assert "is not kin-envs' own" in out.stderr


def test_our_own_packages_pass(tmp_path):
    out = _run(tmp_path, "import kin_envs, agents, detectors; print(agents.__kin_envs_package__)")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"
