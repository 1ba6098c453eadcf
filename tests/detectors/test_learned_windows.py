"""Candidate windows inside the learned detector's compiled driver (issue 11, round 7).

The compiled window cutter against the Python oracle :func:`detectors.windows.candidate_windows` on
randomised scans; the detector's detections with windows (``detect_arrays`` / ``detect_batch``, the env's
table entry, with and without the cascade) against round 6's Python experiment ``split_detector``; a
checkpoint without window settings (the shipped one) runs as before; the settings travel in the npz."""

import math
import shutil

import numpy as np
import pytest

from detectors.features import FeatureConfig, segment_batch
from detectors.learned import (
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    cascade_path,
    load_inference_checkpoint,
    load_npz_checkpoint,
    window_settings,
    write_npz_checkpoint,
)
from detectors.windows import WindowConfig, candidate_windows, cut_windows, wide_segments
from kin_envs.detection.benchmark import permissive
from tests.scripts.helpers import load_script

from .test_cascade_bound import NOISES, adversarial_scans, arena_scans

CONFIGS = (WindowConfig(), WindowConfig(anchor="local", sag=0.0, sag_noise=0.0), WindowConfig(anchor="span"),
           WindowConfig(depth=0.5, sag=0.1, sag_noise=5.0))  # fmt: skip


def _cases():
    for seed in range(6):  # swarms of 8-64 robots, 0-2 % noise
        yield arena_scans(400 + seed, NOISES[seed % 4], (8, 24, 64)[seed % 3], 30)
    rng = np.random.default_rng(11)
    for _ in range(2):  # no-returns of every kind, alternating near / far beams
        yield adversarial_scans(rng)
    ranges, angles = arena_scans(410, 0.01, 32, 20)
    yield ranges[:1], angles  # one scan: without the cascade


CASES = list(_cases())


@pytest.mark.parametrize("config", CONFIGS, ids=["round6", "round5", "span", "other"])
def test_compiled_windows_are_candidate_windows(config):
    fc = FeatureConfig()
    n_win = 0
    for ranges, angles in CASES:
        batch = segment_batch(ranges, angles, fc)
        step = 2 * math.pi / angles.shape[0]
        wide = wide_segments(batch, step, fc.r)
        ref = candidate_windows(batch, wide, step, fc.r, config, fc)
        got = cut_windows(batch, wide, step, fc.r, config)
        for k in ("scan", "first", "count", "prev_beam", "next_beam", "prev_nearer", "next_nearer"):
            assert np.array_equal(getattr(got.batch, k), getattr(ref.batch, k)), k
        assert np.array_equal(got.parent, ref.parent) and np.array_equal(got.anchor, ref.anchor)
        assert np.array_equal(got.sag, ref.sag, equal_nan=True)
        n_win += ref.n_windows
    assert n_win > 200  # the scans hold many windows


WINDOW_VALUES = [0.6, 0.5, 0.7, 0.8, 0.9]  # low enough for the shipped network to accept some windows


def window_checkpoint(tmp_path, values=WINDOW_VALUES, config=None, cascade=True):
    """The shipped weights with window settings (as train_classifier.py writes them), as an npz (and
    the shipped cascade beside it: fitted for the same weights)."""
    ck = load_inference_checkpoint()
    info = dict(ck.get("info") or {})
    info["window_thresholds"] = {"noise_edges": ck["thresholds"]["noise_edges"], "values": list(values)}
    info["window_config"] = (config or WindowConfig()).to_dict()
    ck["info"] = info
    path = tmp_path / "windows.npz"
    write_npz_checkpoint(path, ck)
    if cascade:
        shutil.copy(cascade_path(DEFAULT_CHECKPOINT), cascade_path(path))
    return path


def _dets(results):
    return [[(d.x, d.y, d.score, d.first_beam, d.last_beam, d.n_beams) for d in r.detections]
            for r in results]


@pytest.mark.parametrize("cascade", [False, True])
def test_detections_are_round6_split_detectors(tmp_path, cascade):
    path = window_checkpoint(tmp_path)
    det = LearnedKinDetector(path, reports=False, cascade=cascade)
    assert det.windows and det.cascade == cascade
    ref = load_script("experiment_split_windows").split_detector(
        path, "calibrated", WindowConfig(), cascade=cascade, cascade_windows=True
    )
    plain = LearnedKinDetector(path, reports=False, cascade=cascade, windows=False)
    n_extra = 0
    for ranges, angles in CASES:
        got = det.detect_batch(ranges, angles)
        assert _dets(got) == _dets(ref.detect_batch(ranges, angles))  # the same detections, in order
        without = _dets(plain.detect_batch(ranges, angles))
        # each scan: the segments' detections, then the accepted windows
        assert [g[: len(w)] for g, w in zip(_dets(got), without, strict=True)] == without
        n_extra += sum(len(g) - len(w) for g, w in zip(_dets(got), without, strict=True))
        # the env's table entry, float64 and the lidar's float32 ranges
        arr = det.detect_arrays(ranges, angles)
        cols = (arr.range, arr.bearing, arr.x, arr.y, arr.score, arr.first_beam, arr.last_beam,
                arr.n_beams_on)
        table_ref = np.stack(cols, axis=1).astype(np.float64).reshape(-1, 8)
        r32 = ranges.astype(np.float32)
        for r in (ranges, r32) if np.array_equal(r32, ranges) else (ranges,):  # (the lidar's own float32)
            row, table = det._detect_table_trusted(np.ascontiguousarray(r), angles)
            assert np.array_equal(row, arr.scan) and np.array_equal(table, table_ref)
        # a window's detection names the segment it was cut from: one the pre-gate dropped
        from_window = arr.seg_stage[arr.segment] == 1
        assert (arr.seg_count[arr.segment[from_window]] > arr.n_beams_on[from_window]).all()
    assert n_extra >= 20 and ref.counts["accepted"] >= n_extra


