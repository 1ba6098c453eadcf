"""The circles' candidate pass in float32 (issue 14, session 11: ``_circle_tests`` on float32 copies of the
circles' columns, both kernels): every beam that the exact float64 ray-circle test finds hitting a circle
within range is among the circle's candidate beams, the circle is in reach, its near bound is below the hit,
and the robot's own circle is never a candidate; at any coordinate scale, for circles from tangent-close
to far, tiny to larger than the reach, and origins on a circle's rim."""

import math

import numba
import numpy as np
import pytest

from kin_envs import LidarSpec
from kin_envs.core.lidar import _circle_tests, beam_tables, build_lidar_grid, cast_scan
from tests.kin_envs.test_lidar_scaling import _reference


@numba.njit(cache=False)
def _tests(x0, y0, hw, skip, reach, n_beams, circles):
    m = circles.shape[0]
    f32 = circles.astype(np.float32)
    fx, fy, fr = f32[:, 0].copy(), f32[:, 1].copy(), f32[:, 2].copy()
    fb, fc, fn = np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m, np.float32)
    _circle_tests(x0, y0, hw, skip, reach, n_beams, n_beams / (2.0 * math.pi), m, fx, fy, fr, np.arange(m),
                  fb, fc, fn)  # fmt: skip
    return fb, fc, fn


def _exact_hits(x0, y0, h, circles, n_beams, reach):
    """``(circle, beam) -> t`` of the kernels' exact test (float64, directions rotated from the tables)."""
    tabs = beam_tables(n_beams)
    ux = math.cos(h) * tabs[0] + math.sin(h) * tabs[1]
    uy = math.sin(h) * tabs[0] - math.cos(h) * tabs[1]
    dx, dy, r = circles[:, 0:1] - x0, circles[:, 1:2] - y0, circles[:, 2:3]
    cc = (dx * dx + dy * dy) - r * r
    b = dx * ux + dy * uy
    disc = b * b - cc
    with np.errstate(invalid="ignore"):
        t = b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (b > 0) & (t > 0) & (t < reach), t, np.inf)


@pytest.mark.parametrize("offset", [0.0, 37.0, 1e3, 1e5])
@pytest.mark.parametrize("n_beams", [360, 1000])
def test_float32_candidates_cover_every_exact_hit(offset, n_beams):
    rng = np.random.default_rng(int(offset) + n_beams)
    reach = 12.0
    centre = np.array([offset, -0.5 * offset])
    k = 400
    r = np.concatenate([rng.uniform(0.001, 0.05, k // 2), rng.uniform(0.05, 3.0, k // 2 - 2), [15.0, 0.035]])
    circles = np.column_stack([centre + rng.uniform(-14, 14, (k, 2)), r])
    hits = 0
    for j in range(12):
        if j < 4:  # origins on a circle's rim
            c = circles[j * 7]
            a = rng.uniform(-math.pi, math.pi)
            x0, y0 = c[0] + c[2] * math.cos(a), c[1] + c[2] * math.sin(a)
        else:
            x0, y0 = centre + rng.uniform(-6, 6, 2)
        h = rng.uniform(-50, 50)
        hw = h - 2.0 * math.pi * math.floor(h / (2.0 * math.pi) + 0.5)
        skip = int(rng.integers(-1, k))
        fb, fc, fn = _tests(x0, y0, hw, skip, reach, n_beams, circles)
        t = _exact_hits(x0, y0, h, circles, n_beams, reach)
        if skip >= 0:
            assert fc[skip] == 0
            t[skip] = np.inf
        for q in np.flatnonzero(np.isfinite(t).any(axis=1)):
            beams = np.flatnonzero(np.isfinite(t[q]))
            hits += len(beams)
            assert fc[q] > 0, (x0, y0, q)
            assert fb[q] == int(fb[q]) and 0 <= fb[q] < n_beams and fc[q] == int(fc[q])
            assert np.all((beams - int(fb[q])) % n_beams < fc[q]), (x0, y0, q)
            assert fn[q] <= t[q, beams].min()
    assert hits > 2000


def test_circles_beyond_float32_range_are_never_candidates():
    # centres at 1e39 m (finite in float64, infinite in float32) and 1e300 m among ordinary circles: the
    # scans are the reference kernel's (the float32 pass must not turn them into candidates with NaN beams)
    rng = np.random.default_rng(5)
    near = np.column_stack([rng.uniform(-8, 8, (30, 2)), rng.uniform(0.05, 0.5, 30)])
    far = np.array([[1e39, 0.0, 1.0], [0.0, -1e39, 5.0], [1e300, 1e300, 1e3], [-3.5e38, 2.0, 0.5]])
    circles = np.concatenate([near[:15], far, near[15:]])
    segments = np.array([[-10.0, -10.0, 10.0, -10.0], [10.0, -10.0, 10.0, 10.0]])
    origins = rng.uniform(-7, 7, (6, 2))
    headings = rng.uniform(-math.pi, math.pi, 6)
    spec = LidarSpec(range_max=12.0)
    n_prim = len(circles) + len(segments)
    skip = np.full(6, -1)
    kind, index = np.zeros(n_prim + 1, np.int8), np.arange(-1, n_prim, dtype=np.int32)
    ref = _reference(origins, headings, circles, segments, skip, spec, kind, index)
    grid = build_lidar_grid(circles, segments, dynamic_circles=[15, 16, 17, 18], bounds=(-11, -11, 11, 11))
    for g in (None, grid):
        got = cast_scan(origins, headings, circles, segments, skip, kind, index, spec, grid=g)
        for a, b in zip(got, ref, strict=True):
            np.testing.assert_array_equal(a, b)
