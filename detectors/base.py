"""Detector-agnostic types and input validation for lidar kin detection.

Scan convention (project-wide): a scan is ``ranges`` (n_beams,) in metres and
``angles`` (n_beams,) in radians, in the observer's frame, counter-clockwise
positive, 0 = robot heading, wrapped to (-pi, pi]. 0.0, NaN and inf mean
"no return" (a real RPLIDAR reports 0.0 or inf for an invalid reading) and are
legal input: both detectors map them to the maximum range (paper 4.1), and
such beams never affect the other scans of a batch. Negative ranges are errors.

Nothing in this module is specific to the geometric (paper) detector, so a
learned detector can implement :class:`KinDetector` and reuse
:class:`Segment`, :class:`SegmentReport` and :func:`validate_scan`.
"""

from __future__ import annotations

import contextlib
import gc
import math
import sys
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np


def _check_package() -> None:
    # every module of this package imports this one: if the ``detectors`` package Python imported is
    # not ours (an unrelated distribution named ``detectors`` overwrote our __init__), say so here
    pkg = sys.modules.get(__name__.rpartition(".")[0])
    if pkg is None or getattr(pkg, "__kin_envs_package__", None) is True:
        return
    from importlib import metadata

    dists = sorted(d for d in metadata.packages_distributions().get(pkg.__name__, []) if d != "kin-envs")
    raise ImportError(
        f"the package {pkg.__name__!r} imported from {getattr(pkg, '__file__', '?')} is not kin-envs' own "
        f"(it comes from {dists or 'an unknown source'}): uninstall it and reinstall kin-envs, or use "
        "separate virtual environments"
    )


_check_package()

__all__ = [
    "STAGES",
    "BatchDetections",
    "Detection",
    "DetectionResult",
    "KinDetector",
    "LazyBatchReports",
    "Segment",
    "SegmentReport",
    "segments_from_arrays",
    "validate_scan",
    "wrap_angle",
]


def wrap_angle(a):
    """Wrap angle(s) in radians to (-pi, pi]. Works on floats and arrays."""
    if isinstance(a, np.ndarray):
        w = np.remainder(a + np.pi, 2.0 * np.pi) - np.pi
        w[w <= -np.pi] += 2.0 * np.pi
        return w
    w = math.remainder(a, 2.0 * math.pi)  # in [-pi, pi]
    return w + 2.0 * math.pi if w <= -math.pi else w


def validate_scan(ranges, angles) -> tuple[np.ndarray, np.ndarray]:
    """Check one scan and return it as float64 arrays ``(ranges, angles)``.

    Raises ``ValueError`` naming the offending value if:

    * ``ranges`` or ``angles`` is not 1-D, or their lengths differ, or there
      are fewer than 3 beams;
    * an angle is not finite (NaN / inf);
    * a range is negative (including ``-inf``); NaN and ``+inf`` are allowed
      (they mean "no return");
    * the angles are not a strictly monotonic sweep in one rotational
      direction (every step between consecutive beams, wrapped to (-pi, pi],
      must be non-zero and of the same sign) - detectors rely on beam order
      being angular order.

    The returned arrays may be the inputs themselves when they already are
    float64 arrays; callers must not modify them in place.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if r.ndim != 1:
        raise ValueError(f"ranges must be a 1-D array (n_beams,), got shape {r.shape}")
    if a.ndim != 1:
        raise ValueError(f"angles must be a 1-D array (n_beams,), got shape {a.shape}")
    if r.shape != a.shape:
        raise ValueError(
            f"ranges and angles must have the same length, got {r.shape[0]} ranges and {a.shape[0]} angles"
        )
    if r.shape[0] < 3:
        raise ValueError(f"a scan needs at least 3 beams, got {r.shape[0]}")
    if not np.isfinite(a).all():
        i = int(np.flatnonzero(~np.isfinite(a))[0])
        raise ValueError(f"angles must be finite radians, got angles[{i}] = {a[i]}")
    neg = r < 0.0  # NaN compares False, so NaN passes here on purpose
    if neg.any():
        i = int(np.flatnonzero(neg)[0])
        raise ValueError(f"ranges must be >= 0 metres (non-finite means no return), got ranges[{i}] = {r[i]}")
    _check_sweep(a)
    return r, a


def trusted_ranges(ranges, angles, validated_angles) -> np.ndarray | None:
    """A detector's trusted fast path (the envs, which pass their own lidar's scans): ``ranges`` as
    float64 when ``angles`` is the very array this detector validated before and ``ranges`` is a float
    ``(B, n)`` array on it; ``None`` when the input must be checked in full."""
    if (
        angles is validated_angles
        and type(ranges) is np.ndarray
        and ranges.ndim == 2
        and ranges.shape[1] == angles.shape[0]
        and ranges.dtype.kind == "f"
    ):
        return np.asarray(ranges, dtype=np.float64)  # the lidar's float32 → float64
    return None


def validate_batch(ranges, angles) -> tuple[np.ndarray, np.ndarray]:
    """Shapes of a batch of scans sharing one beam layout: ``ranges (B, n)``, ``angles (n,)``.

    Returns both as float64; raises ``ValueError`` naming the shapes when they do not fit. The
    values of each row are checked by the detector (:func:`validate_scan` semantics).
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"batched ranges must be 2-D (B, n_beams), got shape {r.shape}")
    if a.ndim != 1 or a.shape[0] != r.shape[1]:
        raise ValueError(
            f"angles must be 1-D with n_beams = {r.shape[1]} entries to match ranges "
            f"{r.shape}, got shape {a.shape}"
        )
    return r, a


