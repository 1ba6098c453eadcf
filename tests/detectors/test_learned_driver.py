"""detectors._learned_driver: the fused one-dispatch driver gives the staged pipeline's outputs, bit for bit
(within a few ULP on CPUs where numpy's float64 math is SIMD code: tests/numerics.py).

(The cascade, which the driver does not run, is off here: tests/detectors/test_learned_cascade.py.)

``LearnedKinDetector._detect_arrays_staged`` is the readable staged pipeline (``_predict``: numpy calls
between the stage kernels); ``detect_arrays`` / the trusted entries run the fused driver. They must agree
on every field for every inference path, positioning, pre-gate setting and batch size, including the
paths where the network runs in Python between the driver's two kernels (BLAS, torch).
"""

import math

import numpy as np
import pytest

pytest.importorskip("torch")  # the only reason to skip: CI installs torch

from detectors import _learned_driver as _drv  # noqa: E402
from detectors.base import wrap_angle  # noqa: E402
from detectors.learned import LearnedKinDetector  # noqa: E402
from kin_envs import LidarSpec, World, scenes  # noqa: E402
from tests.numerics import assert_same_values, same_values  # noqa: E402

FIELDS = (
    "scan", "range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams_on", "segment",
    "seg_scan", "seg_first", "seg_count", "seg_prev", "seg_next", "seg_prev_nearer", "seg_next_nearer",
    "seg_stage",
)  # fmt: skip


def assert_same(got, ref):
    assert (got.n_scans, got.n_beams) == (ref.n_scans, ref.n_beams)
    for f in FIELDS:
        a, b = getattr(got, f), getattr(ref, f)
        assert a.dtype == b.dtype and a.shape == b.shape, f
        assert_same_values(a, b, f)
    assert got.seg_values.keys() == ref.seg_values.keys()
    for k, v in ref.seg_values.items():
        assert got.seg_values[k].dtype == v.dtype
        assert_same_values(got.seg_values[k], v, k)


def arena(seed, noise, n_robots=16, n_obstacles=20):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
    return World(scene, seed=seed).scan()


SCANS = [arena(seed, noise) for seed, noise in ((0, 0.0), (1, 0.01), (2, 0.005))]


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"inference": "numba"},
        {"inference": "blas"},
        {"inference": "torch"},
        {"pre_gate": False},
        {"positioning": "fit"},
        {"threshold": 0.3},
    ],
    ids=["default", "numba", "blas", "torch", "no_pre_gate", "fit", "fixed_threshold"],
)
def test_fused_driver_is_bitwise_the_staged_pipeline(kwargs):
    det = LearnedKinDetector(reports=False, cascade=False, **kwargs)
    n_det = 0
    for s in SCANS:
        # one scan (a single-agent env), a few, every robot's (hundreds of rows: the block kernel)
        for r in (s.ranges[:1], s.ranges[2:5], s.ranges):
            ref = det._detect_arrays_staged(r.astype(np.float64), s.angles)
            assert_same(det.detect_arrays(r, s.angles), ref)
            assert_same(det._detect_arrays_trusted(r, s.angles), ref)
            n_det += ref.n_detections
    assert n_det > 0
    assert sum(det.detect_arrays(s.ranges, s.angles).n_segments for s in SCANS) >= 256


def test_fused_driver_edge_cases():
    det = LearnedKinDetector(reports=False, cascade=False)
    s = SCANS[1]
    n = s.angles.shape[0]
    empty = np.full((2, n), np.inf)
    empty[1, :] = 0.0  # "no return" in both RPLIDAR spellings: no segment at all
    one_wall = np.full((1, n), 3.0)  # a round room: one segment without a break, dropped by the pre-gate
    mixed = np.vstack([empty, s.ranges[:1].astype(np.float64), one_wall])
    # every beam its own segment: 360 rows in one scan
    comb = np.where(np.arange(n) % 2 == 0, 1.0, 1.5)[None, :]
    for r in (empty, one_wall, mixed, comb, empty[:1]):
        ref = det._detect_arrays_staged(r, s.angles)
        got = det.detect_arrays(r, s.angles)
        assert_same(got, ref)
    assert det.detect_arrays(empty, s.angles).n_segments == 0
    assert "max_beams" not in det.detect_arrays(empty, s.angles).seg_values  # as the staged pipeline


