"""detectors.learned: the one-scan fast paths (row MLP kernel, trusted entry) give the same outputs."""

import numpy as np
import pytest

pytest.importorskip("torch")  # the only reason to skip: CI installs torch

from detectors import _kernels as _k  # noqa: E402
from detectors.learned import LearnedKinDetector  # noqa: E402
from kin_envs import LidarSpec, World, scenes  # noqa: E402

FIELDS = ("scan", "range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams_on", "segment")


@pytest.fixture(scope="module")
def shipped():
    return LearnedKinDetector(reports=False)


def scans(n, seed=0, noise=0.005):
    """``n`` one-robot scans (float32 ranges, as the envs' lidar gives them) of random arenas."""
    out = []
    for k in range(n):
        scene = scenes.random_arena(8, 12, seed=seed + k).replace(lidar=LidarSpec(noise_sigma=noise))
        s = World(scene, seed=seed + k).scan()
        out.append((s.ranges[:1], s.angles))
    return out


def test_row_kernel_is_bitwise_the_block_kernel(shipped):
    mean, std, w, b, sizes = shipped._numba_weights
    wt = shipped._numba_weights_t[2]
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 31, 65):
        x = (mean + rng.normal(size=(n, mean.size)) * 3.0 * std).astype(np.float32)
        o_block, o_rows = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
        _k.mlp_forward(x, mean, std, w, b, sizes, o_block)
        _k.mlp_forward_rows(x, mean, std, wt, b, sizes, o_rows)
        assert np.array_equal(o_block.view(np.int32), o_rows.view(np.int32)), n


def test_trusted_entry_and_row_kernel_give_the_public_outputs(shipped):
    block = LearnedKinDetector(reports=False, inference="numba")

    def forward_block_kernel(x):  # the pre-existing block kernel for every row count
        out = np.empty((x.shape[0], 3), dtype=np.float32)
        _k.mlp_forward(np.ascontiguousarray(x), *block._numba_weights, out)
        return out.astype(np.float64)

    block._forward = forward_block_kernel
    n_det = 0
    for r, a in scans(6):
        ref = block.detect_arrays(r.astype(np.float64), a)
        for got in (shipped.detect_arrays(r, a), shipped._detect_arrays_trusted(r, a)):
            for f in FIELDS:
                assert np.array_equal(getattr(got, f), getattr(ref, f), equal_nan=True), f
            assert np.array_equal(got.seg_stage, ref.seg_stage)
            for k, v in ref.seg_values.items():
                assert np.array_equal(got.seg_values[k], v, equal_nan=True), k
        n_det += ref.n_detections
    assert n_det > 0  # the scenes have kin in view: the centre path ran


def test_repeated_calls_do_not_share_result_arrays(shipped):
    (r1, a), (r2, _) = scans(2, seed=5)
    first = shipped._detect_arrays_trusted(r1, a)
    kept = {f: getattr(first, f).copy() for f in FIELDS}
    second = shipped._detect_arrays_trusted(r2, a)
    for f in FIELDS:
        assert not np.shares_memory(getattr(first, f), getattr(second, f)), f
        assert np.array_equal(getattr(first, f), kept[f]), f  # the second call left the first alone
    for f in ("seg_scan", "seg_first", "seg_count", "seg_prev", "seg_next", "seg_stage"):
        assert not np.shares_memory(getattr(first, f), getattr(second, f)), f


def test_trusted_entry_still_checks_a_new_layout_and_bad_types(shipped):
    (r, a), = scans(1, seed=9)
    shipped._detect_arrays_trusted(r, a)
    with pytest.raises(ValueError, match="batched ranges must be 2-D"):
        shipped._detect_arrays_trusted(r[0], a)
    with pytest.raises(ValueError, match="beams are"):  # another angles object: validated again
        shipped._detect_arrays_trusted(r[:, ::2], a[::2].copy())
    with pytest.raises(ValueError, match=r"ranges\[0\]"):  # the public entry checks every call
        shipped.detect_arrays(-np.abs(r.astype(np.float64)), a)


def test_geometric_trusted_entry_gives_the_public_outputs():
    from detectors import GeometricKinDetector

    det = GeometricKinDetector(reports=False)
    n_det = 0
    for r, a in scans(4, seed=20, noise=0.0):
        ref = det.detect_arrays(r, a)
        got = det._detect_arrays_trusted(r, a)
        again = det._detect_arrays_trusted(r, a)  # the fast path (layout already checked)
        for f in FIELDS:
            assert np.array_equal(getattr(got, f), getattr(ref, f), equal_nan=True), f
            assert np.array_equal(getattr(again, f), getattr(ref, f), equal_nan=True), f
            assert not np.shares_memory(getattr(again, f), getattr(got, f)), f
        n_det += ref.n_detections
    assert n_det > 0
    with pytest.raises(ValueError, match="batched ranges must be 2-D"):
        det._detect_arrays_trusted(r[0], a)
