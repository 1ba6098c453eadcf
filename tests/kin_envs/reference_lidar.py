"""The lidar's brute-force kernel as it was before its candidate tests were vectorised (kin-envs at
the start of session 4), kept as a reference: the current kernels must return the same scans bit for bit.
Compiled without numba's cache (tests only)."""

import math

import numba
import numpy as np

_EPS = 1e-4
_TOL = 1e-6


@numba.njit(inline="always")
def _fast_atan2(y, x):
    """atan2 to within 1e-5 rad (minimax polynomial): only used to pick candidate beams.

    Written with min / max and conditional expressions so that it compiles without branches: the
    signs of random bearings are unpredictable and mispredicted branches cost more than the
    arithmetic (measured)."""
    ax = abs(x)
    ay = abs(y)
    # min/max: the same quotient as ay/ax or ax/ay; 0 at the origin (where the original returned 0)
    z = min(ax, ay) / max(max(ax, ay), 1e-300)
    z2 = z * z
    a = z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330 + z2 * 0.0208351))))
    a = 0.5 * math.pi - a if ay > ax else a
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a



@numba.njit(nogil=True, inline="always")
def _cast_one(x0, y0, h, skip, range_max, circles, segments, cos_tab, sin_tab, best_d, best_p, ids):
    """Cast one origin's beams into ``best_d`` / ``best_p`` (nearest distance and primitive id).

    Beams with no hit within ``range_max`` get distance ``range_max`` and primitive -1.
    Primitive ids: circles are ``0..C-1``, segments ``C..C+S-1``. Circle ``skip`` (the robot's own
    housing) is ignored. Beam ``i`` has world direction ``h - i*res``. ``ids`` is ``arange(k)`` for
    some ``k >= max(C, S)`` (every primitive is a candidate).
    """
    for i in range(best_d.shape[0]):
        best_d[i] = range_max  # hits beyond range_max are never recorded
        best_p[i] = -1
    _cast_prims(x0, y0, h, skip, range_max, circles, segments, ids, circles.shape[0], ids,
                segments.shape[0], cos_tab, sin_tab, best_d, best_p)  # fmt: skip


@numba.njit(nogil=True)
def _cast_prims(x0, y0, h, skip, reach, circles, segments, c_ids, n_ci, s_ids, n_si, cos_tab, sin_tab,
                best_d, best_p):  # fmt: skip
    """Cast the circles ``c_ids[:n_ci]`` and segments ``s_ids[:n_si]`` into ``best_d`` / ``best_p``.

    ``reach`` (at most ``range_max``, at least every current ``best_d``): nothing beyond it can change
    the scan. A hit replaces the current one when it is nearer *or equally near with a lower primitive
    id*: the result is the minimum of (distance, id) over the primitives whatever order they come in,
    so the brute-force kernel (all primitives in id order) and the grid kernel (rings of cells, near
    ones first) return the same scans bit for bit. Everything that only *selects* candidates (the
    prefilters, the beam intervals, the occlusion test) keeps a margin; what a beam hits and at which
    distance is decided by the same exact arithmetic in every kernel.

    Segments are one-sided: only a beam arriving from the segment's right-hand side (looking from
    its first to its second point) can hit it, i.e. the outside of a CCW polygon. A convex solid's
    back faces can never be the first hit, so culling them halves the work exactly.
    The per-primitive code is written out here, not in helper functions: inlined helpers that take
    the arrays cost reference counting per primitive and ran ~2x slower (measured).
    """
    n_beams = best_d.shape[0]
    res = 2.0 * math.pi / n_beams
    inv_res = 1.0 / res
    n_c = circles.shape[0]
    ch = math.cos(h)
    sh = math.sin(h)
    # the heading wrapped to [-pi, pi] for the beam intervals only (robots' angles are unbounded), so
    # that a bearing minus it lies in [-2pi, 2pi] and its beam index needs no integer modulo
    hw = h - 2.0 * math.pi * math.floor(h / (2.0 * math.pi) + 0.5)
    rc = reach + _TOL
    rc2 = rc * rc
    for q in range(n_ci):
        c = c_ids[q]
        dx = circles[c, 0] - x0
        dy = circles[c, 1] - y0
        r = circles[c, 2]
        d2 = dx * dx + dy * dy
        # branch-free prefilter (out of reach, with a margin), then the exact test: most circles of a
        # large arena are out of reach, and a mispredicted branch costs more than the arithmetic
        if not ((d2 <= (rc + r) * (rc + r)) & (c != skip)):
            continue
        d = math.sqrt(d2)
        cc = d2 - r * r
        if d - r > reach or d <= r or cc <= 0.0:
            continue  # out of reach, or the origin is inside the circle (not a physical state)
        # half-angle subtended: asin(r/d) = atan(z), z = r / sqrt(d^2 - r^2); atan(z) <= z, so a small
        # circle (most of them) takes z itself: a few more candidate beams at most, one atan2 less
        sq = math.sqrt(cc)
        z = r / sq
        half = (z if z < 0.05 else _fast_atan2(r, sq)) + _EPS
        phi = _fast_atan2(dy, dx) - hw  # bearing of the centre relative to the heading
        # beam i points at -i*res: beams within [phi-half, phi+half] have i in
        # [-(phi+half)/res, -(phi-half)/res]
        k0 = int(math.ceil(-(phi + half) * inv_res))
        k1 = int(math.floor(-(phi - half) * inv_res))
        i = k0 + 2 * n_beams - 1  # >= -1: k0 >= -(2pi + pi/2) / res
        while i >= n_beams - 1:
            i -= n_beams
        near = d - r - _TOL  # no hit on this circle is nearer
        for _ in range(k1 - k0 + 1):
            i += 1
            if i == n_beams:
                i = 0
            bd = best_d[i]
            if bd < near:
                continue  # occluded
            # direction of heading - i*res, by rotation (no trig in the inner loop)
            ux = ch * cos_tab[i] + sh * sin_tab[i]
            uy = sh * cos_tab[i] - ch * sin_tab[i]
            b = dx * ux + dy * uy
            disc = b * b - cc
            if disc < 0.0 or b <= 0.0:
                continue
            t = b - math.sqrt(disc)
            if t > 0.0 and (t < bd or (t == bd and c < best_p[i])):
                best_d[i] = t
                best_p[i] = c
    for q in range(n_si):
        s = s_ids[q]
        ax = segments[s, 0] - x0
        ay = segments[s, 1] - y0
        bx = segments[s, 2] - x0
        by = segments[s, 3] - y0
        ex = bx - ax
        ey = by - ay
        # back face (the origin on the left of A->B or on its line) or out of reach, branch-free: the
        # nearest point is A, B or the foot of the perpendicular (at distance^2 cr^2 / ee)
        cr = ey * ax - ex * ay
        ee = ex * ex + ey * ey
        dot = -(ax * ex + ay * ey)
        near = (((dot <= 0.0) & (ax * ax + ay * ay <= rc2))
                | ((dot >= ee) & (bx * bx + by * by <= rc2))
                | ((dot > 0.0) & (dot < ee) & (cr * cr <= rc2 * ee)))  # fmt: skip
        if not ((cr < 0.0) & near):
            continue
        u = min(1.0, max(0.0, dot / ee))
        px = ax + u * ex
        py = ay + u * ey
        dm2 = px * px + py * py
        if dm2 > reach * reach:
            continue
        p = n_c + s
        th_a = _fast_atan2(ay, ax) - hw
        span = _fast_atan2(ax * by - ay * bx, ax * bx + ay * by)  # signed angle A -> B, |span| < pi
        lo = th_a + min(0.0, span) - _EPS
        hi = th_a + max(0.0, span) + _EPS
        k0 = int(math.ceil(-hi * inv_res))
        k1 = int(math.floor(-lo * inv_res))
        i = k0 + 2 * n_beams - 1  # >= -1: k0 >= -(2pi + pi) / res
        while i >= n_beams - 1:
            i -= n_beams
        near_d = math.sqrt(dm2) - _TOL
        for _ in range(k1 - k0 + 1):
            i += 1
            if i == n_beams:
                i = 0
            bd = best_d[i]
            if bd < near_d:
                continue  # occluded
            ux = ch * cos_tab[i] + sh * sin_tab[i]
            uy = sh * cos_tab[i] - ch * sin_tab[i]
            den = ux * ey - uy * ex  # cross(u, e)
            if den == 0.0:
                continue
            # origin + t u = A + s e  ->  t = cross(A, e)/cross(u, e), s = cross(A, u)/cross(u, e)
            t = (ax * ey - ay * ex) / den
            sp = (ax * uy - ay * ux) / den
            if t > 0.0 and 0.0 <= sp <= 1.0 and (t < bd or (t == bd and p < best_p[i])):
                best_d[i] = t
                best_p[i] = p



