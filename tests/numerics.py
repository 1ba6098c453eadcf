"""Comparing compiled kernels with numpy references: bit for bit where numpy's float64 math is libm's.

numpy runs float64 ``exp``, ``log``, ``arctan2``, ``sin``, ``cos``, ... through SIMD code (SVML) on CPUs
with AVX-512 (numpy's ``AVX512_SKX`` dispatch target), accurate to a few ULP but not always the C
library's result, which numba's compiled code calls. So a kernel and the numpy expression of the same
formula agree bit for bit on an AVX2 machine and only to a few ULP on an AVX-512 one (seen on these
machines: ``np.arctan2`` against ``math.atan2``, numpy's softmax against the driver's). Tests that
compare compiled code with a numpy reference use :func:`assert_same_values`: bitwise where numpy's
float64 math is libm's, else equal up to ``RTOL`` / ``ATOL`` (integers, NaN positions and infinities
always exactly).
"""

from __future__ import annotations

import numpy as np

try:  # numpy >= 2
    from numpy._core._multiarray_umath import __cpu_features__ as _FEATURES
except ImportError:  # pragma: no cover - numpy 1.x
    from numpy.core._multiarray_umath import __cpu_features__ as _FEATURES

#: numpy dispatches float64 transcendental functions to AVX-512 SVML code on this CPU
NUMPY_SIMD_MATH = bool(_FEATURES.get("AVX512_SKX", False))
#: tolerance where it does: a few ULP of the O(1) quantities compared (metres, radians, probabilities)
RTOL, ATOL = (1e-12, 1e-12) if NUMPY_SIMD_MATH else (0.0, 0.0)


def same_values(a, b) -> bool:
    """``a`` and ``b`` equal (NaN equal to NaN): bitwise, or within ``RTOL``/``ATOL`` for float arrays
    where numpy's math is not libm's (NaN and infinity positions always exactly)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    floats = np.issubdtype(a.dtype, np.floating) and np.issubdtype(b.dtype, np.floating)
    if not NUMPY_SIMD_MATH or not floats:
        return bool(np.array_equal(a, b, equal_nan=True))
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not (np.array_equal(fa, fb) and np.array_equal(a[~fa], b[~fb], equal_nan=True)):
        return False
    return bool(np.allclose(a[fa], b[fb], rtol=RTOL, atol=ATOL))


def assert_same_values(a, b, msg: str = "") -> None:
    """Assert :func:`same_values`; the message names the field and the largest difference."""
    if not same_values(a, b):
        a, b = np.asarray(a), np.asarray(b)
        detail = ""
        if a.shape == b.shape and a.size:
            with np.errstate(invalid="ignore"):
                diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
            detail = f" (largest difference {np.nanmax(diff) if np.isfinite(diff).any() else 'n/a'})"
        raise AssertionError(f"{msg}: values differ{detail}; numpy SIMD math: {NUMPY_SIMD_MATH}")
