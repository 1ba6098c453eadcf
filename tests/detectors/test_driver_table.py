"""The learned driver's env entry (``_learned_driver.fused_table``) against the lean ``front`` and
``detect_arrays``, bit for bit: its one-pass segmentation with the pre-gate and the one-beam bound, which
keeps only the segments that go on to stage 1 (``_table_segments`` / ``_front_table``); the stage-1
values handed to the features kernel; phi's cos / sin reused by the back end; duplicate suppression
inside the compiled call; float32 ranges read as they are."""

import math

import numpy as np
import pytest

pytest.importorskip("torch")

from detectors import _learned_driver as _drv  # noqa: E402
from detectors import learned as _learned  # noqa: E402
from detectors.learned import LearnedKinDetector  # noqa: E402

from .test_cascade_bound import NOISES, adversarial_scans, arena_scans  # noqa: E402


def _cases():
    for seed in range(6):  # swarms of 8-64 robots, 0-2 % noise
        yield arena_scans(300 + seed, NOISES[seed % 4], (8, 24, 64)[seed % 3], 30)
    rng = np.random.default_rng(7)
    for _ in range(3):  # no-returns of every kind, bin edges, alternating near / far beams
        yield adversarial_scans(rng)
    ranges, angles = arena_scans(310, 0.01, 32, 20)  # a partial sweep (270 beams)
    yield ranges[:, :270], angles[:270].copy()
    yield ranges[:1], angles  # one scan: without the cascade


CASES = list(_cases())


def _table_ref(det, ranges, angles):
    ref = det.detect_arrays(ranges, angles)
    cols = (ref.range, ref.bearing, ref.x, ref.y, ref.score, ref.first_beam, ref.last_beam, ref.n_beams_on)
    return ref.scan, np.stack(cols, axis=1).astype(np.float64).reshape(-1, 8)


KWARGS = ({}, {"positioning": "fit"}, {"cascade": False}, {"pre_gate": False}, {"suppress_duplicates": False})


@pytest.mark.parametrize("kw", KWARGS)
def test_table_front_gives_the_lean_fronts_rows_and_the_same_detections(kw):
    det = LearnedKinDetector(reports=False, **kw)
    n_rows = n_det = 0
    for ranges, angles in CASES:
        rb = det._driver_input(ranges, angles, True)
        cascade = det.cascade
        front_args, _ = det._driver_consts(cascade)
        lean = _drv.front(rb, *front_args, True)
        ws = _drv.new_work(rb.size, rb.size, front_args[17])
        d, scan, first, count, rows, x, frames, scan_cols, _ = _drv._front_table(rb, *front_args, ws)
        # the segments written: those the lean front scored in stage 1 (or, without it, sent on)
        if cascade:
            sel = np.isfinite(lean[13])
        else:
            sel = np.zeros(lean[1].shape[0], dtype=bool)
            sel[lean[9]] = True
        assert np.array_equal(d, lean[0])
        for got, k in ((scan, 1), (first, 2), (count, 3)):
            assert np.array_equal(got, lean[k][sel])
        assert np.array_equal(np.flatnonzero(sel)[rows], lean[9])
        assert np.array_equal(x, lean[10]) and np.array_equal(frames[:, :4], lean[11])
        assert np.array_equal(frames[:, 4], [math.cos(p) for p in frames[:, 2]])
        assert np.array_equal(frames[:, 5], [math.sin(p) for p in frames[:, 2]])
        if lean[1].shape[0] > 0:
            assert np.array_equal(scan_cols, lean[12])
        n_rows += rows.shape[0]
        for r in (ranges, ranges.astype(np.float32)):
            row, table = det._detect_table_trusted(r, angles)
            ref_row, ref_table = _table_ref(det, r, angles)
            assert np.array_equal(row, ref_row) and np.array_equal(table, ref_table)
            n_det += row.shape[0]
    assert n_rows > 1000 and n_det > 500


def _swarm_scans():
    # a clustered 64-robot swarm (aggregation_v2, 1 % noise; steps 40, 50, 60): split housings, so a few
    # duplicates every step
    from kin_envs import aggregation_v2

    env = aggregation_v2.parallel_env(n_robots=64, detector=None, noise_sigma=0.01)
    env.reset(seed=5)
    for i, a in enumerate(env.agents):  # seeded: the duplicates counted below must not vary between runs
        env.action_space(a).seed(100 + i)
    acts = {a: env.action_space(a).sample() for a in env.agents}
    out = []
    for t in range(1, 61):
        env.step(acts)
        if t % 10 == 0 and t >= 40:
            s = env.unwrapped.world.scan()
            out.append((np.array(s.ranges), np.array(s.angles)))
    return out


def test_duplicates_are_dropped_inside_the_call():
    # the env entry with suppression against the one without it and detectors.learned.duplicates after it
    on = LearnedKinDetector(reports=False)
    off = LearnedKinDetector(reports=False, suppress_duplicates=False)
    n_dropped = 0
    for ranges, angles in [*CASES, *_swarm_scans()]:
        row, table = on._detect_table_trusted(ranges, angles)
        row0, table0 = off._detect_table_trusted(ranges, angles)
        keep = _learned.duplicates(row0, table0[:, 2:4], table0[:, 4], on._dup_radius) < 0
        assert np.array_equal(row, row0[keep]) and np.array_equal(table, table0[keep])
        n_dropped += int((~keep).sum())
    assert n_dropped > 2  # (the compaction ran)


