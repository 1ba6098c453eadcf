"""The lidar kernels of issue 14, round 7 (the grid's per-edge pass over the cells whose box of edges is
in reach, the branch-free one-beam casts of segments and circles, World.scan's prepared outputs and
work arrays) against the pre-vectorised reference kernel, bit for bit: far primitives spanning zero or
one beam with exact ties, beams through their ends, polygons straddling cell borders at the edge of
the reach, and swarms of 1 and 256 robots clustered in one cell or sitting on cell borders, moving
across steps (World, both kernels, and WorldBatch)."""

import math

import numpy as np
import pytest

from kin_envs import LidarSpec, World, scenes
from kin_envs.core.lidar import beam_tables, build_lidar_grid, cast_scan
from kin_envs.core.multi import WorldBatch
from kin_envs.core.world import WorldConfig
from kin_envs.scenes import Arena, Robot
from tests.kin_envs.reference_lidar import reference_kernel

NAMES = ("ranges", "true_ranges", "hit_kind", "hit_index")


def _reference(origins, headings, circles, segments, skip, spec, kind, index):
    n, nb = len(origins), spec.n_beams
    out = (np.empty((n, nb), np.float32), np.empty((n, nb), np.float32), np.empty((n, nb), np.int8),
           np.empty((n, nb), np.int32))  # fmt: skip
    reference_kernel(np.ascontiguousarray(origins[:, 0]), np.ascontiguousarray(origins[:, 1]),
                     np.ascontiguousarray(headings, dtype=np.float64), beam_tables(nb), spec.range_min,
                     spec.range_max, circles, skip, segments, kind, index, *out)  # fmt: skip
    return out


def _check_all_kernels(origins, headings, circles, segments, spec, cells, bounds):
    """Brute force and the grid at each cell size against the reference; returns the reference."""
    n, n_prim = len(origins), len(circles) + len(segments)
    skip = np.full(n, -1)
    kind, index = np.zeros(n_prim + 1, np.int8), np.arange(-1, n_prim, dtype=np.int32)
    ref = _reference(origins, headings, circles, segments, skip, spec, kind, index)
    grids = [None] + [build_lidar_grid(circles, segments, bounds=bounds, cell_size=c) for c in cells]
    for grid in grids:
        got = cast_scan(origins, headings, circles, segments, skip, kind, index, spec, grid=grid)
        for name, a, b in zip(NAMES, got, ref, strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"{name}, grid={grid is not None}")
    return ref


def test_far_primitives_spanning_zero_or_one_beam_with_ties():
    # tiny segments and circles 4-11.9 m away: most span no beam or one (the one-beam casts), many with
    # an end exactly on a beam's direction, each present twice (a tie: the lower id wins) and segments
    # both ways (back faces)
    rng = np.random.default_rng(11)
    spec = LidarSpec(range_max=12.0)
    res = 2 * math.pi / spec.n_beams
    k = 300
    d = rng.uniform(4.0, 11.9, k)
    beam = rng.integers(0, spec.n_beams, k)
    on_beam = rng.random(k) < 0.5  # end A exactly on a beam, else anywhere
    ang = np.where(on_beam, -beam * res, rng.uniform(-math.pi, math.pi, k))
    a = np.column_stack([d * np.cos(ang), d * np.sin(ang)])
    t = rng.uniform(0, 2 * math.pi, k)
    length = rng.uniform(0.002, 0.12, k)
    b = a + length[:, None] * np.column_stack([np.cos(t), np.sin(t)])
    seg = np.concatenate([a, b], axis=1)
    segments = np.concatenate([seg, seg, seg[:, [2, 3, 0, 1]]])
    cd = rng.uniform(4.0, 11.9, 200)
    ca = np.where(rng.random(200) < 0.5, -rng.integers(0, spec.n_beams, 200) * res, rng.uniform(-4, 4, 200))
    circ = np.column_stack([cd * np.cos(ca), cd * np.sin(ca), rng.uniform(0.002, 0.04, 200)])
    circles = np.concatenate([circ, circ])
    origins = np.concatenate([np.zeros((1, 2)), rng.normal(0.0, 0.3, (5, 2))])
    headings = np.concatenate([[0.0], rng.uniform(-math.pi, math.pi, 5)])
    ref = _check_all_kernels(origins, headings, circles, segments, spec, (0.5, 4.0), (-13, -13, 13, 13))
    hit = ref[3][0]
    n_c = len(circles)
    # the twins are both in range of many beams; the first copy (lower id) is always reported
    assert np.all((hit < 200) | (hit >= n_c) | (hit == -1))  # circles: never the second copy
    seg_hit = hit[hit >= n_c] - n_c
    assert seg_hit.size > 20 and not np.any((seg_hit >= k) & (seg_hit < 2 * k))  # segments: never a twin


