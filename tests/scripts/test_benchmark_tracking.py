"""scripts/benchmark_tracking.py: a one-episode run writes every output; bad arguments."""

import json

import pytest

from tests.scripts.helpers import load_script


def test_one_episode_run(tmp_path):
    mod = load_script("benchmark_tracking")
    out = tmp_path / "seq"
    argv = ["--splits", "lookalike", "--episodes", "1", "--noise", "0.01", "--detector", "geometric"]
    results = mod.main([*argv, "--baselines", "--out", str(out)])
    assert [r["split"] for r in results] == ["lookalike"]
    for name in ("results.md", "results.json", "f1_vs_frames.png", "tracks.gif", "run.json"):
        assert (out / name).stat().st_size > 0, name
    run = json.loads((out / "run.json").read_text())
    assert run["sequence_version"] == 1 and "lookalike" in run["splits"]
    assert "Frames since the kin came into view" in (out / "results.md").read_text()


@pytest.mark.parametrize("argv", [["--episodes", "0"], ["--noise", "5"], ["--full", "--episodes", "2"]])
def test_bad_arguments(argv, tmp_path):
    mod = load_script("benchmark_tracking")
    with pytest.raises(SystemExit):
        mod.main([*argv, "--out", str(tmp_path)])
