"""Issue 16 (point 2): corrupt checkpoints are refused naming the file and why."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from detectors.features import FeatureConfig, feature_names  # noqa: E402
from detectors.learned import (  # noqa: E402
    DEFAULT_CHECKPOINT,
    LearnedKinDetector,
    ModelConfig,
    SegmentNet,
    load_checkpoint,
    save_checkpoint,
)

torch.set_num_threads(1)
N = len(feature_names())


def _model(seed: int = 0) -> SegmentNet:
    torch.manual_seed(seed)
    m = SegmentNet(ModelConfig(N, (32, 16)))
    m.set_normalisation(np.zeros(N), np.ones(N), [0.03, 0.0], [0.01, 0.01])
    return m.eval()


def _weights_span(raw: bytes, model: SegmentNet) -> tuple[int, int]:
    """Byte range of the largest weight tensor inside the saved file."""
    t = max(model.state_dict().values(), key=lambda v: v.numel()).detach().cpu().numpy().tobytes()
    start = raw.find(t)
    assert start > 0
    return start, start + len(t)


def test_bit_flipped_weights_are_refused(tmp_path):
    model = _model()
    path = save_checkpoint(tmp_path / "m.pt", model, FeatureConfig())
    raw = bytearray(path.read_bytes())
    lo, hi = _weights_span(bytes(raw), model)
    rng = np.random.default_rng(0)
    for k in rng.choice(np.arange(lo, hi), 64, replace=False):  # 64 bytes, one bit each
        raw[k] ^= 1 << int(rng.integers(8))
    bad = tmp_path / "flipped.pt"
    bad.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"flipped\.pt.*SHA-256"):
        load_checkpoint(bad)
    load_checkpoint(path)  # the intact file still loads


def test_non_finite_weights_are_refused(tmp_path):
    model = _model()
    path = save_checkpoint(tmp_path / "m.pt", model, FeatureConfig())
    ck = torch.load(path, weights_only=True)
    name = next(iter(ck["state_dict"]))
    ck["state_dict"][name][0] = float("nan")
    torch.save(ck, tmp_path / "nan.pt")
    with pytest.raises(ValueError, match=rf"nan\.pt.*{name!r} holds NaN"):
        load_checkpoint(tmp_path / "nan.pt")
    with torch.no_grad():
        next(iter(model.parameters()))[0] = float("inf")
    with pytest.raises(ValueError, match="NaN or inf"):
        save_checkpoint(tmp_path / "inf.pt", model, FeatureConfig())
    assert not (tmp_path / "inf.pt").exists()


def test_directory_path_and_cuda_on_cpu_are_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="is a directory"):
        load_checkpoint(tmp_path)
    with pytest.raises(ValueError, match="is a directory"):
        save_checkpoint(tmp_path, _model(), FeatureConfig())
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA device"):
            load_checkpoint(DEFAULT_CHECKPOINT, device="cuda")
        with pytest.raises(ValueError, match="CUDA"):
            LearnedKinDetector(device="cuda")
    with pytest.raises(ValueError, match="device"):
        load_checkpoint(DEFAULT_CHECKPOINT, device="tpu:9")


def test_truncated_checkpoint_names_the_file(tmp_path):
    path = save_checkpoint(tmp_path / "m.pt", _model(), FeatureConfig())
    (tmp_path / "cut.pt").write_bytes(path.read_bytes()[:-200])
    with pytest.raises(ValueError, match=r"cut\.pt"):
        load_checkpoint(tmp_path / "cut.pt")


def test_shipped_checkpoint_carries_a_checksum():
    _, ck = load_checkpoint()
    assert len(ck["weights_sha256"]) == 64