def _check_sweep(angles: np.ndarray) -> None:
    steps = wrap_angle(np.diff(angles))
    direction = 1.0 if steps[0] > 0 else -1.0
    bad = steps * direction <= 0.0
    if bad.any():
        i = int(np.flatnonzero(bad)[0]) + 1
        raise ValueError(
            "angles must be a strictly monotonic sweep (consecutive beams all turning the same "
            f"way), but the step from angles[{i - 1}] = {angles[i - 1]:.6g} to angles[{i}] = "
            f"{angles[i]:.6g} is {steps[i - 1]:.6g} rad"
        )
    total = abs(float(steps.sum()))
    if total >= 2.0 * math.pi:
        raise ValueError(
            f"angles must cover less than one full turn from first to last beam, got a sweep "
            f"of {total:.6g} rad (>= 2*pi): duplicated or repeated beams?"
        )


@dataclass(frozen=True, eq=False)
class Segment:
    """A run of consecutive beams that probably belong to one object.

    Beam indices refer to the scan arrays. In a circular (360 degree) scan a
    segment may wrap across the seam, in which case ``first_beam > last_beam``;
    ``beams`` always lists the indices in scan order.

    Attributes:
        first_beam: index of the first beam on the object.
        last_beam: index of the last beam on the object.
        beams: (n_beams,) int array of beam indices, in scan order.
        prev_beam: index of the beam just before ``first_beam`` (outside the
            segment), or ``None`` if there is none (whole-ring segment, or the
            field-of-view edge of a non-circular scan).
        next_beam: index of the beam just after ``last_beam``, or ``None``.
        prev_nearer: the beam at ``prev_beam`` hit something nearer than the
            segment's first point, i.e. the segment may continue hidden behind
            it (occlusion) on that side.
        next_nearer: same, for ``next_beam``.
    """

    first_beam: int
    last_beam: int
    beams: np.ndarray
    prev_beam: int | None
    next_beam: int | None
    prev_nearer: bool = False
    next_nearer: bool = False

    @property
    def n_beams(self) -> int:
        return int(self.beams.shape[0])


@dataclass(frozen=True)
class Detection:
    """One detected kin, in the observer frame.

    Attributes:
        range: distance from the observer (lidar centre) to the kin's centre, m.
        bearing: direction of the kin's centre, rad, CCW positive, 0 = heading,
            in (-pi, pi].
        x: forward coordinate of the kin's centre, m.
        y: left coordinate of the kin's centre, m.
        score: how kin-like the segment is, higher = more kin-like, in [0, 1].
            Geometric detector: ``F_threshold / (F_threshold + F)`` with ``F``
            the shape error (eq. 6), so ``score >= 0.5`` exactly when the shape
            filter passes (``F`` itself is in the segment's report). Learned
            detector: ``p(kin)``.
        first_beam, last_beam: beam indices bounding the segment (may wrap).
        n_beams: number of beams on the segment.
    """

    range: float
    bearing: float
    x: float
    y: float
    score: float
    first_beam: int
    last_beam: int
    n_beams: int


@dataclass(frozen=True, eq=False)
class SegmentReport:
    """What a detector decided about one segment, and why.

    Attributes:
        segment: the segment.
        stage: ``"accepted"`` or the name of the stage that rejected it
            (geometric detector: ``"diameter"``, ``"too_few_points"``,
            ``"shape"``).
        reason: human-readable explanation with the numbers that decided it.
        metrics: the stage numbers (e.g. ``d_cest``, ``omega_min``, ``F``),
            SI units, keyed by the paper's symbols.
    """

    segment: Segment
    stage: str
    reason: str
    metrics: Mapping[str, float] = field(default_factory=dict)

    @property
    def accepted(self) -> bool:
        return self.stage == "accepted"


