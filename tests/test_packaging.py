"""Packaging: typed packages, the licence, the changelog, extras, and an sdist that carries the tests.

The sdist and the wheel are built with setuptools' own backend (``setuptools.build_meta``, no network,
no build isolation) from a copy of the checkout's tracked files.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("kin_envs", "detectors", "agents")
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_package_is_typed_and_ships_the_marker():
    data = PYPROJECT["tool"]["setuptools"]["package-data"]
    for pkg in PACKAGES:
        assert (ROOT / pkg / "py.typed").is_file(), pkg
        assert "py.typed" in data.get(pkg, []), pkg


def test_licence_is_mit_in_spdx_form():
    project = PYPROJECT["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    req = " ".join(PYPROJECT["build-system"]["requires"])
    m = re.search(r"setuptools>=(\d+)", req)
    assert m and int(m.group(1)) >= 77  # PEP 639 license expressions


def test_changelog_has_unreleased_and_first_release():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in text and "## [0.1.0]" in text


def test_extras_do_not_pin_torch_to_one_release():
    extras = PYPROJECT["project"]["optional-dependencies"]
    torch = [r for reqs in extras.values() for r in reqs if r.replace(" ", "").startswith("torch")]
    assert torch and not [r for r in torch if "==" in r], torch
    # the Makefile still installs the pinned CPU wheel first (anything else downloads CUDA)
    assert "torch==2.13.0" in (ROOT / "Makefile").read_text()


def test_readme_installs_from_the_clone():
    readme = (ROOT / "README.md").read_text()
    # no install of kin-envs from a package index (it is not published): editable installs of the clone
    assert not re.search(r"pip install (-U )?kin-envs", readme)
    assert 'pip install -e ".[viz]"' in readme


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    src = tmp_path_factory.mktemp("src")
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    if not files:
        pytest.skip("not a git checkout")
    for rel in files.decode().split("\0"):
        if rel and (ROOT / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, src / rel)
    dist = tmp_path_factory.mktemp("dist")
    sdist = dist / _build(src, "build_sdist", dist)
    # the wheel is built from the unpacked sdist: proves the sdist is complete
    unpacked = tmp_path_factory.mktemp("unpacked")
    with tarfile.open(sdist) as t:
        t.extractall(unpacked, filter="data")
    (top,) = unpacked.iterdir()
    wheel = dist / _build(top, "build_wheel", dist)
    return sdist, wheel


def _build(src: Path, hook: str, dist: Path) -> str:
    code = f"import sys; from setuptools import build_meta as b; print('BUILT', b.{hook}(sys.argv[1]))"
    out = subprocess.run([sys.executable, "-c", code, str(dist)], cwd=src, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return next(x for x in out.stdout.splitlines() if x.startswith("BUILT ")).split()[1]


def test_sdist_carries_tests_licence_and_changelog(built):
    sdist, _ = built
    with tarfile.open(sdist) as t:
        names = {n.split("/", 1)[1] for n in t.getnames() if "/" in n}
        pkg_info = t.extractfile(next(n for n in t.getnames() if n.endswith("/PKG-INFO"))).read().decode()
    for must in ("LICENSE", "CHANGELOG.md", "README.md", "tests/conftest.py", "tests/test_packaging.py",
                 "tests/fixtures/paper_scenario2_0.8m_scan.npz", "scripts/main_job.py",
                 "detectors/checkpoints/learned_default.pt", "detectors/checkpoints/learned_default.npz",
                 *(f"{p}/py.typed" for p in PACKAGES)):
        assert must in names, must
    assert not any("__pycache__" in n for n in names)
    assert "License-Expression: MIT" in pkg_info


def test_wheel_has_typed_packages_and_the_checkpoint(built):
    _, wheel = built
    names = set(zipfile.ZipFile(wheel).namelist())
    # every shipped model (learned, beam, tracker), whatever its file type
    shipped = sorted(f"detectors/checkpoints/{f.name}" for f in (ROOT / "detectors/checkpoints").iterdir()
                     if f.is_file() and not f.name.startswith("."))
    assert "detectors/checkpoints/beam_default.npz" in shipped
    for must in (*(f"{p}/py.typed" for p in PACKAGES), *shipped):
        assert must in names, must
    assert not any(n.startswith("tests/") for n in names)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
