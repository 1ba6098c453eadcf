"""The one-beam bound of the cascade's stage 1 (``detectors.features.cascade_one_beam_table``) is sound.

The env's driver entry (``_learned_driver.fused_table``, ``lean``) skips stage 1 for one-beam segments
whose bound proves a score below the threshold. Checked here against the stage itself (``_cascade``: the
inputs and the score it computes): the derivation's premises on real one-beam inputs, the bound above the
score of every one-beam segment of random arenas (0-2 % noise) and of adversarial random scans, for the
shipped model and random ones, and the driver's lean and full paths giving the same segments to the
network and the same detections.
"""

import math

import numpy as np
import pytest

pytest.importorskip("torch")

from detectors import _learned_driver as _drv  # noqa: E402
from detectors import features as F  # noqa: E402
from detectors.features import FeatureConfig, beam_trig, scan_noise, segment_batch  # noqa: E402
from detectors.learned import PRE_GATE_MARGIN, LearnedKinDetector  # noqa: E402
from kin_envs import LidarSpec, World, scenes  # noqa: E402

NOISES = (0.0, 0.005, 0.01, 0.02)


def arena_scans(seed, noise, n_robots, n_obstacles):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    s = World(scene, seed=seed).scan()
    return s.ranges.astype(np.float64), s.angles


def adversarial_scans(rng, n_rows=8, n=360):
    # ranges across (and beyond) the table's bins, bin edges exactly, no-returns (0, inf, NaN, beyond
    # d_max) and alternating near / far beams: many one-beam segments with every context pattern
    r = np.exp(rng.uniform(math.log(0.02), math.log(20.0), (n_rows, n)))
    edges = 2.0 ** rng.integers(-5, 5, (n_rows, n)) * (1.0 + rng.integers(0, 8, (n_rows, n)) / 8.0)
    r = np.where(rng.random((n_rows, n)) < 0.2, edges, r)
    r = np.where(rng.random((n_rows, n)) < 0.15, rng.choice([0.0, np.inf, np.nan, 13.0], (n_rows, n)), r)
    r[::2, ::2] = rng.uniform(0.2, 11.0, r[::2, ::2].shape)
    r[1::2, 1::3] += rng.choice([-0.3, 0.3], r[1::2, 1::3].shape)
    return np.abs(r), np.linspace(0.0, 2 * np.pi, n, endpoint=False)


def one_beam_check(ranges, angles, model, table, threshold=None):
    """Stage-1 inputs and scores of every one-beam segment, and their bounds; asserts the derivation's
    premises and ``bound >= score``. Returns ``(scores, bounds)``."""
    c = FeatureConfig()
    batch = segment_batch(ranges, angles, c)
    which = np.nonzero(batch.count == 1)[0].astype(np.int64)
    noise = scan_noise(batch, c)
    x, score = F._cascade(batch, c, which, beam_trig(angles, 32), noise, model)
    # the premises: x0 = log1p(1), omega_min = chord = 0, omega_max in [0, 0.3], the nearer flag's sign
    assert (x[:, 0] == np.float32(math.log1p(1.0))).all() and (x[:, 2] == 0).all() and (x[:, 6] == 0).all()
    assert ((x[:, 3] >= 0) & (x[:, 3] <= np.float32(0.3))).all()
    for k_ctx, k_flag in ((8, 4), (9, 5)):
        assert (np.where(x[:, k_flag] == 1, x[:, k_ctx] <= 0, x[:, k_ctx] >= 0)).all()
    assert (np.abs(x[:, 8:12]) <= 0.5).all()
    scan_cols = np.empty((batch.ranges.shape[0], 2))
    F._scan_columns(noise[0], noise[1], scan_cols)
    bound = np.empty(which.shape[0])
    F._cascade_one_beam_bounds(
        np.ascontiguousarray(batch.ranges).reshape(-1), batch.scan, batch.first, batch.prev_nearer,
        batch.next_nearer, ranges.shape[1], batch.circular, float(c.d_max), scan_cols, table, which, bound,
    )  # fmt: skip
    bad = ~(bound >= score - 1e-9)
    assert not bad.any(), (score[bad][:5], bound[bad][:5])
    if threshold is not None:
        # the filter drops exactly the one-beam segments whose bound is below threshold - delta
        rows = np.arange(batch.n_segments, dtype=np.int64)
        out = np.empty_like(rows)
        m = F._cascade_one_beam_filter(
            np.ascontiguousarray(batch.ranges).reshape(-1), batch.scan, batch.first, batch.count,
            batch.prev_nearer, batch.next_nearer, ranges.shape[1], batch.circular, float(c.d_max), scan_cols,
            table, threshold, rows, out,
        )  # fmt: skip
        dropped = np.setdiff1d(rows, out[:m])
        assert np.array_equal(dropped, which[bound < threshold - F._C1_DELTA])
        assert (score[np.isin(which, dropped)] < threshold).all()
    return score, bound


def shipped():
    det = LearnedKinDetector(reports=False)
    assert det.cascade
    model = det._cascade["model"]
    return det, model, F.cascade_one_beam_table(*model)


