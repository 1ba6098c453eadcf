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


def test_step_cap_check_never_skips_a_step_longer_than_the_cap():
    # _may_exceed_step may say False only when hypot(x, y) <= _GN_MAX_STEP: random steps around the cap,
    # steps of exactly the cap's length up to a few ulps, zeros, tiny, huge and non-finite values
    cap = F._GN_MAX_STEP
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * np.pi, 100_000)
    rad = cap * (1.0 + rng.normal(size=ang.size) * np.exp(rng.uniform(-40, -1, ang.size)))
    xs = np.concatenate([rad * np.cos(ang), [0.0, 1e-170, 1e-300, cap, 0.03, 1e200, np.inf, np.nan]])
    ys = np.concatenate([rad * np.sin(ang), [cap, 1e-170, 0.0, 0.0, 0.04, 0.0, 0.0, 0.0]])
    n_skipped = 0
    for x, y in zip(xs.tolist(), ys.tolist(), strict=True):
        may = _may_exceed(x, y)
        if not may:
            n_skipped += 1
            assert _hypot(x, y) <= cap, (x, y)
    assert 30_000 < n_skipped < 60_000  # the check does skip the short steps


@numba.njit
def _may_exceed(x, y):
    return F._may_exceed_step(x, y)


@numba.njit
def _hypot(x, y):
    return math.hypot(x, y)  # libm's, as the kernels


@numba.njit(error_model="numpy")
def _fit_one(px, py, cx, cy, r, gn_iters):
    # _features_kernel's per-segment circle fit (the expressions _fit_lanes runs in SIMD lanes), one segment:
    # (centre, F0, F_sum, e_max, signed residuals)
    n = px.shape[0]
    F0 = 0.0
    for k in range(n):
        F0 += abs(math.sqrt((px[k] - cx) ** 2 + (py[k] - cy) ** 2) - r)
    F0 /= n
    for _ in range(gn_iters):
        a11 = a12 = a22 = g1 = g2 = 0.0
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
        norm = math.hypot(stx, sty)
        if norm > F._GN_MAX_STEP:
            stx *= F._GN_MAX_STEP / norm
            sty *= F._GN_MAX_STEP / norm
        cx += stx
        cy += sty
    pe = np.empty(n)
    F_sum = 0.0
    e_max = 0.0
    for k in range(n):
        pe[k] = math.sqrt((px[k] - cx) ** 2 + (py[k] - cy) ** 2) - r
        e = abs(pe[k])
        F_sum += e
        e_max = max(e_max, e)
    return cx, cy, F0, F_sum, e_max, pe


@numba.njit(error_model="numpy")
def _lanes(n, c, px, py, cx, cy, ox, oy, cphi, sphi, dcest, r, gn_iters, kp, rs_lo, rs_hi, rs_w, x, fc):
    # (its scratch NaN-filled: the outputs must not depend on what it held)
    F._fit_lanes(n, c, 0, 0, px, py, cx, cy, np.arange(c), ox, oy, cphi, sphi, dcest, r, 1.0, gn_iters, kp,
                 rs_lo, rs_hi, rs_w, 0, x, fc, np.full((14 + n) * c, np.nan))  # fmt: skip


