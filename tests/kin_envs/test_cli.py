"""kin_envs.cli: the run record every script writes, logging set-up, the optional progress bar; and the
library's logging rule (loggers with a NullHandler, never ``print``)."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import logging
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from kin_envs import cli

ROOT = Path(__file__).resolve().parents[2]


@dataclasses.dataclass(frozen=True)
class _Cfg:
    size: tuple = (1, 2)
    path: Path = Path("a/b")


def test_write_run_info_records_command_config_seed_and_versions(tmp_path):
    args = argparse.Namespace(out=tmp_path, n=3)
    info = cli.write_run_info(tmp_path, args, config=_Cfg(), seed=np.int64(7), argv=["--n", 3],
                              script=str(ROOT / "scripts" / "benchmark.py"), score=math.nan,
                              arr=np.arange(2), status="running")
    on_disk = json.loads((tmp_path / "run.json").read_text())  # strict JSON: NaN written as null
    assert on_disk == info
    assert info["script"] == "scripts/benchmark.py"
    assert info["command"] == [sys.executable, "scripts/benchmark.py", "--n", "3"]
    assert info["args"] == {"out": str(tmp_path), "n": 3}
    assert info["config"] == {"size": [1, 2], "path": "a/b"} and info["seed"] == 7
    assert info["score"] is None and info["arr"] == [0, 1] and info["status"] == "running"
    v = info["versions"]
    assert v["numpy"] == np.__version__ and "python" in v and "gymnasium" in v
    assert "git_commit" in info and info["time"].endswith("+00:00")
    # written again: replaced atomically, no temporary file left
    cli.write_run_info(tmp_path, args, config=None, argv=[], status="done")
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.json"]


def test_write_run_info_without_argv_records_sys_argv(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["scripts/x.py", "--seed", "1"])
    info = cli.write_run_info(tmp_path, config={"a": 1}, filename="config.json")
    assert info["command"] == [sys.executable, "scripts/x.py", "--seed", "1"]
    assert (tmp_path / "config.json").is_file()


def test_setup_logging_levels():
    p = argparse.ArgumentParser()
    cli.add_logging_args(p)
    try:
        assert cli.setup_logging(p.parse_args([])) == logging.INFO
        assert cli.setup_logging(p.parse_args(["-v"])) == logging.DEBUG
        assert logging.getLogger("detectors").level == logging.DEBUG
        assert cli.setup_logging(p.parse_args(["--quiet"])) == logging.WARNING
        assert logging.getLogger("agents").getEffectiveLevel() == logging.WARNING
        assert cli.script_logger("scripts/foo.py").getEffectiveLevel() == logging.WARNING
        with pytest.raises(SystemExit):
            p.parse_args(["-v", "-q"])  # mutually exclusive
    finally:
        for name in cli.LOGGERS:
            logging.getLogger(name).setLevel(logging.NOTSET)


def test_progress_falls_back_without_tqdm(monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm", None)  # import tqdm -> ImportError
    bar = cli.progress(range(3), desc="x", disable=False)
    assert list(bar) == [0, 1, 2]
    bar = cli.progress(total=5)
    bar.update(2)
    bar.set_postfix(a=1)
    bar.close()
    assert bar.n == 2


def test_library_packages_log_and_never_print():
    import agents
    import detectors
    import kin_envs

    for mod in (kin_envs, detectors, agents):
        handlers = logging.getLogger(mod.__name__).handlers
        assert any(isinstance(h, logging.NullHandler) for h in handlers), mod.__name__
    # the command-line front ends print their output and one-line errors: that is what they are for
    front_ends = {ROOT / "kin_envs" / "cli.py", ROOT / "kin_envs" / "commands.py"}
    for pkg in ("kin_envs", "detectors", "agents"):
        for path in (ROOT / pkg).rglob("*.py"):
            if path in front_ends:
                continue
            tree = ast.parse(path.read_text(), str(path))
            calls = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call)
                     and isinstance(n.func, ast.Name) and n.func.id == "print"]
            assert calls == [], f"{path.relative_to(ROOT)} calls print() at lines {calls}: use logging"


def test_detector_from_name(monkeypatch):
    from detectors import GeometricKinDetector
    from detectors.beam_detector import BeamKinDetector

    geo = cli.detector_from_name("geometric")
    assert isinstance(geo, GeometricKinDetector) and not geo.reports  # reports cost time, unused
    assert cli.detector_from_name("geometric", reports=True).reports
    assert isinstance(cli.detector_from_name("beam"), BeamKinDetector)
    with pytest.raises(ValueError, match=r"unknown detector 'nope' \(--detector\)"):
        cli.detector_from_name("nope")
    with pytest.raises(TypeError, match="expected a detector name"):
        cli.detector_from_name(None)
    with pytest.raises(ValueError, match="checkpoint applies to 'learned' and 'beam' only"):
        cli.detector_from_name("geometric", checkpoint="x.pt")
    with pytest.raises(ValueError, match="detector 'beam' is unavailable"):
        cli.detector_from_name("beam", checkpoint="/nonexistent/beam.npz")
    with pytest.raises(ValueError, match="cannot import Missing"):
        cli.detector_from_name("detectors.geometric:Missing")
    with pytest.raises(ValueError, match="has no detect_batch"):
        cli.detector_from_name("detectors.geometric:GeometricParams")
    monkeypatch.setitem(sys.modules, "detectors.learned", None)  # as if the module were not there
    with pytest.raises(ValueError, match="detector 'learned' is unavailable"):
        cli.detector_from_name("learned")


@pytest.fixture
def no_sigint_handler(monkeypatch):
    """run_main installs its SIGINT handler; keep pytest's own."""
    from kin_envs.core import interrupts

    monkeypatch.setattr(interrupts, "install", lambda: False)


