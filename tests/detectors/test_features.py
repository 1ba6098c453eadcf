"""detectors.features: the learned classifier's segment representation."""

import math

import numpy as np
import pytest

from detectors.features import (
    FEATURE_VERSION,
    FeatureConfig,
    feature_names,
    local_to_observer,
    observer_to_local,
    scan_noise,
    segment_batch,
    segment_features,
)
from detectors.geometric import filter_by_diameter, preprocess, segment
from kin_envs import LidarSpec, World, scenes
from kin_envs.scenes import Arena, Prism, Robot, Scene

NAMES = feature_names()


def col(x, name):
    return x[:, NAMES.index(name)]


def scan_of(scene, seed=0, rows=None):
    return World(scene, seed=seed).scan(robots=rows)


def test_version_and_names():
    assert isinstance(FEATURE_VERSION, int) and FEATURE_VERSION >= 1
    assert len(NAMES) == len(set(NAMES))
    cfg = FeatureConfig(n_points=5, n_context=1)
    assert len(feature_names(cfg)) == len(NAMES) - 3 * 3 - 2


@pytest.mark.parametrize(
    "bad", [{"n_points": 1}, {"n_context": -1}, {"r": 0.0}, {"d_th": 20.0}, {"gn_iters": 1.5}, {"color": 1}]
)
def test_config_validation(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        FeatureConfig.from_dict(bad)


def test_batch_is_the_geometric_segmentation():
    scan = scan_of(scenes.detection_scene(3, lidar=LidarSpec(noise_sigma=0.01)))
    batch = segment_batch(scan.ranges, scan.angles)
    for b, row in enumerate(scan.ranges):
        ref = segment(preprocess(row))
        got = batch.segments[b]
        assert [(s.first_beam, s.last_beam) for s in got] == [(s.first_beam, s.last_beam) for s in ref]
        sel = batch.scan == b
        assert batch.first[sel].tolist() == [s.first_beam for s in ref]
        assert batch.count[sel].tolist() == [s.n_beams for s in ref]
        assert batch.prev_nearer[sel].tolist() == [s.prev_nearer for s in ref]


def test_diameter_features_match_filter_by_diameter():
    scan = scan_of(scenes.detection_scene(7, lidar=LidarSpec(noise_sigma=0.005)))
    batch = segment_batch(scan.ranges, scan.angles)
    x = segment_features(batch).x
    segs = batch.flat_segments()
    assert x.shape == (len(segs), len(NAMES)) and np.isfinite(x).all()
    for i, s in enumerate(segs):
        dc = filter_by_diameter(s, batch.ranges[batch.scan[i]], batch.angles)
        assert col(x, "omega_min")[i] == pytest.approx(min(dc.omega_min, 0.3), abs=1e-5)
        assert col(x, "omega_max")[i] == pytest.approx(min(dc.omega_max, 0.3), abs=1e-5)
        assert col(x, "diameter_pass")[i] == dc.passed


def test_circle_fit_separates_a_kin_from_a_kin_width_prism():
    # noise-free: the kin's known-radius fit is exact, a 7 cm hexagon's is off by millimetres
    scene = Scene(
        robots=(Robot(0, 0, 0), Robot(0.7, 0.0, 1.0)),
        obstacles=(Prism(x=0.0, y=0.7, sides=6, width=0.07, theta=0.3),),
        arena=Arena(3, 3, walls=False),
    )
    scan = scan_of(scene, rows=[0])
    batch = segment_batch(scan.ranges, scan.angles)
    f = segment_features(batch)
    assert batch.n_segments == 2
    bearing = np.arctan2(f.frames[:, 1], f.frames[:, 0])
    kin, prism = int(np.argmin(np.abs(bearing))), int(np.argmax(bearing))
    assert math.exp(col(f.x, "log_F_mean")[kin]) - 1e-4 < 1e-6
    assert math.exp(col(f.x, "log_F_mean")[prism]) - 1e-4 > 5e-4
    np.testing.assert_allclose(f.fit_centre[kin], [0.7, 0.0], atol=1e-4)
    assert col(f.x, "kasa_curvature")[kin] == pytest.approx(1 / 0.035, rel=1e-3)


def test_features_do_not_depend_on_where_the_robot_looks():
    # the robot turning by k beams rotates the scan; every segment's vector stays the same
    scene = scenes.detection_scene(11)
    scan = scan_of(scene, rows=[0])
    k = 37
    rolled = np.roll(scan.ranges, k, axis=1)
    fa = segment_features(segment_batch(scan.ranges, scan.angles))
    fb = segment_features(segment_batch(rolled, scan.angles))
    ba = segment_batch(scan.ranges, scan.angles)
    bb = segment_batch(rolled, scan.angles)
    n = scan.angles.shape[0]
    order_a = np.argsort(ba.first)
    order_b = np.argsort((bb.first - k) % n)
    assert ba.n_segments == bb.n_segments
    np.testing.assert_allclose(fa.x[order_a], fb.x[order_b], atol=2e-4)


def test_local_frame_round_trip():
    rng = np.random.default_rng(0)
    frames = np.column_stack([rng.normal(size=(5, 2)), rng.uniform(-3, 3, 5), rng.choice([-1.0, 1.0], 5)])
    xy = rng.normal(size=(5, 2))
    np.testing.assert_allclose(local_to_observer(frames, observer_to_local(frames, xy)), xy, atol=1e-12)
    # origin maps to the frame origin, u runs along the bearing phi
    uv = np.array([[1.0, 0.0]] * 5)
    out = local_to_observer(frames, uv) - frames[:, :2]
    np.testing.assert_allclose(
        np.arctan2(out[:, 1], out[:, 0]), np.arctan2(np.sin(frames[:, 2]), np.cos(frames[:, 2]))
    )


@pytest.mark.parametrize("sigma, lo, hi", [(0.0, 0.0, 0.0005), (0.01, 0.007, 0.013)])
def test_scan_noise_estimate(sigma, lo, hi):
    scan = scan_of(scenes.detection_scene(2, lidar=LidarSpec(noise_sigma=sigma)))
    est, n = scan_noise(segment_batch(scan.ranges, scan.angles))
    assert np.all((est >= lo) & (est <= hi)), est
    assert np.all(n > 100)


def test_scan_noise_without_the_segmentation_is_the_same():
    """scan_noise_of(ranges, angles) equals scan_noise(segment_batch(ranges, angles)) bitwise: noisy and
    noise-free scans, no-returns (0, inf, NaN), a partial (270 degree) sweep; bad shapes raise."""
    from detectors.features import scan_noise_of

    rng = np.random.default_rng(4)
    for sigma in (0.0, 0.005, 0.02):
        scan = scan_of(scenes.detection_scene(3, lidar=LidarSpec(noise_sigma=sigma)))
        r = scan.ranges.astype(np.float64)
        r[rng.random(r.shape) < 0.05] = rng.choice([0.0, np.inf, np.nan])
        for angles, rows in ((scan.angles, r), (scan.angles[:270], r[:, :270])):
            want = scan_noise(segment_batch(rows, angles))
            got = scan_noise_of(rows, angles)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
    with pytest.raises(ValueError, match="ranges"):
        scan_noise_of(np.ones((2, 5)), np.zeros(6))


@pytest.mark.parametrize("number", [1, 2])
def test_scan_noise_of_a_noise_free_empty_world(number):
    # only small round and polygonal objects return beams: their shape must not read as noise
    scene = scenes.paper_scenario(number, distance=0.8)
    scan = scan_of(scene, rows=[0])
    est, _ = scan_noise(segment_batch(scan.ranges, scan.angles))
    assert est[0] < 0.001


def test_empty_and_partial_scans():
    spec = LidarSpec()
    batch = segment_batch(np.full((2, spec.n_beams), np.inf), spec.angles)
    f = segment_features(batch)
    assert batch.n_segments == 0 and f.x.shape == (0, len(NAMES))
    # a 270-degree lidar: not circular, segments stop at the field-of-view edges
    angles = np.linspace(0.75 * np.pi, -0.75 * np.pi, 271)
    ranges = np.full(271, 2.0)
    batch = segment_batch(ranges[None], angles)
    assert not batch.circular and batch.n_segments == 1
    assert np.isfinite(segment_features(batch).x).all()


def test_quantile_selection_is_numbas_np_quantile():
    # scan_noise's selection (out-of-place partitions into scratch arrays) must give numba's np.quantile bit
    # for bit (the value the features were trained with): random sizes, ties, tiny and repeated values, sorted
    # and reversed inputs; the input is left as it is
    import numba

    from detectors.features import _quantile

    ref = numba.njit(lambda a, q: np.quantile(a, q))
    rng = np.random.default_rng(0)
    for trial in range(600):
        n = int(rng.integers(2, 400))
        a = [rng.random(n), np.round(rng.random(n) * 5) / 7, np.abs(rng.normal(size=n)) * 1e-3,
             np.full(n, 0.25), np.sort(rng.random(n)), np.sort(rng.random(n))[::-1].copy()
             ][trial % 6]  # fmt: skip
        for q in (0.3, 0.05, 0.5, 0.95):
            b = a.copy()
            assert _quantile(b, n, q) == ref(a, q), (trial, n, q)
            assert np.array_equal(b, a)  # not reordered


def test_log1p_table_is_numbas_log1p():
    # the kernels look log1p(n) up in _LOG1P_N: it must be the value numba's math.log1p gives
    import numba

    from detectors.features import _LOG1P_N, _log1p_n

    ref = numba.njit(lambda n: math.log1p(float(n)))
    look = numba.njit(lambda n: _log1p_n(n))
    for n in range(200):
        assert look(n) == ref(n), n
    assert _LOG1P_N.shape[0] < 200  # the lengths past the table are computed


def _scan_noise_reference(d, d_th, d_max, circular):
    # the kernel's definition beam by beam (plain Python; numpy's quantile on the kept values is
    # compared bitwise to numba's in test_quantile_selection_is_numbas_np_quantile)
    from detectors.features import _NOISE_Q, _NOISE_SCALE, _quantile

    n = d.shape[1]
    est, count = [], []
    for row in d:
        vals = []
        for i in range(n if circular else n - 3):
            a0, a1, a2, a3 = (row[(i + k) % n] for k in range(4))
            if max(a0, a1, a2, a3) >= d_max or max(abs(a1 - a0), abs(a2 - a1), abs(a3 - a2)) > d_th:
                continue
            vals.append(abs(a3 - 3.0 * a2 + 3.0 * a1 - a0) / (0.5 * (a1 + a2)))
        buf = np.array(vals + [0.0])
        est.append(_quantile(buf, len(vals), _NOISE_Q) / _NOISE_SCALE if len(vals) >= 5 else 0.0)
        count.append(len(vals))
    return np.array(est), np.array(count)


@pytest.mark.parametrize("circular", [True, False])
def test_branch_free_scan_noise_keeps_the_same_windows(circular):
    # _scan_noise_kernel writes every window and keeps the qualifying ones: the same values as
    # skipping them, on noisy random-arena scans with no-returns and breaks across beam 0
    c = FeatureConfig()
    scan = scan_of(scenes.random_arena(6, 12, seed=7).replace(lidar=LidarSpec(noise_sigma=0.02)))
    ranges = scan.ranges.copy()
    ranges[:, :2] = np.inf  # a no-return across the wrap
    ranges[1, -1] = 0.5  # a break just before beam 0
    angles = scan.angles if circular else scan.angles[:271].copy()
    batch = segment_batch(ranges if circular else ranges[:, :271].copy(), angles)
    assert batch.circular == circular
    est, count = scan_noise(batch, c)
    ref_est, ref_count = _scan_noise_reference(batch.ranges, c.d_th, c.d_max, circular)
    assert np.array_equal(count, ref_count) and (count > 5).all()
    assert np.array_equal(est, ref_est)


@pytest.mark.parametrize("layout", ["full turn", "reversed", "270 degrees"])
def test_tan_table_gives_the_same_features(layout):
    # the detector's beam_trig(angles, 32) looks eqs. 4-5's tan up; features and cascade inputs must
    # be the very values computed without the table (random arena scans, every segment)
    from detectors.features import _cascade, _segment_features, beam_trig, cascade_features

    scan = scan_of(scenes.random_arena(12, 25, seed=4).replace(lidar=LidarSpec(noise_sigma=0.01)))
    ranges, angles = scan.ranges.astype(np.float64), scan.angles
    if layout == "reversed":
        ranges, angles = ranges[:, ::-1].copy(), angles[::-1].copy()
    elif layout == "270 degrees":
        ranges, angles = ranges[:, :271].copy(), angles[:271].copy()
    batch = segment_batch(ranges, angles)
    assert batch.circular == (layout != "270 degrees") and batch.n_segments > 100
    which = np.arange(batch.n_segments, dtype=np.int64)
    ref = segment_features(batch)
    for n_off in (1, 2, 32, 400):
        trig = beam_trig(angles, n_off)
        got = _segment_features(batch, FeatureConfig(), which, trig)
        for name in ("x", "frames", "fit_centre", "min_beam"):
            assert np.array_equal(getattr(got, name), getattr(ref, name)), (n_off, name)
        x, _ = _cascade(batch, FeatureConfig(), which, trig, None, None)
        assert np.array_equal(x, cascade_features(batch)), n_off
