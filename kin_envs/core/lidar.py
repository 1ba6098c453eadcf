"""Vectorised exact 2D lidar raycaster (the simulator's hot path).

Geometry is reduced to two primitive sets:

* **circles** ``(C, 3)``: ``cx, cy, radius`` — cylinder obstacles and robots' lidar housings;
* **segments** ``(S, 4)``: ``x1, y1, x2, y2`` — the edges of boxes, prisms, convex polygons,
  walls and the arena boundary.

Each primitive carries an *owner* (what a beam that hits it reports: a kind code and an index).
All robots' scans are cast in one call of a numba kernel. For every (robot, primitive) pair the
kernel computes the angular interval the primitive subtends and tests only the beams inside it, with
exact ray–circle / ray–segment intersection, so the cost grows with the number of beams that actually
touch something rather than with ``beams × primitives``. With a :class:`LidarGrid`
(:func:`build_lidar_grid`, used by ``World`` in large arenas) a second kernel visits only the grid
cells within each robot's reach, with bit-identical results (see "broad phase" below).

Angle convention (the paper's, RPLIDAR A1): beam ``i`` points ``i * 360/n_beams`` degrees
**clockwise** from the robot's heading. :attr:`LidarSpec.angles` gives the same directions in the
robot frame as radians, **counter-clockwise positive** (x forward, y left), wrapped to (-pi, pi],
so ``angles[i] = wrap(-2*pi*i/n_beams)``. Consumers should use ``spec.angles``, never re-derive it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from detectors._numba_cache import ensure_cache_dir

ensure_cache_dir(__file__.rsplit('/', 1)[0])  # before the @njit(cache=True) below: read-only installs

__all__ = [
    "HitKind",
    "LidarGrid",
    "LidarSpec",
    "build_lidar_grid",
    "cast_scan",
    "default_cell_size",
    "polygon_edges",
    "scan_shapes",
]


class HitKind(IntEnum):
    """What a beam hit (``Scan.hit_kind``). ``hit_index`` is the robot or obstacle index, else -1."""

    NONE = 0  #: no return within range
    ROBOT = 1  #: a robot's lidar housing (the only part of a robot above beam height)
    BOUNDARY = 2  #: the arena's boundary wall
    CYLINDER = 3
    BOX = 4
    PRISM = 5
    POLYGON = 6
    WALL = 7  #: an interior wall segment (an obstacle)


@dataclass(frozen=True)
class LidarSpec:
    """A 2D spinning lidar. Defaults: RPLIDAR A1 as in the paper's table 2.

    Attributes:
        n_beams: beams per revolution (360 → 1° resolution).
        range_min: minimum range, m. A surface closer than this gives an invalid reading, reported
            as ``range_max`` (like "no return": the RPLIDAR reports 0 / ROS drivers ``inf`` for it, and
            the paper's pre-processing maps both to ``d_max``). Ground truth still names the object.
        range_max: maximum range, m. No return within range reads ``range_max``.
        noise_sigma: Gaussian range noise, relative: ``sigma = noise_sigma * true_range``
            (0.01 = 1 % of the distance). 0 by default, as in the paper.
        dropout_prob: probability that a valid reading is dropped (reads ``range_max``).
    """

    n_beams: int = 360
    range_min: float = 0.15
    range_max: float = 12.0
    noise_sigma: float = 0.0
    dropout_prob: float = 0.0

    def __post_init__(self) -> None:
        from kin_envs.core._validate import check_number

        w = "LidarSpec"
        # 100k beams is far past any real 2D lidar; the bound keeps the (n_robots, n_beams) arrays sane
        check_number(w, "n_beams", self.n_beams, 3, 100_000, integer=True)
        check_number(w, "range_min", self.range_min, 0.0, 1e4)
        check_number(w, "range_max", self.range_max, 0.0, 1e4, lo_open=True)
        if not self.range_max > self.range_min:
            raise ValueError(
                f"LidarSpec.range_max must be > range_min={self.range_min} m, got {self.range_max!r}"
            )
        check_number(w, "noise_sigma", self.noise_sigma, 0.0, 1.0)
        check_number(w, "dropout_prob", self.dropout_prob, 0.0, 1.0)
        if self.dropout_prob >= 1.0:
            raise ValueError(f"LidarSpec.dropout_prob must be in [0, 1), got {self.dropout_prob!r}")

    @property
    def resolution(self) -> float:
        """Angular step between consecutive beams, rad (positive)."""
        return 2.0 * math.pi / self.n_beams

    @cached_property
    def angles(self) -> np.ndarray:
        """Beam directions in the robot frame, rad, CCW positive, in (-pi, pi]; read-only."""
        a = -np.arange(self.n_beams) * self.resolution
        a = np.arctan2(np.sin(a), np.cos(a))
        a[np.isclose(a, -np.pi)] = np.pi
        a.flags.writeable = False
        return a

    @classmethod
    def from_dict(cls, d: dict) -> LidarSpec:
        from kin_envs.core._validate import dataclass_from_dict

        return dataclass_from_dict(cls, d, "lidar")


def polygon_edges(vertices: np.ndarray) -> np.ndarray:
    """Closed polygon ``(k, 2)`` → its ``k`` edges as ``(k, 4)`` segments.

    The raycaster's segments are one-sided (seen from their right): pass a polygon's vertices
    counter-clockwise to see it from outside, clockwise to see it from inside (an arena boundary).
    """
    v = np.asarray(vertices, dtype=np.float64)
    return np.concatenate([v, np.roll(v, -1, axis=0)], axis=1)


# rad: widens each primitive's beam interval. It covers the error of _fast_atan2 (< 1.2e-5 rad),
# so a beam through a vertex or tangent is always tested; the exact intersection test decides.
_EPS = 1e-4
# m: slack on distance bounds (range cut, occlusion), far above the rounding error of a hit distance
_TOL = 1e-6
# relative: twice a bound of the float32 rounding of a circle's centre relative to a lidar (the circles'
# candidate pass works on float32 copies: see _circle_tests)
_F32_ERR = 2.0**-21
# the grid kernel bins its moving circles (robots' housings, movable obstacles) by cell only when there are
# more than this many: with fewer, every robot tests them all (binning's per-call cost is over the cells)
_DYN_BIN_MIN = 8


@numba.njit(cache=True, inline="always")
def _fast_atan2(y, x):
    """atan2 to within 1.2e-5 rad (minimax polynomial): only used to pick candidate beams.

    Written with min / max and conditional expressions so that it compiles without branches: the
    signs of random bearings are unpredictable and mispredicted branches cost more than the
    arithmetic (measured)."""
    ax = abs(x)
    ay = abs(y)
    # min/max: the same quotient as ay/ax or ax/ay; 0 at the origin (where the original returned 0)
    return _atan2_from(min(ax, ay) / max(max(ax, ay), 1e-300), y, x)


@numba.njit(cache=True, nogil=True, inline="always")
def _atan2_from(z, y, x):
    """:func:`_fast_atan2` given its quotient ``z = min(|x|, |y|) / max(|x|, |y|)`` (callers that need
    two quotients take them from one division: the candidate passes are bound by their divisions)."""
    z2 = z * z
    a = z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330 + z2 * 0.0208351))))
    a = 0.5 * math.pi - a if abs(y) > abs(x) else a
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a


@numba.njit(cache=True, nogil=True, inline="always")
def _atan2_from32(z, y, x):
    """:func:`_atan2_from` in float32 (``z``, ``y``, ``x`` float32): its rounding (~1e-7 rad) is far inside
    ``_EPS`` with the polynomial's own 1.2e-5."""
    f = np.float32
    z2 = z * z
    p = f(0.1801410) + z2 * (f(-0.0851330) + z2 * f(0.0208351))
    a = z * (f(0.9998660) + z2 * (f(-0.3302995) + z2 * p))
    a = f(0.5 * math.pi) - a if abs(y) > abs(x) else a
    a = f(math.pi) - a if x < f(0.0) else a
    return -a if y < f(0.0) else a


@numba.njit(cache=True, nogil=True, inline="always")
def _circle_interval(dx, dy, r):
    """A circle's candidate beams from the origin, with one division and no square root (the candidate
    passes are bound by them: a square root per circle was the dearest part of a 256-robot scan's circle
    pass): the centre's bearing (:func:`_fast_atan2`), the half-angle it subtends bounded from above plus
    ``_EPS``, and a lower bound of the centre's distance ``d``. With ``z = min/max(|dx|, |dy|)`` and ``m``
    the max, ``d = m sqrt(1 + z^2)``; on [0, 1] ``sqrt(1 + u)`` lies above its chord and ``1 / sqrt(1 + u)``
    below its own, so ``d >= m (1 + (sqrt2 - 1) z^2)`` and ``r / d <= r / m (1 - (1 - 1/sqrt2) z^2)``; the
    half-angle is ``asin(r / d) <= x + (pi/2 - 1) x^3`` (asin's series has positive coefficients summing
    to pi/2). Selection only (within ~4 % of the half-angle, and ``1e-5`` relative slack for rounding):
    the exact tests decide what a beam hits, so a scan cannot change. In float32 (the candidate passes:
    :func:`_circle_tests`; float64 arguments compute it in float64)."""
    f = np.float32
    ax = abs(dx)
    ay = abs(dy)
    mx = max(max(ax, ay), f(1e-30))
    inv = f(1.0) / mx
    z = min(ax, ay) * inv
    z2 = z * z
    x = min(r * inv * (f(1.0) - f(0.2928932188134524) * z2) * f(1.0 + 1e-5), f(1.0))
    half = x + f(0.5707963267948966) * (x * x * x) + f(_EPS)
    return _atan2_from32(z, dy, dx), half, mx * (f(1.0) + f(0.41421356237309503) * z2) * f(1.0 - 1e-5)


@numba.njit(cache=True, nogil=True, inline="always")
def _segment_interval(ax, ay, bx, by, hw, inv_res, n_beams):
    """A front face A -> B's candidate beams from the origin: ``(first beam, beam count)`` of the beams
    within ``_EPS`` of the bearings from A to B (``hw``: the heading wrapped to [-pi, pi]). The bearing of
    A and the signed angle A -> B (``|span| < pi``) take their two quotients from one division (see
    :func:`_circle_interval`; with the origin on a vertex both are 0, as before)."""
    cr_ = ax * by - ay * bx
    dt = ax * bx + ay * by
    aax = abs(ax)
    aay = abs(ay)
    acr = abs(cr_)
    adt = abs(dt)
    m1 = max(max(aax, aay), 1e-300)
    m2 = max(max(acr, adt), 1e-300)
    inv = 1.0 / max(m1 * m2, 1e-300)
    th_a = _atan2_from(min(aax, aay) * m2 * inv, ay, ax) - hw
    span = _atan2_from(min(acr, adt) * m1 * inv, cr_, dt)
    k0 = np.ceil(-(th_a + max(0.0, span) + _EPS) * inv_res)
    k1 = np.floor(-(th_a + min(0.0, span) - _EPS) * inv_res)
    return _first_beam(k0, n_beams), k1 - k0 + 1.0


def _ccw(v: np.ndarray) -> np.ndarray:
    area2 = np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1))
    return v if area2 > 0 else v[::-1]


