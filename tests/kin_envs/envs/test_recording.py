"""kin_envs.envs.recording: one seeded episode of any env to a GIF or an MP4."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import kin_envs  # noqa: F401  (registers the ids)
from kin_envs import aggregation_v2
from kin_envs.envs.recording import VideoWriter, record_episode

pytest.importorskip("pygame")
Image = pytest.importorskip("PIL.Image")


def _gif_frames(path) -> int:
    with Image.open(path) as im:
        assert im.format == "GIF"
        return im.n_frames


def test_gymnasium_env_to_gif_is_seeded(tmp_path):
    env = gymnasium.make("kin_envs/KinSeek-v2", render_mode="rgb_array", render_size=96)
    a = record_episode(env, tmp_path / "a.gif", seed=3, max_steps=6)
    record_episode(env, tmp_path / "b.gif", seed=3, max_steps=6)
    env.close()
    assert a["steps"] == 6 and a["frames"] == 7 and _gif_frames(a["path"]) == 7
    assert (tmp_path / "a.gif").read_bytes() == (tmp_path / "b.gif").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "b.gif"]  # no temporary files


def test_swarm_to_gif_with_a_policy(tmp_path):
    env = aggregation_v2.parallel_env(n_robots=3, render_mode="rgb_array", render_size=96, max_cycles=4)
    calls = []

    def spin(obs, infos):  # every frame differs (Pillow merges identical consecutive GIF frames)
        calls.append(sorted(obs))
        return {agent: np.array([-0.5, 0.5], np.float32) for agent in obs}

    r = record_episode(env, tmp_path / "swarm.gif", policy=spin, seed=0)
    env.close()
    assert r["steps"] == 4 and _gif_frames(tmp_path / "swarm.gif") == 5  # episode ends at max_cycles
    assert calls[0] == sorted(env.possible_agents)


def test_mp4(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    env = gymnasium.make("kin_envs/KinFollow-v2", render_mode="rgb_array", render_size=97)  # odd size
    r = record_episode(env, tmp_path / "follow.mp4", seed=1, max_steps=5, fps=5)
    env.close()
    data = (tmp_path / "follow.mp4").read_bytes()
    assert r["frames"] == 6 and data[4:8] == b"ftyp" and len(data) > 1000
    assert [p.name for p in tmp_path.iterdir()] == ["follow.mp4"]


def test_bad_input(tmp_path):
    env = gymnasium.make("kin_envs/KinSeek-v2")
    with pytest.raises(ValueError, match="render_mode='rgb_array'"):
        record_episode(env, tmp_path / "x.gif")
    env.close()
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        VideoWriter(tmp_path / "x.avi")
    with pytest.raises(ValueError, match="fps"):
        VideoWriter(tmp_path / "x.gif", fps=0)
    w = VideoWriter(tmp_path / "x.gif")
    with pytest.raises(ValueError, match="H x W x 3 uint8"):
        w.append(np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="no frames"):
        w.close()
    with pytest.raises(RuntimeError), VideoWriter(tmp_path / "y.gif") as w:  # aborted: nothing written
        w.append(np.zeros((8, 8, 3), np.uint8))
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []
