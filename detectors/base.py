"""Detector-agnostic types and input validation for lidar kin detection.

Scan convention (project-wide): a scan is ``ranges`` (n_beams,) in metres and
``angles`` (n_beams,) in radians, in the observer's frame, counter-clockwise
positive, 0 = robot heading, wrapped to (-pi, pi]. Non-finite ranges mean
"no return" and are legal input; what a detector does with them is its own
business (the geometric detector maps them to the maximum range, paper 4.1).

Nothing in this module is specific to the geometric (paper) detector, so a
learned detector can implement :class:`KinDetector` and reuse
:class:`Segment`, :class:`SegmentReport` and :func:`validate_scan`.
"""

from __future__ import annotations

import math
import sys
from abc import ABC, abstractmethod
from collections.abc import Mapping
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
    "Detection",
    "DetectionResult",
    "KinDetector",
    "Segment",
    "SegmentReport",
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
        score: detector-specific quality. Geometric detector: the shape error
            ``F`` in metres (lower = more circle-like). Learned detectors
            document their own meaning.
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


@dataclass(frozen=True, eq=False)
class DetectionResult:
    """Detections of one scan plus one report per segment (in scan order)."""

    detections: list[Detection]
    reports: list[SegmentReport]


class KinDetector(ABC):
    """Interface shared by the geometric and learned kin detectors."""

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
