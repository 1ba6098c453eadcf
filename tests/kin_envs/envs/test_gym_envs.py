"""Gymnasium tasks: API checkers, determinism, reward terms, info channel, errors, rendering."""

from __future__ import annotations

import math
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from kin_envs.core import scenes
from kin_envs.envs import ENV_IDS, register_envs, unpad_detections, unpad_kin_truth
from kin_envs.envs.common import DETECTION_FIELDS, KIN_TRUTH_FIELDS, UnknownArgumentError

from .helpers import assert_same

register_envs()
IDS = list(ENV_IDS)  # the v0 ids too, on purpose: every registered version passes the checks
pytestmark = pytest.mark.filterwarnings("ignore:.*The environment kin_envs/.* is out of date")
SEEK, FOLLOW = "kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"

VARIANTS = [
    {},
    {"action_type": "discrete", "frame_stack": 3, "obs_detections": "topk"},
    {"obs_detections": "mask", "noise_sigma": 0.01, "dropout_prob": 0.02},
    {"detector": None},
]


@pytest.mark.parametrize("kwargs", VARIANTS, ids=["default", "discrete-stack-topk", "mask-noise", "nodet"])
@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_check_env(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    check_env(env.unwrapped)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
        check_env(env)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env(env_id):
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    for kwargs in ({}, {"action_type": "discrete"}):
        env = gym.make(env_id, **kwargs)
        sb3_check_env(env.unwrapped)
        sb3_check_env(env)


def rollout(env_id: str, seed: int, steps: int = 200, **kwargs) -> list:
    """Everything the env returns over ``steps`` seeded random steps (resetting when done)."""
    env = gym.make(env_id, noise_sigma=0.01, dropout_prob=0.01, **kwargs)
    env.action_space.seed(seed)
    out = [env.reset(seed=seed)]
    for _ in range(steps):
        step = env.step(env.action_space.sample())
        out.append(step)
        _, reward, terminated, truncated, info = step
        assert reward == sum(info["reward_terms"].values())
        if terminated or truncated:
            out.append(env.reset())
    return out


@pytest.mark.parametrize("env_id", IDS)
def test_determinism_200_steps(env_id):
    kw = {"max_steps": 60, "obs_detections": "topk"}  # a few resets inside the 200 steps
    a, b = rollout(env_id, 7, **kw), rollout(env_id, 7, **kw)
    assert_same(a, b)
    c = rollout(env_id, 8, steps=1, **kw)
    assert not np.array_equal(a[0][0], c[0][0]), "different seeds should give different layouts"


def fixed_scene(env, robots, obstacles=()):
    """Make ``env`` (unwrapped) start every episode in this scene."""
    scene = scenes.Scene(robots=robots, obstacles=obstacles, arena=scenes.Arena(4.0, 4.0),
                         lidar=env._lidar)
    env._make_scene = lambda rng: scene
    return scene


def test_seek_success_terminates_with_bonus():
    env = gym.make(SEEK, time_penalty=0.0)
    fixed_scene(env.unwrapped, (scenes.Robot(0.0, 0.0, 0.0), scenes.Robot(0.6, 0.0, math.pi)))
    obs, info = env.reset(seed=0)
    assert info["kin_distance"] == pytest.approx(0.6)
    assert list(unpad_kin_truth(info)["index"]) == [1]
    assert unpad_detections(info)["kin_index"].tolist() == [1]  # 0.6 m ahead: detected
    total = 0.0
    for _ in range(30):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0]))
        total += reward
        if terminated:
            break
    assert terminated and not truncated and info["is_success"]
    assert info["kin_distance"] <= 0.3
    assert info["reward_terms"]["success"] == 10.0
    # potential-based progress: the summed progress equals 10 * (start - end distance)
    assert total == pytest.approx(10.0 + 10.0 * (0.6 - info["kin_distance"]))


