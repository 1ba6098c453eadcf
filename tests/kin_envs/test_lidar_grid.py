"""The grid broad phase against the brute-force kernel: the same scans, bit for bit."""

import math

import numpy as np
import pytest

from kin_envs import LidarSpec, World, scenes
from kin_envs.core.lidar import build_lidar_grid, cast_scan
from kin_envs.core.world import WorldConfig
from kin_envs.scenes import Arena, Robot, Scene

BRUTE = WorldConfig(lidar_grid=False)


def _assert_same(a, b):
    for name in ("ranges", "true_ranges", "hit_kind", "hit_index"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x, y, err_msg=name)


def _cast_both(origins, headings, circles, segments, grid, spec=None):
    spec = spec or LidarSpec()
    n_prim = len(circles) + len(segments)
    args = (
        origins, headings, circles, segments, np.full(len(origins), -1), np.zeros(n_prim + 1, np.int8),
        np.arange(-1, n_prim, dtype=np.int32), spec,
    )  # fmt: skip
    a, b = cast_scan(*args, dtype=np.float64), cast_scan(*args, dtype=np.float64, grid=grid)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    return a


@pytest.mark.parametrize(
    "n_robots, n_obstacles, size, cell",
    [
        (3, 10, 5.0, None),
        (16, 100, 16.0, None),
        (8, 1000, 40.0, None),
        (24, 300, 20.0, 0.37),
        (5, 60, 9.0, 4.0),
    ],
)
def test_random_arenas_grid_equals_brute_force(n_robots, n_obstacles, size, cell):
    lidar = LidarSpec(noise_sigma=0.01, dropout_prob=0.05)
    scene = scenes.random_arena(n_robots, n_obstacles, seed=n_obstacles, size=size, lidar=lidar)
    grid = World(scene, seed=3, config=WorldConfig(lidar_grid=True, lidar_cell_size=cell))
    brute = World(scene, seed=3, config=BRUTE)
    assert grid._lidar_grid is not None and brute._lidar_grid is None
    _assert_same(grid.scan(), brute.scan())  # noise and dropouts drawn identically
    _assert_same(grid.scan(robots=[0]), brute.scan(robots=[0]))


def test_moving_robots_and_movable_obstacles():
    scene = scenes.random_arena(12, 40, seed=5, size=6.0)
    movable = tuple(
        scenes.obstacle_from_dict({**o.to_dict(), "movable": True}) if k % 2 == 0 else o
        for k, o in enumerate(scene.obstacles)
    )
    scene = scene.replace(obstacles=movable)
    worlds = [
        World(scene, seed=0, config=c) for c in (WorldConfig(lidar_grid=True, lidar_cell_size=0.5), BRUTE)
    ]
    rng = np.random.default_rng(0)
    for _ in range(15):
        cmd = np.column_stack([np.full(12, 0.3), rng.uniform(-2, 2, 12)])
        # also carry the movable obstacles across cell borders (and out of the arena) by hand
        shift = rng.uniform(-1.5, 1.5, (len(movable), 3))
        for w in worlds:
            w.step(commands=cmd)
            for j in range(0, len(movable), 2):
                body = w.obstacle_bodies[j]
                body.position = (body.position[0] + shift[j, 0], body.position[1] + shift[j, 1])
                body.angle += shift[j, 2]
        _assert_same(worlds[0].scan(noise=False), worlds[1].scan(noise=False))
    assert np.abs(worlds[0].obstacle_poses[::2, :2] - [o.center for o in movable[::2]]).max() > 1.0


