"""PettingZoo swarm: official API tests, determinism (parallel and AEC), sizes, errors."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, render_test

from kin_envs import aggregation_v0
from kin_envs.envs.common import UnknownArgumentError

from .helpers import assert_same


def test_parallel_api():
    parallel_api_test(aggregation_v0.parallel_env(n_robots=4, max_cycles=60), num_cycles=100)


def test_parallel_api_discrete_stacked():
    env = aggregation_v0.parallel_env(n_robots=3, max_cycles=20, action_type="discrete",
                                      frame_stack=2, obs_detections="mask")
    parallel_api_test(env, num_cycles=30)


def test_max_cycles():
    max_cycles_test(aggregation_v0)


def test_aec_api():
    api_test(aggregation_v0.env(n_robots=4, max_cycles=30), num_cycles=40)


def test_render():
    render_test(lambda render_mode=None: aggregation_v0.env(
        n_robots=4, max_cycles=20, render_mode=render_mode, render_size=128))


def test_metadata_and_spaces():
    env = aggregation_v0.parallel_env(n_robots=5)
    assert env.metadata["name"] == "aggregation_v0" and env.metadata["is_parallelizable"]
    assert set(env.metadata["render_modes"]) == {"human", "rgb_array"}
    a, b = env.possible_agents[:2]
    assert env.observation_space(a) is env.observation_space(a)
    assert env.action_space(a) is env.action_space(a)
    assert env.action_space(a) is not env.action_space(b)  # one object per agent
    assert env.observation_space(a) == env.observation_space(b)  # homogeneous
    assert aggregation_v0.raw_env(n_robots=2).possible_agents == ["robot_0", "robot_1"]


def parallel_rollout(seed: int, steps: int = 200, **kwargs) -> list:
    env = aggregation_v0.parallel_env(n_robots=6, max_cycles=80, noise_sigma=0.01,
                                      dropout_prob=0.01, obs_detections="topk", **kwargs)
    for i, a in enumerate(env.possible_agents):
        env.action_space(a).seed(seed + i)
    out = [env.reset(seed=seed), env.state()]
    for _ in range(steps):
        step = env.step({a: env.action_space(a).sample() for a in env.agents})
        out += [step, env.state()]
        for a, r in step[1].items():
            assert r == sum(step[4][a]["reward_terms"].values())
        if not env.agents:
            out.append(env.reset())
    return out


def test_parallel_determinism_200_steps():
    a, b = parallel_rollout(3), parallel_rollout(3)
    assert_same(a, b)
    assert not np.array_equal(a[1], parallel_rollout(4, steps=0)[1])


def aec_rollout(seed: int, cycles: int = 200) -> list:
    """``cycles`` full AEC cycles (all agents act once each), resetting when the episode ends."""
    env = aggregation_v0.env(n_robots=4, max_cycles=70, noise_sigma=0.01)
    for i, a in enumerate(env.possible_agents):
        env.action_space(a).seed(seed + i)
    env.reset(seed=seed)
    out, turns = [], 0
    while turns < cycles * 4:
        for agent in env.agent_iter():
            obs, reward, terminated, truncated, info = env.last()
            out.append((agent, obs, reward, terminated, truncated, info))
            turns += not (terminated or truncated)
            env.step(None if terminated or truncated else env.action_space(agent).sample())
        out.append(env.state())
        env.reset()
    return out


def test_aec_determinism_200_cycles():
    a, b = aec_rollout(11), aec_rollout(11)
    assert len(a) > 800
    assert_same(a, b)


@pytest.mark.parametrize("n", [2, 64])
def test_sizes(n):
    env = aggregation_v0.parallel_env(n_robots=n, detector=None if n == 64 else "geometric",
                                      max_cycles=5)
    assert env.config.arena_size == max(3.0, np.sqrt(n))
    obs, infos = env.reset(seed=0)
    assert len(obs) == n and all(o.shape == (360,) and o.dtype == np.float32 for o in obs.values())
    assert env.state().shape == (n, 3) and env.state_space.contains(env.state())
    for _ in range(5):
        obs, rewards, terms, truncs, infos = env.step(
            {a: env.action_space(a).sample() for a in env.agents})
        assert not any(terms.values())
        assert env.state_space.contains(env.state())
    assert all(truncs.values()) and env.agents == []
    info = infos["robot_0"]
    assert set(info) >= {"kin_truth", "reward_terms", "n_kin"}
    assert ("kin_detections" in info) == (n != 64)
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_kin_reward_counts_neighbours():
    env = aggregation_v0.parallel_env(n_robots=64, area_per_robot=0.5, kin_radius=1.0, detector=None)
    env.reset(seed=1)
    _, rewards, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    p = env.state()[:, :2].astype(np.float64)
    d = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1))
    n_kin = (d <= 1.0).sum(1) - 1
    assert [infos[a]["n_kin"] for a in env.possible_agents] == n_kin.tolist()
    kin = [infos[a]["reward_terms"]["kin"] for a in env.possible_agents]
    np.testing.assert_allclose(kin, 0.1 * np.minimum(n_kin, 6))


class BatchStub:
    """Counts batched calls; reports nothing."""

    def __init__(self):
        self.batches = []

    def detect(self, ranges, angles):  # pragma: no cover - only detect_batch should be used
        raise AssertionError("the swarm must use detect_batch")

    def detect_batch(self, ranges, angles):
        from detectors import DetectionResult

        self.batches.append(np.asarray(ranges).shape)
        return [DetectionResult([], []) for _ in ranges]


def test_detect_batch_on_all_scans():
    stub = BatchStub()
    env = aggregation_v0.parallel_env(n_robots=7, detector=stub)
    env.reset(seed=0)
    env.step({a: env.action_space(a).sample() for a in env.agents})
    assert stub.batches == [(7, 360), (7, 360)]


def test_kin_truth_matches_visible_robots():
    env = aggregation_v0.parallel_env(n_robots=12, detector=None)
    _, infos = env.reset(seed=2)
    scan = env._last_scan
    for i, a in enumerate(env.possible_agents):
        t = infos[a]["kin_truth"]
        assert dict(zip(t["index"].tolist(), t["n_beams"].tolist(), strict=True)) == \
            scan.visible_robots(i)
        assert np.all(np.diff(t["range"]) >= 0)


def test_detections_are_matched_to_truth():
    env = aggregation_v0.parallel_env(n_robots=16, n_obstacles=0)
    _, infos = env.reset(seed=0)
    dets = [infos[a]["kin_detections"] for a in env.possible_agents]
    assert sum(len(d["range"]) for d in dets) > 0
    for i, d in enumerate(dets):
        assert np.all(d["kin_index"] != i)
        # no obstacles: every detection is a real robot
        assert np.all(d["kin_index"] >= 0)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="n_robots must be an integer in"):
        aggregation_v0.parallel_env(n_robots=1)
    with pytest.raises(ValueError, match="n_robots must be an integer in"):
        aggregation_v0.parallel_env(n_robots=257)
    with pytest.raises(UnknownArgumentError, match="unknown argument"):
        aggregation_v0.parallel_env(n_robot=4)
    with pytest.raises(TypeError, match="unknown argument"):
        aggregation_v0.env(speed=4)
    env = aggregation_v0.parallel_env(n_robots=3, detector=None)
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    env.reset(seed=0)
    good = {a: np.zeros(2, np.float32) for a in env.agents}
    with pytest.raises(ValueError, match=r"missing \['robot_2'\]"):
        env.step({k: v for k, v in good.items() if k != "robot_2"})
    with pytest.raises(ValueError, match=r"unknown \['robot_9'\]"):
        env.step({**good, "robot_9": np.zeros(2)})
    with pytest.raises(ValueError, match="action of 'robot_1' must be finite"):
        env.step({**good, "robot_1": np.array([np.nan, 0.0])})
    with pytest.raises(ValueError, match=r"action of 'robot_0' must have shape \(2,\)"):
        env.step({**good, "robot_0": np.zeros(3)})
    with pytest.raises(ValueError, match="must be a dict"):
        env.step([np.zeros(2)] * 3)


def test_rgb_array():
    env = aggregation_v0.parallel_env(n_robots=8, render_mode="rgb_array", render_size=200)
    env.reset(seed=0)
    img = env.render()
    assert img.dtype == np.uint8 and img.shape == (200, 200, 3)


def test_supersuit_vector_env():
    ss = pytest.importorskip("supersuit")
    vec = ss.pettingzoo_env_to_vec_env_v1(
        aggregation_v0.parallel_env(n_robots=4, max_cycles=3, detector=None))
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (4, 360)
    for _ in range(4):  # crosses the time limit: all agents truncate together, then auto-reset
        obs, rewards, terminations, truncations, _ = vec.step(np.zeros((4, 2), np.float32))
        assert obs.shape == (4, 360) and rewards.shape == (4,)
