"""Array-first detection (``detect_arrays`` / ``BatchDetections``) against the previous implementation,
and "no return" readings (0.0, NaN, inf) that leave the other rows of a batch alone (issue 15)."""

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from detectors import _kernels as _k
from detectors.base import STAGES, BatchDetections
from detectors.geometric import _LM_LAMBDA0, _LM_LAMBDA_MAX, _LM_XTOL, GeometricKinDetector, GeometricParams
from kin_envs import LidarSpec, World, scenes
from tests.detectors.reference_detectors import ReferenceGeometricKinDetector
from tests.numerics import ATOL, RTOL

R = 0.035


def _paper_scans():
    out = []
    for k in (1, 2):
        for d in scenes.PAPER_DISTANCES:
            scan = World(scenes.paper_scenario(k, distance=d), seed=0).scan()
            out.append((f"paper_{k}_{d}", scan.ranges.astype(np.float64), scan.angles))
    return out


def _arena_scans(noise, seed, n_robots=12, n_obstacles=30):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    scan = World(scene, seed=seed).scan()
    return scan.ranges.astype(np.float64), scan.angles


SCANS = _paper_scans() + [
    (f"arena_{noise}_{seed}", *_arena_scans(noise, seed)) for noise, seed in ((0.0, 1), (0.01, 2), (0.01, 3))
]


def _close(a, b, tol=1e-7):
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b or (math.isnan(a) and math.isnan(b))
    return abs(a - b) <= tol * max(1.0, abs(b))


# --------------------------------------------------------------------------- geometric


@pytest.mark.parametrize(
    "params",
    [GeometricParams(), GeometricParams(noise_filter=True, shape_metric="mean", F_threshold=0.0015)],
    ids=["paper", "filter_mean"],
)
@pytest.mark.parametrize("name,ranges,angles", SCANS, ids=[s[0] for s in SCANS])
def test_geometric_matches_the_previous_implementation(name, ranges, angles, params):
    new = GeometricKinDetector(params).detect_batch(ranges, angles)
    old = ReferenceGeometricKinDetector(params).detect_batch(ranges, angles)
    assert len(new) == len(old) == ranges.shape[0]
    n_det = 0
    for a, b in zip(new, old, strict=True):
        assert [r.stage for r in a.reports] == [r.stage for r in b.reports]
        for x, y in zip(a.reports, b.reports, strict=True):
            sx, sy = x.segment, y.segment
            assert (sx.first_beam, sx.last_beam, sx.prev_beam, sx.next_beam) == (
                sy.first_beam,
                sy.last_beam,
                sy.prev_beam,
                sy.next_beam,
            )
            assert (sx.prev_nearer, sx.next_nearer) == (sy.prev_nearer, sy.next_nearer)
            np.testing.assert_array_equal(sx.beams, sy.beams)
            assert x.reason.split(":")[0] == y.reason.split(":")[0]
            assert set(x.metrics) == set(y.metrics)
            for k in x.metrics:
                assert _close(x.metrics[k], y.metrics[k]), (k, x.metrics[k], y.metrics[k])
        assert len(a.detections) == len(b.detections)
        for x, y in zip(a.detections, b.detections, strict=True):
            n_det += 1
            assert (x.first_beam, x.last_beam, x.n_beams) == (y.first_beam, y.last_beam, y.n_beams)
            for k in ("range", "x", "y"):
                assert _close(getattr(x, k), getattr(y, k), 1e-8)
            assert abs(math.remainder(x.bearing - y.bearing, 2 * math.pi)) < 1e-8
            # the reference scores with F itself; the new score is F_th / (F_th + F)
            assert _close(x.score, params.F_threshold / (params.F_threshold + y.score), 1e-6)
            assert x.score >= 0.5
    if name.startswith("paper"):
        assert n_det >= 1