def test_origins_and_primitives_on_cell_borders_and_corners():
    rng = np.random.default_rng(1)
    circles = np.column_stack([rng.uniform(-5, 5, (40, 2)), rng.uniform(0.02, 0.3, 40)])
    walls = rng.uniform(-5, 5, (30, 4))
    box = np.array([[-6, -6, 6, -6], [6, -6, 6, 6], [6, 6, -6, 6], [-6, 6, -6, -6]], float)
    segments = np.concatenate([walls, box])
    for cell in (1.0, 0.5, 2.5):
        grid = build_lidar_grid(circles, segments, bounds=(-6, -6, 6, 6), cell_size=cell)
        gx, gy = grid.origin
        # snap everything onto grid lines: origins on corners and edges, segment ends on corners
        k = rng.integers(1, min(grid.shape) - 1, (60, 2))
        corners = np.column_stack([gx + k[:, 0] * cell, gy + k[:, 1] * cell])
        edges = corners + np.column_stack([rng.uniform(0, cell, 60), np.zeros(60)])
        origins = np.concatenate([corners, edges])
        snapped = segments.copy()
        snapped[:30, :2] = corners[:30]
        snapped[:30, 2:] = corners[30:60]
        grid2 = build_lidar_grid(circles, snapped, bounds=(-6, -6, 6, 6), cell_size=cell)
        assert grid2.origin == grid.origin
        # headings along the grid lines: beams run exactly along cell borders and through corners
        headings = rng.choice([0.0, math.pi / 2, math.pi, -math.pi / 2, math.pi / 4], len(origins))
        _cast_both(origins, headings, circles, snapped, grid2)
        _cast_both(origins, rng.uniform(-math.pi, math.pi, len(origins)), circles, segments, grid)


def test_robots_and_moving_primitives_outside_the_grid():
    # no walls: robots may leave the arena the grid covers; they fall back to brute force
    scene = Scene(robots=(Robot(0, 0, 0), Robot(1.0, 0.2, 1.0)), arena=Arena(4, 4, walls=False))
    world = World(scene)
    circles = world._circles.copy()
    circles[:, :2] = [[30.0, 0.0], [25.0, 0.01]]  # both far outside the 4 x 4 m grid
    grid = build_lidar_grid(circles, np.zeros((0, 4)), [0, 1], bounds=(-2, -2, 2, 2))
    origins = np.array([[30.0, 0.0], [25.0, 0.01], [0.0, 0.0]])
    r = _cast_both(origins, np.array([math.pi, 0.0, 0.0]), circles, np.zeros((0, 4)), grid)
    # from 30 m looking back: the housing at (25, 0.01), beam 0 passing 1 cm off its centre
    assert r[1][0, 0] == pytest.approx(5.0 - math.sqrt(0.035**2 - 0.01**2), abs=1e-9)
    # a moving primitive outside the grid seen from inside it
    circles[0, :2] = [2.5, 0.0]
    _cast_both(np.array([[0.0, 0.0]]), np.zeros(1), circles, np.zeros((0, 4)), grid)


def test_ties_go_to_the_lower_primitive_id():
    # twin circles on the left, twin segments ahead: exactly equal distances
    circles = np.array([[0.0, 2.0, 0.1], [0.0, 2.0, 0.1], [0.0, -3.0, 0.2]])
    segments = np.array([[1.0, 3.0, 1.0, -3.0], [1.0, 3.0, 1.0, -3.0]])
    for cell in (0.3, 1.0):
        grid = build_lidar_grid(circles, segments, bounds=(-4, -4, 4, 4), cell_size=cell)
        _, _, _, prim = _cast_both(np.zeros((1, 2)), np.zeros(1), circles, segments, grid)
        assert prim[0, 270] == 0 and prim[0, 0] == 3  # ids (owner table = primitive id)


def test_default_uses_the_grid_only_in_arenas_wider_than_the_lidar_reach():
    small = World(scenes.random_arena(2, 5, seed=0, size=20.0))
    large = World(scenes.random_arena(2, 5, seed=0, size=(30.0, 25.0)))
    assert small._lidar_grid is None
    assert large._lidar_grid is not None and large._lidar_grid.cell_size == 12.0 / 3
    assert World(
        scenes.random_arena(2, 5, seed=0, size=20.0), config=WorldConfig(lidar_grid=True)
    )._lidar_grid


