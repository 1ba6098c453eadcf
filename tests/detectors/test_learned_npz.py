"""Issue 14 (torch-free learned inference): the checkpoint's npz form, read without torch.

``detectors.learned`` (and the envs with ``detector="learned"``) never import torch: the detector reads the
checkpoint's ``.npz`` form, written beside the ``.pt`` by ``save_checkpoint`` or
``scripts/export_checkpoint.py``. Checked here: the shipped npz holds the ``.pt``'s weights bit for bit
and gives the same detections as the torch-loaded checkpoint (every inference path, the paper's
scenes, a 64-robot swarm batch); the round trip save -> export -> load; every bad file is refused
naming the path and what is expected; and, in subprocesses, that nothing imports torch (and that all of
it works with torch unimportable).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from detectors.features import FEATURE_VERSION, FeatureConfig, feature_names
from detectors.fileio import sha256_file
from detectors.learned import (
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    cascade_path,
    load_inference_checkpoint,
    load_npz_checkpoint,
    npz_path,
    write_npz_checkpoint,
)
from kin_envs import LidarSpec, World, scenes

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "tests" / "fixtures" / "paper_scenario2_0.8m_scan.npz"
SHIPPED_NPZ = npz_path(DEFAULT_CHECKPOINT)
N = len(feature_names())


def assert_same(got, ref):
    """Every array of two ``BatchDetections`` the same, bit for bit (the same code on the same weights)."""
    assert (got.n_scans, got.n_beams) == (ref.n_scans, ref.n_beams)
    fields = ("scan", "range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams_on",
              "segment", "seg_scan", "seg_first", "seg_count", "seg_prev", "seg_next", "seg_prev_nearer",
              "seg_next_nearer", "seg_stage")  # fmt: skip
    pairs = [(f, getattr(got, f), getattr(ref, f)) for f in fields]
    assert got.seg_values.keys() == ref.seg_values.keys()
    pairs += [(k, got.seg_values[k], v) for k, v in ref.seg_values.items()]
    for name, a, b in pairs:
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name


def _torch():
    torch = pytest.importorskip("torch")  # the only reason to skip: CI installs torch
    torch.set_num_threads(1)
    return torch


def _torch_copy(tmp_path: Path, name: str = "m") -> Path:
    """The shipped .pt (and its cascade) under another name, without an npz: loaded through torch."""
    pt = tmp_path / f"{name}.pt"
    shutil.copy(DEFAULT_CHECKPOINT, pt)
    shutil.copy(cascade_path(DEFAULT_CHECKPOINT), cascade_path(pt))
    return pt


def _scans():
    """The paper's Scenario II scan (every robot), detection scenes and a 64-robot swarm batch, with and
    without noise."""
    z = np.load(FIXTURE)
    out = [(z["ranges"], z["angles"])]
    for seed, noise in ((0, 0.0), (1, 0.01)):
        s = World(scenes.detection_scene(seed, lidar=LidarSpec(noise_sigma=noise)), seed=seed).scan()
        out.append((s.ranges, s.angles))
    for seed, noise in ((0, 0.01), (1, 0.0)):
        scene = scenes.random_arena(64, 50, seed=seed).replace(lidar=LidarSpec(noise_sigma=noise))
        s = World(scene, seed=seed).scan()
        out.append((s.ranges, s.angles))
    return out


# ------------------------------------------------------------------------------------ the shipped npz


def test_shipped_npz_is_the_pt_bit_for_bit():
    _torch()
    from detectors.learned_torch import load_checkpoint

    npz = load_npz_checkpoint(SHIPPED_NPZ)
    _, pt = load_checkpoint(DEFAULT_CHECKPOINT)
    assert npz["source"] == {"file": DEFAULT_CHECKPOINT.name, "sha256": sha256_file(DEFAULT_CHECKPOINT)}
    assert npz["weights_sha256"] == pt["weights_sha256"]
    assert sorted(npz["state_dict"]) == sorted(pt["state_dict"])
    for k, v in pt["state_dict"].items():
        a = npz["state_dict"][k]
        assert a.dtype == np.float32 and a.tobytes() == v.numpy().tobytes(), k
    for k in ("feature_config", "model_config", "normalisation", "thresholds", "positioning",
              "angular_resolution", "feature_names", "feature_version", "info"):  # fmt: skip
        assert npz[k] == pt[k], k
    # what the detector reads by default: the npz, named by the .pt
    ck = load_inference_checkpoint()
    assert ck["npz"] == str(SHIPPED_NPZ) and ck["path"] == str(DEFAULT_CHECKPOINT)


@pytest.mark.parametrize("inference", ["auto", "numba", "blas", "torch"])
def test_npz_and_torch_loaded_detectors_detect_the_same(tmp_path, inference):
    _torch()
    pt = _torch_copy(tmp_path)
    a = LearnedKinDetector(inference=inference, reports=False)  # the shipped npz
    b = LearnedKinDetector(pt, inference=inference, reports=False)  # the .pt through torch
    assert a.checkpoint["npz"] == str(SHIPPED_NPZ) and b.checkpoint["npz"] is None
    assert a.cascade and b.cascade
    n = 0
    for ranges, angles in _scans():
        assert_same(a.detect_arrays(ranges, angles), b.detect_arrays(ranges, angles))
        ra, ta = a._detect_table_trusted(ranges, angles)
        rb, tb = b._detect_table_trusted(ranges, angles)
        assert np.array_equal(ra, rb) and ta.tobytes() == tb.tobytes()
        n += ra.shape[0]
    assert n > 500  # the swarm batches' kin among others


def test_torch_module_built_from_the_npz_is_the_checkpoints(tmp_path):
    torch = _torch()
    from detectors.learned_torch import load_checkpoint

    det = LearnedKinDetector()
    assert det._model is None  # not built for compiled inference
    model, _ = load_checkpoint(DEFAULT_CHECKPOINT)
    x = torch.randn(300, N)
    with torch.inference_mode():
        torch.testing.assert_close(det.model(x), model(x), rtol=0, atol=0)


# ------------------------------------------------------------------------------------ the round trip


def _random_net(hidden=(16, 8), seed=0):
    torch = _torch()
    from detectors.learned_torch import ModelConfig, SegmentNet

    torch.manual_seed(seed)
    m = SegmentNet(ModelConfig(N, hidden))
    m.set_normalisation(np.linspace(-1, 1, N), np.linspace(0.5, 2, N), [0.03, 0.0], [0.01, 0.02])
    with torch.no_grad():
        m.head.bias[0] = 1.5  # some segments accepted
    return m.eval()


def test_save_export_load_round_trip(tmp_path):
    _torch()
    from detectors.learned_torch import export_checkpoint, load_checkpoint, save_checkpoint

    thr = {"noise_edges": [0.003], "values": [0.3, 0.6]}
    pt = save_checkpoint(tmp_path / "m.pt", _random_net(), FeatureConfig(), positioning="fit",
                         thresholds=thr, info={"note": np.float64(1.5), "nan": float("nan")})  # fmt: skip
    npz = tmp_path / "m.npz"
    assert npz.is_file() and sorted(p.name for p in tmp_path.iterdir()) == ["m.npz", "m.pt"]
    saved = load_npz_checkpoint(npz)
    _, ref = load_checkpoint(pt)
    assert saved["source"]["sha256"] == sha256_file(pt) and saved["weights_sha256"] == ref["weights_sha256"]
    assert saved["positioning"] == "fit" and saved["thresholds"] == thr and saved["info"]["note"] == 1.5
    # export (the same file again, from the .pt alone) and load: the same content
    npz.unlink()
    assert export_checkpoint(pt) == npz
    exported = load_npz_checkpoint(npz)
    other = export_checkpoint(pt, tmp_path / "elsewhere.npz")
    for ck in (exported, load_npz_checkpoint(other)):
        assert ck["weights_sha256"] == saved["weights_sha256"] and ck["source"] == saved["source"]
        for k, v in saved["state_dict"].items():
            assert ck["state_dict"][k].tobytes() == v.tobytes()
        assert json.dumps(ck["info"]) == json.dumps(saved["info"])  # (NaN too)
    # the detector from the .pt (via its npz), from the npz itself and through torch: same detections
    scan = World(scenes.random_arena(24, 20, seed=5), seed=5).scan()
    via_npz = LearnedKinDetector(pt, reports=False)
    direct = LearnedKinDetector(other, reports=False)
    assert via_npz.checkpoint["npz"] == str(npz) and via_npz.checkpoint["path"] == str(pt)
    ref_arr = via_npz.detect_arrays(scan.ranges, scan.angles)
    assert ref_arr.n_detections > 0
    assert_same(direct.detect_arrays(scan.ranges, scan.angles), ref_arr)
    npz.unlink()
    through_torch = LearnedKinDetector(pt, reports=False)
    assert through_torch.checkpoint["npz"] is None
    assert_same(through_torch.detect_arrays(scan.ranges, scan.angles), ref_arr)


def test_stale_npz_is_not_used_for_a_rewritten_pt(tmp_path):
    _torch()
    from detectors.learned_torch import save_checkpoint

    pt = save_checkpoint(tmp_path / "m.pt", _random_net(seed=1), FeatureConfig())
    old_npz = (tmp_path / "m.npz").read_bytes()
    save_checkpoint(tmp_path / "m.pt", _random_net(seed=2), FeatureConfig())
    new = LearnedKinDetector(pt).checkpoint["weights_sha256"]
    (tmp_path / "m.npz").write_bytes(old_npz)  # e.g. a .pt copied over by hand
    with pytest.warns(UserWarning, match=r"m\.npz beside it was exported from other bytes.*export_"):
        ck = LearnedKinDetector(pt).checkpoint
    assert ck["npz"] is None and ck["weights_sha256"] == new
    # only the npz (the .pt removed): it is read
    (tmp_path / "m.pt").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert LearnedKinDetector(pt).checkpoint["npz"] == str(tmp_path / "m.npz")


# ------------------------------------------------------------------------------------ bad files


def _meta_and_state(path):
    z = np.load(path)
    meta = json.loads(z["meta"].tobytes())
    return meta, {k[len("param:") :]: z[k] for k in z.files if k != "meta"}


def _write(path, meta, state):
    np.savez(path, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8),
             **{"param:" + k: v for k, v in state.items()})  # fmt: skip
    return path


def test_bad_npz_files_are_refused_naming_the_file(tmp_path):
    meta, state = _meta_and_state(SHIPPED_NPZ)
    with pytest.raises(FileNotFoundError, match=r"missing\.npz does not exist"):
        load_npz_checkpoint(tmp_path / "missing.npz")
    with pytest.raises(ValueError, match="is a directory"):
        load_npz_checkpoint(tmp_path)
    # a flipped bit: the zip's CRC, or (rewritten with a consistent zip) the weights' SHA-256
    raw = bytearray(SHIPPED_NPZ.read_bytes())
    w = state["body.2.weight"].tobytes()
    start = raw.find(w)
    assert start > 0
    raw[start + len(w) // 2] ^= 0x10
    (tmp_path / "flipped.npz").write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"flipped\.npz: not a readable npz checkpoint.*CRC"):
        load_npz_checkpoint(tmp_path / "flipped.npz")
    bad = dict(state)
    bad["body.2.weight"] = state["body.2.weight"].copy()
    bad["body.2.weight"].view(np.uint32)[3, 5] ^= 1  # the last bit of one weight
    _write(tmp_path / "tampered.npz", meta, bad)
    with pytest.raises(ValueError, match=r"tampered\.npz: corrupt checkpoint.*SHA-256"):
        load_npz_checkpoint(tmp_path / "tampered.npz")
    nan = dict(state, **{"head.bias": np.array([np.nan, 0, 0], np.float32)})
    with pytest.raises(ValueError, match=r"nan\.npz: corrupt checkpoint.*'head.bias' holds NaN"):
        load_npz_checkpoint(_write(tmp_path / "nan.npz", meta, nan))
    # truncated, junk, a lone .npy, no metadata, another format
    (tmp_path / "cut.npz").write_bytes(SHIPPED_NPZ.read_bytes()[:-300])
    (tmp_path / "junk.npz").write_bytes(np.random.default_rng(0).bytes(3000))
    np.save(tmp_path / "lone.npy", np.zeros(3))
    shutil.move(tmp_path / "lone.npy", tmp_path / "lone.npz")
    np.savez(tmp_path / "nometa.npz", **{"param:" + k: v for k, v in state.items()})
    for name in ("cut", "junk", "lone"):
        with pytest.raises(ValueError, match=rf"{name}\.npz: not a readable npz checkpoint.*expected"):
            load_npz_checkpoint(tmp_path / f"{name}.npz")
    with pytest.raises(ValueError, match=r"nometa\.npz: not a learned kin detector checkpoint"):
        load_npz_checkpoint(tmp_path / "nometa.npz")
    with pytest.raises(ValueError, match=r"other\.npz: not a learned kin detector checkpoint"):
        load_npz_checkpoint(_write(tmp_path / "other.npz", {**meta, "format": "something/else"}, state))
    # wrong shape (the model config says 64 hidden units), missing and extra parameters
    wrong = dict(state, **{"body.0.weight": state["body.0.weight"][:, :10]})
    with pytest.raises(ValueError, match=r"shape\.npz: inconsistent.*'body\.0\.weight' is float32 "
                       rf"\(64, 10\), expected float32 \(64, {N}\)"):  # fmt: skip
        load_npz_checkpoint(_write(tmp_path / "shape.npz", meta, wrong))
    f64 = dict(state, **{"head.bias": state["head.bias"].astype(np.float64)})
    with pytest.raises(ValueError, match=r"f64\.npz: inconsistent.*'head\.bias' is float64"):
        load_npz_checkpoint(_write(tmp_path / "f64.npz", meta, f64))
    fewer = {k: v for k, v in state.items() if k != "head.bias"}
    with pytest.raises(ValueError, match=r"fewer\.npz: inconsistent.*parameters.*are not those of"):
        load_npz_checkpoint(_write(tmp_path / "fewer.npz", meta, fewer))
    small = {**meta, "model_config": {"n_features": 10, "hidden": [64, 64]}}
    with pytest.raises(ValueError, match=rf"small\.npz: inconsistent.*10 input features.*{N}"):
        load_npz_checkpoint(_write(tmp_path / "small.npz", small, state))
    # another feature version, format version, thresholds
    old = {**meta, "feature_version": FEATURE_VERSION - 1}
    with pytest.raises(ValueError, match=rf"old\.npz: .*feature version {FEATURE_VERSION - 1}.*retrain"):
        LearnedKinDetector(_write(tmp_path / "old.npz", old, state))
    with pytest.raises(ValueError, match=r"fmt\.npz: checkpoint format version 99"):
        load_npz_checkpoint(_write(tmp_path / "fmt.npz", {**meta, "format_version": 99}, state))
    thr = {**meta, "thresholds": {"noise_edges": [0.01], "values": [0.5]}}
    with pytest.raises(ValueError, match=r"thr\.npz: inconsistent checkpoint.*thresholds"):
        load_npz_checkpoint(_write(tmp_path / "thr.npz", thr, state))
    nrm = {**meta, "normalisation": {**meta["normalisation"], "x_std": [0.0] * N}}
    with pytest.raises(ValueError, match=r"nrm\.npz: .*x_std"):
        load_npz_checkpoint(_write(tmp_path / "nrm.npz", nrm, state))
    # the shipped npz itself passes every check
    assert load_npz_checkpoint(_write(tmp_path / "same.npz", meta, state))["weights_sha256"] == meta[
        "weights_sha256"
    ]


def test_npz_writer_and_save_checkpoint_refuse_bad_names(tmp_path):
    ck = load_npz_checkpoint(SHIPPED_NPZ)
    with pytest.raises(ValueError, match=r"m\.pt must end in \.npz"):
        write_npz_checkpoint(tmp_path / "m.pt", ck)
    _torch()
    from detectors.learned_torch import export_checkpoint, save_checkpoint

    with pytest.raises(ValueError, match=r"m\.npz is the name of the npz form; give the \.pt path"):
        save_checkpoint(tmp_path / "m.npz", _random_net(), FeatureConfig())
    with pytest.raises(ValueError, match="must be an .npz path"):
        export_checkpoint(DEFAULT_CHECKPOINT, tmp_path / "x.pt")
    with pytest.raises(FileNotFoundError, match=r"nothing\.pt does not exist"):
        export_checkpoint(tmp_path / "nothing.pt")
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------ without torch

_NO_TORCH = r"""
import importlib.abc, json, sys

class NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "torch":
            raise ImportError(f"No module named {name!r} (blocked: the base install has no torch)")
        return None

sys.meta_path.insert(0, NoTorch())
import numpy as np
import detectors.learned
from detectors import LearnedKinDetector
from detectors.learned import load_inference_checkpoint

z = np.load(sys.argv[1])
det = LearnedKinDetector(reports=False)
arr = det.detect_arrays(z["ranges"], z["angles"])
out = {"detections": int(arr.n_detections), "x": arr.x.tolist(), "y": arr.y.tolist(),
       "score": arr.score.tolist()}

import gymnasium as gym
import kin_envs
from kin_envs import aggregation_v2
from kin_envs.envs.common import resolve_detector

out["resolve"] = type(resolve_detector("learned")).__name__
env = gym.make("kin_envs/KinSeek-v2", detector="learned")
env.reset(seed=0)
env.action_space.seed(0)
for _ in range(5):
    env.step(env.action_space.sample())
env.close()
par = aggregation_v2.parallel_env(n_robots=8, detector="learned")
obs, _ = par.reset(seed=0)
for _ in range(5):
    obs, *_ = par.step({a: par.action_space(a).sample() for a in par.agents})
out["aggregation_agents"] = len(obs)
par.close()
for what, call in (("inference_torch", lambda: LearnedKinDetector(inference="torch")),
                   ("segment_net", lambda: detectors.learned.SegmentNet),
                   ("model", lambda: det.model),
                   ("pt_without_npz", lambda: load_inference_checkpoint(sys.argv[2]))):
    try:
        call()
        out[what] = "no error"
    except (ImportError, ValueError) as e:
        out[what] = f"{type(e).__name__}: {e}"
