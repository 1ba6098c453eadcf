"""Physics: differential drive, no tunnelling at top speed, determinism, contacts, bad input."""

import json
import math

import numpy as np
import pytest

from kin_envs import Contact, World, WorldConfig, scenes
from kin_envs.scenes import Arena, Box, Cylinder, Robot, Scene, Wall

TOP = scenes.RobotSpec().max_speed


@pytest.mark.parametrize("physics_dt", [0.005, 0.02, 0.05])
def test_no_tunnelling_at_top_speed(physics_dt):
    """Robots driven flat out into a thin wall, the boundary, a cylinder, a box and each other."""
    scene = Scene(
        robots=(
            Robot(0.0, 0.0, 0.0),  # -> thin interior wall at x = 0.5 (2 cm thick)
            Robot(-1.0, 0.5, math.pi),  # -> boundary at x = -1.5
            Robot(0.0, -1.0, -math.pi / 2),  # -> boundary at y = -1.5
            Robot(-0.2, 0.8, math.pi / 2),  # -> cylinder
            Robot(-0.8, -0.6, 0.0),  # head-on with the next robot
            Robot(-0.2, -0.6, math.pi),
            Robot(1.0, 0.8, 0.0),  # -> small box
        ),
        obstacles=(
            Wall(0.5, -0.6, 0.5, 0.3, thickness=0.02),
            Cylinder(-0.2, 1.3, 0.05),
            Box(1.3, 0.8, width=0.04, depth=0.2),
        ),
        arena=Arena(3, 3),
    )
    world = World(scene, config=WorldConfig(physics_dt=physics_dt))
    r = scene.robot.body_radius
    full = np.tile([TOP, 0.0], (7, 1))
    for _ in range(150):  # 15 s: everything is pushing against something for >10 s
        world.step(commands=full)
        p = world.poses
        # penetration is bounded by the solver slop plus at most one physics step of travel
        tol = 0.002 + TOP * physics_dt
        assert p[0, 0] <= 0.49 - r + tol
        assert p[1, 0] >= -1.5 + r - tol
        assert p[2, 1] >= -1.5 + r - tol
        assert np.hypot(p[3, 0] + 0.2, p[3, 1] - 1.3) >= 0.05 + r - tol
        assert p[5, 0] - p[4, 0] >= 2 * r - 2 * tol
        assert p[6, 0] <= 1.28 - r + tol
    p = world.poses
    # at rest against the obstacle, within a few millimetres
    assert p[0, 0] == pytest.approx(0.49 - r, abs=0.005)
    assert p[1, 0] == pytest.approx(-1.5 + r, abs=0.005)
    assert world.contacts[0] & Contact.WALL and world.contacts[3] & Contact.OBSTACLE
    assert world.contacts[4] & Contact.ROBOT and world.contacts[5] & Contact.ROBOT


def test_differential_drive_kinematics():
    scene = Scene(robots=(Robot(0, 0, 0),), arena=Arena(6, 6))
    world = World(scene)
    for _ in range(20):
        world.step(commands=[[0.2, 0.0]])
    assert world.poses[0, 0] == pytest.approx(0.4, abs=0.01)
    assert world.poses[0, 1] == pytest.approx(0.0, abs=1e-9)
    world = World(scene)
    for _ in range(10):
        world.step(commands=[[0.0, 1.0]])
    assert world.poses[0, 2] == pytest.approx(1.0, abs=0.03)
    assert np.hypot(*world.poses[0, :2]) < 1e-6
    # wheel speeds: equal wheels drive straight at wheel_radius * speed
    world = World(scene)
    for _ in range(10):
        world.step(wheel_speeds=[[5.0, 5.0]])
    assert world.poses[0, 0] == pytest.approx(5.0 * scene.robot.wheel_radius, abs=0.01)