def test_repeated_calls_with_different_scans_keep_earlier_results():
    det = LearnedKinDetector(reports=False, cascade=False)
    scans = [arena(seed, 0.01, n_robots=8) for seed in (10, 11, 12)]
    got, kept = [], []
    for s in scans:
        for r in s.ranges[:4]:
            b = det._detect_arrays_trusted(r[None, :], s.angles)
            got.append(b)
            kept.append({f: getattr(b, f).copy() for f in FIELDS})
    for b, k in zip(got, kept, strict=True):  # later calls left every earlier result alone
        for f in FIELDS:
            assert np.array_equal(getattr(b, f), k[f], equal_nan=True), f
    for f in FIELDS:
        assert not np.shares_memory(getattr(got[0], f), getattr(got[1], f)), f
    rows, tables = [], []
    for s in scans:
        row, tab = det._detect_table_trusted(s.ranges[:1], s.angles)
        rows.append(row)
        tables.append(tab)
        ref = det._detect_arrays_staged(s.ranges[:1], s.angles)
        expected = np.stack(
            [ref.range, ref.bearing, ref.x, ref.y, ref.score, ref.first_beam, ref.last_beam, ref.n_beams_on],
            axis=1,
        ).astype(np.float64)
        assert same_values(tab, expected) and np.array_equal(row, ref.scan)
    assert not np.shares_memory(tables[0], tables[1])


def test_driver_bearing_expression_matches_numpy():
    # the driver's wrap(atan2) per detection against the staged path's wrap_angle(np.arctan2)
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(2, 2000)) * 3.0
    x[:4], y[:4] = (-1.0, 0.0, 0.0, -0.0), (-0.0, 1.0, -1.0, 0.0)
    assert_same_values(_drv_wrap_atan2(y, x), wrap_angle(np.arctan2(y, x)), "bearing")


def _drv_wrap_atan2(y, x):
    from detectors import _kernels as _k

    return np.array([_k.wrap(math.atan2(b, a)) for a, b in zip(x.tolist(), y.tolist(), strict=True)])


def test_table_fields_are_the_env_detection_fields():
    from kin_envs.envs.info import DETECTION_FIELDS

    assert _drv.TABLE_FIELDS == DETECTION_FIELDS[:8]


def _staged_table(det, r, angles):
    ref = det._detect_arrays_staged(np.asarray(r, dtype=np.float64), angles)
    cols = [ref.range, ref.bearing, ref.x, ref.y, ref.score, ref.first_beam, ref.last_beam, ref.n_beams_on]
    return ref.scan, np.stack(cols, axis=1).astype(np.float64).reshape(-1, 8)


@pytest.mark.parametrize("inference", ["auto", "numba", "blas"])
def test_table_entry_equals_the_staged_detections(inference):
    det = LearnedKinDetector(reports=False, cascade=False, inference=inference)
    s = SCANS[2]
    n = s.angles.shape[0]
    # every beam its own segment (alternating ranges): 360 segments reach the network in one scan
    comb = np.where(np.arange(n) % 2 == 0, 1.0, 1.5)[None, :]
    det._detect_table_trusted(s.ranges[:1], s.angles)  # the layout is checked once, then trusted
    for r in (s.ranges[:1], s.ranges[5:6], s.ranges[:3], comb, s.ranges):
        row, tab = det._detect_table_trusted(r, s.angles)
        ref_row, ref_tab = _staged_table(det, r, s.angles)
        assert row.dtype == np.int64 and tab.dtype == np.float64
        assert np.array_equal(row, ref_row) and same_values(tab, ref_tab)
    assert det.detect_arrays(comb, s.angles).n_segments == n


