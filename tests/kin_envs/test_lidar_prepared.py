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


def test_beams_through_segment_ends_and_along_segments():
    """Segment ends exactly on beam 0 (s = 0 or 1 exactly, where the kernels skip a division only with a
    margin), segments along it (cross(u, e) = 0) and twins (ties): both kernels give the reference's
    scans bit for bit."""
    from kin_envs import LidarSpec
    from kin_envs.core.lidar import beam_tables, build_lidar_grid
    from tests.kin_envs.reference_lidar import reference_kernel

    # from origins on the x axis looking along it, beam 0 runs exactly along y = 0
    segments = np.array([
        [2.0, 0.0, 2.0, 1.0], [2.0, -1.0, 2.0, 0.0],  # front faces ending / starting on the beam
        [3.0, 0.0, 3.0, -0.5], [3.0, 0.5, 3.0, 0.0],  # back faces, ends on the beam
        [4.0, 0.0, 5.0, 0.0], [5.0, 0.0, 4.0, 0.0],  # along the beam, both ways
        [6.0, -1.0, 6.0, 1.0], [6.0, -1.0, 6.0, 1.0],  # twins: the lower id wins
        [2.5, 1e-12, 2.5, 2.0], [2.6, -2.0, 2.6, -1e-300],  # ends a hair off the beam
    ])  # fmt: skip
    segments = np.concatenate([segments, segments[:, [2, 3, 0, 1]]])  # every face both ways
    circles = np.array([[7.0, 0.0, 0.2], [7.0, 0.0, 0.2], [1.0, 0.0, 0.05]])
    origins = np.array([[0.0, 0.0], [1.5, 0.0], [2.2, 0.0], [-3.0, 0.0]])
    spec = LidarSpec()
    n, nb, n_prim = len(origins), spec.n_beams, len(circles) + len(segments)
    kind, index = np.zeros(n_prim + 1, np.int8), np.arange(-1, n_prim, dtype=np.int32)
    out = (np.empty((n, nb), np.float32), np.empty((n, nb), np.float32), np.empty((n, nb), np.int8),
           np.empty((n, nb), np.int32))  # fmt: skip
    reference_kernel(origins[:, 0].copy(), origins[:, 1].copy(), np.zeros(n), beam_tables(nb), spec.range_min,
                     spec.range_max, circles, np.full(n, -1), segments, kind, index, *out)  # fmt: skip
    # from x = 1.5, beam 0 ends on two front faces at x = 2 (reversed copies 13, 14) at the same
    # distance: the lower id (owner table = primitive id); from x = 0 the small circle 2 is nearer
    assert out[3][1, 0] == 13 and out[1][1, 0] == 0.5 and out[3][0, 0] == 2
    for grid in (None, *(build_lidar_grid(circles, segments, bounds=(-8, -8, 8, 8), cell_size=c)
                         for c in (0.5, 4.0))):  # fmt: skip
        got = cast_scan(origins, np.zeros(n), circles, segments, np.full(n, -1), kind, index, spec, grid=grid)
        for name, a, b in zip(("ranges", "true_ranges", "hit_kind", "hit_index"), got, out, strict=True):
            np.testing.assert_array_equal(a, b, err_msg=name)


def test_one_heading_wrap_for_poses_scans_and_batches():
    from kin_envs.core.lidar import wrap_headings
    from kin_envs.core.multi import WorldBatch

    a = np.concatenate([np.random.default_rng(0).uniform(-50, 50, 2000), [np.pi, -np.pi, 0.0, 3 * np.pi]])
    rows = np.zeros((len(a), 3))
    rows[:, 2] = a
    wrap_headings(rows)
    np.testing.assert_array_max_ulp(rows[:, 2], np.arctan2(np.sin(a), np.cos(a)), maxulp=2)
    assert np.all(np.abs(rows[:, 2]) <= np.pi)
    scene = scenes.random_arena(3, 5, seed=1, size=6.0)
    w, batch = World(scene, seed=0), WorldBatch([World(scene, seed=0)])
    cmd = np.tile([0.2, 2.5], (3, 1))
    for _ in range(30):  # the headings wind past +-pi
        w.step(commands=cmd)
        batch.step(batch[0].unicycle_to_wheel_speeds(cmd)[None])
    np.testing.assert_array_equal(w.scan(robots=[2, 0]).poses, w.poses[[2, 0]])
    np.testing.assert_array_equal(batch.poses()[0], w.poses)


def test_circle_interval_bounds_the_half_angle_and_distance():
    """The candidate passes' circle interval (one division, no square root, in float32 as the passes call
    it): the bearing within the fast atan2's 1.2e-5 rad (and float32's ~1e-7), the half-angle ``asin(r /
    d)`` bounded from above to within float32's rounding, far inside ``_EPS`` (by at most 6 % of it for far
    circles, ``r < d / 10``, 30 % for near ones) and the distance from below (by at most 3 %), at every
    bearing and from tangent-close to far circles."""
    from kin_envs.core.lidar import _EPS, _circle_interval

    rng = np.random.default_rng(0)
    d = np.concatenate([rng.uniform(0.01, 60.0, 4000), np.logspace(-6, 3, 400)])
    ang = np.concatenate([rng.uniform(-np.pi, np.pi, 4000), np.linspace(-np.pi, np.pi, 400)])
    ang[:16] = np.arange(16) * np.pi / 4 - 2 * np.pi  # the axes and diagonals exactly
    ratio = np.concatenate([rng.uniform(0.0, 1.0, 4000) ** 3, rng.uniform(0.0, 0.999, 400)])
    f = np.float32
    dx, dy, r = f(d * np.cos(ang)), f(d * np.sin(ang)), f(ratio * d)
    got = np.array([_circle_interval(a, b, c) for a, b, c in zip(dx, dy, r, strict=True)], dtype=np.float64)
    dx, dy, r = dx.astype(np.float64), dy.astype(np.float64), r.astype(np.float64)
    phi, half, dlo = got.T
    true_d = np.hypot(dx, dy)
    dphi = np.angle(np.exp(1j * (phi - np.arctan2(dy, dx))))
    assert np.all(np.abs(dphi) < 1.25e-5)  # (the polynomial: 1.14e-5 at the diagonals)
    true_half = np.arcsin(np.minimum(r / true_d, 1.0))
    assert np.all(half - f(_EPS) >= true_half - 1e-6)
    over = (half - f(_EPS)) / np.maximum(true_half, 1e-300)
    assert np.all(over[r > 0] <= 1.3) and np.all(over[(r > 0) & (r < 0.1 * true_d)] <= 1.06)
    assert np.all(dlo <= true_d) and np.all(dlo >= 0.97 * true_d)


@pytest.mark.parametrize("n_beams", [3, 7, 360, 361, 1000, 100_000])
def test_first_beam_is_the_modulo(n_beams):
    """The candidate passes' first beam: ``k0 mod n_beams`` for every whole ``|k0| < 3 n_beams`` (near the
    multiples, where the multiplied quotient can be off by one, every value)."""
    from kin_envs.core.lidar import _first_beam

    k = np.arange(-3 * n_beams + 1, 3 * n_beams)
    if len(k) > 20_000:
        m = np.arange(-3, 4)[:, None] * n_beams + np.arange(-5, 6)[None, :]
        rand = np.random.default_rng(1).integers(-3 * n_beams + 1, 3 * n_beams, 5000)
        k = np.concatenate([m.ravel(), rand])
        k = k[np.abs(k) < 3 * n_beams]
    got = np.array([_first_beam(float(v), n_beams) for v in k])
    np.testing.assert_array_equal(got, k % n_beams)