def test_seek_truncates_and_penalises_collisions():
    env = gym.make(SEEK, max_steps=12)
    fixed_scene(env.unwrapped, (scenes.Robot(0.0, 0.0, 0.0), scenes.Robot(-1.5, 0.0, 0.0)),
                (scenes.Wall(x1=0.2, y1=-0.5, x2=0.2, y2=0.5),))
    env.reset(seed=0)
    hits = []
    for i in range(12):
        _, _, terminated, truncated, info = env.step(np.array([1.0, 1.0]))
        hits.append(info["reward_terms"]["collision"])
        assert truncated == (i == 11) and not terminated
    assert hits[-1] == -0.1 and info["collision"]


def test_follow_lost_terminates():
    env = gym.make(FOLLOW, lost_distance=0.9, kin_speed=0.0)
    fixed_scene(env.unwrapped, (scenes.Robot(0.0, 0.0, 0.0), scenes.Robot(0.6, 0.0, math.pi)))
    _, info = env.reset(seed=0)
    assert info["in_band"]
    for _ in range(40):
        _, reward, terminated, truncated, info = env.step(np.array([-1.0, -1.0]))
        if terminated:
            break
    assert terminated and info["kin_distance"] > 0.9
    assert info["reward_terms"]["lost"] == -5.0
    assert info["reward_terms"]["out_of_band"] < 0


def test_follow_kin_wanders():
    env = gym.make(FOLLOW)
    env.reset(seed=1)
    start = env.unwrapped.world.poses[1].copy()
    for _ in range(30):
        env.step(np.zeros(2))
    assert np.hypot(*(env.unwrapped.world.poses[1, :2] - start[:2])) > 0.2


@pytest.mark.parametrize("env_id", IDS)
def test_kin_truth_matches_scan(env_id):
    env = gym.make(env_id, n_distractors=0)
    _, info = env.reset(seed=3)
    for _ in range(20):
        u = env.unwrapped
        scan, poses = u._last_scan, u.world.poses
        truth = unpad_kin_truth(info)
        assert tuple(truth) == KIN_TRUTH_FIELDS
        assert dict(zip(truth["index"].tolist(), truth["n_beams"].tolist(), strict=True)) == \
            scan.visible_robots(0)
        for k, j in enumerate(truth["index"]):
            d = poses[j, :2] - poses[0, :2]
            assert truth["range"][k] == pytest.approx(np.hypot(*d))
            assert truth["x"][k] == pytest.approx(truth["range"][k] * math.cos(truth["bearing"][k]))
        assert tuple(unpad_detections(info)) == DETECTION_FIELDS
        _, _, _, _, info = env.step(env.action_space.sample())


def test_detector_none_removes_key_and_obs_unchanged():
    with_det = gym.make(SEEK)
    without = gym.make(SEEK, detector=None)
    obs_a, info_a = with_det.reset(seed=5)
    obs_b, info_b = without.reset(seed=5)
    assert "kin_detections" in info_a and "kin_detections" not in info_b
    assert np.array_equal(obs_a, obs_b)  # the detector never changes the observation unless asked


class StubDetector:
    """Reports one kin 1 m ahead, 30° to the left, on beams 355..3 (wrapping)."""

    def __init__(self):
        self.calls = 0

    def detect(self, ranges, angles):
        from detectors import Detection, DetectionResult

        self.calls += 1
        b = math.radians(30)
        return DetectionResult([Detection(1.0, b, math.cos(b), math.sin(b), 0.001, 355, 3, 9)], [])


def test_custom_detector_and_observation_channels():
    det = StubDetector()
    env = gym.make(SEEK, detector=det, obs_detections="topk", obs_top_k=2, frame_stack=2)
    obs, info = env.reset(seed=0)
    layout = env.unwrapped.layout
    assert obs.shape == (2 * (360 + 8),) and det.calls == 1
    assert unpad_detections(info)["range"].tolist() == [1.0]
    frame = obs[layout.frame_dim :]
    np.testing.assert_allclose(frame[360:368], [1, 1 / 12, 0.5, math.cos(math.radians(30)), 0, 0, 0, 0],
                               atol=1e-6)
    assert np.array_equal(obs[: layout.frame_dim], frame)  # reset fills the stack
    obs, *_ = env.step(np.zeros(2))
    np.testing.assert_allclose(layout.newest_scan(obs), env.unwrapped._last_scan.ranges[0], rtol=1e-6)

    env = gym.make(SEEK, detector=StubDetector(), obs_detections="mask")
    obs, _ = env.reset(seed=0)
    mask = obs[360:]
    assert mask.shape == (360,) and np.flatnonzero(mask).tolist() == [0, 1, 2, 3, 355, 356, 357, 358, 359]