def test_arrays_are_the_objects():
    ranges, angles = _arena_scans(0.01, 2)
    det = GeometricKinDetector()
    arr = det.detect_arrays(ranges, angles)
    assert isinstance(arr, BatchDetections)
    res = det.detect_batch(ranges, angles)
    assert arr.n_scans == len(res) and arr.n_segments == sum(len(r.reports) for r in res)
    np.testing.assert_array_equal(arr.counts(), [len(r.detections) for r in res])
    for b, r in enumerate(res):
        assert arr.detections(b) == r.detections
        assert [STAGES[c] for c in arr.seg_stage[arr.seg_scan == b]] == [x.stage for x in r.reports]
    assert (arr.score >= 0.5).all() and (arr.seg_stage[arr.segment] == 0).all()
    np.testing.assert_allclose(np.hypot(arr.x, arr.y), arr.range)
    # fixed-shape slots for vector envs
    k = 3
    pad = arr.padded(k)
    assert pad["x"].shape == pad["mask"].shape == (arr.n_scans, k)
    np.testing.assert_array_equal(pad["count"], arr.counts())
    np.testing.assert_array_equal(pad["mask"].sum(1), np.minimum(arr.counts(), k))
    off = arr.offsets()
    for b in range(arr.n_scans):
        m = min(k, int(arr.counts()[b]))
        np.testing.assert_array_equal(pad["x"][b, :m], arr.x[off[b] : off[b] + m])
        assert np.isnan(pad["x"][b, m:]).all() and (pad["first_beam"][b, m:] == -1).all()
    with pytest.raises(ValueError, match="k must be an integer"):
        arr.padded(-1)


def test_single_scan_interface_is_unchanged():
    ranges, angles = _arena_scans(0.01, 3)
    det = GeometricKinDetector()
    batch = det.detect_batch(ranges, angles)
    for row, res in zip(ranges, batch, strict=True):
        one = det.detect(row, angles)
        assert one.detections == res.detections
        assert [r.stage for r in one.reports] == [r.stage for r in res.reports]