def test_float32_ranges_go_in_as_they_are():
    det = LearnedKinDetector(reports=False)
    ranges, angles = CASES[2]
    r32 = ranges.astype(np.float32)
    det._detect_table_trusted(r32, angles)  # the first call validates the layout (then reads the float32)
    assert det._table_input(r32, angles) is r32
    # not C-contiguous: converted as before; another layout object: checked in full, then passed on
    assert det._table_input(np.asfortranarray(r32), angles).dtype == np.float64
    assert det._table_input(r32.astype(np.float64), angles).dtype == np.float64
    other = angles.copy()
    assert det._table_input(r32, other) is r32 and det._angles_src is other
    got = det._detect_table_trusted(r32, angles)
    ref = LearnedKinDetector(reports=False)._detect_table_trusted(r32.astype(np.float64), angles)
    assert all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True)) and got[0].shape[0] > 50
    with pytest.raises(ValueError, match="ranges"):  # a bad float32 reading is still refused
        bad = r32.copy()
        bad[3, 5] = -1.0
        det._detect_table_trusted(bad, angles.copy())


@pytest.mark.parametrize("kw", ({}, {"positioning": "fit", "suppress_duplicates": False}))
def test_table_entry_with_its_arguments_in_one_object_is_the_entry(kw):
    # fused_table_args (the single-robot envs' kernel takes fused_table's other arguments, work arrays
    # included, as one DriverArgs structref) against fused_table with the arguments themselves, bit for bit:
    # scans of every kind, one scan and batches (cascade on and off)
    det = LearnedKinDetector(reports=False, **kw)
    mean, std, w, b, sizes = det._numba_weights
    wt = det._numba_weights_t[2]
    n_det = 0
    for ranges, angles in CASES:
        rb = det._driver_input(ranges, angles, True)
        front_args, back_args = det._driver_consts(det.cascade)
        expanded = (front_args, _learned._DRIVER_ROWS_MAX, mean, std, w, wt, b, sizes, back_args, 0.07, 0.07)
        args = _drv.driver_args(*expanded, _drv.new_work(rb.size, rb.size, front_args[17]))
        assert isinstance(args, _drv.DriverArgs)
        row, table = _drv.fused_table_args(rb, args)
        ref_row, ref_table = _drv.fused_table(rb, *expanded, _drv.new_work(rb.size, rb.size, front_args[17]))
        assert np.array_equal(row, ref_row) and table.tobytes() == ref_table.tobytes()
        n_det += row.shape[0]
    assert n_det > 20


def test_table_entry_does_not_read_what_its_work_arrays_held():
    # the work arrays also hold the scans' noise columns and the stage-1 scores (the env entry allocates no
    # array of its own for them): filled with NaN, huge values or another batch's values, the same rows,
    # features, frames, noise columns and detections bit for bit
    det = LearnedKinDetector(reports=False)
    mean, std, w, b, sizes = det._numba_weights
    wt = det._numba_weights_t[2]
    n_det = n_rows = 0
    for ranges, angles in CASES:
        rb = det._driver_input(ranges, angles, True)
        front_args, back_args = det._driver_consts(det.cascade)
        expanded = (front_args, _learned._DRIVER_ROWS_MAX, mean, std, w, wt, b, sizes, back_args, 0.07, 0.07)
        fronts, tables = [], []
        for fill in ("fresh", np.nan, 1e300, "other"):
            ws = _drv.new_work(rb.size, rb.size, front_args[17])
            if fill == "other":  # another batch's call on them first (a larger, clustered swarm)
                other = det._driver_input(*CASES[1], True)
                o_args = det._driver_consts(det.cascade)[0]
                ws = _drv.new_work(max(rb.size, other.size), max(rb.size, other.size), front_args[17])
                _drv._front_table(other, *o_args, ws)
            elif fill != "fresh":
                for arr in ws[:6]:
                    if arr.dtype.kind == "f":  # (the float32 features: their largest value)
                        arr.fill(fill if np.isnan(fill) else min(fill, float(np.finfo(arr.dtype).max)))
                    else:
                        arr.fill(-1 if arr.dtype.kind == "i" else True)
            fronts.append([np.array(a) for a in _drv._front_table(rb, *front_args, ws)[:8]])
            tables.append(_drv.fused_table(rb, *expanded, ws))
        for got, ref in zip(fronts[1:], [fronts[0]] * 3, strict=True):
            assert all(g.tobytes() == r.tobytes() for g, r in zip(got, ref, strict=True))
        for got in tables[1:]:
            assert np.array_equal(got[0], tables[0][0]) and got[1].tobytes() == tables[0][1].tobytes()
        n_det += tables[0][0].shape[0]
        n_rows += fronts[0][4].shape[0]
    assert n_det > 20 and n_rows > 1000
