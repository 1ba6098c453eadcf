"""Compiled (numba) kernels of the batch-first detector paths.

One pass per stage over *all* scans of a batch, writing flat per-segment arrays: pre-processing
(paper 4.1), segmentation (4.2), the diameter filter (4.3.1) and the known-radius circle fit
(4.3.2, the same Levenberg-Marquardt iteration as :func:`detectors.geometric.fit_circle`). The
numpy functions of :mod:`detectors.geometric` stay the readable one-segment reference; tests check
that both agree. ``error_model="numpy"`` throughout (no zero-divisor check per division; see
:mod:`detectors._learned_driver`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic


@intrinsic
def prefetch(typingctx, arr, idx):
    """``prefetch(arr, i)``: a hint that ``arr[i]`` (a contiguous 1-D array, ``0 <= i < len``) will be
    read soon (``llvm.prefetch``, read, into all cache levels). No effect on any value."""
    sig = types.void(arr, types.intp)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(builder.gep(ary.data, [args[1]]), i8p), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return sig, codegen

# Segment stage codes shared by both detectors (detectors.base.STAGES names them).
ACCEPTED, DIAMETER, TOO_FEW_POINTS, SHAPE, LEARNED = 0, 1, 2, 3, 4

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


@numba.njit(cache=True, error_model="numpy", nogil=True)
def preprocess_rows(r, d_max, d_th, circular, noise_filter, out):
    """Paper 4.1 on every row of ``r`` into ``out``: 0.0, negative, NaN and inf -> ``d_max``
    (a real RPLIDAR reports 0.0 for an invalid reading), clip at ``d_max``, optional spike filter
    (as :func:`detectors.geometric.preprocess`)."""
    n_rows, n = r.shape
    row = np.empty(n) if noise_filter else out[0, :0]  # (the filter's scratch; none without it)
    for b in range(n_rows):
        if not noise_filter:  # straight into out (the same values; no copy of every row)
            for i in range(n):
                v = r[b, i]
                out[b, i] = v if (v > 0.0 and v < d_max) else d_max
            continue
        for i in range(n):
            v = r[b, i]
            # NaN fails both comparisons, inf the second
            row[i] = v if (v > 0.0 and v < d_max) else d_max
        for i in range(n):
            d = row[i]
            if circular:
                a = row[i - 1] if i > 0 else row[n - 1]
                c = row[i + 1] if i < n - 1 else row[0]
            else:
                a = row[i - 1] if i > 0 else row[0]
                c = row[i + 1] if i < n - 1 else row[n - 1]
            up = d - a
            down = d - c
            if (up > d_th and down > d_th) or (up < -d_th and down < -d_th):
                d = max(min(a, d), min(max(a, d), c))  # median of three
            out[b, i] = d


@numba.njit(cache=True, error_model="numpy", nogil=True)
def segment_rows(d, d_th, d_max, circular, scan, first, count, prev, nxt, prev_nearer, next_nearer):
    """Paper 4.2 (eq. 1) on every row of pre-processed ``d`` (B, n), as
    :func:`detectors.geometric.segment`: maximal runs of beams ``< d_max`` without a break
    ``|d_i - d_{i-1}| > d_th`` (no return reads ``d_max + 2 d_th``, so a change between return and
    no return is always a break). Output arrays hold at least ``B * n`` entries; returns the number
    of segments written (scan 0's first, each scan's in order of first beam).

    Without branches on the data: the breaks' positions are compacted in one pass, then every break
    writes a segment (to the next break) into the next slot, kept when its first beam has a return (a
    noisy swarm scan breaks at ~1 beam in 3, unpredictably: a branch per beam and a walk per segment
    mispredicted)."""
    n_rows, n = d.shape
    pos = np.empty(n + 1, dtype=np.int64)
    s = 0
    for b in range(n_rows):
        row = d[b]
        m, n_valid = row_breaks(row, d_th, d_max, circular, pos)
        if m == 0:
            if n_valid == n:  # a ring without any break (round room): one segment
                scan[s] = b
                first[s] = 0
                count[s] = n
                prev[s] = -1
                nxt[s] = -1
                prev_nearer[s] = False
                next_nearer[s] = False
                s += 1
            continue
        for j in range(m):
            f, c, p, q, pn, nn = break_segment(row, pos, j, circular)
            scan[s] = b
            first[s] = f
            count[s] = c
            prev[s] = p
            nxt[s] = q
            prev_nearer[s] = pn
            next_nearer[s] = nn
            s += row[f] < d_max  # kept when its first beam has a return
    return s


@numba.njit(cache=True, error_model="numpy", inline="always")
def row_breaks(row, d_th, d_max, circular, pos):
    """:func:`segment_rows`' break pass over one row: the first beams of its segments compacted into
    ``pos`` (``pos[m]`` the end of the last one: the row's end, partial sweep, or around to the first
    break) and ``(m, number of beams with a return)``; ``m == 0``: no break (a ring if every beam
    returned, else nothing)."""
    n = row.shape[0]
    hi = d_max + 2.0 * d_th
    prev_e = row[n - 1] if row[n - 1] < d_max else hi
    m = 0
    n_valid = 0
    for i in range(n):
        v = row[i]
        ok = v < d_max
        e = v if ok else hi
        pos[m] = i
        m += abs(e - prev_e) > d_th or (i == 0 and not circular)
        n_valid += ok
        prev_e = e
    if m > 0:
        pos[m] = pos[0] + n if circular else n
    return m, n_valid


@numba.njit(cache=True, error_model="numpy", inline="always")
def break_segment(row, pos, j, circular):
    """Segment ``j`` of :func:`row_breaks`' ``pos``: ``(first, count, prev, next, prev_nearer,
    next_nearer)`` as :func:`segment_rows` writes them."""
    # (selects only, no short-circuit branch: inlined in a loop, the row's reference count is then taken and
    # dropped in one block, which numba's pruning removes; with branches it stayed, two atomic operations a
    # segment)
    n = row.shape[0]
    f = pos[j]
    c = pos[j + 1] - f
    k = f + c - 1  # last beam, < 2 n
    k = k - n if k >= n else k
    # (f - 1) % n and (k + 1) % n for 0 <= f, k < n without an integer division; -1 past a partial sweep
    p = f - 1 if (f > 0 or not circular) else n - 1
    q = k + 1 if k < n - 1 else (0 if circular else -1)
    return f, c, p, q, (p >= 0) & (row[max(p, 0)] < row[f]), (q >= 0) & (row[max(q, 0)] < row[k])


def segment_arrays(d: np.ndarray, d_th: float, d_max: float, circular: bool) -> tuple[np.ndarray, ...]:
    """Flat segments of pre-processed scans ``d`` (B, n) with :func:`segment_rows`: ``(scan, first,
    count, prev, next, prev_nearer, next_nearer)`` arrays (int64 x 5, bool x 2)."""
    return _segment_arrays(d, d_th, d_max, circular)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _segment_views(d, d_th, d_max, circular):
    # _segment_arrays as views of the (B * n) buffers, for callers that drop them within the call
    # (the learned driver): no copies
    cap = d.shape[0] * d.shape[1]
    scan = np.empty(cap, dtype=np.int64)
    first = np.empty(cap, dtype=np.int64)
    count = np.empty(cap, dtype=np.int64)
    prev = np.empty(cap, dtype=np.int64)
    nxt = np.empty(cap, dtype=np.int64)
    p_near = np.empty(cap, dtype=np.bool_)
    n_near = np.empty(cap, dtype=np.bool_)
    s = segment_rows(d, d_th, d_max, circular, scan, first, count, prev, nxt, p_near, n_near)
    return scan[:s], first[:s], count[:s], prev[:s], nxt[:s], p_near[:s], n_near[:s]


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _segment_arrays(d, d_th, d_max, circular):
    # buffers and exact-size copies made inside one compiled call: for one scan, 14 numpy
    # allocations and 7 slices from Python cost more than the segmentation itself
    scan, first, count, prev, nxt, p_near, n_near = _segment_views(d, d_th, d_max, circular)
    return scan.copy(), first.copy(), count.copy(), prev.copy(), nxt.copy(), p_near.copy(), n_near.copy()


@numba.njit(cache=True, error_model="numpy", inline="always")
def _half_width(d_cest, alpha):
    # eqs. 4-5 half-widths; an angle >= 90 deg from the min beam bounds no finite diameter
    return d_cest * math.tan(alpha) if alpha < _HALF_PI else math.inf


@numba.njit(cache=True, error_model="numpy", nogil=True)
def lm_fit(px, py, n, r, rc, tc, max_iter, xtol, lam0, lam_max):
    """:func:`detectors.geometric._lm_scalar` compiled: known-radius circle fit of the first ``n``
    points (Cartesian ``px, py``) from the polar centre ``(rc, tc)``. Same iteration, so the same
    fit up to rounding. Returns ``(r_c, theta_c (not wrapped), sum |e_i|)``."""
    a11, a12, a22, g1, g2, cost, sabs = _lm_eval(px, py, n, r, rc, tc)
    lam = lam0
    nu = 2.0
    s1 = a11
    s2 = a22
    tol2 = (xtol * rc) ** 2
    for _ in range(max_iter):
        s1 = max(s1, a11)
        s2 = max(s2, a22)
        m11 = a11 + lam * s1
        m22 = a22 + lam * s2
        det = m11 * m22 - a12 * a12
        if not det > 0.0:
            break
        drc = (a12 * g2 - m22 * g1) / det
        dtc = (a12 * g1 - m11 * g2) / det
        if not drc * drc + (dtc * rc) ** 2 > tol2:
            break
        b11, b12, b22, h1, h2, new_cost, new_sabs = _lm_eval(px, py, n, r, rc + drc, tc + dtc)
        gain = cost - new_cost
        if gain > 0.0:
            rho = gain / (drc * (lam * s1 * drc - g1) + dtc * (lam * s2 * dtc - g2))
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            rc = rc + drc
            tc = tc + dtc
            a11, a12, a22, g1, g2, cost, sabs = b11, b12, b22, h1, h2, new_cost, new_sabs
        else:
            lam *= nu
            nu *= 2.0
            if lam > lam_max:
                break
    return rc, tc, sabs


@numba.njit(cache=True, error_model="numpy", inline="always")
def _lm_eval(px, py, n, r, rc, tc):
    # points rotated by -theta_c put the centre at (r_c, 0): q = rotated point - centre,
    # e = |q| - r; one cos/sin per evaluation instead of one per point
    c = math.cos(tc)
    s = math.sin(tc)
    a11 = a12 = a22 = g1 = g2 = cost = sabs = 0.0
    for k in range(n):
        qx = px[k] * c + py[k] * s - rc
        qy = py[k] * c - px[k] * s
        nd = -math.sqrt(qx * qx + qy * qy)
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


@numba.njit(cache=True, error_model="numpy", inline="always")
def _mod_two_pi(x):
    """``x % (2 pi)``, the same value: Python's float modulo is ``fmod`` (slow) and ``fmod(x, 2 pi)`` is ``x``
    itself for ``0 < x < 2 pi``, where the sign fix-up does nothing."""
    return x if (x > 0.0 and x < _TWO_PI) else x % _TWO_PI


@numba.njit(cache=True, error_model="numpy", inline="always")
def wrap(a):
    """Angle to (-pi, pi] (as :func:`detectors.base.wrap_angle` on arrays)."""
    # (an atan2's angle, the detections' bearings, always takes _mod_two_pi's branch without fmod)
    w = _mod_two_pi(a + math.pi) - math.pi
    return w + _TWO_PI if w <= -math.pi else w


@numba.njit(cache=True, error_model="numpy", inline="always")
def _omega_max(dc, am, ang, p, q, p_nearer, q_nearer, sweep, occlusion_unbounded):
    """eq. 5's ``omega_max``: the half-widths at ``d_cest`` from the min beam's angle ``am`` to the previous
    beam ``p`` and to the next beam ``q`` (inf where there is none, or where it is nearer and
    ``occlusion_unbounded``)."""
    h_p = math.inf
    if not (p < 0 or (occlusion_unbounded and p_nearer)):
        h_p = _half_width(dc, _mod_two_pi((ang[p] - am) * -sweep))
    h_q = math.inf
    if not (q < 0 or (occlusion_unbounded and q_nearer)):
        h_q = _half_width(dc, _mod_two_pi((ang[q] - am) * sweep))
    return h_p + h_q


@numba.njit(cache=True, error_model="numpy", nogil=True)
def geometric_segments(
    d,
    ang,
    sweep,
    scan,
    first,
    count,
    prev,
    nxt,
    prev_nearer,
    next_nearer,
    r,
    F_threshold,
    mean_metric,
    occlusion_unbounded,
    min_points,
    max_iter,
    xtol,
    lam0,
    lam_max,
    stage,
    min_beam,
    d_cest,
    omega_min,
    omega_max,
    F,
    r_c,
    theta_c,
):
    """Paper 4.3 for every segment: eqs. 2-5 (as :func:`detectors.geometric.filter_by_diameter`),
    then for candidates with ``>= min_points`` beams the eq. 6-7 fit and the shape decision.
    Writes the stage code and the stage numbers of segment ``i`` into row ``i`` of the outputs
    (``F``, ``r_c``, ``theta_c`` NaN where there was no fit)."""
    n_beams = ang.shape[0]
    cos_a = np.cos(ang)
    sin_a = np.sin(ang)
    px = np.empty(n_beams)
    py = np.empty(n_beams)
    diameter = 2.0 * r
    for i in range(scan.shape[0]):
        b = scan[i]
        f = first[i]
        n = count[i]
        kmin = 0
        dmin = d[b, f]
        j = f
        for k in range(n):
            v = d[b, j]
            px[k] = v * cos_a[j]
            py[k] = v * sin_a[j]
            if v < dmin:  # the first minimum in scan order, as np.argmin
                dmin = v
                kmin = k
            j = j + 1 if j < n_beams - 1 else 0
        mb = (f + kmin) % n_beams
        last = (f + n - 1) % n_beams
        dc = dmin + r  # eq. 2
        am = ang[mb]
        # angles turned along the sweep from the first / previous beam to the min beam and from
        # it to the last / next beam
        o_min = _half_width(dc, _mod_two_pi((ang[f] - am) * -sweep)) + _half_width(
            dc, _mod_two_pi((ang[last] - am) * sweep)
        )
        o_max = _omega_max(dc, am, ang, prev[i], nxt[i], prev_nearer[i], next_nearer[i], sweep,
                           occlusion_unbounded)
        min_beam[i] = mb
        d_cest[i] = dc
        omega_min[i] = o_min
        omega_max[i] = o_max
        F[i] = math.nan
        r_c[i] = math.nan
        theta_c[i] = math.nan
        if o_min > diameter or not diameter < o_max:  # eq. 3
            stage[i] = DIAMETER
            continue
        if n < min_points:
            stage[i] = TOO_FEW_POINTS
            continue
        rc, tc, sabs = lm_fit(px, py, n, r, dc, am, max_iter, xtol, lam0, lam_max)  # eq. 7 start
        err = sabs / n if mean_metric else sabs
        F[i] = err
        r_c[i] = rc
        theta_c[i] = wrap(tc)
        stage[i] = ACCEPTED if err < F_threshold else SHAPE


@numba.njit(cache=True, error_model="numpy", nogil=True)
def accepted_segments(d, ang, sweep, scan, first, count, prev, nxt, prev_nearer, next_nearer, r,
                      F_threshold, mean_metric, occlusion_unbounded, min_points, max_iter, xtol, lam0,
                      lam_max, accepted, F, r_c, theta_c):  # fmt: skip
    """:func:`geometric_segments` for a caller that keeps the accepted segments only (the envs' table):
    ``accepted[i]`` is ``stage[i] == ACCEPTED`` and, for those, ``F``, ``r_c``, ``theta_c`` are its values,
    bit for bit (the same expressions in the same order); other rows of them are left unset. A segment with
    fewer than ``min_points`` beams is rejected before any arithmetic (its stage, DIAMETER or
    TOO_FEW_POINTS, is a rejection either way), the next-beam half-width only when the first passes and the
    points only for a fit: ~40-60 % of the segments of a swarm's or KinSeek's scans have 1-2 beams."""
    fitted_segments(d, ang, sweep, scan, first, count, prev, nxt, prev_nearer, next_nearer, r, F_threshold,
                    F_threshold, mean_metric, occlusion_unbounded, min_points, max_iter, xtol, lam0, lam_max,
                    accepted, accepted, F, r_c, theta_c)  # fmt: skip


@numba.njit(cache=True, error_model="numpy", nogil=True)
def fitted_segments(d, ang, sweep, scan, first, count, prev, nxt, prev_nearer, next_nearer, r, F_threshold,
                    F_keep, mean_metric, occlusion_unbounded, min_points, max_iter, xtol, lam0, lam_max,
                    accepted, kept, F, r_c, theta_c):  # fmt: skip
    """:func:`accepted_segments`, which also keeps (``kept``) the segments whose fit reached ``F`` <
    ``F_keep`` (>= ``F_threshold``: stage ``ACCEPTED`` or ``SHAPE`` with that ``F``; the envs' permissive
    feed, ``kin_envs.envs.tracks.PermissiveFeed``), their ``F``, ``r_c``, ``theta_c`` those of
    :func:`geometric_segments` bit for bit. ``kept`` may be ``accepted`` itself (``F_keep`` =
    ``F_threshold``)."""
    n_beams = ang.shape[0]
    cos_a = np.cos(ang)
    sin_a = np.sin(ang)
    px = np.empty(n_beams)
    py = np.empty(n_beams)
    diameter = 2.0 * r
    for i in range(scan.shape[0]):
        accepted[i] = False
        kept[i] = False
        n = count[i]
        if n < min_points:
            continue
        b = scan[i]
        f = first[i]
        kmin = 0
        dmin = d[b, f]
        j = f
        for k in range(n):
            v = d[b, j]
            if v < dmin:  # the first minimum in scan order, as np.argmin
                dmin = v
                kmin = k
            j = j + 1 if j < n_beams - 1 else 0
        mb = (f + kmin) % n_beams
        last = (f + n - 1) % n_beams
        dc = dmin + r  # eq. 2
        am = ang[mb]
        a_first = _mod_two_pi((ang[f] - am) * -sweep)
        a_last = _mod_two_pi((ang[last] - am) * sweep)
        # tan(x) >= x on [0, pi/2): dc (a_first + a_last) bounds omega_min from below, so a segment it puts
        # over the diameter (with a margin far above the few ulps of the tans, products and sum) is one
        # that omega_min rejects, without the two tans
        if a_first < _HALF_PI and a_last < _HALF_PI and dc < math.inf:
            if dc * (a_first + a_last) * (1.0 - 1e-12) > diameter:
                continue
        o_min = _half_width(dc, a_first) + _half_width(dc, a_last)
        if o_min > diameter:  # eq. 3, the lower bound
            continue
        o_max = _omega_max(dc, am, ang, prev[i], nxt[i], prev_nearer[i], next_nearer[i], sweep,
                           occlusion_unbounded)
        if not diameter < o_max:  # eq. 3, the upper bound
            continue
        j = f
        for k in range(n):
            v = d[b, j]
            px[k] = v * cos_a[j]
            py[k] = v * sin_a[j]
            j = j + 1 if j < n_beams - 1 else 0
        rc, tc, sabs = lm_fit(px, py, n, r, dc, am, max_iter, xtol, lam0, lam_max)  # eq. 7 start
        err = sabs / n if mean_metric else sabs
        if err < F_keep:
            accepted[i] = err < F_threshold
            kept[i] = True
            F[i] = err
            r_c[i] = rc
            theta_c[i] = wrap(tc)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def fit_centres(d, ang, scan, first, count, which, r, max_iter, xtol, lam0, lam_max, out):
    """Observer-frame ``x, y`` of the circle fit (eq. 7 start at the first min beam) of the
    segments ``which`` into ``out`` rows; one-beam segments get eq. 7's centre."""
    n_beams = ang.shape[0]
    px = np.empty(n_beams)
    py = np.empty(n_beams)
    for i in which:
        b = scan[i]
        f = first[i]
        n = count[i]
        kmin = 0
        for k in range(n):
            j = (f + k) % n_beams
            px[k] = d[b, j] * math.cos(ang[j])
            py[k] = d[b, j] * math.sin(ang[j])
            if d[b, j] < d[b, (f + kmin) % n_beams]:
                kmin = k
        mb = (f + kmin) % n_beams
        rc = d[b, mb] + r
        tc = ang[mb]
        if n >= 2:
            rc, tc, _ = lm_fit(px, py, n, r, rc, tc, max_iter, xtol, lam0, lam_max)
        tc = wrap(tc)
        out[i, 0] = rc * math.cos(tc)
        out[i, 1] = rc * math.sin(tc)


@numba.njit(cache=True, nogil=True, fastmath={"contract"}, inline="always")
def _mlp_block(a, h, weights, biases, sizes, lanes):
    """The layers of :func:`mlp_forward` on one block (``a`` the standardised inputs, (unit, row)),
    ``lanes`` rows wide; returns the array holding the outputs. Inlined twice in
    :func:`mlp_forward`, once with the constant full-block width (fixed-length SIMD loops)."""
    n_layers = weights.shape[0]
    for li in range(n_layers):
        k_in = sizes[li]
        n_out = sizes[li + 1]
        k4 = k_in - k_in % 4
        j = 0
        # (lanes past m hold finite leftovers of an earlier block and are never read out)
        while j + 4 <= n_out:  # four units a pass: each activation load serves four sums
            b0 = biases[li, j]
            b1 = biases[li, j + 1]
            b2 = biases[li, j + 2]
            b3 = biases[li, j + 3]
            for r_ in range(lanes):
                h[j, r_] = b0
                h[j + 1, r_] = b1
                h[j + 2, r_] = b2
                h[j + 3, r_] = b3
            for k in range(0, k4, 4):
                u0 = weights[li, j, k]
                u1 = weights[li, j, k + 1]
                u2 = weights[li, j, k + 2]
                u3 = weights[li, j, k + 3]
                v0 = weights[li, j + 1, k]
                v1 = weights[li, j + 1, k + 1]
                v2 = weights[li, j + 1, k + 2]
                v3 = weights[li, j + 1, k + 3]
                w0 = weights[li, j + 2, k]
                w1 = weights[li, j + 2, k + 1]
                w2 = weights[li, j + 2, k + 2]
                w3 = weights[li, j + 2, k + 3]
                z0 = weights[li, j + 3, k]
                z1 = weights[li, j + 3, k + 1]
                z2 = weights[li, j + 3, k + 2]
                z3 = weights[li, j + 3, k + 3]
                for r_ in range(lanes):
                    x0 = a[k, r_]
                    x1 = a[k + 1, r_]
                    x2 = a[k + 2, r_]
                    x3 = a[k + 3, r_]
                    p = h[j, r_]
                    p += u0 * x0
                    p += u1 * x1
                    p += u2 * x2
                    p += u3 * x3
                    h[j, r_] = p
                    q = h[j + 1, r_]
                    q += v0 * x0
                    q += v1 * x1
                    q += v2 * x2
                    q += v3 * x3
                    h[j + 1, r_] = q
                    t = h[j + 2, r_]
                    t += w0 * x0
                    t += w1 * x1
                    t += w2 * x2
                    t += w3 * x3
                    h[j + 2, r_] = t
                    y = h[j + 3, r_]
                    y += z0 * x0
                    y += z1 * x1
                    y += z2 * x2
                    y += z3 * x3
                    h[j + 3, r_] = y
            for k in range(k4, k_in):
                u0 = weights[li, j, k]
                v0 = weights[li, j + 1, k]
                w0 = weights[li, j + 2, k]
                z0 = weights[li, j + 3, k]
                for r_ in range(lanes):
                    h[j, r_] += u0 * a[k, r_]
                    h[j + 1, r_] += v0 * a[k, r_]
                    h[j + 2, r_] += w0 * a[k, r_]
                    h[j + 3, r_] += z0 * a[k, r_]
            j += 4
        while j + 2 <= n_out:
            b0 = biases[li, j]
            b1 = biases[li, j + 1]
            for r_ in range(lanes):
                h[j, r_] = b0
                h[j + 1, r_] = b1
            for k in range(0, k4, 4):
                u0 = weights[li, j, k]
                u1 = weights[li, j, k + 1]
                u2 = weights[li, j, k + 2]
                u3 = weights[li, j, k + 3]
                v0 = weights[li, j + 1, k]
                v1 = weights[li, j + 1, k + 1]
                v2 = weights[li, j + 1, k + 2]
                v3 = weights[li, j + 1, k + 3]
                for r_ in range(lanes):
                    x0 = a[k, r_]
                    x1 = a[k + 1, r_]
                    x2 = a[k + 2, r_]
                    x3 = a[k + 3, r_]
                    p = h[j, r_]
                    p += u0 * x0
                    p += u1 * x1
                    p += u2 * x2
                    p += u3 * x3
                    h[j, r_] = p
                    q = h[j + 1, r_]
                    q += v0 * x0
                    q += v1 * x1
                    q += v2 * x2
                    q += v3 * x3
                    h[j + 1, r_] = q
            for k in range(k4, k_in):
                u0 = weights[li, j, k]
                v0 = weights[li, j + 1, k]
                for r_ in range(lanes):
                    h[j, r_] += u0 * a[k, r_]
                    h[j + 1, r_] += v0 * a[k, r_]
            j += 2
        if j < n_out:  # an odd last unit
            b0 = biases[li, j]
            for r_ in range(lanes):
                h[j, r_] = b0
            for k in range(k_in):
                u0 = weights[li, j, k]
                for r_ in range(lanes):
                    h[j, r_] += u0 * a[k, r_]
        if li < n_layers - 1:
            for jj in range(n_out):
                for r_ in range(lanes):
                    if h[jj, r_] < 0.0:
                        h[jj, r_] = 0.0
        a, h = h, a
    return a


@numba.njit(cache=True, nogil=True, fastmath={"contract"})
def mlp_forward(x, mean, std, weights, biases, sizes, out):
    """``out = MLP((x - mean) / std)``: ReLU hidden layers, linear head, float32.

    Layer ``l`` maps ``sizes[l]`` to ``sizes[l + 1]`` units with ``weights[l, :sizes[l + 1],
    :sizes[l]]`` (``(out, in)``, zero-padded to one 3-D array) and ``biases[l, :sizes[l + 1]]``.
    Rows go through in blocks of 64, activations stored transposed (unit, row) so that the inner
    loops run over contiguous rows and compile to SIMD. Four units (then two, then one for the
    rest) and four inputs per pass over a block: each activation load serves four units and each
    partial sum stays in a register for four inputs (two units a pass: ~2x faster than one unit
    and one input, which loads and stores the sum for every multiply-add; four: ~5 % more). The
    inputs are standardised row by row with SIMD divisions, then transposed into the block. Each
    unit's sum is still accumulated input by input, in order, with one fused multiply-add each
    (``contract``, no reassociation), so the outputs are bitwise those of :func:`mlp_forward_rows`
    and of ``detectors._learned_driver.mlp_rows4`` (``tests/detectors/test_learned_driver.py``), for
    any layer widths.
    """
    n_rows, n_in = x.shape
    blk = 64
    width = max(sizes.max(), n_in)
    # (not zeroed, 2 x 16 kB a call: every value read is written first, but a first short block's padding
    # lanes of the inputs, zeroed below; later blocks' padding lanes hold the previous block's finite values)
    buf = np.empty((2 * width + 1, blk), dtype=np.float32)  # (one allocation)
    a = buf[:width]
    h = buf[width : 2 * width]
    row = buf[2 * width, :n_in] if n_in <= blk else np.empty(n_in, dtype=np.float32)
    n_layers = weights.shape[0]
    for s in range(0, n_rows, blk):
        m = min(blk, n_rows - s)
        lanes = min(blk, (m + 7) // 8 * 8)  # whole SIMD vectors; a short block does not pay for 64
        if s == 0:
            for k in range(n_in):
                for r_ in range(m, lanes):
                    a[k, r_] = 0.0
        # a row's inputs as SIMD divisions (np.true_divide: the IEEE quotients of `/`, without the
        # zero-divisor check and branch that keep `/` scalar), then into the block's column; read
        # through x itself (a row view per row took a reference count pair on x, two atomics a row)
        for r_ in range(m):
            sr = s + r_
            for k in range(n_in):
                row[k] = np.true_divide(x[sr, k] - mean[k], std[k])
            for k in range(n_in):
                a[k, r_] = row[k]
        if m == blk:
            a_out = _mlp_block(a, h, weights, biases, sizes, blk)
        else:
            a_out = _mlp_block(a, h, weights, biases, sizes, lanes)
        n_out = sizes[n_layers]
        for r_ in range(m):
            for jj in range(n_out):
                out[s + r_, jj] = a_out[jj, r_]


@numba.njit(cache=True, nogil=True, fastmath=True)
def mlp_forward_rows(x, mean, std, weights_t, biases, sizes, out):
    """:func:`mlp_forward` for a few rows (one scan's segments): one row at a time, the units of a
    layer in the SIMD loop, with ``weights_t[l, :sizes[l], :sizes[l + 1]]`` the ``(in, out)``
    transposes. With few rows :func:`mlp_forward`'s row loops run one or two iterations and its
    loop overhead dominates (~30 us for one row). Each unit's sum is accumulated over the inputs
    in the same order, element by element, so the outputs are bitwise the same
    (``tests/detectors/test_learned_overhead.py``)."""
    n_rows, n_in = x.shape
    width = max(sizes.max(), n_in)
    a = np.zeros(width, dtype=np.float32)
    h = np.zeros(width, dtype=np.float32)
    n_layers = weights_t.shape[0]
    for r_ in range(n_rows):
        for k in range(n_in):
            a[k] = (x[r_, k] - mean[k]) / std[k]
        for li in range(n_layers):
            k_in = sizes[li]
            n_out = sizes[li + 1]
            for j in range(n_out):
                h[j] = biases[li, j]
            for k in range(k_in):
                ak = a[k]
                for j in range(n_out):
                    h[j] += weights_t[li, k, j] * ak
            if li < n_layers - 1:
                for j in range(n_out):
                    if h[j] < 0.0:
                        h[j] = 0.0
            a, h = h, a
        for j in range(sizes[n_layers]):
            out[r_, j] = a[j]


@numba.njit(cache=True, error_model="numpy", nogil=True)
def housing_max_beams(d, scan, first, count, step, r, slack, margin, out):
    """Most beams (``step`` rad apart) a circle of radius ``r`` can return, plus ``margin``, for
    every segment, from its nearest reading ``d_min``: the circle's centre is at least ``slack *
    d_min`` away (every visible point is nearer than the centre, and ``slack = 1 / (1 + k sigma)``
    allows each reading to be ``k sigma`` too long), where it spans ``2 asin(r / D)``, so at most
    ``floor(2 asin(r / D) / step) + 1`` beams. Writes ``out[i]`` (float64; a segment with more
    beams cannot be a housing)."""
    _housing_max_beams(d, scan, first, count, step, r, slack, margin, 0, out)


@numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")
def _housing_max_beams(d, scan, first, count, step, r, slack, margin, skip_upto, out):
    # housing_max_beams; NaN for segments of at most skip_upto beams (not computed: the learned driver's lean
    # path, where the bound, >= 1 + margin, keeps them anyway)
    n_beams = d.shape[1]
    for i in range(scan.shape[0]):
        if count[i] <= skip_upto:
            out[i] = np.nan
            continue
        b = scan[i]
        j = first[i]
        dmin = d[b, j]
        for _ in range(count[i]):
            if d[b, j] < dmin:
                dmin = d[b, j]
            j += 1
            if j >= n_beams:
                j = 0
        out[i] = max_beams_of(dmin, step, r, slack, margin)


@numba.njit(cache=True, error_model="numpy", inline="always")
def max_beams_of(dmin, step, r, slack, margin):
    """:func:`housing_max_beams` of a segment whose nearest reading is ``dmin``."""
    dc = slack * dmin
    half = _HALF_PI if dc <= r else math.asin(r / dc)
    return math.floor(2.0 * half / step) + 1.0 + margin
