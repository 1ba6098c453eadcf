"""The vectorised raycaster against pymunk's own segment queries, and the lidar conventions."""

import math

import numpy as np
import pytest

from kin_envs import HitKind, LidarSpec, World, scenes
from kin_envs.core.lidar import scan_shapes
from kin_envs.scenes import Arena, Box, Cylinder, Prism, Robot, Scene, Wall
from tests.kin_envs.oracle import oracle_scan


def _compare_with_oracle(world: World) -> None:
    scan = world.scan(noise=False)
    for r in range(world.n_robots):
        d, kind, index = oracle_scan(world, r)
        np.testing.assert_array_equal(np.isfinite(d), np.isfinite(scan.true_ranges[r]))
        hit = np.isfinite(d)
        # float32 storage: rounding error <= 4.8e-7 m below 16 m
        np.testing.assert_allclose(scan.true_ranges[r][hit], d[hit], atol=1e-6, rtol=0)
        np.testing.assert_array_equal(scan.hit_kind[r], kind)
        np.testing.assert_array_equal(scan.hit_index[r], index)
        readable = hit & (d >= world.scene.lidar.range_min)
        np.testing.assert_allclose(scan.ranges[r][readable], d[readable], atol=1e-6, rtol=0)
        assert np.all(scan.ranges[r][~readable] == world.scene.lidar.range_max)


@pytest.mark.parametrize("seed", range(6))
def test_random_arenas_match_pymunk_oracle(seed):
    rng = np.random.default_rng(seed)
    scene = scenes.random_arena(int(rng.integers(2, 12)), int(rng.integers(5, 40)), seed=seed, size=6.0)
    _compare_with_oracle(World(scene, seed=seed))


def test_oracle_after_motion_and_with_movable_obstacles():
    scene = scenes.random_arena(8, 20, seed=11, size=5.0)
    movable = tuple(
        scenes.obstacle_from_dict({**o.to_dict(), "movable": True}) if k % 2 == 0 else o
        for k, o in enumerate(scene.obstacles)
    )
    world = World(scene.replace(obstacles=movable), seed=0)
    rng = np.random.default_rng(0)
    for _ in range(30):
        world.step(commands=np.column_stack([np.full(8, 0.3), rng.uniform(-2, 2, 8)]))
    _compare_with_oracle(world)


def test_robots_show_only_their_housing():
    """A beam that crosses a robot's body but misses its 3.5 cm housing passes above it."""
    scene = Scene(robots=(Robot(0, 0, 0), Robot(1.0, 0, 0)), arena=Arena(4, 4, walls=False))
    scan = World(scene).scan()
    beams = scan.visible_robots(0)
    # housing radius 0.035 at 1 m subtends 2*asin(0.035) = 4.01 degrees: beams 358, 359, 0, 1, 2
    assert beams == {1: 5}
    on = np.flatnonzero(scan.hit_kind[0] == HitKind.ROBOT)
    assert sorted(on.tolist()) == [0, 1, 2, 358, 359]
    assert scan.ranges[0, 0] == pytest.approx(1.0 - 0.035, abs=1e-6)
    # beam 3 (3 degrees) crosses the 9 cm body (half-angle 5.2 deg) but reads max range
    assert scan.ranges[0, 3] == 12.0 and scan.hit_kind[0, 3] == HitKind.NONE


def test_beam_convention_clockwise_from_heading():
    spec = LidarSpec()
    assert spec.angles.shape == (360,)
    assert spec.angles[0] == 0.0
    assert spec.angles[90] == pytest.approx(-math.pi / 2)  # 90 degrees clockwise = the right
    assert spec.angles[270] == pytest.approx(math.pi / 2)  # the left
    # an object on the robot's left is seen by beam 270, rotated with the heading
    for heading in (0.0, 1.0, -2.5):
        left = (math.cos(heading + math.pi / 2), math.sin(heading + math.pi / 2))
        r = scan_shapes(origin=(0, 0), heading=heading, circles=[(2 * left[0], 2 * left[1], 0.1)])
        assert np.argmin(r) == 270
        assert r[270] == pytest.approx(1.9, abs=1e-9)