def test_four_row_network_kernel_is_bitwise_the_row_and_block_kernels():
    from detectors import _kernels as _k

    det = LearnedKinDetector(reports=False, cascade=False)
    mean, std, w, b, sizes = det._numba_weights
    wt = det._numba_weights_t[2]
    rng = np.random.default_rng(1)
    for n in (1, 2, 3, 4, 5, 7, 8, 31, 40, 65, 130):
        x = (mean + rng.normal(size=(n, mean.size)) * 3.0 * std).astype(np.float32)
        outs = [np.empty((n, 3), np.float32) for _ in range(3)]
        _drv.mlp_rows4(x, mean, std, wt, b, sizes, outs[0])
        _k.mlp_forward_rows(x, mean, std, wt, b, sizes, outs[1])
        _k.mlp_forward(x, mean, std, w, b, sizes, outs[2])
        assert np.array_equal(outs[0].view(np.int32), outs[1].view(np.int32)), n
        assert np.array_equal(outs[0].view(np.int32), outs[2].view(np.int32)), n


@pytest.mark.parametrize("sizes", [(13, 7, 10, 3), (9, 6, 5, 2), (52, 64, 64, 3), (5, 4, 1), (6, 11, 9, 4)])
def test_block_network_kernel_is_bitwise_the_row_kernels_for_any_widths(sizes):
    # random networks whose widths are not multiples of the block kernel's four units (the 4-, 2- and 1-unit
    # passes) nor of its four inputs, random inputs with exact zeros: every kernel's bits are the same
    from detectors import _kernels as _k

    rng = np.random.default_rng(sum(sizes))
    sizes = np.array(sizes, dtype=np.int64)
    n_layers = sizes.size - 1
    w_max = int(sizes.max())
    w = np.zeros((n_layers, w_max, w_max), np.float32)
    b = np.zeros((n_layers, w_max), np.float32)
    for li in range(n_layers):
        w[li, : sizes[li + 1], : sizes[li]] = rng.normal(size=(sizes[li + 1], sizes[li])) / np.sqrt(sizes[li])
        b[li, : sizes[li + 1]] = rng.normal(size=sizes[li + 1]) * 0.3
    wt = np.ascontiguousarray(w.transpose(0, 2, 1))
    mean = rng.normal(size=sizes[0]).astype(np.float32)
    std = rng.uniform(0.5, 2.0, sizes[0]).astype(np.float32)
    for n in (1, 3, 4, 9, 63, 64, 65, 200):
        x = (mean + rng.normal(size=(n, sizes[0])) * 2.0 * std).astype(np.float32)
        x[rng.random(x.shape) < 0.2] = 0.0
        outs = [np.empty((n, sizes[-1]), np.float32) for _ in range(3)]
        _k.mlp_forward(x, mean, std, w, b, sizes, outs[0])
        _k.mlp_forward_rows(x, mean, std, wt, b, sizes, outs[1])
        _drv.mlp_rows4(x, mean, std, wt, b, sizes, outs[2])
        assert np.array_equal(outs[0].view(np.int32), outs[1].view(np.int32)), n
        assert np.array_equal(outs[0].view(np.int32), outs[2].view(np.int32)), n


def _random_arena_batches():
    # random arenas of several densities and noise levels, every robot's scan (batched calls)
    for seed, noise, n_robots in ((10, 0.01, 24), (11, 0.0, 12), (12, 0.005, 40)):
        scan = arena(seed, noise, n_robots=n_robots, n_obstacles=30)
        yield scan.ranges, scan.angles


