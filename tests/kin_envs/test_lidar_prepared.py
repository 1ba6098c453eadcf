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


def _reference_scan(w: World) -> tuple:
    from kin_envs.core.lidar import beam_tables
    from tests.kin_envs.reference_lidar import reference_kernel

    p, n, nb = w.poses, w.n_robots, w.scene.lidar.n_beams
    w._update_lidar_geometry(p)
    out = (np.empty((n, nb), np.float32), np.empty((n, nb), np.float32), np.empty((n, nb), np.int8),
           np.empty((n, nb), np.int32))  # fmt: skip
    reference_kernel(p[:, 0].copy(), p[:, 1].copy(), p[:, 2].copy(), beam_tables(nb), w.scene.lidar.range_min,
                     w.scene.lidar.range_max, w._circles, np.arange(n), w._segments, w._prim_kind,
                     w._prim_index, *out)  # fmt: skip
    return out


@pytest.mark.parametrize(
    "n_robots, n_obstacles, size",
    [(1, 10, 5.0), (40, 10, 9.0), (12, 120, 13.0), (8, 600, 30.0)],
)
def test_kernels_equal_the_pre_vectorised_reference(n_robots, n_obstacles, size):
    """The vectorised candidate passes select a superset of what hits and keep the hit arithmetic:
    brute force, grid and WorldBatch give the previous kernel's scans bit for bit."""
    from kin_envs.core.multi import WorldBatch

    scene = scenes.random_arena(n_robots, n_obstacles, seed=n_obstacles, size=size)
    worlds = [World(scene, seed=4, config=WorldConfig(lidar_grid=g)) for g in (False, True)]
    batch = WorldBatch([World(scene, seed=4, config=WorldConfig(lidar_grid=g)) for g in (False, True)])
    rng = np.random.default_rng(0)
    for _ in range(3):
        pairs = [(w, w.scan(noise=False)) for w in worlds]
        pairs += list(zip(batch.worlds, batch.scan(noise=False)[0], strict=True))
        for w, scan in pairs:
            for name, a in zip(("ranges", "true_ranges", "hit_kind", "hit_index"), _reference_scan(w),
                               strict=True):  # fmt: skip
                np.testing.assert_array_equal(getattr(scan, name), a, err_msg=name)
        cmd = rng.uniform(-1, 1, (n_robots, 2)) * [0.3, 1.5]
        for w in worlds:
            w.step(commands=cmd)
        batch.step(np.stack([batch[0].unicycle_to_wheel_speeds(cmd)] * 2))