def test_compiled_lm_matches_scipy():
    rng = np.random.default_rng(7)
    for _ in range(100):
        dist, bearing, k = rng.uniform(0.3, 4.0), rng.uniform(-math.pi, math.pi), int(rng.integers(3, 12))
        half = math.asin(R / dist) * 0.95
        ti = bearing + np.linspace(-half, half, k)
        b = dist * np.cos(ti - bearing)
        ri = (b - np.sqrt(np.maximum(b * b - (dist * dist - R * R), 0.0))) * (1 + rng.normal(0, 0.01, k))
        j = int(ri.argmin())
        x0 = np.array([ri[j] + R, ti[j]])

        def res(p, ri=ri, ti=ti):
            return np.sqrt(ri**2 + p[0] ** 2 - 2 * ri * p[0] * np.cos(ti - p[1])) - R

        ref = least_squares(res, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        rc, tc, sabs = _k.lm_fit(
            ri * np.cos(ti), ri * np.sin(ti), k, R, x0[0], x0[1], 200, _LM_XTOL, _LM_LAMBDA0, _LM_LAMBDA_MAX
        )
        assert rc == pytest.approx(ref[0], abs=1e-6)
        assert math.remainder(tc - ref[1], 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
        assert sabs == pytest.approx(np.abs(res(ref)).sum(), abs=1e-6)


# --------------------------------------------------------------------------- no return


def _with_bad_rows(ranges):
    """The batch with rows of 0.0 / NaN / inf readings inserted, and the indices of the good rows."""
    bad = np.array(ranges[:4])
    bad[0, :] = 0.0  # a whole scan of invalid readings
    bad[1, ::3] = 0.0  # every third beam invalid (0.0 inside and next to objects)
    bad[2, 5:40] = np.nan
    bad[2, 100:] = np.inf
    bad[3, ::2] = 0.0
    bad[3, 1::4] = np.nan
    rows = [bad[0], ranges[0], bad[1], ranges[1], bad[2], ranges[2], bad[3], ranges[3]]
    return np.array(rows), [1, 3, 5, 7]


def _detector(kind):
    if kind == "geometric":
        return GeometricKinDetector()
    pytest.importorskip("torch")
    from detectors.learned import LearnedKinDetector

    return LearnedKinDetector(inference=kind.split("-")[1])


@pytest.mark.parametrize("kind", ["geometric", "learned-torch", "learned-numba"])
def test_no_return_rows_leave_the_other_rows_alone(kind):
    det = _detector(kind)
    ranges, angles = _arena_scans(0.01, 2)
    batch, good = _with_bad_rows(ranges)
    got = det.detect_batch(batch, angles)
    assert len(got) == batch.shape[0]
    for i, row in zip(good, ranges[:4], strict=True):
        alone = det.detect_batch(row[None, :], angles)[0]
        if kind == "learned-torch":  # float32 matmuls may round differently with other rows around
            assert [(d.first_beam, d.last_beam) for d in got[i].detections] == [
                (d.first_beam, d.last_beam) for d in alone.detections
            ]
            for x, y in zip(got[i].detections, alone.detections, strict=True):
                assert x.x == pytest.approx(y.x, abs=1e-6) and x.score == pytest.approx(y.score, abs=1e-6)
        else:
            assert got[i].detections == alone.detections
        assert [r.stage for r in got[i].reports] == [r.stage for r in alone.reports]
    # an all-0.0 scan sees nothing; 0.0 reads exactly as inf (no return)
    assert got[0].detections == [] and got[0].reports == []
    as_inf = np.where(batch == 0.0, np.inf, batch)
    assert det.detect_batch(as_inf, angles)[2].detections == got[2].detections
    assert det.detect(batch[6], angles).detections == got[6].detections


@pytest.mark.parametrize("kind", ["geometric", "learned-numba"])
def test_negative_range_names_its_row(kind):
    det = _detector(kind)
    ranges, angles = _arena_scans(0.0, 1)
    ranges = ranges[:3].copy()
    ranges[2, 17] = -0.5
    with pytest.raises(ValueError, match=r"ranges\[2\].*>= 0"):
        det.detect_batch(ranges, angles)
    with pytest.raises(ValueError, match=">= 0"):
        det.detect(ranges[2], angles)


# --------------------------------------------------------------------------- learned


@pytest.fixture(scope="module")
def torch_mod():
    return pytest.importorskip("torch")


@pytest.mark.parametrize("inference", ["torch", "numba", "blas"])
@pytest.mark.parametrize("positioning", ["regression", "fit"])
@pytest.mark.parametrize("pre_gate", [False, True])
def test_learned_matches_the_previous_implementation(torch_mod, inference, positioning, pre_gate):
    from detectors.learned import LearnedKinDetector
    from tests.detectors.reference_detectors import reference_learned_predict

    # the cascade (its own tests: test_learned_cascade.py) off: the pre-gate alone drops only rejects
    det = LearnedKinDetector(inference=inference, positioning=positioning, pre_gate=pre_gate, cascade=False)
    n_gated = 0
    for _, ranges, angles in SCANS[::2] + SCANS[-2:]:
        arr = det.detect_arrays(ranges, angles)
        batch, p, centres, thr = reference_learned_predict(det, ranges, angles)
        gated = np.isnan(arr.seg_values["p_kin"])
        if pre_gate:
            # the pre-gate drops only segments the network rejects, with the "diameter" stage
            assert (p[gated] < thr[gated]).all()
            np.testing.assert_array_equal(arr.seg_stage[gated], 1)
            np.testing.assert_array_equal(gated, batch.count > arr.seg_values["max_beams"])
            n_gated += int(gated.sum())
            p = np.where(gated, np.nan, p)
        else:
            assert "max_beams" not in arr.seg_values
        np.testing.assert_array_equal(arr.seg_scan, batch.scan)
        np.testing.assert_array_equal(arr.seg_first, batch.first)
        np.testing.assert_array_equal(arr.seg_count, batch.count)
        np.testing.assert_array_equal(arr.seg_prev, batch.prev_beam)
        np.testing.assert_array_equal(arr.seg_next_nearer, batch.next_nearer)
        # torch: the same module on the same rows (its softmax a few ULP off numpy's on AVX-512 CPUs:
        # tests/numerics.py); numba / blas: float32 sums in another order
        np.testing.assert_allclose(
            arr.seg_values["p_kin"], p, rtol=RTOL, atol=ATOL if inference == "torch" else 1e-5
        )
        near = np.abs(p - thr) < 1e-5  # a segment this close to the threshold may go either way
        np.testing.assert_array_equal((arr.seg_stage == 0)[~near], (p >= thr)[~near])
        acc = arr.segment[~near[arr.segment]]
        sel = ~near[arr.segment]
        np.testing.assert_allclose(arr.x[sel], centres[acc, 0], atol=1e-6)
        np.testing.assert_allclose(arr.y[sel], centres[acc, 1], atol=1e-6)
    assert (n_gated > 0) == pre_gate


def test_learned_inference_leaves_the_callers_torch_threads_alone(torch_mod):
    from detectors.learned import LearnedKinDetector

    ranges, angles = _arena_scans(0.01, 3)
    det = LearnedKinDetector(reports=False)
    before = torch_mod.get_num_threads()
    try:
        torch_mod.set_num_threads(2)
        a = det.detect_arrays(ranges, angles)
        assert torch_mod.get_num_threads() == 2
        torch_mod.set_num_threads(1)
        b = det.detect_arrays(ranges, angles)
    finally:
        torch_mod.set_num_threads(before)
    np.testing.assert_array_equal(a.seg_values["p_kin"], b.seg_values["p_kin"])
    with pytest.raises(ValueError, match="inference must be one of"):
        LearnedKinDetector(inference="onnx")
    with pytest.raises(ValueError, match="torch_threads"):
        LearnedKinDetector(torch_threads=0)


def test_learned_blas_inference_leaves_the_callers_blas_threads_alone():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    from detectors.learned import LearnedKinDetector

    ranges, angles = _arena_scans(0.01, 3)
    auto, blas, numba_ = (LearnedKinDetector(reports=False, inference=i) for i in ("auto", "blas", "numba"))
    ctl = threadpoolctl.ThreadpoolController().select(user_api="blas")
    if not ctl.lib_controllers:
        pytest.skip("no BLAS library found by threadpoolctl")
    results = {}
    for n in (1, 2):
        with ctl.limit(limits=n):
            results[n] = blas.detect_arrays(ranges, angles)
            # the caller's count is back after the call
            assert {lib.num_threads for lib in ctl.lib_controllers} == {n}
            assert {lib.get_num_threads() for lib in ctl.lib_controllers} == {n}
    np.testing.assert_array_equal(results[1].seg_values["p_kin"], results[2].seg_values["p_kin"])
    # BLAS agrees with the compiled kernels within float32 rounding; "auto" is the compiled kernels
    ref = numba_.detect_arrays(ranges, angles)
    np.testing.assert_allclose(results[1].seg_values["p_kin"], ref.seg_values["p_kin"], rtol=0, atol=1e-5)
    for r in (ranges, ranges[:1]):
        got, want = auto.detect_arrays(r, angles), numba_.detect_arrays(r, angles)
        np.testing.assert_array_equal(got.seg_values["p_kin"], want.seg_values["p_kin"])


@pytest.mark.parametrize("kind", ["geometric", "learned-numba"])
def test_reports_are_built_once_on_first_access(kind, monkeypatch):
    det = _detector(kind)
    ranges, angles = _arena_scans(0.01, 2)
    eager = det.segment_reports(det.detect_arrays(ranges, angles))
    calls = []
    build = det.segment_reports
    monkeypatch.setattr(det, "segment_reports", lambda arr: calls.append(1) or build(arr))
    res = det.detect_batch(ranges, angles)
    assert calls == []  # detections only: no report objects made
    assert [r.stage for r in res[3].reports] == [r.stage for r in eager[3]]
    assert [r.reason for r in res[0].reports] == [r.reason for r in eager[0]]
    assert calls == [1]  # one build for the whole batch
    assert sum(len(r.reports) for r in res) == sum(map(len, eager))
    det.reports = False
    assert all(r.reports == [] for r in det.detect_batch(ranges, angles)) and calls == [1]
