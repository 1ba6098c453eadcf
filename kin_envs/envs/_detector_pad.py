"""The learned detector's table matched and padded in the detector's own compiled call (imported lazily by
:mod:`kin_envs.envs.common` when an env's detector offers ``_detect_table_then``, so that ``import kin_envs``
imports no detector code).

:func:`learned_match_pad` runs :func:`detectors._learned_driver.fused_table` (its constant arguments as one
:class:`~detectors._learned_driver.DriverArgs`) and then
:func:`kin_envs.envs.common._match_pad_kernel` (``flat=False``) on the table it returns: the same values as
the two calls one after the other, without the second dispatch, the table's crossing into Python and back,
and the empty flat columns' return (``tests/kin_envs/envs/test_detection_glue.py``). The single-robot envs'
step takes it (:func:`kin_envs.envs.common.detect_one_padded`); a swarm's does not (slower there, measured:
see :func:`kin_envs.envs.common._padded_in_detector`)."""

from __future__ import annotations

import numba

from detectors._learned_driver import fused_table_args
from kin_envs.envs.common import _match_pad_kernel


@numba.njit(cache=True, nogil=True)
def learned_match_pad(r, args, match):
    """``(padded floats (5, n_rows, slots), padded ints (4, n_rows, slots), count (n_rows,))`` of the scans
    ``r``: ``fused_table``'s other arguments as one :class:`detectors._learned_driver.DriverArgs` (the
    detector's, ``LearnedKinDetector._detect_table_then``) and ``match = (observers, poses, tol2, slots,
    int_pads, hit_kind, hit_index, robot_kind)``, the rest of ``_match_pad_kernel``'s."""
    row, tab = fused_table_args(r, args)
    observers, poses, tol2, slots, int_pads, hit_kind, hit_index, robot_kind = match
    out = _match_pad_kernel(tab, row, observers, poses, tol2, r.shape[0], slots, int_pads, hit_kind,
                            hit_index, robot_kind, False)  # fmt: skip
    return out[3], out[4], out[5]