@numba.njit(cache=True, nogil=True, inline="always")
def _cast_one(x0, y0, h, skip, range_max, circ, seg, cos_tab, sin_tab, best_d, best_p, ws):
    """Cast one origin's beams into ``best_d`` / ``best_p`` (nearest distance and primitive id).

    Beams with no hit within ``range_max`` get distance ``range_max`` and primitive -1.
    ``circ`` / ``seg``: the primitives as columns (:func:`_columns`: the circles' float64 columns, then their
    float32 copies). Primitive ids: circles are
    ``0..C-1``, segments ``C..C+S-1``. Circle ``skip`` (the robot's own housing) is ignored. Beam ``i``
    has world direction ``h - i*res``. ``ws``: :func:`_work` for some ``k >= max(C, S)``.
    """
    for i in range(best_d.shape[0]):
        best_d[i] = range_max  # hits beyond range_max are never recorded
        best_p[i] = -1
    n_c = circ[0].shape[0]
    n_s = seg[0].shape[0]
    ids = ws[0][0]
    _cast_prims(x0, y0, h, skip, range_max, circ[0], circ[1], circ[2], circ[3], circ[4], circ[5], ids, n_c,
                seg[0], seg[1], seg[2], seg[3], ids, n_s, n_c, cos_tab, sin_tab, best_d, best_p,
                ws)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _columns(circles, segments):
    """The primitive arrays as columns, ``(x, y, r)`` and their float32 copies, and ``(x1, y1, x2, y2)``
    (1-D contiguous arrays), made once per kernel call: the candidate pass of :func:`_cast_prims` then
    reads them in order, which the compiler vectorises (rows of ``(C, 3)`` / ``(S, 4)`` arrays it does
    not)."""
    c = np.empty((3, circles.shape[0]))
    c32 = np.empty((3, circles.shape[0]), np.float32)
    for k in range(circles.shape[0]):
        c[0, k] = circles[k, 0]
        c[1, k] = circles[k, 1]
        c[2, k] = circles[k, 2]
        c32[0, k] = circles[k, 0]
        c32[1, k] = circles[k, 1]
        c32[2, k] = circles[k, 2]
    s = np.empty((4, segments.shape[0]))
    for k in range(segments.shape[0]):
        s[0, k] = segments[k, 0]
        s[1, k] = segments[k, 1]
        s[2, k] = segments[k, 2]
        s[3, k] = segments[k, 3]
    return (c[0], c[1], c[2], c32[0], c32[1], c32[2]), (s[0], s[1], s[2], s[3])


@numba.njit(cache=True, nogil=True)
def _work(k, ids=True):
    """Scratch of :func:`_cast_prims` for up to ``k`` candidates of each kind, allocated once per kernel
    call: ``ints[0]`` = ``arange(k)`` (every primitive as a candidate; filled only with ``ids``: the grid
    kernel rarely needs it, and writing it touches every page of a large world's scratch), ``ints[1]``
    the candidates kept by the first pass (``ints[2]``: those with one beam), ``floats[0:3]`` each
    candidate's first beam, beam count and occlusion distance, ``floats[3:7]`` the coordinates of the
    segments that pass the cheap test."""
    k = max(k, 1)
    ints = np.empty((3, k), np.int64)
    for q in range(k if ids else 0):
        ints[0, q] = q
    return ints, np.empty((7, k))


@numba.njit(cache=True, nogil=True, inline="always")
def _first_beam(k0, n_beams):
    """``k0`` modulo ``n_beams`` (a whole float, ``|k0| < 3 n_beams``), without a division or branch. The
    quotient by a multiplication (exact products and difference: whole numbers below 2^53), off by one at
    most at an exact multiple, which the two selects correct: a chain of five compare-and-subtract steps
    was the most sampled part of the candidate passes (perf, 256 robots)."""
    s = k0 - n_beams * np.floor(k0 * (1.0 / n_beams))
    s = s - n_beams if s >= n_beams else s
    return s + n_beams if s < 0.0 else s


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _split_by_count(cnt, n, many, one):
    """The indices ``q < n`` with ``cnt[q] > 1`` into ``many`` and those with ``cnt[q] == 1`` into ``one``
    (each at least ``n`` long), without a branch: both stores always happen, the counts advance by the
    comparisons (whether a primitive spans one beam was mispredicted about as often as not). Returns
    ``(len(many), len(one))``."""
    m = 0
    m1 = 0
    for q in range(n):
        many[m] = q
        one[m1] = q
        m += cnt[q] > 1.0
        m1 += cnt[q] == 1.0
    return m, m1


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _front_in_reach(ax, ay, bx, by, rc2):
    """1.0 if the segment A -> B (relative to the lidar) faces it and has a point within ``sqrt(rc2)``,
    else 0.0, without a branch (the candidate passes vectorise it). A back face has the origin on the
    left of A -> B or on its line; the nearest point is A, B or the foot of the perpendicular (at
    distance^2 ``cr^2 / ee``)."""
    ex = bx - ax
    ey = by - ay
    cr_ = ey * ax - ex * ay
    ee = ex * ex + ey * ey
    dot = -(ax * ex + ay * ey)
    near = (((dot <= 0.0) & (ax * ax + ay * ay <= rc2))
            | ((dot >= ee) & (bx * bx + by * by <= rc2))
            | ((dot > 0.0) & (dot < ee) & (cr_ * cr_ <= rc2 * ee)))  # fmt: skip
    return 1.0 if (cr_ < 0.0) & near else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _circle_t(dx, dy, cc, ux, uy):
    """The exact ray-circle test of :func:`_cast_prims` on one beam (direction ``ux, uy``) of a circle at
    ``dx, dy`` from the origin (``cc = d^2 - r^2``): the hit distance, or inf for no hit. Circles with one
    beam to test (far ones: most of a swarm's housings) get it in a pass of their own, without a branch
    and vectorised (the square root: it does not depend on the current hits), then
    :func:`_take_nearer` in order (branches on whether a far circle hits were mispredicted about as often
    as not, and the one-beam casts were ~15 % of a 256-robot scan's kernel as one scalar loop)."""
    b = dx * ux + dy * uy
    disc = b * b - cc
    t = b - math.sqrt(max(disc, 0.0))  # (the same t where disc >= 0, the only case kept)
    return t if (disc >= 0.0) & (b > 0.0) & (t > 0.0) else np.inf


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _take_nearer(t, c, u, best_d, best_p):
    """Beam ``u``'s hit becomes primitive ``c`` at ``t`` if nearer, or equally near with a lower id
    (``t = inf``: no hit), without a branch. (An occlusion test is not needed: an occluded circle's
    ``t`` is beyond the beam's current hit.)"""
    bd = best_d[u]
    bp = best_p[u]
    hit = (t < bd) | ((t == bd) & (c < bp))
    best_d[u] = t if hit else bd
    best_p[u] = c if hit else bp


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _cast_prims(x0, y0, h, skip, reach, cx, cy, cr, fx, fy, fr, cid, n_ci, sx1, sy1, sx2, sy2, sid, n_si, n_c,
                cos_tab, sin_tab, best_d, best_p, ws):  # fmt: skip
    """Cast ``n_ci`` circles and ``n_si`` segments into ``best_d`` / ``best_p``.

    Candidate ``q`` is circle ``cid[q]`` at ``(cx[q], cy[q])``, radius ``cr[q]`` (``fx``, ``fy``, ``fr``:
    the same as float32, for the candidate pass :func:`_circle_tests`), and segment ``sid[q]``
    from ``(sx1[q], sy1[q])`` to ``(sx2[q], sy2[q])`` (primitive id ``n_c + sid[q]``).
    ``reach`` (at most ``range_max``, at least every current ``best_d``): nothing beyond it can change
    the scan. A hit replaces the current one when it is nearer *or equally near with a lower primitive
    id*: the result is the minimum of (distance, id) over the primitives whatever order they come in,
    so the brute-force kernel (all primitives in id order) and the grid kernel (rings of cells, near
    ones first) return the same scans bit for bit. Everything that only *selects* candidates (the
    prefilters, the beam intervals, the occlusion test) keeps a margin; what a beam hits and at which
    distance is decided by the same exact arithmetic in every kernel.

    Segments are one-sided: only a beam arriving from the segment's right-hand side (looking from
    its first to its second point) can hit it, i.e. the outside of a CCW polygon. A convex solid's
    back faces can never be the first hit, so culling them halves the work exactly.

    Each kind takes two passes. The first computes every candidate's reach, back-face and beam-interval
    tests without a branch, over contiguous columns, so that the compiler vectorises it (4 candidates
    per instruction); the second tests the beams of the survivors. Written as one branchy loop, the
    per-candidate branches (in or out of reach, one or two beams) were mispredicted so often that a
    candidate cost ~35 ns; the vectorised pass costs ~5 (measured).
    """
    n_beams = best_d.shape[0]
    res = 2.0 * math.pi / n_beams
    inv_res = 1.0 / res
    ch = math.cos(h)
    sh = math.sin(h)
    # the heading wrapped to [-pi, pi] for the beam intervals only (robots' angles are unbounded), so
    # that a bearing minus it lies in [-2pi, 2pi] and its first beam index is found without a modulo
    hw = h - 2.0 * math.pi * math.floor(h / (2.0 * math.pi) + 0.5)
    rc = reach + _TOL
    rc2 = rc * rc
    keep = ws[0][1]
    one = ws[0][2]
    f_beam = ws[1][0]
    f_count = ws[1][1]
    # the circles' first beams, counts and near bounds as float32 (_circle_tests), in the same rows
    c_beam = f_beam.view(np.float32)
    c_count = f_count.view(np.float32)
    c_near = ws[1][2].view(np.float32)
    _circle_tests(x0, y0, hw, skip, reach, n_beams, inv_res, n_ci, fx, fy, fr, cid, c_beam, c_count, c_near)
    # the circles with one beam to test (far ones: most of a swarm's housings) apart, cast without a branch
    m, m1 = _split_by_count(c_count, n_ci, keep, one)
    t_one = ws[1][3]  # (free until the segments' pass below)
    for v in range(m1):
        q = np.uint64(one[v])
        dx = cx[q] - x0
        dy = cy[q] - y0
        r = cr[q]
        w = np.uint64(c_beam[q])
        ux = ch * cos_tab[w] + sh * sin_tab[w]
        uy = sh * cos_tab[w] - ch * sin_tab[w]
        t_one[v] = _circle_t(dx, dy, (dx * dx + dy * dy) - r * r, ux, uy)
    for v in range(m1):
        q = np.uint64(one[v])
        _take_nearer(t_one[v], cid[q], np.uint64(c_beam[q]), best_d, best_p)
    # indices as unsigned integers: numba's negative-index wraparound costs ~20 % in these loops
    for u in range(m):
        q = np.uint64(keep[u])
        c = cid[q]
        dx = cx[q] - x0
        dy = cy[q] - y0
        r = cr[q]
        cc = (dx * dx + dy * dy) - r * r  # the exact tests' (float64)
        near = np.float64(c_near[q])
        i = int(c_beam[q]) - 1
        for _ in range(int(c_count[q])):
            i += 1
            if i == n_beams:
                i = 0
            w = np.uint64(i)
            bd = best_d[w]
            if bd < near:
                continue  # occluded
            # direction of heading - i*res, by rotation (no trig in the inner loop)
            ux = ch * cos_tab[w] + sh * sin_tab[w]
            uy = sh * cos_tab[w] - ch * sin_tab[w]
            b = dx * ux + dy * uy
            disc = b * b - cc
            if disc < 0.0 or b <= 0.0:
                continue
            t = b - math.sqrt(disc)
            if t > 0.0 and (t < bd or (t == bd and c < best_p[w])):
                best_d[w] = t
                best_p[w] = c
    for q in range(n_si):
        f_count[q] = _front_in_reach(sx1[q] - x0, sy1[q] - y0, sx2[q] - x0, sy2[q] - y0, rc2)
    # segments take one more, cheap pass first: half of them face away and in a large arena many are out
    # of reach, while their beam interval costs two atan2 and a division; the survivors are copied into
    # contiguous columns so that the interval pass stays vectorised
    g1 = ws[1][3]
    g2 = ws[1][4]
    g3 = ws[1][5]
    g4 = ws[1][6]
    m = 0
    for q in range(n_si):
        keep[m] = q
        g1[m] = sx1[q]
        g2[m] = sy1[q]
        g3[m] = sx2[q]
        g4[m] = sy2[q]
        m += f_count[q] > 0.0
    # their beam intervals (the reach was tested above with a margin of _TOL: a segment farther than
    # range_max cannot beat a beam's initial range_max)
    for v in range(m):
        f_beam[v], f_count[v] = _segment_interval(g1[v] - x0, g2[v] - y0, g3[v] - x0, g4[v] - y0, hw, inv_res,
                                                  n_beams)  # fmt: skip
    k = 0
    for v in range(m):
        keep[k] = keep[v]
        f_beam[k] = f_beam[v]
        f_count[k] = f_count[v]
        k += f_count[v] > 0.0
    # their beams without a branch, in vectorisable runs (up to the wrap, then from beam 0; as the grid's
    # _segment_run): hit or not, occluded or not, were mispredicted often (the arena's walls span ~90 beams)
    for v in range(k):
        q = np.uint64(keep[v])
        ax = sx1[q] - x0
        ay = sy1[q] - y0
        ex = (sx2[q] - x0) - ax
        ey = (sy2[q] - y0) - ay
        i0 = np.uint64(f_beam[v])
        i1 = i0 + np.uint64(f_count[v])  # one past the last beam, unwrapped
        p = n_c + sid[q]
        _segment_run_tab(ax, ay, ex, ey, p, i0, min(i1, np.uint64(n_beams)), ch, sh, cos_tab, sin_tab, best_d,
                         best_p)  # fmt: skip
        _segment_run_tab(ax, ay, ex, ey, p, np.uint64(0), i1 - min(i1, np.uint64(n_beams)), ch, sh, cos_tab,
                         sin_tab, best_d, best_p)  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _segment_run_tab(ax, ay, ex, ey, p, i0, i1, ch, sh, cos_tab, sin_tab, best_d, best_p):
    """The exact ray-segment test of :func:`_cast_prims` on the beams ``i0..i1-1`` of a front face, their
    directions rotated from the tables (bit for bit as before), without a branch: a front face has
    ``cross(A, e) < 0``, so ``t > 0`` needs ``den < 0`` (``den = 0`` gives ``t = -inf``, no hit), and a
    beam whose current hit is nearer than the segment (the occlusion test before) gets ``t > bd``."""
    tn = ax * ey - ay * ex
    for w in range(i0, i1):
        bd = best_d[w]
        bp = best_p[w]
        ux = ch * cos_tab[w] + sh * sin_tab[w]
        uy = sh * cos_tab[w] - ch * sin_tab[w]
        den = ux * ey - uy * ex  # cross(u, e)
        # origin + t u = A + s e  ->  t = cross(A, e)/cross(u, e), s = cross(A, u)/cross(u, e)
        t = tn / den
        sp = (ax * uy - ay * ux) / den
        hit = (den != 0.0) & (t > 0.0) & (sp >= 0.0) & (sp <= 1.0) & ((t < bd) | ((t == bd) & (p < bp)))
        best_d[w] = t if hit else bd
        best_p[w] = p if hit else bp


