"""Lidar kin detectors: the paper's geometric detector, the learned one and the shared interface.

``import detectors`` stays light (numpy/scipy): ``LearnedKinDetector`` (torch) is loaded on first
access, and the evaluation harness lives in :mod:`detectors.evaluation`.
"""

from .base import (
    Detection,
    DetectionResult,
    KinDetector,
    Segment,
    SegmentReport,
    validate_batch,
    validate_scan,
    wrap_angle,
)
from .geometric import (
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


def __getattr__(name: str):
    # torch is imported only when the learned detector is asked for
    if name == "LearnedKinDetector":
        from .learned import LearnedKinDetector

        return LearnedKinDetector
    raise AttributeError(f"module 'detectors' has no attribute {name!r}")


__all__ = [
    "CircleFit",
    "LearnedKinDetector",
    "Detection",
    "DetectionResult",
    "DiameterCheck",
    "GeometricKinDetector",
    "GeometricParams",
    "KinDetector",
    "KinPosition",
    "Segment",
    "SegmentReport",
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