def test_grid_input_errors():
    circles, segments = np.zeros((2, 3)) + [0, 0, 0.1], np.array([[1.0, 1.0, 2.0, 2.0]])
    with pytest.raises(ValueError, match="cell_size"):
        build_lidar_grid(circles, segments, cell_size=0.0)
    with pytest.raises(ValueError, match="dynamic_circles"):
        build_lidar_grid(circles, segments, dynamic_circles=[5])
    with pytest.raises(ValueError, match="bounds"):
        build_lidar_grid(circles, segments, bounds=(1, 1, 0, 0))
    grid = build_lidar_grid(circles, segments)
    with pytest.raises(ValueError, match="rebuild"):
        cast_scan(np.zeros((1, 2)), np.zeros(1), circles[:1], segments, np.array([-1]),
                  np.zeros(3, np.int8), np.arange(-1, 2, dtype=np.int32), LidarSpec(), grid=grid)  # fmt: skip
    with pytest.raises(TypeError, match="LidarGrid"):
        cast_scan(np.zeros((1, 2)), np.zeros(1), circles, segments, np.array([-1]),
                  np.zeros(4, np.int8), np.arange(-1, 3, dtype=np.int32), LidarSpec(), grid="g")  # fmt: skip
    with pytest.raises(ValueError, match="lidar_cell_size"):
        WorldConfig(lidar_cell_size=-1.0)
    with pytest.raises(ValueError, match="lidar_grid"):
        WorldConfig(lidar_grid="yes")


def test_unbounded_headings():
    # robots' body angles are unbounded (a robot turning in place); the kernels wrap the heading only to
    # pick candidate beams, so a heading 2 pi k away gives the same scan up to rounding
    scene = scenes.random_arena(6, 60, seed=2, size=9.0)
    world = World(scene, seed=0)
    grid = build_lidar_grid(world._circles, world._segments, range(6), bounds=(-4.5, -4.5, 4.5, 4.5),
                            cell_size=1.5)  # fmt: skip
    poses = world.poses
    base = _cast_both(poses[:, :2], poses[:, 2], world._circles, world._segments, grid)
    for k in (-1000, -3, 1, 7, 250):
        r = _cast_both(poses[:, :2], poses[:, 2] + 2 * math.pi * k, world._circles, world._segments, grid)
        same = r[3] == base[3]
        assert same.mean() > 0.998  # beams grazing an edge may flip with the heading's rounding
        np.testing.assert_allclose(r[1][same], base[1][same], atol=1e-6)


def test_groups_long_segments_and_large_circles():
    # boxes and prisms (edges chained into groups), long walls (listed in every cell they touch) and
    # cylinders larger than half a cell (indexed with the moving circles), seen from far away, from
    # right next to them and from inside their bounding circles
    rng = np.random.default_rng(7)
    polys = []
    for _ in range(30):
        c, r, k = rng.uniform(-5, 5, 2), rng.uniform(0.05, 0.4), rng.integers(3, 7)
        a = np.sort(rng.uniform(0, 2 * math.pi, k))
        polys.append(np.column_stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a)]))  # CCW
    walls = np.array([[-4.0, -4.5, 4.0, -4.5], [4.5, -4.0, 4.5, 3.0], [-3.0, 2.0, 3.0, 2.2]])
    segments = np.concatenate([np.concatenate([v, np.roll(v, -1, axis=0)], axis=1) for v in polys] + [walls])
    circles = np.column_stack([rng.uniform(-5, 5, (12, 2)), rng.uniform(0.02, 1.5, 12)])
    near = np.concatenate([v[:1] + rng.normal(0, 0.05, (1, 2)) for v in polys])  # next to / inside
    origins = np.concatenate([rng.uniform(-5.5, 5.5, (40, 2)), near])
    for cell in (0.6, 1.5, 4.0):
        grid = build_lidar_grid(circles, segments, bounds=(-6, -6, 6, 6), cell_size=cell)
        assert grid.groups.shape[1] > 0 and len(grid.segment_items) >= len(walls)
        assert len(grid.dynamic_circles) == int(np.sum(circles[:, 2] > cell / 2))
        _cast_both(origins, rng.uniform(-math.pi, math.pi, len(origins)), circles, segments, grid)


def test_world_scratch_reused_across_scans():
    # the World keeps the grid kernel's work arrays; every scan (all robots, subsets, one robot, after
    # motion) must still equal the brute force's
    scene = scenes.random_arena(10, 150, seed=9, size=26.0)
    grid = World(scene, seed=1, config=WorldConfig(lidar_grid=True))
    brute = World(scene, seed=1, config=BRUTE)
    rng = np.random.default_rng(3)
    for robots in (None, [3], [9, 0, 4], None, [3]):
        _assert_same(grid.scan(robots=robots), brute.scan(robots=robots))
        cmd = rng.uniform(-1, 1, (10, 2)) * [0.3, 2.0]
        grid.step(commands=cmd)
        brute.step(commands=cmd)
