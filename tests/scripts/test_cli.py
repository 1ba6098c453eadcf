"""Every script on the core install: ``--help`` works, every option has help text, ``--verbose/--quiet``.

The core install is simulated: one subprocess in which importing any optional dependency (the ``train``,
``viz`` and ``distributed`` extras) raises, the way ``tests/detectors/test_layering.py`` forbids the
simulator. Each script runs as ``python scripts/x.py --help`` would (``runpy``, ``__main__``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(p.name for p in (ROOT / "scripts").glob("*.py"))
#: what ``pip install kin-envs`` (no extras) does not bring
OPTIONAL = ("torch", "tqdm", "matplotlib", "stable_baselines3", "supersuit", "tensorboard", "ray", "pygame",
            "moviepy", "imageio", "PIL")

_CODE = r"""
import argparse, importlib.abc, json, runpy, sys

OPTIONAL = set(sys.argv[2].split(","))

class CoreInstall(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in OPTIONAL:
            raise ImportError(f"No module named {name!r} (core install: optional dependency)")
        return None

sys.meta_path.insert(0, CoreInstall())
parsers = []
_parse = argparse.ArgumentParser.parse_known_args

def parse_known_args(self, *a, **k):
    parsers.append(self)
    return _parse(self, *a, **k)

argparse.ArgumentParser.parse_known_args = parse_known_args
results = {}
for script in sys.argv[3:]:
    parsers.clear()
    sys.argv = [script, "--help"]
    import io, contextlib
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_path(script, run_name="__main__")
        code = "returned without exiting"
    except SystemExit as e:
        code = e.code
    except BaseException as e:
        code = f"{type(e).__name__}: {e}"
    p = parsers[-1] if parsers else None
    opts = [] if p is None else [a for a in p._actions if not isinstance(a, argparse._HelpAction)]
    results[script] = {
        "exit": code,
        "usage": buf.getvalue().startswith("usage:"),
        "no_help": [a.option_strings[0] if a.option_strings else a.dest for a in opts
                    if not a.help or a.help == argparse.SUPPRESS],
        "options": sorted(s for a in opts for s in a.option_strings),
        "help": buf.getvalue(),
        "option_help": {s: a.help for a in opts for s in a.option_strings if isinstance(a.help, str)},
    }
print("RESULTS " + json.dumps(results))
"""


@pytest.fixture(scope="module")
def core_help():
    # rllib script re-execs without PYTHONPATH; a wide terminal: argparse does not wrap "--opt" in two
    env = {**os.environ, "PYTHONHASHSEED": "0", "PYTHONPATH": str(ROOT), "COLUMNS": "1000"}
    out = subprocess.run(
        [sys.executable, "-c", _CODE, str(ROOT), ",".join(OPTIONAL),
         *(str(ROOT / "scripts" / s) for s in SCRIPTS)],
        capture_output=True, text=True, timeout=600, cwd=ROOT, env=env,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    line = next(x for x in out.stdout.splitlines() if x.startswith("RESULTS "))
    return {Path(k).name: v for k, v in json.loads(line[len("RESULTS "):]).items()}


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_runs_on_the_core_install(core_help, script):
    r = core_help[script]
    assert r["exit"] == 0 and r["usage"], r


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_option_has_help_text(core_help, script):
    assert core_help[script]["no_help"] == []


@pytest.mark.parametrize("script", SCRIPTS)
def test_verbose_and_quiet_flags(core_help, script):
    opts = core_help[script]["options"]
    assert {"--verbose", "--quiet", "-v", "-q"} <= set(opts)


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_names_only_options_the_script_has(core_help, script):
    # the docstring and option help are the script's spec: an option they name must exist (the
    # benchmark's docstring offered a "--size reduced" it never had); "other.py --opt" is a reference
    r = core_help[script]
    text = re.sub(r"[\w/]+\.py (--[a-z][\w-]*)", "", r["help"])
    named = set(re.findall(r"(?<![\w-])(--[a-z][\w-]*)", text))
    assert named <= {*r["options"], "--help"}, sorted(named - {*r["options"], "--help"})


NAMED_DETECTORS = [s for s in SCRIPTS if "detector_from_name" in (ROOT / "scripts" / s).read_text()]


@pytest.mark.parametrize("script", NAMED_DETECTORS)
def test_detector_options_name_every_detector(core_help, script):
    # kin_envs.cli.detector_from_name takes geometric, learned, beam and module:Class; the help of
    # evaluate_detectors.py (and three tracker scripts) left beam out, or module:Class
    helps = {o: h for o, h in core_help[script]["option_help"].items() if o in ("--detector", "--detectors")}
    assert helps, script
    for opt, text in helps.items():
        assert all(name in text for name in ("geometric", "learned", "beam", "module:Class")), (opt, text)


def test_scripts_write_run_json_through_the_shared_helper():
    # one helper (kin_envs.cli.write_run_info) instead of a copy per script. Not yet converted: the
    # scripts added in parallel (they write run.json with detectors.fileio.write_json, atomically too)
    later = {"benchmark_detectors.py", "train_beam_detector.py"}
    for script in sorted(set(SCRIPTS) - later):
        text = (ROOT / "scripts" / script).read_text()
        assert '"run.json").write_text' not in text, script
        if "run.json" in text:
            assert "write_run_info(" in text, script


def test_scripts_skip_figures_without_matplotlib(tmp_path, monkeypatch):
    # a .[distributed] (or core) install has no matplotlib: tables and JSON, a warning, no crash
    from tests.scripts.helpers import load_script

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    ev = load_script("evaluate_detectors")
    res = ev.main(["--scenes", "1", "--noise", "0", "--detectors", "geometric", "--out", str(tmp_path / "ev"),
                   "--no-progress", "--quiet"])
    assert res["results"]["figures"] == [] and (tmp_path / "ev" / "results.md").is_file()
    assert not list((tmp_path / "ev").glob("*.png"))
    rp = load_script("reproduce_paper")
    res = rp.main(["--distances", "0.5", "--draws", "0", "--repeats", "1", "--out", str(tmp_path / "rp"),
                   "--quiet"])
    assert res["figures"] == [] and (tmp_path / "rp" / "reproduction.md").is_file()
