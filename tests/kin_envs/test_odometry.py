"""Wheel odometry: exact when nothing slips, blind to what encoders cannot see, seeded noise and drift."""

import numpy as np
import pytest

from kin_envs import World, WorldConfig, scenes
from kin_envs.core.odometry import OdometrySpec, compose, relative
from kin_envs.core.scenes import Robot

EXACT = WorldConfig(odometry=OdometrySpec.exact())


def _open_world(robots, config=EXACT, seed=0):
    sc = scenes.random_arena(n_robots=len(robots), n_obstacles=0, seed=1)
    return World(sc.replace(robots=tuple(Robot(*r) for r in robots)), seed=seed, config=config)


def _wrap(a):
    return np.arctan2(np.sin(a), np.cos(a))


def test_compose_relative_inverse():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-3, 3, (50, 3)), rng.uniform(-3, 3, (50, 3))
    np.testing.assert_allclose(compose(a, relative(a, b)), np.c_[b[:, :2], _wrap(b[:, 2])], atol=1e-12)


def test_exact_odometry_straight_and_turning():
    w = _open_world([(0.0, 0.0, 0.3), (1.0, 1.0, -2.0)])
    for _ in range(50):  # straight: odometry is the pose
        w.step(commands=[[0.3, 0.0], [0.2, 0.0]])
    np.testing.assert_allclose(w.odometry, w.poses, atol=1e-9)
    rng = np.random.default_rng(1)
    for _ in range(100):  # turning: heading exact; position within the drive's small lateral slip
        w.step(commands=np.c_[[0.2, 0.1], rng.uniform(-2, 2, 2)])
    assert not w.contacts.any()
    np.testing.assert_allclose(_wrap(w.odometry[:, 2] - w.poses[:, 2]), 0.0, atol=1e-9)
    assert np.abs(w.odometry[:, :2] - w.poses[:, :2]).max() < 0.02  # < 1 % of the ~2.5 m driven


def test_increments_integrate_to_the_odometry_pose():
    w = _open_world([(0.0, 0.0, 0.0), (0.5, -0.5, 1.0)], config=WorldConfig())
    pose = w.odometry
    rng = np.random.default_rng(2)
    for _ in range(40):
        w.step(commands=np.c_[[0.25, 0.1], rng.uniform(-1, 1, 2)])
        pose = compose(pose, w.odometry_delta)
    np.testing.assert_allclose(pose, w.odometry, atol=1e-9)


def test_blocked_robot_measures_no_travel():
    # driving into the arena wall: the robot stops and so does its odometry (achieved, not commanded)
    sc = scenes.random_arena(n_robots=1, n_obstacles=0, seed=1)
    hx = sc.arena.half_extents[0]
    w = World(sc.replace(robots=(Robot(hx - 0.3, 0.0, 0.0),)), seed=0, config=EXACT)
    for _ in range(60):
        w.step(commands=[[0.3, 0.0]])
    assert w.contacts[0]
    assert abs(w.odometry[0, 0] - w.poses[0, 0]) < 0.005
    w.step(commands=[[0.3, 0.0]])
    assert abs(w.odometry_delta[0, 0]) < 1e-3


def test_noise_is_seeded_and_leaves_the_lidar_alone():
    sc = scenes.random_arena(n_robots=6, n_obstacles=8, seed=3)

    def run(config, seed):
        w = World(sc, seed=seed, config=config)
        cmd = np.c_[np.full(6, 0.2), np.linspace(-1, 1, 6)]
        for _ in range(30):
            w.step(commands=cmd)
        return w.odometry, w.scan().ranges

    noisy = WorldConfig(odometry=OdometrySpec(scale_sigma=0.02, noise_k=0.02))
    o1, s1 = run(noisy, 5)
    o2, s2 = run(noisy, 5)
    o3, s3 = run(EXACT, 5)
    o4, _ = run(noisy, 6)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(s1, s3)  # odometry draws never shift the lidar noise
    assert not np.array_equal(o1, o3) and not np.array_equal(o1, o4)


def test_noise_magnitude_matches_the_model():
    # 200 seeds, a robot drives 1 m straight: the heading error's spread is the model's
    # sqrt(2 k^2 L) / b (each wheel's travel error has variance k^2 L)
    n, k, s = 200, 0.01, 0.0
    sc = scenes.random_arena(n_robots=1, n_obstacles=0, seed=1).replace(robots=(Robot(-1.0, 0.0, 0.0),))
    errs = []
    for seed in range(n):
        w = World(sc, seed=seed, config=WorldConfig(odometry=OdometrySpec(scale_sigma=s, noise_k=k)))
        for _ in range(30):
            w.step(commands=[[1.0 / 3.0, 0.0]])
        errs.append(_wrap(w.odometry[0, 2] - w.poses[0, 2]))
    dist = 30 * 0.1 / 3.0
    b = sc.robot.wheel_base
    expected = np.sqrt(2 * k**2 * dist) / b
    assert np.std(errs) == pytest.approx(expected, rel=0.2)


def test_bad_odometry_spec():
    with pytest.raises(ValueError, match="noise_k"):
        OdometrySpec(noise_k=-0.1)
    with pytest.raises(ValueError, match="scale_sigma"):
        OdometrySpec(scale_sigma=float("nan"))
    with pytest.raises(ValueError, match="unknown key"):
        WorldConfig(odometry={"bogus": 1})
    assert WorldConfig(odometry={"noise_k": 0.0}).odometry == OdometrySpec(noise_k=0.0)


@pytest.mark.parametrize(
    "spec", [OdometrySpec(), OdometrySpec.exact(), OdometrySpec(scale_sigma=0.05, noise_k=0.2)]
)
def test_compiled_substep_and_normals_drawn_ahead_are_bit_identical(spec):
    """The native vector env's odometry substep (compiled arithmetic, ``integrate_state``) and its
    normals drawn many at a time (``take_ahead``) give exactly what ``integrate`` with a draw per call
    gives: random states with signed zeros, standing and reversing robots, over many substeps."""
    from kin_envs.core.odometry import Odometry

    rng = np.random.default_rng(7)
    n = 64
    start = np.c_[rng.uniform(-5, 5, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ref = Odometry(start, 0.12, spec, np.random.default_rng(3))
    fast = Odometry(start, 0.12, spec, np.random.default_rng(3))
    changed = 0
    for t in range(60):
        state = np.c_[rng.uniform(-np.pi, np.pi, n), rng.normal(0, 0.3, (n, 2)), rng.normal(0, 3, n)]
        state[rng.random(n) < 0.2, 1:] = 0.0  # robots standing still
        state[rng.random(n) < 0.1, 1:3] = -0.0
        cos_h, sin_h = np.cos(state[:, 0]), np.sin(state[:, 0])
        if t % 5 == 0 and spec.noise_k > 0:
            fast.take_ahead(5, 7)  # taken out, then put back as the next rows: the stream goes on as drawn
            fast.ahead_pos -= 5
        ref.integrate(state[:, 1] * cos_h + state[:, 2] * sin_h, state[:, 3], 0.02)
        fast.integrate_state(state, cos_h, sin_h, 0.02)
        assert np.array_equal(ref.pose, fast.pose)
        assert np.array_equal(np.signbit(ref.pose), np.signbit(fast.pose))
        changed += int(np.count_nonzero(ref.pose != start))
    assert changed > 0
    for _ in range(10):  # the streams go on alike (rows drawn ahead first)
        assert np.array_equal(ref._normals((n, 2)), fast._normals((n, 2)))