def test_checkpoint_without_window_settings_is_unchanged(tmp_path):
    """The shipped checkpoint has no window settings: windows off, and ``windows=False`` on a checkpoint
    that has them gives exactly the shipped detector's output (same weights)."""
    shipped = LearnedKinDetector(reports=False)
    assert not shipped.windows and window_settings(shipped.checkpoint) is None
    with pytest.raises(ValueError, match="no window settings"):
        LearnedKinDetector(windows=True)
    off = LearnedKinDetector(window_checkpoint(tmp_path), reports=False, windows=False)
    for ranges, angles in CASES[:4]:
        a, b = shipped.detect_arrays(ranges, angles), off.detect_arrays(ranges, angles)
        for k in ("scan", "x", "y", "score", "first_beam", "n_beams_on", "segment", "seg_stage"):
            assert np.array_equal(getattr(a, k), getattr(b, k)), k
        for k, v in a.seg_values.items():
            assert np.array_equal(v, b.seg_values[k], equal_nan=True), k
        assert np.array_equal(a.scan, shipped._detect_table_trusted(ranges, angles)[0])


def test_settings_in_the_npz_and_errors(tmp_path):
    path = window_checkpoint(tmp_path, config=WindowConfig(sag=0.2))
    cfg, th = window_settings(load_npz_checkpoint(path))
    assert cfg == WindowConfig(sag=0.2) and th["values"] == WINDOW_VALUES
    det = LearnedKinDetector(path, reports=False)
    assert det.window_config == WindowConfig(sag=0.2)
    # the PR curve's permissive run keeps the windows (accepted at their own thresholds)
    assert permissive(det).windows and not permissive(LearnedKinDetector(path, windows=False)).windows
    with pytest.raises(ValueError, match="pre_gate"):
        LearnedKinDetector(path, pre_gate=False, windows=True)
    assert not LearnedKinDetector(path, pre_gate=False).windows  # windows are cut from pre-gated segments
    with pytest.raises(ValueError, match="windows must be"):
        LearnedKinDetector(path, windows="yes")
    with pytest.raises(ValueError, match="staged pipeline"):
        det._detect_arrays_staged(*CASES[0])
    bad = window_checkpoint(tmp_path, values=[0.5, 1.5, 0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="bad window settings"):
        LearnedKinDetector(bad)
    # window_thresholds: the scan noise's bin of the checkpoint's window thresholds (log(noise + 1e-4) in)
    edges = np.asarray(th["noise_edges"], dtype=np.float64)
    sigma = np.concatenate([[0.0], edges, edges + 1e-4, [0.05]])
    log_noise = np.log(sigma + 1e-4).astype(np.float32)
    want = np.asarray(WINDOW_VALUES)[np.searchsorted(edges, np.exp(log_noise.astype(np.float64)) - 1e-4,
                                                     side="right")]  # fmt: skip
    assert np.array_equal(det.window_thresholds(log_noise), want) and len(set(want.tolist())) > 1
    with pytest.raises(ValueError, match="windows are off"):
        LearnedKinDetector(reports=False).window_thresholds(log_noise)  # the shipped one: no windows


def test_train_checkpoint_carries_window_settings_in_both_forms(tmp_path):
    torch_ = pytest.importorskip("torch")
    from detectors.learned_torch import load_checkpoint, save_checkpoint

    model, ck = load_checkpoint(DEFAULT_CHECKPOINT)
    info = dict(ck.get("info") or {})
    info["window_thresholds"] = {"noise_edges": ck["thresholds"]["noise_edges"], "values": WINDOW_VALUES}
    info["windows"] = [WindowConfig().to_dict(), None]  # datasets' manifests: one with windows
    pt = tmp_path / "w.pt"
    save_checkpoint(pt, model, ck["feature_config"], positioning=ck["positioning"],
                    angular_resolution=ck["angular_resolution"], thresholds=ck["thresholds"],
                    info=info)  # fmt: skip
    assert torch_ is not None
    for ckpt in (load_checkpoint(pt)[1], load_npz_checkpoint(pt.with_suffix(".npz"))):
        assert window_settings(ckpt) == (WindowConfig(), {"noise_edges": ck["thresholds"]["noise_edges"],
                                                          "values": WINDOW_VALUES})  # fmt: skip
    assert LearnedKinDetector(pt).windows
    info["windows"] = [WindowConfig().to_dict(), WindowConfig(sag=0.1).to_dict()]  # two configs: refused
    save_checkpoint(pt, model, ck["feature_config"], positioning=ck["positioning"],
                    angular_resolution=ck["angular_resolution"], thresholds=ck["thresholds"],
                    info=info)  # fmt: skip
    with pytest.raises(ValueError, match="no single window config"):
        LearnedKinDetector(pt)
