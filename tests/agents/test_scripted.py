"""The scripted KinSeek baseline beats a random policy by a wide margin."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from agents.scripted import ScriptedKinSeeker
from kin_envs.envs import register_envs

register_envs()
SEEDS = range(20)


def success_rate(env, make_policy) -> float:
    wins = 0
    for seed in SEEDS:
        obs, info = env.reset(seed=seed)
        policy = make_policy(seed)
        while True:
            obs, _, terminated, truncated, info = env.step(policy(obs, info))
            if terminated or truncated:
                break
        wins += bool(info["is_success"])
    return wins / len(SEEDS)


def random_policy(space):
    def make(seed):
        space.seed(seed)
        return lambda obs, info: space.sample()

    return make


def test_scripted_beats_random():
    env = gym.make("kin_envs/KinSeek-v2")
    scripted = success_rate(env, lambda s: ScriptedKinSeeker.for_env(env, seed=s))
    # same layouts (the detector draws no random numbers); the random policy needs no detections
    blind = gym.make("kin_envs/KinSeek-v2", detector=None)
    random = success_rate(blind, random_policy(blind.action_space))
    assert scripted >= 0.5, scripted
    assert scripted >= random + 0.4, (scripted, random)


def test_scripted_discrete_actions():
    env = gym.make("kin_envs/KinSeek-v2", action_type="discrete", max_steps=50)
    policy = ScriptedKinSeeker.for_env(env, seed=0)
    obs, info = env.reset(seed=0)
    for _ in range(50):
        action = policy(obs, info)
        assert env.action_space.contains(action)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break


def test_scripted_needs_detections():
    env = gym.make("kin_envs/KinSeek-v2", detector=None)
    policy = ScriptedKinSeeker.for_env(env)
    obs, info = env.reset(seed=0)
    with pytest.raises(ValueError, match="kin_detections"):
        policy(obs, info)


def test_scripted_continuous_actions_in_space():
    env = gym.make("kin_envs/KinSeek-v2", frame_stack=2, obs_detections="topk")
    policy = ScriptedKinSeeker.for_env(env, seed=1)
    obs, info = env.reset(seed=1)
    for _ in range(20):
        action = policy(obs, info)
        assert env.action_space.contains(action) and np.all(np.isfinite(action))
        obs, *_, info = env.step(action)
