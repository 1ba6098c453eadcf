"""Issue 16 (points 5-6): every env can be deep-copied and pickled after reset, a copy stepped with
the same actions follows the same trajectory (RNG state included). World-level copies and the reset soak test:
tests/kin_envs/test_world_integrity.py."""

from __future__ import annotations

import copy
import pickle

import cloudpickle
import gymnasium as gym
import numpy as np
import pytest

import kin_envs  # noqa: F401  (registers the ids)
from kin_envs import aggregation_v2

from .helpers import assert_same

COPIERS = {
    "deepcopy": copy.deepcopy,
    "pickle": lambda x: pickle.loads(pickle.dumps(x)),
    "cloudpickle": lambda x: cloudpickle.loads(cloudpickle.dumps(x)),
}


def _actions(space, n: int, seed: int) -> list:
    space.seed(seed)
    return [space.sample() for _ in range(n)]


@pytest.mark.parametrize("how", sorted(COPIERS))
@pytest.mark.parametrize("env_id", ["kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"])
def test_gym_env_copy_follows_the_same_trajectory(env_id, how):
    env = gym.make(env_id, noise_sigma=0.01, dropout_prob=0.02, obs_detections="topk")
    env.reset(seed=5)
    for a in _actions(env.action_space, 15, 0):  # into contacts and a used RNG
        env.step(a)
    twin = COPIERS[how](env)
    assert twin.unwrapped.world is not env.unwrapped.world
    assert twin.unwrapped.np_random.bit_generator.state == env.unwrapped.np_random.bit_generator.state
    for a in _actions(env.action_space, 40, 1):
        assert_same(twin.step(a), env.step(a))
        np.testing.assert_array_equal(twin.unwrapped.world.poses, env.unwrapped.world.poses)


@pytest.mark.parametrize("how", sorted(COPIERS))
def test_swarm_copy_follows_the_same_trajectory(how):
    env = aggregation_v2.parallel_env(n_robots=12, max_cycles=200, noise_sigma=0.01)
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(15):
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    twin = COPIERS[how](env)
    for _ in range(30):
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        assert_same(twin.step(actions), env.step(actions))
        np.testing.assert_array_equal(twin.state(), env.state())