@pytest.mark.parametrize("cell", [1.0, 2.0, 4.0])
def test_polygons_straddling_cell_borders_at_the_edge_of_reach(cell):
    # CCW polygons (groups) centred near cell borders, their edges reaching into the next cells; origins
    # placed so that polygons lie just within and just beyond a short lidar's reach: a cell is visited only
    # when the box of its groups' edges is in reach
    rng = np.random.default_rng(int(cell * 10))
    spec = LidarSpec(range_max=3.0)
    bounds = (-8.0, -8.0, 8.0, 8.0)
    grid0 = build_lidar_grid(np.zeros((0, 3)), np.zeros((0, 4)), bounds=bounds, cell_size=cell)
    gx, gy = grid0.origin
    polys = []
    for _ in range(60):
        kx, ky = rng.integers(1, int(14 / cell), 2)
        c = np.array([gx + kx * cell, gy + ky * cell]) + rng.normal(0, 0.05, 2)  # near a corner
        r, m = rng.uniform(0.05, cell / 2 * 0.9), rng.integers(3, 7)
        a = np.sort(rng.uniform(0, 2 * math.pi, m))
        polys.append(np.column_stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a)]))
    segments = np.concatenate([np.concatenate([v, np.roll(v, -1, axis=0)], axis=1) for v in polys])
    # origins 3 m (+- 2 cm) from a polygon vertex, in a random direction
    pick = rng.integers(0, len(segments), 80)
    th = rng.uniform(0, 2 * math.pi, 80)
    dist = 3.0 + rng.uniform(-0.02, 0.02, 80)
    origins = segments[pick, :2] + dist[:, None] * np.column_stack([np.cos(th), np.sin(th)])
    grid = build_lidar_grid(np.zeros((0, 3)), segments, bounds=bounds, cell_size=cell)
    assert np.isfinite(grid.group_boxes).any() and grid.groups.shape[1] >= len(polys) - 5  # (most are groups)
    # the boxes hold every edge of their cell's groups
    ref = _check_all_kernels(origins, rng.uniform(-math.pi, math.pi, 80), np.zeros((0, 3)), segments, spec,
                             (cell,), bounds)  # fmt: skip
    assert (ref[3] >= 0).any() and (ref[3] < 0).any()


def _swarm_scene(n_robots, where, seed, size=32.0):
    """``n_robots`` robots on a 0.25 m lattice around ``where`` among a random arena's obstacles (those in
    the way dropped)."""
    base = scenes.random_arena(0, 400, seed=seed, size=size)
    side = int(math.ceil(math.sqrt(n_robots)))
    rng = np.random.default_rng(seed)
    xy = np.asarray(where) + 0.25 * np.stack(np.divmod(np.arange(n_robots), side), axis=1)
    robots = tuple(Robot(float(x), float(y), float(rng.uniform(-math.pi, math.pi))) for x, y in xy)
    lo, hi = xy.min(axis=0) - 1.3, xy.max(axis=0) + 1.3
    keep = tuple(o for o in base.obstacles if not np.all((lo < o.center) & (np.asarray(o.center) < hi)))
    return base.replace(robots=robots, obstacles=keep, arena=Arena(size, size, walls=True))


