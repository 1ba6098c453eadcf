"""scripts/train_single.py, train_swarm.py, evaluate_policies.py: tiny end-to-end runs and bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scripts.helpers import load_script

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = ROOT / "scripts"
SEEK_KW = json.dumps({"obs_detections": "topk", "max_steps": 15})


def run(script: str, *argv: str) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, str(SCRIPTS / script), *argv, "--no-progress"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Both training scripts run end to end in subprocesses with tiny budgets."""
    base = tmp_path_factory.mktemp("train")
    single, swarm = base / "single", base / "swarm"
    run("train_single.py", "--env-kwargs", SEEK_KW, "--timesteps", "128", "--n-envs", "2",
        "--hyperparams", '{"n_steps": 32, "batch_size": 32, "n_epochs": 1}', "--eval-freq", "64",
        "--eval-episodes", "2", "--checkpoint-freq", "64", "--out", str(single))
    run("train_swarm.py", "--n-robots", "2", "--n-copies", "1", "--timesteps", "128",
        "--env-kwargs", '{"obs_detections": "topk", "max_cycles": 16}',
        "--hyperparams", '{"n_steps": 32, "batch_size": 32, "n_epochs": 1}', "--checkpoint-freq", "64",
        "--out", str(swarm))
    return single, swarm


def test_train_single_outputs(trained):
    single, _ = trained
    for f in ("model.zip", "best/best_model.zip", "eval/evaluations.npz", "run.json"):
        assert (single / f).is_file(), f
    assert list((single / "checkpoints").glob("*.zip"))
    assert sorted(q.name for q in (single / "eval").iterdir()) == ["evaluations.npz"]  # no scratch copy left
    assert list((single / "monitor").glob("*.monitor.csv"))
    assert any((single / "tb").rglob("events.out.tfevents*"))
    r = json.loads((single / "run.json").read_text())
    assert r["status"] == "done" and r["seed"] == 0 and r["algo"] == "ppo"
    assert r["env_kwargs"] == json.loads(SEEK_KW)
    assert r["config"]["algo_kwargs"]["n_steps"] == 32  # CLI override of the shipped value
    assert r["config"]["algo_kwargs"]["gae_lambda"] == 0.95  # shipped value kept
    assert "--timesteps" in r["command"]
    ev = np.load(single / "eval" / "evaluations.npz")
    assert len(ev["timesteps"]) == 2 and ev["successes"].shape == (2, 2)


def test_train_swarm_outputs(trained):
    _, swarm = trained
    assert (swarm / "model.zip").is_file() and list((swarm / "checkpoints").glob("*.zip"))
    r = json.loads((swarm / "run.json").read_text())
    assert r["status"] == "done" and r["env_id"] == "aggregation_v2"
    assert r["env_kwargs"] == {"n_robots": 2, "obs_detections": "topk", "max_cycles": 16}
    assert r["timesteps"] >= 128
    lines = (swarm / "monitor.csv").read_text().splitlines()
    assert len(lines) > 2  # header + rows: 16-cycle episodes finished


def test_evaluate_single_and_swarm(trained, tmp_path):
    single, swarm = trained
    ev = load_script("evaluate_policies")
    out = tmp_path / "seek"
    res = ev.main(["--episodes", "3", "--env-kwargs", SEEK_KW, "--model", f"ppo={single / 'model.zip'}",
                   "--out", str(out), "--no-progress"])
    assert list(res["results"]) == ["random", "scripted", "ppo"]
    for r in res["results"].values():
        lo, hi = r["success_ci"]
        assert r["episodes"] == 3 and lo <= r["success_rate"] <= hi
    md = (out / "results.md").read_text()
    assert "| scripted |" in md and "| ppo |" in md
    assert (out / "learning_curve.png").stat().st_size > 1000
    assert json.loads((out / "run.json").read_text())["env_kwargs"]["ppo"] == json.loads(SEEK_KW)

    # the swarm, in a subprocess (the command line as a user runs it)
    out = tmp_path / "swarm"
    run("evaluate_policies.py", "--env", "aggregation_v2", "--n-robots", "3", "--episodes", "2",
        "--max-cycles", "12", "--metric-cycles", "4", "--model", f"shared={swarm / 'model.zip'}",
        "--out", str(out))
    res = json.loads((out / "results.json").read_text())["results"]
    assert list(res) == ["random", "wander", "aggregator", "shared"]
    for r in res.values():
        assert 0 < r["largest_cluster"][0] <= 1 and r["nearest"][0] > 0.18
    assert "largest-cluster fraction" in (out / "results.md").read_text()


def test_bad_input_raises(tmp_path):
    ts = load_script("train_single")
    with pytest.raises(ValueError, match="obs_detections"):
        ts.main(["--env-kwargs", '{"obs_detections": "everything"}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="unknown argument"):
        ts.main(["--env-kwargs", '{"speed": 2}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="JSON object"):
        ts.main(["--env-kwargs", "[1, 2]", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="hyperparameter.*learning_rte"):
        ts.main(["--hyperparams", '{"learning_rte": 1}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="SAC needs continuous"):
        ts.main(["--algo", "sac", "--env-kwargs", '{"action_type": "discrete"}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="no shipped hyperparameters"):
        ts.main(["--env", "CartPole-v1", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="unknown TrainConfig key"):
        ts.TrainConfig.from_dict({"total_steps": 5})
    with pytest.raises(ValueError, match="n_envs"):
        ts.TrainConfig(n_envs=0)
    sw = load_script("train_swarm")
    with pytest.raises(ValueError, match="--n-robots"):
        sw.main(["--env-kwargs", '{"n_robots": 4}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="n_robots"):
        sw.main(["--n-robots", "1", "--out", str(tmp_path)])
    ev = load_script("evaluate_policies")
    with pytest.raises(ValueError, match="unknown policy"):
        ev.main(["--policies", "genius", "--out", str(tmp_path), "--no-progress"])
    with pytest.raises(ValueError, match="no file"):
        ev.main(["--model", str(tmp_path / "nope.zip"), "--out", str(tmp_path), "--no-progress"])
    assert not list(tmp_path.iterdir())  # nothing written before the input was checked


def test_train_single_sac_in_process(tmp_path):
    ts = load_script("train_single")
    res = ts.main(["--algo", "sac", "--env-kwargs", '{"detector": null, "max_steps": 10}',
                   "--timesteps", "40",
                   "--hyperparams", '{"learning_starts": 20, "buffer_size": 100, "batch_size": 8}',
                   "--eval-freq", "0", "--checkpoint-freq", "0", "--out", str(tmp_path), "--no-progress"])
    assert type(res["model_object"]).__name__ == "SAC" and res["run"]["timesteps"] == 40
    assert json.loads((tmp_path / "run.json").read_text())["algo"] == "sac"
