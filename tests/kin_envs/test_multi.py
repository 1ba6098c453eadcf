"""WorldBatch: K worlds stepped and scanned together give bit-identical results to stepping and
scanning each World on its own (poses, contacts, commands, scans with noise, ground truth),
also when worlds are replaced or only some are active."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from kin_envs import LidarSpec, World, scenes
from kin_envs.core.multi import WorldBatch

LIDAR = LidarSpec(noise_sigma=0.01, dropout_prob=0.02)
FIELDS = ("ranges", "true_ranges", "hit_kind", "hit_index", "poses", "robots")


def worlds(k: int, first_seed: int = 0) -> list[World]:
    # small crowded arenas: robots bump into each other, obstacles and walls
    return [World(scenes.random_arena(3, 8, seed=s, size=2.5, lidar=LIDAR), seed=s)
            for s in range(first_seed, first_seed + k)]


def assert_same(single: list[World], batch: WorldBatch, robots, active=None) -> None:
    scans, poses = batch.scan(robots, active=active)
    for j, w in enumerate(single):
        if active is not None and not active[j]:
            assert scans[j] is None
            continue
        ref = w.scan(robots)
        assert np.array_equal(w.poses, batch[j].poses) and np.array_equal(poses[j], w.poses)
        assert np.array_equal(w.contacts, batch[j].contacts)
        assert np.array_equal(w.commands, batch[j].commands)
        assert w.time == batch[j].time
        assert np.array_equal(w.odometry, batch[j].odometry)
        assert np.array_equal(w.odometry_delta, batch[j].odometry_delta)
        for f in FIELDS:
            assert np.array_equal(getattr(ref, f), getattr(scans[j], f)), f


def test_batch_is_bit_identical_to_separate_worlds():
    k = 6
    single, batch = worlds(k), WorldBatch(worlds(k))
    rng = np.random.default_rng(0)
    contacts = 0
    for t in range(120):
        # mostly forward at full speed: collisions with everything
        wheels = rng.uniform(4.0, 12.0, (k, 3, 2)) * rng.choice([1, -1], (k, 3, 1))
        wheels[:, 1] *= rng.random((k, 1)) < 0.5  # robot 1 often stands still, as a KinSeek kin
        wheels[:, 2, 1] = -wheels[:, 2, 0] * (t % 3 == 0)  # robot 2 sometimes turns in place
        for w, x in zip(single, wheels, strict=True):
            w.step(wheel_speeds=x)
        batch.step(wheels)
        if t == 60:  # a new episode in world 2
            single[2] = World(scenes.random_arena(3, 8, seed=99, size=2.5, lidar=LIDAR), seed=99)
            batch[2] = World(scenes.random_arena(3, 8, seed=99, size=2.5, lidar=LIDAR), seed=99)
        assert_same(single, batch, [0, 2] if t % 2 else None)
        contacts += sum(int(np.count_nonzero(w.contacts)) for w in single)
    assert contacts > 20
    # a copy of a batch-stepped world replays the same history (World copies)
    copy = pickle.loads(pickle.dumps(batch[0]))
    assert np.array_equal(copy.poses, single[0].poses)


def test_only_active_worlds_move_and_draw_noise():
    k = 4
    single, batch = worlds(k, 10), WorldBatch(worlds(k, 10))
    active = np.array([True, False, True, True])
    wheels = np.full((k, 3, 2), 6.0)
    for _ in range(20):
        for j, w in enumerate(single):
            if active[j]:
                w.step(wheel_speeds=wheels[j])
        batch.step(wheels, active=active)
        assert_same(single, batch, [1], active=active)
    # the inactive world did not move and its RNG was not used
    fresh = worlds(k, 10)[1]
    assert np.array_equal(batch[1].poses, fresh.poses)
    assert batch[1].rng.random() == fresh.rng.random()


def test_bad_input():
    with pytest.raises(ValueError, match="at least one world"):
        WorldBatch([])
    b = WorldBatch([World(scenes.random_arena(2, 0, seed=0)), World(scenes.random_arena(3, 0, seed=0))])
    with pytest.raises(ValueError, match="world 1 differs"):
        b.scan()
    b = WorldBatch(worlds(2))
    with pytest.raises(ValueError, match=r"shape \(2, 3, 2\)"):
        b.step(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="finite"):
        b.step(np.full((2, 3, 2), np.nan))
    with pytest.raises(ValueError, match="robot indices"):
        b.scan([5])
    with pytest.raises(TypeError, match="expected a World"):
        b[0] = "world"


def test_worlds_with_a_lidar_grid_scan_through_it():
    # WorldBatch makes World's kernel choice per world: gridded and brute-force worlds side by side
    from kin_envs.core import multi
    from kin_envs.core.world import WorldConfig

    def make(s, grid):
        scene = scenes.random_arena(3, 12, seed=s, size=6.0 + s, lidar=LIDAR)
        return World(scene, seed=s, config=WorldConfig(lidar_grid=grid, lidar_cell_size=1.0))

    grids = [True, False, True, False, True]
    single = [make(s, g) for s, g in enumerate(grids)]
    batch = WorldBatch([make(s, g) for s, g in enumerate(grids)])
    assert [w._lidar_grid is not None for w in batch.worlds] == grids
    calls = []
    real = multi.cast_prepared  # gridded worlds go through their own kernel arguments (grid, work arrays)
    multi.cast_prepared = lambda *a: calls.append(a[5]) or real(*a)
    try:
        rng = np.random.default_rng(1)
        for t in range(12):
            wheels = rng.uniform(-6.0, 12.0, (len(grids), 3, 2))
            for w, x in zip(single, wheels, strict=True):
                w.step(wheel_speeds=x)
            batch.step(wheels)
            assert_same(single, batch, [1, 2] if t % 2 else None)
        active = np.array([True, False, False, True, True])
        assert_same(single, batch, None, active=active)
    finally:
        multi.cast_prepared = real
    assert len(calls) == 12 * 3 + 2 and all(g is not None for g in calls)


def test_compiled_chipmunk_calls_match_pymunk():
    """The compiled loops WorldBatch steps with read and write what pymunk's own API does: body state
    (batch rows and attributes), control velocities, every space's arbiters in pymunk's order."""
    import pymunk.batch as pmbatch

    from kin_envs.core._chipmunk_calls import ChipmunkCalls, address

    calls = ChipmunkCalls.here()
    ws = worlds(5, 20)
    bodies = np.array([address(b._body) for w in ws for b in w.robot_bodies], np.uintp)
    controls = [c for w in ws for c in w._controls]
    ctrl = np.array([address(c._body) for c in controls], np.uintp)
    spaces = np.array([address(w.space._space) for w in ws], np.uintp)
    rng = np.random.default_rng(0)
    for _ in range(40):
        vx, vy, om = rng.normal(0, 0.4, (3, ctrl.size))
        calls.set_angular_velocities(ctrl, om)
        calls.set_velocities(ctrl, vx, vy)
        for c, x, y, o in zip(controls, vx, vy, om, strict=True):
            assert tuple(c.velocity) == (x, y) and c.angular_velocity == o
        calls.set_and_step(ctrl, vx, vy, spaces, 0.02)
        state = calls.read_bodies(bodies, np.empty((bodies.size, 4)))
        poses = calls.read_poses(bodies, np.empty((bodies.size, 3)))
        ref = [(b.angle, *b.velocity, b.angular_velocity, *b.position) for w in ws for b in w.robot_bodies]
        ref = np.array(ref)
        assert np.array_equal(state, ref[:, :4]) and np.array_equal(poses, ref[:, [4, 5, 0]])
        pairs, counts = calls.arbiter_pairs(spaces)
        buf, fields = pmbatch.Buffer(), pmbatch.ArbiterFields.BODY_A_ID | pmbatch.ArbiterFields.BODY_B_ID
        expected = []
        for w in ws:
            buf.clear()
            pmbatch.get_space_arbiters(w.space, fields, buf)
            expected.append(np.frombuffer(buf.int_buf(), np.uintp).reshape(-1, 2).copy())
        assert np.array_equal(counts, [len(e) for e in expected])
        assert np.array_equal(pairs, np.concatenate(expected))
    assert counts.sum() > 0  # the crowded arenas have contacts


def test_replaced_worlds_update_the_compiled_loops_tables():
    # a world replaced (an autoreset) rewrites its rows of the body / space tables in place: the
    # same tables as a batch built over the new worlds
    batch = WorldBatch(worlds(4))
    batch.step(np.zeros((4, 3, 2)))
    batch[1] = worlds(1, 50)[0]
    batch[-1] = worlds(1, 60)[0]
    fresh = WorldBatch(batch.worlds)._physics()
    for key, table in batch._physics().items():
        assert np.array_equal(table, fresh[key]), key
    batch[2] = World(scenes.random_arena(2, 3, seed=0))  # fewer robots: tables dropped, batch refused
    assert batch._phys is None
    with pytest.raises(ValueError, match="world 2 differs"):
        batch.step(np.zeros((4, 3, 2)))


@pytest.mark.parametrize("huge", [False, True])
def test_command_limits_match_world_step(huge):
    """WorldBatch.step's compiled limits (_limit_wheels) give the commands World.step applies, bit for
    bit: rows past the wheel limit, standing robots, signed zeros and (``huge``) rows past the overflow
    cap next to ordinary ones, which World scales by exactly 1."""
    k = 5
    single, batch = worlds(k, 30), WorldBatch(worlds(k, 30))
    rng = np.random.default_rng(2)
    for t in range(6):
        wheels = rng.normal(0, 8.0, (k, 3, 2))
        wheels[0, 1] = 0.0
        wheels[1, 2] = (-0.0, 0.0)
        wheels[2, 0] = (3e-13, -1e-300)
        if huge:
            wheels[3, 1] = (1e300, -2e299 * t)
            wheels[4, 0, 0] = -1e13
        for w, x in zip(single, wheels, strict=True):
            w.step(wheel_speeds=x)
        batch.step(wheels)
        for w, b in zip(single, batch.worlds, strict=True):
            assert w.commands.tobytes() == b.commands.tobytes()
        assert_same(single, batch, None)