def test_learned_detector_channel():
    pytest.importorskip("torch")
    env = gym.make(SEEK, detector="learned", obs_detections="topk")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert set(unpad_detections(info)) >= {"range", "bearing", "score", "kin_index"}
    with pytest.raises(ValueError, match="detector must be .*, got 'neural'"):
        gym.make(SEEK, detector="neural")


@pytest.mark.parametrize("env_id", IDS)
def test_bad_actions_raise(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    for bad, msg in [
        (np.array([np.nan, 0.0]), "finite"),
        (np.array([0.0, np.inf]), "finite"),
        (np.zeros(3), r"shape \(2,\)"),
        (np.zeros((2, 2)), r"shape \(2,\)"),
        ("go", "2 numbers"),
    ]:
        with pytest.raises(ValueError, match=msg):
            env.step(bad)
    env = gym.make(env_id, action_type="discrete")
    env.reset(seed=0)
    for bad in (5, -1, 1.5, np.nan, True):
        with pytest.raises(ValueError, match=r"integer in \[0, 5\)"):
            env.step(bad)
    env.step(np.int32(1))
    env.step(np.array(2))


@pytest.mark.parametrize("env_id", IDS)
def test_unknown_kwargs_raise(env_id):
    with pytest.raises(TypeError, match=r"unknown argument\(s\) \['n_robotz'\]"):
        gym.make(env_id, n_robotz=3)
    with pytest.raises(ValueError, match="valid arguments are"):
        gym.make(env_id, colour="red")
    assert issubclass(UnknownArgumentError, TypeError) and issubclass(UnknownArgumentError, ValueError)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_distractors": -1}, "n_distractors must be an integer"),
        ({"n_distractors": 2.5}, "n_distractors must be an integer"),
        ({"arena_size": float("nan")}, "arena_size must be a finite number"),
        ({"noise_sigma": -0.1}, "noise_sigma"),
        ({"max_steps": 0}, "max_steps"),
        ({"frame_stack": 0}, "frame_stack"),
        ({"action_type": "joystick"}, "action_type must be one of"),
        ({"obs_detections": "boxes"}, "obs_detections must be"),
        ({"obs_detections": "topk", "detector": None}, "needs a detector"),
        ({"detector": "magic"}, "detector must be"),
        ({"detector": 42}, "detector must be"),
        ({"render_mode": "ascii"}, "render_mode must be"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    with warnings.catch_warnings(), pytest.raises(ValueError, match=match):
        warnings.simplefilter("ignore")  # gym.make's own warning about an unknown render_mode
        gym.make(SEEK, **kwargs)


def test_bad_follow_band_raises():
    with pytest.raises(ValueError, match="band_max"):
        gym.make(FOLLOW, band_min=0.8, band_max=0.5)


def test_rgb_array_render_marks_detections():
    env = gym.make(SEEK, render_mode="rgb_array", render_size=256)
    fixed_scene(env.unwrapped, (scenes.Robot(0.0, 0.0, 0.0), scenes.Robot(0.6, 0.0, math.pi)),
                (scenes.Prism(x=-0.8, y=0.4, sides=6, width=0.07),))
    env.reset(seed=0)
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and max(img.shape) == 256
    green = np.all(img == (20, 170, 40), axis=-1)
    assert green.any()  # the real kin's detection ring
    env.step(np.array([1.0, -1.0]))
    assert not np.array_equal(img, env.render())


@pytest.mark.parametrize("env_id", IDS)
def test_human_render_and_close(env_id):
    env = gym.make(env_id, render_mode="human", render_size=128)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.render() is None
    env.close()
    env.close()


def test_render_without_mode_warns():
    env = gym.make(SEEK).unwrapped
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_missing_pygame_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)  # makes `import pygame` fail
    with pytest.raises(gym.error.DependencyNotInstalled, match=r"pip install kin-envs\[viz\]"):
        gym.make(SEEK, render_mode="rgb_array")