@numba.njit(cache=True, nogil=True)
def _beam_tables(n_beams):
    res = 2.0 * math.pi / n_beams
    cos_tab = np.empty(n_beams)
    sin_tab = np.empty(n_beams)
    for i in range(n_beams):
        cos_tab[i] = math.cos(i * res)
        sin_tab[i] = math.sin(i * res)
    return cos_tab, sin_tab


_TABLES: dict[int, np.ndarray] = {}


def beam_tables(n_beams: int) -> np.ndarray:
    """``(2, n_beams)`` cos and sin of ``i * 2pi / n_beams``, computed once per beam count (by the same
    compiled code as before: 360 sin/cos per kernel call were a quarter of a one-robot scan)."""
    tabs = _TABLES.get(n_beams)
    if tabs is None:
        tabs = np.stack(_beam_tables(n_beams))
        tabs.flags.writeable = False
        _TABLES[n_beams] = tabs
    return tabs


@numba.njit(cache=True, nogil=True)
def _write_row(n, best_d, best_p, base, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
               out_kind, out_index):  # fmt: skip
    """Row ``n`` of the outputs from one origin's nearest hits (``best_p`` = -1: no hit). The owner tables
    are read from ``base`` (a world's offset in a batch of worlds). Readings below ``range_min`` and misses
    read ``range_max``, as the real lidar reports them; ``out_true`` keeps the true distance (inf: miss)."""
    # unsigned owner-table indices (p >= 0: numba's negative-index wraparound made this loop scalar) and
    # selects, not branches: the row was ~17 % of a 256-robot scan's kernel (perf)
    for i in range(best_d.shape[0]):
        p = best_p[i] + 1
        d = best_d[i]
        u = np.uint64(base + p)
        out_kind[n, i] = prim_kind[u]
        out_index[n, i] = prim_index[u]
        out_true[n, i] = d if p != 0 else np.inf
        out_ranges[n, i] = d if (p != 0) & (d >= range_min) else range_max


@numba.njit(cache=True, nogil=True)
def _write_row_split(n, best_d, best_p, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
                     out_kind, out_index):  # fmt: skip
    """:func:`_write_row` (``base`` 0) with the distances in a pass of their own, which the compiler
    vectorises, and the owner-table reads apart (gathers, scalar): in one loop the gathers kept it all
    scalar, ~25 instructions per beam in the grid kernel (callgrind). The grid kernel's only: the
    brute-force kernel keeps the one loop (its speed is the swarm envs' detector-off step)."""
    for i in range(best_d.shape[0]):
        d = best_d[i]
        hit = best_p[i] >= 0
        out_true[n, i] = d if hit else np.inf
        out_ranges[n, i] = d if hit & (d >= range_min) else range_max
    for i in range(best_d.shape[0]):
        u = np.uint64(best_p[i] + 1)
        out_kind[n, i] = prim_kind[u]
        out_index[n, i] = prim_index[u]


@numba.njit(cache=True, nogil=True)
def _scan_kernel(
    ox,
    oy,
    heading,
    tabs,
    range_min,
    range_max,
    circles,
    circle_skip,
    segments,
    prim_kind,
    prim_index,
    out_ranges,
    out_true,
    out_kind,
    out_index,
):
    """The world's scan in one pass: noise-free readings and per-beam ground truth.

    Per robot the work happens in small buffers that stay in L1 cache and each output row is written
    once, sequentially (no intermediate arrays to evict the caches between robots).
    ``prim_kind`` / ``prim_index`` are owner tables indexed by primitive id + 1 (slot 0 = no hit).
    ``tabs``: :func:`beam_tables`.
    """
    bf, bi = _brute_scratch(circles.shape[0], segments.shape[0], tabs.shape[1])
    _scan_kernel_into(ox, oy, heading, tabs, range_min, range_max, circles, circle_skip, segments, prim_kind,
                      prim_index, bf, bi, out_ranges, out_true, out_kind, out_index)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _brute_scratch(n_circles, n_segments, n_beams):
    """Work arrays of :func:`_scan_kernel_into` (``World`` keeps one pair: allocating them, with the
    primitives' columns, cost ~1 us of a one-robot scan): floats for the columns of :func:`_columns`,
    :func:`_work`'s floats, ``best_d`` and the circles' float32 columns (``2 n_circles`` float64 slots);
    ints for :func:`_work`'s ints (``ints[0]`` filled) and ``best_p``."""
    k = max(n_circles, n_segments, 1)
    bf = np.empty(3 * n_circles + 4 * n_segments + 7 * k + n_beams + 2 * n_circles)
    bi = np.empty(3 * k + n_beams, np.int64)
    for q in range(k):
        bi[q] = q
    return bf, bi


@numba.njit(cache=True, nogil=True)
def _scan_kernel_into(ox, oy, heading, tabs, range_min, range_max, circles, circle_skip, segments, prim_kind,
                      prim_index, bf, bi, out_ranges, out_true, out_kind, out_index):  # fmt: skip
    """:func:`_scan_kernel` with its work arrays ``bf`` / ``bi`` (:func:`_brute_scratch`)."""
    n_beams = tabs.shape[1]
    n_c = circles.shape[0]
    n_s = segments.shape[0]
    k = max(n_c, n_s, 1)
    c = bf[: 3 * n_c].reshape((3, n_c))
    sg = bf[3 * n_c : 3 * n_c + 4 * n_s].reshape((4, n_s))
    for q in range(n_c):  # the columns of _columns, refreshed (the housings moved)
        c[0, q] = circles[q, 0]
        c[1, q] = circles[q, 1]
        c[2, q] = circles[q, 2]
    for q in range(n_s):
        sg[0, q] = segments[q, 0]
        sg[1, q] = segments[q, 1]
        sg[2, q] = segments[q, 2]
        sg[3, q] = segments[q, 3]
    f0 = 3 * n_c + 4 * n_s
    ws = (bi[: 3 * k].reshape((3, k)), bf[f0 : f0 + 7 * k].reshape((7, k)))
    best_d = bf[f0 + 7 * k : f0 + 7 * k + n_beams]
    best_p = bi[3 * k : 3 * k + n_beams]
    f1 = f0 + 7 * k + n_beams
    c32 = bf[f1 : f1 + 2 * n_c].view(np.float32)  # (4 n_c float32 slots, 3 n_c used)
    for q in range(n_c):
        c32[q] = c[0, q]
        c32[n_c + q] = c[1, q]
        c32[2 * n_c + q] = c[2, q]
    circ = (c[0], c[1], c[2], c32[:n_c], c32[n_c : 2 * n_c], c32[2 * n_c : 3 * n_c])
    seg = (sg[0], sg[1], sg[2], sg[3])
    cos_tab = tabs[0]
    sin_tab = tabs[1]
    for n in range(ox.shape[0]):
        _cast_one(ox[n], oy[n], heading[n], circle_skip[n], range_max, circ, seg, cos_tab, sin_tab,
                  best_d, best_p, ws)  # fmt: skip
        _write_row(n, best_d, best_p, 0, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
                   out_kind, out_index)


# --- broad phase: a loose uniform grid of objects ---------------------------------------------------
#
# The brute-force kernel above culls every (robot, primitive) pair, so a scan costs O(all primitives).
# The grid kernel indexes the static geometry once per world, as *items*: circles, and *groups* (runs of
# consecutive segments that chain end to start and fit in a small circle: the edges of one box, prism or
# polygon), each binned by the centre of its bounding circle (a loose grid: a cell's extent is widened by
# the largest item radius, so an item is listed once and never cast twice). Per robot, pass 1 runs over
# the column runs of cells within reach (contiguous in the cell-major lists, so the per-item tests are
# vectorised as in :func:`_cast_prims`): each circle's reach test and beam interval, and the back-face and
# reach test of every edge of the groups listed there (their edges are stored cell by cell too), which
# keeps the front faces within reach; long segments (the arena boundary, long walls, large polygons) are
# listed in every cell they touch, gathered once and tested alike. Then every kept segment's beam
# interval (vectorised), and pass 2 casts the circles and the segments with beams to test, those with
# exactly one beam (most far ones) without a branch. (A per-group bounding-circle test, a front-to-back
# order and skipping hidden groups or segments were measured slower: branches mispredicted per group, per
# edge and per beam cost more than the vectorised per-edge tests they saved.) Every exact test is the
# brute force's arithmetic, and a hit replaces the current one when it
# is nearer *or equally near with a lower primitive id*: the result is the minimum of (distance, id) over
# the primitives, which is what the brute force's in-order strict ``<`` computes, so both kernels return
# bit-identical scans whatever order the items come in.
#
# Indices into arrays are taken as slices from 0 or as unsigned integers where they could not be proved
# non-negative: numba's negative-index wraparound otherwise stops LLVM vectorising the candidate passes
# (measured 2.5x slower).

