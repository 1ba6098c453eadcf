"""scripts/train_swarm_rllib.py: argument errors everywhere; a 1-iteration RLlib run on a local Ray."""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scripts.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]
RAY_REASON = "ray is not installed here; the distributed tests run in .venv-ray (make test-distributed)"
TINY = [
    "--n-robots", "3", "--max-cycles", "10", "--iterations", "1", "--batch", "40", "--minibatch", "20",
    "--epochs", "1", "--hidden", "16", "--no-progress",
]  # fmt: skip


@pytest.fixture(scope="module")
def mod():
    return load_script("train_swarm_rllib")


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--n-robots", "1"], "--n-robots must be >= 2"),
        (["--iterations", "0"], "--iterations must be >= 1"),
        (["--batch", "10", "--minibatch", "20"], "must not exceed --batch"),
        (["--env-runners", "-1"], "must be >= 0"),
        (["--lr", "nan"], "--lr must be > 0"),
        (["--num-cpus", "2", "--address", "auto"], "sizes a local Ray"),
        (["--env-kwargs", "[1]"], "must be a JSON object"),
        (["--env-kwargs", "{oops"], "must be a JSON object"),
        (["--env-kwargs", '{"colour": 1}'], "--env-kwargs: .*colour"),
    ],
)
def test_bad_arguments_exit_with_a_message(mod, argv, match, capsys):
    with pytest.raises(SystemExit) as e:
        mod.parse_args(argv)
    assert e.value.code == 2
    assert re.search(match, capsys.readouterr().err)


def test_env_config_and_mapping(mod):
    args = mod.parse_args(["--n-robots", "4", "--env-kwargs", '{"obs_detections": null, "kin_reward": 0.2}'])
    assert args.env_config == {"obs_detections": None, "kin_reward": 0.2, "n_robots": 4, "max_cycles": 500}
    assert mod.parse_args([]).env_config["obs_detections"] == "topk"  # as scripts/train_swarm.py
    assert {mod.policy_mapping_fn(f"robot_{i}", None) for i in range(4)} == {mod.POLICY_ID}


def test_without_ray_the_error_says_what_to_install(mod, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(ImportError, match=r"pip install kin-envs\[distributed\]"):
        mod.main([*TINY, "--out", str(tmp_path)])


@pytest.mark.distributed
def test_one_iteration_on_a_local_ray_writes_run_json_metrics_and_a_checkpoint(mod, tmp_path):
    ray = pytest.importorskip("ray", reason=RAY_REASON)
    import torch
    from ray.rllib.core.rl_module.rl_module import RLModule

    from kin_envs import aggregation_v2

    res = mod.main([*TINY, "--env-runners", "1", "--num-cpus", "2", "--seed", "3", "--out", str(tmp_path)])
    assert not ray.is_initialized()  # the script shut down the Ray it started
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["seed"] == 3 and run["config"]["seed"] == 3
    assert run["command"][-1] == str(tmp_path) and run["args"]["env_runners"] == 1
    assert run["env_config"] == {"obs_detections": "topk", "n_robots": 3, "max_cycles": 10}
    assert run["config"]["num_env_runners"] == 1 and run["versions"]["ray"] == ray.__version__
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert rows == res["metrics"] and len(rows) == 1
    assert rows[0]["env_steps"] >= 40 and rows[0]["agent_steps"] == 3 * rows[0]["env_steps"]
    assert rows[0]["episode_len_mean"] == 10  # episodes of max_cycles steps completed
    # the shared policy alone loads from its checkpoint and acts for every robot
    module = RLModule.from_checkpoint(run["module_checkpoint"])
    env = aggregation_v2.parallel_env(**run["env_config"])
    obs, _ = env.reset(seed=0)
    batch = torch.as_tensor(np.stack([obs[a] for a in env.agents]))
    out = module.forward_inference({"obs": batch})
    assert out["action_dist_inputs"].shape == (3, 4)  # mean and log-std of 2 wheel speeds per robot
    # the checkpoint was saved beside its name and renamed: no scratch directory left
    assert sorted(q.name for q in tmp_path.iterdir()) == ["checkpoint", "metrics.jsonl", "run.json"]


def test_checkpoints_are_renamed_into_place(mod, tmp_path):
    class Algo:  # stands in for an RLlib Algorithm: writes its files one by one
        def save_to_path(self, path):
            Path(path).mkdir()
            (Path(path) / "a").write_text("1")

    (tmp_path / "checkpoint").mkdir()  # an earlier run's
    (tmp_path / "checkpoint" / "old").write_text("0")
    assert mod.save_checkpoint(Algo(), tmp_path / "checkpoint") == (tmp_path / "checkpoint").resolve()
    assert sorted(q.name for q in tmp_path.iterdir()) == ["checkpoint"]
    assert sorted(q.name for q in (tmp_path / "checkpoint").iterdir()) == ["a"]


@pytest.mark.distributed
def test_more_env_runners_than_cpus_is_a_clear_error(mod, tmp_path):
    ray = pytest.importorskip("ray", reason=RAY_REASON)
    with pytest.raises(ValueError, match="--env-runners 3 needs as many CPUs, the Ray cluster has 1"):
        mod.main([*TINY, "--env-runners", "3", "--num-cpus", "1", "--out", str(tmp_path)])
    assert not ray.is_initialized()