def test_circle_fits_in_simd_lanes_are_the_per_segment_fits():
    # _fit_lanes (segments of n beams side by side) against the per-segment expressions above (hypot on every
    # step): kin-like arcs with noise, lines, points far off the circle (long, capped steps), 1-100 lanes
    rng = np.random.default_rng(4)
    r = 0.035
    kp = 8
    for trial in range(60):
        n = int(rng.integers(2, F._FIT_LANES_MAX + 1))
        c = int(rng.integers(1, 100))
        gn_iters = int(rng.integers(0, 5))
        rng_ = rng.uniform(0.2, 8.0, c)
        bear = rng.uniform(-np.pi, np.pi, c)
        centre = np.stack([(rng_ + r) * np.cos(bear), (rng_ + r) * np.sin(bear)], 1)
        t = np.linspace(-1.0, 1.0, n)[:, None] * rng.uniform(0.1, 1.4, c)[None, :]
        kind = rng.integers(0, 3, c)
        px = centre[:, 0] - r * np.cos(bear + t) * (kind != 1) + t * 0.05 * np.sin(bear) * (kind == 1)
        py = centre[:, 1] - r * np.sin(bear + t) * (kind != 1) - t * 0.05 * np.cos(bear) * (kind == 1)
        px = px + rng.normal(size=px.shape) * 10.0 ** rng.uniform(-5, -1.5) * (1 + 20 * (kind == 2))
        py = py + rng.normal(size=py.shape) * 10.0 ** rng.uniform(-5, -1.5) * (1 + 20 * (kind == 2))
        d = np.hypot(px, py)
        kmin = d.argmin(0)
        grow = 1.0 + r / d[kmin, np.arange(c)]
        cx0 = px[kmin, np.arange(c)] * grow
        cy0 = py[kmin, np.arange(c)] * grow
        ox, oy = px.mean(0), py.mean(0)
        phi = np.arctan2(oy, ox)
        cphi, sphi = np.cos(phi), np.sin(phi)
        dcest = d.min(0) + r
        rs_lo = np.zeros((n + 1, kp), np.int64)
        rs_hi = np.zeros((n + 1, kp), np.int64)
        rs_w = np.zeros((n + 1, kp))
        for j in range(kp):
            tt = j * (n - 1) / (kp - 1)
            lo = min(int(math.floor(tt)), n - 1)
            rs_lo[n, j], rs_hi[n, j], rs_w[n, j] = lo, min(lo + 1, n - 1), tt - lo
        x = np.zeros((c, 24 + kp), np.float32)
        fc = np.zeros((c, 2))
        cx, cy = cx0.copy(), cy0.copy()
        _lanes(n, c, np.ascontiguousarray(px).ravel(), np.ascontiguousarray(py).ravel(), cx, cy, ox, oy, cphi,
               sphi, dcest, r, gn_iters, kp, rs_lo, rs_hi, rs_w, x, fc)  # fmt: skip
        for q in range(c):
            fx, fy, f0, fs, em, pe = _fit_one(px[:, q].copy(), py[:, q].copy(), cx0[q], cy0[q], r, gn_iters)
            assert fc[q, 0] == fx and fc[q, 1] == fy, (trial, q)
            fdx, fdy = fx - ox[q], fy - oy[q]
            want = [_log_err(f0), _log_err(fs), _log_err(fs / n), _log_err(em),
                    _clip_hypot(fx, fy, dcest[q]),
                    min(max(fdx * cphi[q] + fdy * sphi[q], -F._OFF_CLIP), F._OFF_CLIP),
                    min(max(-fdx * sphi[q] + fdy * cphi[q], -F._OFF_CLIP), F._OFF_CLIP), 1.0]  # fmt: skip
            assert np.array_equal(x[q, 11:19], np.float32(want)), (trial, q)
            res = [min(max(pe[rs_lo[n, j]] * (1.0 - rs_w[n, j]) + pe[rs_hi[n, j]] * rs_w[n, j], -F._RES_CLIP),
                       F._RES_CLIP) for j in range(kp)]  # fmt: skip
            assert np.array_equal(x[q, 24:], np.float32(res)), (trial, q)


@numba.njit(error_model="numpy")
def _log_err(e):
    return F._log_err(e)


@numba.njit(error_model="numpy")
def _clip_hypot(x, y, d):
    return slow(x, y, d, -F._OFF_CLIP, F._OFF_CLIP)


@numba.njit(cache=False, error_model="numpy")
def _wrap_fmod(a):
    # _kernels.wrap as it was: always through Python's float modulo (fmod)
    w = (a + math.pi) % (2.0 * math.pi) - math.pi
    return w + 2.0 * math.pi if w <= -math.pi else w


@numba.njit(cache=False, error_model="numpy")
def _wrap_all(a, out):
    for i in range(a.shape[0]):
        out[i] = _k.wrap(a[i])


def test_wrap_without_fmod_is_the_fmod_expression():
    # _kernels.wrap skips the fmod where it returns its argument exactly (0 < a + pi < 2 pi): the same
    # bits everywhere, at the edges (+-pi, +-0, the neighbours of the branch's limits), far out and NaN
    rng = np.random.default_rng(3)
    edges = [math.pi, -math.pi, 0.0, -0.0, 2 * math.pi, -2 * math.pi, 3 * math.pi, np.inf, -np.inf, np.nan]
    edges += [np.nextafter(v, s) for v in (math.pi, -math.pi, 2 * math.pi - math.pi) for s in (-10.0, 10.0)]
    a = np.concatenate([
        np.array(edges), rng.uniform(-math.pi, math.pi, 200_000), rng.uniform(-50.0, 50.0, 50_000),
        np.arctan2(rng.normal(size=50_000), rng.normal(size=50_000)), rng.normal(scale=1e-300, size=1000),
    ])  # fmt: skip
    got = np.empty_like(a)
    _wrap_all(a, got)
    ref = np.array([_wrap_fmod(v) for v in a])
    assert np.array_equal(got.view(np.int64), ref.view(np.int64))