@dataclass(frozen=True, eq=False)
class LidarGrid:
    """Static primitives indexed in a loose uniform grid, built once per world (:func:`build_lidar_grid`).

    Cell ``(ix, iy)`` has id ``ix * ny + iy`` and covers ``origin + cell_size * [ix, ix+1) x [iy, iy+1)``.
    Circles and groups (consecutive segments chaining end to start within a circle of radius
    ``cell_size / 2``: one convex obstacle's edges) are listed once, in the cell of their (bounding)
    centre, as contiguous columns cell by cell; every other static segment is listed in each cell its
    bounding box touches. The primitives in ``dynamic_*`` move between scans (robots' housings, movable
    obstacles) and are indexed again on every scan, as are static circles too large for the grid. The grid
    stays valid while the static rows of the primitive arrays do not change (a world's static geometry
    never does).
    """

    origin: tuple[float, float]  #: (x, y) of the grid's lower-left corner, m
    cell_size: float  #: m
    shape: tuple[int, int]  #: (nx, ny) cells
    circle_start: np.ndarray  #: (nx*ny + 1,) int64 CSR offsets into the circle columns
    circles: np.ndarray  #: (3, k) float64 x, y, r of the listed static circles, cell by cell
    circle_ids: np.ndarray  #: (k,) int64 their primitive ids
    circle_pad: float  #: m, the largest listed circle radius
    group_start: np.ndarray  #: (nx*ny + 1,) int64 CSR offsets into the group columns
    groups: np.ndarray  #: (3, g) float64 bounding circle x, y, r of the groups, cell by cell
    group_offsets: np.ndarray  #: (g + 1,) int64 rows of each group in ``group_segments``
    group_segments: np.ndarray  #: (sum, 4) float64 the groups' segments, group by group
    group_segment_ids: np.ndarray  #: (sum,) int64 their segment indices
    group_pad: float  #: m, the largest group radius
    group_boxes: np.ndarray  #: (4, nx*ny) float64 box (xmin, ymin, xmax, ymax) of each cell's group edges
    #: (5, sum) float64 per edge of ``group_segments``: ``k = ey x1 - ex y1``, ``ex``, ``ey`` (``e = B - A``),
    #: the midpoint's x and y; and (sum,) its half length (slightly widened): the kernel's cheap back-face
    #: and reach test (:func:`_edge_flags`)
    group_edge_tests: np.ndarray
    group_edge_half: np.ndarray
    #: m, the largest ``|x1| + |y1| + |x2| + |y2|`` of the groups' edges (scales the back-face test's margin)
    group_extent: float
    segment_start: np.ndarray  #: (nx*ny + 1,) int64 CSR offsets into ``segment_items``
    segment_items: np.ndarray  #: int64 long static segments, listed in every cell they touch
    dynamic_circles: np.ndarray  #: int64 circles indexed on every scan
    dynamic_segments: np.ndarray  #: int64 segments tested by every robot
    n_circles: int
    n_segments: int


@numba.njit(cache=True, nogil=True)
def _boxes(circles, segments, cids, sids):
    """Bounding boxes ``(k, 4)`` of circles ``cids`` then segments ``sids``."""
    box = np.empty((cids.shape[0] + sids.shape[0], 4))
    for k in range(cids.shape[0]):
        c = cids[k]
        r = circles[c, 2]
        box[k, 0] = circles[c, 0] - r
        box[k, 1] = circles[c, 1] - r
        box[k, 2] = circles[c, 0] + r
        box[k, 3] = circles[c, 1] + r
    for k in range(sids.shape[0]):
        s = sids[k]
        m = cids.shape[0] + k
        box[m, 0] = min(segments[s, 0], segments[s, 2])
        box[m, 1] = min(segments[s, 1], segments[s, 3])
        box[m, 2] = max(segments[s, 0], segments[s, 2])
        box[m, 3] = max(segments[s, 1], segments[s, 3])
    return box


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_range(lo, hi, g0, cs, n):
    """Cells ``[i0, i1]`` that the closed interval ``[lo, hi]`` touches (a point on a border: both)."""
    i0 = int(math.floor((lo - g0) / cs - 1e-9))
    i1 = int(math.floor((hi - g0) / cs + 1e-9))
    return max(i0, 0), min(i1, n - 1)