def _raise_during_ctrl_c(cleanup_error: Exception):
    def main():
        try:
            raise KeyboardInterrupt
        finally:
            raise cleanup_error  # a library's clean-up failing while the Ctrl-C unwinds

    return main


@pytest.mark.parametrize("error", [ValueError("Can't close the ZIP file"), RuntimeError("torn")])
def test_run_main_treats_an_error_raised_during_ctrl_c_as_the_interrupt(error, capsys, no_sigint_handler):
    with pytest.raises(SystemExit) as stop:
        cli.run_main(_raise_during_ctrl_c(error))
    assert stop.value.code == cli.EXIT_INTERRUPTED
    assert "interrupted (Ctrl-C)" in capsys.readouterr().err


def test_run_main_treats_an_error_after_its_ctrl_c_as_the_interrupt(capsys, monkeypatch, no_sigint_handler):
    """A C extension can swallow the KeyboardInterrupt and raise its own error with no trace of it
    (matplotlib's Agg renderer: "Invalid bounding box", seen in CI): after the handler has raised a
    Ctrl-C, any error ends the script as interrupted."""
    import signal

    from kin_envs.core import interrupts

    monkeypatch.setattr(interrupts, "_raised", False)

    def main():
        try:
            interrupts._handler(signal.SIGINT, None)
        except KeyboardInterrupt:
            pass  # swallowed, as the C code does
        raise ValueError("Invalid bounding box")

    with pytest.raises(SystemExit) as stop:
        cli.run_main(main)
    assert stop.value.code == cli.EXIT_INTERRUPTED
    assert "interrupted (Ctrl-C)" in capsys.readouterr().err

    def no_ctrl_c():
        raise ValueError("Invalid bounding box")

    monkeypatch.setattr(interrupts, "_raised", False)  # without a Ctrl-C the same error is bad input
    with pytest.raises(SystemExit) as stop:
        cli.run_main(no_ctrl_c)
    assert stop.value.code == 2 and "interrupted" not in capsys.readouterr().err


def test_run_main_bad_input_and_other_errors(capsys, monkeypatch, no_sigint_handler):
    def bad():
        raise ValueError("--noise must be in [0, 0.2]")

    with pytest.raises(SystemExit) as stop:
        cli.run_main(bad)
    assert stop.value.code == 2 and "--noise must be" in capsys.readouterr().err

    def missing():  # a missing input file is bad input too: one line naming it, not a traceback
        raise FileNotFoundError("learned detector checkpoint /tmp/x.pt does not exist")

    with pytest.raises(SystemExit) as stop:
        cli.run_main(missing)
    assert stop.value.code == 2 and "/tmp/x.pt does not exist" in capsys.readouterr().err

    def no_torch():  # a training script on the core install: the extra to install, not a traceback
        import importlib

        importlib.import_module("torch")

    with monkeypatch.context() as m:
        m.setitem(sys.modules, "torch", None)  # as on the core install: torch cannot be imported
        with pytest.raises(SystemExit) as stop:
            cli.run_main(no_torch)
    assert stop.value.code == 2
    assert "needs torch, which is not installed: pip install 'kin-envs[train]'" in capsys.readouterr().err

    def bad_submodule():  # an installed optional package, a wrong import inside it: a bug, kept
        import importlib

        importlib.import_module("pytest.definitely_not_a_submodule")

    with pytest.raises(ModuleNotFoundError):
        cli.run_main(bad_submodule)

    def unknown_module():  # not an optional dependency of ours: a real error, kept
        import importlib

        importlib.import_module("no_such_module_anywhere")

    with pytest.raises(ModuleNotFoundError):
        cli.run_main(unknown_module)

    def broken():
        raise RuntimeError("a real bug")

    with pytest.raises(RuntimeError, match="a real bug"):
        cli.run_main(broken)


@pytest.mark.parametrize("edges", [[1.0], [1.0, 0.5], [0.3, 0.3], [-0.1, 1.0]])
def test_check_distance_bins_names_the_option(edges):
    from kin_envs.cli import check_distance_bins

    with pytest.raises(ValueError, match=r"--bins must be >= 2 increasing distances >= 0"):
        check_distance_bins(edges)
    assert check_distance_bins([0, 1, 2.5]) == [0.0, 1.0, 2.5]


def test_every_optional_package_maps_to_an_extra_of_pyproject():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    extras = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    extras = extras["project"]["optional-dependencies"]
    assert set(cli.EXTRA_OF.values()) <= set(extras)


def test_help_shows_defaults_once():
    import argparse

    from kin_envs.cli import add_logging_args

    p = argparse.ArgumentParser(formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", type=int, default=30, help="number of scenes")
    p.add_argument("--noise", type=float, default=0.0, help="range noise")
    p.add_argument("--out", default="outputs/x", help="output directory (default: outputs/x)")
    p.add_argument("--flag", action="store_true", help="a switch")
    p.add_argument("--opt", default=None, help="optional")
    add_logging_args(p)
    add_logging_args(argparse.ArgumentParser())  # another parser: its own formatter
    text = " ".join(p.format_help().split())
    assert "number of scenes (default: 30)" in text and "range noise (default: 0.0)" in text
    assert text.count("default: outputs/x") == 1
    assert "a switch (default" not in text and "optional (default" not in text
    assert issubclass(p.formatter_class, argparse.RawDescriptionHelpFormatter)
