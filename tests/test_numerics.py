"""tests/numerics.py: the comparison the kernel-vs-numpy tests use is exact where it must be."""

import math

import numpy as np

from tests import numerics


def test_integers_nan_and_infinities_compare_exactly():
    assert numerics.same_values(np.array([1, 2]), np.array([1, 2]))
    assert not numerics.same_values(np.array([1, 2]), np.array([1, 3]))
    a = np.array([np.nan, np.inf, -np.inf, 1.0])
    assert numerics.same_values(a, a.copy())
    assert not numerics.same_values(a, np.array([np.nan, np.inf, np.inf, 1.0]))
    assert not numerics.same_values(a, np.array([1.0, np.inf, -np.inf, 1.0]))
    assert not numerics.same_values(np.zeros(2), np.zeros(3))


def test_floats_bitwise_or_within_a_few_ulp_only_where_numpy_math_is_simd():
    x = np.linspace(0.1, 3.0, 50)
    one_ulp = np.nextafter(x, np.inf)
    assert numerics.same_values(x, one_ulp) == numerics.NUMPY_SIMD_MATH
    assert not numerics.same_values(x, x + 1e-6)  # a real difference fails on every CPU
    # what the tolerance is for: numpy's arctan2 against the C library's, as numba calls it
    y = np.random.default_rng(0).normal(size=(2, 500))
    ref = np.array([math.atan2(b, a) for a, b in y.T])
    assert numerics.same_values(np.arctan2(y[1], y[0]), ref)
