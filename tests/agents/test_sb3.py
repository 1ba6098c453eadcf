"""SB3 adapter: a saved model reloads and acts in both APIs; space checks; seeded shared vec env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import kin_envs  # noqa: F401  (registers the ids)
from agents import PolicyGroup, run_episode, run_parallel_episode
from agents.sb3 import SB3Policy, detect_algo, shared_vec_env
from kin_envs import aggregation_v2

torch = pytest.importorskip("torch")
sb3 = pytest.importorskip("stable_baselines3")


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ppo_path(tmp_path_factory):
    """A tiny PPO model trained on KinSeek with the topk detector channel (shape 360 + 12)."""
    env = gym.make("kin_envs/KinSeek-v2", obs_detections="topk", max_steps=20)
    model = sb3.PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(32)
    path = tmp_path_factory.mktemp("ppo") / "model.zip"
    model.save(path)
    return path


def test_reloaded_model_acts_in_gymnasium(ppo_path):
    policy = SB3Policy.load(ppo_path)
    env = gym.make("kin_envs/KinSeek-v2", obs_detections="topk", max_steps=20)
    policy.check_env(env)
    a = run_episode(env, policy, seed=0)
    b = run_episode(env, policy, seed=0)
    assert a.length == 20 or a.success
    assert a.episode_return == b.episode_return  # deterministic actions


def test_reloaded_model_acts_in_pettingzoo_parallel_and_aec(ppo_path):
    policy = SB3Policy.load(ppo_path)
    par = aggregation_v2.parallel_env(n_robots=3, obs_detections="topk", max_cycles=5)
    group = PolicyGroup.shared(policy.check_env(par), par.possible_agents)
    res = run_parallel_episode(par, group, seed=0)
    assert res["length"] == 5 and set(res["returns"]) == set(par.possible_agents)

    aec = aggregation_v2.env(n_robots=3, obs_detections="topk", max_cycles=3)
    policy.check_env(aec)
    aec.reset(seed=0)
    steps = 0
    for agent in aec.agent_iter():
        obs, _, term, trunc, info = aec.last()
        action = None if term or trunc else policy.act(obs, info)
        assert action is None or aec.action_space(agent).contains(action)
        aec.step(action)
        steps += 1
    assert steps >= 9


def test_batched_and_single_actions_agree(ppo_path):
    policy = SB3Policy.load(ppo_path)
    par = aggregation_v2.parallel_env(n_robots=4, obs_detections="topk")
    obs, infos = par.reset(seed=1)
    many = policy.act_many(list(obs.values()), list(infos.values()))
    for a, o in zip(many, obs.values(), strict=True):
        np.testing.assert_allclose(a, policy.act(o, {}), atol=1e-6)


def test_space_mismatch_raises(ppo_path):
    policy = SB3Policy.load(ppo_path)
    with pytest.raises(ValueError, match=r"shape \(372,\).*\(360,\)"):
        policy.check_env(gym.make("kin_envs/KinSeek-v2"))
    with pytest.raises(ValueError, match="action_type"):
        policy.check_env(gym.make("kin_envs/KinSeek-v2", obs_detections="topk", action_type="discrete"))
    with pytest.raises(ValueError, match="no model file"):
        SB3Policy.load(ppo_path.parent / "missing.zip")
    with pytest.raises(ValueError, match="Stable-Baselines3 model"):
        SB3Policy(object())


def test_discrete_model_returns_ints(tmp_path):
    env = gym.make("kin_envs/KinSeek-v2", detector=None, action_type="discrete", max_steps=10)
    model = sb3.PPO("MlpPolicy", env, n_steps=16, batch_size=16, n_epochs=1, seed=0, device="cpu")
    policy = SB3Policy(model)
    obs, info = env.reset(seed=0)
    a = policy.act(obs, info)
    assert isinstance(a, int) and env.action_space.contains(a)


def test_detect_algo_reads_the_zip(ppo_path, tmp_path):
    assert detect_algo(ppo_path) == "ppo"
    env = gym.make("kin_envs/KinSeek-v2", detector=None, max_steps=10)
    sac = sb3.SAC("MlpPolicy", env, learning_starts=5, buffer_size=100, batch_size=8, seed=0,
                  device="cpu", policy_kwargs={"net_arch": [16]})
    sac.learn(10)
    sac.save(tmp_path / "sac.zip")
    assert detect_algo(tmp_path / "sac.zip") == "sac"
    assert isinstance(SB3Policy.load(tmp_path / "sac.zip").model, sb3.SAC)
    (tmp_path / "junk.zip").write_text("not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model"):
        detect_algo(tmp_path / "junk.zip")


def _swarm_run(seed: int):
    """First rollout observations and parameters after one PPO update on the shared vec env."""
    par = aggregation_v2.parallel_env(n_robots=3, detector=None, max_cycles=20)
    venv = shared_vec_env(par, n_copies=2)
    model = sb3.PPO("MlpPolicy", venv, n_steps=16, batch_size=48, n_epochs=1, seed=seed, device="cpu",
                    policy_kwargs={"net_arch": [16]})
    model.learn(16 * venv.num_envs)
    first = model.rollout_buffer.observations.copy()  # the whole first rollout (flattened)
    params = torch.nn.utils.parameters_to_vector(model.policy.parameters()).detach().numpy().copy()
    venv.close()
    return first, params


def test_shared_vec_env_seeding_is_reproducible():
    obs_a, par_a = _swarm_run(7)
    obs_b, par_b = _swarm_run(7)
    obs_c, par_c = _swarm_run(8)
    assert obs_a.shape == (16 * 6, 360)  # 16 steps x 2 swarm copies x 3 robots
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(par_a, par_b)
    assert not np.array_equal(obs_a, obs_c)
    assert not np.array_equal(par_a, par_c)


def test_shared_vec_env_reset_seed_argument():
    venv = shared_vec_env(aggregation_v2.parallel_env(n_robots=2, detector=None), n_copies=2)
    a = venv.reset(seed=3)
    b = venv.reset(seed=3)
    c = venv.reset()  # no seed: continues the RNG streams
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(a[:2], a[2:])  # copy i is seeded with seed + i
    with pytest.raises(ValueError, match="n_copies"):
        shared_vec_env(aggregation_v2.parallel_env(n_robots=2), n_copies=0)


def test_scan_conv_extractor_trains_saves_and_reloads(tmp_path):
    from agents.sb3 import ScanConvExtractor, resolve_policy_kwargs

    pk = resolve_policy_kwargs({"features_extractor_class": "agents.sb3:ScanConvExtractor",
                                "features_extractor_kwargs": {"frame_stack": 2}, "net_arch": [16]})
    assert pk["features_extractor_class"] is ScanConvExtractor
    env = gym.make("kin_envs/KinSeek-v2", obs_detections="topk", frame_stack=2, max_steps=10)
    model = sb3.PPO("MlpPolicy", env, n_steps=16, batch_size=16, n_epochs=1, seed=0, device="cpu",
                    policy_kwargs=pk)
    model.learn(16)
    model.save(tmp_path / "conv.zip")
    policy = SB3Policy.load(tmp_path / "conv.zip").check_env(env)
    assert isinstance(policy.model.policy.features_extractor, ScanConvExtractor)
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(policy.act(obs, info), SB3Policy(model).act(obs, info), atol=1e-6)
    with pytest.raises(ValueError, match="frame_stack=3"):
        ScanConvExtractor(env.observation_space, frame_stack=3)
    with pytest.raises(ValueError, match="module:Class"):
        resolve_policy_kwargs({"features_extractor_class": "agents.sb3:Nope"})


def test_sb3_wrappers_on_the_shared_vec_env_build_without_warnings():
    # SB3 warned "The `render_mode` attribute is not defined in your environment" on every
    # train_swarm.py run (its VecMonitor): noise a newcomer takes for a problem
    import warnings

    from stable_baselines3.common.vec_env import VecMonitor

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        venv = VecMonitor(shared_vec_env(aggregation_v2.parallel_env(n_robots=2, detector=None), n_copies=2))
    assert venv.render_mode is None and venv.num_envs == 4
    assert venv.get_attr("render_mode", [0, 3]) == [None, None]
    venv.close()