@numba.njit(nogil=True)
def _write_row(n, best_d, best_p, base, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
               out_kind, out_index):  # fmt: skip
    """Row ``n`` of the outputs from one origin's nearest hits (``best_p`` = -1: no hit). The owner tables
    are read from ``base`` (a world's offset in a batch of worlds). Readings below ``range_min`` and misses
    read ``range_max``, as the real lidar reports them; ``out_true`` keeps the true distance (inf: miss)."""
    for i in range(best_d.shape[0]):
        p = best_p[i] + 1
        d = best_d[i]
        out_kind[n, i] = prim_kind[base + p]
        out_index[n, i] = prim_index[base + p]
        if p == 0:
            out_true[n, i] = np.inf
            out_ranges[n, i] = range_max
        else:
            out_true[n, i] = d
            out_ranges[n, i] = d if d >= range_min else range_max


@numba.njit(nogil=True)
def reference_kernel(
    ox,
    oy,
    heading,
    tabs,
    range_min,
    range_max,
    circles,
    circle_skip,
    segments,
    prim_kind,
    prim_index,
    out_ranges,
    out_true,
    out_kind,
    out_index,
):
    """The world's scan in one pass: noise-free readings and per-beam ground truth.

    Per robot the work happens in small buffers that stay in L1 cache and each output row is written
    once, sequentially (no intermediate arrays to evict the caches between robots).
    ``prim_kind`` / ``prim_index`` are owner tables indexed by primitive id + 1 (slot 0 = no hit).
    ``tabs``: :func:`beam_tables`.
    """
    n_beams = tabs.shape[1]
    cos_tab = tabs[0]
    sin_tab = tabs[1]
    best_d = np.empty(n_beams)
    best_p = np.empty(n_beams, dtype=np.int32)
    ids = np.arange(max(circles.shape[0], segments.shape[0]))
    for n in range(ox.shape[0]):
        _cast_one(ox[n], oy[n], heading[n], circle_skip[n], range_max, circles, segments, cos_tab, sin_tab,
                  best_d, best_p, ids)  # fmt: skip
        _write_row(n, best_d, best_p, 0, prim_kind, prim_index, range_min, range_max, out_ranges, out_true,
                   out_kind, out_index)