def _reference_scan(w: World):
    p, n, spec = w.poses, w.n_robots, w.scene.lidar
    w._update_lidar_geometry(p)
    return _reference(p[:, :2], p[:, 2], w._circles, w._segments, np.arange(n), spec, w._prim_kind,
                      w._prim_index)  # fmt: skip


@pytest.mark.parametrize(
    "n_robots, where",
    [(1, (0.999, 0.999)), (256, (-1.0, -1.0)), (256, (5.2, -9.3)), (40, (-14.5, 13.0))],
)
def test_swarms_clustered_in_a_cell_and_on_its_borders(n_robots, where):
    # 256 robots packed into one 4 m cell of a 32 m arena (and across the borders of its neighbours, and
    # in a corner), 1 robot on a cell corner; robots move across steps; every World (grid, brute force,
    # the default) and a WorldBatch of them equal the reference kernel
    scene = _swarm_scene(n_robots, where, seed=n_robots)
    configs = [WorldConfig(lidar_grid=g) for g in (True, False, None)]
    worlds = [World(scene, seed=2, config=c) for c in configs]
    batch = WorldBatch([World(scene, seed=2, config=c) for c in configs])
    assert worlds[0]._lidar_grid is not None and worlds[1]._lidar_grid is None
    rng = np.random.default_rng(n_robots)
    for step in range(3):
        ref = _reference_scan(worlds[0])
        for scan in [w.scan(noise=False) for w in worlds] + list(batch.scan(noise=False)[0]):
            for name, a in zip(NAMES, ref, strict=True):
                np.testing.assert_array_equal(getattr(scan, name), a, err_msg=f"{name}, step {step}")
        cmd = rng.uniform(-1, 1, (n_robots, 2)) * [0.4, 3.0]
        for w in worlds:
            w.step(commands=cmd)
        batch.step(np.stack([batch[0].unicycle_to_wheel_speeds(cmd)] * 3))
    # housings seen by the others: the one-beam circle casts were exercised
    if n_robots > 1:
        assert np.isin(worlds[0].scan(noise=False).hit_kind, [1]).mean() > 0.05


def test_robots_exactly_on_cell_borders():
    # robots at grid-line coordinates (x or y on a cell border, and on corners), one scan per subset
    probe = World(scenes.random_arena(1, 300, seed=4, size=30.0), seed=0, config=WorldConfig(lidar_grid=True))
    gx, gy = probe._lidar_grid.origin
    cs = probe._lidar_grid.cell_size
    spots = [(gx + 3 * cs, gy + 3 * cs), (gx + 4 * cs, gy + 3.5 * cs), (gx + 5.3 * cs, gy + 4 * cs),
             (gx + 5 * cs + 1e-12, gy + 5 * cs - 1e-12)]  # fmt: skip
    base = probe.scene
    robots = tuple(Robot(float(x), float(y), 0.3 * k) for k, (x, y) in enumerate(spots))
    keep = tuple(
        o for o in base.obstacles if min(math.hypot(o.center[0] - x, o.center[1] - y) for x, y in spots) > 1.3
    )
    scene = base.replace(robots=robots, obstacles=keep)
    w = World(scene, seed=0, config=WorldConfig(lidar_grid=True))
    assert w._lidar_grid.origin == (gx, gy)
    ref = _reference_scan(w)
    for robots_ in (None, [2], [3, 0]):
        scan = w.scan(robots=robots_, noise=False)
        rows = np.arange(4) if robots_ is None else np.asarray(robots_)
        for name, a in zip(NAMES, ref, strict=True):
            np.testing.assert_array_equal(getattr(scan, name), a[rows], err_msg=name)
