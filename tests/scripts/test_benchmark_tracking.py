"""scripts/benchmark_tracking.py: a one-episode run writes every output; bad arguments."""

import json

import pytest

from tests.scripts.helpers import load_script


def test_one_episode_run(tmp_path):
    mod = load_script("benchmark_tracking")
    out = tmp_path / "seq"
    argv = ["--splits", "lookalike", "--episodes", "1", "--noise", "0.01", "--detector", "geometric"]
    results = mod.main([*argv, "--baselines", "--cost-robots", "4", "--cost-env-steps", "2",
                        "--out", str(out), "--tracker-params", '{"birth_min_score": 0.2}'])  # fmt: skip
    assert [r["split"] for r in results] == ["lookalike"]
    for name in ("results.md", "results.json", "f1_vs_frames.png", "tracks.gif", "run.json"):
        assert (out / name).stat().st_size > 0, name
    run = json.loads((out / "run.json").read_text())
    assert run["sequence_version"] == 1 and "lookalike" in run["splits"]
    md = (out / "results.md").read_text()
    assert "Frames since the kin came into view" in md and "Target window" in md
    assert "Tracking cost at 4 observers" in md
    # the in-env measurement: aggregation_v2, KinSeek-v2 and its vector env, each a column
    assert "What the tracker costs in the envs (geometric detector, default (auto) feed)" in md
    assert "| aggregation_v2 (4 robots) | KinSeek-v2 | vector KinSeek-v2 (K = 4) |" in md
    cost = json.loads((out / "results.json").read_text())["cost"]["env"]
    assert set(cost["envs"]) == {"aggregation_v2", "KinSeek-v2", "vector"} and cost["steps"] == 2
    assert "target window, kin frames: both right" in md and "single scan only" in md


def test_tune_tracker_script(tmp_path):
    """scripts/tune_tracker.py on one training episode per split, a two-value grid: writes the tuned
    parameters (loadable), the table and the log; the tuned objective is at least the defaults'."""
    from detectors.tracking import TrackerParams

    mod = load_script("tune_tracker")
    out = tmp_path / "tune"
    # the grid holds the default (the descent's start, evaluated once) and one other value, whatever the
    # shipped default is
    grid = [TrackerParams().kin_threshold, TrackerParams().kin_threshold / 2]
    argv = ["--detectors", "geometric", "--swarm-episodes", "1", "--lookalike-episodes", "1", "--passes", "1",
            "--grid", json.dumps({"kin_threshold": grid}), "--out", str(out)]  # fmt: skip
    res = mod.main(argv)
    params = TrackerParams.from_dict(json.loads((out / "params.json").read_text()))
    assert params.kin_threshold in grid and res["params"]["kin_threshold"] == params.kin_threshold
    log = json.loads((out / "log.json").read_text())
    assert len(log) == 2 and all(len(e["per_set"]) == 2 for e in log)
    assert max(e["objective"] for e in log) == pytest.approx(
        next(e["objective"] for e in log if e["params"]["kin_threshold"] == params.kin_threshold)
    )
    assert "| geometric / swarm |" in (out / "tuning.md").read_text()
    with pytest.raises(SystemExit):
        mod.main(["--swarm-episodes", "0", "--out", str(tmp_path / "x")])


def test_env_cost_accepted_feed():
    """The in-env cost, tiny, with the accepted feed: every env times its detector call (the feed's),
    the tracker's update and info; the probes are removed afterwards."""
    from detectors.tracking import KinTracker
    from kin_envs.envs import tracks

    mod = load_script("benchmark_tracking")
    before = (tracks.track_update, tracks.track_info, KinTracker.update_batch)
    cost = mod.env_cost("geometric", n_robots=3, steps=2, warm=1, feed="accepted")
    assert (tracks.track_update, tracks.track_info, KinTracker.update_batch) == before
    for name, e in cost["envs"].items():
        us = e["us_per_step"]
        assert us["detector"] > 0 and us["update"] > 0 and us["info"] > 0, name
        assert e["ratio"] > 0 and e["step_us"] > 0, name
    assert "accepted feed" in "\n".join(mod.env_cost_lines(cost))
    with pytest.raises(ValueError, match="steps and warm"):
        mod.env_cost(steps=0)


@pytest.mark.parametrize("argv", [["--episodes", "0"], ["--cost-env-steps", "-1"], ["--noise", "5"],
                                  ["--full", "--episodes", "2"],
                                  ["--tracker-params", '{"bogus": 1}'], ["--tracker-params", "{"],
                                  ["--tracker-params", '{"birth_min_score": 1.5}']])  # fmt: skip
def test_bad_arguments(argv, tmp_path, capsys):
    mod = load_script("benchmark_tracking")
    with pytest.raises(SystemExit):
        mod.main([*argv, "--out", str(tmp_path)])
    if "--tracker-params" in argv:  # the message names what is wrong
        err = capsys.readouterr().err
        assert any(w in err for w in ("bogus", "JSON object", "birth_min_score")), err


def test_runs_on_the_core_install(tmp_path, monkeypatch, caplog):
    # an install without the tracking extra (README's ".[train,viz]") ended `make run` with a motmetrics
    # traceback at the sequence benchmark, and the core install with tqdm's, torch's or matplotlib's; now
    # the tables, a warning and a line saying why CLEAR MOT is missing
    import sys

    for name in ("motmetrics", "tqdm", "matplotlib", "torch"):  # import -> ImportError, find_spec -> None
        monkeypatch.setitem(sys.modules, name, None)
    mod = load_script("benchmark_tracking")
    argv = ["--splits", "lookalike", "--episodes", "1", "--noise", "0.01"]  # the learned detector feeds it
    results = mod.main([*argv, "--baselines", "--cost-robots", "0", "--out", str(tmp_path)])
    assert results[0]["mot"] == {} and results[0]["by_age"]
    md = (tmp_path / "results.md").read_text()
    assert "CLEAR MOT (tracker): not scored (motmetrics is not installed: pip install kin-envs[tracking])" \
        in md
    assert "Target window" in md and "CLEAR MOT (MOTA / IDF1) not scored" in caplog.text
    assert "no f1_vs_frames.png / tracks.gif: matplotlib is not installed" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json", "results.md", "run.json"]
