"""detectors.windows: candidate windows inside segments too wide for a housing (issue 11, rounds 5-6)."""

import math

import numpy as np
import pytest

from detectors.features import FeatureConfig, segment_batch
from detectors.windows import PRE_GATE_MARGIN, PRE_GATE_SLACK, WindowConfig, candidate_windows, wide_segments

N = 360
STEP = 2 * math.pi / N
R = 0.035
ANGLES = np.arange(N) * STEP
ROUND5 = WindowConfig(anchor="local", sag=0.0, sag_noise=0.0)
ROUND6 = WindowConfig()


def _scene(centre_dist, centre_beam, wall=1.0, wall_angle=0.0, half=25, noise=0.0, rng=None, housing=True):
    """One scan: a straight wall at ``wall`` m (normal ``wall_angle`` rad off beam 0) over beams
    -half..half, and (optionally) a housing of radius R whose centre is ``centre_dist`` m away at the
    (fractional) beam ``centre_beam`` → ``(ranges (1, N), housing beams)``."""
    k = np.arange(-half, half + 1)
    th = k * STEP
    d = wall / np.cos(th - wall_angle)
    hit = np.zeros(k.size, bool)
    if housing:
        s = centre_dist * np.sin(th - centre_beam * STEP)
        hit = np.abs(s) < R
        near = centre_dist * np.cos(th[hit] - centre_beam * STEP) - np.sqrt(R * R - s[hit] ** 2)
        d[hit] = np.minimum(d[hit], near)
    if noise:
        d = d * (1 + noise * rng.standard_normal(d.shape))
    ranges = np.full((1, N), np.inf)
    ranges[0, k % N] = d
    return ranges, set((k[hit] % N).tolist())


def _windows(ranges, config):
    batch = segment_batch(ranges, ANGLES, FeatureConfig())
    return batch, candidate_windows(batch, wide_segments(batch, STEP, R), STEP, R, config, FeatureConfig())


def _beams(win, i):
    return {(int(win.batch.first[i]) + k) % N for k in range(int(win.batch.count[i]))}


@pytest.mark.parametrize("config", [ROUND5, ROUND6], ids=["round5", "round6"])
@pytest.mark.parametrize("offset", [0.0, 0.4])  # housing centred on a beam / between two beams
def test_housing_touching_a_wall_is_exactly_its_own_beams(config, offset):
    ranges, housing = _scene(1.0 - R, offset)
    batch, win = _windows(ranges, config)
    assert batch.n_segments == 1 and wide_segments(batch, STEP, R).tolist() == [0]  # merged with the wall
    assert win.n_windows == 1  # the wall's ranges grow away from beam 0: its only minimum is the housing's
    assert _beams(win, 0) == housing and win.batch.count[0] >= 4
    # the window's neighbours are the wall beams beside it, farther than its ends
    first, count = int(win.batch.first[0]), int(win.batch.count[0])
    assert win.batch.prev_beam[0] == (first - 1) % N and win.batch.next_beam[0] == (first + count) % N
    assert not win.batch.prev_nearer[0] and not win.batch.next_nearer[0]
    assert win.parent.tolist() == [0] and win.sag[0] > R  # bulges by ~2 r in front of the wall


def test_lone_housing_gives_one_window():
    """A housing standing in front of a straight wall (touching it or up to 2 cm off: one merged segment;
    the wall at 0.45-1.2 m, its normal up to 0.35 rad off): round 6 gives exactly one window, on the
    housing's own beams; round 5 also cuts windows at the wall's own range minimum or its nearer end."""
    rng = np.random.default_rng(0)
    extra_r5 = merged = 0
    for _ in range(60):
        wall = rng.uniform(0.45, 1.2)
        gap = rng.uniform(0.0, 0.02)
        beam = rng.uniform(-15, 15)
        angle = rng.uniform(-0.35, 0.35)  # the wall's own minimum inside, away from its ends
        dist = wall / math.cos(beam * STEP - angle) - R - gap / math.cos(beam * STEP - angle)
        ranges, housing = _scene(dist, beam, wall, angle)
        batch, win = _windows(ranges, ROUND6)
        if batch.n_segments != 1:  # a steep wall behind a housing off it breaks at the housing's edge
            continue
        merged += 1
        assert win.n_windows == 1 and _beams(win, 0) == housing, (wall, gap, beam, angle)
        extra_r5 += _windows(ranges, ROUND5)[1].n_windows - 1
    assert merged >= 40 and extra_r5 > 0