@numba.njit(error_model="numpy")
def _log_errs_fast(e, out, fell_back):
    # as the feature kernels use them: the SIMD loop, then libm's log where it gave NaN
    for i in range(e.shape[0]):
        out[i] = F._log_err_f32(e[i])
    for i in range(e.shape[0]):
        fell_back[i] = out[i] != out[i]
        out[i] = F._log_err_or(out[i], e[i])


@numba.njit(error_model="numpy")
def _log_errs_libm(e, out):
    for i in range(e.shape[0]):
        out[i] = math.log(min(e[i], F._ERR_CLIP) + F._ERR_FLOOR)  # the kernels' previous expression


def test_log_error_without_libm_is_the_float32_of_libm_log():
    # _log_err_f32 (a polynomial with an error interval, libm's log at float32 rounding edges) stores the
    # float32 that libm's log gives, on random residuals, residuals whose log is a float32 midpoint, and edges
    rng = np.random.default_rng(1)
    mids = np.float32(rng.uniform(math.log(F._ERR_FLOOR), math.log(F._ERR_CLIP + F._ERR_FLOOR), 20_000))
    mids = (mids.astype(np.float64) + np.nextafter(mids, np.float32(0)).astype(np.float64)) / 2
    # residuals whose log(e + floor) is within ~1e-13 of a float32 midpoint
    mids = np.exp(mids[np.exp(mids) - F._ERR_FLOOR >= 0]) - F._ERR_FLOOR
    e = np.concatenate([
        rng.uniform(0.0, 0.12, 2_000_000), 10.0 ** rng.uniform(-14, 0.5, 2_000_000), mids,
        [0.0, -0.0, 5e-324, 1e-300, 0.1, np.nextafter(0.1, 1), np.nextafter(0.1, 0), 0.2, 1e300, np.inf,
         np.nan],
        np.sqrt(2.0) * 2.0 ** np.arange(-14, -3) - F._ERR_FLOOR, 2.0 ** np.arange(-14, -3) - F._ERR_FLOOR,
    ])  # fmt: skip
    fast, libm = np.empty_like(e), np.empty_like(e)
    fell_back = np.zeros(e.size, dtype=np.bool_)
    _log_errs_fast(e, fast, fell_back)
    _log_errs_libm(e, libm)
    f32, ref = fast.astype(np.float32), libm.astype(np.float32)
    same = (f32.view(np.int32) == ref.view(np.int32)) | (np.isnan(f32) & np.isnan(ref))
    assert same.all(), e[~same][:10]
    n_mid = mids.size
    mid_fb = fell_back[4_000_000 : 4_000_000 + n_mid]
    # at a float32 midpoint the interval cannot decide: libm's log; elsewhere almost never
    assert mid_fb.mean() > 0.99, mid_fb.mean()
    assert fell_back[:4_000_000].mean() < 1e-4
    assert fell_back[-(11 + 22) : -22][10]  # NaN (inf is clipped to _ERR_CLIP)


def test_preprocess_rows_is_the_numpy_preprocess():
    # preprocess_rows (without the spike filter it writes each row straight into out) against the numpy
    # geometric.preprocess row by row: 0.0, negative, NaN, +-inf, above d_max, float64 and the lidar's float32
    # readings, with a fresh output, an output full of stale values and in place; with the filter too
    from detectors.geometric import preprocess

    rng = np.random.default_rng(3)
    r = rng.uniform(-1.0, 14.0, (16, 90))
    special = rng.random(r.shape)
    r[special < 0.05] = 0.0
    r[(special >= 0.05) & (special < 0.1)] = np.nan
    r[(special >= 0.1) & (special < 0.15)] = np.inf
    r[(special >= 0.15) & (special < 0.2)] = -np.inf
    for src in (r, r.astype(np.float32)):
        for noise_filter in (False, True):
            for circular in (True, False):
                ref = np.stack([preprocess(row, 12.0, noise_filter, circular, 0.1) for row in src])
                out = np.full(r.shape, 99.0)
                _k.preprocess_rows(src, 12.0, 0.1, circular, noise_filter, out)
                assert np.array_equal(out, ref), (src.dtype, noise_filter, circular)
    inplace = r.copy()
    _k.preprocess_rows(inplace, 12.0, 0.1, True, False, inplace)
    assert np.array_equal(inplace, np.stack([preprocess(row, 12.0) for row in r]))