@pytest.mark.parametrize("suppress", [True, False])
@pytest.mark.parametrize("cascade", [True, False])
def test_batched_fused_driver_with_cascade_is_bitwise_the_staged_pipeline(cascade, suppress):
    # batches (>= 2 scans) run the cascade inside the one compiled call: every field, seg_values
    # (cascade_score included) and the env's table equal the staged pipeline's
    det = LearnedKinDetector(reports=False, cascade=cascade, suppress_duplicates=suppress)
    assert det.cascade == cascade
    n_dropped = 0
    for ranges, angles in _random_arena_batches():
        for r in (ranges[:2], ranges):
            ref = det._detect_arrays_staged(r.astype(np.float64), angles)
            assert_same(det.detect_arrays(r, angles), ref)
            row, tab = det._detect_table_trusted(r, angles)
            ref_row, ref_tab = _staged_table(det, r, angles)
            assert np.array_equal(row, ref_row) and same_values(tab, ref_tab)
            if cascade:
                p, score = ref.seg_values["p_kin"], ref.seg_values["cascade_score"]
                n_dropped += int((np.isfinite(score) & np.isnan(p)).sum())
    assert n_dropped > 0 or not cascade  # the cascade did drop segments here


def test_fused_driver_with_a_small_random_network(tmp_path):
    # kernels for any layer widths the checkpoint loader accepts: a random 52 -> 7 -> 5 -> 3 network
    # (odd widths: the block kernel's odd last unit and input remainder), with the shipped cascade
    # re-tied to its weights, bitwise the staged pipeline on one scan and on batches
    import json

    import torch

    from detectors.learned import (
        SegmentNet,
        cascade_path,
        load_checkpoint,
        save_checkpoint,
    )

    _, ck = load_checkpoint()
    torch.manual_seed(0)
    net = SegmentNet(type(ck["model_config"])(n_features=ck["model_config"].n_features, hidden=(7, 5)))
    nrm = ck["normalisation"]
    net.set_normalisation(nrm["x_mean"], nrm["x_std"], nrm["t_mean"], nrm["t_std"])
    with torch.no_grad():
        net.head.bias[0] = 2.0  # some segments above threshold
    path = save_checkpoint(tmp_path / "small.pt", net, ck["feature_config"], thresholds=ck["thresholds"])
    card = json.loads(cascade_path(None).read_text())
    card["checkpoint_weights_sha256"] = load_checkpoint(path)[1]["weights_sha256"]
    cascade_path(path).write_text(json.dumps(card))
    for cascade in (True, False):
        det = LearnedKinDetector(path, reports=False, cascade=cascade)
        n_det = 0
        for ranges, angles in _random_arena_batches():
            for r in (ranges[:1], ranges[3:5], ranges):
                # (one scan as a batch: the cascade on every call, LearnedKinDetector.cascade)
                ref = det._detect_arrays_staged(r.astype(np.float64), angles)
                assert_same(det.detect_arrays(r, angles), ref)
                n_det += ref.n_detections
        assert n_det > 0


def test_callers_of_fastmath_kernels_keep_the_default_error_model():
    """numba compiles a callee in its first caller's error model, and a ``fastmath`` kernel compiled under
    ``error_model="numpy"`` gets other machine code and other last bits than when called from Python: so
    every jitted function on a call path to a fastmath kernel keeps the default model, or the outputs
    depend on which path compiled the kernel first (a fresh clone's CI failed this way)."""
    import inspect
    import re

    from numba.core.registry import CPUDispatcher

    from detectors import _kernels, features

    jitted = {n: f for m in (_drv, features, _kernels) for n, f in vars(m).items()
              if isinstance(f, CPUDispatcher)}
    fast = {n for n, f in jitted.items() if f.targetoptions.get("fastmath")}
    assert {"mlp_rows4", "mlp_forward", "mlp_forward_rows", "_cascade_scores"} <= fast
    callers, grew = set(fast), True
    while grew:  # every jitted function that calls one of them, transitively
        grew = False
        for n, f in jitted.items():
            src = inspect.getsource(f.py_func)
            if n not in callers and any(re.search(rf"\b{c}\(", src) for c in callers):
                callers.add(n)
                grew = True
    assert {"front", "fused_table", "fused_packed"} <= callers
    numpy_model = sorted(n for n in callers - fast if jitted[n].targetoptions.get("error_model") == "numpy")
    assert not numpy_model, f"call fastmath kernels under error_model='numpy': {numpy_model}"