def test_anchor_is_noise_robust_on_a_wall():
    """A bare straight wall (81 beams, 0.5-1.5 m, at any angle up to 0.6 rad) with 1 % range noise: round
    5 cuts a window at every noisy local minimum (~19 per wall), round 6 (bulge test against the scan's
    noise) more than 8 times fewer; a housing touching the same wall keeps its window."""
    rng = np.random.default_rng(1)
    r5 = r6 = found = 0
    trials = 40
    for _ in range(trials):
        wall, angle = rng.uniform(0.5, 1.5), rng.uniform(-0.6, 0.6)
        ranges, _ = _scene(0.0, 0.0, wall, angle, half=40, noise=0.01, rng=rng, housing=False)
        # the scan-noise estimate needs the wall's own beams; the bare wall is the whole scan
        r5 += _windows(ranges, ROUND5)[1].n_windows
        r6 += _windows(ranges, ROUND6)[1].n_windows
        beam = rng.uniform(-20, 20)
        dist = wall / math.cos(beam * STEP - angle) - R
        ranges, housing = _scene(dist, beam, wall, angle, half=40, noise=0.01, rng=rng)
        _, win = _windows(ranges, ROUND6)
        found += any(len(_beams(win, i) & housing) > len(housing) // 2 for i in range(win.n_windows))
    assert r5 / trials > 12  # a window every few beams
    assert r6 / trials < 2 and r6 * 8 < r5
    assert found >= 0.85 * trials


def _round5_rows(ranges, r, depth, batch, segs):
    """Round 5's window builder (a Python loop over beams): the slow oracle of ``anchor="local"``
    without the bulge test."""
    n = ranges.shape[1]
    rows = []
    for s in segs.tolist():
        b, f, c = int(batch.scan[s]), int(batch.first[s]), int(batch.count[s])
        idx = (f + np.arange(c)) % n
        d = ranges[b, idx]
        for j in range(c):
            if (j > 0 and d[j] > d[j - 1]) or (j < c - 1 and d[j] >= d[j + 1]):
                continue
            dm = d[j]
            w = int(math.floor(math.asin(min(r / (dm + r), 1.0)) / STEP)) + 1
            a0 = a1 = j
            while a0 > 0 and j - a0 + 1 <= w and d[a0 - 1] - dm <= depth * r:
                a0 -= 1
            while a1 < c - 1 and a1 + 1 - j <= w and d[a1 + 1] - dm <= depth * r:
                a1 += 1
            if a1 - a0 + 1 < 2 or (a0 == 0 and a1 == c - 1):
                continue
            prev = int(idx[a0 - 1]) if a0 > 0 else int(batch.prev_beam[s])
            nxt = int(idx[a1 + 1]) if a1 < c - 1 else int(batch.next_beam[s])
            pn = bool(d[a0 - 1] < d[a0]) if a0 > 0 else bool(batch.prev_nearer[s])
            nn = bool(d[a1 + 1] < d[a1]) if a1 < c - 1 else bool(batch.next_nearer[s])
            rows.append((b, int(idx[a0]), a1 - a0 + 1, prev, nxt, pn, nn, s, int(idx[j])))
    return rows


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_local_anchor_matches_round5_loop(noise):
    from kin_envs import World, scenes

    scene = scenes.random_arena(24, 30, seed=3, size=5.0)
    scan = World(scene, seed=4).scan(noise=False)
    rng = np.random.default_rng(5)
    ranges = scan.ranges * (1 + noise * rng.standard_normal(scan.ranges.shape))
    batch = segment_batch(ranges, scan.angles, FeatureConfig())
    segs = wide_segments(batch, STEP, R)
    assert segs.size > 10
    for depth in (1.0, 0.5):
        win = candidate_windows(batch, segs, STEP, R, WindowConfig(anchor="local", depth=depth, sag=0.0,
                                                                   sag_noise=0.0))  # fmt: skip
        wb = win.batch
        got = list(zip(wb.scan.tolist(), wb.first.tolist(), wb.count.tolist(), wb.prev_beam.tolist(),
                       wb.next_beam.tolist(), wb.prev_nearer.tolist(), wb.next_nearer.tolist(),
                       win.parent.tolist(), win.anchor.tolist(), strict=True))  # fmt: skip
        assert got == _round5_rows(batch.ranges, R, depth, batch, segs)


def test_round6_windows_are_a_subset_with_the_bulge():
    """``anchor="local"`` with the bulge test keeps exactly the windows of the plain local minima whose
    bulge passes; ``sag`` is the anchor's distance in front of the chord (checked with a loop)."""
    from kin_envs import World, scenes

    scan = World(scenes.random_arena(24, 30, seed=6, size=5.0), seed=7).scan()
    batch = segment_batch(scan.ranges, scan.angles, FeatureConfig())
    segs = wide_segments(batch, STEP, R)
    plain = candidate_windows(batch, segs, STEP, R, ROUND5)
    r6 = candidate_windows(batch, segs, STEP, R, ROUND6)
    key = lambda w: list(zip(w.batch.scan.tolist(), w.batch.first.tolist(), w.batch.count.tolist(),  # noqa: E731
                             strict=True))  # fmt: skip
    assert set(key(r6)) < set(key(plain))
    keep = [i for i, k in enumerate(key(plain)) if k in set(key(r6))]
    np.testing.assert_allclose(r6.sag, plain.sag[keep])
    assert (r6.sag >= ROUND6.sag * R).all()


def test_wide_segments_are_the_pre_gates():
    torch = pytest.importorskip("torch")  # noqa: F841
    from detectors import _kernels as _k
    from detectors import learned
    from kin_envs import scenes
    from kin_envs.core.world import World

    assert (PRE_GATE_SLACK, PRE_GATE_MARGIN) == (learned.PRE_GATE_SLACK, learned.PRE_GATE_MARGIN)
    scan = World(scenes.random_arena(32, 40, seed=8, size=6.0), seed=9).scan()
    det = learned.LearnedKinDetector(reports=False, cascade=False)
    a = det.detect_arrays(scan.ranges, scan.angles)
    batch = segment_batch(scan.ranges, scan.angles, det.feature_config)
    assert np.array_equal(batch.first, a.seg_first)
    np.testing.assert_array_equal(wide_segments(batch, STEP, R), np.flatnonzero(a.seg_stage == _k.DIAMETER))


def test_config_errors():
    with pytest.raises(ValueError, match="anchor"):
        WindowConfig(anchor="nearest")
    with pytest.raises(ValueError, match="depth"):
        WindowConfig(depth=0.0)
    with pytest.raises(ValueError, match="sag_noise"):
        WindowConfig(sag_noise=float("nan"))