class DetectionResult:
    """Detections of one scan plus one report per segment (in scan order).

    ``DetectionResult(detections, reports)``. The built-in detectors build ``reports`` lazily: the
    readable :class:`SegmentReport` objects of a whole batch are made on the first access to any
    scan's ``reports`` (an env that reads only ``detections`` never pays for them).
    """

    __slots__ = ("_lazy", "_reports", "detections")

    def __init__(self, detections: list[Detection], reports: list[SegmentReport] | None = None) -> None:
        self.detections = detections
        self._reports = [] if reports is None else reports
        self._lazy = None

    @classmethod
    def lazy(cls, detections: list[Detection], build: Callable[[], list[list[SegmentReport]]], b: int):
        """Scan ``b``'s result whose reports are ``build()[b]``, ``build`` called at most once per
        batch (it must cache its result)."""
        res = cls(detections)
        res._reports = None
        res._lazy = (build, b)
        return res

    @property
    def reports(self) -> list[SegmentReport]:
        if self._reports is None:
            build, b = self._lazy
            self._reports = build()[b]
            self._lazy = None
        return self._reports

    def __repr__(self) -> str:
        n = "?" if self._reports is None else len(self._reports)
        return f"DetectionResult(detections={self.detections!r}, reports=<{n} reports>)"


class LazyBatchReports:
    """Builds the per-scan report lists of a batch once, on the first call (see
    :meth:`DetectionResult.lazy`)."""

    __slots__ = ("_build", "_value")

    def __init__(self, build: Callable[[], list[list[SegmentReport]]]) -> None:
        self._build = build
        self._value = None

    def __call__(self) -> list[list[SegmentReport]]:
        if self._value is None:
            self._value = self._build()
            self._build = None
        return self._value


#: ``SegmentReport.stage`` of each :attr:`BatchDetections.seg_stage` code: accepted, rejected by the
#: geometric detector's diameter filter, too few points for its circle fit, its shape filter, or
#: rejected by the learned classifier.
STAGES = ("accepted", "diameter", "too_few_points", "shape", "learned")


@dataclass(frozen=True, eq=False)
class BatchDetections:
    """Detections and per-segment decisions of ``B`` scans as flat arrays (``detect_arrays``).

    Detections (``D`` of them, scan 0's first, each scan's in segment order; the same values as the
    :class:`Detection` objects ``detect_batch`` returns):

    Attributes:
        n_scans: ``B``.
        n_beams: beams per scan.
        scan: ``(D,)`` int64 scan row of each detection.
        range, bearing, x, y: ``(D,)`` float64 kin centre in the observer frame (m, rad, m, m).
        score: ``(D,)`` float64, higher = more kin-like (see :attr:`Detection.score`).
        first_beam, last_beam, n_beams_on: ``(D,)`` int64 beams bounding the segment (may wrap) and
            its number of beams.
        segment: ``(D,)`` int64 index of the detection's segment in the ``seg_*`` arrays.
        seg_scan, seg_first, seg_count: ``(S,)`` int64 scan row, first beam, number of beams of
            every segment (scan order).
        seg_prev, seg_next: ``(S,)`` int64 beam just outside the segment (-1 = none).
        seg_prev_nearer, seg_next_nearer: ``(S,)`` bool, as :class:`Segment`.
        seg_stage: ``(S,)`` int8 stage code, an index into :data:`STAGES`.
        seg_values: the stage numbers, name -> ``(S,)`` float64 (NaN where a stage did not run),
            keyed as the reports' ``metrics``.
    """

    n_scans: int
    n_beams: int
    scan: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    x: np.ndarray
    y: np.ndarray
    score: np.ndarray
    first_beam: np.ndarray
    last_beam: np.ndarray
    n_beams_on: np.ndarray
    segment: np.ndarray
    seg_scan: np.ndarray
    seg_first: np.ndarray
    seg_count: np.ndarray
    seg_prev: np.ndarray
    seg_next: np.ndarray
    seg_prev_nearer: np.ndarray
    seg_next_nearer: np.ndarray
    seg_stage: np.ndarray
    seg_values: Mapping[str, np.ndarray]

    @property
    def n_detections(self) -> int:
        return int(self.scan.shape[0])

    @property
    def n_segments(self) -> int:
        return int(self.seg_scan.shape[0])

    def counts(self) -> np.ndarray:
        """``(B,)`` number of detections in each scan."""
        return np.bincount(self.scan, minlength=self.n_scans)

    def offsets(self) -> np.ndarray:
        """``(B + 1,)``: scan ``b``'s detections are rows ``offsets[b]:offsets[b + 1]``."""
        return np.searchsorted(self.scan, np.arange(self.n_scans + 1))

    def padded(self, k: int) -> dict[str, np.ndarray]:
        """Fixed-shape view for vector envs: ``(B, k)`` slots per field, in each scan's order.

        Returns ``range``, ``bearing``, ``x``, ``y``, ``score`` (float64, NaN in empty slots),
        ``first_beam``, ``last_beam``, ``n_beams`` (int64, -1 in empty slots), ``mask`` ``(B, k)``
        bool and ``count`` ``(B,)`` (detections in the scan, which may exceed ``k``: the first ``k``
        are kept).
        """
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
            raise ValueError(f"padded: k must be an integer >= 0 (slots per scan), got {k!r}")
        k = int(k)
        off = self.offsets()
        slot = np.arange(self.n_detections) - off[self.scan]
        keep = slot < k
        rows, cols = self.scan[keep], slot[keep]
        out: dict[str, np.ndarray] = {}
        for name in ("range", "bearing", "x", "y", "score"):
            a = np.full((self.n_scans, k), np.nan)
            a[rows, cols] = getattr(self, name)[keep]
            out[name] = a
        for name, src in (
            ("first_beam", "first_beam"),
            ("last_beam", "last_beam"),
            ("n_beams", "n_beams_on"),
        ):
            a = np.full((self.n_scans, k), -1, dtype=np.int64)
            a[rows, cols] = getattr(self, src)[keep]
            out[name] = a
        mask = np.zeros((self.n_scans, k), dtype=bool)
        mask[rows, cols] = True
        out["mask"] = mask
        out["count"] = np.diff(off)
        return out

    def detections(self, b: int | None = None) -> list[Detection] | list[list[Detection]]:
        """:class:`Detection` objects of scan ``b``, or per scan for all (``b=None``)."""
        cols = (
            self.range.tolist(),
            self.bearing.tolist(),
            self.x.tolist(),
            self.y.tolist(),
            self.score.tolist(),
            self.first_beam.tolist(),
            self.last_beam.tolist(),
            self.n_beams_on.tolist(),
        )
        dets = list(map(Detection, *cols))
        off = self.offsets().tolist()
        if b is not None:
            return dets[off[b] : off[b + 1]]
        return [dets[off[i] : off[i + 1]] for i in range(self.n_scans)]

    def segments(self) -> list[Segment]:
        """Every segment as a :class:`Segment` (flat, in ``seg_*`` order)."""
        return segments_from_arrays(
            self.n_beams,
            self.seg_first,
            self.seg_count,
            self.seg_prev,
            self.seg_next,
            self.seg_prev_nearer,
            self.seg_next_nearer,
        )


