"""World.scan's prepared kernel path and its state read against the public, checked ones."""

import numpy as np
import pytest

from kin_envs import World, scenes
from kin_envs.core import world as world_mod
from kin_envs.core.lidar import cast_scan
from kin_envs.core.world import WorldConfig


@pytest.mark.parametrize(
    "n_robots, n_obstacles, size, grid",
    [(1, 10, 5.0, None), (12, 60, 9.0, False), (6, 400, 30.0, None), (9, 50, 9.0, True)],
)
def test_world_scan_equals_cast_scan(n_robots, n_obstacles, size, grid):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=n_obstacles, size=size)
    w = World(scene, seed=1, config=WorldConfig(lidar_grid=grid))
    w.step(commands=np.tile([0.2, 0.7], (n_robots, 1)))
    for robots in (None, [n_robots - 1], list(range(n_robots))[::-1]):
        scan = w.scan(robots=robots, noise=False)
        idx = np.arange(n_robots) if robots is None else np.asarray(robots)
        ref = cast_scan(scan.poses[:, :2], scan.poses[:, 2], w._circles, w._segments, idx, w._prim_kind,
                        w._prim_index, scene.lidar, grid=w._lidar_grid)  # fmt: skip
        for name, a in zip(("ranges", "true_ranges", "hit_kind", "hit_index"), ref, strict=True):
            np.testing.assert_array_equal(getattr(scan, name), a, err_msg=name)
        np.testing.assert_array_equal(scan.robots, idx)


@pytest.mark.parametrize("n_robots, n_obstacles", [(1, 10), (2, 300), (40, 10)])
def test_poses_same_whichever_state_read(monkeypatch, n_robots, n_obstacles):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=2, size=20.0)
    w = World(scene, seed=0)
    w.step(commands=np.tile([0.3, -0.9], (n_robots, 1)))
    auto, reads = world_mod._direct_read, {}
    for direct in (True, False):
        monkeypatch.setattr(world_mod, "_direct_read", lambda n, m, d=direct: d)
        reads[direct] = (w.poses, w.scan(noise=False).true_ranges)
    np.testing.assert_array_equal(reads[True][0], reads[False][0])
    np.testing.assert_array_equal(reads[True][1], reads[False][1])
    # the automatic choice reads body by body only with few robots among many bodies
    assert auto(1, 10) and auto(2, 300)
    assert not auto(40, 10) and not auto(64, 1000)