@numba.njit(cache=True, nogil=True)
def _bin(box, ids, gx, gy, cs, nx, ny):
    """CSR lists of ``ids`` (bounding boxes ``box``) in every cell their box touches."""
    n_cells = nx * ny
    start = np.zeros(n_cells + 1, np.int64)
    for k in range(ids.shape[0]):
        i0, i1 = _cell_range(box[k, 0], box[k, 2], gx, cs, nx)
        j0, j1 = _cell_range(box[k, 1], box[k, 3], gy, cs, ny)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                start[i * ny + j + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    items = np.empty(start[n_cells], np.int64)
    fill = start[:n_cells].copy()
    for k in range(ids.shape[0]):
        i0, i1 = _cell_range(box[k, 0], box[k, 2], gx, cs, nx)
        j0, j1 = _cell_range(box[k, 1], box[k, 3], gy, cs, ny)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                c = i * ny + j
                items[fill[c]] = ids[k]
                fill[c] += 1
    return start, items


def _by_centre(x: np.ndarray, y: np.ndarray, gx: float, gy: float, cs: float, nx: int, ny: int):
    """CSR offsets of items binned by their centre, and the order that lists them cell by cell."""
    cell = (np.clip(((x - gx) / cs).astype(np.int64), 0, nx - 1) * ny
            + np.clip(((y - gy) / cs).astype(np.int64), 0, ny - 1))  # fmt: skip
    order = np.argsort(cell, kind="stable")
    start = np.zeros(nx * ny + 1, np.int64)
    np.add.at(start, cell + 1, 1)
    return np.cumsum(start), order


def _segment_groups(segments: np.ndarray, ids: np.ndarray, max_r: float):
    """Runs of consecutive segments among ``ids`` (sorted) in which each starts where the previous ends,
    with a bounding circle of radius ``<= max_r``: ``(first, end)`` rows, their bounding circles
    ``(x, y, r)`` and the ids of the segments in no group."""
    if not len(ids):
        return np.zeros((0, 2), np.int64), np.zeros((0, 3)), ids
    s = segments[ids]
    chained = (ids[1:] == ids[:-1] + 1) & np.all(s[1:, :2] == s[:-1, 2:], axis=1)
    first = np.flatnonzero(np.concatenate([[True], ~chained]))
    end = np.append(first[1:], len(ids))
    lo = np.minimum.reduceat(np.minimum(s[:, :2], s[:, 2:]), first)
    hi = np.maximum.reduceat(np.maximum(s[:, :2], s[:, 2:]), first)
    c = 0.5 * (lo + hi)
    cr = np.repeat(c, end - first, axis=0)
    d2 = np.maximum(((s[:, :2] - cr) ** 2).sum(1), ((s[:, 2:] - cr) ** 2).sum(1))
    # every point of a segment is within the largest distance of its ends (a disc is convex)
    r = np.sqrt(np.maximum.reduceat(d2, first)) * (1.0 + 1e-9) + 1e-12
    ok = (r <= max_r) & (end - first >= 2)
    rows = np.column_stack([ids[first[ok]], ids[first[ok]] + (end - first)[ok]]).astype(np.int64)
    single = np.repeat(~ok, end - first)
    return rows, np.column_stack([c[ok], r[ok]]), ids[single]


def default_cell_size(range_max: float) -> float:
    """Grid cell side for a lidar of reach ``range_max``: ``range_max / 3`` (at least 0.5 m).
    Measured on random arenas at 0.7 objects/m^2: see the README's Performance section."""
    return max(0.5, float(range_max) / 3.0)


def build_lidar_grid(
    circles: np.ndarray,
    segments: np.ndarray,
    dynamic_circles=(),
    dynamic_segments=(),
    bounds: tuple[float, float, float, float] | None = None,
    cell_size: float | None = None,
) -> LidarGrid:
    """Index the static primitives in a loose uniform grid for :func:`cast_scan` (built once per world).

    Args:
        circles, segments: the raycaster's primitive arrays ``(C, 3)`` and ``(S, 4)``.
        dynamic_circles, dynamic_segments: indices of the circles / segments that move between scans
            (indexed on every scan instead).
        bounds: ``(xmin, ymin, xmax, ymax)`` the grid must cover (e.g. the arena), m; the bounding box
            of the static primitives is always included. Robots and moving primitives outside the grid
            are handled apart (correct, only slower).
        cell_size: m; default :func:`default_cell_size` of a 12 m lidar.
    """
    circles = np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3)
    segments = np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4)
    ids = []
    for name, dyn, n in (("dynamic_circles", dynamic_circles, len(circles)),
                         ("dynamic_segments", dynamic_segments, len(segments))):  # fmt: skip
        d = np.unique(np.asarray(dyn, dtype=np.int64).reshape(-1))
        if d.size and (d[0] < 0 or d[-1] >= n):
            raise ValueError(f"build_lidar_grid: {name} must be indices in [0, {n}), got {d.tolist()}")
        ids += [d, np.setdiff1d(np.arange(n), d)]
    dyn_c, static_c, dyn_s, static_s = ids
    if cell_size is None:
        cell_size = default_cell_size(12.0)
    if not (isinstance(cell_size, int | float) and math.isfinite(cell_size) and cell_size > 0):
        raise ValueError(f"build_lidar_grid: cell_size must be a number > 0 m, got {cell_size!r}")
    cs = float(cell_size)
    if not np.all(np.isfinite(circles[static_c])) or not np.all(np.isfinite(segments[static_s])):
        raise ValueError("build_lidar_grid: primitive coordinates must be finite")
    # large circles would widen every cell: they are indexed with the moving ones
    big = circles[static_c, 2] > 0.5 * cs
    dyn_c = np.union1d(dyn_c, static_c[big]).astype(np.int64)
    static_c = static_c[~big]
    group_rows, group_circles, single = _segment_groups(segments, static_s, 0.5 * cs)
    c = circles[static_c]
    box = [c[:, :2] - c[:, 2:], c[:, :2] + c[:, 2:]]
    box = [np.concatenate([box[0], group_circles[:, :2] - group_circles[:, 2:]]),
           np.concatenate([box[1], group_circles[:, :2] + group_circles[:, 2:]])]  # fmt: skip
    seg_box = _boxes(circles, segments, np.zeros(0, np.int64), single)
    lo = np.concatenate([box[0], seg_box[:, :2]])
    hi = np.concatenate([box[1], seg_box[:, 2:]])
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64).reshape(4)
        if not (np.all(np.isfinite(b)) and b[0] < b[2] and b[1] < b[3]):
            raise ValueError(
                f"build_lidar_grid: bounds must be finite (xmin, ymin, xmax, ymax), got {bounds!r}"
            )
        lo, hi = np.concatenate([lo, b[None, :2]]), np.concatenate([hi, b[None, 2:]])
    if not len(lo):
        lo = hi = np.zeros((1, 2))
    # a little margin: robots and primitives on the bounds are strictly inside
    lo, hi = lo.min(axis=0) - 1e-3, hi.max(axis=0) + 1e-3
    nx, ny = (int(v) for v in np.maximum(1, np.ceil((hi - lo) / cs)))
    gx, gy = float(lo[0]), float(lo[1])
    c_start, order = _by_centre(c[:, 0], c[:, 1], gx, gy, cs, nx, ny)
    g_start, g_order = _by_centre(group_circles[:, 0], group_circles[:, 1], gx, gy, cs, nx, ny)
    rows = group_rows[g_order]
    seg_ids = np.concatenate([np.arange(a, b) for a, b in rows]) if len(rows) else np.zeros(0)
    seg_ids = seg_ids.astype(np.int64)
    s_start, s_items = _bin(seg_box, single, gx, gy, cs, nx, ny)
    # each cell's box around the edges of its groups (the kernel visits a cell only if its box is in reach)
    e_cell = np.repeat(np.repeat(np.arange(nx * ny), np.diff(g_start)), rows[:, 1] - rows[:, 0])
    e_seg = segments[seg_ids].reshape(-1, 4)
    g_box = np.empty((4, nx * ny))
    g_box[:2], g_box[2:] = np.inf, -np.inf
    for k, (f, a) in enumerate(((np.minimum, 0), (np.minimum, 1), (np.maximum, 0), (np.maximum, 1))):
        f.at(g_box[k], e_cell, f(e_seg[:, a], e_seg[:, a + 2]))
    ex, ey = e_seg[:, 2] - e_seg[:, 0], e_seg[:, 3] - e_seg[:, 1]
    e_tests = np.stack([ey * e_seg[:, 0] - ex * e_seg[:, 1], ex, ey, 0.5 * (e_seg[:, 0] + e_seg[:, 2]),
                        0.5 * (e_seg[:, 1] + e_seg[:, 3])])  # fmt: skip
    # every point of an edge is within half its length of its midpoint (widened for the rounding of both)
    e_half = 0.5 * np.hypot(ex, ey) * (1.0 + 1e-9) + 1e-12
    return LidarGrid(
        origin=(gx, gy),
        cell_size=cs,
        shape=(nx, ny),
        circle_start=c_start,
        circles=np.ascontiguousarray(c[order].T),
        circle_ids=static_c[order].astype(np.int64),
        circle_pad=float(c[:, 2].max()) if len(c) else 0.0,
        group_start=g_start,
        groups=np.ascontiguousarray(group_circles[g_order].T),
        group_offsets=np.concatenate([[0], np.cumsum(rows[:, 1] - rows[:, 0])]).astype(np.int64),
        group_segments=np.ascontiguousarray(segments[seg_ids]).reshape(-1, 4),
        group_segment_ids=seg_ids,
        group_pad=float(group_circles[:, 2].max()) if len(group_circles) else 0.0,
        group_boxes=g_box,
        group_edge_tests=np.ascontiguousarray(e_tests).reshape(5, -1),
        group_edge_half=e_half,
        group_extent=float(np.abs(e_seg).sum(axis=1).max()) if len(e_seg) else 0.0,
        segment_start=s_start,
        segment_items=s_items,
        dynamic_circles=dyn_c,
        dynamic_segments=dyn_s.astype(np.int64),
        n_circles=len(circles),
        n_segments=len(segments),
    )


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _gather_circles(xs, ys, rs, ids, a, b, m, kx, ky, kr, kid, fx, fy, fr):
    """Append the circles ``a..b-1`` of the columns ``xs``, ``ys``, ``rs`` (ids ``ids``) at ``m`` of the
    candidate columns, and their float32 copies to ``fx``, ``fy``, ``fr`` (:func:`_circle_tests`);
    returns the new count."""
    for q in range(np.uint64(b - a)):
        x = xs[np.uint64(a) + q]
        y = ys[np.uint64(a) + q]
        r = rs[np.uint64(a) + q]
        kx[np.uint64(m) + q] = x
        ky[np.uint64(m) + q] = y
        kr[np.uint64(m) + q] = r
        fx[np.uint64(m) + q] = np.float32(x)
        fy[np.uint64(m) + q] = np.float32(y)
        fr[np.uint64(m) + q] = np.float32(r)
        kid[np.uint64(m) + q] = ids[np.uint64(a) + q]
    return m + (b - a)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _circle_tests(x0, y0, hw, skip, reach, n_beams, inv_res, m, kx, ky, kr, kid, fb, fc, fn):
    """The reach test and beam interval of the circle passes for the ``m`` candidate circles ``kx``,
    ``ky``, ``kr`` (float32 copies of their columns): first beam, beam count (0: none to test) and a
    lower bound of the distance of any hit, into the float32 ``fb``, ``fc``, ``fn`` (float64 outputs or the
    int64 ids in the same loop halve its vector width).

    In float32, 16 candidates per AVX-512 instruction (the pass was ~2.4 ns per circle in float64, ~1 in
    float32: the dearest part of a 256-robot scan's per-housing cost). Selection only, so a scan cannot
    change: the centre relative to the lidar is off the float64 one by at most ``e`` (``_F32_ERR`` times
    the coordinates' magnitudes: both roundings of a coordinate and of the difference), so the circle
    grown by ``e`` contains the exact one and its interval, reach and distance bounds cover every beam that
    the exact float64 test can find hitting it (``1e-5`` relative slack on each bound for float32's own
    rounding; the bearing's is ~1e-7 rad against ``_EPS``). The beam indices are whole numbers below
    2^24, exact in float32."""
    f = np.float32
    x0f = f(x0)
    y0f = f(y0)
    hwf = f(hw)
    irf = f(inv_res)
    nbf = f(n_beams)
    inv_nb = f(1.0 / n_beams)
    rcf = f(reach + _TOL)
    oab = abs(x0f) + abs(y0f)
    for q in range(np.uint64(m)):
        cx = kx[q]
        cy = ky[q]
        r = kr[q]
        dx = cx - x0f
        dy = cy - y0f
        e = f(_F32_ERR) * (abs(cx) + abs(cy) + oab)
        ro = r + e  # the circle grown by the centre's error
        ri = max(r - e, f(0.0))
        d2 = dx * dx + dy * dy
        # in reach and the origin outside the circle (each with a margin: a circle that contains the origin is
        # never hit, by the exact tests); d2 finite: a centre beyond float32's range (3e38 m) is out of reach
        ok = ((d2 <= (rcf + ro) * (rcf + ro) * f(1.0 + 1e-5)) & (d2 > ri * ri * f(1.0 - 1e-5))
              & (d2 < f(1e38)))  # fmt: skip
        phi, half, dlo = _circle_interval(dx, dy, ro)
        # an origin that may be inside the grown circle (within e of the exact one's rim) sees it anywhere
        half = f(math.pi + _EPS) if d2 <= ro * ro * f(1.0 + 1e-5) else half
        phi -= hwf  # bearing of the centre relative to the heading
        # beam i points at -i*res: beams within [phi-half, phi+half] have i in
        # [-(phi+half)/res, -(phi-half)/res]
        k0 = np.ceil(-(phi + half) * irf)
        k1 = np.floor(-(phi - half) * irf)
        # the first beam as _first_beam, in float32 (exact: whole numbers below 2^24)
        b = k0 - nbf * np.floor(k0 * inv_nb)
        b = b - nbf if b >= nbf else b
        fb[q] = b + nbf if b < f(0.0) else b
        fc[q] = k1 - k0 + f(1.0) if ok else f(0.0)
        # no hit on this circle is nearer (d - r > d - 2r: an occlusion test's bound, without a square root)
        fn[q] = dlo - f(2.0) * ro - f(_TOL)
    for q in range(np.uint64(m)):  # not the robot's own housing
        fc[q] = f(0.0) if kid[q] == skip else fc[q]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _edge_flags(x0, y0, rc, tol, tk, tex, tey, tmx, tmy, th, a, b, m, eidx, flag):
    """The back-face and reach test of :func:`_cast_prims`' segments, in a cheaper form that keeps every
    edge that test keeps (selection only: a scan cannot change), over the edges ``a..b-1`` of the
    precomputed columns ``tk`` .. ``th`` (:attr:`LidarGrid.group_edge_tests` / ``group_edge_half``); the
    indices of the front faces within reach are appended at ``m`` to ``eidx``. Returns the new count.

    The cross product that decides a back face is ``k - ey x0 + ex y0`` (two multiply-adds, against the
    exact test's six subtractions and two products: the coordinates relative to the origin); ``tol``
    covers the rounding of both forms, so a face the exact test finds in front (the only ones that can be
    hit: a back face's ``t`` is never positive) is kept. The reach test is the midpoint within ``reach +
    half length``: every point within reach has its midpoint there. (~0.3 ns per edge against ~0.75 for
    :func:`_front_in_reach`'s, standalone.) Flags first, in a pass the compiler vectorises, then the
    indices, one store per edge without a branch. Unsigned indices and no slices: a slice made here, once
    per run of cells, costs two atomic reference-count updates."""
    a_ = np.uint64(a)
    for q in range(np.uint64(b - a)):
        u = a_ + q
        dx = tmx[u] - x0
        dy = tmy[u] - y0
        rh = rc + th[u]
        front = (tk[u] - tey[u] * x0) + tex[u] * y0 < tol
        flag[q] = 1.0 if front & (dx * dx + dy * dy <= rh * rh) else 0.0
    k = np.uint64(m)
    for q in range(np.uint64(b - a)):
        eidx[k] = a_ + q
        k += np.uint64(flag[q] > 0.0)
    return np.int64(k)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _segment_run(ax, ay, ex, ey, p, i0, i1, bux, buy, best_d, best_p):
    """:func:`_segment_beam`'s test on the beams ``i0..i1-1`` (a segment's beams up to the wrap, then from
    0), without a branch, so that the compiler vectorises it (the previous per-beam branches, on products
    first and divisions only for the beams that could hit, were mispredicted often: whether a near
    segment's beam hits depends on what occludes it). A front face has ``tn < 0``: a beam with ``den >= 0``
    gives ``t <= 0``, inf or NaN and no hit."""
    tn = ax * ey - ay * ex
    for u in range(i0, i1):
        bd = best_d[u]
        bp = best_p[u]
        ux = bux[u]
        uy = buy[u]
        den = ux * ey - uy * ex
        t = tn / den
        sp = (ax * uy - ay * ux) / den
        hit = (den < 0.0) & (t > 0.0) & (sp >= 0.0) & (sp <= 1.0) & ((t < bd) | ((t == bd) & (p < bp)))
        best_d[u] = t if hit else bd
        best_p[u] = p if hit else bp


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _segment_beam(ax, ay, ex, ey, p, u, bux, buy, best_d, best_p):
    """The exact ray-segment test of :func:`_cast_prims` on the one beam ``u``, without a branch
    (a hit on a front face has ``den < 0``; a zero ``den`` is no hit, as there), the update as selects.
    (Branches on these tests were mispredicted often: far segments hit or miss at random.)"""
    bd = best_d[u]
    bp = best_p[u]
    ux = bux[u]
    uy = buy[u]
    den = ux * ey - uy * ex
    t = (ax * ey - ay * ex) / den
    sp = (ax * uy - ay * ux) / den
    hit = (den < 0.0) & (t > 0.0) & (sp >= 0.0) & (sp <= 1.0) & ((t < bd) | ((t == bd) & (p < bp)))
    best_d[u] = t if hit else bd
    best_p[u] = p if hit else bp