def test_speed_limits_scale_wheels_together():
    scene = Scene(robots=(Robot(0, 0, 0),), arena=Arena(6, 6))
    world = World(scene)
    world.step(commands=[[10.0, 0.0]])
    assert world.commands[0, 0] == pytest.approx(TOP)
    world.step(commands=[[10.0, 10.0]])
    v, w = world.commands[0]
    assert v / w == pytest.approx(1.0)  # turning radius kept
    wheels = world.unicycle_to_wheel_speeds(world.commands)
    assert np.max(np.abs(wheels)) == pytest.approx(scene.robot.max_wheel_speed)


def test_same_seed_same_trajectory_and_scans():
    from kin_envs import LidarSpec

    scene = scenes.random_arena(6, 15, seed=5, size=5.0, lidar=LidarSpec(noise_sigma=0.01, dropout_prob=0.05))

    def run(seed):
        world = World(scene, seed=seed)
        rng = np.random.default_rng(42)
        out = []
        for _ in range(40):
            world.step(commands=np.column_stack([rng.uniform(-0.3, 0.3, 6), rng.uniform(-3, 3, 6)]))
            out.append((world.poses, world.scan().ranges))
        return out

    a, b = run(1), run(1)
    for (pa, ra), (pb, rb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa, pb)
        np.testing.assert_array_equal(ra, rb)
    c = run(2)
    assert not np.array_equal(a[-1][1], c[-1][1])  # noise differs with the seed


def test_world_to_dict_round_trip():
    world = World(scenes.random_arena(4, 8, seed=1, size=4.0))
    for _ in range(5):
        world.step(commands=np.tile([0.1, 0.2], (4, 1)))
    d = json.loads(json.dumps(world.to_dict()))
    rebuilt = World(scenes.Scene.from_dict(d))
    np.testing.assert_allclose(rebuilt.poses, world.poses, atol=1e-12)
    np.testing.assert_array_equal(rebuilt.scan().ranges, world.scan().ranges)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"commands": [[np.nan, 0.0]] * 2}, r"commands\[0, 0\] is nan"),
        ({"commands": [[0.0, np.inf]] * 2}, r"commands\[0, 1\] is inf"),
        ({"commands": [[0.0, 0.0]]}, r"shape \(2, 2\)"),
        ({"wheel_speeds": np.zeros((2, 3))}, r"wheel_speeds must have shape \(2, 2\)"),
        ({}, "exactly one of"),
        ({"commands": np.zeros((2, 2)), "wheel_speeds": np.zeros((2, 2))}, "exactly one of"),
    ],
)
def test_bad_commands_raise(kwargs, match):
    world = World(scenes.paper_scenario(1))
    with pytest.raises(ValueError, match=match):
        world.step(**kwargs)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"physics_dt": 0.1}, "physics_dt"),
        ({"physics_dt": -0.01}, "physics_dt"),
        ({"control_dt": 0.01, "physics_dt": 0.02}, "control_dt"),
    ],
)
def test_bad_world_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        WorldConfig(**kwargs)


def test_world_rejects_non_scene():
    with pytest.raises(ValueError, match="expected a Scene"):
        World({"robots": []})


def test_movable_obstacle_is_pushed_static_is_not():
    scene = Scene(
        robots=(Robot(0, 0, 0), Robot(0, 1, 0)),
        obstacles=(Cylinder(0.3, 0, 0.05, movable=True, mass=0.5), Cylinder(0.3, 1, 0.05)),
        arena=Arena(4, 4),
    )
    world = World(scene)
    for _ in range(30):
        world.step(commands=[[TOP, 0.0], [TOP, 0.0]])
    moved, static = world.obstacle_poses
    assert moved[0] > 0.5  # pushed along
    assert static[0] == pytest.approx(0.3)
    assert world.poses[1, 0] < 0.3 - 0.14 + 0.005


_REF_BUFFERS: list = []


