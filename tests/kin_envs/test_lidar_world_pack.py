"""World.scan's compiled entry (issue 14, round 9): the robots' poses read there through Chipmunk's getters
(never a stale copy: bodies moved by hand between steps are seen), its arguments packed in two arrays
(``world_pack``: the primitives are views that moved obstacles update), and the shared index array of a
scan of every robot."""

import math

import numba
import numpy as np
import pymunk
import pytest
from pymunk._chipmunk import ffi

from kin_envs import World, scenes
from kin_envs.core import world as world_mod
from kin_envs.core.lidar import LidarSpec, build_lidar_grid, cast_scan, grid_args, read_poses, world_pack
from kin_envs.core.multi import WorldBatch
from kin_envs.core.world import WorldConfig
from tests.kin_envs.oracle import oracle_scan

NAMES = ("ranges", "true_ranges", "hit_kind", "hit_index")


def _address(body: pymunk.Body) -> int:
    return int(ffi.cast("uintptr_t", body._body))


def test_compiled_pose_read_equals_chipmunk_getters():
    rng = np.random.default_rng(0)
    bodies = [pymunk.Body(1.0, 1.0) for _ in range(40)]
    for k, b in enumerate(bodies):
        scale = 10.0 ** rng.integers(-8, 8)  # tiny to huge coordinates and unbounded angles
        b.position = tuple(rng.normal(0.0, scale, 2))
        b.angle = float(rng.normal(0.0, 50.0)) if k % 3 else -0.0
    out = np.full((len(bodies), 3), np.nan)
    read_poses(np.array(world_mod._GETTERS), np.array([_address(b) for b in bodies], np.int64), out)
    ref = np.array([(b.position.x, b.position.y, b.angle) for b in bodies])
    assert out.tobytes() == ref.tobytes()  # bit for bit, signed zeros included


def _reference(w: World, robots) -> tuple:
    """The world's scan from poses read through pymunk's Python API and the brute-force kernel."""
    poses = w.poses[robots]
    circles = w._circles.copy()
    circles[: w.n_robots, :2] = w.poses[:, :2]
    return poses, cast_scan(poses[:, :2], poses[:, 2], circles, w._segments.copy(), np.asarray(robots),
                            w._prim_kind, w._prim_index, w.scene.lidar)  # fmt: skip


