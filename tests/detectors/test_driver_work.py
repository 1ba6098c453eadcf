"""The learned detector's kept work arrays (``detectors.learned._driver_work``): the fused driver reuses one
set per thread across calls, grown when a batch needs more. Results must not depend on them: nothing a
call returns is a view of them, a later call (larger or smaller batch, the env's table entry or the full
``detect_arrays``) leaves earlier results alone, and the outputs are bitwise those of a call on arrays of
its own (too few network rows, a batch past ``WORK_MAX_CELLS``, another thread's set)."""

import threading

import numpy as np
import pytest

pytest.importorskip("torch")  # the only reason to skip: CI installs torch

from detectors import _learned_driver as _drv  # noqa: E402
from detectors import learned as _learned  # noqa: E402
from detectors.learned import LearnedKinDetector  # noqa: E402
from tests.detectors.test_learned_driver import FIELDS, arena  # noqa: E402


def arena_scans(seed, noise, n_robots, n_obstacles=20):
    s = arena(seed, noise, n_robots, n_obstacles)
    return s.ranges.astype(np.float64), s.angles


BATCHES = [arena_scans(seed, noise, n) for seed, noise, n in ((0, 0.01, 64), (1, 0.0, 3), (2, 0.02, 32),
                                                              (3, 0.005, 2), (4, 0.01, 48))]  # fmt: skip
BATCHES.insert(3, (BATCHES[0][0][5:6], BATCHES[0][1]))  # one scan


def arrays_of(res):
    """Every array a driver call handed back: a (row, table) pair or a BatchDetections."""
    if isinstance(res, tuple):
        return list(res)
    return [getattr(res, f) for f in FIELDS] + list(res.seg_values.values())


def call(det, kind, r, a):
    return det._detect_table_trusted(r, a) if kind == "table" else det.detect_arrays(r, a)


def test_later_calls_leave_earlier_results_alone():
    det = LearnedKinDetector(reports=False)
    results, copies = [], []
    for kind in ("table", "packed"):
        for r, a in BATCHES:
            res = call(det, kind, r, a)
            results.append(res)
            copies.append([x.copy() for x in arrays_of(res)])
    work = _learned._WORK.ws
    n_det = 0
    for res, kept in zip(results, copies, strict=True):
        for x, k in zip(arrays_of(res), kept, strict=True):
            assert x.dtype == k.dtype and np.array_equal(x, k, equal_nan=True)
            assert not any(np.shares_memory(x, w) for w in work)  # never a view of the work arrays
        n_det += arrays_of(res)[0].shape[0]
    for i, res in enumerate(results):  # nor of one another
        for other in results[i + 1 :]:
            for x in arrays_of(res):
                assert not any(np.shares_memory(x, y) for y in arrays_of(other))
    assert n_det > 100


def test_kept_arrays_give_the_outputs_of_fresh_ones(monkeypatch):
    for det in (LearnedKinDetector(reports=False), LearnedKinDetector(reports=False, cascade=False)):
        kept = [(call(det, "table", r, a), call(det, "packed", r, a)) for r, a in BATCHES]
        # every call on a set of its own: none (segments past the limit) or without room for the network rows
        for own in ((0, 0), "rows"):
            def fresh(cells, n_feat, own=own):
                return _drv.new_work(*((cells, 0) if own == "rows" else own), n_feat)

            with monkeypatch.context() as m:
                m.setattr(_learned, "_driver_work", fresh)
                for (table, packed), (r, a) in zip(kept, BATCHES, strict=True):
                    for ref, got in ((table, call(det, "table", r, a)), (packed, call(det, "packed", r, a))):
                        for x, y in zip(arrays_of(ref), arrays_of(got), strict=True):
                            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True)


def test_work_arrays_grow_for_more_rows_and_are_not_kept_past_the_limit(monkeypatch):
    det = LearnedKinDetector(reports=False, cascade=False)  # every pre-gated segment reaches the network
    r, a = BATCHES[0]
    ref = det._detect_table_trusted(r, a)
    cells = r.shape[0] * r.shape[1]
    n_feat = det._driver_consts(False)[0][17]
    small = _drv.new_work(cells, 8, n_feat)  # room for 8 network rows: the call uses its own, then grows
    monkeypatch.setattr(_learned._WORK, "ws", small, raising=False)
    got = det._detect_table_trusted(r, a)
    grown = _learned._WORK.ws
    assert grown is not small and grown[5].shape[0] >= small[6][0] > 8
    assert all(np.array_equal(x, y) for x, y in zip(got, ref, strict=True))
    again = det._detect_table_trusted(r, a)
    assert _learned._WORK.ws is grown and all(np.array_equal(x, y) for x, y in zip(again, ref, strict=True))
    # a batch past the limit: arrays of the call's own, the kept set left as it was
    monkeypatch.setattr(_drv, "WORK_MAX_CELLS", cells - 1)
    big = det._detect_table_trusted(r, a)
    assert _learned._WORK.ws is grown and all(np.array_equal(x, y) for x, y in zip(big, ref, strict=True))


def test_each_thread_has_its_own_work_arrays():
    det = LearnedKinDetector(reports=False)
    ref = [call(det, "table", r, a) for r, a in BATCHES]
    main_ws = _learned._WORK.ws
    out, sets, errors = {}, {}, []
    start = threading.Barrier(2)

    def run(k):
        try:
            start.wait()
            got = []
            for _ in range(5):  # the two threads' calls interleave (the kernels release the GIL)
                for r, a in BATCHES[k::2] + BATCHES:
                    got.append((r.shape, call(det, "table", r, a)))
            out[k] = got
            sets[k] = _learned._WORK.ws
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert sets[0] is not sets[1] and main_ws is not sets[0] and main_ws is not sets[1]
    by_shape = {r.shape: res for (r, _), res in zip(BATCHES, ref, strict=True)}
    for k in (0, 1):
        for shape, (row, table) in out[k]:
            assert np.array_equal(row, by_shape[shape][0]) and np.array_equal(table, by_shape[shape][1])
