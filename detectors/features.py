"""Segment representation of the learned kin classifier (numpy only, no torch).

The learned detector keeps the paper's segmentation (:func:`detectors.geometric.segment`, the very
function the geometric detector calls) and replaces only the classification stage. Each segment is
turned into a fixed-length vector of :func:`feature_names` (``FEATURE_VERSION`` names the layout;
checkpoints store it and refuse another):

* **shape**: the segment's points in a *local frame*, resampled to ``n_points`` points by linear
  interpolation along the beam order. The frame is centred on the points' centroid with ``u``
  pointing away from the observer along the centroid's bearing and ``v`` along the scan's sweep,
  so the representation does not depend on where around the robot the object is, yet keeps the
  absolute scale (a kin is always 7 cm wide) and the side the observer sees (a circle bulges
  towards it);
* **context**: ``n_context`` beams on each side, as range differences from the segment's end beam
  (clipped to +-0.5 m; no return reads +0.5): occlusion by nearer objects versus free space or a
  distant background;
* **the paper's geometric features** (eqs. 2-7): number of beams, ``min(d_i)`` (``d_cest - r``),
  ``omega_min``, ``omega_max`` and whether eq. 3 holds, the chord width, the known-radius circle
  fit (``F`` at the eq. 7 start and after a few Gauss-Newton steps, residual statistics, fitted
  centre offsets), plus a free-radius (Kasa) curvature and a straight-line residual;
* **scan noise**: the scan's relative range noise estimated from all its beams (:func:`scan_noise`),
  without which residuals are ambiguous (a noise-free prism fits a circle as badly as a noisy kin);
* **residual profile**: the circle fit's signed residuals, resampled like the points.

Every feature is bounded (clipped) so that walls, no-return sides and degenerate fits stay in range.
Everything is vectorised over all segments of all scans of a batch.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numba
import numpy as np

from . import _kernels as _k
from .base import Segment, segments_from_arrays, wrap_angle
from .geometric import is_circular_sweep

__all__ = [
    "CASCADE_FEATURES",
    "FEATURE_VERSION",
    "FeatureConfig",
    "SegmentBatch",
    "SegmentFeatures",
    "cascade_features",
    "feature_names",
    "segment_batch",
    "segment_features",
    "scan_noise",
    "local_to_observer",
    "observer_to_local",
]

#: Version of the feature layout; bump on any change to what :func:`segment_features` computes.
FEATURE_VERSION = 1

# Clipping keeps every feature's spread set by kin-sized objects: with walls metres long in the
# data, unclipped widths or coordinates would standardise a kin's centimetre details to ~0.
_CTX_CLIP = 0.5  # m: context range differences beyond this carry no more information
_LEN_CLIP = 0.3  # m: widths (omega, chord, depth) beyond ~4 kin diameters are "far too wide" alike
_PT_CLIP = 0.15  # m: local point coordinates
_ERR_CLIP = 0.1  # m: circle-fit residuals beyond this are "not a 3.5 cm circle" alike
_ERR_FLOOR = 1e-4  # m: residuals enter as log(e + 0.1 mm): a noise-free circle (~0) vs a prism (~2 mm)
_OFF_CLIP = 0.1  # m: fitted-centre offsets
_RES_CLIP = 0.03  # m: signed residuals of the circle fit in the residual profile
_NOISE_Q = 0.3  # quantile of |second differences| used by scan_noise ...
_NOISE_SCALE = 0.385 * math.sqrt(20.0)  # ... and its value for unit noise: 0.3-quantile of |N(0, 20)|
_CURV_CLIP = 60.0  # 1/m: curvature of circles below 1.7 cm radius; a kin is 28.6
_GN_MAX_STEP = 0.05  # m: cap on one Gauss-Newton step (keeps 2-point fits from flying off)
_TWO_PI = 2.0 * math.pi
#: ``math.log1p(float(n))`` for segment lengths ``n < 64`` (libm's log1p, the function numba calls: the
#: same bits, ``tests/detectors/test_features.py``); the kernels look it up instead of a log per segment
_LOG1P_N = np.array([math.log1p(float(n)) for n in range(64)])


@dataclass(frozen=True)
class FeatureConfig:
    """Settings of the segment representation (stored in checkpoints and dataset manifests).

    Attributes:
        n_points: points each segment is resampled to (shape part of the vector).
        n_context: beams of context on each side of the segment.
        r: kin lidar-housing radius, m (paper: 0.035).
        d_th: segmentation break threshold, m (same as the geometric detector's ``d_th``).
        d_max: maximum range, m; readings at or beyond it are "no return".
        occlusion_unbounded: ``omega_max`` side unbounded when the outside beam is nearer
            (as :attr:`detectors.geometric.GeometricParams.occlusion_unbounded`).
        gn_iters: Gauss-Newton iterations of the known-radius circle fit.
    """

    n_points: int = 8
    n_context: int = 2
    r: float = 0.035
    d_th: float = 0.1
    d_max: float = 12.0
    occlusion_unbounded: bool = True
    gn_iters: int = 3

    def __post_init__(self) -> None:
        for name in ("n_points", "n_context", "gn_iters"):
            v = getattr(self, name)
            lo = 2 if name == "n_points" else 0
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
                raise ValueError(f"FeatureConfig.{name} must be an integer >= {lo}, got {v!r}")
        for name in ("r", "d_th", "d_max"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"FeatureConfig.{name} must be a finite number > 0 (m), got {v!r}")
        if self.d_th >= self.d_max:
            raise ValueError(f"FeatureConfig: d_th={self.d_th} m must be < d_max={self.d_max} m")
        if not isinstance(self.occlusion_unbounded, bool):
            raise ValueError(
                f"FeatureConfig.occlusion_unbounded must be True or False, got {self.occlusion_unbounded!r}"
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d) -> FeatureConfig:
        return config_from_dict(cls, d)


def config_from_dict(cls, d, lists_as_tuples: bool = False):
    """``cls(**d)`` for a config dataclass, refusing a non-mapping or unknown keys with a message naming
    the class and the keys it takes; ``lists_as_tuples``: JSON lists become the tuples a frozen config
    holds."""
    if not isinstance(d, Mapping):
        raise ValueError(f"{cls.__name__}: expected a dict, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown key(s) {unknown}; expected a subset of {sorted(names)}")
    return cls(**{k: tuple(v) if lists_as_tuples and isinstance(v, list) else v for k, v in d.items()})


_GEOMETRIC_NAMES = (
    "log_n_beams",  # log(1 + number of beams)
    "n_beams_clipped",  # min(number of beams, 40)
    "log_range_min",  # log min(d_i) (eq. 2: d_cest = min(d_i) + r), log m
    "range_mean",  # mean(d_i), m
    "omega_min",  # eq. 4, m (clipped)
    "omega_max",  # eq. 5, m (clipped; inf -> clip)
    "diameter_pass",  # eq. 3: omega_min <= 2r < omega_max
    "prev_nearer",  # the beam before the segment hit something nearer (occlusion)
    "next_nearer",  # same after
    "chord",  # first-to-last point distance, m
    "depth",  # extent of the points along u (radial), m
    "log_F0_mean",  # mean |e_i| at the eq. 7 centre (min(d_i) + r at the min beam); log(m + 0.1 mm)
    "log_F_sum",  # eq. 6: sum |e_i| after the fit; log(m + 0.1 mm), as all log_ residuals
    "log_F_mean",  # mean |e_i| after the fit
    "log_e_max",  # max |e_i| after the fit
    "fit_dr",  # fitted centre range - (min(d_i) + r), m
    "fit_u",  # fitted centre in the local frame, m
    "fit_v",
    "fit_ok",  # >= 2 points (the fit means something)
    "kasa_curvature",  # free-radius circle fit, signed curvature, 1/m (> 0: convex towards observer)
    "kasa_ok",  # >= 3 points and not collinear
    "log_line_rms",  # rms distance of the points from their best straight line
    "log_scan_noise",  # the scan's relative range noise, estimated from all its beams; log(x + 1e-4)
    "log_scan_noise_n",  # log(1 + number of beam quadruples behind that estimate): how far to trust it
)


def feature_names(config: FeatureConfig | None = None) -> list[str]:
    """Names of the feature vector's entries, in order (for ``config``)."""
    return list(_feature_names(config or FeatureConfig()))


@functools.lru_cache(maxsize=16)
def _feature_names(c: FeatureConfig) -> tuple[str, ...]:
    names = [f"u{k}" for k in range(c.n_points)] + [f"v{k}" for k in range(c.n_points)]
    names += [f"ctx_prev{j}" for j in range(1, c.n_context + 1)]
    names += [f"ctx_next{j}" for j in range(1, c.n_context + 1)]
    return tuple(names + list(_GEOMETRIC_NAMES) + [f"e{k}" for k in range(c.n_points)])


@dataclass(frozen=True, eq=False)
class SegmentBatch:
    """All segments of ``B`` scans, flattened.

    Attributes:
        ranges: ``(B, n)`` pre-processed ranges (finite, ``<= d_max``), m.
        angles: ``(n,)`` beam angles, rad.
        circular: the beams cover a full turn.
        scan: ``(S,)`` scan row of each segment (segments of scan 0 first, in scan order).
        first, count: ``(S,)`` first beam and number of beams.
        prev_beam, next_beam: ``(S,)`` beam just outside (``-1`` = none).
        prev_nearer, next_nearer: ``(S,)`` bool, as :class:`~detectors.base.Segment`.

    :attr:`segments` (per scan, the :class:`~detectors.base.Segment` list that
    :func:`detectors.geometric.segment` gives) is built from the arrays on first access.
    """

    ranges: np.ndarray
    angles: np.ndarray
    circular: bool
    scan: np.ndarray
    first: np.ndarray
    count: np.ndarray
    prev_beam: np.ndarray
    next_beam: np.ndarray
    prev_nearer: np.ndarray
    next_nearer: np.ndarray

    @property
    def n_segments(self) -> int:
        return int(self.scan.shape[0])

    @functools.cached_property
    def segments(self) -> list[list[Segment]]:
        flat = segments_from_arrays(
            self.angles.shape[0],
            self.first,
            self.count,
            self.prev_beam,
            self.next_beam,
            self.prev_nearer,
            self.next_nearer,
        )
        bounds = np.searchsorted(self.scan, np.arange(self.ranges.shape[0] + 1)).tolist()
        return [flat[bounds[b] : bounds[b + 1]] for b in range(self.ranges.shape[0])]

    def flat_segments(self) -> list[Segment]:
        return [s for segs in self.segments for s in segs]


def segment_batch(ranges, angles, config: FeatureConfig | None = None, circular: bool | None = None):
    """Pre-process and segment ``B`` scans with the geometric detector's own stages 1-2 (compiled).

    Args:
        ranges: ``(B, n)`` raw ranges, m (0.0, NaN, inf = no return). Not validated here.
        angles: ``(n,)`` beam angles, rad.
        config: supplies ``d_th`` and ``d_max``.
        circular: whether the scan is a full turn (default: :func:`is_circular_sweep`).
    """
    c = config or FeatureConfig()
    a = np.asarray(angles, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2 or a.ndim != 1 or r.shape[1] != a.shape[0]:
        raise ValueError(
            f"segment_batch: expected ranges (B, n) and angles (n,), got {r.shape} and {a.shape}"
        )
    circ = is_circular_sweep(a) if circular is None else bool(circular)
    return _segment_batch(r, a, c, circ)


def _segment_batch(r: np.ndarray, a: np.ndarray, c: FeatureConfig, circ: bool) -> SegmentBatch:
    """:func:`segment_batch` without argument checks (``r`` float64 (B, n), ``a`` float64 (n,))."""
    d = np.empty(r.shape)
    _k.preprocess_rows(np.ascontiguousarray(r), float(c.d_max), float(c.d_th), circ, False, d)
    scan, first, count, prev, nxt, p_near, n_near = _k.segment_arrays(d, float(c.d_th), float(c.d_max), circ)
    return SegmentBatch(
        ranges=d,
        angles=a,
        circular=circ,
        scan=scan,
        first=first,
        count=count,
        prev_beam=prev,
        next_beam=nxt,
        prev_nearer=p_near,
        next_nearer=n_near,
    )


@dataclass(frozen=True, eq=False)
class SegmentFeatures:
    """Output of :func:`segment_features`.

    Attributes:
        x: ``(S, F)`` float32 feature vectors (:func:`feature_names`).
        frames: ``(S, 4)`` local frame of each segment: origin ``ox, oy`` (the points' centroid,
            observer frame, m), bearing ``phi`` of the ``u`` axis (rad) and the sweep sign ``s``
            (``v`` axis = ``u`` rotated by ``s * 90 deg``). See :func:`local_to_observer`.
        fit_centre: ``(S, 2)`` known-radius circle-fit centre, observer frame ``x, y``, m.
        min_beam: ``(S,)`` beam index of ``min(d_i)``.
        scan_x: ``(B, 2)`` float32 the per-scan features ``log_scan_noise``, ``log_scan_noise_n`` of
            each scan (the values in its segments' rows of ``x``); ``None`` for an empty batch.
    """

    x: np.ndarray
    frames: np.ndarray
    fit_centre: np.ndarray
    min_beam: np.ndarray
    scan_x: np.ndarray | None = None


def local_to_observer(frames: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``(S, 2)`` local-frame points ``u, v`` → observer-frame ``x, y`` (m)."""
    ox, oy, phi, s = frames.T
    c, sn = np.cos(phi), np.sin(phi)
    u, v = uv[:, 0], uv[:, 1]
    return np.stack([ox + u * c - s * v * sn, oy + u * sn + s * v * c], axis=1)


def observer_to_local(frames: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Inverse of :func:`local_to_observer`."""
    ox, oy, phi, s = frames.T
    c, sn = np.cos(phi), np.sin(phi)
    dx, dy = xy[:, 0] - ox, xy[:, 1] - oy
    return np.stack([dx * c + dy * sn, s * (-dx * sn + dy * c)], axis=1)


#: relative bound on ``|sqrt(x * x + y * y) - math.hypot(x, y)|`` used by :func:`_f32_clip_hypot` (the two
#: differ by a few ulps, 2**-51 relative; 32x margin)
_HYPOT_EPS = 2.0**-46


@numba.njit(cache=True, error_model="numpy", inline="always")
def _f32_clip_hypot(x, y, d, lo, hi):
    """``float(np.float32(min(max(math.hypot(x, y) - d, lo), hi)))`` without ``hypot`` (~17 ns) when the
    float32 value is certain: ``sqrt(x * x + y * y)`` is within ``_HYPOT_EPS`` of it (relative; no under- or
    overflow in the squares), rounding, the clip and the float32 conversion are monotone, so when both
    ends of that interval give the same non-zero float32 the exact value gives it too; else (a zero's
    sign, a value at a float32 rounding edge, about one in 10**7) ``hypot`` itself."""
    a = math.sqrt(x * x + y * y)
    if a > 1e-150 and a < 1e150:
        e = a * _HYPOT_EPS
        f_lo = np.float32(min(max((a - e) - d, lo), hi))
        f_hi = np.float32(min(max((a + e) - d, lo), hi))
        if f_lo == f_hi and f_lo != 0.0:
            return np.float64(f_lo)
    return np.float64(np.float32(min(max(math.hypot(x, y) - d, lo), hi)))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _may_exceed_step(x, y):
    # False only when hypot(x, y) <= _GN_MAX_STEP for certain: sqrt(x * x + y * y) is within _HYPOT_EPS of
    # it (relative; a square that underflows only makes both smaller, an overflow gives inf: True), so the
    # Gauss-Newton step's cap needs the hypot only past this (most steps are shorter)
    return not (math.sqrt(x * x + y * y) * (1.0 + _HYPOT_EPS) < _GN_MAX_STEP)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _log_err(e):
    return math.log(min(e, _ERR_CLIP) + _ERR_FLOOR)


# _log_err_f32's polynomial: log(a) for a in [_ERR_FLOOR, _ERR_CLIP + _ERR_FLOOR] as k ln 2 + 2 atanh(s),
# s = (m - 1) / (m + 1), m = a 2**-k in (1/sqrt 2, sqrt 2] (|s| <= 0.1716), the series to s**17 (the rest
# < 2 s**19 / 19 / (1 - s**2) < 4e-16). With the roundings of the reduction (exact), of s (~4e-17), of the
# series and of the sum with k ln 2 (ln 2 in two parts, k * _LN2_HI exact; |log a| < 9.3: a few ulps of 9.3,
# < 1e-14) and libm's own error (< 1 ulp, 2e-15), libm's log lies within _LOG_EPS (2**-40, ~9e-13: a 50x
# margin) of the value computed.
_LN2_HI = 6.93147180369123816490e-01  # (fdlibm's split of ln 2)
_LN2_LO = 1.90821492927058770002e-10
_LOG_EPS = 2.0**-40
_SQRT2 = math.sqrt(2.0)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _log_err_f32(e):
    """The float32 value of :func:`_log_err` (what the features store), or NaN where :func:`_log_err` must
    be called: when both ends of ``[y - _LOG_EPS, y + _LOG_EPS]`` around the polynomial value ``y`` (above)
    round to the same float32, that is the float32 of libm's ``log``, which lies inside (rounding is
    monotone); else (about one in 10**5) or outside the range (NaN) NaN. No branch and no call: a loop of
    these compiles to SIMD (~1.5 ns a value against ~9 ns for libm's ``log`` called from the feature
    loops; ``tests/detectors/test_fast_paths.py``)."""
    a = min(e, _ERR_CLIP) + _ERR_FLOOR
    bits = np.float64(a).view(np.int64)
    k = (bits >> 52) - 1023
    m = np.int64((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000).view(np.float64)  # a 2**-k in [1, 2)
    big = m > _SQRT2
    m = m * 0.5 if big else m
    k = k + 1 if big else k
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    r = z * (1.0 / 3 + z * (1.0 / 5 + z * (1.0 / 7 + z * (1.0 / 9 + z * (1.0 / 11 + z * (1.0 / 13 + z * (
        1.0 / 15 + z * (1.0 / 17))))))))  # fmt: skip
    fk = float(k)
    y = fk * _LN2_HI + ((2.0 * s + 2.0 * s * r) + fk * _LN2_LO)
    f_lo = np.float32(y - _LOG_EPS)
    good = (f_lo == np.float32(y + _LOG_EPS)) & (a >= _ERR_FLOOR) & (a <= _ERR_CLIP + _ERR_FLOOR)
    return np.float64(f_lo) if good else math.nan


@numba.njit(cache=True, error_model="numpy", inline="always")
def _log_err_or(v, e):
    # v from _log_err_f32(e), or _log_err(e) where that is NaN (the same float32 value)
    return v if v == v else _log_err(e)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _log1p_n(n):
    # math.log1p(float(n)) for a segment length n >= 0, from _LOG1P_N when it is there
    return _LOG1P_N[n] if n < _LOG1P_N.shape[0] else math.log1p(float(n))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _wrap_index(i, n):
    # i % n for -n <= i < 2n without an integer division (the same value)
    if i >= n:
        return i - n
    if i < 0:
        return i + n
    return i


@numba.njit(cache=True, error_model="numpy", inline="always")
def _mod_two_pi(x):
    # Python's x % 2 pi: for |x| < 2 pi fmod returns x exactly, so the same value without fmod
    # (and +0.0 for -0.0, as Python)
    if x > 0.0:
        return x if x < _TWO_PI else x % _TWO_PI
    if x == 0.0:
        return 0.0
    if x > -_TWO_PI:
        return x + _TWO_PI
    return x % _TWO_PI


@numba.njit(cache=True, error_model="numpy", inline="always")
def _half_width(d_cest, alpha):
    # eqs. 4-5 half-widths; an angle >= 90 deg from the min beam bounds no finite diameter
    return d_cest * math.tan(alpha) if alpha < 0.5 * math.pi else math.inf


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _tan_table(ang, sweep, n_off, out):
    # tan_tab[off, i]: what _half_width multiplies d_cest by for beams i and j = i - off (wrapped).
    # Offset-major: most lookups are a few beams apart (a segment's min beam and its ends), and each offset's
    # row (n values) stays in cache; beam-major, a lookup missed the cache on many stage-1 rows
    n = ang.shape[0]
    for i in range(n):
        for off in range(n_off):
            j = i - off if i >= off else i - off + n
            alpha = _mod_two_pi(sweep * (ang[i] - ang[j]))
            out[off, i] = math.tan(alpha) if alpha < 0.5 * math.pi else math.inf


@numba.njit(cache=True, error_model="numpy", inline="always")
def _tan_flat(tan_tab):
    """``tan_tab`` (:func:`beam_trig`'s ``(n_off, n)`` table) as the flat array :func:`_omegas` reads, one
    element at least: an empty table (``n_off == 0``) becomes ``[0.0]``, read at index 0 and never used."""
    return tan_tab.reshape(-1) if tan_tab.size > 0 else np.zeros(1)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _half_width_reads(i, j, ang, n_beams, tan_flat, n_off):
    """The array reads of ``_half_width(d_cest, _mod_two_pi(sweep * (ang[i] - ang[j])))``: ``(in table,
    tan, ang[i] - ang[j])``, the tan ``tan_tab[off, i]`` (the table's very value, or inf) when beam ``j`` is
    ``off < n_off`` beams before ``i``. Reads only, the table at a clamped index: inlined into a loop, the
    arrays' reference counts are then taken and dropped in one block and pruned (around a branch they
    stayed: four atomic operations on every stage-1 row, ~2,500 rows a 64-robot step)."""
    off = i - j if i >= j else i - j + n_beams
    in_tab = off < n_off
    return in_tab, tan_flat[off * n_beams + i if in_tab else 0], ang[i] - ang[j]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _half_width_of(d_cest, in_tab, t, da, sweep):
    # the half-width from _half_width_reads' values (scalars only): d_cest times the table's tan, else
    # _half_width's own tan (the same value: the table holds that very tan, or inf)
    if in_tab:
        return d_cest * t
    return _half_width(d_cest, _mod_two_pi(sweep * da))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _omegas(d_cest, bmin, f, bl, pb, nb, unbounded, ang, sweep, n_beams, tan_flat, n_off):
    """Eqs. 4-5: ``omega_min`` (the segment's own extent, nearest beam ``bmin`` to its first ``f`` and last
    ``bl`` beams) and ``omega_max`` (to the outside beams ``pb`` / ``nb``; inf when ``unbounded``), m.
    ``tan_flat``, ``n_off``: :func:`_tan_flat` of :func:`beam_trig`'s table and its row count. The four
    half-widths' array reads come first, without a branch (``pb`` / ``nb``, possibly -1, replaced by
    ``bmin`` when unbounded: read, not used), then the arithmetic (see :func:`_half_width_reads`)."""
    pb_r = bmin if unbounded else pb
    nb_r = bmin if unbounded else nb
    t0, v0, a0 = _half_width_reads(bmin, f, ang, n_beams, tan_flat, n_off)
    t1, v1, a1 = _half_width_reads(bl, bmin, ang, n_beams, tan_flat, n_off)
    t2, v2, a2 = _half_width_reads(bmin, pb_r, ang, n_beams, tan_flat, n_off)
    t3, v3, a3 = _half_width_reads(nb_r, bmin, ang, n_beams, tan_flat, n_off)
    omega_min = _half_width_of(d_cest, t0, v0, a0, sweep) + _half_width_of(d_cest, t1, v1, a1, sweep)
    omega_max = math.inf
    if not unbounded:
        omega_max = _half_width_of(d_cest, t2, v2, a2, sweep) + _half_width_of(d_cest, t3, v3, a3, sweep)
    return omega_min, omega_max


@numba.njit(cache=True, error_model="numpy", inline="always")
def _context_value(d_flat, row, idx, n_beams, circular, d_edge, d_max):
    """A context feature: beam ``idx``'s range minus the segment's edge range ``d_edge``, clipped to
    +-_CTX_CLIP; _CTX_CLIP where the beam is outside a partial sweep or has no return."""
    # (selects only, the range read at a clamped index: inlined in a loop, d_flat's reference count is then
    # taken and dropped in one block and pruned; with branches it stayed, two atomic operations a call)
    idx = _wrap_index(idx, n_beams) if circular else idx
    ok = (idx >= 0) & (idx < n_beams)
    dc = d_flat[row + (idx if ok else 0)]
    return min(max(dc - d_edge, -_CTX_CLIP), _CTX_CLIP) if ok & (dc < d_max) else _CTX_CLIP


#: :func:`_features_kernel` fits the circles of segments of 2 to this many beams with the segments in SIMD
#: lanes (:func:`_fit_lanes`; ~95 % of a swarm's network rows), longer ones one segment at a time
_FIT_LANES_MAX = 8
_PREFETCH = 4  # rows ahead whose ranges _features_kernel requests (their segment columns twice that)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _fit_lanes(n, c, q0, p0, l_px, l_py, l_cx, l_cy, l_o, l_ox, l_oy, l_cphi, l_sphi, l_dcest, r, sweep,
               gn_iters, kp, rs_lo, rs_hi, rs_w, col_g, x, fit_centre, lw):  # fmt: skip
    """The known-radius circle fits of the ``c`` segments of ``n`` beams in lanes ``q0 ..`` (their points
    ``l_px, l_py`` point-major from ``p0``, eq. 7 starts ``l_cx, l_cy``) and their fit-dependent columns of
    ``x`` (row ``l_o``): :func:`_features_kernel`'s expressions per segment, in the same order, one loop
    over the lanes per step (no reduction across lanes: each lane's values are those of the segment
    fitted alone), so the divisions and square roots of ``c`` segments run as SIMD instructions side by
    side instead of one dependent chain per segment (``tests/detectors/test_fast_paths.py``). ``lw``: scratch
    of ``(14 + n) c`` values at least (the lanes' sums, steps and residuals: views of it, not ~14 arrays
    allocated per call)."""
    px = l_px[p0 : p0 + n * c].reshape((n, c))
    py = l_py[p0 : p0 + n * c].reshape((n, c))
    cx = l_cx[q0 : q0 + c]
    cy = l_cy[q0 : q0 + c]
    f0 = lw[:c]
    f0[:] = 0.0
    for k in range(n):
        for q in range(c):
            f0[q] += abs(math.sqrt((px[k, q] - cx[q]) ** 2 + (py[k, q] - cy[q]) ** 2) - r)
    for q in range(c):
        f0[q] /= n
    a11 = lw[c : 2 * c]
    a12 = lw[2 * c : 3 * c]
    a22 = lw[3 * c : 4 * c]
    g1 = lw[4 * c : 5 * c]
    g2 = lw[5 * c : 6 * c]
    stx = lw[6 * c : 7 * c]
    sty = lw[7 * c : 8 * c]
    for _ in range(gn_iters):
        a11[:] = 0.0
        a12[:] = 0.0
        a22[:] = 0.0
        g1[:] = 0.0
        g2[:] = 0.0
        for k in range(n):
            for q in range(c):
                qx = px[k, q] - cx[q]
                qy = py[k, q] - cy[q]
                nq = max(math.sqrt(qx * qx + qy * qy), 1e-12)
                e = nq - r
                jx = qx / nq
                jy = qy / nq
                a11[q] += jx * jx
                a12[q] += jx * jy
                a22[q] += jy * jy
                g1[q] += jx * e
                g2[q] += jy * e
        for q in range(c):
            mu = 1e-6 + 1e-3 * (a11[q] + a22[q])
            m11 = a11[q] + mu
            m22 = a22[q] + mu
            det = m11 * m22 - a12[q] * a12[q]
            stx[q] = (m22 * g1[q] - a12[q] * g2[q]) / det
            sty[q] = (m11 * g2[q] - a12[q] * g1[q]) / det
        for q in range(c):  # the step's cap (rare: a loop of its own, the others stay branch-free)
            if abs(stx[q]) + abs(sty[q]) > 0.5 * _GN_MAX_STEP and _may_exceed_step(stx[q], sty[q]):
                norm = math.hypot(stx[q], sty[q])
                if norm > _GN_MAX_STEP:
                    stx[q] *= _GN_MAX_STEP / norm
                    sty[q] *= _GN_MAX_STEP / norm
        for q in range(c):
            cx[q] += stx[q]
            cy[q] += sty[q]
    f_sum = lw[8 * c : 9 * c]
    e_max = lw[9 * c : 10 * c]
    f_sum[:] = 0.0
    e_max[:] = 0.0
    pe = lw[10 * c : (10 + n) * c].reshape((n, c))
    for k in range(n):
        for q in range(c):
            pe[k, q] = math.sqrt((px[k, q] - cx[q]) ** 2 + (py[k, q] - cy[q]) ** 2) - r
            e = abs(pe[k, q])
            f_sum[q] += e
            e_max[q] = max(e_max[q], e)
    lg = lw[(10 + n) * c : (14 + n) * c].reshape((4, c))  # the four log errors' float32 values in SIMD lanes
    # (NaN: libm's log below)
    for q in range(c):
        lg[0, q] = _log_err_f32(f0[q])
        lg[1, q] = _log_err_f32(f_sum[q])
        lg[2, q] = _log_err_f32(f_sum[q] / n)
        lg[3, q] = _log_err_f32(e_max[q])
    for q in range(c):
        o = l_o[q0 + q]
        fx = cx[q]
        fy = cy[q]
        fit_centre[o, 0] = fx
        fit_centre[o, 1] = fy
        fdx = fx - l_ox[q0 + q]
        fdy = fy - l_oy[q0 + q]
        cphi = l_cphi[q0 + q]
        sphi = l_sphi[q0 + q]
        fit_u = fdx * cphi + fdy * sphi
        fit_v = sweep * (-fdx * sphi + fdy * cphi)
        x[o, col_g + 11] = _log_err_or(lg[0, q], f0[q])
        x[o, col_g + 12] = _log_err_or(lg[1, q], f_sum[q])
        x[o, col_g + 13] = _log_err_or(lg[2, q], f_sum[q] / n)
        x[o, col_g + 14] = _log_err_or(lg[3, q], e_max[q])
        x[o, col_g + 15] = _f32_clip_hypot(fx, fy, l_dcest[q0 + q], -_OFF_CLIP, _OFF_CLIP)
        x[o, col_g + 16] = min(max(fit_u, -_OFF_CLIP), _OFF_CLIP)
        x[o, col_g + 17] = min(max(fit_v, -_OFF_CLIP), _OFF_CLIP)
        x[o, col_g + 18] = 1.0
        for j in range(kp):
            lo = rs_lo[n, j]
            hi = rs_hi[n, j]
            w = rs_w[n, j]
            e = pe[lo, q] * (1.0 - w) + pe[hi, q] * w
            x[o, col_g + 24 + j] = min(max(e, -_RES_CLIP), _RES_CLIP)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _features_kernel(
    d_flat,
    cos_a,
    sin_a,
    ang,
    scan,
    first,
    count,
    prev_beam,
    next_beam,
    prev_nearer,
    next_nearer,
    n_beams,
    circular,
    sweep,
    r,
    d_max,
    occlusion_unbounded,
    n_points,
    n_context,
    gn_iters,
    scan_noise,
    noise_n,
    which,
    x,
    frames,
    fit_centre,
    min_beam,
    scan_cols,
    tan_tab,
    pre,
):
    """One pass over the segments ``which``: row ``o`` of every output for segment ``which[o]``,
    and each scan's two noise features into ``scan_cols`` (B, 2). ``tan_tab``: :func:`beam_trig`'s
    table (``(0, n)``: none; the same outputs). ``pre`` ``(len(which), 9)`` float32: the values the
    cascade's stage 1 already computed for these segments (:func:`_cascade_kernel` with a 13th column;
    the learned driver's env entry, ``n_context == 2``): ``log_range_min``, ``omega_min``, ``omega_max``,
    ``omega_in_range``, ``chord``, ``ctx_prev1, ctx_prev2, ctx_next1, ctx_next2`` (the same float32
    values); ``(0, 9)``: computed here.

    Points are gathered into scratch buffers, then every feature is a short loop over them: with
    ~3-10 points per segment this is ~50x faster than the equivalent flat numpy expressions
    (whose ~300 array operations dominate at batch sizes of a few thousand segments).
    """
    tan_flat = _tan_flat(tan_tab)
    n_off = tan_tab.shape[0]
    kp = n_points
    n_top = 1
    for o in range(which.shape[0]):
        n_top = max(n_top, count[which[o]])
    n_sel = which.shape[0]
    n_rs = (n_top + 1) * kp
    # the call's scratch arrays as views of one int64 and one float64 allocation (~26 arrays: their
    # allocations and frees were ~1-2 us of a one-scan call); the same values
    lm = _FIT_LANES_MAX
    iw = np.empty(4 * (lm + 2) + 2 * n_rs + n_sel, dtype=np.int64)
    lane_n = iw[: lm + 1]
    lane0 = iw[lm + 2 : 2 * lm + 4]  # first lane of each beam count
    pt0 = iw[2 * lm + 4 : 3 * lm + 6]  # first point slot of each beam count
    fill = iw[3 * lm + 6 : 4 * lm + 7]
    rs_lo = iw[4 * lm + 8 : 4 * lm + 8 + n_rs].reshape((n_top + 1, kp))
    rs_hi = iw[4 * lm + 8 + n_rs : 4 * lm + 8 + 2 * n_rs].reshape((n_top + 1, kp))
    # the circle fits of segments of 2.._FIT_LANES_MAX beams run after the row loop, grouped by beam count
    # with the segments in the SIMD lanes (_fit_lanes); the others' in it, one segment at a time
    lane_n[:] = 0
    for o in range(n_sel):
        n = count[which[o]]
        if n >= 2 and n <= lm:
            lane_n[n] += 1
    lane0[0] = 0
    pt0[0] = 0
    for n in range(lm + 1):
        lane0[n + 1] = lane0[n] + lane_n[n]
        pt0[n + 1] = pt0[n] + n * lane_n[n]
    n_lanes = lane0[lm + 1]
    n_pts = pt0[lm + 1]
    c_top = 0
    for n in range(2, lm + 1):
        c_top = max(c_top, lane_n[n])
    l_o = iw[4 * lm + 8 + 2 * n_rs : 4 * lm + 8 + 2 * n_rs + n_lanes]
    n_lw = (14 + lm) * c_top
    fw = np.empty(6 * n_beams + n_rs + n_lw + 7 * n_lanes + 2 * n_pts + 2 * n_sel)
    px = fw[:n_beams]
    py = fw[n_beams : 2 * n_beams]
    pd = fw[2 * n_beams : 3 * n_beams]
    pu = fw[3 * n_beams : 4 * n_beams]
    pv = fw[4 * n_beams : 5 * n_beams]
    pe = fw[5 * n_beams : 6 * n_beams]
    o_f = 6 * n_beams
    rs_w = fw[o_f : o_f + n_rs].reshape((n_top + 1, kp))
    o_f += n_rs
    lw = fw[o_f : o_f + n_lw]  # _fit_lanes' scratch, for every beam count
    o_f += n_lw
    l_cx = fw[o_f : o_f + n_lanes]
    l_cy = fw[o_f + n_lanes : o_f + 2 * n_lanes]
    l_ox = fw[o_f + 2 * n_lanes : o_f + 3 * n_lanes]
    l_oy = fw[o_f + 3 * n_lanes : o_f + 4 * n_lanes]
    l_cphi = fw[o_f + 4 * n_lanes : o_f + 5 * n_lanes]
    l_sphi = fw[o_f + 5 * n_lanes : o_f + 6 * n_lanes]
    l_dcest = fw[o_f + 6 * n_lanes : o_f + 7 * n_lanes]
    o_f += 7 * n_lanes
    l_px = fw[o_f : o_f + n_pts]
    l_py = fw[o_f + n_pts : o_f + 2 * n_pts]
    o_f += 2 * n_pts
    l_rms = fw[o_f : o_f + n_sel]  # each row's line_rms, its log error written after the loop
    lg = fw[o_f + n_sel : o_f + 2 * n_sel]
    for n in range(lm + 1):
        fill[n] = lane0[n]
    # resampling positions t = j (n - 1) / (kp - 1) per segment length n, once per call instead of
    # a division and a floor per point and segment (the same expressions: same bits)
    for n in range(1, n_top + 1):
        for j in range(kp):
            t = j * (n - 1) / (kp - 1)
            lo = min(int(math.floor(t)), n - 1)
            rs_lo[n, j] = lo
            rs_hi[n, j] = min(lo + 1, n - 1)
            rs_w[n, j] = t - lo
    log_err0 = _log_err(0.0)
    # the per-scan features once per scan, not once per segment (the same expressions: same bits)
    for b in range(scan_noise.shape[0]):
        scan_cols[b, 0] = math.log(scan_noise[b] + 1e-4)
        scan_cols[b, 1] = math.log1p(float(noise_n[b]))
    col_g = 2 * kp + 2 * n_context
    use_pre = pre.shape[0] > 0 and n_context == 2
    for o in range(n_sel):
        # the segments a few rows ahead are scattered over the batch's arrays: their reads requested now
        if o + 2 * _PREFETCH < n_sel:
            i2 = which[o + 2 * _PREFETCH]
            _k.prefetch(scan, i2)
            _k.prefetch(first, i2)
            _k.prefetch(count, i2)
            _k.prefetch(prev_beam, i2)
            _k.prefetch(next_beam, i2)
            _k.prefetch(prev_nearer, i2)
            _k.prefetch(next_nearer, i2)
        if o + _PREFETCH < n_sel:
            i2 = which[o + _PREFETCH]
            _k.prefetch(d_flat, scan[i2] * n_beams + first[i2])
        i = which[o]
        n = count[i]
        f = first[i]
        row = scan[i] * n_beams
        # gather; the first minimum range is eq. 2's min(d_i)
        sx = 0.0
        sy = 0.0
        sd = 0.0
        kmin = 0
        for k in range(n):
            b = f + k  # < 2 n_beams: a compare instead of an integer division
            if b >= n_beams:
                b -= n_beams
            dk = d_flat[row + b]
            pd[k] = dk
            px[k] = dk * cos_a[b]
            py[k] = dk * sin_a[b]
            sx += px[k]
            sy += py[k]
            sd += dk
            if dk < pd[kmin]:
                kmin = k
        ox = sx / n
        oy = sy / n
        phi = math.atan2(oy, ox)
        cphi = math.cos(phi)
        sphi = math.sin(phi)
        umin = 1e300
        umax = -1e300
        for k in range(n):
            dx = px[k] - ox
            dy = py[k] - oy
            pu[k] = dx * cphi + dy * sphi
            pv[k] = sweep * (-dx * sphi + dy * cphi)
            umin = min(umin, pu[k])
            umax = max(umax, pu[k])
        frames[o, 0] = ox
        frames[o, 1] = oy
        frames[o, 2] = phi
        frames[o, 3] = sweep
        if frames.shape[1] >= 6:  # the learned driver's env entry: cos / sin of phi for the back end too
            frames[o, 4] = cphi
            frames[o, 5] = sphi
        # shape: resampled along the beam order
        for j in range(kp):
            lo = rs_lo[n, j]
            hi = rs_hi[n, j]
            w = rs_w[n, j]
            x[o, j] = min(max(pu[lo] * (1.0 - w) + pu[hi] * w, -_PT_CLIP), _PT_CLIP)
            x[o, kp + j] = min(max(pv[lo] * (1.0 - w) + pv[hi] * w, -_PT_CLIP), _PT_CLIP)
        col = 2 * kp
        # context beams
        last = f + n - 1
        if use_pre:
            for j in range(4):
                x[o, col + j] = pre[o, 5 + j]
            col += 4
        else:
            for side in range(2):
                base = f if side == 0 else last
                step = -1 if side == 0 else 1
                d_edge = pd[0] if side == 0 else pd[n - 1]
                for j in range(1, n_context + 1):
                    x[o, col] = _context_value(d_flat, row, base + step * j, n_beams, circular, d_edge, d_max)
                    col += 1
        # eqs. 2-5 (detectors.geometric.filter_by_diameter)
        bmin = _wrap_index(f + kmin, n_beams)
        min_beam[o] = bmin
        d_min = pd[kmin]
        d_cest = d_min + r
        pb = prev_beam[i]
        nb = next_beam[i]
        unb_f = pb < 0 or (occlusion_unbounded and prev_nearer[i])
        unb_l = nb < 0 or (occlusion_unbounded and next_nearer[i])
        bl = _wrap_index(last, n_beams)
        if use_pre:  # stage 1's values of this segment (the same expressions, the same float32 values)
            log_d_min = float(pre[o, 0])
            omega_min_c = float(pre[o, 1])
            omega_max_c = float(pre[o, 2])
            omega_fits = float(pre[o, 3])
            chord_f = float(pre[o, 4])
        else:
            omega_min, omega_max = _omegas(
                d_cest, bmin, f, bl, pb, nb, unb_f or unb_l, ang, sweep, n_beams, tan_flat, n_off
            )
            log_d_min = math.log(d_min)
            omega_min_c = min(omega_min, _LEN_CLIP)
            omega_max_c = min(omega_max, _LEN_CLIP)
            omega_fits = 1.0 if (omega_min <= 2.0 * r and 2.0 * r < omega_max) else 0.0
            # min(chord, _LEN_CLIP) enters the float32 vector only
            chord_f = _f32_clip_hypot(px[n - 1] - px[0], py[n - 1] - py[0], 0.0, 0.0, _LEN_CLIP)
        # known-radius circle fit (eqs. 6-7): Gauss-Newton from the eq. 7 centre
        grow = 1.0 + r / d_min
        cx = px[kmin] * grow
        cy = py[kmin] * grow
        lanes = n >= 2 and n <= _FIT_LANES_MAX
        if lanes:  # fitted in _fit_lanes: its points and start to lane q (points k at pt0[n] + k c + q)
            q = fill[n]
            fill[n] += 1
            c = lane_n[n]
            for k in range(n):
                l_px[pt0[n] + k * c + (q - lane0[n])] = px[k]
                l_py[pt0[n] + k * c + (q - lane0[n])] = py[k]
            l_o[q] = o
            l_cx[q] = cx
            l_cy[q] = cy
            l_ox[q] = ox
            l_oy[q] = oy
            l_cphi[q] = cphi
            l_sphi[q] = sphi
            l_dcest[q] = d_cest
        fit_ok = n >= 2 and not lanes  # (the lanes' fit-dependent columns: written by _fit_lanes)
        F0 = 0.0
        if not lanes:
            for k in range(n):
                F0 += abs(math.sqrt((px[k] - cx) ** 2 + (py[k] - cy) ** 2) - r)
            F0 /= n
        if fit_ok:
            for _ in range(gn_iters):
                a11 = 0.0
                a12 = 0.0
                a22 = 0.0
                g1 = 0.0
                g2 = 0.0
                for k in range(n):
                    qx = px[k] - cx
                    qy = py[k] - cy
                    nq = max(math.sqrt(qx * qx + qy * qy), 1e-12)
                    e = nq - r
                    jx = qx / nq
                    jy = qy / nq
                    a11 += jx * jx
                    a12 += jx * jy
                    a22 += jy * jy
                    g1 += jx * e
                    g2 += jy * e
                mu = 1e-6 + 1e-3 * (a11 + a22)
                m11 = a11 + mu
                m22 = a22 + mu
                det = m11 * m22 - a12 * a12
                stx = (m22 * g1 - a12 * g2) / det
                sty = (m11 * g2 - a12 * g1) / det
                # the step's length only matters past _GN_MAX_STEP: a step with |x| + |y| (>= its
                # length, here with a 2x margin over rounding) below half that needs no hypot
                if abs(stx) + abs(sty) > 0.5 * _GN_MAX_STEP and _may_exceed_step(stx, sty):
                    norm = math.hypot(stx, sty)
                    if norm > _GN_MAX_STEP:
                        stx *= _GN_MAX_STEP / norm
                        sty *= _GN_MAX_STEP / norm
                cx += stx
                cy += sty
        F_sum = 0.0
        e_max = 0.0
        if not lanes:
            for k in range(n):
                pe[k] = math.sqrt((px[k] - cx) ** 2 + (py[k] - cy) ** 2) - r
                e = abs(pe[k])
                F_sum += e
                e_max = max(e_max, e)
        fit_centre[o, 0] = cx
        fit_centre[o, 1] = cy
        fdx = cx - ox
        fdy = cy - oy
        fit_u = fdx * cphi + fdy * sphi
        fit_v = sweep * (-fdx * sphi + fdy * cphi)
        # free-radius (Kasa) fit and straight-line residual from centred moments
        suu = 0.0
        suv = 0.0
        svv = 0.0
        bu = 0.0
        bv = 0.0
        for k in range(n):
            u = pu[k]
            v = pv[k]
            q = u * u + v * v
            suu += u * u
            suv += u * v
            svv += v * v
            bu += 0.5 * u * q
            bv += 0.5 * v * q
        det = suu * svv - suv * suv
        kasa_ok = n >= 3 and det > 1e-12 * (suu + svv) ** 2 + 1e-30
        curv = 0.0
        if kasa_ok:
            ca = (svv * bu - suv * bv) / det
            cb = (suu * bv - suv * bu) / det
            rad = math.sqrt(ca * ca + cb * cb + (suu + svv) / n)
            if rad > 0.0:
                curv = min(max(math.copysign(1.0, ca) / rad, -_CURV_CLIP), _CURV_CLIP)
        half_tr = 0.5 * (suu + svv)
        lam_min = half_tr - math.sqrt(max(half_tr * half_tr - det, 0.0))
        line_rms = math.sqrt(max(lam_min, 0.0) / n)
        l_rms[o] = line_rms
        # the geometric part, in _GEOMETRIC_NAMES order
        g = (
            _log1p_n(n),
            float(min(n, 40)),
            log_d_min,
            sd / n,
            omega_min_c,
            omega_max_c,
            omega_fits,
            1.0 if prev_nearer[i] else 0.0,
            1.0 if next_nearer[i] else 0.0,
            chord_f,
            min(umax - umin, _LEN_CLIP),
            _log_err(F0) if not lanes else 0.0,
            _log_err(F_sum) if fit_ok else log_err0,
            _log_err(F_sum / n) if fit_ok else log_err0,
            _log_err(e_max) if fit_ok else log_err0,
            _f32_clip_hypot(cx, cy, d_cest, -_OFF_CLIP, _OFF_CLIP) if fit_ok else 0.0,
            min(max(fit_u, -_OFF_CLIP), _OFF_CLIP) if fit_ok else 0.0,
            min(max(fit_v, -_OFF_CLIP), _OFF_CLIP) if fit_ok else 0.0,
            1.0 if fit_ok else 0.0,
            curv,
            1.0 if kasa_ok else 0.0,
            0.0,  # (_log_err(line_rms): after this loop, in SIMD lanes)
            scan_cols[scan[i], 0],
            scan_cols[scan[i], 1],
        )
        for val in g:
            x[o, col] = val
            col += 1
        # signed residual profile of the fit, resampled like the points (0 without a fit)
        if not lanes:
            for j in range(kp):
                lo = rs_lo[n, j]
                hi = rs_hi[n, j]
                w = rs_w[n, j]
                e = pe[lo] * (1.0 - w) + pe[hi] * w if fit_ok else 0.0
                x[o, col + j] = min(max(e, -_RES_CLIP), _RES_CLIP)
    for o in range(n_sel):
        lg[o] = _log_err_f32(l_rms[o])
    for o in range(n_sel):
        x[o, col_g + 21] = _log_err_or(lg[o], l_rms[o])
    for n in range(2, _FIT_LANES_MAX + 1):
        if lane_n[n] > 0:
            _fit_lanes(n, lane_n[n], lane0[n], pt0[n], l_px, l_py, l_cx, l_cy, l_o, l_ox, l_oy, l_cphi,
                       l_sphi, l_dcest, r, sweep, gn_iters, kp, rs_lo, rs_hi, rs_w, col_g, x, fit_centre,
                       lw)  # fmt: skip


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _scan_noise_kernel(d, d_th, d_max, circular, out, count):
    n_rows, n = d.shape
    fw = np.empty(4 * n)  # (one allocation: four arrays' were ~0.3 us of a one-scan call)
    buf = fw[:n]
    lo_buf = fw[n : 2 * n]  # _quantile_into's scratch
    hi_buf = fw[2 * n : 3 * n]
    val = fw[3 * n :]
    ok = np.empty(n, dtype=np.bool_)
    for b in range(n_rows):
        row = d[b]
        # the windows that do not wrap without a branch: every window's value and test in one SIMD loop
        # (the divisions 8 at once), then each value kept only if its window qualifies (~45 % do,
        # unpredictably: ~1.4x faster than skipping; the split loops ~1.5x faster than one, measured; the
        # kept values and their order are the same)
        for i in range(n - 3):
            a0 = row[i]
            a1 = row[i + 1]
            a2 = row[i + 2]
            a3 = row[i + 3]
            ok[i] = (max(a0, a1, a2, a3) < d_max) & (abs(a1 - a0) <= d_th) & (abs(a2 - a1) <= d_th) & (
                abs(a3 - a2) <= d_th
            )
            # np.true_divide: `/`'s IEEE quotient without the zero-divisor check that the driver's front
            # (compiled in numba's default error model, which its callees inherit) puts before `/`
            val[i] = np.true_divide(abs(a3 - 3.0 * a2 + 3.0 * a1 - a0), 0.5 * (a1 + a2))
        k = 0
        for i in range(n - 3):
            buf[k] = val[i]
            k += ok[i]
        if circular:  # the last three windows wrap past beam 0
            for i in range(max(n - 3, 0), n):
                a0 = row[i]
                a1 = row[(i + 1) % n]
                a2 = row[(i + 2) % n]
                a3 = row[(i + 3) % n]
                if max(a0, a1, a2, a3) >= d_max:
                    continue
                if abs(a1 - a0) > d_th or abs(a2 - a1) > d_th or abs(a3 - a2) > d_th:
                    continue
                buf[k] = abs(a3 - 3.0 * a2 + 3.0 * a1 - a0) / (0.5 * (a1 + a2))
                k += 1
        out[b] = _quantile_into(buf, k, _NOISE_Q, lo_buf, hi_buf) / _NOISE_SCALE if k >= 5 else 0.0
        count[b] = k


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _quantile(buf, n, q):
    """numba's ``np.quantile(buf[:n], q)`` (linear interpolation between the two order statistics
    around rank ``1 + (n - 1) q``, its expressions) for ``n >= 2`` finite values and ``0 < q < 1``
    (:func:`_quantile_into` with scratch arrays of its own; ``buf`` is left as it is)."""
    return _quantile_into(buf, n, q, np.empty(n), np.empty(n))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _quantile_into(buf, n, q, lo_buf, hi_buf):
    """:func:`_quantile` with the scratch arrays ``lo_buf`` / ``hi_buf`` (``n`` values each), the same
    value as numba's ``np.quantile`` without its four temporary arrays and NaN checks (a selection's
    order statistics do not depend on the algorithm; ``tests/detectors/test_features.py``).

    Quickselect of the ``k``-th smallest with out-of-place three-way partitions: the values ``<`` the
    pivot go to ``lo_buf``, those ``>`` it to ``hi_buf``, both written on every step with the counts
    advanced by the comparisons (no branch on the data: a scan's values are in random order; and no
    load of a slot the previous step wrote, which the in-place Lomuto partition waited on: ~2x faster
    on a swarm scan's ~165 values, measured). A partition reads ``src[i]`` and writes at indices
    ``<= i``, so it can write into the array it reads. The next order statistic is then
    ``lower`` itself when more than ``k + 1`` values are ``<= lower``, else the least value above it."""
    rank = 1 + (n - 1) * ((q * 100.0) / 100.0)
    f = math.floor(rank)
    m = rank - f
    k = int(f - 1)
    src = buf
    size = n
    kk = k
    lower = buf[0]
    while True:
        # the median of src[0], src[mid], src[size - 1] as the pivot (a value of src)
        a = src[0]
        b = src[size >> 1]
        c = src[size - 1]
        if a > b:
            a, b = b, a
        piv = max(a, min(b, c))
        n_lo = 0
        n_hi = 0
        for i in range(size):
            v = src[i]
            lo_buf[n_lo] = v
            hi_buf[n_hi] = v
            n_lo += v < piv
            n_hi += v > piv
        n_eq = size - n_lo - n_hi
        if kk < n_lo:
            src = lo_buf
            size = n_lo
        elif kk < n_lo + n_eq:
            lower = piv
            break
        else:
            src = hi_buf
            size = n_hi
            kk -= n_lo + n_eq
    n_le = 0
    upper = math.inf
    for i in range(n):
        v = buf[i]
        n_le += v <= lower
        upper = min(upper, v if v > lower else math.inf)
    if n_le >= k + 2:
        upper = lower
    return lower * (1 - m) + upper * m


def scan_noise(batch: SegmentBatch, config: FeatureConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Relative range noise of each scan (0.01 = 1 % of the distance), estimated from the scan itself.

    Third differences ``d_{i+3} - 3 d_{i+2} + 3 d_{i+1} - d_i`` of four consecutive beams on one
    surface (no break of ``d_th`` between them) are ~0 for walls and for the slowly varying
    curvature of round objects at 1 deg spacing, and ``N(0, 20 sigma^2)`` for independent noise of
    std ``sigma``; their 30th percentile (relative to the range), which the grazing edges of small
    objects barely move, is ``0.385 * sqrt(20) * sigma``. Second differences would not do: a 3.5 cm
    circle's own curvature reads as ~0.5 % noise in a scan that sees nothing else (the paper's
    empty world). A segment's residuals mean little without this: a noise-free 7 cm prism fits a
    circle as badly (~2 mm) as a kin seen with 0.5 % noise at 0.5 m.

    Returns ``(sigma (B,), n (B,))``: the estimate (0 with fewer than 5 quadruples) and the number
    of quadruples it is based on.
    """
    c = config or FeatureConfig()
    out = np.empty(batch.ranges.shape[0])
    count = np.empty(batch.ranges.shape[0], dtype=np.int64)
    _scan_noise_kernel(
        np.ascontiguousarray(batch.ranges, dtype=np.float64),
        float(c.d_th),
        float(c.d_max),
        batch.circular,
        out,
        count,
    )
    return out, count


def scan_noise_of(ranges, angles, config: FeatureConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`scan_noise` of ``segment_batch(ranges, angles, config)`` without its segmentation, which the
    estimate does not read (the same values; about half the cost of a 64-scan batch)."""
    c = config or FeatureConfig()
    r = np.ascontiguousarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    if r.ndim != 2 or r.shape[1] != a.shape[0]:
        raise ValueError(f"scan_noise_of: expected ranges (B, n) and angles (n,), got {r.shape} and "
                         f"{a.shape}")  # fmt: skip
    circ = is_circular_sweep(a)
    d = np.empty(r.shape)
    _k.preprocess_rows(r, float(c.d_max), float(c.d_th), circ, False, d)
    out = np.empty(r.shape[0])
    count = np.empty(r.shape[0], dtype=np.int64)
    _scan_noise_kernel(d, float(c.d_th), float(c.d_max), circ, out, count)
    return out, count


def _scan_noise_of_d(d: np.ndarray, circular: bool, config: FeatureConfig | None = None):
    """:func:`scan_noise_of` on rows ``d`` already preprocessed as it preprocesses them (``config``'s
    ``d_max``, no spike filter; e.g. the geometric detector's own rows when its ``d_max`` is the same and its
    ``noise_filter`` off: :meth:`detectors.geometric.GeometricKinDetector._detect_table_feed_trusted`),
    ``circular`` the beams' :func:`~detectors.geometric.is_circular_sweep`: the same values."""
    c = config or FeatureConfig()
    out = np.empty(d.shape[0])
    count = np.empty(d.shape[0], dtype=np.int64)
    _scan_noise_kernel(d, float(c.d_th), float(c.d_max), bool(circular), out, count)
    return out, count


def segment_features(
    batch: SegmentBatch, config: FeatureConfig | None = None, which: np.ndarray | None = None
) -> SegmentFeatures:
    """The feature vectors of every segment in ``batch`` (see the module docstring), or of the
    segments ``which`` (int indices), row ``o`` for segment ``which[o]``: each row is the same as
    without ``which`` (every segment's features are its own; only the scan noise is per scan)."""
    c = config or FeatureConfig()
    if which is None:
        which = np.arange(batch.n_segments, dtype=np.int64)
    else:
        which = np.asarray(which)
        if which.ndim != 1 or which.dtype.kind not in "iu" or (
            which.size and (which.min() < 0 or which.max() >= batch.n_segments)
        ):
            raise ValueError(
                f"segment_features: which must be a 1-D array of segment indices in [0, "
                f"{batch.n_segments}), got {which!r}"
            )
        which = which.astype(np.int64, copy=False)
    return _segment_features(batch, c, which, beam_trig(batch.angles))


def beam_trig(angles, tan_offsets: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """``(angles, cos, sin, sweep sign, tan table)`` of a scan's beams as the feature kernels take
    them (a detector computes them once per beam layout). The table ``(tan_offsets, n)`` holds the
    ``tan`` of eqs. 4-5's half-widths for beams up to ``tan_offsets - 1`` apart (a segment's min beam
    and its ends; ~10 ns each, four per segment), the same values the kernels compute without it."""
    ang = np.ascontiguousarray(angles, dtype=np.float64)
    sweep = 1.0 if ang.shape[0] > 1 and wrap_angle(float(ang[1] - ang[0])) > 0 else -1.0
    tab = np.empty((min(int(tan_offsets), ang.shape[0]), ang.shape[0]))
    _tan_table(ang, sweep, tab.shape[0], tab)
    return ang, np.cos(ang), np.sin(ang), sweep, tab


def _segment_features(
    batch: SegmentBatch, c: FeatureConfig, which: np.ndarray, trig, noise=None
) -> SegmentFeatures:
    """:func:`segment_features` without argument checks: ``which`` int64 indices, ``trig`` from
    :func:`beam_trig` of ``batch.angles``, ``noise`` the :func:`scan_noise` of ``batch`` if the
    caller has it already."""
    n_seg = which.shape[0]
    n_feat = len(_feature_names(c))
    x = np.empty((n_seg, n_feat), dtype=np.float32)
    frames = np.empty((n_seg, 4))
    fit_centre = np.empty((n_seg, 2))
    min_beam = np.empty(n_seg, dtype=np.int64)
    scan_cols = np.empty((batch.ranges.shape[0], 2))
    if batch.n_segments == 0:
        return SegmentFeatures(x, frames, fit_centre, min_beam, None)
    ang, cos_a, sin_a, sweep, tan_tab = trig
    _features_kernel(
        np.ascontiguousarray(batch.ranges, dtype=np.float64).reshape(-1),
        cos_a,
        sin_a,
        ang,
        batch.scan,
        batch.first,
        batch.count,
        batch.prev_beam,
        batch.next_beam,
        batch.prev_nearer,
        batch.next_nearer,
        ang.shape[0],
        batch.circular,
        sweep,
        float(c.r),
        float(c.d_max),
        c.occlusion_unbounded,
        c.n_points,
        c.n_context,
        c.gn_iters,
        *(scan_noise(batch, c) if noise is None else noise),
        which,
        x,
        frames,
        fit_centre,
        min_beam,
        scan_cols,
        tan_tab,
        np.empty((0, 9), dtype=np.float32),
    )
    return SegmentFeatures(
        x=x, frames=frames, fit_centre=fit_centre, min_beam=min_beam, scan_x=scan_cols.astype(np.float32)
    )


# --------------------------------------------------------------------------- cascade, stage 1

#: The cheap first stage of the learned detector's cascade (:class:`detectors.learned.LearnedKinDetector`
#: ``cascade``) scores each segment from these entries of the full feature vector only: no centroid
#: frame, no circle fit, no resampling. :func:`cascade_features` computes them with the same
#: expressions as :func:`segment_features` (the same float32 values, tested).
CASCADE_FEATURES = (
    "log_n_beams",
    "log_range_min",
    "omega_min",
    "omega_max",
    "prev_nearer",
    "next_nearer",
    "chord",
    "log_scan_noise",
    "ctx_prev1",
    "ctx_next1",
    "ctx_prev2",
    "ctx_next2",
)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _scan_columns(scan_noise, noise_n, out):
    # the per-scan features, the same expressions as in _features_kernel (same bits)
    for b in range(scan_noise.shape[0]):
        out[b, 0] = math.log(scan_noise[b] + 1e-4)
        out[b, 1] = math.log1p(float(noise_n[b]))


_CAS_BLOCK = 32  # rows per block of _cascade_scores
_N_CAS = len(CASCADE_FEATURES)  # a compile-time constant: the input loop unrolls


@numba.njit(cache=True, nogil=True, fastmath=True)
def _cascade_scores(x, w1t, b1, w2, b2, out):
    """Stage-1 score of every row of ``x``: one hidden ReLU layer (the standardisation folded into
    ``w1t``, ``(in, out)``), float64, ~200 multiply-adds a row against the full network's ~7,700.

    Rows go through in blocks of 32 in the SIMD lanes (inputs transposed), a unit's 12 inputs unrolled:
    each row's score is computed by the same instructions whatever block it is in (no reduction
    across rows for the compiler to reorder), ~2x faster than a row at a time with the units in the
    lanes (measured)."""
    n_hid = w1t.shape[1]
    xt = np.empty((_N_CAS, _CAS_BLOCK))
    s = np.empty(_CAS_BLOCK)
    for r0 in range(0, x.shape[0], _CAS_BLOCK):
        m = min(_CAS_BLOCK, x.shape[0] - r0)
        for k in range(_N_CAS):
            for q in range(m):
                xt[k, q] = x[r0 + q, k]
        for q in range(m):
            s[q] = b2
        for j in range(n_hid):
            bj = b1[j]
            w2j = w2[j]
            for q in range(m):
                a = bj
                for k in range(_N_CAS):
                    a += w1t[k, j] * xt[k, q]
                s[q] += max(a, 0.0) * w2j
        for q in range(m):
            out[r0 + q] = s[q]


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _cascade_kernel(
    d_flat, cos_a, sin_a, ang, scan, first, count, prev_beam, next_beam, prev_nearer, next_nearer,
    n_beams, circular, sweep, r, d_max, occlusion_unbounded, scan_cols, which, x, tan_tab,
):  # fmt: skip
    """:data:`CASCADE_FEATURES` of the segments ``which`` into ``x`` (rows as float32 values in
    float64). Expressions as in :func:`_features_kernel` (the context with ``n_context = 2``)."""
    n_sel = which.shape[0]
    tan_flat = _tan_flat(tan_tab)
    n_off = tan_tab.shape[0]
    for o in range(n_sel):
        # (as in _features_kernel; written out in both: one shared inline="always" helper made the learned
        # call ~20 % slower, 1.38 -> 1.80 ms per 64 scans, CPU time, session 10)
        if o + 2 * _PREFETCH < n_sel:
            i2 = which[o + 2 * _PREFETCH]
            _k.prefetch(scan, i2)
            _k.prefetch(first, i2)
            _k.prefetch(count, i2)
            _k.prefetch(prev_beam, i2)
            _k.prefetch(next_beam, i2)
            _k.prefetch(prev_nearer, i2)
            _k.prefetch(next_nearer, i2)
        if o + _PREFETCH < n_sel:
            i2 = which[o + _PREFETCH]
            _k.prefetch(d_flat, scan[i2] * n_beams + first[i2])
        i = which[o]
        n = count[i]
        f = first[i]
        row = scan[i] * n_beams
        kmin = 0
        dmin = d_flat[row + f]
        for k in range(1, n):
            b = f + k
            if b >= n_beams:
                b -= n_beams
            if d_flat[row + b] < dmin:
                dmin = d_flat[row + b]
                kmin = k
        last = f + n - 1
        bl = _wrap_index(last, n_beams)
        d_first = d_flat[row + f]
        d_last = d_flat[row + bl]
        # context beams
        for side in range(2):
            base = f if side == 0 else last
            step = -1 if side == 0 else 1
            d_edge = d_first if side == 0 else d_last
            for j in range(1, 3):
                val = _context_value(d_flat, row, base + step * j, n_beams, circular, d_edge, d_max)
                # ctx_prev1, ctx_next1, ctx_prev2, ctx_next2
                x[o, 8 + side + 2 * (j - 1)] = np.float32(val)
        bmin = _wrap_index(f + kmin, n_beams)
        d_cest = dmin + r
        pb = prev_beam[i]
        nb = next_beam[i]
        unb_f = pb < 0 or (occlusion_unbounded and prev_nearer[i])
        unb_l = nb < 0 or (occlusion_unbounded and next_nearer[i])
        omega_min, omega_max = _omegas(
            d_cest, bmin, f, bl, pb, nb, unb_f or unb_l, ang, sweep, n_beams, tan_flat, n_off
        )
        # a one-beam segment (~60 % of a noisy swarm scan's) has chord hypot(0, 0) = 0.0
        chord = 0.0
        if n > 1:
            dx = d_last * cos_a[bl] - d_first * cos_a[f]
            chord = _f32_clip_hypot(dx, d_last * sin_a[bl] - d_first * sin_a[f], 0.0, 0.0, _LEN_CLIP)
        x[o, 0] = np.float32(_log1p_n(n))
        x[o, 1] = np.float32(math.log(dmin))
        x[o, 2] = np.float32(min(omega_min, _LEN_CLIP))
        x[o, 3] = np.float32(min(omega_max, _LEN_CLIP))
        x[o, 4] = 1.0 if prev_nearer[i] else 0.0
        x[o, 5] = 1.0 if next_nearer[i] else 0.0
        x[o, 6] = chord  # (float32 value)
        x[o, 7] = np.float32(scan_cols[scan[i], 0])
        if x.shape[1] > 12:  # for _features_kernel's pre (the learned driver's env entry)
            x[o, 12] = 1.0 if (omega_min <= 2.0 * r and 2.0 * r < omega_max) else 0.0


def cascade_features(
    batch: SegmentBatch, config: FeatureConfig | None = None, which: np.ndarray | None = None, noise=None
) -> np.ndarray:
    """``(len(which), len(CASCADE_FEATURES))`` float64: the cascade's stage-1 inputs of the segments
    ``which`` (default all), each equal to the float32 value of the same name in
    :func:`segment_features` (``noise``: :func:`scan_noise` of ``batch`` if already computed)."""
    c = config or FeatureConfig()
    if c.n_context < 2:
        raise ValueError(f"cascade_features: needs FeatureConfig.n_context >= 2, got {c.n_context}")
    if which is None:
        which = np.arange(batch.n_segments, dtype=np.int64)
    x, _ = _cascade(batch, c, np.asarray(which, dtype=np.int64), beam_trig(batch.angles), noise, None)
    return x


def _cascade(batch: SegmentBatch, c: FeatureConfig, which: np.ndarray, trig, noise, model):
    """``(x, score)``: :func:`_cascade_kernel` then :func:`_cascade_scores`; ``model`` ``(w1t, b1,
    w2, b2)`` float64 (``w1t`` the hidden layer's ``(in, out)`` matrix, the input standardisation
    folded in) or None (then ``score`` is empty)."""
    if noise is None:
        noise = scan_noise(batch, c)
    scan_cols = np.empty((batch.ranges.shape[0], 2))
    _scan_columns(noise[0], noise[1], scan_cols)
    x = np.empty((which.shape[0], len(CASCADE_FEATURES)))
    ang, cos_a, sin_a, sweep, tan_tab = trig
    _cascade_kernel(
        np.ascontiguousarray(batch.ranges, dtype=np.float64).reshape(-1), cos_a, sin_a, ang,
        batch.scan, batch.first, batch.count, batch.prev_beam, batch.next_beam, batch.prev_nearer,
        batch.next_nearer, ang.shape[0], batch.circular, sweep, float(c.r), float(c.d_max),
        c.occlusion_unbounded, scan_cols, which, x, tan_tab,
    )  # fmt: skip
    if model is None:
        return x, np.empty(0)
    score = np.empty(which.shape[0])
    _cascade_scores(x, *model, score)
    return x, score


# ---------------------------------------------------------------- cascade, a bound for one-beam segments

# Most segments of a noisy swarm scan are one beam (1 % noise breaks long-range walls), and stage 1
# rejects nearly all of them. :func:`_cascade_one_beam_filter` proves most of those rejections from an
# upper bound on the stage-1 score that costs a table lookup and a six-term dot product, instead of
# the inputs (a ``log``, the eq. 4-5 widths) and the 16-unit score.
#
# Derivation. The score is ``s(x) = b2 + sum_j w2_j relu(a_j(x))``, ``a_j(x) = b1_j + sum_k W_kj x_k``.
# For a one-beam segment the inputs lie in a box: ``x0 = log1p(1)``, ``x2 = omega_min = 0`` (eqs. 4-5
# from its only beam to itself: ``d tan(0) = 0``), ``x6 = chord = 0``, ``x3 = min(omega_max, 0.3)`` in
# ``[0, 0.3]``, the flags ``x4, x5`` exact, ``ctx_prev1`` (``x8``) ``<= 0`` when the previous beam is
# nearer (``x4 = 1``, the same comparison) and ``>= 0`` otherwise (``x9``/``x5`` alike), the other
# contexts in ``[-0.5, 0.5]``; the table's cell also fixes a bin of the scan noise ``x7`` and one of
# the range ``d``, so ``x1 = log d`` in ``[log d_lo, log d_hi]``. Over the box each ``a_j`` lies in
# ``[L_j, U_j]`` (interval arithmetic), and on ``[L, U]``: ``relu(a) <= U (a - L) / (U - L)`` (the
# chord of a convex function, ``L < 0 < U``) and ``relu(a) >= lam a`` for ``lam`` in ``{0, 1}``; with
# ``relu = 0`` for ``U <= 0`` and ``= a`` for ``L >= 0``. Each unit's term gets the upper linear
# bound where ``w2_j > 0``, the lower one where ``w2_j < 0``: an affine ``s(x) <= c + g . x`` on the
# box. ``x0`` to ``x6`` are then replaced by the maximum of their terms over the box, leaving
# ``B = c' + g7 x7 + g8 x8 + g9 x9 + g10 x10 + g11 x11`` on the exact float32 values the stage computes.
# Rounding: the score and ``B`` are float64 sums of ~30 terms below ~1e3 in size (errors ~1e-12), the
# box's ``log d`` edges are padded by 1e-6 (libm's and float32's roundings of ``log d`` are ~1e-7),
# so rejecting only ``B < threshold - 1e-6`` never drops a segment the stage would keep: the outputs
# that depend on the kept segments stay bitwise the same (``tests/detectors/test_cascade_bound.py``).
_C1_SHIFT = 49  # float64 bits >> 49: the exponent and 3 mantissa bits, 8 range bins per octave
_C1_D_LO = 2.0**-4  # m: ranges outside [_C1_D_LO, _C1_D_HI) are scored in full
_C1_D_HI = 2.0**4
_C1_K0 = int(np.array(_C1_D_LO).view(np.int64)) >> _C1_SHIFT
_C1_ND = (int(np.array(_C1_D_HI).view(np.int64)) >> _C1_SHIFT) - _C1_K0
_C1_X7_LO = -9.5  # log_scan_noise bins of 0.5 (exact in binary) over [-9.5, 3.5); log(1e-4) = -9.2
_C1_X7_W = 0.5
_C1_N7 = 26
_C1_DELTA = 1e-6  # the rounding margin above


def cascade_one_beam_table(w1t, b1, w2, b2) -> np.ndarray:
    """``(_C1_N7, 4, _C1_ND, 6)`` float64: for each scan-noise bin, flag pair ``prev_nearer + 2
    next_nearer`` and range bin, ``(c', g7, g8, g9, g10, g11)`` of the affine bound above on the
    stage-1 score ``(w1t, b1, w2, b2)`` (:func:`_cascade_scores`'s model) of a one-beam segment."""
    w1t, b1, w2 = (np.asarray(a, dtype=np.float64) for a in (w1t, b1, w2))
    n_in = len(CASCADE_FEATURES)
    if w1t.ndim != 2 or w1t.shape[0] != n_in or b1.shape != (w1t.shape[1],) or w2.shape != b1.shape:
        raise ValueError(f"cascade_one_beam_table: not a {n_in} -> H -> 1 model: w1t {w1t.shape}")
    edges = (np.arange(_C1_K0, _C1_K0 + _C1_ND + 1, dtype=np.int64) << _C1_SHIFT).view(np.float64)
    x7e = _C1_X7_LO + _C1_X7_W * np.arange(_C1_N7 + 1)
    key = np.arange(4)
    prev_n, next_n = (key & 1).astype(float), (key >> 1).astype(float)
    shape = (_C1_N7, 4, _C1_ND, n_in)
    lo, hi = np.zeros(shape), np.zeros(shape)
    lo[..., 0] = hi[..., 0] = np.float32(math.log1p(1.0))
    lo[..., 1] = np.log(edges[:-1]) - 1e-6
    hi[..., 1] = np.log(edges[1:]) + 1e-6
    hi[..., 3] = float(np.float32(_LEN_CLIP)) + 1e-6
    lo[..., 4] = hi[..., 4] = prev_n[:, None]
    lo[..., 5] = hi[..., 5] = next_n[:, None]
    lo[..., 7] = x7e[:-1, None, None]
    hi[..., 7] = x7e[1:, None, None]
    for k, flag in ((8, prev_n), (9, next_n)):  # a nearer neighbour: the context difference is <= 0
        lo[..., k] = np.where(flag > 0, -_CTX_CLIP, 0.0)[:, None]
        hi[..., k] = np.where(flag > 0, 0.0, _CTX_CLIP)[:, None]
    lo[..., 10:] = -_CTX_CLIP
    hi[..., 10:] = _CTX_CLIP
    wp, wn = np.maximum(w1t, 0.0), np.minimum(w1t, 0.0)
    low = b1 + lo @ wp + hi @ wn  # (..., H): each unit's pre-activation range over the box
    up = b1 + hi @ wp + lo @ wn
    mid = (low < 0.0) & (up > 0.0)
    span = np.where(mid, up - low, 1.0)
    # slope of the linear bound of relu: the chord (w2 > 0) or 0 / 1 (w2 < 0), 0 or 1 off the kink
    slope = np.where(low >= 0.0, 1.0, np.where(mid, np.where(w2 > 0.0, up / span, (up > -low) * 1.0), 0.0))
    offset = np.where(mid & (w2 > 0.0), -slope * low, 0.0)
    coef = slope * w2
    g = coef @ w1t.T
    c = b2 + coef @ b1 + offset @ w2
    for k in range(7):  # the fixed (x0, x2, x4-x6) or bounded (x1, x3) inputs at their worst
        c = c + np.maximum(g[..., k] * lo[..., k], g[..., k] * hi[..., k])
    return np.ascontiguousarray(np.concatenate([c[..., None], g[..., 7:]], axis=-1))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _one_beam_bound(d_flat, d_bits, row, f, n_beams, circular, d_max, key, base, x7, tab_flat):
    # the bound B of the derivation above for the one-beam segment at beam f of the scan starting at
    # d_flat[row]; inf when its range or scan noise (base < 0: _one_beam_scan_bins) is outside the table.
    # tab_flat: a full table (callers check). Selects only, the table read at a clamped index: inlined in a
    # loop, the arrays' reference counts are then taken and dropped in one block and pruned (with branches
    # they stayed: atomic operations on every one-beam segment)
    kd = (d_bits[row + f] >> _C1_SHIFT) - _C1_K0
    v = d_flat[row + f]
    c8 = np.float32(_context_value(d_flat, row, f - 1, n_beams, circular, v, d_max))
    c9 = np.float32(_context_value(d_flat, row, f + 1, n_beams, circular, v, d_max))
    c10 = np.float32(_context_value(d_flat, row, f - 2, n_beams, circular, v, d_max))
    c11 = np.float32(_context_value(d_flat, row, f + 2, n_beams, circular, v, d_max))
    inside = (base >= 0) & (kd >= 0) & (kd < _C1_ND)
    t = base + (key * _C1_ND + kd) * 6 if inside else 0  # tab[k7, key, kd, :] in the flat table
    b = (tab_flat[t] + tab_flat[t + 1] * x7 + tab_flat[t + 2] * c8 + tab_flat[t + 3] * c9
         + tab_flat[t + 4] * c10 + tab_flat[t + 5] * c11)  # fmt: skip
    return b if inside else math.inf


@numba.njit(cache=True, error_model="numpy", inline="always")
def _segment_bound(i, d_flat, d_bits, scan, first, prev_nearer, next_nearer, n_beams, circular, d_max,
                   base, x7, tab_flat):  # fmt: skip
    # _one_beam_bound of one-beam segment i (its scan's bins from _one_beam_scan_bins)
    b = scan[i]
    key = (1 if prev_nearer[i] else 0) + (2 if next_nearer[i] else 0)
    return _one_beam_bound(d_flat, d_bits, b * n_beams, first[i], n_beams, circular, d_max, key, base[b],
                           x7[b], tab_flat)  # fmt: skip


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _one_beam_scan_bins(scan_cols, tab):
    # per scan: where its bin starts in the flat table (-1: outside the table, or an empty table) and its
    # log_scan_noise as the stage sees it (float32)
    base = np.empty(scan_cols.shape[0], dtype=np.int64)
    x7 = np.empty(scan_cols.shape[0])
    _one_beam_scan_bins_into(scan_cols, tab, base, x7)
    return base, x7


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _one_beam_scan_bins_into(scan_cols, tab, base, x7):
    # _one_beam_scan_bins into the caller's arrays
    full = tab.shape[0] == _C1_N7 and tab.shape[1] == 4 and tab.shape[2] == _C1_ND and tab.shape[3] == 6
    for b in range(scan_cols.shape[0]):
        v = float(np.float32(scan_cols[b, 0]))
        x7[b] = v
        base[b] = -1
        if full and v >= _C1_X7_LO and v < _C1_X7_LO + _C1_X7_W * _C1_N7:
            k = int((v - _C1_X7_LO) / _C1_X7_W)
            # the bin's edges are exact (multiples of 0.5): put v inside them whatever the rounding
            if k > 0 and v < _C1_X7_LO + _C1_X7_W * k:
                k -= 1
            elif k < _C1_N7 - 1 and v >= _C1_X7_LO + _C1_X7_W * (k + 1):
                k += 1
            base[b] = k * (4 * _C1_ND * 6)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _cascade_one_beam_filter(d_flat, scan, first, count, prev_nearer, next_nearer, n_beams, circular, d_max,
                             scan_cols, tab, threshold, rows, out):  # fmt: skip
    """Copy into ``out`` the segments ``rows`` that stage 1 must score: all but the one-beam segments
    whose bound (:func:`cascade_one_beam_table`) proves a score below ``threshold``. Returns how many
    (in the order of ``rows``)."""
    base, x7 = _one_beam_scan_bins(scan_cols, tab)
    d_bits = d_flat.view(np.int64)
    tab_flat = tab.reshape(-1)
    full = base.shape[0] > 0 and base.max() >= 0  # (else every bound is inf)
    lim = threshold - _C1_DELTA
    m = 0
    for o in range(rows.shape[0]):
        i = rows[o]
        if full and count[i] == 1 and _segment_bound(i, d_flat, d_bits, scan, first, prev_nearer, next_nearer,
                                                     n_beams, circular, d_max, base, x7,
                                                     tab_flat) < lim:  # fmt: skip
            continue
        out[m] = i
        m += 1
    return m


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _cascade_one_beam_bounds(d_flat, scan, first, prev_nearer, next_nearer, n_beams, circular, d_max,
                             scan_cols, tab, which, out):  # fmt: skip
    # the bound of each (one-beam) segment of `which` (tests compare it with the stage-1 score)
    base, x7 = _one_beam_scan_bins(scan_cols, tab)
    d_bits = d_flat.view(np.int64)
    tab_flat = tab.reshape(-1)
    full = base.shape[0] > 0 and base.max() >= 0  # (else every bound is inf)
    for o in range(which.shape[0]):
        out[o] = math.inf
        if full:
            out[o] = _segment_bound(which[o], d_flat, d_bits, scan, first, prev_nearer, next_nearer, n_beams,
                                    circular, d_max, base, x7, tab_flat)  # fmt: skip