def segments_from_arrays(n_beams, first, count, prev, nxt, prev_nearer, next_nearer) -> list[Segment]:
    """:class:`Segment` objects from flat segment arrays (``-1`` = no outside beam)."""
    last = (first + count - 1) % n_beams
    starts = np.cumsum(count) - count
    seg_id = np.repeat(np.arange(first.shape[0]), count)
    beams = np.arange(seg_id.shape[0]) + (first - starts)[seg_id]
    beams %= n_beams
    return [
        Segment(f, la, beams[o : o + k], p if p >= 0 else None, q if q >= 0 else None, pn, qn)
        for f, la, o, k, p, q, pn, qn in zip(
            first.tolist(),
            last.tolist(),
            starts.tolist(),
            count.tolist(),
            prev.tolist(),
            nxt.tolist(),
            prev_nearer.tolist(),
            next_nearer.tolist(),
            strict=True,
        )
    ]


class KinDetector(ABC):
    """Interface shared by the geometric and learned kin detectors.

    Both built-in detectors also have ``detect_arrays(ranges (B, n), angles (n,))`` returning a
    :class:`BatchDetections` (no per-object Python); ``detect_batch`` and ``detect`` are built from
    it.
    """

    @abstractmethod
    def detect(self, ranges, angles) -> DetectionResult:
        """Detect kins in one scan: ``ranges`` (n,) m, ``angles`` (n,) rad."""

    def detect_batch(self, ranges, angles) -> list[DetectionResult]:
        """Detect kins in ``B`` scans sharing one beam layout.

        Args:
            ranges: (B, n) metres.
            angles: (n,) radians, same for every scan.

        The default loops over :meth:`detect`; subclasses may vectorise.
        """
        r, a = validate_batch(ranges, angles)
        return [self.detect(row, a) for row in r]


@contextlib.contextmanager
def gc_paused():
    """Python's cyclic garbage collector paused inside the block; its previous state restored on exit
    (also when the block raises).

    For bursts of many short-lived objects without reference cycles (a batch's result objects, K
    sub-envs' resets): each few hundred allocations would trigger a collection, and the full ones
    traverse every object of the process (torch's included). Reference counting still frees the
    objects; the first collection after the block examines the survivors once."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
