"""scripts/evaluate_detectors.py: a tiny sweep writing markdown, JSON and PNGs; detector names."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "evaluate_detectors.py"


def load_script():
    spec = importlib.util.spec_from_file_location("evaluate_detectors_under_test", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def mod():
    return load_script()


def test_tiny_sweep_writes_tables_json_and_plots(mod, tmp_path):
    argv = [
        "--scenes", "3", "--noise", "0", "0.01", "--out", str(tmp_path), "--no-progress",
        "--detectors", "geometric", "detectors.geometric:GeometricKinDetector",
    ]  # fmt: skip
    res = mod.main(argv)
    evals = res["evaluations"]
    assert list(evals) == ["geometric", "detectors.geometric:GeometricKinDetector"]
    a, b = evals.values()
    assert a.n_scans == b.n_scans == 3 * 2
    assert a.metrics() == b.metrics()  # the same detector, however it is named
    assert a.metrics().n_kin > 0
    md = (tmp_path / "results.md").read_text()
    for heading in (
        "Per noise level",
        "Per distance bin",
        "valid beams",
        "False positives",
        "Speed",
        "Paper",
    ):
        assert heading in md
    assert "| geometric | II | 0.5 m | yes | 1 × cylinder r=3.5 cm (kin radius) |" in md
    assert "seeds 1000000–1000002" in md
    for png in ("f1_vs_distance.png", "centre_error_vs_distance.png"):
        data = (tmp_path / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    results = json.loads((tmp_path / "results.json").read_text())  # strict JSON: NaN written as null
    assert set(results["detectors"]) == set(evals)
    assert len(results["detectors"]["geometric"]["per_distance"]["0.01"]) == 9
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["seeds"]["first"] == 1_000_000 and run["seeds"]["count"] == 3
    assert run["noise_levels"] == [0.0, 0.01] and run["scene_config"]["n_kin"] == 3


def test_sweep_is_seeded(mod):
    cfg = mod.DetectionSceneConfig()
    one = mod.sweep_pairs(2, 1_000_000, [0.0, 0.02], cfg, progress=False)
    two = mod.sweep_pairs(2, 1_000_000, [0.0, 0.02], cfg, progress=False)
    assert all(
        (s1.ranges == s2.ranges).all() and c1 == c2 for (s1, c1), (s2, c2) in zip(one, two, strict=True)
    )
    assert (one[0][0].ranges != one[1][0].ranges).any()  # the noisy scan differs


def test_detector_names(mod, monkeypatch):
    from detectors import GeometricKinDetector

    assert isinstance(mod.resolve_detector("geometric"), GeometricKinDetector)
    with pytest.raises(ValueError, match="unknown detector 'nope'"):
        mod.resolve_detector("nope")
    with pytest.raises(ValueError, match="cannot import Missing"):
        mod.resolve_detector("detectors.geometric:Missing")
    with pytest.raises(ValueError, match="has no detect_batch"):
        mod.resolve_detector("detectors.geometric:GeometricParams")
    monkeypatch.setitem(sys.modules, "detectors.learned", None)  # as if the module were not there
    with pytest.raises(ValueError, match="detector 'learned' is unavailable"):
        mod.resolve_detector("learned")


@pytest.mark.parametrize("argv, match", [
    (["--gate", "0"], "gate must be a finite distance > 0 m"),
    (["--gate", "nan"], "gate must be a finite distance > 0 m"),
    (["--detectors", "nope"], "unknown detector"),
    (["--noise", "-0.01"], "noise levels must be >= 0"),
    (["--scenes", "0"], "scenes"),
    (["--scene-config", '{"n_kin": 2, "colour": 1}'], "unknown key"),
])  # fmt: skip
def test_bad_inputs_raise(mod, tmp_path, argv, match):
    with pytest.raises(ValueError, match=match):
        mod.main([*argv, "--out", str(tmp_path), "--no-progress"])


def test_cli_error_is_a_message_not_a_traceback(tmp_path):
    cmd = [sys.executable, str(SCRIPT), "--detectors", "nope", "--out", str(tmp_path)]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert p.returncode == 1
    assert "evaluate_detectors: error: unknown detector 'nope'" in p.stderr
    assert "Traceback" not in p.stderr