@numba.njit(cache=True, nogil=True, inline="always")
def _unpack_grid(gf, gi):
    """The grid arguments of :func:`_grid_cast` (``gx`` to ``dyn_s``) from :func:`grid_args`' two arrays."""
    k, s = gi[2], gi[4]
    n_cells = gi[0] * gi[1]
    o = gi[5:15]
    # float layout: 6 scalars, circle columns (3, k), cell boxes (4, cells), edges (4, s), edge tests (5, s),
    # edge half lengths (s)
    f1 = 6 + 3 * k
    f2 = f1 + 4 * n_cells
    f3 = f2 + 4 * s
    f4 = f3 + 5 * s
    return (gf[0], gf[1], gf[2], gi[0], gi[1], gi[o[0]:o[1]], gf[6:f1].reshape((3, k)), gi[o[1]:o[2]], gf[3],
            gi[o[2]:o[3]], gf[f1:f2].reshape((4, n_cells)), gi[o[3]:o[4]],
            gf[f2:f3].reshape((4, s)), gf[f3:f4].reshape((5, s)), gf[f4 : f4 + s], gf[5],
            gi[o[4]:o[5]], gf[4], gi[o[5]:o[6]], gi[o[6]:o[7]], gi[o[7]:o[8]], gi[o[8]:o[9]])  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _scan_kernel_grid(ox, oy, heading, tabs, range_min, range_max, circles, circle_skip, segments, prim_kind,
                      prim_index, gf, gi, fs, js, out_ranges, out_true, out_kind, out_index):  # fmt: skip
    """The grid's scan of every origin (see "broad phase" above). ``gf`` / ``gi``: the grid packed by
    :func:`grid_args`; ``fs`` / ``js``: :func:`grid_scratch`, reused across calls (allocating ~30 arrays
    per call cost more than a one-robot scan's casting)."""
    _grid_cast(ox, oy, heading, tabs, range_min, range_max, circles, circle_skip, segments, prim_kind,
               prim_index, *_unpack_grid(gf, gi), fs, js, out_ranges, out_true, out_kind, out_index)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _grid_pass2(x0, y0, n_c, mc, kx, ky, kr, kid, kb, kc, kn, cmany, cone, t_one, m, s1, s2, s3, s4, sb, sc,
                sid, order, one, bux, buy, best_d, best_p):  # fmt: skip
    """Pass 2 of :func:`_grid_cast` for one origin: the ``mc`` candidate circles and ``m`` front faces with
    their beams (see there). (Compiled as a function of its own it took ~4 % fewer instructions, the
    kernel's array pointers no longer reloaded from the stack in every cast, but no less time: inlined.)"""
    n_beams = best_d.shape[0]
    # those with beams to test (without a branch: a third of them fall between two beams)
    me, m1 = _split_by_count(sc, m, order, one)
    # --- pass 2: circles (those with one beam apart, without a branch), then segments
    cm, c1 = _split_by_count(kc, mc, cmany, cone)
    for w in range(c1):
        q = np.uint64(cone[w])
        dx = kx[q] - x0
        dy = ky[q] - y0
        r = kr[q]
        u = np.uint64(kb[q])
        t_one[w] = _circle_t(dx, dy, (dx * dx + dy * dy) - r * r, bux[u], buy[u])
    for w in range(c1):
        q = np.uint64(cone[w])
        _take_nearer(t_one[w], kid[q], np.uint64(kb[q]), best_d, best_p)
    for w in range(cm):
        q = np.uint64(cmany[w])
        c = kid[q]
        dx = kx[q] - x0
        dy = ky[q] - y0
        r = kr[q]
        cc = (dx * dx + dy * dy) - r * r  # as in _cast_prims, bit for bit
        near = np.float64(kn[q])
        i = int(kb[q]) - 1
        for _ in range(int(kc[q])):
            i += 1
            if i == n_beams:
                i = 0
            u = np.uint64(i)
            bd = best_d[u]
            if bd < near:
                continue  # occluded
            b = dx * bux[u] + dy * buy[u]
            disc = b * b - cc
            if disc < 0.0 or b <= 0.0:
                continue
            t = b - math.sqrt(disc)
            if t > 0.0 and (t < bd or (t == bd and c < best_p[u])):
                best_d[u] = t
                best_p[u] = c
    for w in range(me):
        v = np.uint64(order[w])
        ax = s1[v] - x0
        ay = s2[v] - y0
        ex = (s3[v] - x0) - ax
        ey = (s4[v] - y0) - ay
        i0 = np.uint64(sb[v])
        i1 = i0 + np.uint64(sc[v])  # one past the last beam, unwrapped
        p = n_c + sid[v]
        _segment_run(ax, ay, ex, ey, p, i0, min(i1, np.uint64(n_beams)), bux, buy, best_d, best_p)
        _segment_run(ax, ay, ex, ey, p, np.uint64(0), i1 - min(i1, np.uint64(n_beams)), bux, buy, best_d,
                     best_p)  # fmt: skip
    # segments with one beam to test (most of the far ones): that beam without a branch
    for w in range(m1):
        v = np.uint64(one[w])
        ax = s1[v] - x0
        ay = s2[v] - y0
        ex = (s3[v] - x0) - ax
        ey = (s4[v] - y0) - ay
        _segment_beam(ax, ay, ex, ey, n_c + sid[v], np.uint64(sb[v]), bux, buy, best_d, best_p)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _grid_cast(
    ox, oy, heading, tabs, range_min, range_max, circles, circle_skip, segments, prim_kind, prim_index,
    gx, gy, cs, nx, ny, c_start, c_cols, c_ids, c_pad, g_start, g_box, g_off, g_seg, g_tests, g_half, g_ext,
    g_sid, g_pad, s_start, s_items, dyn_c, dyn_s, fs, js, out_ranges, out_true, out_kind, out_index,
):  # fmt: skip
    """:func:`_scan_kernel_grid` with the grid unpacked."""
    n_beams = tabs.shape[1]
    cos_tab = tabs[0]
    sin_tab = tabs[1]
    inv_res = n_beams / (2.0 * math.pi)
    n_c = circles.shape[0]
    reach = range_max
    # the moving circles, binned by centre for this call; those outside the grid are tested by everyone
    n_d = dyn_c.shape[0]
    n_cells = nx * ny
    # binning a few moving circles costs more than letting every robot test them (a one-robot scan's
    # per-call reset and prefix sum over the cells: ~0.3 us of it); they are then all "outside"
    binned = n_d > _DYN_BIN_MIN
    d_start = js[6, : n_cells + 1]
    d_cell = js[4]
    xmax = gx + nx * cs
    ymax = gy + ny * cs
    d_pad = 0.0
    n_in = 0
    fill = js[7]
    if binned:
        d_start[:] = 0
        for k in range(n_d):
            c = dyn_c[k]
            x = circles[c, 0]
            y = circles[c, 1]
            if x > gx and x < xmax and y > gy and y < ymax:
                cell = min(int((x - gx) / cs), nx - 1) * ny + min(int((y - gy) / cs), ny - 1)
                d_cell[k] = cell
                d_start[cell + 1] += 1
                d_pad = max(d_pad, circles[c, 2])
            else:
                d_cell[k] = -1
        acc = 0
        for c in range(n_cells):
            fill[c] = acc
            acc += d_start[c + 1]
            d_start[c + 1] = acc
        n_in = acc
    else:
        for k in range(n_d):
            d_cell[k] = -1
    d_cols = fs[19:22]
    d_ids = js[5]
    o = n_in
    for k in range(n_d):
        c = dyn_c[k]
        cell = d_cell[k]
        if cell >= 0:
            p = fill[cell]
            fill[cell] += 1
        else:
            p = o
            o += 1
        d_cols[0, p] = circles[c, 0]
        d_cols[1, p] = circles[c, 1]
        d_cols[2, p] = circles[c, 2]
        d_ids[p] = c
    # the columns as 1-D views made once per call (see the cell loop below)
    tk, tex, tey, tmx, tmy = g_tests[0], g_tests[1], g_tests[2], g_tests[3], g_tests[4]
    cc0, cc1, cc2 = c_cols[0], c_cols[1], c_cols[2]
    dc0, dc1, dc2 = d_cols[0], d_cols[1], d_cols[2]
    # scratch: candidate circles (k*), segments (s*), the segment pass's flags
    kx, ky, kr = fs[0], fs[1], fs[2]
    kb, kc, kn = fs[3].view(np.float32), fs[4].view(np.float32), fs[5].view(np.float32)  # (_circle_tests)
    cap = fs.shape[1]
    f7, f8 = fs[7].view(np.float32), fs[8].view(np.float32)
    fx, fy, fr = f7[:cap], f7[cap:], f8[:cap]  # their float32 copies (_circle_tests)
    flags = fs[9]
    t_one = fs[6]  # the one-beam circles' hit distances
    s1, s2, s3, s4, sb, sc = fs[12], fs[13], fs[14], fs[15], fs[16], fs[17]
    best_d, bux, buy = fs[22, :n_beams], fs[23, :n_beams], fs[24, :n_beams]  # (_write_row: n_beams long)
    kid, order, one, sid = js[0], js[1], js[2], js[3]
    best_p, stamp = js[9, :n_beams], js[10]
    cmany, cone = js[8], js[12]  # the circles with several beams to test, with one
    eidx = js[13]  # the groups' front faces in reach, by edge index
    # stamp tags stay unique across calls (the scratch is reused): the last one is kept in js[11, 0]
    tag0 = js[11, 0]
    js[11, 0] = tag0 + ox.shape[0]
    rc = reach + _TOL
    rc2 = rc * rc
    for n in range(ox.shape[0]):
        x0 = ox[n]
        y0 = oy[n]
        h = heading[n]
        skip = circle_skip[n]
        ch = math.cos(h)
        sh = math.sin(h)
        hw = h - 2.0 * math.pi * math.floor(h / (2.0 * math.pi) + 0.5)  # as in _cast_prims
        # the margin of _edge_flags' back-face test: ~50x a bound of both forms' rounding (~100 eps M^2 for
        # coordinates up to M)
        ext = 1.0 + abs(x0) + abs(y0) + g_ext
        tol = 1e-12 * ext * ext
        for i in range(n_beams):
            best_d[i] = range_max
            best_p[i] = -1
            # the direction of beam i, by the same rotation as _cast_prims (bit for bit)
            bux[i] = ch * cos_tab[i] + sh * sin_tab[i]
            buy[i] = sh * cos_tab[i] - ch * sin_tab[i]
        # --- pass 1: the column runs of cells within reach (cells widened by the layer's largest radius):
        # the circles' coordinates are gathered into contiguous columns and the groups' front faces within
        # reach are listed by their edge index (one store per edge visited; copying their coordinates
        # there cost more than testing them), then both get their tests in single vectorised passes (a
        # pass per run paid its vector loop's scalar remainder once per column: ~0.15 us each)
        mc = 0
        ms = 0
        for layer in range(3):
            # (no array variable assigned here: each assignment or view of an array in these loops costs
            # two atomic reference-count updates, ~10 % of a one-robot scan before they were hoisted)
            if layer == 0:
                pad = c_pad
            elif layer == 1:
                if not binned:
                    continue
                pad = d_pad
            else:
                pad = g_pad
            fi0 = (x0 - pad - reach - gx) / cs
            fi1 = (x0 + pad + reach - gx) / cs
            if not (fi1 >= 0.0 and fi0 < nx):
                continue  # (NaN origins too)
            for i in range(int(max(fi0, 0.0)), int(min(fi1, nx - 1.0)) + 1):
                left = gx + i * cs - pad
                ddx = max(max(left - x0, 0.0), x0 - (left + cs + 2.0 * pad))
                hy2 = rc2 - ddx * ddx
                if hy2 < 0.0:
                    continue
                hy = math.sqrt(hy2)
                fj0 = (y0 - hy - pad - gy) / cs
                fj1 = (y0 + hy + pad - gy) / cs
                if not (fj1 >= 0.0 and fj0 < ny):
                    continue
                if layer == 2:
                    # the groups' edges, by runs of the cells whose box of edges is within reach
                    c0 = i * ny + int(max(fj0, 0.0))
                    c1 = i * ny + int(min(fj1, ny - 1.0)) + 1
                    ra = c1
                    for cc in range(c0, c1 + 1):
                        ok = False
                        if cc < c1:
                            bdx = max(max(g_box[0, cc] - x0, 0.0), x0 - g_box[2, cc])
                            bdy = max(max(g_box[1, cc] - y0, 0.0), y0 - g_box[3, cc])
                            ok = bdx * bdx + bdy * bdy <= rc2
                        if ok and ra == c1:
                            ra = cc
                        elif not ok and ra < c1:
                            ea, eb = g_off[g_start[ra]], g_off[g_start[cc]]
                            ms = _edge_flags(x0, y0, rc, tol, tk, tex, tey, tmx, tmy, g_half, ea, eb, ms,
                                             eidx, flags)  # fmt: skip
                            ra = c1
                    continue
                ca = i * ny + int(max(fj0, 0.0))
                cb = i * ny + int(min(fj1, ny - 1.0)) + 1
                if layer == 0:
                    mc = _gather_circles(cc0, cc1, cc2, c_ids, c_start[ca], c_start[cb], mc, kx, ky, kr, kid,
                                         fx, fy, fr)  # fmt: skip
                else:
                    mc = _gather_circles(dc0, dc1, dc2, d_ids, d_start[ca], d_start[cb], mc, kx, ky, kr, kid,
                                         fx, fy, fr)  # fmt: skip
        if n_in < n_d:
            mc = _gather_circles(dc0, dc1, dc2, d_ids, n_in, n_d, mc, kx, ky, kr, kid, fx, fy, fr)
        _circle_tests(x0, y0, hw, skip, reach, n_beams, inv_res, mc, fx, fy, fr, kid, kb, kc, kn)
        # the front faces' coordinates and ids, gathered in contiguous columns for the interval pass
        for v in range(ms):
            q = np.uint64(eidx[v])
            s1[v] = g_seg[0, q]
            s2[v] = g_seg[1, q]
            s3[v] = g_seg[2, q]
            s4[v] = g_seg[3, q]
            sid[v] = g_sid[q]
        # --- long segments of the cells within reach (each once: stamp), and the moving segments
        ns = 0
        fi0 = (x0 - reach - gx) / cs
        fi1 = (x0 + reach - gx) / cs
        fj0 = (y0 - reach - gy) / cs
        fj1 = (y0 + reach - gy) / cs
        if s_items.shape[0] > 0 and fi1 >= 0.0 and fi0 < nx and fj1 >= 0.0 and fj0 < ny:
            j0 = int(max(fj0, 0.0))
            j1 = int(min(fj1, ny - 1.0))
            for i in range(int(max(fi0, 0.0)), int(min(fi1, nx - 1.0)) + 1):
                for q in range(s_start[i * ny + j0], s_start[i * ny + j1 + 1]):
                    s = s_items[np.uint64(q)]
                    if stamp[s] != tag0 + n + 1:
                        stamp[s] = tag0 + n + 1
                        order[ns] = s
                        ns += 1
        for q in range(dyn_s.shape[0]):
            order[ns] = dyn_s[q]
            ns += 1
        # their back-face and reach test (as _cast_prims), appended to the groups' front faces
        m = ms
        for v in range(ns):
            s = order[v]
            front = _front_in_reach(segments[s, 0] - x0, segments[s, 1] - y0, segments[s, 2] - x0,
                                    segments[s, 3] - y0, rc2)  # fmt: skip
            sid[m] = s
            s1[m] = segments[s, 0]
            s2[m] = segments[s, 1]
            s3[m] = segments[s, 2]
            s4[m] = segments[s, 3]
            m += front > 0.0
        # the beam interval of every front face (as _cast_prims; their reach was tested above, with a margin
        # of _TOL: a segment farther than range_max cannot beat a beam's initial range_max)
        for v in range(m):
            sb[v], sc[v] = _segment_interval(s1[v] - x0, s2[v] - y0, s3[v] - x0, s4[v] - y0, hw, inv_res,
                                             n_beams)  # fmt: skip
        _grid_pass2(x0, y0, n_c, mc, kx, ky, kr, kid, kb, kc, kn, cmany, cone, t_one, m, s1, s2, s3, s4, sb,
                    sc, sid, order, one, bux, buy, best_d, best_p)  # fmt: skip
        _write_row_split(n, best_d, best_p, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
                         out_kind, out_index)  # fmt: skip