@pytest.mark.parametrize("grid", [False, True])
@pytest.mark.parametrize("n_robots, n_obstacles, size", [(1, 30, 26.0), (6, 60, 10.0), (40, 300, 28.0)])
def test_scan_sees_robots_moved_by_hand_between_steps(grid, n_robots, n_obstacles, size):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=n_robots, size=size)
    w = World(scene, seed=0, config=WorldConfig(lidar_grid=grid))
    rng = np.random.default_rng(n_robots)
    hx, hy = scene.arena.half_extents
    for t in range(4):
        w.step(commands=np.tile([0.3, 0.8], (n_robots, 1)))
        before = w.scan(noise=False)
        # teleport and turn some robots by hand (no step: nothing else updates): the next scan sees them
        moved = rng.choice(n_robots, max(1, n_robots // 3), replace=False)
        for i in moved:
            b = w.robot_bodies[i]
            while True:  # somewhere clear (an origin inside a shape is no scan to compare with the oracle)
                xy = (float(rng.uniform(-hx + 0.5, hx - 0.5)), float(rng.uniform(-hy + 0.5, hy - 0.5)))
                near = w.space.point_query(xy, 0.3, pymunk.ShapeFilter())
                if not [q for q in near if q.shape.body is not b]:
                    break
            b.position = xy
            b.angle = float(rng.uniform(-20.0, 20.0))  # unbounded: the scan wraps it
            w.space.reindex_shapes_for_body(b)  # (for the oracle's queries only)
        robots = None if t % 2 else sorted(set(moved.tolist()) | {0})
        scan = w.scan(robots=robots, noise=False)
        idx = np.arange(n_robots) if robots is None else np.asarray(robots)
        poses, ref = _reference(w, idx)
        np.testing.assert_array_equal(scan.poses, poses)
        wrapped = np.arctan2(np.sin(poses[:, 2]), np.cos(poses[:, 2]))
        np.testing.assert_allclose(scan.poses[:, 2], wrapped, rtol=0, atol=1e-12)
        for name, a in zip(NAMES, ref, strict=True):
            np.testing.assert_array_equal(getattr(scan, name), a, err_msg=name)
        for i in moved:  # the robots did move: the previous scan's poses are not the new ones
            assert not np.array_equal(before.poses[i, :2], w.poses[i, :2])
    # and against the independent pymunk oracle, robot 0 (moved obstacles and housings in the space)
    d, kind, index = oracle_scan(w, 0)
    scan = w.scan(noise=False)
    hit = np.isfinite(d)
    np.testing.assert_array_equal(np.isfinite(scan.true_ranges[0]), hit)
    np.testing.assert_allclose(scan.true_ranges[0][hit], d[hit], atol=1e-6, rtol=0)
    np.testing.assert_array_equal(scan.hit_kind[0], kind)
    np.testing.assert_array_equal(scan.hit_index[0], index)


@pytest.mark.parametrize("grid", [False, True])
def test_obstacles_moved_by_hand_are_seen_through_the_packed_primitives(grid):
    scene = scenes.random_arena(3, 40, seed=9, size=26.0)
    scene = scene.replace(obstacles=tuple(
        scenes.obstacle_from_dict({**o.to_dict(), "movable": True}) if k % 2 else o
        for k, o in enumerate(scene.obstacles)))  # fmt: skip
    w = World(scene, seed=0, config=WorldConfig(lidar_grid=grid))
    assert (w._lidar_grid is not None) == grid
    wf = w._lidar_call[1]
    # the primitives World updates are views into the packed array the kernel reads
    assert np.shares_memory(w._circles, wf) and np.shares_memory(w._segments, wf)
    rng = np.random.default_rng(2)
    robot = w.robot_bodies[0].position
    for _ in range(3):
        for j in range(1, len(scene.obstacles), 2):
            b = w.obstacle_bodies[j]
            # around robot 0, within the lidar's reach and clear of it (its origin inside nothing)
            r, a = rng.uniform(2.0, 6.0), rng.uniform(-math.pi, math.pi)
            b.position = (robot[0] + r * math.cos(a), robot[1] + r * math.sin(a))
            b.angle = float(rng.uniform(-3, 3))
            w.space.reindex_shapes_for_body(b)  # (for the oracle's queries)
        scan = w.scan(noise=False)
        d, kind, index = oracle_scan(w, 0)
        hit = np.isfinite(d)
        # (overlapping moved obstacles can make the oracle and the raycaster disagree only on which of two
        # coincident surfaces is first: compare distances everywhere, owners where they are unambiguous)
        np.testing.assert_array_equal(np.isfinite(scan.true_ranges[0]), hit)
        np.testing.assert_allclose(scan.true_ranges[0][hit], d[hit], atol=1e-6, rtol=0)
        assert np.mean(scan.hit_index[0] == index) > 0.95
        assert np.any(np.isin(scan.hit_index[0], np.arange(1, len(scene.obstacles), 2)))


def test_scan_of_every_robot_shares_a_read_only_index_array():
    w = World(scenes.random_arena(4, 5, seed=0, size=6.0), seed=0)
    a, b = w.scan(), w.scan()
    np.testing.assert_array_equal(a.robots, np.arange(4))
    assert not a.robots.flags.writeable and a.robots is b.robots
    with pytest.raises(ValueError):
        a.robots[0] = 3
    # the caller's arrays are never reused
    assert not np.shares_memory(a.ranges, b.ranges) and not np.shares_memory(a.poses, b.poses)
    some = w.scan(robots=[3, 1])
    assert some.robots.flags.writeable
    np.testing.assert_array_equal(some.robots, [3, 1])


@pytest.mark.parametrize("grid", [False, True])
def test_world_pack_layout(grid):
    from kin_envs import LidarSpec

    rng = np.random.default_rng(1)
    circles = np.column_stack([rng.uniform(-5, 5, (7, 2)), rng.uniform(0.05, 0.3, 7)])
    segments = rng.uniform(-5, 5, (11, 4))
    kind = rng.integers(0, 8, 19).astype(np.int8)
    index = rng.integers(-1, 50, 19).astype(np.int32)
    g = build_lidar_grid(circles, segments, [0, 1], bounds=(-6, -6, 6, 6)) if grid else None
    spec = LidarSpec(n_beams=90, range_min=0.2, range_max=7.0)
    wf, wi, c, s, gv = world_pack([11, 22], (5, 6), spec, circles, segments, kind, index, g)
    np.testing.assert_array_equal(c, circles)
    np.testing.assert_array_equal(s, segments)
    assert np.shares_memory(c, wf) and np.shares_memory(s, wf)
    assert wi[:8].tolist() == [2, 90, 7, 11, 19, 5, 6, int(grid)]
    fo, io = wi[8:16], wi[16:22]
    assert fo[-1] == len(wf) and io[-1] == len(wi) and np.all(np.diff(fo) >= 0) and np.all(np.diff(io) >= 0)
    assert wf[0] == 0.2 and wf[1] == 7.0
    assert wi[io[0] : io[1]].tolist() == [11, 22]
    np.testing.assert_array_equal(wi[io[1] : io[2]], kind)
    np.testing.assert_array_equal(wi[io[2] : io[3]], index)
    if grid:
        gf, gi = grid_args(g)
        np.testing.assert_array_equal(gv[0], gf)
        np.testing.assert_array_equal(gv[1], gi)
        assert gv[2].shape[0] == 25 and gv[3].shape[0] == 14 and not gv[3].any()  # stamps start at 0
    else:
        assert gv is None
        k = max(len(circles), len(segments))
        np.testing.assert_array_equal(wi[io[4] : io[4] + k], np.arange(k))  # the brute force's ids


def test_world_batch_sees_robots_moved_by_hand_like_world():
    scene = scenes.random_arena(5, 200, seed=4, size=26.0)
    worlds = [World(scene, seed=1, config=WorldConfig(lidar_grid=g)) for g in (True, False)]
    batch = WorldBatch([World(scene, seed=1, config=WorldConfig(lidar_grid=g)) for g in (True, False)])
    for k, w in enumerate(worlds):
        for ws in (w, batch[k]):
            ws.robot_bodies[2].position = (3.0, -4.0)
            ws.robot_bodies[2].angle = 7.5
    scans, poses = batch.scan(noise=False)
    for k, w in enumerate(worlds):
        ref = w.scan(noise=False)
        np.testing.assert_array_equal(ref.poses, poses[k])
        assert ref.poses[2].tolist() == [3.0, -4.0, math.atan2(math.sin(7.5), math.cos(7.5))]
        for name in NAMES:
            np.testing.assert_array_equal(getattr(ref, name), getattr(scans[k], name), err_msg=name)


def test_pose_read_checked_once_per_process(monkeypatch):
    # a platform whose getters' results the compiled read misreads is refused, naming what it read
    monkeypatch.setattr(world_mod, "_GETTERS_CHECKED", [])
    monkeypatch.setattr(world_mod, "read_poses", lambda getters, bodies, out: out.fill(0.5))
    with pytest.raises(RuntimeError, match=r"gave \[\[0.5, 0.5, 0.5\]\]"):
        World(scenes.random_arena(1, 2, seed=0, size=5.0), seed=0)
    monkeypatch.undo()
    world_mod._check_getters()  # the real read passes
    assert world_mod._GETTERS_CHECKED == [True]


@pytest.mark.parametrize("grid", [False, True])
def test_scan_calls_the_compiled_entry_directly_with_the_same_results(grid):
    """After its first scan a World calls the kernel's compiled entry without numba's dispatch
    (``compiled_entry``): every later scan, of all robots, some, none or repeated ones, with noise, is the
    one the dispatcher gives, bit for bit."""
    scene = scenes.random_arena(5, 40, seed=3, size=26.0 if grid else 10.0,
                                lidar=LidarSpec(noise_sigma=0.01, dropout_prob=0.05))  # fmt: skip
    worlds = [World(scene, seed=1, config=WorldConfig(lidar_grid=grid)) for _ in range(2)]
    worlds[1]._scan_dispatch = False  # keeps numba's dispatcher
    kernel = worlds[1]._scan_consts[0]
    assert isinstance(kernel, numba.core.registry.CPUDispatcher)
    for robots in (None, [2], None, [], [4, 0, 4, 4, 1, 1, 3, 2], np.array([1], np.int8), None):
        for w in worlds:
            w.step(commands=np.tile([0.4, 0.7], (5, 1)))
        a, b = (w.scan(robots) for w in worlds)
        for name in (*NAMES, "poses", "robots"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (robots, name)
            assert getattr(a, name).dtype == getattr(b, name).dtype
        assert a.range_max == b.range_max and a.angles is b.angles
    entry = worlds[0]._scan_consts[0]
    assert entry is not kernel and not isinstance(entry, numba.core.registry.CPUDispatcher)
    assert worlds[1]._scan_consts[0] is kernel
