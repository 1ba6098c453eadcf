"""Vectorised exact 2D lidar raycaster (the simulator's hot path).

Geometry is reduced to two primitive sets:

* **circles** ``(C, 3)``: ``cx, cy, radius`` — cylinder obstacles and robots' lidar housings;
* **segments** ``(S, 4)``: ``x1, y1, x2, y2`` — the edges of boxes, prisms, convex polygons,
  walls and the arena boundary.

Each primitive carries an *owner* (what a beam that hits it reports: a kind code and an index).
All robots' scans are cast in one call of a numba kernel. For every (robot, primitive) pair the
kernel computes the angular interval the primitive subtends and tests only the beams inside it, with
exact ray–circle / ray–segment intersection, so the cost grows with the number of beams that actually
touch something rather than with ``beams × primitives``.

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

from detectors._numba_cache import ensure_cache_dir

ensure_cache_dir(__file__.rsplit('/', 1)[0])  # before the @njit(cache=True) below: read-only installs

__all__ = ["HitKind", "LidarSpec", "cast_scan", "scan_shapes", "polygon_edges"]


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


# rad: widens each primitive's beam interval. It covers the error of _fast_atan2 (< 1e-5 rad),
# so a beam through a vertex or tangent is always tested; the exact intersection test decides.
_EPS = 1e-4


@numba.njit(cache=True, inline="always")
def _fast_atan2(y, x):
    """atan2 to within 1e-5 rad (minimax polynomial): only used to pick candidate beams."""
    ax = abs(x)
    ay = abs(y)
    if ax == 0.0 and ay == 0.0:
        return 0.0
    swap = ay > ax
    z = ax / ay if swap else ay / ax
    z2 = z * z
    a = z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330 + z2 * 0.0208351))))
    if swap:
        a = 0.5 * math.pi - a
    if x < 0.0:
        a = math.pi - a
    return -a if y < 0.0 else a


def _ccw(v: np.ndarray) -> np.ndarray:
    area2 = np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1))
    return v if area2 > 0 else v[::-1]


@numba.njit(cache=True, nogil=True, inline="always")
def _cast_one(x0, y0, h, skip, range_max, circles, segments, cos_tab, sin_tab, best_d, best_p):
    """Cast one origin's beams into ``best_d`` / ``best_p`` (nearest distance and primitive id).

    Beams with no hit within ``range_max`` get distance ``range_max`` and primitive -1.
    Primitive ids: circles are ``0..C-1``, segments ``C..C+S-1``. Circle ``skip`` (the robot's own
    housing) is ignored. Beam ``i`` has world direction ``h - i*res``.
    Segments are one-sided: only a beam arriving from the segment's right-hand side (looking from
    its first to its second point) can hit it, i.e. the outside of a CCW polygon. A convex solid's
    back faces can never be the first hit, so culling them halves the work exactly.
    """
    n_beams = best_d.shape[0]
    res = 2.0 * math.pi / n_beams
    n_c = circles.shape[0]
    n_s = segments.shape[0]
    rmax2 = range_max * range_max
    ch = math.cos(h)
    sh = math.sin(h)
    for i in range(n_beams):
        best_d[i] = range_max  # hits beyond range_max are never recorded
        best_p[i] = -1
    for c in range(n_c):
        if c == skip:
            continue
        dx = circles[c, 0] - x0
        dy = circles[c, 1] - y0
        r = circles[c, 2]
        d2 = dx * dx + dy * dy
        d = math.sqrt(d2)
        if d - r > range_max or d <= r:
            # out of range, or the origin is inside the circle (not a physical state)
            continue
        # half-angle subtended: asin(r/d) = atan(r / sqrt(d^2 - r^2))
        half = _fast_atan2(r, math.sqrt(d2 - r * r)) + _EPS
        phi = _fast_atan2(dy, dx) - h  # bearing of the centre relative to the heading
        # beam i points at -i*res: beams within [phi-half, phi+half] have i in
        # [-(phi+half)/res, -(phi-half)/res]
        k0 = int(math.ceil(-(phi + half) / res))
        k1 = int(math.floor(-(phi - half) / res))
        cc = d2 - r * r
        i = k0 % n_beams - 1  # one modulo per primitive; the beam index then wraps by hand
        for _ in range(k1 - k0 + 1):
            i += 1
            if i == n_beams:
                i = 0
            # direction of heading - i*res, by rotation (no trig in the inner loop)
            ux = ch * cos_tab[i] + sh * sin_tab[i]
            uy = sh * cos_tab[i] - ch * sin_tab[i]
            b = dx * ux + dy * uy
            disc = b * b - cc
            if disc < 0.0 or b <= 0.0:
                continue
            t = b - math.sqrt(disc)
            if t > 0.0 and t < best_d[i]:
                best_d[i] = t
                best_p[i] = c
    for s in range(n_s):
        ax = segments[s, 0] - x0
        ay = segments[s, 1] - y0
        bx = segments[s, 2] - x0
        by = segments[s, 3] - y0
        ex = bx - ax
        ey = by - ay
        # back face: the origin is on the left of A->B (or on its line)
        if ey * ax - ex * ay >= 0.0:
            continue
        ee = ex * ex + ey * ey
        u = -(ax * ex + ay * ey) / ee
        u = min(1.0, max(0.0, u))
        px = ax + u * ex
        py = ay + u * ey
        if px * px + py * py > rmax2:
            continue
        th_a = _fast_atan2(ay, ax) - h
        span = _fast_atan2(ax * by - ay * bx, ax * bx + ay * by)  # signed angle A -> B
        lo = th_a + min(0.0, span) - _EPS
        hi = th_a + max(0.0, span) + _EPS
        k0 = int(math.ceil(-hi / res))
        k1 = int(math.floor(-lo / res))
        i = k0 % n_beams - 1
        for _ in range(k1 - k0 + 1):
            i += 1
            if i == n_beams:
                i = 0
            ux = ch * cos_tab[i] + sh * sin_tab[i]
            uy = sh * cos_tab[i] - ch * sin_tab[i]
            den = ux * ey - uy * ex  # cross(u, e)
            if den == 0.0:
                continue
            # origin + t u = A + s e  ->  t = cross(A, e)/cross(u, e), s = cross(A, u)/cross(u, e)
            t = (ax * ey - ay * ex) / den
            sp = (ax * uy - ay * ux) / den
            if t > 0.0 and 0.0 <= sp <= 1.0 and t < best_d[i]:
                best_d[i] = t
                best_p[i] = n_c + s


@numba.njit(cache=True, nogil=True)
def _beam_tables(n_beams):
    res = 2.0 * math.pi / n_beams
    cos_tab = np.empty(n_beams)
    sin_tab = np.empty(n_beams)
    for i in range(n_beams):
        cos_tab[i] = math.cos(i * res)
        sin_tab[i] = math.sin(i * res)
    return cos_tab, sin_tab


@numba.njit(cache=True, nogil=True)
def _scan_kernel(
    ox,
    oy,
    heading,
    n_beams,
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
    """
    cos_tab, sin_tab = _beam_tables(n_beams)
    best_d = np.empty(n_beams)
    best_p = np.empty(n_beams, dtype=np.int32)
    for n in range(ox.shape[0]):
        _cast_one(
            ox[n],
            oy[n],
            heading[n],
            circle_skip[n],
            range_max,
            circles,
            segments,
            cos_tab,
            sin_tab,
            best_d,
            best_p,
        )
        for i in range(n_beams):
            p = best_p[i] + 1
            d = best_d[i]
            out_kind[n, i] = prim_kind[p]
            out_index[n, i] = prim_index[p]
            if p == 0:
                out_true[n, i] = np.inf
                out_ranges[n, i] = range_max
            else:
                out_true[n, i] = d
                out_ranges[n, i] = d if d >= range_min else range_max


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
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free lidar readings plus per-beam ground truth, fused in one kernel pass.

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
    _scan_kernel(
        origins[:, 0].copy(),
        origins[:, 1].copy(),
        np.ascontiguousarray(headings, dtype=np.float64).reshape(n),
        int(nb),
        float(spec.range_min),
        float(spec.range_max),
        np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3),
        np.ascontiguousarray(skip_circle, dtype=np.int64).reshape(n),
        np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4),
        np.ascontiguousarray(prim_kind, dtype=np.int8),
        np.ascontiguousarray(prim_index, dtype=np.int32),
        ranges,
        true,
        kind,
        index,
    )
    return ranges, true, kind, index


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
