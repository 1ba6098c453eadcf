"""Exact fast paths of the learned detector's kernels: values the slow expression would give, bit for bit."""

import math

import numba
import numpy as np

from detectors import _kernels as _k
from detectors import features as F


@numba.njit
def slow(x, y, d, lo, hi):
    # the kernels' previous expression, compiled: numba's math.hypot is libm's (Python's own differs in the
    # last bit in places)
    return np.float64(np.float32(min(max(math.hypot(x, y) - d, lo), hi)))


def test_clip_hypot_without_hypot_is_the_float32_of_hypot():
    # _f32_clip_hypot's sqrt(x * x + y * y) with a fallback at float32 rounding edges: the chord (d = 0,
    # clip [0, 0.3]) and the fitted centre's range offset (d ~ range, clip +-0.1) on random and edge values
    rng = np.random.default_rng(0)
    n = 200_000
    x = rng.normal(size=n) * np.exp(rng.uniform(-12, 3, n))
    y = rng.normal(size=n) * np.exp(rng.uniform(-12, 3, n))
    d = np.hypot(x, y) + rng.normal(size=n) * np.exp(rng.uniform(-25, -1, n))  # offsets down to ~1e-11
    cases = [(x, y, 0.0 * d, 0.0, F._LEN_CLIP), (x, y, d, -F._OFF_CLIP, F._OFF_CLIP)]
    # values right at float32 rounding edges (a float32 midpoint) and at the clips, zeros, tiny and huge
    mids = (np.nextafter(np.float32(rng.uniform(0.001, 0.3, 2000)), np.float32(1)).astype(np.float64)
            + np.float32(rng.uniform(0.001, 0.3, 2000)).astype(np.float64)) / 2  # fmt: skip
    ang = rng.uniform(0, 2 * np.pi, mids.size)
    cases.append((mids * np.cos(ang), mids * np.sin(ang), 0.0 * mids, 0.0, F._LEN_CLIP))
    edge = np.array([0.0, -0.0, 1e-160, 1e-300, 5e-324, 0.3, 0.1, 1e200, 3.0, 2.5])
    ex, ey = np.meshgrid(edge, edge)
    off = (-F._OFF_CLIP, F._OFF_CLIP)
    for dd, lo, hi in ((0.0, 0.0, F._LEN_CLIP), (3.0, *off), (2.9, *off)):
        cases.append((ex.ravel(), ey.ravel(), np.full(ex.size, dd), lo, hi))
    n_fallback = 0
    for xs, ys, ds, lo, hi in cases:
        for a, b, c in zip(xs.tolist(), ys.tolist(), ds.tolist(), strict=True):
            got, ref = F._f32_clip_hypot(a, b, c, lo, hi), slow(a, b, c, lo, hi)
            assert np.float64(got).tobytes() == np.float64(ref).tobytes(), (a, b, c, lo, hi)
            n_fallback += takes_hypot(a, b, c, lo, hi)
    assert n_fallback > 100  # the edge cases reach the exact fallback


def takes_hypot(x, y, d, lo, hi):
    # _f32_clip_hypot's test for its fallback, in Python
    a = math.sqrt(x * x + y * y)
    if not 1e-150 < a < 1e150:
        return True
    e = a * F._HYPOT_EPS
    f_lo, f_hi = (np.float32(min(max(v - d, lo), hi)) for v in (a - e, a + e))
    return not (f_lo == f_hi and f_lo != 0.0)


@numba.njit
def segment_rows_walk(d, d_th, d_max, circular, scan, first, count, prev, nxt, prev_nearer, next_nearer):
    # the previous segment_rows (a branch per beam, a walk per segment), the reference of the branch-free one
    n_rows, n = d.shape
    hi = d_max + 2.0 * d_th
    brk = np.empty(n, dtype=np.bool_)
    s = 0
    for b in range(n_rows):
        prev_e = d[b, n - 1] if d[b, n - 1] < d_max else hi
        all_valid = True
        for i in range(n):
            e = d[b, i] if d[b, i] < d_max else hi
            brk[i] = True if (i == 0 and not circular) else abs(e - prev_e) > d_th
            prev_e = e
            if not d[b, i] < d_max:
                all_valid = False
        s0 = s
        for f in range(n):
            if not (brk[f] and d[b, f] < d_max):
                continue
            k = f
            c = 1
            nk = k + 1 if k < n - 1 else 0
            while not brk[nk]:
                k = nk
                nk = k + 1 if k < n - 1 else 0
                c += 1
            scan[s], first[s], count[s] = b, f, c
            if circular:
                p, q = (f - 1) % n, (k + 1) % n
            else:
                p, q = f - 1, (k + 1 if k < n - 1 else -1)
            prev[s], nxt[s] = p, q
            prev_nearer[s] = p >= 0 and d[b, p] < d[b, f]
            next_nearer[s] = q >= 0 and d[b, q] < d[b, k]
            s += 1
        if s == s0 and all_valid:
            scan[s], first[s], count[s], prev[s], nxt[s] = b, 0, n, -1, -1
            prev_nearer[s] = next_nearer[s] = False
            s += 1
    return s


def test_branch_free_segmentation_is_the_walk():
    # random pre-processed scans (no return = d_max), both sweeps, 1-360 beams: breaks everywhere, runs of
    # no returns, rings without a break, rows of only no returns, steps of exactly d_th
    rng = np.random.default_rng(1)
    d_th, d_max = 0.1, 12.0
    n_seg = 0
    for trial in range(400):
        n = int(rng.choice([1, 2, 3, 4, 7, 31, 360]))
        rows = int(rng.integers(1, 9))
        base = rng.uniform(0.2, 11.0, (rows, 1))
        step = rng.choice([0.0, 0.05, d_th, 0.3], (rows, n), p=[0.4, 0.3, 0.1, 0.2])
        d = base + np.cumsum(step * rng.choice([-1.0, 1.0], (rows, n)), axis=1)
        d = np.where(rng.random((rows, n)) < rng.choice([0.0, 0.1, 0.5]), d_max, d)
        d = np.clip(d, 0.01, d_max)
        if trial % 50 == 0:
            d[0] = 3.0  # a ring
        if trial % 50 == 1:
            d[-1] = d_max  # nothing
        for circular in (True, False):
            got, ref = outputs(rows * n), outputs(rows * n)
            s = _k.segment_rows(d, d_th, d_max, circular, *got)
            assert s == segment_rows_walk(d, d_th, d_max, circular, *ref)
            for a, b in zip(got, ref, strict=True):
                assert np.array_equal(a[:s], b[:s])
            n_seg += s
    assert n_seg > 10_000


def outputs(cap):
    return [np.zeros(cap, np.int64) for _ in range(5)] + [np.zeros(cap, bool) for _ in range(2)]