def test_bound_is_above_every_one_beam_score_in_random_arenas():
    det, model, table = shipped()
    thr = det._cascade["threshold"]
    n_one = n_rejected = 0
    for seed in range(12):
        noise = NOISES[seed % len(NOISES)]
        n_robots, n_obstacles = ((2, 5), (16, 20), (64, 50), (40, 10))[seed % 4]
        ranges, angles = arena_scans(100 + seed, noise, n_robots, n_obstacles)
        score, bound = one_beam_check(ranges, angles, model, table, thr)
        n_one += score.shape[0]
        n_rejected += int((bound < thr - F._C1_DELTA).sum())
    # the point of the bound: it settles nearly every one-beam segment of noisy swarm scans
    assert n_one > 5000 and n_rejected > 0.95 * n_one


def test_bound_is_above_the_score_on_adversarial_scans_and_random_models():
    det, model, table = shipped()
    rng = np.random.default_rng(7)
    n = 0
    for trial in range(24):
        ranges, angles = adversarial_scans(rng)
        if trial % 3 == 2:  # a partial sweep: no wrap-around context
            ranges, angles = ranges[:, :271].copy(), angles[:271].copy()
        if trial % 2:  # a random model, weights up to ~10x the shipped one's
            w1t = rng.normal(0.0, rng.uniform(0.1, 3.0), model[0].shape)
            b1 = rng.normal(0.0, 2.0, model[1].shape)
            w2 = rng.normal(0.0, 2.0, model[2].shape)
            m = (w1t, b1, w2, float(rng.normal()))
            thr = float(rng.normal(0, 5))
            score, _ = one_beam_check(ranges, angles, m, F.cascade_one_beam_table(*m), thr)
        else:
            score, _ = one_beam_check(ranges, angles, model, table, det._cascade["threshold"])
        n += score.shape[0]
    assert n > 10000


def test_table_refuses_a_model_of_another_shape():
    with pytest.raises(ValueError, match="12 -> H -> 1"):
        F.cascade_one_beam_table(np.zeros((11, 4)), np.zeros(4), np.zeros(4), 0.0)


@pytest.mark.parametrize("positioning", ["regression", "fit"])
def test_lean_driver_sends_the_same_segments_to_the_network(positioning):
    # random arenas, 0-2 % noise: the env's lean entry and the full one differ only in the one-beam
    # segments' max_beams (not computed) and in stage-1 scores the bound settled; rows, features,
    # frames, detections and stage codes are bitwise the same, and so is the env's table
    det = LearnedKinDetector(reports=False, positioning=positioning)
    n_skipped = n_det = 0
    for seed in range(8):
        ranges, angles = arena_scans(200 + seed, NOISES[seed % 4], (8, 24, 64, 32)[seed % 4], 30)
        rb = det._driver_input(ranges, angles, True)
        front_args, back_args = det._driver_consts(True)
        full = _drv.front(rb, *front_args, False)
        lean = _drv.front(rb, *front_args, True)
        for k in (0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 12):
            assert np.array_equal(full[k], lean[k], equal_nan=True), k
        one = full[3] == 1
        short = full[3] <= 1 + PRE_GATE_MARGIN  # (their bound, >= 1 + margin, always keeps them)
        assert np.isnan(lean[8][short]).all() and np.array_equal(full[8][~short], lean[8][~short])
        assert (full[3][short] <= full[8][short]).all()
        settled = np.isfinite(full[13]) & np.isnan(lean[13])
        assert (one[settled]).all() and np.array_equal(full[13][~settled], lean[13][~settled], equal_nan=True)
        n_skipped += int(settled.sum())
        out = np.zeros((full[10].shape[0], 3))
        bk_full = _drv.back_rest(out, full, back_args)
        bk_lean = _drv.back_rest(out, lean, back_args)
        # (the last output: the accepted candidate windows' columns)
        for a, b in zip((*bk_full[:-1], *bk_full[-1]), (*bk_lean[:-1], *bk_lean[-1]), strict=True):
            assert np.array_equal(a, b, equal_nan=True)
        ref = det.detect_arrays(ranges, angles)
        row, table = det._detect_table_trusted(ranges, angles)
        cols = (ref.range, ref.bearing, ref.x, ref.y, ref.score, ref.first_beam, ref.last_beam)
        cols = (*cols, ref.n_beams_on)
        assert np.array_equal(row, ref.scan)
        assert np.array_equal(table, np.stack(cols, axis=1).astype(np.float64).reshape(-1, 8))
        n_det += ref.n_detections
    assert n_skipped > 1000 and n_det > 0


def test_filter_without_a_table_keeps_every_segment():
    # the stand-in table of a detector without a cascade (or any other shape) settles nothing
    ranges, angles = arena_scans(5, 0.01, 16, 20)
    batch = segment_batch(ranges, angles)
    scan_cols = np.full((ranges.shape[0], 2), -4.5)
    rows = np.arange(batch.n_segments, dtype=np.int64)
    for table in (np.zeros((0, 4, 0, 6)), np.full((F._C1_N7, 4, F._C1_ND - 1, 6), -1e9)):
        out = np.empty_like(rows)
        m = F._cascade_one_beam_filter(
            np.ascontiguousarray(batch.ranges).reshape(-1), batch.scan, batch.first, batch.count,
            batch.prev_nearer, batch.next_nearer, ranges.shape[1], batch.circular, 12.0, scan_cols, table,
            0.0, rows, out,
        )  # fmt: skip
        assert m == rows.shape[0] and np.array_equal(out, rows)
