"""Geometric lidar kin detector of the paper (sections 4.1-4.4), numpy only.

Pipeline, one public function per stage so each can be inspected alone:

1. :func:`preprocess` (4.1): non-finite readings -> ``d_max``; optional
   one-beam spike / dropout filter (3-beam median on isolated beams).
2. :func:`segment` (4.2, eq. 1): split the scan where the range derivative
   ``∂_i = d_i - d_{i-1}`` exceeds ``d_th`` (:func:`range_derivative`).
3. :func:`filter_by_diameter` (4.3.1, eqs. 2-5): keep segments with
   ``omega_min <= 2r < omega_max``.
4. :func:`fit_circle` / :func:`filter_by_shape` (4.3.2, eqs. 6-7): fit a
   circle of known radius ``r`` in polar coordinates with Levenberg-Marquardt
   and threshold the absolute residual sum ``F``.
5. :func:`position_kin` (4.4): range, bearing, x, y of the fitted centre.

:class:`GeometricKinDetector` chains them, running segmentation and the
diameter filter vectorised over all segments of a scan and the circle fits of
all candidates together. :meth:`GeometricKinDetector.detect_arrays` runs all
stages of a batch of scans in compiled code (:mod:`detectors._kernels`) and
returns flat arrays; the Python result objects are built from them on demand.

Conventions: ranges in metres, angles in radians in the observer frame,
counter-clockwise positive, 0 = heading (x forward, y left). Beam order is
whatever the scan uses (the RPLIDAR A1 sweeps clockwise); nothing here assumes
a direction, a beam count or a uniform step: angular quantities are computed
from the beam angles supplied with the scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numba
import numpy as np

from . import _kernels as _k
from .base import (
    STAGES,
    BatchDetections,
    DetectionResult,
    KinDetector,
    LazyBatchReports,
    Segment,
    SegmentReport,
    trusted_ranges,
    validate_batch,
    validate_scan,
    wrap_angle,
)

__all__ = [
    "CircleFit",
    "DiameterCheck",
    "GeometricKinDetector",
    "GeometricParams",
    "KinPosition",
    "ShapeCheck",
    "circle_residuals",
    "filter_by_diameter",
    "filter_by_shape",
    "fit_circle",
    "fit_circles",
    "is_circular_sweep",
    "position_kin",
    "preprocess",
    "range_derivative",
    "segment",
    "shape_error",
]

_HALF_PI = 0.5 * math.pi
# alpha_min_first, alpha_min_last, alpha_max_first, alpha_max_last are measured
# towards the min beam for the first / previous beam and away from it for the
# last / next beam
_SWEEP_SIGNS = np.array([[-1.0], [1.0], [-1.0], [1.0]])


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class GeometricParams:
    """Parameters of the geometric detector, defaults from the paper.

    Attributes:
        r: radius of the kin's lidar housing, m (paper table 2: 0.035). Used in
            eq. 2 (``d_cest = min(d_i) + r``), eq. 3 (the diameter ``2r``),
            eq. 6 (known-radius circle) and eq. 7 (``r_c`` initial value).
        F_threshold: eq. 6 shape threshold, m. A segment passes the shape
            filter if ``F < F_threshold``. The paper's empirical 0.006 is for
            ``shape_metric="sum"``; if you switch to ``"mean"`` pick a
            threshold for the mean (e.g. 0.006 / typical point count).
        d_th: eq. 1 break threshold on ``|d_i - d_{i-1}|``, m. The paper gives
            no value; 0.1 m is chosen because every visible point of a circle
            of radius ``r`` lies between depth ``d_c - r`` and
            ``sqrt(d_c^2 - r^2)``, so two adjacent beams on one kin differ by
            less than ``r`` (3.5 cm) at any distance: 0.1 m (~3r) never splits
            a kin even with a few cm of range noise (RPLIDAR A1: < 1 % of
            distance), yet separates a kin from anything >= 10 cm behind it.
            Smaller values split grazing walls into more (harmless) segments;
            larger ones merge a kin with objects just behind it.
        d_max: maximum range, m (section 4.1, table 2: 12). Non-finite readings
            become ``d_max``; readings ``>= d_max`` are "no return" and belong
            to no segment.
        min_points: minimum beams on a segment for the shape fit (eq. 6). A
            known-radius circle has 2 parameters, so it passes exactly through
            any 2 points less than ``2r`` apart (F = 0): 3 is the smallest
            count for which ``F`` says anything about shape.
        noise_filter: in pre-processing (4.1), replace isolated one-beam
            spikes / dropouts (a jump of more than ``d_th`` away from both
            neighbours) by the 3-beam median; see :func:`preprocess`. The paper
            applies no filter (noise-free simulation), so off by default.
        shape_metric: ``"sum"`` (paper, eq. 6: ``F = sum_i |e_i|``) or
            ``"mean"`` (``F = mean_i |e_i|``, less dependent on distance
            through the number of points).
        occlusion_unbounded: on a side where the beam just outside the
            segment hit something *nearer* (``Segment.prev_nearer`` /
            ``next_nearer``), the object may continue hidden behind it, so the
            paper's ``omega_max`` half (eq. 5) is no bound there: use ``inf``.
            Set False for the paper's literal eq. 5, which rejects partly
            occluded kins when few beams are visible.
        lm_max_iter: iteration cap for the Levenberg-Marquardt fit.
    """

    r: float = 0.035
    F_threshold: float = 0.006
    d_th: float = 0.1
    d_max: float = 12.0
    min_points: int = 3
    noise_filter: bool = False
    shape_metric: Literal["sum", "mean"] = "sum"
    occlusion_unbounded: bool = True
    lm_max_iter: int = 200

    def __post_init__(self) -> None:
        for name in ("r", "F_threshold", "d_th", "d_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"GeometricParams.{name} must be a finite number > 0, got {v!r}")
        if self.d_th >= self.d_max:
            raise ValueError(
                f"GeometricParams.d_th must be < d_max, got d_th={self.d_th!r}, d_max={self.d_max!r}"
            )
        if isinstance(self.min_points, bool) or not isinstance(self.min_points, int):
            raise ValueError(f"GeometricParams.min_points must be an int, got {self.min_points!r}")
        if self.min_points < 2:
            raise ValueError(
                f"GeometricParams.min_points must be >= 2 (2-parameter circle fit), got {self.min_points}"
            )
        if self.shape_metric not in ("sum", "mean"):
            raise ValueError(
                f"GeometricParams.shape_metric must be 'sum' or 'mean', got {self.shape_metric!r}"
            )
        if isinstance(self.lm_max_iter, bool) or not isinstance(self.lm_max_iter, int):
            raise ValueError(f"GeometricParams.lm_max_iter must be an int, got {self.lm_max_iter!r}")
        if self.lm_max_iter < 1:
            raise ValueError(f"GeometricParams.lm_max_iter must be >= 1, got {self.lm_max_iter}")


# --------------------------------------------------------------------------- 4.1 pre-processing


def is_circular_sweep(angles) -> bool:
    """True if the beams cover a full turn, so the last beam neighbours the first.

    The seam step ``angles[0] - angles[-1]`` (wrapped) must turn the same way
    as the other steps and be no larger than 1.5x the largest of them; a
    270-degree lidar, say, has a 90-degree gap there and is not circular.
    """
    a = np.asarray(angles, dtype=np.float64)
    steps = wrap_angle(np.diff(a))
    seam = wrap_angle(float(a[0] - a[-1]))
    return bool(seam * steps[0] > 0 and abs(seam) <= 1.5 * float(np.abs(steps).max()) + 1e-12)


def preprocess(
    ranges,
    d_max: float = 12.0,
    noise_filter: bool = False,
    circular: bool = True,
    d_th: float = 0.1,
) -> np.ndarray:
    """Paper 4.1: clean a scan's ranges (m) before segmentation.

    Readings of 0.0 (the RPLIDAR's invalid reading) or below, and non-finite
    ones (inf = no return, NaN = failed reading) become ``d_max``; readings
    above ``d_max`` are clipped to it. Everything at
    ``d_max`` is then ignored by :func:`segment`.

    If ``noise_filter``, isolated beams - ones that jump away from *both*
    neighbours by more than ``d_th`` in the same direction (a one-beam spike,
    or a one-beam dropout inside an object) - are replaced by the median of
    themselves and their two neighbours (wrapping across the seam when
    ``circular``; the end beams of a non-circular scan have only one
    neighbour and are left alone). Other beams are untouched: a plain 3-beam
    median would flatten the apex of a kin (5 beams at 1 m), raise ``min(d_i)``
    and with it ``d_cest`` (eq. 2), and make true kins fail eq. 3.

    Returns a new float64 (n_beams,) array.
    """
    r = np.asarray(ranges, dtype=np.float64)
    # a real RPLIDAR reports 0.0 for an invalid reading: no return, like NaN and inf
    with np.errstate(invalid="ignore"):
        d = np.where(np.isfinite(r) & (r > 0.0), r, d_max)
    np.minimum(d, d_max, out=d)
    if noise_filter:
        if circular:
            a, c = np.roll(d, 1), np.roll(d, -1)
        else:
            a = np.concatenate((d[:1], d[:-1]))
            c = np.concatenate((d[1:], d[-1:]))
        up, down = d - a, d - c
        spike = ((up > d_th) & (down > d_th)) | ((up < -d_th) & (down < -d_th))
        # median of three without sorting: max(min(a, b), min(max(a, b), c))
        med = np.maximum(np.minimum(a, d), np.minimum(np.maximum(a, d), c))
        d = np.where(spike, med, d)
    return d


# --------------------------------------------------------------------------- 4.2 segmentation


def range_derivative(ranges, d_th: float = 0.1, circular: bool = True) -> np.ndarray:
    """Eq. 1: ``∂_i = d_i - d_{i-1}`` where ``|d_i - d_{i-1}| > d_th``, else 0 (m).

    ``∂_0`` compares beam 0 with the last beam when ``circular`` (the seam of a
    360-degree scan), and is 0 otherwise. ``∂_i < 0`` is a falling edge (beam
    ``i`` starts something nearer), ``∂_i > 0`` a rising edge (beam ``i - 1``
    ended something nearer).
    """
    d = np.asarray(ranges, dtype=np.float64)
    diff = np.empty_like(d)
    np.subtract(d[1:], d[:-1], out=diff[1:])
    diff[0] = d[0] - d[-1] if circular else 0.0
    diff[np.abs(diff) <= d_th] = 0.0
    return diff


class _Runs(NamedTuple):
    """All segments of one scan as arrays (K segments, P beams in segments).

    ``prev`` / ``next`` are -1 where there is no outside beam. ``beams`` is the
    concatenation of every segment's beam indices in scan order, segment k
    occupying ``beams[offsets[k]:offsets[k] + length[k]]``.
    """

    first: np.ndarray
    last: np.ndarray
    length: np.ndarray
    prev: np.ndarray
    next: np.ndarray
    prev_nearer: np.ndarray
    next_nearer: np.ndarray
    beams: np.ndarray
    offsets: np.ndarray
    seg_id: np.ndarray


def _runs(d: np.ndarray, d_th: float, d_max: float, circular: bool) -> _Runs:
    """Vectorised core of :func:`segment` (no per-beam Python)."""
    n = d.shape[0]
    valid = d < d_max
    # eq. 1 on ranges where "no return" sits 2 d_th above d_max, so that a change
    # between return and no return is always a break, even within d_th of d_max
    e = np.where(valid, d, d_max + 2.0 * d_th)
    diff = np.empty(n)
    np.subtract(e[1:], e[:-1], out=diff[1:])
    diff[0] = e[0] - e[-1] if circular else np.inf
    brk = np.abs(diff, out=diff) > d_th
    first = np.flatnonzero(valid & brk)
    if first.shape[0] == 0:
        if not valid.all():
            first = last = np.zeros(0, dtype=np.intp)
        else:  # circular ring without any break (round room): one segment
            first, last = np.zeros(1, dtype=np.intp), np.full(1, n - 1, dtype=np.intp)
    else:
        end = valid.copy()
        end[:-1] &= brk[1:]
        end[-1] &= brk[0]
        last = np.flatnonzero(end)
        if last[0] < first[0]:  # the last run wraps across the seam
            last = np.concatenate((last[1:], last[:1]))
    length = last - first
    length %= n
    length += 1
    if circular:
        prev = first - 1
        prev %= n
        nxt = last + 1
        nxt %= n
        if length.shape[0] == 1 and length[0] == n:  # a whole ring has no outside beams
            prev[0] = nxt[0] = -1
    else:
        prev = first - 1
        nxt = np.where(last < n - 1, last + 1, -1)
    # no return reads d_max > any segment range, so "nearer" implies a return
    prev_nearer = d[prev] < d[first]
    next_nearer = d[nxt] < d[last]
    if prev[0:1].tolist() == [-1] or nxt[-1:].tolist() == [-1]:
        prev_nearer &= prev >= 0
        next_nearer &= nxt >= 0
    offsets = np.cumsum(length)
    offsets -= length
    seg_id = np.repeat(np.arange(first.shape[0]), length)
    beams = np.arange(seg_id.shape[0])
    beams += (first - offsets)[seg_id]
    beams %= n
    return _Runs(first, last, length, prev, nxt, prev_nearer, next_nearer, beams, offsets, seg_id)


def _segments_from_runs(runs: _Runs) -> list[Segment]:
    beams, off, ln = runs.beams, runs.offsets.tolist(), runs.length.tolist()
    return [
        Segment(f, la, beams[o : o + k], p if p >= 0 else None, q if q >= 0 else None, pn, qn)
        for f, la, o, k, p, q, pn, qn in zip(
            runs.first.tolist(),
            runs.last.tolist(),
            off,
            ln,
            runs.prev.tolist(),
            runs.next.tolist(),
            runs.prev_nearer.tolist(),
            runs.next_nearer.tolist(),
            strict=True,
        )
    ]


def segment(ranges, *, d_th: float = 0.1, d_max: float = 12.0, circular: bool = True) -> list[Segment]:
    """Paper 4.2: point-distance-based segmentation of pre-processed ranges.

    A segment is a maximal run of consecutive beams with ranges ``< d_max``
    and no break of eq. 1 (``|∂_i| > d_th``) inside. This generalises the
    paper's "a falling edge and the next rising edge bound a segment" so that
    the usual cases come out right:

    * an isolated object: falling edge ... rising edge (the paper's case);
    * an object next to a *nearer* one (partly occluded, or two objects
      touching in angle at different depths): bounded by a rising or falling
      edge on that side; ``Segment.prev_nearer`` / ``next_nearer`` say so;
    * an object next to "no return" beams: the validity change is a break
      even if the range step is below ``d_th`` (object within ``d_th`` of
      ``d_max``);
    * the seam of a circular scan: a run crossing the last/first beam is one
      segment with ``first_beam > last_beam``.

    Background surfaces (e.g. a wall between two objects) are segments too;
    the filters reject them. Input must already be pre-processed (finite,
    ``<= d_max``). Segments are ordered by first beam index.
    """
    d = np.asarray(ranges, dtype=np.float64)
    return _segments_from_runs(_runs(d, d_th, d_max, circular))


# --------------------------------------------------------------------------- 4.3.1 diameter


@dataclass(frozen=True)
class DiameterCheck:
    """Result of :func:`filter_by_diameter` (eqs. 2-5), lengths in m, angles in rad.

    ``first``/``last`` name the segment's two sides by beam order; for the
    clockwise RPLIDAR they are the paper's left (``l``) and right (``r``).
    Angles are turned along the sweep from / to the min beam. An
    ``alpha_max_*`` of ``inf`` means that side is unbounded (no outside beam,
    or occluded with ``occlusion_unbounded``); a half-width whose angle is
    >= 90 degrees is infinite.
    """

    min_beam: int  #: beam with min(d_i)
    d_cest: float  #: eq. 2: min(d_i) + r
    alpha_min_first: float  #: angle from the first beam on the object to the min beam
    alpha_min_last: float  #: angle from the min beam to the last beam on the object
    alpha_max_first: float  #: angle from the beam before the first to the min beam
    alpha_max_last: float  #: angle from the min beam to the beam after the last
    omega_min: float  #: eq. 4: d_cest * (tan(alpha_min_first) + tan(alpha_min_last))
    omega_max: float  #: eq. 5: d_cest * (tan(alpha_max_first) + tan(alpha_max_last))
    diameter: float  #: 2r
    passed: bool  #: eq. 3: omega_min <= 2r < omega_max
    reason: str

    def metrics(self) -> dict[str, float]:
        return {"d_cest": self.d_cest, "omega_min": self.omega_min, "omega_max": self.omega_max}


class _Diameters(NamedTuple):
    min_beam: np.ndarray
    d_cest: np.ndarray
    alphas: np.ndarray  # (4, K): min_first, min_last, max_first, max_last
    omega_min: np.ndarray
    omega_max: np.ndarray
    passed: np.ndarray
    too_wide: np.ndarray


def _sweep_sign(angles: np.ndarray) -> float:
    """+1 if beam angles increase (CCW sweep), -1 if they decrease (CW, RPLIDAR)."""
    return 1.0 if math.remainder(float(angles[1] - angles[0]), 2.0 * math.pi) > 0 else -1.0


def _diameters(
    d: np.ndarray,
    angles: np.ndarray,
    runs: _Runs,
    r: float,
    occlusion_unbounded: bool,
    sweep: float,
) -> _Diameters:
    """Eqs. 2-5 for all segments of a scan at once (see :func:`filter_by_diameter`)."""
    n = d.shape[0]
    dv = d[runs.beams]
    mins = np.minimum.reduceat(dv, runs.offsets)
    # first beam (in scan order) holding the minimum, as np.argmin would pick
    pos = runs.beams - runs.first[runs.seg_id]
    pos %= n
    pos[dv != mins[runs.seg_id]] = n
    min_beam = runs.first + np.minimum.reduceat(pos, runs.offsets)
    min_beam %= n
    d_cest = mins + r  # eq. 2
    # angles turned along the sweep from the first / previous beam to the min
    # beam and from it to the last / next beam; measuring the short way instead
    # would make a segment spanning more than half a turn look narrow
    alphas = angles[np.stack((runs.first, runs.last, runs.prev, runs.next))]
    alphas -= angles[min_beam]
    alphas *= _SWEEP_SIGNS * sweep
    np.mod(alphas, 2.0 * math.pi, out=alphas)
    open_p, open_q = runs.prev < 0, runs.next < 0
    if occlusion_unbounded:
        open_p |= runs.prev_nearer
        open_q |= runs.next_nearer
    alphas[2, open_p] = np.inf
    alphas[3, open_q] = np.inf
    # half-widths d_cest * tan(alpha), infinite from 90 degrees on
    wide = alphas >= _HALF_PI
    halves = np.tan(np.where(wide, 0.0, alphas))
    halves *= d_cest
    halves[wide] = np.inf
    omega_min = halves[0] + halves[1]  # eq. 4
    omega_max = halves[2] + halves[3]  # eq. 5
    diameter = 2.0 * r
    too_wide = omega_min > diameter
    passed = diameter < omega_max  # eq. 3
    passed &= ~too_wide
    return _Diameters(min_beam, d_cest, alphas, omega_min, omega_max, passed, too_wide)


def _diameter_reason(passed: bool, too_wide: bool, omega_min, omega_max, diameter) -> str:
    if passed:
        return f"omega_min={omega_min:.4f} m <= 2r={diameter:.4f} m < omega_max={omega_max:.4f} m"
    if too_wide:
        return f"too wide: omega_min={omega_min:.4f} m > 2r={diameter:.4f} m"
    return f"too narrow: omega_max={omega_max:.4f} m <= 2r={diameter:.4f} m"


def filter_by_diameter(
    seg: Segment, ranges, angles, r: float = 0.035, occlusion_unbounded: bool = True
) -> DiameterCheck:
    """Paper 4.3.1, eqs. 2-5: does the segment's width fit a circle of radius ``r``?

    ``d_cest = min(d_i) + r`` (eq. 2) estimates the distance to the centre.
    ``omega_min`` (eq. 4) is the width spanned by the first and last beams on
    the object, ``omega_max`` (eq. 5) the width spanned by the beams just
    outside it, each as ``d_cest * tan(alpha)`` on either side of the min
    beam. The segment passes if ``omega_min <= 2r < omega_max`` (eq. 3).

    Args:
        seg: a segment from :func:`segment`.
        ranges: (n,) pre-processed ranges, m.
        angles: (n,) beam angles, rad.
        r: kin radius, m.
        occlusion_unbounded: see :attr:`GeometricParams.occlusion_unbounded`.
    """
    d = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    one = np.zeros(1, dtype=np.intp)
    runs = _Runs(
        np.array([seg.first_beam]),
        np.array([seg.last_beam]),
        np.array([seg.n_beams]),
        np.array([-1 if seg.prev_beam is None else seg.prev_beam]),
        np.array([-1 if seg.next_beam is None else seg.next_beam]),
        np.array([seg.prev_nearer]),
        np.array([seg.next_nearer]),
        np.asarray(seg.beams),
        one,
        np.zeros(seg.n_beams, dtype=np.intp),
    )
    res = _diameters(d, a, runs, r, occlusion_unbounded, _sweep_sign(a))
    omega_min, omega_max = float(res.omega_min[0]), float(res.omega_max[0])
    passed, too_wide = bool(res.passed[0]), bool(res.too_wide[0])
    return DiameterCheck(
        int(res.min_beam[0]),
        float(res.d_cest[0]),
        *res.alphas[:, 0].tolist(),
        omega_min,
        omega_max,
        2.0 * r,
        passed,
        _diameter_reason(passed, too_wide, omega_min, omega_max, 2.0 * r),
    )


# --------------------------------------------------------------------------- 4.3.2 shape


def circle_residuals(r_c: float, theta_c: float, ranges_pts, angles_pts, r: float = 0.035):
    """Eq. 6 terms: ``e_i = sqrt(r_i^2 + r_c^2 - 2 r_i r_c cos(theta_i - theta_c)) - r``.

    Signed distance (m) of each point ``(r_i, theta_i)`` from the circle of
    radius ``r`` centred at polar ``(r_c, theta_c)``: > 0 outside, < 0 inside.
    """
    ri = np.asarray(ranges_pts, dtype=np.float64)
    ti = np.asarray(angles_pts, dtype=np.float64)
    d2 = ri * ri + r_c * r_c - 2.0 * ri * r_c * np.cos(ti - theta_c)
    return np.sqrt(np.maximum(d2, 0.0)) - r


def shape_error(residuals, metric: Literal["sum", "mean"] = "sum") -> float:
    """The thresholded shape error ``F`` (m): ``sum_i |e_i|`` (paper) or its mean."""
    e = np.abs(np.asarray(residuals, dtype=np.float64))
    return float(e.sum() if metric == "sum" else e.mean())


@dataclass(frozen=True, eq=False)
class CircleFit:
    """Known-radius circle fitted by :func:`fit_circle`.

    ``(r_c, theta_c)`` is the centre in polar coordinates (m, rad CCW, theta_c
    wrapped to (-pi, pi]); ``residuals`` are the eq. 6 terms ``e_i`` at the
    solution; ``cost = sum_i e_i^2`` is what Levenberg-Marquardt minimised.
    """

    r_c: float
    theta_c: float
    residuals: np.ndarray
    cost: float
    n_iter: int
    converged: bool


# Levenberg-Marquardt constants shared by the vectorised and the scalar fit, so
# both follow exactly the same iteration.
_LM_LAMBDA0 = 1e-3  # initial damping, relative to the diagonal of J^T J
_LM_LAMBDA_MAX = 1e16  # damping so large that no step can matter: stop
_LM_XTOL = 1e-9  # stop when the step is below xtol * r_c (1 nm at 1 m)
# Below this many segments the plain-Python fit is faster than the vectorised one
# (numpy's per-call overhead dominates small arrays); measured crossover.
_VECTORISE_MIN_SEGMENTS = 32


def fit_circles(
    ranges_pts,
    angles_pts,
    counts,
    r: float,
    r_c0,
    theta_c0,
    *,
    max_iter: int = 200,
    xtol: float = _LM_XTOL,
):
    """Vectorised Levenberg-Marquardt fit of many known-radius circles at once.

    Minimises, for each segment independently, ``sum_i e_i(r_c, theta_c)^2``
    with ``e_i`` the eq. 6 residual (:func:`circle_residuals`), over the polar
    centre ``(r_c, theta_c)``. All segments iterate together on flat arrays,
    converged ones are frozen; the cost per iteration is nearly independent of
    the number of segments, so this is the fast path for many segments (e.g.
    a batch of scans). :func:`fit_circle` runs the identical iteration in
    plain Python, which is faster for a handful of segments.

    Algorithm: Marquardt's ``(J^T J + lam * D) delta = -J^T e`` with ``D``
    the running maximum of ``diag(J^T J)`` (MINPACK's scaling). A step is
    accepted if it lowers the cost; the damping follows Nielsen's rule (Madsen,
    Nielsen & Tingleff 2004): with ``rho`` = actual / predicted cost
    reduction, ``lam *= max(1/3, 1 - (2 rho - 1)^3)`` after an accepted step,
    ``lam *= nu; nu *= 2`` after a rejected one. (Plain x0.1 / x10 zig-zags
    across the narrow valleys of non-circular segments for hundreds of
    iterations.) A segment stops when its step is below ``xtol * r_c`` (m,
    with the angle step scaled by ``r_c``) or ``lam`` exceeds 1e16.

    Args:
        ranges_pts, angles_pts: (P,) points of all segments, concatenated
            (m, rad).
        counts: (S,) points per segment (each >= 1), summing to P.
        r: known radius, m.
        r_c0, theta_c0: (S,) initial centres (eq. 7: ``min(d_i) + r`` and the
            angle of the min-range point).
        max_iter: iteration cap.
        xtol: relative step tolerance.

    Returns:
        ``(r_c, theta_c, residuals, n_iter, converged)``: (S,) m, (S,) rad
        wrapped to (-pi, pi], (P,) eq. 6 residuals at the solution (m), (S,)
        iterations, (S,) bool (False = hit ``max_iter``).
    """
    ri = np.asarray(ranges_pts, dtype=np.float64)
    ti = np.asarray(angles_pts, dtype=np.float64)
    cnt = np.asarray(counts, dtype=np.intp)
    n_seg, n_pts = cnt.shape[0], ri.shape[0]
    seg = np.repeat(np.arange(n_seg), cnt)
    if n_seg == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.intp), np.ones(0, bool)
    if cnt.min() < 1 or cnt.sum() != n_pts:
        raise ValueError(f"counts must be >= 1 and sum to the {n_pts} points, got {cnt.tolist()}")
    offsets = np.concatenate(([0], np.cumsum(cnt[:-1])))
    z = ri * np.exp(1j * ti)  # points as complex numbers x + iy
    rc = np.array(r_c0, dtype=np.float64).reshape(n_seg)
    tc = np.array(theta_c0, dtype=np.float64).reshape(n_seg)

    def evaluate(rc, tc):
        # Rotating the points by -theta_c puts the centre at (r_c, 0); with
        # q = rotated point - centre: e = |q| - r, de/dr_c = -Re q/|q|,
        # de/dtheta_c = -r_c Im q/|q|. Rows of B: de/dr_c, de/dtheta_c, e.
        # G holds the 3x3 products of those rows summed per segment, i.e.
        # J^T J (0, 1, 4), J^T e (2, 5) and the cost sum e^2 (8).
        rcs = rc[seg]
        q = z * np.exp(-1j * tc)[seg]
        q -= rcs
        nd = np.abs(q)
        np.negative(nd, out=nd)
        b = np.empty((3, n_pts))
        np.divide(q.real, nd, out=b[0])
        np.multiply(rcs, q.imag, out=b[1])
        b[1] /= nd
        np.subtract(-r, nd, out=b[2])
        g = np.add.reduceat((b[:, None, :] * b[None, :, :]).reshape(9, n_pts), offsets, axis=1)
        return b, g

    b, g = evaluate(rc, tc)
    lam = np.full(n_seg, _LM_LAMBDA0)
    nu = np.full(n_seg, 2.0)
    s1, s2 = g[0].copy(), g[4].copy()
    n_iter = np.zeros(n_seg, dtype=np.intp)
    active = np.ones(n_seg, dtype=bool)
    tol2 = (xtol * rc) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(max_iter):
            a11, a12, g1, a22, g2 = g[0], g[1], g[2], g[4], g[5]
            np.maximum(s1, a11, out=s1)
            np.maximum(s2, a22, out=s2)
            m11 = a11 + lam * s1
            m22 = a22 + lam * s2
            det = m11 * m22 - a12 * a12
            drc = (a12 * g2 - m22 * g1) / det
            dtc = (a12 * g1 - m11 * g2) / det
            # a degenerate system (det <= 0, NaN step) counts as converged
            done = ~(drc * drc + np.square(dtc * rc) > tol2)
            n_iter += active
            new_rc = rc + drc
            new_tc = tc + dtc
            new_b, new_g = evaluate(new_rc, new_tc)
            gain = g[8] - new_g[8]
            accept = gain > 0.0
            accept &= active
            accept &= ~done
            rho = gain / (drc * (lam * s1 * drc - g1) + dtc * (lam * s2 * dtc - g2))
            down = np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            reject = active & ~accept  # finished segments keep their lam and nu
            lam *= np.where(accept, down, np.where(reject, nu, 1.0))
            nu = np.where(accept, 2.0, np.where(reject, 2.0 * nu, nu))
            np.copyto(rc, new_rc, where=accept)
            np.copyto(tc, new_tc, where=accept)
            np.copyto(g, new_g, where=accept)
            np.copyto(b, new_b, where=accept[seg])
            active &= ~done
            active &= lam <= _LM_LAMBDA_MAX
            if not active.any():
                break
    converged = ~active
    return rc, wrap_angle(tc), b[2].copy(), n_iter, converged


def _lm_scalar(ri: list, ti: list, r: float, rc: float, tc: float, max_iter: int, xtol: float):
    """:func:`fit_circles`' iteration for one segment in plain Python floats.

    Returns ``(r_c, theta_c, n_iter, converged, sum_abs_e)``; theta_c is not
    wrapped; ``sum_abs_e`` is ``sum_i |e_i|`` at the returned centre.
    """
    cos, sin, hypot = math.cos, math.sin, math.hypot
    pts = list(zip(ri, ti, strict=True))

    def evaluate(rc, tc):
        a11 = a12 = a22 = g1 = g2 = cost = sabs = 0.0
        for rr, tt in pts:
            dt = tt - tc
            qx = rr * cos(dt) - rc
            qy = rr * sin(dt)
            nd = -hypot(qx, qy)
            e = -nd - r
            jr = qx / nd
            jt = rc * qy / nd
            a11 += jr * jr
            a12 += jr * jt
            a22 += jt * jt
            g1 += jr * e
            g2 += jt * e
            cost += e * e
            sabs += abs(e)
        return a11, a12, a22, g1, g2, cost, sabs

    a11, a12, a22, g1, g2, cost, sabs = evaluate(rc, tc)
    lam, nu, s1, s2 = _LM_LAMBDA0, 2.0, a11, a22
    tol2 = (xtol * rc) ** 2
    for it in range(1, max_iter + 1):
        s1 = max(s1, a11)
        s2 = max(s2, a22)
        m11 = a11 + lam * s1
        m22 = a22 + lam * s2
        det = m11 * m22 - a12 * a12
        if not det > 0.0:
            return rc, tc, it, True, sabs
        drc = (a12 * g2 - m22 * g1) / det
        dtc = (a12 * g1 - m11 * g2) / det
        if not drc * drc + (dtc * rc) ** 2 > tol2:
            return rc, tc, it, True, sabs
        new = evaluate(rc + drc, tc + dtc)
        gain = cost - new[5]
        if gain > 0.0:
            rho = gain / (drc * (lam * s1 * drc - g1) + dtc * (lam * s2 * dtc - g2))
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            rc, tc = rc + drc, tc + dtc
            a11, a12, a22, g1, g2, cost, sabs = new
        else:
            lam *= nu
            nu *= 2.0
            if lam > _LM_LAMBDA_MAX:
                return rc, tc, it, True, sabs
    return rc, tc, max_iter, False, sabs


def fit_circle(
    ranges_pts,
    angles_pts,
    r: float = 0.035,
    r_c0: float | None = None,
    theta_c0: float | None = None,
    *,
    max_iter: int = 200,
    xtol: float = _LM_XTOL,
) -> CircleFit:
    """Fit a circle of known radius ``r`` to one segment's points (paper eqs. 6-7).

    Minimised: ``sum_i e_i^2`` with ``e_i`` from :func:`circle_residuals`,
    over the polar centre ``(r_c, theta_c)``, by Levenberg-Marquardt (same
    iteration as :func:`fit_circles`) started at eq. 7, ``r_c = min(r_i) +
    r``, and ``theta_c`` = angle of the min-range point (override with
    ``r_c0`` / ``theta_c0``). What the paper thresholds, ``F = sum |e_i|``,
    is computed from the residuals by :func:`shape_error`.

    Args:
        ranges_pts: (k,) ranges of the segment's points, m, k >= 2.
        angles_pts: (k,) their beam angles, rad.
        r: known radius, m.
    """
    ri = np.asarray(ranges_pts, dtype=np.float64).reshape(-1)
    ti = np.asarray(angles_pts, dtype=np.float64).reshape(-1)
    if ri.shape != ti.shape:
        raise ValueError(
            f"ranges_pts and angles_pts must have the same length, got {ri.shape[0]} and {ti.shape[0]}"
        )
    if ri.shape[0] < 2:
        raise ValueError(f"fit_circle needs at least 2 points, got {ri.shape[0]}")
    if not (np.isfinite(ri).all() and np.isfinite(ti).all()):
        raise ValueError("fit_circle needs finite ranges_pts and angles_pts")
    k = int(ri.argmin())
    rc0 = float(ri[k] + r if r_c0 is None else r_c0)
    tc0 = float(ti[k] if theta_c0 is None else theta_c0)
    rc, tc, it, conv, _ = _lm_scalar(ri.tolist(), ti.tolist(), r, rc0, tc0, max_iter, xtol)
    e = circle_residuals(rc, tc, ri, ti, r)
    return CircleFit(rc, wrap_angle(tc), e, float(e @ e), it, conv)


@dataclass(frozen=True, eq=False)
class ShapeCheck:
    """Result of :func:`filter_by_shape`: the fit, ``F`` and the decision."""

    fit: CircleFit
    F: float  #: shape error in m (sum or mean of |e_i|, see ``metric``)
    threshold: float
    metric: str
    passed: bool  #: F < threshold
    reason: str

    def metrics(self) -> dict[str, float]:
        return {"F": self.F, "r_c": self.fit.r_c, "theta_c": self.fit.theta_c}


def _shape_decision(F: float, threshold: float, metric: str) -> tuple[bool, str]:
    if F < threshold:
        return True, f"circle fit: F={F:.5f} m < {threshold:.5f} m ({metric} |e_i|)"
    return False, f"not circular: F={F:.5f} m >= {threshold:.5f} m ({metric} |e_i|)"


def filter_by_shape(
    seg: Segment,
    ranges,
    angles,
    r: float = 0.035,
    F_threshold: float = 0.006,
    metric: Literal["sum", "mean"] = "sum",
) -> ShapeCheck:
    """Paper 4.3.2: fit a radius-``r`` circle to the segment and threshold ``F``.

    The fit minimises ``sum e_i^2`` (:func:`fit_circle`); the decision uses
    ``F = sum_i |e_i|`` (paper) or ``mean_i |e_i|`` and passes if
    ``F < F_threshold``.
    """
    b = seg.beams
    fit = fit_circle(np.asarray(ranges)[b], np.asarray(angles)[b], r)
    F = shape_error(fit.residuals, metric)
    passed, reason = _shape_decision(F, F_threshold, metric)
    return ShapeCheck(fit, F, F_threshold, metric, passed, reason)


# --------------------------------------------------------------------------- 4.4 positioning


class KinPosition(NamedTuple):
    """Kin centre in the observer frame: m, rad (CCW, (-pi, pi]), m forward, m left."""

    range: float
    bearing: float
    x: float
    y: float


def position_kin(r_c: float, theta_c: float) -> KinPosition:
    """Paper 4.4: the fitted centre ``(r_c, theta_c)`` as range, bearing, x, y."""
    b = wrap_angle(float(theta_c))
    return KinPosition(float(r_c), b, r_c * math.cos(b), r_c * math.sin(b))


# --------------------------------------------------------------------------- detector


class GeometricKinDetector(KinDetector):
    """The paper's detector: pre-process, segment, diameter filter, shape filter.

    ``detect`` returns the accepted kins plus one :class:`SegmentReport` per
    segment with the stage that rejected it (``"diameter"``,
    ``"too_few_points"``, ``"shape"``) or ``"accepted"``, and the stage numbers
    (``d_cest``, ``omega_min``, ``omega_max``, ``F``, ``r_c``, ``theta_c``).
    ``Detection.score`` is ``F_threshold / (F_threshold + F)``: higher = more
    circle-like, ``>= 0.5`` exactly when the shape filter passes.

    :meth:`detect_arrays` is the fast path: every stage of every scan of a batch
    runs in compiled code and the result is a :class:`BatchDetections` of flat
    arrays; :meth:`detect_batch` / :meth:`detect` build the Python objects from
    it, and :meth:`results` turns any :class:`BatchDetections` of this detector
    into them (reports included) on demand.

    Args:
        params: detector parameters (paper defaults).
        reports: build the per-segment reports in ``detect`` / ``detect_batch``.
            Cluttered scans have ~100 segments (mostly 1-2 beam fragments), and
            their Python report objects cost far more than the detection
            itself; pass False when only ``detections`` are needed
            (``reports`` is then empty).

    The same stages are available one segment at a time, in numpy, as
    :func:`segment`, :func:`filter_by_diameter` and :func:`filter_by_shape`.
    """

    def __init__(self, params: GeometricParams | None = None, *, reports: bool = True) -> None:
        self.params = GeometricParams() if params is None else params
        if not isinstance(self.params, GeometricParams):
            raise TypeError(f"params must be a GeometricParams, got {type(self.params).__name__}")
        self.reports = bool(reports)
        self._angles_key: np.ndarray | None = None
        self._angles_src: np.ndarray | None = None
        self._circular = True
        self._sweep = -1.0

    def _check_batch(self, ranges, angles, trusted: bool = False) -> tuple[np.ndarray, np.ndarray]:
        if trusted and (rb := trusted_ranges(ranges, angles, self._angles_src)) is not None:
            return rb, angles
        rb, a = validate_batch(ranges, angles)
        # Validating the sweep costs as much as detecting a small scan, so the
        # last beam layout seen is remembered; ranges are always checked.
        key = self._angles_key
        if key is None or key.shape != a.shape or not np.array_equal(key, a):
            validate_scan(np.zeros(a.shape), a)
            self._circular = is_circular_sweep(a)
            self._sweep = _sweep_sign(a)
            self._angles_key = a.copy()
        _check_negative_rows(rb, a)
        if trusted:
            self._angles_src = angles  # the caller's (never mutated) layout array, checked above
        return rb, a

    def detect_arrays(self, ranges, angles) -> BatchDetections:
        """Detect kins in ``B`` scans (``ranges`` (B, n) m, shared ``angles`` (n,) rad) → arrays.

        0.0, NaN and inf readings are no return; a negative range raises ``ValueError`` naming
        its scan row and beam.
        """
        return self._detect_arrays(ranges, angles, False)

    def _detect_arrays_trusted(self, ranges, angles) -> BatchDetections:
        """:meth:`detect_arrays` without the per-call input checks, for callers that guarantee
        their input (internal; the envs): see
        :meth:`detectors.learned.LearnedKinDetector._detect_arrays_trusted`. Outputs are identical."""
        return self._detect_arrays(ranges, angles, True)

    def _detect_table_trusted(self, ranges, angles) -> tuple[np.ndarray, np.ndarray]:
        """The detections of :meth:`_detect_arrays_trusted` (same input contract) as ``(scan row (D,) int64,
        table (D, 8) float64)``, the columns ``range, bearing, x, y, score, first_beam, last_beam, n_beams``:
        what ``kin_envs.envs.common.detection_arrays`` reads (as the learned detector's entry of that name),
        without a :class:`~detectors.base.BatchDetections` and the ~25 numpy calls that build it and stack
        it back into a table. The same values (``x``, ``y``: numpy's ``cos`` / ``sin`` of the same contiguous
        bearings, times the same ranges); fresh arrays on every call."""
        # the stages of _stages and the gather in one compiled call (for one scan, the ~12 allocations and
        # four calls from Python cost about as much as the scan's detection, measured)
        row, table, rc, bearing = _detect_table(*self._table_args(ranges, angles))
        return _table_xy(row, table, rc, bearing)

    def _table_args(self, ranges, angles) -> tuple:
        """The compiled table calls' arguments: the checked scans and this detector's parameters."""
        rb, a = self._check_batch(ranges, angles, True)
        p = self.params
        return (np.ascontiguousarray(rb), np.ascontiguousarray(a), float(p.d_max), float(p.d_th),
                self._circular, p.noise_filter, self._sweep, float(p.r), float(p.F_threshold),
                p.shape_metric == "mean", p.occlusion_unbounded, p.min_points, p.lm_max_iter, _LM_XTOL,
                _LM_LAMBDA0, _LM_LAMBDA_MAX)  # fmt: skip

    def _detect_table_feed_trusted(self, ranges, angles, F_keep: float) -> tuple[tuple, tuple]:
        """:meth:`_detect_table_trusted` (same input contract) and, from the same compiled call, every segment
        whose circle fit reached ``F`` < ``F_keep`` (>= ``F_threshold``; stage ``ACCEPTED`` or ``SHAPE``),
        in segment order: ``((row, table), (scan row, first beam, beam count, F, r_c, theta_c, accepted),
        d)``, the values of :meth:`_detect_arrays_trusted`'s ``seg_*`` arrays and ``seg_values`` at those
        segments bit for bit (the envs' permissive feed: :class:`kin_envs.envs.tracks.PermissiveFeed`, without
        a :class:`~detectors.base.BatchDetections` of every segment); ``d`` the preprocessed scans (B, n)."""
        args = (*self._table_args(ranges, angles), float(F_keep))
        row, table, rc, bearing, feed, d = _detect_table_feed(*args)
        return _table_xy(row, table, rc, bearing), feed, d

    def _stages(self, ranges, angles, trusted: bool):
        """Segments and stages of every segment: ``(ranges, angles, segments (scan, first, count, prev, next,
        prev_nearer, next_nearer), stage (S,), values {d_cest, omega_min, omega_max, F, r_c, theta_c})``."""
        rb, a = self._check_batch(ranges, angles, trusted)
        rb, a = np.ascontiguousarray(rb), np.ascontiguousarray(a)  # one compiled signature
        p = self.params
        d = np.empty(rb.shape)
        d_max, d_th = float(p.d_max), float(p.d_th)  # ints would compile another signature
        _k.preprocess_rows(rb, d_max, d_th, self._circular, p.noise_filter, d)
        seg = _k.segment_arrays(d, d_th, d_max, self._circular)
        S = seg[0].shape[0]
        stage = np.empty(S, dtype=np.int8)
        min_beam = np.empty(S, dtype=np.int64)
        vals = {k: np.empty(S) for k in ("d_cest", "omega_min", "omega_max", "F", "r_c", "theta_c")}
        _k.geometric_segments(
            d,
            a,
            self._sweep,
            *seg,
            float(p.r),
            float(p.F_threshold),
            p.shape_metric == "mean",
            p.occlusion_unbounded,
            p.min_points,
            p.lm_max_iter,
            _LM_XTOL,
            _LM_LAMBDA0,
            _LM_LAMBDA_MAX,
            stage,
            min_beam,
            *vals.values(),
        )
        return rb, a, seg, stage, vals

    def _detect_arrays(self, ranges, angles, trusted: bool) -> BatchDetections:
        rb, a, seg, stage, vals = self._stages(ranges, angles, trusted)
        p = self.params
        idx = np.flatnonzero(stage == _k.ACCEPTED)
        rc, bearing, F = vals["r_c"][idx], vals["theta_c"][idx], vals["F"][idx]
        first, count = seg[1][idx], seg[2][idx]
        n = a.shape[0]
        return BatchDetections(
            n_scans=rb.shape[0],
            n_beams=n,
            scan=seg[0][idx],
            range=rc,
            bearing=bearing,
            x=rc * np.cos(bearing),
            y=rc * np.sin(bearing),
            score=p.F_threshold / (p.F_threshold + F),
            first_beam=first,
            last_beam=(first + count - 1) % n,
            n_beams_on=count,
            segment=idx,
            seg_scan=seg[0],
            seg_first=seg[1],
            seg_count=seg[2],
            seg_prev=seg[3],
            seg_next=seg[4],
            seg_prev_nearer=seg[5],
            seg_next_nearer=seg[6],
            seg_stage=stage,
            seg_values=vals,
        )

    def results(self, arrays: BatchDetections, reports: bool | None = None) -> list[DetectionResult]:
        """:class:`DetectionResult` per scan of ``arrays`` (from :meth:`detect_arrays`), with
        readable per-segment reports if ``reports`` (default: this detector's ``reports``), built
        on first access."""
        reports = self.reports if reports is None else bool(reports)
        dets = arrays.detections()
        if not reports:
            return [DetectionResult(ds, []) for ds in dets]
        build = LazyBatchReports(lambda: self.segment_reports(arrays))
        return [DetectionResult.lazy(ds, build, b) for b, ds in enumerate(dets)]

    def segment_reports(self, arrays: BatchDetections) -> list[list[SegmentReport]]:
        """The readable :class:`SegmentReport` of every segment of ``arrays``, per scan: stage,
        reason string and the stage numbers."""
        p = self.params
        diameter = 2.0 * p.r
        v = {k: a.tolist() for k, a in arrays.seg_values.items()}
        reps = []
        for k, (sg, code, n) in enumerate(
            zip(arrays.segments(), arrays.seg_stage.tolist(), arrays.seg_count.tolist(), strict=True)
        ):
            m = {"d_cest": v["d_cest"][k], "omega_min": v["omega_min"][k], "omega_max": v["omega_max"][k]}
            if code in (_k.ACCEPTED, _k.SHAPE):
                m.update(F=v["F"][k], r_c=v["r_c"][k], theta_c=v["theta_c"][k])
                reason = _shape_decision(m["F"], p.F_threshold, p.shape_metric)[1]
            elif code == _k.TOO_FEW_POINTS:
                reason = f"{n} beams < min_points={p.min_points} for the circle fit"
            else:
                reason = _diameter_reason(
                    False, m["omega_min"] > diameter, m["omega_min"], m["omega_max"], diameter
                )
            reps.append(SegmentReport(sg, STAGES[code], reason, m))
        bounds = np.searchsorted(arrays.seg_scan, np.arange(arrays.n_scans + 1)).tolist()
        return [reps[bounds[b] : bounds[b + 1]] for b in range(arrays.n_scans)]

    def detect(self, ranges, angles) -> DetectionResult:
        """Detect kins in one scan (``ranges`` (n,) m, ``angles`` (n,) rad)."""
        r = np.asarray(ranges, dtype=np.float64)
        a = np.asarray(angles, dtype=np.float64)
        if r.ndim != 1 or a.ndim != 1 or r.shape != a.shape or (r < 0.0).any():
            validate_scan(r, a)  # raises with the full message
        return self.results(self.detect_arrays(r[None, :], a))[0]

    def detect_batch(self, ranges, angles) -> list[DetectionResult]:
        """Detect kins in ``B`` scans (``ranges`` (B, n) m, shared ``angles`` (n,) rad): the
        objects of :meth:`detect_arrays`, one :class:`DetectionResult` per scan, same as
        :meth:`detect` per row."""
        return self.results(self.detect_arrays(ranges, angles))


def _table_xy(row, table, rc, bearing) -> tuple[np.ndarray, np.ndarray]:
    """``(row, table)`` with the table's ``x, y`` columns filled: numpy's ``cos`` / ``sin`` of the contiguous
    bearings times the ranges (the values :meth:`GeometricKinDetector._detect_arrays_trusted` gives)."""
    if row.shape[0]:
        np.multiply(rc, np.cos(bearing), out=table[:, 2])
        np.multiply(rc, np.sin(bearing), out=table[:, 3])
    return row, table


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _segmented(rb, d_max, d_th, circular, noise_filter):
    """The preprocessed scans ``d`` and their segments (:func:`detectors._kernels._segment_views`)."""
    d = np.empty(rb.shape)
    _k.preprocess_rows(rb, d_max, d_th, circular, noise_filter, d)
    scan, first, count, prev, nxt, p_near, n_near = _k._segment_views(d, d_th, d_max, circular)
    return d, scan, first, count, prev, nxt, p_near, n_near


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _detect_table(rb, a, d_max, d_th, circular, noise_filter, sweep, r, F_threshold, mean_metric,
                  occlusion_unbounded, min_points, lm_max_iter, xtol, lam0, lam_max):  # fmt: skip
    """:meth:`GeometricKinDetector._stages` (the same compiled stages on the same arguments, the shape
    stage only for the segments that can be accepted: :func:`detectors._kernels.accepted_segments`) then
    :func:`_accepted_table`, in one call."""
    d, scan, first, count, prev, nxt, p_near, n_near = _segmented(rb, d_max, d_th, circular, noise_filter)
    S = scan.shape[0]
    accepted = np.empty(S, dtype=np.bool_)
    F = np.empty(S)
    r_c = np.empty(S)
    theta_c = np.empty(S)
    _k.accepted_segments(
        d, a, sweep, scan, first, count, prev, nxt, p_near, n_near, r, F_threshold, mean_metric,
        occlusion_unbounded, min_points, lm_max_iter, xtol, lam0, lam_max, accepted, F, r_c, theta_c,
    )  # fmt: skip
    return _accepted_table(accepted, scan, first, count, r_c, theta_c, F, F_threshold, a.shape[0])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _detect_table_feed(rb, a, d_max, d_th, circular, noise_filter, sweep, r, F_threshold, mean_metric,
                       occlusion_unbounded, min_points, lm_max_iter, xtol, lam0, lam_max,
                       F_keep):  # fmt: skip
    """:func:`_detect_table` and the segments whose fit reached ``F < F_keep``
    (:meth:`GeometricKinDetector._detect_table_feed_trusted`), in one call."""
    d, scan, first, count, prev, nxt, p_near, n_near = _segmented(rb, d_max, d_th, circular, noise_filter)
    S = scan.shape[0]
    accepted = np.empty(S, dtype=np.bool_)
    kept = np.empty(S, dtype=np.bool_)
    F = np.empty(S)
    r_c = np.empty(S)
    theta_c = np.empty(S)
    _k.fitted_segments(
        d, a, sweep, scan, first, count, prev, nxt, p_near, n_near, r, F_threshold, F_keep, mean_metric,
        occlusion_unbounded, min_points, lm_max_iter, xtol, lam0, lam_max, accepted, kept, F, r_c, theta_c,
    )  # fmt: skip
    row, table, rc, bearing = _accepted_table(accepted, scan, first, count, r_c, theta_c, F, F_threshold,
                                              a.shape[0])  # fmt: skip
    m = 0
    for i in range(S):
        m += kept[i]
    f_row, f_first, f_count = np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64)
    f_F, f_rc, f_theta, f_acc = np.empty(m), np.empty(m), np.empty(m), np.empty(m, np.bool_)
    k = 0
    for i in range(S):
        if kept[i]:
            f_row[k], f_first[k], f_count[k] = scan[i], first[i], count[i]
            f_F[k], f_rc[k], f_theta[k], f_acc[k] = F[i], r_c[i], theta_c[i], accepted[i]
            k += 1
    return row, table, rc, bearing, (f_row, f_first, f_count, f_F, f_rc, f_theta, f_acc), d


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _accepted_table(accepted, scan, first, count, r_c, theta_c, F, F_threshold, n):
    """:meth:`GeometricKinDetector._detect_table_trusted`'s gather of the accepted segments, in segment order:
    ``(scan row (D,), table (D, 8): range, bearing, (x, y left for the caller), score, first_beam, last_beam,
    n_beams; the ranges (D,) and bearings (D,) as contiguous arrays)``, each value the expression
    :meth:`GeometricKinDetector._detect_arrays` evaluates in numpy (the same IEEE operations)."""
    n_det = 0
    for i in range(accepted.shape[0]):
        n_det += accepted[i]
    row = np.empty(n_det, dtype=np.int64)
    table = np.empty((n_det, 8))
    rc = np.empty(n_det)
    bearing = np.empty(n_det)
    k = 0
    for i in range(accepted.shape[0]):
        if not accepted[i]:
            continue
        row[k] = scan[i]
        rc[k] = table[k, 0] = r_c[i]
        bearing[k] = table[k, 1] = theta_c[i]
        table[k, 4] = F_threshold / (F_threshold + F[i])
        table[k, 5] = first[i]
        table[k, 6] = (first[i] + count[i] - 1) % n
        table[k, 7] = count[i]
        k += 1
    return row, table, rc, bearing


def _check_negative_rows(rb: np.ndarray, a: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first scan row with a negative range (NaN passes)."""
    bad = rb < 0.0
    if bad.any():
        b = int(np.flatnonzero(bad.any(axis=1))[0])
        try:
            validate_scan(rb[b], a)
        except ValueError as e:
            raise ValueError(f"ranges[{b}]: {e}") from None