def cast_scan(
    origins: np.ndarray,
    headings: np.ndarray,
    circles: np.ndarray,
    segments: np.ndarray,
    skip_circle: np.ndarray,
    prim_kind: np.ndarray,
    prim_index: np.ndarray,
    spec: LidarSpec,
    dtype: type = np.float32,
    grid: LidarGrid | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free lidar readings plus per-beam ground truth, fused in one kernel pass.

    With ``grid`` (:func:`build_lidar_grid` over the same primitive arrays) the kernel visits only the
    grid cells near each robot (see "broad phase" above); without it, every primitive (the brute-force
    reference). Both return the same arrays, bit for bit.

    ``prim_kind`` / ``prim_index`` give each primitive's owner, indexed by primitive id + 1 (slot 0
    is "no hit"). Returns ``ranges`` (``dtype``, ``range_max`` for no return or a surface closer than
    ``range_min``), ``true_ranges`` (``dtype``, ``inf`` for no hit), ``hit_kind`` (int8) and
    ``hit_index`` (int32), each ``(N, n_beams)``. Distances are computed in float64 either way.
    """
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 2)
    n, nb = origins.shape[0], spec.n_beams
    ranges = np.empty((n, nb), dtype)
    true = np.empty((n, nb), dtype)
    kind = np.empty((n, nb), np.int8)
    index = np.empty((n, nb), np.int32)
    circles = np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3)
    segments = np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4)
    args = (
        origins[:, 0].copy(),
        origins[:, 1].copy(),
        np.ascontiguousarray(headings, dtype=np.float64).reshape(n),
        beam_tables(nb),
        float(spec.range_min),
        float(spec.range_max),
        circles,
        np.ascontiguousarray(skip_circle, dtype=np.int64).reshape(n),
        segments,
        np.ascontiguousarray(prim_kind, dtype=np.int8),
        np.ascontiguousarray(prim_index, dtype=np.int32),
    )
    if grid is None:
        _scan_kernel(*args, ranges, true, kind, index)
    else:
        if not isinstance(grid, LidarGrid):
            raise TypeError(f"cast_scan: grid must be a LidarGrid or None, got {type(grid).__name__}")
        if (grid.n_circles, grid.n_segments) != (len(circles), len(segments)):
            raise ValueError(
                f"cast_scan: the grid indexes {grid.n_circles} circles and {grid.n_segments} segments, "
                f"got {len(circles)} and {len(segments)}; rebuild it with build_lidar_grid"
            )
        _scan_kernel_grid(*args, *grid_args(grid), *grid_scratch(grid, nb), ranges, true, kind, index)
    return ranges, true, kind, index


def grid_args(grid: LidarGrid) -> tuple[np.ndarray, np.ndarray]:
    """The grid kernel's arguments for ``grid`` (after the primitive owner tables): its arrays packed in
    one float64 and one int64 array (a compiled call costs ~70 ns per array argument: 19 arguments
    were ~1.5 us of a one-robot scan)."""
    (gx, gy), (nx, ny) = grid.origin, grid.shape
    ints = [grid.circle_start, grid.circle_ids, grid.group_start, grid.group_offsets, grid.group_segment_ids,
            grid.segment_start, grid.segment_items, grid.dynamic_circles, grid.dynamic_segments]  # fmt: skip
    ends = np.cumsum([15] + [len(a) for a in ints])  # the header is 15 long
    head = [nx, ny, grid.circles.shape[1], grid.groups.shape[1], len(grid.group_segments), *ends]
    gi = np.concatenate([np.asarray(head, np.int64), *ints]).astype(np.int64)
    gf = np.concatenate([[gx, gy, grid.cell_size, grid.circle_pad, grid.group_pad, grid.group_extent],
                         grid.circles.ravel(), grid.group_boxes.ravel(), grid.group_segments.T.ravel(),
                         grid.group_edge_tests.ravel(), grid.group_edge_half])  # fmt: skip
    gf = gf.astype(np.float64)
    return gf, gi


def _grid_cap(grid: LidarGrid, n_beams: int) -> int:
    """Columns of the grid kernel's work arrays: the most candidates of any kind in one scan."""
    return max(len(grid.circle_ids) + len(grid.dynamic_circles), grid.groups.shape[1],
               len(grid.segment_items) + len(grid.dynamic_segments), n_beams, grid.shape[0] * grid.shape[1],
               grid.n_segments) + 1  # fmt: skip


def grid_scratch(grid: LidarGrid, n_beams: int) -> tuple[np.ndarray, np.ndarray]:
    """Work arrays of the grid kernel for ``grid`` and ``n_beams`` beams, passed after :func:`grid_args`.
    A caller that scans often (``World``) keeps one pair; they must not be used by two scans at once."""
    cap = _grid_cap(grid, n_beams)
    # the float rows are always written before they are read; the int rows hold the stamps (and their
    # last tag), which must start below every tag
    return np.empty((25, cap)), np.zeros((14, cap), np.int64)


def cast_prepared(ox, oy, heading, skip, static: tuple, grid: tuple | None):
    """:func:`cast_scan` for callers that keep their arguments in the kernel's form (``World.scan``:
    the conversions and checks cost more than a one-robot scan's kernel). ``ox``, ``oy``, ``heading``:
    ``(N,)`` contiguous float64; ``skip``: ``(N,)`` int64; ``static``: ``(beam_tables, range_min,
    range_max, circles, segments, prim_kind, prim_index)`` as :func:`cast_scan` converts them; ``grid``:
    :func:`grid_args` followed by :func:`grid_scratch`, or ``None``. Returns float32 readings as
    :func:`cast_scan`."""
    tabs, range_min, range_max, circles, segments, prim_kind, prim_index = static
    n, nb = ox.shape[0], tabs.shape[1]
    out = (np.empty((n, nb), np.float32), np.empty((n, nb), np.float32), np.empty((n, nb), np.int8),
           np.empty((n, nb), np.int32))  # fmt: skip
    args = (ox, oy, heading, tabs, range_min, range_max, circles, skip, segments, prim_kind, prim_index)
    if grid is None:
        _scan_kernel(*args, *out)
    else:
        _scan_kernel_grid(*args, *grid, *out)
    return out


@numba.njit(cache=True, nogil=True)
def wrap_headings(rows):
    """Wrap column 2 of ``rows`` (``(n, 3)`` x, y, angle) to (-pi, pi] in place, as
    ``arctan2(sin, cos)``: the one wrap of ``World.poses``, ``World.scan`` and ``WorldBatch.poses``."""
    for k in range(rows.shape[0]):
        a = rows[k, 2]
        rows[k, 2] = math.atan2(math.sin(a), math.cos(a))