def test_no_return_and_min_range_read_max_range():
    spec = LidarSpec()
    assert np.all(scan_shapes(spec=spec) == spec.range_max)
    # a surface closer than range_min gives an invalid reading, reported as range_max
    r = scan_shapes(circles=[(0.12, 0.0, 0.02)])
    assert r[0] == spec.range_max
    # beyond range_max: no return
    r = scan_shapes(circles=[(12.5, 0.0, 0.1)])
    assert np.all(r == spec.range_max)


def test_polygon_scan_exact_distance():
    # a 7 cm square 1 m ahead, face-on: the central beam reads 1 - 0.035
    square = Box(x=1.0, width=0.07, depth=0.07).footprint()[1]
    r = scan_shapes(polygons=[square])
    assert r[0] == pytest.approx(0.965, abs=1e-12)
    hexagon = Prism(x=0.5, sides=6, width=0.07).footprint()[1]
    r = scan_shapes(polygons=[hexagon])
    assert r[0] == pytest.approx(0.5 - 0.035, abs=1e-12)  # a vertex points at the sensor


def test_noise_is_seeded_and_relative():
    lidar = LidarSpec(noise_sigma=0.01)
    scene = scenes.random_arena(4, 10, seed=3, size=6.0, lidar=lidar)
    a = World(scene, seed=7).scan()
    b = World(scene, seed=7).scan()
    c = World(scene, seed=8).scan()
    np.testing.assert_array_equal(a.ranges, b.ranges)
    assert not np.array_equal(a.ranges, c.ranges)
    valid = a.ranges < 12.0
    rel = (a.ranges[valid] - a.true_ranges[valid]) / a.true_ranges[valid]
    assert 0.008 < rel.std() < 0.012
    assert abs(rel.mean()) < 0.002


def test_dropouts():
    scene = scenes.random_arena(4, 10, seed=3, size=6.0, lidar=LidarSpec(dropout_prob=0.2))
    scan = World(scene, seed=1).scan()
    dropped = (scan.ranges == 12.0) & np.isfinite(scan.true_ranges)
    assert 0.15 < dropped.mean() < 0.25


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_beams": 2}, "n_beams"),
        ({"range_min": -1.0}, "range_min"),
        ({"range_max": 0.1}, "range_max"),
        ({"noise_sigma": -0.1}, "noise_sigma"),
        ({"dropout_prob": 1.5}, "dropout_prob"),
    ],
)
def test_lidar_spec_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LidarSpec(**kwargs)


def test_scan_rejects_bad_robot_index():
    world = World(scenes.paper_scenario(1))
    with pytest.raises(ValueError, match="robot indices"):
        world.scan(robots=[0, 9])


def test_walls_are_seen_and_owned():
    scene = Scene(
        robots=(Robot(0, 0, 0),), obstacles=(Wall(1.0, -1.0, 1.0, 1.0, thickness=0.1),), arena=Arena(4, 4)
    )
    scan = World(scene).scan()
    assert scan.hit_kind[0, 0] == HitKind.WALL and scan.hit_index[0, 0] == 0
    assert scan.ranges[0, 0] == pytest.approx(0.95, abs=1e-6)
    assert scan.hit_kind[0, 180] == HitKind.BOUNDARY and scan.hit_index[0, 180] == -1
    assert scan.ranges[0, 180] == pytest.approx(2.0, abs=1e-6)
    cyl = Scene(robots=(Robot(0, 0, 0),), obstacles=(Cylinder(0, 1, 0.1),), arena=Arena(4, 4))
    assert World(cyl).scan().hit_kind[0, 270] == HitKind.CYLINDER
