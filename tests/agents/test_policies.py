"""Built-in policies: interface, both action types, seeding, swarm groups, bad input."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import kin_envs  # noqa: F401  (registers the ids)
from agents import (
    Aggregator,
    KinSeeker,
    Policy,
    PolicyGroup,
    RandomPolicy,
    ScriptedKinSeeker,
    Wanderer,
    env_layout,
    run_episode,
    run_parallel_episode,
    steer_to_action,
)
from agents.scripted import ScriptedKinSeeker as LegacySeeker
from kin_envs import aggregation_v2


def test_import_agents_is_torch_free():
    code = ("import sys, agents, agents.sb3, agents.hyperparams\n"
            "assert 'torch' not in sys.modules and 'stable_baselines3' not in sys.modules, "
            "sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_scripted_alias_is_the_seeker():
    assert LegacySeeker is KinSeeker is ScriptedKinSeeker


ALL = [RandomPolicy.for_env, Wanderer.for_env, KinSeeker.for_env, Aggregator.for_env]


@pytest.mark.parametrize("action_type", ["continuous", "discrete"])
@pytest.mark.parametrize("make", ALL)
def test_actions_are_in_the_space(make, action_type):
    env = gym.make("kin_envs/KinSeek-v2", action_type=action_type, max_steps=30)
    policy = make(env, seed=0)
    assert isinstance(policy, Policy)
    obs, info = env.reset(seed=3)
    for _ in range(30):
        a = policy.act(obs, info)
        assert env.action_space.contains(a), a
        obs, _, term, trunc, info = env.step(a)
        if term or trunc:
            break


@pytest.mark.parametrize("make", [RandomPolicy.for_env, Wanderer.for_env, KinSeeker.for_env])
def test_same_seed_same_episode(make):
    env = gym.make("kin_envs/KinSeek-v2", max_steps=60)
    a = run_episode(env, make(env), seed=5)
    b = run_episode(env, make(env), seed=5)
    c = run_episode(env, make(env), seed=6)
    assert (a.episode_return, a.length) == (b.episode_return, b.length)
    assert a.episode_return != c.episode_return


def test_wanderer_drives_without_collisions():
    """Full speed ahead collides most of the time; the wanderer also drives but avoids obstacles."""

    class Straight(Policy):
        def act(self, obs, info):
            return np.array([1.0, 1.0], np.float32)

    env = gym.make("kin_envs/KinSeek-v2", detector=None, max_steps=200, n_distractors=12)
    straight = sum(run_episode(env, Straight(), seed=s).collisions for s in range(4))
    wander = sum(run_episode(env, Wanderer.for_env(env), seed=s).collisions for s in range(4))
    assert straight > 200 and wander <= 10, (straight, wander)


def test_seeker_reads_topk_channel_without_info():
    env = gym.make("kin_envs/KinSeek-v2", obs_detections="topk", frame_stack=2)
    policy = KinSeeker.for_env(env, seed=0)
    wins = 0
    for s in range(6):
        obs, info = env.reset(seed=s)
        policy.reset(s)
        while True:  # the policy sees only the observation
            obs, _, term, trunc, info = env.step(policy.act(obs, {}))
            if term or trunc:
                break
        wins += info["is_success"]
    assert wins >= 3, wins


def test_steer_to_action():
    assert steer_to_action(1.0, 0.0, "discrete") == 1
    assert steer_to_action(0.0, 0.5, "discrete") == 2
    assert steer_to_action(0.0, -0.5, "discrete") == 3
    assert steer_to_action(0.0, 0.0, "discrete") == 0
    np.testing.assert_allclose(steer_to_action(1.0, 1.0, "continuous"), [0.0, 1.0])


def test_bad_input_raises():
    env = gym.make("kin_envs/KinSeek-v2")
    layout, _ = env_layout(env)
    with pytest.raises(ValueError, match="action_type"):
        Wanderer(layout, "jerky")
    with pytest.raises(ValueError, match="clearance"):
        Wanderer(layout, clearance=-1.0)
    with pytest.raises(ValueError, match="select"):
        KinSeeker(layout, select="loudest")
    with pytest.raises(ValueError, match="seed"):
        Wanderer(layout, seed=-3)
    with pytest.raises(ValueError, match="kin_envs env"):
        env_layout(object())
    with pytest.raises(ValueError, match="Box or Discrete"):
        RandomPolicy(gym.spaces.MultiBinary(3))
    blind = gym.make("kin_envs/KinSeek-v2", detector=None)
    obs, info = blind.reset(seed=0)
    with pytest.raises(ValueError, match="kin_detections"):
        Aggregator.for_env(blind).act(obs, info)


def test_policy_group_refuses_to_share_memory():
    par = aggregation_v2.parallel_env(n_robots=3, detector=None)
    w = Wanderer.for_env(par)
    with pytest.raises(ValueError, match="per-agent memory"):
        PolicyGroup.shared(w, par.possible_agents)
    with pytest.raises(ValueError, match="agents.Policy"):
        PolicyGroup({"robot_0": lambda o, i: 0})


@pytest.mark.parametrize("action_type", ["continuous", "discrete"])
def test_swarm_groups_run_and_are_seeded(action_type):
    par = aggregation_v2.parallel_env(n_robots=4, max_cycles=40, action_type=action_type)

    def final_state(group, seed):
        run_parallel_episode(par, group, seed)
        return par.state().copy()

    agg = PolicyGroup.per_agent(lambda: Aggregator.for_env(par), par.possible_agents)
    rnd = PolicyGroup.shared(RandomPolicy.for_env(par), par.possible_agents)
    for group in (agg, rnd):
        a, b, c = final_state(group, 1), final_state(group, 1), final_state(group, 2)
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)


def test_aggregator_gathers_better_than_wandering():
    par = aggregation_v2.parallel_env(n_robots=6, max_cycles=250)

    def mean_nearest(factory):
        out = []
        for s in range(3):
            run_parallel_episode(par, PolicyGroup.per_agent(factory, par.possible_agents), s)
            p = par.state()[:, :2]
            d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(len(p)) * 1e9
            out.append(d.min(axis=1).mean())
        return float(np.mean(out))

    agg = mean_nearest(lambda: Aggregator.for_env(par))
    wander = mean_nearest(lambda: Wanderer.for_env(par))
    assert agg < 0.8 * wander, (agg, wander)