def _reference_advance(world: World, applied: np.ndarray) -> None:
    """World._advance through pymunk's own batch API and the numpy odometry (``Odometry.integrate``):
    what the compiled Chipmunk loops of ``World.step`` replaced, kept as their oracle."""
    import pymunk.batch as pmbatch

    if not _REF_BUFFERS:  # made once: pymunk never frees a Buffer's native arrays
        _REF_BUFFERS.extend(pmbatch.Buffer() for _ in range(2))
    buf, set_buf = _REF_BUFFERS  # a set buffer's array is numpy's: never grown by a get
    f = pmbatch.BodyFields
    buf.clear()
    pmbatch.get_space_bodies(world.space, f.BODY_ID, buf)
    where = {int(b): k for k, b in enumerate(np.frombuffer(buf.int_buf(), dtype=np.uintp))}
    rs = np.array([where[b.id] for b in world.robot_bodies])
    cs = np.array([where[c.id] for c in world._controls])
    world._commands = applied
    dt, odom = world.config.physics_dt, world._odometry
    v, omega = applied[:, 0], applied[:, 1]
    odom.begin_step()
    for _ in range(world.config.substeps):
        buf.clear()
        pmbatch.get_space_bodies(world.space, f.ANGLE | f.VELOCITY | f.ANGULAR_VELOCITY, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4)  # angle, vx, vy, omega
        heading, r = rows[rs, 0], rows[rs]
        odom.integrate(r[:, 1] * np.cos(heading) + r[:, 2] * np.sin(heading), r[:, 3], dt)
        vel = rows[:, 1:].copy()  # every body's velocity written back (a no-op but for the controls)
        vel[cs, 0], vel[cs, 1], vel[cs, 2] = v * np.cos(heading), v * np.sin(heading), omega
        set_buf.set_float_buf(vel)
        pmbatch.set_space_bodies(world.space, f.VELOCITY | f.ANGULAR_VELOCITY, set_buf)
        world.space.step(dt)
    odom.end_step()
    world.time += world.config.substeps * dt
    contacts = np.zeros(world.n_robots, np.int8)
    owner = {b.id: (Contact.ROBOT, i) for i, b in enumerate(world.robot_bodies)}
    buf.clear()
    pmbatch.get_space_arbiters(
        world.space, pmbatch.ArbiterFields.BODY_A_ID | pmbatch.ArbiterFields.BODY_B_ID, buf
    )
    for ida, idb in np.frombuffer(buf.int_buf(), dtype=np.uintp).reshape(-1, 2):
        for me, other in ((int(ida), int(idb)), (int(idb), int(ida))):
            if me in owner:
                kind = world._body_owner.get(other, (Contact.WALL, -1))[0]
                contacts[owner[me][1]] |= kind
    world.contacts = contacts


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_step_matches_pymunk_batch_reference(seed):
    """World.step's compiled Chipmunk loops and odometry kernel equal pymunk's batch API and the numpy
    odometry bit for bit: poses, velocities, movable obstacles, contacts, odometry (noisy), on crowded
    random arenas with movable obstacles, robots standing still, reversing and turning."""
    rng = np.random.default_rng(seed)
    scene = scenes.random_arena(6, 16, seed=seed, size=2.5)
    scene = scene.replace(obstacles=tuple(
        scenes.obstacle_from_dict({**o.to_dict(), "movable": True, "mass": 0.3}) if k % 3 else o
        for k, o in enumerate(scene.obstacles)))  # fmt: skip
    fast, ref = World(scene, seed=seed), World(scene, seed=seed)
    ref._advance = lambda applied: _reference_advance(ref, applied)
    pushed, start = 0, fast.obstacle_poses
    for _ in range(120):
        cmd = np.column_stack([rng.choice([0.3, -0.3, 0.0], 6, p=[0.8, 0.1, 0.1]), rng.uniform(-3, 3, 6)])
        fast.step(commands=cmd)
        ref.step(commands=cmd)
        for name in ("poses", "velocities", "obstacle_poses", "odometry", "odometry_delta", "contacts"):
            assert np.array_equal(getattr(fast, name), getattr(ref, name)), name
        assert fast.time == ref.time
        pushed += int(np.count_nonzero(fast.contacts & Contact.OBSTACLE))
    assert pushed > 20 and np.any(fast.obstacle_poses != start)  # obstacles touched and moved
    assert fast.config.odometry.noise_k > 0  # the default odometry: noisy
