"""The grid's precomputed back-face and reach test of its groups' edges (issue 14, session 11:
``LidarGrid.group_edge_tests``, ``_edge_flags``) keeps every edge the exact test (``_front_in_reach``) keeps,
at any coordinate scale, with the origin on an edge's line or on a vertex; and grid scans stay bit for bit
the reference kernel's in worlds far from the coordinate origin."""

import math

import numba
import numpy as np
import pytest

from kin_envs import LidarSpec
from kin_envs.core.lidar import _TOL, _edge_flags, _front_in_reach, build_lidar_grid
from tests.kin_envs.test_lidar_scaling import _check_all_kernels


@numba.njit(cache=False)
def _flags_both(x0, y0, reach, segs, tests, half, extent):
    """Per edge: the exact test's flag and the precomputed test's, as the grid kernel calls them."""
    n = segs.shape[0]
    rc = reach + _TOL
    exact = np.empty(n)
    for q in range(n):
        a_x, a_y, b_x, b_y = segs[q, 0] - x0, segs[q, 1] - y0, segs[q, 2] - x0, segs[q, 3] - y0
        exact[q] = _front_in_reach(a_x, a_y, b_x, b_y, rc * rc)
    ext = 1.0 + abs(x0) + abs(y0) + extent
    eidx = np.empty(n, np.int64)
    flag = np.empty(n)
    m = _edge_flags(x0, y0, rc, 1e-12 * ext * ext, tests[0], tests[1], tests[2], tests[3], tests[4], half,
                    0, n, 0, eidx, flag)  # fmt: skip
    cheap = np.zeros(n)
    cheap[eidx[:m]] = 1.0
    return exact, cheap


def _polygon_edges(rng, k, scale, offset):
    """``k`` random convex quads / triangles as chained CCW edges (the grid's groups), around ``offset``."""
    out = []
    for _ in range(k):
        c = offset + rng.uniform(-scale, scale, 2)
        n = rng.integers(3, 6)
        ang = np.sort(rng.uniform(0, 2 * math.pi, n))
        r = rng.uniform(0.05, 0.6)
        v = c + r * np.column_stack([np.cos(ang), np.sin(ang)])
        out.append(np.concatenate([v, np.roll(v, -1, axis=0)], axis=1))
    return np.concatenate(out)


@pytest.mark.parametrize("offset", [0.0, 37.0, 1e3, 1e5])
def test_cheap_edge_test_keeps_every_edge_the_exact_test_keeps(offset):
    rng = np.random.default_rng(int(offset) % 1000 + 3)
    segs = _polygon_edges(rng, 300, 16.0, np.array([offset, -offset]))
    grid = build_lidar_grid(np.zeros((0, 3)), segs, cell_size=4.0)
    order = grid.group_segment_ids
    tests, half = grid.group_edge_tests, grid.group_edge_half
    np.testing.assert_array_equal(grid.group_segments, segs[order])
    # origins: random, on edges' lines (at a vertex, on the edge, beyond its ends), near the reach's rim
    a, b = segs[order[:60], :2], segs[order[:60], 2:]
    t = rng.choice([0.0, 0.5, 1.0, -0.7, 1.9], 60)[:, None]
    on_line = a + t * (b - a)
    rim = np.column_stack([offset + 12.0 * np.cos(np.arange(20)), -offset + 12.0 * np.sin(np.arange(20))])
    origins = np.concatenate([np.array([offset, -offset]) + rng.uniform(-14, 14, (40, 2)), on_line, rim])
    kept_back = 0
    n_back = 0
    for x0, y0 in origins:
        exact, cheap = _flags_both(x0, y0, 12.0, grid.group_segments, tests, half, grid.group_extent)
        assert np.all(cheap[exact > 0] > 0), (x0, y0)  # a superset: no front face in reach is dropped
        ax, ay = grid.group_segments[:, 0] - x0, grid.group_segments[:, 1] - y0
        ex = grid.group_segments[:, 2] - grid.group_segments[:, 0]
        ey = grid.group_segments[:, 3] - grid.group_segments[:, 1]
        # (the test's margin is 1e-12 (1 + |x0| + |y0| + extent)^2: 1e-8 m^2 at 40 m from the origin)
        back = ey * ax - ex * ay > 1e-10 * (1 + abs(x0) + abs(y0) + grid.group_extent) ** 2
        kept_back += int(np.sum(cheap[back] > 0))
        n_back += int(back.sum())
    # ... and a cull: clear back faces are dropped (at 1e5 m from the origin the margin covers most of them)
    assert kept_back == 0 and n_back > (1000 if offset <= 1e3 else 10)


@pytest.mark.parametrize("offset", [0.0, 2.5e3, 4e4])
def test_grid_scans_far_from_the_coordinate_origin(offset):
    # polygons and circles in a 30 m world centred at (offset, -offset / 3), robots on edges' lines, on
    # vertices and anywhere: every kernel bit for bit the reference
    rng = np.random.default_rng(7)
    centre = np.array([offset, -offset / 3])
    segs = _polygon_edges(rng, 120, 15.0, centre)
    circles = np.column_stack([centre + rng.uniform(-15, 15, (40, 2)), rng.uniform(0.03, 0.4, 40)])
    a, b = segs[:20, :2], segs[:20, 2:]
    mid, beyond = a[6:12] + 0.5 * (b[6:12] - a[6:12]), a[12:] + 1.5 * (b[12:] - a[12:])
    origins = np.concatenate([centre + rng.uniform(-15, 15, (10, 2)), a[:6], mid, beyond])
    headings = rng.uniform(-math.pi, math.pi, len(origins))
    bounds = (centre[0] - 16, centre[1] - 16, centre[0] + 16, centre[1] + 16)
    _check_all_kernels(origins, headings, circles, segs, LidarSpec(range_max=12.0), (2.0, 4.0), bounds)
