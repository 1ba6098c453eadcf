"""Lidar kin detectors: the paper's geometric detector, the learned one and the shared interface.

A library for any 2D scan, simulated or recorded on a real robot: it never imports ``kin_envs`` (or
pymunk). ``import detectors`` stays light (numpy/scipy/numba): ``LearnedKinDetector`` (its compiled
driver) is loaded on first access. Only training and ``inference="torch"`` need torch
(:mod:`detectors.learned_torch`, the ``train`` extra). The dataset format and category names are in
:mod:`detectors.samples`; generating labelled data and evaluating against the simulator's ground truth
is on the simulator side (:mod:`kin_envs.detection`).

It reports through the ``detectors`` logger (``logging``; silent unless the application configures it).
"""

import logging

# kin-envs' marker: ``import kin_envs`` and ``detectors.base`` check for it, since an unrelated
# distribution named ``detectors`` exists and would shadow or overwrite this file (kin_envs._toplevel)
__kin_envs_package__ = True
logging.getLogger(__name__).addHandler(logging.NullHandler())

from . import _numba_cache  # noqa: E402,F401  (first: a cache directory before any @njit(cache=True))
from .base import (  # noqa: E402
    STAGES,
    BatchDetections,
    Detection,
    DetectionResult,
    KinDetector,
    Segment,
    SegmentReport,
    validate_batch,
    validate_scan,
    wrap_angle,
)
from .geometric import (  # noqa: E402
    CircleFit,
    DiameterCheck,
    GeometricKinDetector,
    GeometricParams,
    KinPosition,
    ShapeCheck,
    circle_residuals,
    filter_by_diameter,
    filter_by_shape,
    fit_circle,
    fit_circles,
    is_circular_sweep,
    position_kin,
    preprocess,
    range_derivative,
    segment,
    shape_error,
)
from .tracking import KinTracker, Track, TrackerParams  # noqa: E402


def __getattr__(name: str):
    # the learned detector's module (its compiled driver's cache) is loaded only when it is asked for
    if name == "LearnedKinDetector":
        from .learned import LearnedKinDetector

        return LearnedKinDetector
    raise AttributeError(f"module 'detectors' has no attribute {name!r}")


__all__ = [
    "STAGES",
    "BatchDetections",
    "CircleFit",
    "LearnedKinDetector",
    "Detection",
    "DetectionResult",
    "DiameterCheck",
    "GeometricKinDetector",
    "GeometricParams",
    "KinDetector",
    "KinPosition",
    "KinTracker",
    "Segment",
    "SegmentReport",
    "Track",
    "TrackerParams",
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
    "validate_batch",
    "validate_scan",
    "wrap_angle",
]
