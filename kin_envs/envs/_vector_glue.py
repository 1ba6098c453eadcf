"""The native vector env's detection glue in one compiled call: the K learners' detections matched to
their own world's robots and padded into the info's slots.

:func:`match_pad_worlds` gives what ``detect_rows(detector, ..., robot_world=...)`` (the general numpy
path, :func:`kin_envs.envs.common._match_rows_numpy`, with the vector env's conversion of ``kin_index`` to
each sub-env's own robot index) followed by :func:`kin_envs.envs.info.pad_rows` gives, bit for bit
(``tests/kin_envs/envs/test_vector_glue.py``), from the detector's table: the numpy path builds a
``(detections, K * n)`` distance matrix and ~40 small arrays a step (~0.1 ms of a 64-world step, most of
it call overhead); a world here has ``n`` robots (2 in KinSeek), so its candidates are a short loop.
"""

from __future__ import annotations

import numba
import numpy as np

from kin_envs.envs.common import (
    _INT_PADS,
    KIN_MATCH_TOLERANCE,
    _detection_blocks,
    _detection_cols,
    _put_detection,
    _sort_by_range,
)

__all__ = ["match_pad_worlds"]


def match_pad_worlds(owner: np.ndarray, tab: np.ndarray, poses: np.ndarray, n: int, slots: int):
    """``((row, cols), (padded, count))`` for the detector table ``(owner (D,), tab (D, 8))`` of ``K``
    learners' scans (row ``r``: the observer, robot ``r * n`` of ``poses`` ``(K * n, 3)``, whose world is
    robots ``r * n .. r * n + n - 1``): flat columns (:data:`DETECTION_FIELDS`, sorted by row then range,
    ``kin_index`` the world's own robot index or -1) and ``(K, slots)`` padded columns with counts. ``None``
    when ``owner`` is not sorted (the caller takes the general path)."""
    k = poses.shape[0] // n
    # the observers' headings, contiguous as the numpy path's gathered copy (np.cos / np.sin, the same loop)
    th = np.ascontiguousarray(poses[::n, 2])
    ok, row, flo, ints, pf, pi, count = _match_pad_worlds(
        np.ascontiguousarray(tab, dtype=np.float64), np.ascontiguousarray(owner, dtype=np.int64), poses,
        np.cos(th), np.sin(th), n, KIN_MATCH_TOLERANCE**2, k, slots, _INT_PADS,
    )  # fmt: skip
    if not ok:
        return None
    return (row, _detection_cols(flo, ints)), (_detection_cols(pf, pi), count)


@numba.njit(cache=True, nogil=True)
def _match_pad_worlds(tab, owner, poses, cos_obs, sin_obs, n, tol2, k, slots, int_pads):
    """:func:`match_pad_worlds`' arrays: ``(ok, row, floats (5, D), ints (4, D), padded floats (5, k,
    slots), padded ints (4, k, slots), count (k,))``.

    The numpy path term by term: the detected centre in the world ``wx = px + c x - s y``, ``wy = py + s x
    + c y`` (``c``, ``s``: numpy's cos / sin of the observer's heading), squared distances to the robots of
    the observer's world but itself, ``np.argmin``'s pick (the first of equals; any NaN distance: the
    first NaN, which fails the tolerance), kept within ``tol2``; rows in order, each sorted by range as
    ``np.lexsort`` sorts (stable, NaN last); the first ``slots`` of a row padded."""
    n_det = tab.shape[0]
    for i in range(1, n_det):
        if owner[i] < owner[i - 1]:
            return (False, np.empty(0, np.int64), np.empty((5, 0)), np.empty((4, 0), np.int64),
                    np.empty((5, 0, 0)), np.empty((4, 0, 0), np.int64), np.empty(0, np.int64))  # fmt: skip
    for i in range(n_det):
        if owner[i] < 0 or owner[i] >= k:
            raise ValueError("detection rows must be scan rows in [0, K)")
    row, flo, ints, pf, pi = _detection_blocks(n_det, k, slots, int_pads)
    count = np.zeros(k, dtype=np.int64)
    order = np.arange(n_det)
    lo = 0
    while lo < n_det:
        r = owner[lo]
        hi = lo + 1
        while hi < n_det and owner[hi] == r:
            hi += 1
        _sort_by_range(tab, order, lo, hi)  # stable, NaN last (np.lexsort's order)
        obs = r * n
        px = poses[obs, 0]
        py = poses[obs, 1]
        c = cos_obs[r]
        s = sin_obs[r]
        count[r] = min(hi - lo, slots)
        for a in range(lo, hi):
            t = order[a]
            wx = px + c * tab[t, 2] - s * tab[t, 3]
            wy = py + s * tab[t, 2] + c * tab[t, 3]
            best = -1
            best_d2 = np.inf
            nan = False
            for q in range(obs + 1, obs + n):  # the observer itself never matches
                dx = wx - poses[q, 0]
                dy = wy - poses[q, 1]
                d2 = dx * dx + dy * dy
                if np.isnan(d2):
                    nan = True
                    break
                if best < 0 or d2 < best_d2:
                    best = q
                    best_d2 = d2
            kin = best - obs if (not nan and best >= 0 and best_d2 <= tol2) else -1
            _put_detection(tab, t, r, a, a - lo, slots, kin, True, row, flo, ints, pf, pi)
        lo = hi
    return True, row, flo, ints, pf, pi, count