out["torch"] = sorted(k for k in sys.modules if k.split(".")[0] == "torch")
print("OUT " + json.dumps(out))
"""

_NORMAL = r"""
import json, sys
import gymnasium as gym
import kin_envs
from kin_envs import aggregation_v2

env = gym.make("kin_envs/KinSeek-v2", detector="learned")
env.reset(seed=0)
env.step(env.action_space.sample())
par = aggregation_v2.parallel_env(n_robots=8, detector="learned")
par.reset(seed=0)
par.step({a: par.action_space(a).sample() for a in par.agents})
print("OUT " + json.dumps(sorted(k for k in sys.modules if k.split(".")[0] == "torch")))
"""


def _run(code: str, *args: str) -> object:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=600,
                         cwd=ROOT, env=env)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(next(x for x in out.stdout.splitlines() if x.startswith("OUT "))[4:])


def test_learned_detector_and_envs_run_with_torch_unimportable(tmp_path):
    pt = tmp_path / "lonely.pt"
    shutil.copy(DEFAULT_CHECKPOINT, pt)  # no npz beside it
    out = _run(_NO_TORCH, str(FIXTURE), str(pt))
    assert out["torch"] == []
    assert out["resolve"] == "LearnedKinDetector" and out["aggregation_agents"] == 8
    # the same detections as in this process (the kin 0.8 m ahead of robot 0 among them)
    z = np.load(FIXTURE)
    ref = LearnedKinDetector(reports=False).detect_arrays(z["ranges"], z["angles"])
    assert out["detections"] == ref.n_detections > 0
    assert out["x"] == ref.x.tolist() and out["y"] == ref.y.tolist() and out["score"] == ref.score.tolist()
    # what needs torch says so
    for what in ("inference_torch", "segment_net", "model"):
        assert out[what].startswith("ImportError") and "torch" in out[what], out[what]
    msg = out["pt_without_npz"]
    assert msg.startswith("ValueError") and "lonely.pt" in msg and "torch cannot be imported" in msg
    assert "scripts/export_checkpoint.py" in msg and "lonely.npz" in msg


def test_creating_learned_envs_does_not_import_torch():
    assert _run(_NORMAL) == []