@intrinsic
def _call_getters(typingctx, get_position, get_angle, body):
    """``(x, y, angle)`` of a physics body by its C getters: ``get_position`` a ``struct {double x, y;}
    (*)(void *)`` and ``get_angle`` a ``double (*)(void *)`` function address, ``body`` the address of the
    body (``World`` passes Chipmunk's ``cpBodyGetPosition`` / ``cpBodyGetAngle`` and its robots'
    ``cpBody`` pointers: the pose of the moment, read without Python)."""
    sig = types.UniTuple(types.float64, 3)(types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        ptr, dbl = ir.IntType(8).as_pointer(), ir.DoubleType()
        xy_type = ir.LiteralStructType([dbl, dbl])  # returned in two registers (x86-64 SysV, AArch64)
        pos_fn = builder.inttoptr(args[0], ir.FunctionType(xy_type, [ptr]).as_pointer())
        ang_fn = builder.inttoptr(args[1], ir.FunctionType(dbl, [ptr]).as_pointer())
        body = builder.inttoptr(args[2], ptr)
        xy = builder.call(pos_fn, [body])
        angle = builder.call(ang_fn, [body])
        return context.make_tuple(builder, signature.return_type,
                                  [builder.extract_value(xy, 0), builder.extract_value(xy, 1), angle])

    return sig, codegen


@intrinsic
def _borrowed(typingctx, arr):
    """``arr`` without its owner (memory info and parent set to null): views made from it take no
    reference, where each view of an owned array costs two atomic reference-count updates on its owner
    (all of them on the same one: ~10 % of a one-robot scan among 1,000 obstacles, sampled with perf; numba
    does not prune those it cannot pair within a block). Only for arrays the caller keeps alive for the
    whole call (``World.scan``'s packed arrays), never for one that is returned or stored."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, signature, args):
        src = context.make_array(signature.args[0])(context, builder, value=args[0])
        out = context.make_array(signature.return_type)(context, builder, value=src._getvalue())
        out.meminfo = context.get_constant_null(types.MemInfoPointer(types.voidptr))
        out.parent = context.get_constant_null(types.pyobject)
        return out._getvalue()

    return arr(arr), codegen


@numba.njit(cache=True, nogil=True)
def read_poses(getters, bodies, out):
    """``out[k] = (x, y, angle)`` of body ``bodies[k]`` through the getters ``getters`` (two function
    addresses, see :func:`_call_getters`); angles raw (unwrapped)."""
    for k in range(bodies.shape[0]):
        x, y, a = _call_getters(getters[0], getters[1], bodies[k])
        out[k, 0] = x
        out[k, 1] = y
        out[k, 2] = a


# World.scan's arguments are packed in two arrays (a compiled call costs ~50-70 ns per argument: the
# 19 of the previous entry were ~1 us of a one-robot scan): ``wf`` (float64) and ``wi`` (int64), each a
# header-described run of regions. wi[0:8]: robots, beams, circles, segments, owner-table length,
# position getter, angle getter, 1 if gridded; wi[8:16] and wi[16:24]: the start of each region of wf
# (range_min/max, beam tables, circles, segments, the robots' rows, grid floats, work floats, end) and of
# wi (the robots' bodies, owner kinds, owner indices, grid ints, work ints, end, -, -).
_WI_HEAD = 24


def world_pack(bodies, getters, spec: LidarSpec, circles, segments, prim_kind, prim_index, grid):
    """``World.scan``'s two packed arrays and views into them: ``(wf, wi, circles, segments, grid)``.

    ``bodies``: the robots' body addresses (robot ``i``'s housing is circle ``i``); ``getters``: the
    position and angle getters (:func:`_call_getters`); ``circles`` / ``segments`` / owner tables as
    :func:`cast_scan` takes them; ``grid``: a :class:`LidarGrid` or ``None`` (the brute-force kernel).
    The returned ``circles`` / ``segments`` are the packed copies, which the caller must update in place
    (moved obstacles), and ``grid`` is ``(gf, gi, fs, js)`` for :func:`cast_prepared` (views, or
    ``None``). One scan at a time: the work arrays are inside."""
    nb, n_r = spec.n_beams, len(bodies)
    circles = np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3)
    segments = np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4)
    n_c, n_s, n_p = len(circles), len(segments), len(prim_kind)
    if grid is None:
        k = max(n_c, n_s, 1)
        gf, gi = np.zeros(0), np.zeros(0, np.int64)
        n_fw, n_iw = 5 * n_c + 4 * n_s + 7 * k + nb, 3 * k + nb  # _brute_scratch
    else:
        gf, gi = grid_args(grid)
        cap = _grid_cap(grid, nb)
        n_fw, n_iw = 25 * cap, 14 * cap  # grid_scratch
    fo = np.cumsum([0, 2, 2 * nb, 3 * n_c, 4 * n_s, 3 * n_r, len(gf), n_fw])
    io = np.cumsum([_WI_HEAD, n_r, n_p, n_p, len(gi), n_iw])
    wf = np.zeros(fo[-1])
    wi = np.zeros(io[-1], np.int64)
    wi[:8] = (n_r, nb, n_c, n_s, n_p, getters[0], getters[1], grid is not None)
    wi[8:16] = fo
    wi[16:22] = io
    wf[:2] = spec.range_min, spec.range_max
    wf[fo[1] : fo[2]] = beam_tables(nb).ravel()
    wf[fo[2] : fo[3]] = circles.ravel()
    wf[fo[3] : fo[4]] = segments.ravel()
    wf[fo[5] : fo[6]] = gf
    wi[io[0] : io[1]] = bodies
    wi[io[1] : io[2]] = prim_kind
    wi[io[2] : io[3]] = prim_index
    wi[io[3] : io[4]] = gi
    if grid is None:
        wi[io[4] : io[4] + k] = np.arange(k)  # _brute_scratch's ints[0]
    views = (wf[fo[2] : fo[3]].reshape(n_c, 3), wf[fo[3] : fo[4]].reshape(n_s, 4))
    if grid is None:
        return wf, wi, *views, None
    return wf, wi, *views, (wf[fo[5] : fo[6]], wi[io[3] : io[4]], wf[fo[6] : fo[7]].reshape(25, cap),
                            wi[io[4] : io[5]].reshape(14, cap))  # fmt: skip


@numba.njit(cache=True, nogil=True, inline="always")
def _world_unpack(wf, wi, idx, poses):
    """The packed arrays' regions (see :func:`world_pack`), after reading the robots' poses: the housings
    (circles ``0..robots-1``) moved to them, the headings of robots ``idx`` wrapped (as
    :func:`wrap_headings`) and their poses written to ``poses``; returns ``(x, y, heading)`` rows of
    ``idx``, the beam tables, range_min, range_max, circles, segments, owner kinds and indices, and the
    grid / work regions."""
    n_r, nb, n_c, n_s = wi[0], wi[1], wi[2], wi[3]
    fo = wi[8:16]
    io = wi[16:22]
    circles = wf[fo[2] : fo[3]].reshape((n_c, 3))
    bodies = wi[io[0] : io[1]]
    for k in range(n_r):
        x, y, a = _call_getters(wi[5], wi[6], bodies[k])
        circles[k, 0] = x
        circles[k, 1] = y
    n = idx.shape[0]
    # the rows in wf's region for them (an allocation was ~1.5k instructions of a one-robot call), unless a
    # robot is listed more than once
    ob = wf[fo[4] : fo[4] + 3 * n] if 3 * n <= fo[5] - fo[4] else np.empty(3 * n)
    o = (ob[:n], ob[n : 2 * n], ob[2 * n :])
    for m in range(n):
        x, y, a = _call_getters(wi[5], wi[6], bodies[idx[m]])
        a = math.atan2(math.sin(a), math.cos(a))  # wrap_headings
        poses[m, 0] = o[0][m] = x
        poses[m, 1] = o[1][m] = y
        poses[m, 2] = o[2][m] = a
    return (o, wf[fo[1] : fo[2]].reshape((2, nb)), wf[0], wf[1], circles, wf[fo[3] : fo[4]].reshape((n_s, 4)),
            wi[io[1] : io[2]], wi[io[2] : io[3]], wf[fo[5] : fo[6]], wi[io[3] : io[4]], wf[fo[6] : fo[7]],
            wi[io[4] : io[5]])  # fmt: skip


def compiled_entry(dispatcher, args: tuple):
    """The compiled function that ``dispatcher`` runs for ``args``, to be called directly (after a call of
    ``dispatcher`` with them): numba's dispatch (typing each argument, choosing the overload) was ~0.3 us
    of a one-robot ``World.scan``. Only for a caller whose arguments always have these numba types (the
    entry does not check them); ``dispatcher`` itself if numba has no such overload."""
    try:
        return dispatcher.overloads[tuple(numba.typeof(a) for a in args)].entry_point
    except (AttributeError, KeyError, TypeError, ValueError):
        return dispatcher


@numba.njit(cache=True, nogil=True)
def _world_scan_brute(idx, wf, wi, poses, ranges, true, kind, index):
    """``World.scan`` in one compiled call (the Python around a one-robot scan's kernel cost as much as
    the kernel): the robots' poses read (:func:`_world_unpack`), robots ``idx`` cast by the brute-force
    kernel with the work arrays packed in ``wf`` / ``wi`` (:func:`world_pack`). Writes their poses and
    the four outputs of :func:`cast_scan` (float32) into the last five arrays (allocated by the caller:
    returning five arrays from a compiled call cost ~1.8 us, allocating them in Python ~0.9). (Two
    entries, not one with a flag: a fresh install compiles only the kernel it uses.)"""
    unpacked = _world_unpack(_borrowed(wf), _borrowed(wi), idx, poses)
    o, tabs, range_min, range_max, circles, segments, kinds, owners, _, _, ff, fi = unpacked
    n_c, n_s, nb = circles.shape[0], segments.shape[0], tabs.shape[1]
    k = max(n_c, n_s, 1)
    _scan_kernel_into(o[0], o[1], o[2], tabs, range_min, range_max, circles, idx, segments, kinds, owners,
                      ff[: 5 * n_c + 4 * n_s + 7 * k + nb], fi[: 3 * k + nb], ranges, true, kind, index)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _world_scan_grid(idx, wf, wi, poses, ranges, true, kind, index):
    """:func:`_world_scan_brute` through the grid packed in ``wf`` / ``wi``."""
    unpacked = _world_unpack(_borrowed(wf), _borrowed(wi), idx, poses)
    o, tabs, range_min, range_max, circles, segments, kinds, owners, gf, gi, ff, fi = unpacked
    cap = ff.shape[0] // 25
    _grid_cast(o[0], o[1], o[2], tabs, range_min, range_max, circles, idx, segments, kinds, owners,
               *_unpack_grid(gf, gi), ff.reshape((25, cap)), fi.reshape((14, cap)), ranges, true, kind, index)


def scan_shapes(
    origin=(0.0, 0.0),
    heading: float = 0.0,
    circles=(),
    polygons=(),
    spec: LidarSpec | None = None,
) -> np.ndarray:
    """Noise-free scan of loose shapes, for synthetic tests and notebooks.

    Args:
        origin: sensor position ``(x, y)``, m.
        heading: sensor heading, rad, CCW from the x axis.
        circles: iterable of ``(cx, cy, r)``.
        polygons: iterable of closed convex vertex arrays ``(k, 2)``, either winding.
        spec: the lidar; default RPLIDAR A1.

    Returns:
        ``ranges (n_beams,)`` float64, m, ordered as ``spec.angles``; ``range_max`` where nothing is
        hit within ``[range_min, range_max]``.
    """
    spec = spec or LidarSpec()
    c = np.asarray(list(circles), dtype=np.float64).reshape(-1, 3)
    segs = [polygon_edges(_ccw(np.asarray(p, dtype=np.float64))) for p in polygons]
    s = np.concatenate(segs) if segs else np.zeros((0, 4))
    n_prim = len(c) + len(s)
    ranges, _, _, _ = cast_scan(
        np.asarray([origin]), np.asarray([heading]), c, s, np.array([-1]),
        np.zeros(n_prim + 1, np.int8), np.arange(-1, n_prim, dtype=np.int32), spec, dtype=np.float64,
    )  # fmt: skip
    return ranges[0]
