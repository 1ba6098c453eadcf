"""Learned lidar kin detector: the paper's segmentation, a small network as the classifier.

Pipeline (same interface and output types as :class:`detectors.GeometricKinDetector`):

1. pre-processing and segmentation: the geometric detector's own stages (paper 4.1-4.2, the compiled
   kernels behind its ``detect_arrays``, equal to :func:`detectors.geometric.preprocess` and
   :func:`detectors.geometric.segment`), so both detectors see the same segments;
2. a conservative geometric **pre-gate** (``pre_gate=True``): segments with more beams than a 7 cm
   housing can return at their range (generous bounds, :data:`PRE_GATE_SLACK`,
   :data:`PRE_GATE_MARGIN`) stop here, with stage ``"diameter"``;
2b. the **cascade** (``cascade``, on when the checkpoint has a cascade file): a 12-16-1 network on
   cheap quantities (:data:`detectors.features.CASCADE_FEATURES`) drops the segments it scores
   below its threshold, fitted on training seeds to keep >= 99.9 % of the kin segments the full
   model accepts (``scripts/fit_cascade.py``); stage ``"learned"``;
2c. **candidate windows** (``windows``, on when the checkpoint has window settings: a network trained on
   them): housing-sized windows cut out of the segments the pre-gate dropped (:mod:`detectors.windows`),
   going on with the segments as more rows (cascade, features, network), accepted at max(segment, window
   threshold), dropped near a kept detection;
3. one feature vector per segment (:mod:`detectors.features`, ``FEATURE_VERSION``);
4. **classification** (replaces the paper's diameter and shape filters, 4.3): an MLP gives
   ``p(kin)`` for every segment of every scan of a batch in one pass (the checkpoint's weights as
   float32 matrix products on one BLAS thread, or in a compiled kernel, or its torch module);
5. **positioning** (4.4): the same network regresses the kin's centre in the segment's local frame
   (``positioning="regression"``), or the geometric detector's circle fit is used
   (``positioning="fit"``: the Levenberg-Marquardt fit of :func:`detectors.geometric.fit_circle` from
   the eq. 7 start). The checkpoint names the better one on held-out data.

``detect_arrays`` runs stages 1-5 in one compiled dispatch (:mod:`detectors._learned_driver`: one call
per scan or batch, the network inside it unless it goes to BLAS or torch); ``_predict`` keeps the
stages as separate calls, the readable reference the driver is tested against bit for bit.

Torch is not imported here: inference reads the checkpoint's torch-free form (``.npz``, beside the
``.pt``; :func:`load_inference_checkpoint`) and runs the network compiled or in numpy, so the base
install runs this detector. The torch parts (:class:`SegmentNet`, :func:`save_checkpoint`,
:func:`load_checkpoint`, :func:`export_checkpoint`, :func:`train_segment_net`, ``inference="torch"``)
live in :mod:`detectors.learned_torch` (the ``train`` extra); their names stay importable from here,
which imports that module on first use.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import _kernels as _k
from . import _learned_driver as _drv
from .base import (
    STAGES,
    BatchDetections,
    DetectionResult,
    KinDetector,
    LazyBatchReports,
    SegmentReport,
    gc_paused,
    trusted_ranges,
    validate_batch,
    validate_scan,
    wrap_angle,
)
from .features import (
    CASCADE_FEATURES,
    FEATURE_VERSION,
    FeatureConfig,
    SegmentBatch,
    SegmentFeatures,
    _cascade,
    _segment_batch,
    _segment_features,
    beam_trig,
    cascade_one_beam_table,
    config_from_dict,
    feature_names,
    local_to_observer,
    scan_noise,
    segment_features,
)
from .fileio import atomic_write, sha256_file
from .geometric import _LM_LAMBDA0, _LM_LAMBDA_MAX, _LM_XTOL, is_circular_sweep
from .windows import WindowConfig

__all__ = [
    "CASCADE_FORMAT",
    "CHECKPOINT_FORMAT",
    "DEFAULT_CHECKPOINT",
    "LearnedKinDetector",
    "ModelConfig",
    "TrainConfig",
    "cascade_path",
    "check_thresholds",
    "duplicates",
    "expected_beams",
    "load_cascade",
    "load_inference_checkpoint",
    "load_npz_checkpoint",
    "npz_path",
    "sample_weights",
    "weights_digest",
    "window_settings",
    "write_npz_checkpoint",
]

#: the names of :mod:`detectors.learned_torch` (torch) that this module still provides, imported on first
#: use (``from detectors.learned import SegmentNet`` keeps working; ``import detectors.learned`` and a
#: star import stay torch-free, so they are not in ``__all__``)
_TORCH_NAMES = frozenset({
    "SegmentNet", "save_checkpoint", "load_checkpoint", "export_checkpoint", "train_segment_net",
    "model_from_checkpoint", "load_checkpoint_arrays", "_check_device", "_torch_threads", "_losses",
})  # fmt: skip


def __getattr__(name: str):
    if name in _TORCH_NAMES:
        from . import learned_torch

        return getattr(learned_torch, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


CHECKPOINT_FORMAT = "kin-envs/learned-kin-detector"
CHECKPOINT_FORMAT_VERSION = 1
#: The shipped model (trained by ``scripts/train_classifier.py``; see ``learned_default.json``).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "learned_default.pt"
POSITIONING = ("regression", "fit")
INFERENCE = ("auto", "blas", "numba", "torch")
_CHUNK = 4096  # segments per forward chunk
_BLAS_CHUNK = 1024  # rows per BLAS chain: the activations stay in cache
#: below this many segments per call ``"numba"`` inference runs :func:`detectors._kernels.mlp_forward_rows`
#: (bitwise the same outputs; the block kernel computes at least 8 rows: 1 row ~2 us vs ~10 us, 8 rows
#: 8.7 vs 10.3 us, 12 rows 12.6 vs 11.4 us, measured under load in one run)
_ROWS_KERNEL_MAX = 10
#: the fused driver's network runs :func:`detectors._learned_driver.mlp_rows4` below this many rows,
#: the block kernel from there (rows4 vs block: 12 rows 9.9 vs 11.4 us, 16 rows 13.0 vs 11.7 us, 64 rows
#: 48 vs 22 us; measured under load in one run)
_DRIVER_ROWS_MAX = 14
#: eqs. 4-5's tan looked up (:func:`detectors.features.beam_trig`) for beams up to this many apart minus
#: one: every pre-gated segment of a 1-degree lidar at >= ~0.5 m (a 360 x 32 table, 92 kB)
_TAN_OFFSETS = 32
#: Pre-gate bounds (``LearnedKinDetector(pre_gate=True)``): a segment is dropped before the network
#: when it has more beams than a housing can return, computed with the housing's centre at
#: ``PRE_GATE_SLACK * min(d_i)`` (readings up to 25 % too long: 12 sigma of 2 % noise) plus
#: ``PRE_GATE_MARGIN`` beams.
PRE_GATE_SLACK = 0.8
PRE_GATE_MARGIN = 2
#: The cascade's stage-1 model file (``<checkpoint>.cascade.json``, written by ``scripts/fit_cascade.py``).
CASCADE_FORMAT = "kin-envs/learned-cascade"
CASCADE_FORMAT_VERSION = 1
_BEAM_KEYS = ("beam_edges", "table")
#: this thread's kept work arrays of the fused driver (:func:`_driver_work`), shared by its detectors
_WORK = threading.local()


_F32 = np.dtype(np.float32)


def _driver_work(cells: int, n_feat: int) -> tuple:
    """This thread's work arrays (:func:`detectors._learned_driver.new_work`) for a batch of ``cells``
    beams: kept and reused across calls (grown when a batch needs more; a call only uses them inside
    itself, so the detectors of one thread can share them), or a set of the call's own for batches past
    ``WORK_MAX_CELLS``."""
    if cells > _drv.WORK_MAX_CELLS:
        return _drv.new_work(0, 0, n_feat)
    ws = getattr(_WORK, "ws", None)
    if ws is None or ws[1].shape[0] < _drv._W_I64 * cells:
        old_rows = 0 if ws is None else ws[5].shape[0] // _drv._R_I64
        ws = _WORK.ws = _drv.new_work(cells, max(old_rows, cells // 4), n_feat)
    return ws


def _grow_driver_rows(ws: tuple, n_feat: int) -> None:
    """After a driver call on the kept work arrays ``ws``: room for more network rows next time if that
    call needed more than they hold (it then used arrays of its own)."""
    need = int(ws[6][0])
    if need * (n_feat + 3) > ws[4].shape[0] or need * _drv._R_F64 > ws[3].shape[0]:
        cells = ws[1].shape[0] // _drv._W_I64
        if getattr(_WORK, "ws", None) is ws:
            _WORK.ws = _drv.new_work(cells, min(cells, need + need // 4 + 64), n_feat)


def duplicates(scan, xy, score, radius: float) -> np.ndarray:
    """``(D,)`` for detections in segment order (``scan`` sorted): the index of a higher-scored
    detection of the same scan, next to it in that order among the kept ones (the last and the first
    of a scan too: the sweep wraps), whose centre lies within ``radius``; -1 for the detections to
    keep. Neighbours only: a split housing's parts are adjacent segments. A chain split in three
    keeps one; ties keep the earlier (compiled: :func:`_duplicates_kernel`)."""
    scan = np.ascontiguousarray(scan, dtype=np.int64)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(scan.shape[0], -1, np.int64)
    if scan.shape[0] > 1:
        _duplicates_kernel(scan, np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                           np.ascontiguousarray(score, dtype=np.float64), float(radius), out)  # fmt: skip
    return out


_duplicates_kernel = _drv.duplicates_kernel  # (compiled; the learned driver's env entry calls it too)


def expected_beams(range_min, step: float, r: float = 0.035) -> np.ndarray:
    """Beams (``step`` rad apart, on average) that a housing of radius ``r`` returns when a segment's
    nearest reading is ``range_min`` (m): its centre at ``range_min + r`` spans ``2 asin(r / (range_min
    + r))``. What the beam-dependent thresholds (:func:`save_checkpoint`) are indexed by: a score
    calibrated on 5-beam housings is not one on 2-beam housings, and the expected count (not the
    segment's own, which occlusion and merging change) is what the range says about the kin prior."""
    d = np.asarray(range_min, dtype=np.float64) + r
    return 2.0 * np.arcsin(np.minimum(r / d, 1.0)) / step


# --------------------------------------------------------------------------- model


@dataclass(frozen=True)
class ModelConfig:
    """Shape of :class:`SegmentNet`: ``n_features`` inputs, ReLU hidden layers of ``hidden`` units."""

    n_features: int
    hidden: tuple[int, ...] = (64, 64)

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(self.hidden))
        if isinstance(self.n_features, bool) or not isinstance(self.n_features, int) or self.n_features < 1:
            raise ValueError(f"ModelConfig.n_features must be an integer >= 1, got {self.n_features!r}")
        if not self.hidden or not all(
            isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in self.hidden
        ):
            raise ValueError(f"ModelConfig.hidden must be one or more integers >= 1, got {self.hidden!r}")

    def to_dict(self) -> dict:
        return {"n_features": self.n_features, "hidden": list(self.hidden)}

    @classmethod
    def from_dict(cls, d) -> ModelConfig:
        if not isinstance(d, dict):
            raise ValueError(f"ModelConfig: expected a dict, got {type(d).__name__}")
        unknown = sorted(set(d) - {"n_features", "hidden"})
        if unknown:
            raise ValueError(f"ModelConfig: unknown key(s) {unknown}; expected n_features, hidden")
        return cls(**d)


# --------------------------------------------------------------------------- checkpoints


def _plain(obj):
    """``obj`` with numpy scalars / arrays turned into Python numbers and lists (the checkpoint is
    loaded with ``weights_only=True``, which admits only plain types and tensors)."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _param_array(name: str, v) -> np.ndarray:
    """A parameter as a numpy array: a numpy array as it is, a torch tensor (anything with ``detach``)
    copied to the CPU; anything else is a corrupt checkpoint."""
    if isinstance(v, np.ndarray):
        return v
    if hasattr(v, "detach"):  # a torch tensor (this module never imports torch)
        return v.detach().cpu().contiguous().numpy()
    raise _CorruptWeights(f"parameter {name!r} is a {type(v).__name__}, not a tensor or array")


def weights_digest(state_dict: dict, normalisation: dict) -> str:
    """SHA-256 over every parameter (name, dtype, shape, bytes) and the normalisation statistics: what
    decides the detections. Stored in the checkpoint and checked on load (a flipped bit is refused).
    The parameters may be torch tensors or numpy arrays: both give the same digest (the dtype is
    named as torch names it, ``torch.float32``, as in every checkpoint written so far)."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        a = _param_array(name, state_dict[name])
        h.update(f"{name}|torch.{a.dtype.name}|{tuple(a.shape)}|".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    for name in sorted(normalisation):
        h.update(f"{name}|".encode())
        h.update(np.asarray(normalisation[name], dtype=np.float64).tobytes())
    return h.hexdigest()


def check_thresholds(thresholds) -> dict:
    """Validated per-noise thresholds (see :func:`save_checkpoint`); ``None`` -> 0.5 everywhere."""
    if thresholds is None:
        return {"noise_edges": [], "values": [0.5]}
    if not isinstance(thresholds, dict) or set(thresholds) - {"noise_edges", "values", "info", *_BEAM_KEYS}:
        raise ValueError(
            f"thresholds must be a dict with noise_edges and values (and optionally beam_edges and table), "
            f"got {thresholds!r}"
        )
    edges = [float(e) for e in thresholds.get("noise_edges", [])]
    values = [float(v) for v in thresholds.get("values", [])]
    if len(values) != len(edges) + 1 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError(
            f"thresholds: expected len(noise_edges) + 1 probabilities in [0, 1], got {len(edges)} edges "
            f"and values {values}"
        )
    if any(not (b > a) for a, b in zip(edges, edges[1:], strict=False)) or not all(map(math.isfinite, edges)):
        raise ValueError(f"thresholds: noise_edges must be finite and increasing, got {edges}")
    out = {"noise_edges": edges, "values": values}
    if set(_BEAM_KEYS) & set(thresholds):
        if not set(_BEAM_KEYS) <= set(thresholds):
            raise ValueError(f"thresholds: beam_edges and table come together, got keys {sorted(thresholds)}")
        bedges = [float(e) for e in thresholds["beam_edges"]]
        table = [[float(v) for v in row] for row in thresholds["table"]]
        if (
            not bedges
            or not all(map(math.isfinite, bedges))
            or any(not (b > a) for a, b in zip(bedges, bedges[1:], strict=False))
        ):
            raise ValueError(f"thresholds: beam_edges must be finite and increasing, got {bedges}")
        if len(table) != len(values) or any(
            len(row) != len(bedges) + 1 or not all(0.0 <= v <= 1.0 for v in row) for row in table
        ):
            raise ValueError(
                f"thresholds: table must be {len(values)} rows (noise bins) of {len(bedges) + 1} "
                f"probabilities in [0, 1] (expected-beams bins), got {table}"
            )
        out["beam_edges"], out["table"] = bedges, table
    if "info" in thresholds:
        out["info"] = _plain(thresholds["info"])
    return out


class _CorruptWeights(ValueError):
    pass


def _check_weights(state: dict, nrm: dict, digest: str | None) -> None:
    """Non-finite parameters or statistics, or weights that do not match the stored checksum, raise.

    Checkpoints written before the checksum existed carry none; they are only checked for
    non-finite values. ``state``: torch tensors or numpy arrays."""
    for k, v in state.items():
        a = _param_array(k, v)
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise _CorruptWeights(f"parameter {k!r} holds NaN or inf")
    for k, v in nrm.items():
        if not np.all(np.isfinite(np.asarray(v, dtype=np.float64))):
            raise _CorruptWeights(f"normalisation statistic {k!r} holds NaN or inf")
    if digest is not None and weights_digest(state, nrm) != digest:
        raise _CorruptWeights("the weights do not match their stored SHA-256 (the file is corrupt)")


# ------------------------------------------------------------- checkpoints: the torch-free form (npz)

#: the checkpoint entries an npz carries besides its arrays (in its JSON ``meta``)
_NPZ_META = (
    "format", "format_version", "feature_version", "feature_config", "feature_names", "model_config",
    "normalisation", "weights_sha256", "positioning", "angular_resolution", "thresholds", "info",
)  # fmt: skip
_NPZ_PARAM = "param:"  # prefix of the parameters' array names


def npz_path(checkpoint) -> Path:
    """Where a checkpoint's torch-free form lives: ``<checkpoint without .pt>.npz`` beside it (written
    by :func:`~detectors.learned_torch.save_checkpoint` and
    :func:`~detectors.learned_torch.export_checkpoint`); an ``.npz`` path is its own."""
    p = Path(DEFAULT_CHECKPOINT if checkpoint is None else checkpoint)
    return p if p.suffix == ".npz" else p.with_name(p.stem + ".npz")


def _expected(what: str = "checkpoint") -> str:
    return (
        f"expected a learned kin detector {what} written by scripts/train_classifier.py "
        f"(format {CHECKPOINT_FORMAT!r}, feature version {FEATURE_VERSION})"
    )


def _param_shapes(mc: ModelConfig) -> dict[str, tuple[int, ...]]:
    """The parameters of a ``mc`` network by name (the names of :class:`SegmentNet`'s
    ``state_dict``: ``body.0``, ``body.2``, ... the hidden layers, ``head`` the output) and shape."""
    shapes, d = {}, mc.n_features
    for i, h in enumerate(mc.hidden):
        shapes[f"body.{2 * i}.weight"], shapes[f"body.{2 * i}.bias"] = (h, d), (h,)
        d = h
    shapes["head.weight"], shapes["head.bias"] = (3, d), (3,)
    return shapes


def write_npz_checkpoint(path, checkpoint: dict, source: dict | None = None) -> Path:
    """Write a checkpoint's torch-free form to ``path`` atomically (a temporary name, then a rename):
    the parameters as float32 arrays and the rest (:data:`_NPZ_META`: configs, normalisation,
    thresholds, ``weights_sha256``, ...) as UTF-8 JSON in the byte array ``meta``. ``checkpoint``: a
    checkpoint dict (as :func:`~detectors.learned_torch.load_checkpoint` returns; tensors or arrays,
    configs as objects or dicts). ``source``: ``{"file": name, "sha256": hex}`` of the ``.pt`` it was
    made from, checked by :func:`load_inference_checkpoint` before it uses the npz for that ``.pt``."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"write_npz_checkpoint: {path} must end in .npz")
    meta = {}
    for k in _NPZ_META:
        v = checkpoint.get(k)
        meta[k] = v.to_dict() if hasattr(v, "to_dict") else v
    state = {k: np.ascontiguousarray(_param_array(k, v)) for k, v in checkpoint["state_dict"].items()}
    if meta["weights_sha256"] is None:  # a checkpoint from before the checksum: the npz gets one
        meta["weights_sha256"] = weights_digest(state, meta["normalisation"])
    meta = {**_plain(meta), "form": "npz", "source": _plain(source)}
    arrays = {"meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)}  # UTF-8 JSON
    arrays.update({_NPZ_PARAM + k: v for k, v in state.items()})
    with atomic_write(path) as f:  # a crash or Ctrl-C never leaves half a file under the name
        np.savez(f, **arrays)
    return path


def _check_versions(meta: dict, path, expected: str) -> None:
    """A checkpoint's format and feature versions against this code's (``ValueError`` naming ``path``);
    shared by the npz loader and :func:`detectors.learned_torch.load_checkpoint`."""
    if meta.get("format_version") != CHECKPOINT_FORMAT_VERSION:
        raise ValueError(
            f"{path}: checkpoint format version {meta.get('format_version')!r} is not "
            f"{CHECKPOINT_FORMAT_VERSION}; {expected}"
        )
    if meta.get("feature_version") != FEATURE_VERSION:
        raise ValueError(
            f"{path}: checkpoint was trained on feature version {meta.get('feature_version')!r}, but this "
            f"code computes feature version {FEATURE_VERSION}; retrain it with scripts/train_classifier.py"
        )


def _checked_configs(meta: dict) -> tuple[FeatureConfig, ModelConfig]:
    """A checkpoint's ``(FeatureConfig, ModelConfig)``, its feature names and the model's input size
    checked against what this code computes (``ValueError``, ``KeyError`` or ``TypeError``: the callers
    name the file)."""
    fc = FeatureConfig.from_dict(meta["feature_config"])
    mc = ModelConfig.from_dict(meta["model_config"])
    names = feature_names(fc)
    if meta.get("feature_names") != names:
        raise ValueError(f"feature names {meta.get('feature_names')!r} differ from {names!r}")
    if mc.n_features != len(names):
        raise ValueError(
            f"the model takes {mc.n_features} input features but feature version {FEATURE_VERSION} with "
            f"{fc} gives {len(names)}"
        )
    return fc, mc


def _checked_operating_point(meta: dict) -> tuple[float, dict]:
    """A checkpoint's ``(angular_resolution, thresholds)``, its positioning checked (``ValueError`` /
    ``KeyError`` / ``TypeError``: the callers name the file); shared like :func:`_checked_configs`."""
    if meta.get("positioning") not in POSITIONING:
        raise ValueError(f"positioning {meta.get('positioning')!r} is not one of {POSITIONING}")
    return float(meta["angular_resolution"]), check_thresholds(meta.get("thresholds"))


def load_npz_checkpoint(path) -> dict:
    """Read a checkpoint's torch-free form (:func:`write_npz_checkpoint`) → the checkpoint dict of
    :func:`~detectors.learned_torch.load_checkpoint` with numpy arrays as ``state_dict`` (and
    ``npz``: the file read, ``source``: the ``.pt`` it was made from). No torch.

    Raises ``FileNotFoundError`` if there is no file at ``path`` and ``ValueError`` naming the path
    and what is expected if it is not such an npz, of another ``FEATURE_VERSION``, has parameters of
    the wrong names, dtypes or shapes for its model config, or weights that do not match their
    ``weights_sha256`` (a flipped bit)."""
    path = Path(path)
    expected = _expected("checkpoint's npz form") + " (save_checkpoint or scripts/export_checkpoint.py)"
    if path.is_dir():
        raise ValueError(f"learned detector checkpoint {path} is a directory, not a file; {expected}")
    if not path.is_file():
        raise FileNotFoundError(f"learned detector checkpoint {path} does not exist; {expected}")
    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError(f"a single {type(z).__name__}, not an npz archive")
        with z:
            arrays = {k: z[k] for k in z.files}
    except Exception as e:  # zipfile, numpy and OS errors for a file that is not an intact npz
        raise ValueError(
            f"{path}: not a readable npz checkpoint ({type(e).__name__}: {e}); {expected}"
        ) from e
    raw = arrays.pop("meta", None)
    try:
        ok = raw is not None and raw.ndim == 1 and raw.dtype == np.uint8
        meta = json.loads(raw.tobytes()) if ok else None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: unreadable metadata ({e}); {expected}") from e
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT or meta.get("form") != "npz":
        raise ValueError(f"{path}: not a learned kin detector checkpoint; {expected}")
    _check_versions(meta, path, expected)
    try:
        fc, mc = _checked_configs(meta)
        other = sorted(k for k in arrays if not k.startswith(_NPZ_PARAM))
        if other:
            raise ValueError(f"unexpected arrays {other}")
        state = {k[len(_NPZ_PARAM) :]: v for k, v in arrays.items()}
        shapes = _param_shapes(mc)
        if sorted(state) != sorted(shapes):
            raise ValueError(f"parameters {sorted(state)} are not those of a {mc} network, {sorted(shapes)}")
        for k, shape in shapes.items():
            if state[k].dtype != np.float32 or state[k].shape != shape:
                raise ValueError(
                    f"parameter {k!r} is {state[k].dtype} {state[k].shape}, expected float32 {shape} "
                    f"(model config {mc})"
                )
        digest = meta["weights_sha256"]
        if not isinstance(digest, str) or len(digest) != 64:
            raise ValueError(f"weights_sha256 must be a SHA-256 hex digest, got {digest!r}")
        nrm = meta["normalisation"]
        if not isinstance(nrm, dict) or sorted(nrm) != ["t_mean", "t_std", "x_mean", "x_std"]:
            raise ValueError(f"normalisation must hold x_mean, x_std, t_mean, t_std, got {nrm!r}")
        for name, n in (("x_mean", mc.n_features), ("x_std", mc.n_features), ("t_mean", 2), ("t_std", 2)):
            v = np.asarray(nrm[name], dtype=np.float64)
            if v.shape != (n,) or (name.endswith("std") and (v <= 0).any()):
                raise ValueError(f"normalisation {name} must be {n} values (std > 0), got shape {v.shape}")
        _check_weights(state, nrm, digest)
        res, thresholds = _checked_operating_point(meta)
    except _CorruptWeights as e:
        raise ValueError(f"{path}: corrupt checkpoint: {e}; refusing to load it") from e
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: inconsistent checkpoint ({type(e).__name__}: {e}); {expected}") from e
    meta.update(feature_config=fc, model_config=mc, state_dict=state, angular_resolution=res,
                thresholds=thresholds, path=str(path), npz=str(path))  # fmt: skip
    return meta


def load_inference_checkpoint(path=None) -> dict:
    """The checkpoint at ``path`` (default: the shipped one) with numpy arrays as ``state_dict``, for
    inference; without torch where its npz form exists (``path`` stays the name given):

    * an ``.npz`` path: :func:`load_npz_checkpoint`;
    * a ``.pt`` path whose npz beside it (:func:`npz_path`) was written for these exact bytes (the npz
      records the ``.pt``'s SHA-256; the shipped one's is), or only the npz: the npz;
    * otherwise the ``.pt`` through torch (:func:`~detectors.learned_torch.load_checkpoint`); without
      torch a ``ValueError`` that says how to export it (``scripts/export_checkpoint.py``). A stale
      npz (the ``.pt`` rewritten by other means) is ignored with a warning.
    """
    p = Path(DEFAULT_CHECKPOINT if path is None else path)
    if p.suffix == ".npz":
        return load_npz_checkpoint(p)
    if p.is_dir():
        raise ValueError(f"learned detector checkpoint {p} is a directory, not a file; {_expected()}")
    npz, stale = npz_path(p), None
    if npz.is_file():
        ck = load_npz_checkpoint(npz)
        src = ck.get("source") if isinstance(ck.get("source"), dict) else {}
        if not p.exists() or src.get("sha256") == sha256_file(p):
            ck["path"] = str(p)
            return ck
        stale = (
            f"{npz.name} beside it was exported from other bytes (its recorded .pt SHA-256 "
            f"{src.get('sha256')!r} is not this file's)"
        )
    if not p.exists():
        raise FileNotFoundError(f"learned detector checkpoint {p} does not exist; {_expected()}")
    try:
        from . import learned_torch
    except ImportError as e:
        why = stale or f"there is no {npz.name} beside it"
        raise ValueError(
            f"{p}: a torch checkpoint, and torch cannot be imported here ({e}); {why}. Export its "
            f"torch-free form once where torch is installed: python scripts/export_checkpoint.py {p} "
            f"(writes {npz}), or install the train extra (in the clone: pip install -e '.[train]')"
        ) from e
    if stale:
        warnings.warn(f"{p}: {stale}; loading the .pt through torch (re-export: python "
                      f"scripts/export_checkpoint.py {p})", stacklevel=3)  # fmt: skip
    return learned_torch.load_checkpoint_arrays(p)


def _numba_weights(ck: dict) -> tuple:
    """The network of checkpoint ``ck`` (numpy ``state_dict``) as arguments of
    :func:`detectors._kernels.mlp_forward`: ``(mean, std, weights, biases, sizes)``, float32, the layers'
    ``(out, in)`` matrices zero-padded into one array (head last)."""
    state, mc = ck["state_dict"], ck["model_config"]
    names = [f"body.{2 * i}" for i in range(len(mc.hidden))] + ["head"]
    mats = [(state[n + ".weight"], state[n + ".bias"]) for n in names]
    sizes = np.array([mc.n_features] + [w.shape[0] for w, _ in mats], dtype=np.int64)
    w = int(sizes.max())
    weights = np.zeros((len(mats), w, w), dtype=np.float32)
    biases = np.zeros((len(mats), w), dtype=np.float32)
    for i, (wi, bi) in enumerate(mats):
        weights[i, : wi.shape[0], : wi.shape[1]] = wi
        biases[i, : bi.shape[0]] = bi
    nrm = ck["normalisation"]  # float32, as the torch module's buffers hold them
    mean = np.asarray(nrm["x_mean"], dtype=np.float32)
    std = np.asarray(nrm["x_std"], dtype=np.float32)
    return mean, std, weights, biases, sizes


def _blas_weights(numba_weights: tuple) -> list[tuple[np.ndarray, np.ndarray]]:
    """The network as float32 ``(W (in, out), b)`` per layer (head last) for :func:`_blas_forward`,
    the input standardisation folded into the first layer (computed in float64), from
    :func:`_numba_weights`' arrays."""
    mean, std, weights, biases, sizes = numba_weights
    f64 = lambda a: a.astype(np.float64)  # noqa: E731
    layers = [(f64(weights[i, : sizes[i + 1], : sizes[i]]).T, f64(biases[i, : sizes[i + 1]]))
              for i in range(len(sizes) - 1)]  # fmt: skip
    mean, std = mean.astype(np.float64), std.astype(np.float64)
    w0, b0 = layers[0]
    layers[0] = (w0 / std[:, None], b0 - (mean / std) @ w0)
    return [(np.ascontiguousarray(w, dtype=np.float32), b.astype(np.float32)) for w, b in layers]


# --------------------------------------------------------------------------- cascade


def cascade_path(checkpoint) -> Path:
    """Where a checkpoint's cascade stage-1 model lives: ``<checkpoint without .pt>.cascade.json``."""
    p = Path(DEFAULT_CHECKPOINT if checkpoint is None else checkpoint)
    return p.with_name(p.stem + ".cascade.json")


def load_cascade(path, weights_sha256: str | None = None) -> dict:
    """Read and check a cascade file (see ``scripts/fit_cascade.py``) → dict with ``model`` (float64
    ``(w1t, b1, w2, b2)`` for :func:`detectors.features._cascade`), ``threshold`` (segments
    scoring below it skip the features and the network), ``min_p_threshold`` (the lowest ``p(kin)``
    threshold the retention was measured for) and ``info``.

    ``weights_sha256``: the checkpoint's; a cascade fitted to other weights is refused. Raises
    ``ValueError`` naming the file and what is wrong.
    """
    path = Path(path)
    what = f"cascade file {path}"
    if not path.is_file():
        raise ValueError(f"{what} does not exist (write one with scripts/fit_cascade.py)")
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{what}: not readable JSON ({e})") from e
    if not isinstance(d, dict) or d.get("format") != CASCADE_FORMAT:
        raise ValueError(f"{what}: not a learned-detector cascade (format {CASCADE_FORMAT!r})")
    if d.get("format_version") != CASCADE_FORMAT_VERSION or d.get("feature_version") != FEATURE_VERSION:
        raise ValueError(
            f"{what}: format version {d.get('format_version')!r} / feature version "
            f"{d.get('feature_version')!r}; this code reads {CASCADE_FORMAT_VERSION} / {FEATURE_VERSION}"
        )
    if d.get("features") != list(CASCADE_FEATURES):
        raise ValueError(f"{what}: features {d.get('features')!r} are not {list(CASCADE_FEATURES)}")
    if weights_sha256 is not None and d.get("checkpoint_weights_sha256") != weights_sha256:
        raise ValueError(
            f"{what} was fitted for other checkpoint weights (sha256 {d.get('checkpoint_weights_sha256')!r}, "
            f"the checkpoint's {weights_sha256!r}); refit it with scripts/fit_cascade.py"
        )
    try:
        f = len(CASCADE_FEATURES)
        arr = {k: np.asarray(d[k], dtype=np.float64) for k in ("mean", "std", "w1", "b1", "w2")}
        b2, thr, min_p = float(d["b2"]), float(d["threshold"]), float(d["min_p_threshold"])
        h = arr["w1"].shape[0]
        shapes_ok = (
            arr["mean"].shape == (f,) and arr["std"].shape == (f,) and arr["w1"].shape == (h, f)
            and arr["b1"].shape == (h,) and arr["w2"].shape == (h,) and h >= 1
        )  # fmt: skip
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{what}: missing or malformed entry ({type(e).__name__}: {e})") from e
    if not shapes_ok:
        raise ValueError(f"{what}: weights do not form a {f} -> H -> 1 network")
    if not all(np.isfinite(v).all() for v in arr.values()) or not all(map(math.isfinite, (b2, thr, min_p))):
        raise ValueError(f"{what}: NaN or inf weights or thresholds")
    if (arr["std"] <= 0).any() or not 0.0 <= min_p <= 1.0:
        raise ValueError(f"{what}: std must be > 0 and min_p_threshold in [0, 1]")
    # the kernel takes the (in, out) matrix with the standardisation folded in
    w1t = arr["w1"].T / arr["std"][:, None]
    b1 = arr["b1"] - (arr["mean"] / arr["std"]) @ arr["w1"].T
    model = (np.ascontiguousarray(w1t), np.ascontiguousarray(b1), np.ascontiguousarray(arr["w2"]), b2)
    return {"model": model, "threshold": thr, "min_p_threshold": min_p, "info": d.get("info", {}),
            "path": str(path)}  # fmt: skip


# --------------------------------------------------------------------------- candidate windows


def window_settings(checkpoint: dict) -> tuple[WindowConfig, dict] | None:
    """A checkpoint's candidate-window settings (issue 11, rounds 6-7): ``(WindowConfig, thresholds)``
    when its ``info`` has the window thresholds that ``scripts/train_classifier.py`` calibrates for a
    network trained on windows (``window_thresholds``: ``noise_edges`` and ``values``) and the config its
    datasets' windows were cut with (``window_config``, or the one config all of ``windows`` name: the
    datasets' manifests), else None (a checkpoint trained without windows). Malformed settings raise a
    ``ValueError`` naming what is wrong."""
    info = checkpoint.get("info") or {}
    wt = info.get("window_thresholds")
    if wt is None:
        return None
    cfg = info.get("window_config")
    if cfg is None:
        named = [w for w in (info.get("windows") or []) if w is not None]
        if not named or any(w != named[0] for w in named):
            raise ValueError(f"window thresholds but no single window config (info windows: {named!r})")
        cfg = named[0]
    if not isinstance(wt, dict):
        raise ValueError(f"window_thresholds must be a dict with noise_edges and values, got {wt!r}")
    th = check_thresholds({"noise_edges": wt.get("noise_edges", []), "values": wt.get("values", [])})
    return WindowConfig.from_dict(cfg), th


# --------------------------------------------------------------------------- detector


class LearnedKinDetector(KinDetector):
    """Kin detector with a learned segment classifier (see the module docstring).

    Args:
        checkpoint: path of a checkpoint (default: the shipped ``learned_default.pt``): a ``.pt``, read
            from the torch-free ``.npz`` beside it when that was written for it, or an ``.npz``
            (:func:`load_inference_checkpoint`). Only ``inference="torch"`` imports torch.
        threshold: a segment is a kin if ``p(kin) >= threshold``; ``None`` (default): the
            checkpoint's thresholds, calibrated on validation scenes per estimated scan-noise level
            (:func:`detectors.features.scan_noise`; 0.5 if the checkpoint has none).
        device: torch device for the forward pass of ``inference="torch"`` (``"cpu"`` or ``"cuda"``);
            the other inference modes run on the CPU.
        positioning: ``"regression"`` or ``"fit"``; default: the checkpoint's choice.
        reports: build one :class:`SegmentReport` per segment in ``detect`` / ``detect_batch``
            (pass False when only detections are needed; ``reports`` is then empty).
        inference: ``"blas"`` (the exported float32 weights as numpy matrix products, BLAS on
            one thread inside each call (threadpoolctl), the caller's setting restored afterwards),
            ``"numba"`` (the exported weights in compiled float32 kernels, inside the fused driver's
            one compiled call), ``"auto"`` (default: ``"numba"``, measured faster than one-thread
            BLAS at every batch size since its block kernel keeps partial sums in registers,
            README, Performance; ``"blas"`` agrees to float32 rounding, ~1e-6 in ``p(kin)``) or
            ``"torch"`` (the checkpoint's module, run on ``torch_threads`` threads inside each call,
            the caller's torch setting restored afterwards; needs the ``train`` extra). Only
            ``"torch"`` runs on ``device``.
        torch_threads: torch intra-op threads during inference (``"torch"``).
        pre_gate: drop segments that cannot be a housing from their geometry alone before the
            features and the network (default True): a segment with more beams than a circle of
            radius ``r`` (7 cm wide) returns at its range, computed generously (the centre at
            :data:`PRE_GATE_SLACK` ``* min(d_i)``, i.e. readings up to 25 % too long, plus
            :data:`PRE_GATE_MARGIN` beams; :func:`detectors._kernels.housing_max_beams`). These
            are walls and large obstacles (in a dense 64-robot arena ~9 % of the segments but half
            of the beams); on 1,000 training-seed scenes it dropped 1 of the 27,323 kin segments
            the network accepts (``scripts/validate_pre_gate.py``; README, "The learned segment
            classifier"). Dropped segments get stage ``"diameter"``, ``p_kin`` NaN and the bound in
            ``seg_values["max_beams"]``. With ``False`` the outputs are those of every segment
            through the network.
        cascade: (every call, one scan or a batch: a scan's detections never depend on its batch) a cheap
            first stage after the pre-gate (default ``None``: on when the checkpoint
            has a cascade file, :func:`cascade_path`, and the ``p(kin)`` thresholds are not below
            the ones it was fitted for; ``True``: required; ``False``: off; or a cascade file's
            path). A one-hidden-layer network on :data:`detectors.features.CASCADE_FEATURES`
            (segment size, range, eqs. 4-5 widths, chord, context, scan noise: no circle fit)
            scores each segment; those below its threshold skip the features and the network
            (stage ``"learned"``, ``p_kin`` NaN, ``seg_values["cascade_score"]``). Fitted by
            ``scripts/fit_cascade.py`` on training seeds to keep >= 99.9 % of the kin segments the
            full model accepts (README, "The learned segment classifier").
        windows: candidate windows (issue 11, round 7; :mod:`detectors.windows`): housing-sized windows
            cut out of the segments the pre-gate drops (a kin merged with a wall or a touching neighbour),
            scored by the same network after the same cascade, accepted at max(the segment threshold,
            the checkpoint's window threshold for the scan's noise); a window whose centre lies within
            ``2 r`` of a kept detection of its scan is dropped (best first). ``None`` (default): on when
            the checkpoint has window settings (:func:`window_settings`: a network trained on windows);
            ``True``: required; ``False``: off. Needs the pre-gate and per-noise thresholds (not the
            expected-beams table). A window's detection follows its scan's segment detections, with the
            window's beams and ``segment`` = the segment it was cut from (its stage stays ``"diameter"``).
        suppress_duplicates: of two accepted segments of one scan, next to each other among the
            accepted ones, whose kin centres lie within a housing's diameter (``2 r``: two housings
            cannot be closer), keep the higher-scored one (default True). A housing right next to the
            observer (~0.18 m, robots touching) is often split into two segments, both accepted with
            the same centre: one kin, two detections, one of them a false positive (on noise-free
            swarm scenes 190 of the 198 false positives with 3-4 beams). The dropped segment gets
            stage ``"learned"``, a reason naming the kept one and ``seg_values["duplicate_of"]``.
            With ``False``: every accepted segment is a detection (as before).

    ``Detection.score`` is ``p(kin)`` (higher = more kin-like). Each :class:`SegmentReport` has
    stage ``"accepted"`` or ``"learned"`` (rejected by the classifier) and ``metrics["p_kin"]``.
    :meth:`detect_arrays` returns a :class:`~detectors.base.BatchDetections` of flat arrays
    (``seg_values``: ``p_kin``, ``threshold``); ``detect_batch`` / ``detect`` build objects from it.
    The speed does not depend on the caller's torch or BLAS thread settings: inference runs on one
    BLAS thread (``"blas"``), in a compiled kernel (``"numba"``) or on ``torch_threads`` (1) torch
    threads, and the caller's counts are restored afterwards.
    """

    def __init__(
        self,
        checkpoint=None,
        threshold: float | None = None,
        device="cpu",
        *,
        positioning: str | None = None,
        reports: bool = True,
        inference: str = "auto",
        torch_threads: int = 1,
        pre_gate: bool = True,
        cascade: bool | str | Path | None = None,
        suppress_duplicates: bool = True,
        windows: bool | None = None,
    ) -> None:
        if not isinstance(suppress_duplicates, bool):
            raise ValueError(
                f"LearnedKinDetector: suppress_duplicates must be True or False, got {suppress_duplicates!r}"
            )
        self.suppress_duplicates = suppress_duplicates
        if not isinstance(pre_gate, bool):
            raise ValueError(f"LearnedKinDetector: pre_gate must be True or False, got {pre_gate!r}")
        if inference not in INFERENCE:
            raise ValueError(f"LearnedKinDetector: inference must be one of {INFERENCE}, got {inference!r}")
        if isinstance(torch_threads, bool) or not isinstance(torch_threads, int) or torch_threads < 1:
            raise ValueError(
                f"LearnedKinDetector: torch_threads must be an integer >= 1, got {torch_threads!r}"
            )
        if threshold is not None and (
            isinstance(threshold, bool)
            or not isinstance(threshold, int | float)
            or not 0.0 <= threshold <= 1.0
        ):
            raise ValueError(
                f"LearnedKinDetector: threshold must be a probability in [0, 1], got {threshold!r}"
            )
        if inference == "torch":
            from . import learned_torch

            self.device = learned_torch._check_device(device)
        else:
            dev = getattr(device, "type", device)  # a torch.device or its name
            if not isinstance(dev, str) or dev.split(":")[0] not in ("cpu", "cuda"):
                raise ValueError(f"LearnedKinDetector: device must be 'cpu' or 'cuda', got {device!r}")
            if dev.split(":")[0] != "cpu":
                raise ValueError(
                    f"LearnedKinDetector: inference={inference!r} runs on the CPU, got device {device!r}; "
                    "use inference='torch' for a CUDA device"
                )
            self.device = device
        self._model = None
        self.checkpoint = load_inference_checkpoint(checkpoint)
        self.feature_config: FeatureConfig = self.checkpoint["feature_config"]
        self._dup_radius = 2.0 * float(self.feature_config.r)  # two housings' centres are never closer
        self.threshold = None if threshold is None else float(threshold)
        th = self.checkpoint["thresholds"]
        self._noise_edges = np.asarray(th["noise_edges"], dtype=np.float64)
        self._noise_thresholds = np.asarray(th["values"], dtype=np.float64)
        names = feature_names(self.feature_config)
        self._noise_col = names.index("log_scan_noise")
        self._range_col = names.index("log_range_min")
        # thresholds by expected beams on a housing at the segment's range (checkpoints calibrated
        # by scripts/calibrate_thresholds.py --by-beams); older checkpoints: per noise level only
        self._beam_edges = np.asarray(th.get("beam_edges", []), dtype=np.float64)
        self._beam_table = np.asarray(th["table"], dtype=np.float64) if "table" in th else None
        pos = self.checkpoint["positioning"] if positioning is None else positioning
        if pos not in POSITIONING:
            raise ValueError(f"LearnedKinDetector: positioning must be one of {POSITIONING}, got {pos!r}")
        self.positioning = pos
        self.reports = bool(reports)
        self.inference = inference
        self.torch_threads = torch_threads
        # the compiled network's weights also serve the fused driver's signature with torch inference
        self._numba_weights = _numba_weights(self.checkpoint)
        mean, std, w, b, sizes = self._numba_weights
        self._numba_weights_t = (mean, std, np.ascontiguousarray(w.transpose(0, 2, 1)), b, sizes)
        #: the fused driver runs the network itself (else ``_run_driver``)
        self._network_compiled = inference in ("auto", "numba")
        self._drv_args = None
        self._then_fast = None  # _detect_table_then's kept call (shape, trig, settings, ws, args, ...)
        if inference == "torch":
            _ = self.model  # built now: a bad device or checkpoint fails here, not in the first call
        else:
            self._blas_weights = _blas_weights(self._numba_weights)
            if inference == "blas" and _blas_controller() is None:
                raise ImportError(
                    "LearnedKinDetector: inference='blas' needs threadpoolctl (pip install threadpoolctl) "
                    "to run BLAS on one thread; use inference='auto' or 'numba'"
                )
        self.pre_gate = pre_gate
        self._cascade = self._load_cascade(cascade)
        self._load_windows(windows)
        self._angles_key: np.ndarray | None = None
        self._angles_src: np.ndarray | None = None
        self._circular = True
        self._step = float(self.checkpoint["angular_resolution"])
        self._trig = None
        nrm = self.checkpoint["normalisation"]
        self._t_mean = np.asarray(nrm["t_mean"], dtype=np.float64)
        self._t_std = np.asarray(nrm["t_std"], dtype=np.float64)

    @property
    def model(self):
        """The network as a torch module (:class:`~detectors.learned_torch.SegmentNet`, eval mode, on
        ``device``), built on first access: only ``inference="torch"`` runs it, so that the others never
        import torch."""
        if self._model is None:
            from . import learned_torch

            self._model = learned_torch.model_from_checkpoint(
                self.checkpoint, self.device if self.inference == "torch" else "cpu"
            )
        return self._model

    def _load_windows(self, windows) -> None:
        if windows is not None and not isinstance(windows, bool):
            raise ValueError(f"LearnedKinDetector: windows must be None, True or False, got {windows!r}")
        try:
            ws = window_settings(self.checkpoint)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"LearnedKinDetector: {self.checkpoint['path']}: bad window settings: {e}"
            ) from None
        if windows is True and ws is None:
            raise ValueError(
                f"LearnedKinDetector: windows=True, but the checkpoint {self.checkpoint['path']} has no "
                "window settings (train one on windows: make_dataset.py --windows, train_classifier.py)"
            )
        on = ws is not None and windows is not False
        if on and windows is True and (not self.pre_gate or self._beam_table is not None):
            raise ValueError("LearnedKinDetector: windows=True needs pre_gate=True and per-noise thresholds")
        on = on and self.pre_gate and (self._beam_table is None or self.threshold is not None)
        #: the window config, or None (windows off)
        self.window_config: WindowConfig | None = ws[0] if on else None
        th = ws[1] if on else {"noise_edges": [], "values": [1.0]}
        self._win_edges = np.asarray(th["noise_edges"], dtype=np.float64)
        self._win_values = np.asarray(th["values"], dtype=np.float64)

    @property
    def windows(self) -> bool:
        """Whether candidate windows are cut and scored (see ``windows``)."""
        return self.window_config is not None

    @property
    def cascade(self) -> bool:
        """Whether the cascade's first stage runs (see ``cascade``): on every call, one scan as a batch, so
        that a scan's detections never depend on the batch it comes in (until session 16 one-scan calls
        went without it; there it costs about what it saves, measured)."""
        return self._cascade is not None

    def _load_cascade(self, cascade) -> dict | None:
        if cascade is False:
            return None
        if not (cascade is None or cascade is True or isinstance(cascade, str | Path)):
            raise ValueError(
                "LearnedKinDetector: cascade must be None, True, False or a cascade file path, "
                f"got {cascade!r}"
            )
        path = cascade_path(self.checkpoint["path"]) if cascade is None or cascade is True else Path(cascade)
        if cascade is None and not path.is_file():
            return None
        sha = self.checkpoint.get("weights_sha256")
        try:
            cas = load_cascade(path, sha)
        except ValueError as e:
            if cascade is not None:
                raise ValueError(f"LearnedKinDetector: {e}") from None
            warnings.warn(f"LearnedKinDetector: cascade off: {e}", stacklevel=3)
            return None
        lowest = self.threshold if self.threshold is not None else float(self._noise_thresholds.min())
        if lowest < cas["min_p_threshold"] - 1e-12:
            # the retention was measured at the fitted thresholds: a lower one (a PR curve's
            # permissive run, threshold calibration) needs every segment's p(kin)
            if cascade is not None:
                raise ValueError(
                    f"LearnedKinDetector: threshold {lowest:g} is below the {cas['min_p_threshold']:g} "
                    f"the cascade {path} was fitted for; use cascade=None or False"
                )
            return None
        return cas

    # -- input checks ---------------------------------------------------------------------------
    def _check(self, ranges, angles, trusted: bool = False) -> tuple[np.ndarray, np.ndarray]:
        if trusted and (rb := trusted_ranges(ranges, angles, self._angles_src)) is not None:
            return rb, angles
        rb, a = validate_batch(ranges, angles)
        key = self._angles_key
        if key is None or key.shape != a.shape or not np.array_equal(key, a):
            # the beam layout is validated once and remembered (costly for small scans)
            validate_scan(np.zeros(a.shape), a)
            step = float(np.abs(wrap_angle(np.diff(a))).mean())
            res = self.checkpoint["angular_resolution"]
            if abs(step - res) > 0.25 * res:
                raise ValueError(
                    f"LearnedKinDetector: the scan's beams are {math.degrees(step):.3f} deg apart, but the "
                    f"checkpoint {self.checkpoint['path']} was trained on {math.degrees(res):.3f} deg beams; "
                    "train one for this lidar (scripts/make_dataset.py, scripts/train_classifier.py)"
                )
            self._circular = is_circular_sweep(a)
            self._step = step
            self._angles_key = a.copy()
            self._trig = beam_trig(self._angles_key, _TAN_OFFSETS)
        if trusted:
            self._angles_src = angles  # the caller's (never mutated) layout array, checked above
        bad = rb < 0.0  # NaN / +inf mean "no return" and are fine
        if bad.any():
            b = int(np.flatnonzero(bad.any(axis=1))[0])
            try:
                validate_scan(rb[b], a)
            except ValueError as e:
                raise ValueError(f"ranges[{b}]: {e}") from None
        return rb, a

    # -- stages ---------------------------------------------------------------------------------
    def predict_segments(
        self, ranges, angles
    ) -> tuple[SegmentBatch, SegmentFeatures, np.ndarray, np.ndarray]:
        """Stages 1-4 for ``B`` scans without building results.

        Returns ``(batch, features, p_kin (S,), centres (S, 2))``: the segments of all scans, their
        features (of every segment, pre-gated or not), the kin probability of each segment (NaN
        where the pre-gate or the cascade dropped it) and the kin centre each would have (observer
        frame ``x, y``, m; with this detector's ``positioning``; regression for every segment that reached the
        network, circle fit only where ``p_kin >= threshold``, NaN elsewhere).
        """
        batch, feats, p, centres, _, _, _ = self._predict(ranges, angles, all_features=True)
        return batch, feats, p, centres

    def segment_thresholds(self, feats: SegmentFeatures) -> np.ndarray:
        """``(S,)`` the ``p(kin)`` threshold of each segment: ``threshold``, or the checkpoint's for
        the noise level its scan's noise estimate falls in (and, if the checkpoint has them, for the
        beams a housing would return at the segment's range, :func:`expected_beams`)."""
        thr = self._thresholds(feats.x[:, self._noise_col])
        return self._by_beams(thr, feats.x[:, self._noise_col], feats.x[:, self._range_col])

    def _noise_bin(self, log_noise: np.ndarray, edges: np.ndarray | None = None) -> np.ndarray:
        sigma = np.exp(log_noise.astype(np.float64)) - 1e-4
        return np.searchsorted(self._noise_edges if edges is None else edges, sigma, side="right")

    def window_thresholds(self, log_noise: np.ndarray) -> np.ndarray:
        """The candidate windows' own ``p(kin)`` thresholds (a window is accepted at the larger of this and
        its segment threshold) for float32 ``log_scan_noise`` feature values; needs window settings."""
        if not self.windows:
            raise ValueError(f"{self.checkpoint['path']}: candidate windows are off (no window thresholds)")
        return self._win_values[self._noise_bin(log_noise, self._win_edges)]

    def _thresholds(self, log_noise: np.ndarray) -> np.ndarray:
        """Per-noise thresholds for float32 ``log_scan_noise`` feature values."""
        n = log_noise.shape[0]
        if self.threshold is not None:
            return np.full(n, self.threshold)
        if self._noise_edges.size == 0:
            return np.full(n, float(self._noise_thresholds[0]))
        return self._noise_thresholds[self._noise_bin(log_noise)]

    def _by_beams(self, thr: np.ndarray, log_noise: np.ndarray, log_range_min: np.ndarray) -> np.ndarray:
        """``thr`` replaced by the checkpoint's noise x expected-beams table where it has one (the
        rows' float32 ``log_scan_noise`` and ``log_range_min`` features)."""
        if self.threshold is not None or self._beam_table is None or thr.size == 0:
            return thr
        d_min = np.exp(log_range_min.astype(np.float64))
        eb = expected_beams(d_min, self._step, float(self.feature_config.r))
        col = np.searchsorted(self._beam_edges, eb, side="right")
        return self._beam_table[self._noise_bin(log_noise), col]

    def _forward(self, x: np.ndarray) -> np.ndarray:
        """``(S, 3)`` float64 network outputs for ``(S, F)`` float32 features."""
        inf = self.inference
        if inf == "auto":
            inf = "numba"
        if inf == "blas":
            return _blas_forward(x, self._blas_weights)
        if inf == "numba":
            out = np.empty((x.shape[0], 3), dtype=np.float32)
            if x.shape[0] < _ROWS_KERNEL_MAX:  # one scan's segments: the row kernel, same bits
                _k.mlp_forward_rows(np.ascontiguousarray(x), *self._numba_weights_t, out)
            else:
                _k.mlp_forward(np.ascontiguousarray(x), *self._numba_weights, out)
            return out.astype(np.float64)
        from . import learned_torch

        return learned_torch.forward(self.model, x, self.device, self.torch_threads)

    def gate(self, batch: SegmentBatch) -> np.ndarray:
        """``(S,)`` the pre-gate's bound: the most beams a housing can return at each segment's range
        (see ``pre_gate``); segments with more are dropped."""
        out = np.empty(batch.n_segments)
        _k.housing_max_beams(
            batch.ranges, batch.scan, batch.first, batch.count, self._step, float(self.feature_config.r),
            PRE_GATE_SLACK, float(PRE_GATE_MARGIN), out,
        )  # fmt: skip
        return out

    def _predict(
        self, ranges, angles, all_centres: bool = True, all_features: bool = False, trusted: bool = False
    ):
        """``(batch, feats, p, centres, thr, max_beams, cascade_score)``; ``feats`` holds the rows of
        the segments that reached the network unless ``all_features``; ``max_beams`` is None without
        pre-gate, ``cascade_score`` (NaN where not scored) None without cascade."""
        rb, a = self._check(ranges, angles, trusted)
        batch = _segment_batch(rb, a, self.feature_config, self._circular)
        n_seg = batch.n_segments
        if n_seg == 0:
            feats = segment_features(batch, self.feature_config)
            return batch, feats, np.zeros(0), np.zeros((0, 2)), np.zeros(0), None, None
        max_beams = rows = score = noise = None
        if self.pre_gate:
            max_beams = self.gate(batch)
            rows = np.flatnonzero(batch.count <= max_beams)
        if self._cascade is not None:
            noise = scan_noise(batch, self.feature_config)  # once for both stages
            cand = np.arange(n_seg, dtype=np.int64) if rows is None else rows
            _, s1 = _cascade(batch, self.feature_config, cand, self._trig, noise, self._cascade["model"])
            score = np.full(n_seg, np.nan)
            score[cand] = s1
            rows = cand[s1 >= self._cascade["threshold"]]
        which = rows if (rows is not None and not all_features) else np.arange(n_seg, dtype=np.int64)
        feats = _segment_features(batch, self.feature_config, which, self._trig, noise)
        x, frames = feats.x, feats.frames
        if rows is not None and all_features:
            x, frames = x[rows], frames[rows]
        # every scan's threshold once (the same float32 feature value as in its segments' rows)
        thr = self._thresholds(feats.scan_x[:, 0])[batch.scan]
        if self._beam_table is not None and self.threshold is None:
            thr_rows = self._by_beams(thr if rows is None else thr[rows], x[:, self._noise_col],
                                      x[:, self._range_col])  # fmt: skip
            if rows is None:
                thr = thr_rows
            else:
                thr[rows] = thr_rows
        out = self._forward(x)
        p_rows = 1.0 / (1.0 + np.exp(-out[:, 0]))
        if rows is None:
            p = p_rows
            acc_rows = p >= thr
        else:
            p = np.full(n_seg, np.nan)
            p[rows] = p_rows
            acc_rows = p_rows >= thr[rows]
        if self.positioning == "regression":
            if all_centres:
                uv = self._t_mean + self._t_std * out[:, 1:3]
                if rows is None:
                    centres = local_to_observer(frames, uv)
                else:
                    centres = np.full((n_seg, 2), np.nan)
                    centres[rows] = local_to_observer(frames, uv)
            else:  # only the accepted segments' centres are used: NaN elsewhere
                centres = np.full((n_seg, 2), np.nan)
                sel = np.flatnonzero(acc_rows)
                if sel.size:  # most one-scan calls accept nothing
                    uv = self._t_mean + self._t_std * out[sel, 1:3]  # the same values, only these rows
                    centres[sel if rows is None else rows[sel]] = local_to_observer(frames[sel], uv)
        else:
            centres = self._fit_centres(batch, p >= thr)
        return batch, feats, p, centres, thr, max_beams, score

    def _fit_centres(self, batch: SegmentBatch, which: np.ndarray) -> np.ndarray:
        """Geometric stage 4 for the segments ``which``: LM circle fit from eq. 7, else NaN.

        One-beam segments have no fit; their centre is eq. 7's (``min(d_i) + r`` along the beam).
        """
        centres = np.full((batch.n_segments, 2), np.nan)
        _k.fit_centres(
            batch.ranges,
            np.ascontiguousarray(batch.angles),
            batch.scan,
            batch.first,
            batch.count,
            np.flatnonzero(which),
            float(self.feature_config.r),
            200,
            _LM_XTOL,
            _LM_LAMBDA0,
            _LM_LAMBDA_MAX,
            centres,
        )
        return centres

    def detect_arrays(self, ranges, angles) -> BatchDetections:
        """Detect kins in ``B`` scans (``ranges`` (B, n) m, shared ``angles`` (n,) rad) → arrays.

        The segments of all scans go through the network in one pass, the whole call in one
        compiled dispatch (:mod:`detectors._learned_driver`). 0.0, NaN and inf readings
        are no return; a negative range raises ``ValueError`` naming its scan row and beam.
        ``seg_values`` holds ``p_kin`` and ``threshold`` for every segment.
        """
        return self._detect_arrays(ranges, angles, False)

    def _detect_arrays_trusted(self, ranges, angles) -> BatchDetections:
        """:meth:`detect_arrays` for callers that guarantee their input (internal; the envs, see
        ``kin_envs.envs.common.detection_arrays(trusted=True)``): ``ranges`` a float64 ``(B, n)``
        array of readings ``>= 0`` (or inf / NaN), ``angles`` the same, never-mutated layout
        array on every call. The per-call input checks (a fixed cost that matters for one-scan
        calls) are skipped once that ``angles`` object has been validated; a different ``angles``
        object or a ranges array of another type is checked as in :meth:`detect_arrays`. Outputs
        are identical."""
        return self._detect_arrays(ranges, angles, True)

    def _detect_table_trusted(self, ranges, angles) -> tuple[np.ndarray, np.ndarray]:
        """The detections of :meth:`_detect_arrays_trusted` (same input contract) as ``(scan row
        (D,) int64, table (D, 8) float64)``, the table's columns
        :data:`detectors._learned_driver.TABLE_FIELDS` (range, bearing, x, y, score, first_beam,
        last_beam, n_beams): what ``kin_envs.envs.common.detection_arrays`` reads, straight from the
        compiled driver without building a :class:`~detectors.base.BatchDetections`. Fresh arrays
        on every call."""
        if self._beam_table is not None and self.threshold is None:  # table thresholds: the staged path
            a = self._detect_arrays_staged(ranges, angles, True)
            cols = (a.range, a.bearing, a.x, a.y, a.score, a.first_beam, a.last_beam, a.n_beams_on)
            return a.scan, np.stack(cols, axis=1).astype(np.float64).reshape(-1, 8)
        rb = self._table_input(ranges, angles)
        # the whole call compiled, only the table returns (returning the driver's intermediate
        # arrays to Python costs ~0.9 ms per 64 dense-arena scans, measured)
        # (duplicate suppression inside the compiled call: a radius < 0 turns it off)
        radius = float(self._dup_radius) if self.suppress_duplicates else -1.0
        res = self._call_driver(_drv.fused_table, rb, self.cascade, radius, float(self._dup_radius))
        if res is not None:
            return res
        fr, bk = self._run_driver(np.ascontiguousarray(rb, dtype=np.float64))
        scan, table = fr[1][bk[3]], bk[4]
        if self.suppress_duplicates and scan.shape[0] > 1:
            d = np.full(scan.shape[0], -1, np.int64)
            _duplicates_kernel(scan, table[:, 2], table[:, 3], table[:, 4], self._dup_radius, d)
            if (d >= 0).any():
                keep = d < 0
                scan, table = scan[keep], table[keep]
        w_scan, _, w_table = bk[5]
        if w_scan.shape[0] > 0:  # the accepted windows after each scan's segment detections
            src, idx = _drv.window_merge(scan, table[:, 2], table[:, 3], w_scan, w_table[:, 2], w_table[:, 3],
                                         w_table[:, 4], float(self._dup_radius))  # fmt: skip
            scan = _merged(src, idx, scan, w_scan)
            table = _merged(src, idx, table, w_table)
        return scan, table

    def _detect_table_then(self, kernel, ranges, angles, *extra):
        """:meth:`_detect_table_trusted` (same input contract) with the caller's compiled work on its table in
        the same compiled call: ``kernel(r, args, *extra)``, a numba function that passes ``r`` and ``args``
        (:func:`detectors._learned_driver.fused_table`'s other arguments, the work arrays included, as one
        :class:`~detectors._learned_driver.DriverArgs`) to :func:`~detectors._learned_driver.fused_table_args`
        and works on the ``(scan row, table)`` it returns.
        Its output, or ``None`` where the table would not come from ``fused_table`` (thresholds by expected
        beams; inference ``"blas"`` / ``"torch"``): the caller then reads :meth:`_detect_table_trusted`. (The
        envs match and pad the table so: one dispatch, and the table never crosses into Python.)"""
        fast = self._then_fast
        # a single-robot env's step: the lidar's own float32 (1, n) scan on the validated layout, settings as
        # when the call's arguments were kept below: the kernel straight away (the checks and the argument
        # assembly of the path below are ~10 Python calls, ~7-11 us of a KinSeek step, run cold there)
        if (fast is not None and angles is self._angles_src
                and type(ranges) is np.ndarray and ranges.dtype is _F32 and ranges.shape == fast[0]
                and ranges.flags.c_contiguous and fast[1] is self._trig
                and getattr(_WORK, "ws", None) is fast[3]
                and fast[2] == (self.threshold, self.pre_gate, self.positioning, self.window_config,
                                self.suppress_duplicates)):  # fmt: skip
            ws = fast[3]
            res = kernel(ranges, fast[4], *extra)
            if ws[6][0] > fast[5]:  # (as _grow_driver_rows: more rows than the work arrays hold)
                _grow_driver_rows(ws, fast[6])
            return res
        if (self._beam_table is not None and self.threshold is None) or not self._network_compiled:
            return None
        rb = self._table_input(ranges, angles)
        front_args, back_args = self._driver_consts(self.cascade)
        mean, std, w, b, sizes = self._numba_weights
        radius = float(self._dup_radius) if self.suppress_duplicates else -1.0
        n_feat = int(front_args[17])
        consts = (front_args, _DRIVER_ROWS_MAX, mean, std, w, self._numba_weights_t[2], b, sizes, back_args,
                  radius, float(self._dup_radius))  # fmt: skip
        ws = _driver_work(rb.shape[0] * rb.shape[1], n_feat)
        res = kernel(rb, _drv.driver_args(*consts, ws), *extra)
        _grow_driver_rows(ws, n_feat)
        if rb is ranges and rb.dtype == np.float32 and rb.shape[0] == 1:
            # (the lidar's scan as it is: the arguments, kept for the next call with
            # this thread's work arrays, grown or not)
            ws = _driver_work(rb.shape[0] * rb.shape[1], n_feat)
            rows = min(ws[4].shape[0] // (n_feat + 3), ws[3].shape[0] // _drv._R_F64)  # network rows ws holds
            state = (self.threshold, self.pre_gate, self.positioning, self.window_config,
                     self.suppress_duplicates)  # fmt: skip
            self._then_fast = (rb.shape, self._trig, state, ws, _drv.driver_args(*consts, ws), rows, n_feat)
        return res

    def _detect_arrays(self, ranges, angles, trusted: bool) -> BatchDetections:
        if self._beam_table is not None and self.threshold is None:
            # thresholds by expected beams (calibrate_thresholds.py --by-beams): the staged pipeline,
            # which the fused driver does not implement
            return self._detect_arrays_staged(ranges, angles, trusted)
        rb = self._driver_input(ranges, angles, trusted)
        cascade = self.cascade
        # the whole call compiled, the columns handed back in a few blocks (not the driver's
        # intermediate arrays: returning them to Python costs ~0.9 ms per 64 dense-arena scans)
        packed = self._call_driver(_drv.fused_packed, rb, cascade)
        if packed is None:
            packed = _drv.pack(*self._run_driver(rb))
        seg_i, seg_b, seg_f, stage, det, det_f, det_i, win = packed
        n_seg = seg_i.shape[1]
        dup = None
        if self.suppress_duplicates and det.shape[0] > 1:
            d = np.full(det.shape[0], -1, np.int64)
            _duplicates_kernel(det_i[0], det_f[2], det_f[3], det_f[4], self._dup_radius, d)
            drop = d >= 0
            if drop.any():  # rare: as _detect_arrays_staged (the dropped get stage "learned")
                stage = stage.copy()
                stage[det[drop]] = _k.LEARNED
                dup = np.full(n_seg, -1, np.int64)
                dup[det[drop]] = det[d[drop]]
                keep = ~drop
                det, det_f, det_i = det[keep], det_f[:, keep], det_i[:, keep]
        if win.shape[0] > 0:
            det, det_f, det_i = self._with_windows(det, det_f, det_i, win)
        values = {"p_kin": seg_f[0], "threshold": seg_f[1]}
        if n_seg > 0:  # (the staged pipeline's values of an empty batch: p_kin and threshold only)
            if self.pre_gate:
                values["max_beams"] = seg_f[2]
            if cascade:
                values["cascade_score"] = seg_f[3]
        if dup is not None:
            values["duplicate_of"] = dup
        return BatchDetections(
            n_scans=rb.shape[0],
            n_beams=rb.shape[1],
            scan=det_i[0],
            range=det_f[0],
            bearing=det_f[1],
            x=det_f[2],
            y=det_f[3],
            score=det_f[4],
            first_beam=det_i[1],
            last_beam=det_i[2],
            n_beams_on=det_i[3],
            segment=det,
            seg_scan=seg_i[0],
            seg_first=seg_i[1],
            seg_count=seg_i[2],
            seg_prev=seg_i[3],
            seg_next=seg_i[4],
            seg_prev_nearer=seg_b[0],
            seg_next_nearer=seg_b[1],
            seg_stage=stage,
            seg_values=values,
        )

    def _with_windows(self, det, det_f, det_i, win) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The detection columns with the accepted windows ``win`` (:func:`~detectors._learned_driver.pack`)
        after each scan's segment detections, those within ``2 r`` of a kept one dropped
        (:func:`~detectors._learned_driver.window_merge`); a window's ``segment`` is its parent's."""
        w_scan = win[:, 8].astype(np.int64)
        src, idx = _drv.window_merge(det_i[0], det_f[2], det_f[3], w_scan, win[:, 2], win[:, 3], win[:, 4],
                                     float(self._dup_radius))  # fmt: skip
        w_i = np.stack([w_scan, win[:, 5].astype(np.int64), win[:, 6].astype(np.int64), win[:,
                                                                                            7].astype(np.int64)])
        return (_merged(src, idx, det, win[:, 9].astype(np.int64)), _merged(src, idx, det_f.T, win[:, :5]).T,
                _merged(src, idx, det_i.T, w_i.T).T)  # fmt: skip

    def _driver_args(self) -> tuple:
        """The fused driver's constant arguments ``(front_args, front_args with the cascade or None,
        back_args)`` for the current beam layout and settings (see :meth:`_driver_consts`)."""
        c = self.feature_config
        ang, cos_a, sin_a, sweep, tan_tab = self._trig
        fixed = -1.0 if self.threshold is None else self.threshold
        front = (
            float(c.d_th), float(c.d_max), self._circular, self.pre_gate, self._step, float(c.r),
            PRE_GATE_SLACK, float(PRE_GATE_MARGIN), ang, cos_a, sin_a, float(sweep), tan_tab,
            c.occlusion_unbounded, int(c.n_points), int(c.n_context), int(c.gn_iters), len(feature_names(c)),
        )  # fmt: skip
        # the cascade's model, or empty stand-ins of the same types (one compiled signature)
        off = (False, np.zeros((0, 0)), np.zeros(0), np.zeros(0), 0.0, 0.0, np.zeros((0, 4, 0, 6)))
        wc = self.window_config
        win = (False, False, 1.0, 0.0, 0.0) if wc is None else (
            True, wc.anchor == "span", float(wc.depth), float(wc.sag), float(wc.sag_noise))
        front_cas = None
        if self._cascade is not None:
            w1t, b1, w2, b2 = self._cascade["model"]
            if "one_beam_table" not in self._cascade:  # the bound's table: once per cascade model
                self._cascade["one_beam_table"] = cascade_one_beam_table(w1t, b1, w2, b2)
            front_cas = (
                *front, True, w1t, b1, w2, float(b2), float(self._cascade["threshold"]),
                self._cascade["one_beam_table"], *win,
            )  # fmt: skip
        back = (
            ang, self.pre_gate, float(fixed), self._noise_edges, self._noise_thresholds, self._win_edges,
            self._win_values, self.positioning == "regression", self._t_mean, self._t_std, float(c.r), 200,
            _LM_XTOL,
            _LM_LAMBDA0, _LM_LAMBDA_MAX,
        )  # fmt: skip
        return (*front, *off, *win), front_cas, back

    def _driver_consts(self, cascade: bool = False) -> tuple[tuple, tuple]:
        """``(front_args, back_args)`` of :meth:`_driver_args` (with the cascade if ``cascade``),
        cached; rebuilt when ``_check`` saw a new beam layout or ``threshold``, ``pre_gate`` or
        ``positioning`` changed."""
        cached = self._drv_args
        if (
            cached is None
            or cached[0][0] is not self._trig
            or cached[0][1:] != (self.threshold, self.pre_gate, self.positioning, self.window_config)
        ):
            key = (self._trig, self.threshold, self.pre_gate, self.positioning, self.window_config)
            self._drv_args = cached = (key, *self._driver_args())
        return (cached[2] if cascade else cached[1]), cached[3]

    def _table_input(self, ranges, angles) -> np.ndarray:
        """:meth:`_driver_input` for :meth:`_detect_table_trusted`, except that a C-contiguous float32
        ``(B, n)`` array on the validated ``angles`` (the lidar's own scans) is passed on as it is: the
        driver reads it as float64 (exact), without a float64 copy of the batch (~180 kB at 64 robots,
        written and read once more on every step; the compiled entry's float32 specialization is only
        compiled where float32 ranges come)."""
        lidar = (
            type(ranges) is np.ndarray
            and ranges.dtype == np.float32
            and ranges.ndim == 2
            and ranges.flags.c_contiguous
        )
        if angles is self._angles_src and lidar and ranges.shape[1] == angles.shape[0]:
            return ranges
        rb = self._driver_input(ranges, angles, True)  # checked in full (the first call validates the layout)
        # (the float32 array itself once checked: the env's first step does not compile a float64 entry too)
        return ranges if lidar and angles is self._angles_src else rb

    def _driver_input(self, ranges, angles, trusted: bool) -> np.ndarray:
        """Checked ranges as the driver takes them (C-contiguous float64, one compiled signature)."""
        rb, _ = self._check(ranges, angles, trusted)
        return np.ascontiguousarray(rb, dtype=np.float64)

    def _call_driver(self, kernel, rb: np.ndarray, cascade: bool, *extra):
        """``kernel`` (:func:`~detectors._learned_driver.fused_table` or
        :func:`~detectors._learned_driver.fused_packed`) on ``rb`` with this detector's arguments (the
        cascade if ``cascade``): its outputs, or None when the network does not run compiled
        (inference ``"blas"`` / ``"torch"``: then :meth:`_run_driver`)."""
        if not self._network_compiled:
            return None
        front_args, back_args = self._driver_consts(cascade)
        mean, std, w, b, sizes = self._numba_weights
        n_feat = int(front_args[17])
        ws = _driver_work(rb.shape[0] * rb.shape[1], n_feat)
        res = kernel(rb, front_args, _DRIVER_ROWS_MAX, mean, std, w, self._numba_weights_t[2], b, sizes,
                     back_args, *extra, ws)  # fmt: skip
        _grow_driver_rows(ws, n_feat)
        return res

    def _run_driver(self, rb: np.ndarray):
        """The driver's two kernels with the network in between in Python (BLAS or torch
        inference): ``(front outputs, back outputs)`` for :func:`~detectors._learned_driver.pack`."""
        front_args, back_args = self._driver_consts(self.cascade)
        fr = _drv.front(rb, *front_args, False)
        return fr, _drv.back_rest(self._forward(fr[10]), fr, back_args)

    def _detect_arrays_staged(self, ranges, angles, trusted: bool = False) -> BatchDetections:
        """:meth:`detect_arrays` through the staged Python pipeline (:meth:`_predict`): the readable
        reference of the fused driver (tests compare the two bit for bit). Without candidate windows
        (their Python reference is ``scripts/experiment_split_windows.py``'s ``split_detector``)."""
        if self.windows:
            raise ValueError(
                "LearnedKinDetector: the staged pipeline has no candidate windows (use windows=False)"
            )
        batch, _, p, centres, thr, max_beams, score = self._predict(
            ranges, angles, all_centres=False, trusted=trusted
        )
        acc = p >= thr
        idx = np.flatnonzero(acc)
        xs, ys = centres[idx, 0], centres[idx, 1]
        dup = None
        if self.suppress_duplicates and idx.size > 1:
            d = np.full(idx.size, -1, np.int64)
            _duplicates_kernel(batch.scan[idx], xs, ys, p[idx], self._dup_radius, d)
            drop = d >= 0
            if drop.any():  # rare: the dropped segments get stage "learned" and the kept one's index
                acc[idx[drop]] = False
                dup = np.full(p.shape[0], -1, np.int64)
                dup[idx[drop]] = idx[d[drop]]
                keep = ~drop
                idx, xs, ys = idx[keep], xs[keep], ys[keep]
        first, count = batch.first[idx], batch.count[idx]
        n = batch.angles.shape[0]
        values = {"p_kin": p, "threshold": np.asarray(thr, dtype=np.float64)}
        if max_beams is not None:
            values["max_beams"] = max_beams
        if score is not None:
            values["cascade_score"] = score
        if dup is not None:
            values["duplicate_of"] = dup
        return BatchDetections(
            n_scans=batch.ranges.shape[0],
            n_beams=n,
            scan=batch.scan[idx],
            range=np.hypot(xs, ys),
            bearing=wrap_angle(np.arctan2(ys, xs)),
            x=xs,
            y=ys,
            score=p[idx],
            first_beam=first,
            last_beam=(first + count - 1) % n,
            n_beams_on=count,
            segment=idx,
            seg_scan=batch.scan,
            seg_first=batch.first,
            seg_count=batch.count,
            seg_prev=batch.prev_beam,
            seg_next=batch.next_beam,
            seg_prev_nearer=batch.prev_nearer,
            seg_next_nearer=batch.next_nearer,
            seg_stage=self._stages(acc, batch.count, max_beams),
            seg_values=values,
        )

    @staticmethod
    def _seg_values(p, thr, max_beams, score) -> dict[str, np.ndarray]:
        values = {"p_kin": p, "threshold": np.asarray(thr, dtype=np.float64)}
        if max_beams is not None:
            values["max_beams"] = max_beams
        if score is not None:
            values["cascade_score"] = score
        return values

    @staticmethod
    def _stages(acc: np.ndarray, count: np.ndarray, max_beams) -> np.ndarray:
        stage = np.where(acc, _k.ACCEPTED, _k.LEARNED).astype(np.int8)
        if max_beams is not None:
            stage[count > max_beams] = _k.DIAMETER
        return stage

    def results(self, arrays: BatchDetections, reports: bool | None = None) -> list[DetectionResult]:
        """:class:`DetectionResult` per scan of ``arrays`` (from :meth:`detect_arrays`), with
        per-segment reports if ``reports`` (default: this detector's ``reports``), built on first
        access."""
        reports = self.reports if reports is None else bool(reports)
        dets = arrays.detections()
        if not reports:
            return [DetectionResult(ds, []) for ds in dets]
        build = LazyBatchReports(lambda: self.segment_reports(arrays))
        return [DetectionResult.lazy(ds, build, b) for b, ds in enumerate(dets)]

    def segment_reports(self, arrays: BatchDetections) -> list[list[SegmentReport]]:
        """The :class:`SegmentReport` of every segment of ``arrays``, per scan (stage ``"accepted"``,
        ``"learned"`` (rejected by the classifier) or ``"diameter"`` (dropped by the pre-gate),
        ``metrics`` ``p_kin`` and ``threshold``, plus ``max_beams`` with the pre-gate and
        ``cascade_score`` with the cascade; a segment the cascade dropped is ``"learned"`` with
        ``p_kin`` NaN)."""
        with gc_paused():
            p, thr = arrays.seg_values["p_kin"], arrays.seg_values["threshold"]
            gate = arrays.seg_values.get("max_beams")
            cas = arrays.seg_values.get("cascade_score")
            stage = arrays.seg_stage
            if cas is not None:  # dropped by the cascade: a reason of their own (code -1)
                stage = np.where((stage == _k.LEARNED) & np.isnan(p), -1, stage)
            stl = stage.tolist()
            # the numbers are in metrics["p_kin"]; shared reason strings keep ~100 reports per
            # cluttered scan cheap
            why = {
                t: {
                    _k.LEARNED: f"p(kin) < threshold {t:g}",
                    _k.ACCEPTED: f"p(kin) >= threshold {t:g}",
                    _k.DIAMETER: f"pre-gate: more beams than a {2 * self.feature_config.r:g} m housing "
                    "returns at this range",
                    -1: "cascade: stage-1 score below "
                    f"{self._cascade['threshold'] if self._cascade else math.nan:g}",
                }
                for t in np.unique(thr).tolist()
            }
            tl = thr.tolist()
            metrics = [{"p_kin": v, "threshold": t} for v, t in zip(p.tolist(), tl, strict=True)]
            for name, col in (("max_beams", gate), ("cascade_score", cas)):
                if col is not None:
                    for m, v in zip(metrics, col.tolist(), strict=True):
                        m[name] = v
            reasons = [why[t][st] for t, st in zip(tl, stl, strict=True)]
            dup = arrays.seg_values.get("duplicate_of")
            if dup is not None:
                for j in np.flatnonzero(dup >= 0).tolist():  # a few per scan at most
                    reasons[j] = (f"duplicate: centre within {2 * self.feature_config.r:g} m of segment "
                                  f"{int(dup[j])}'s detection, which scores higher")  # fmt: skip
            reps = list(
                map(
                    SegmentReport,
                    arrays.segments(),
                    [STAGES[st] if st >= 0 else "learned" for st in stl],
                    reasons,
                    metrics,
                )
            )
            bounds = np.searchsorted(arrays.seg_scan, np.arange(arrays.n_scans + 1)).tolist()
            return [reps[bounds[b] : bounds[b + 1]] for b in range(arrays.n_scans)]

    def detect(self, ranges, angles) -> DetectionResult:
        """Detect kins in one scan: ``ranges`` (n,) m, ``angles`` (n,) rad."""
        r = np.asarray(ranges, dtype=np.float64)
        if r.ndim != 1:
            raise ValueError(f"ranges must be a 1-D array (n_beams,), got shape {r.shape}")
        a = np.asarray(angles, dtype=np.float64)
        if a.ndim != 1 or a.shape != r.shape or (r < 0.0).any():
            validate_scan(r, a)  # raises with the full message
        return self.detect_batch(r[None, :], a)[0]

    def detect_batch(self, ranges, angles) -> list[DetectionResult]:
        """Detect kins in ``B`` scans (``ranges`` (B, n) m, shared ``angles`` (n,) rad): the objects of
        :meth:`detect_arrays`, one :class:`DetectionResult` per scan."""
        return self.results(self.detect_arrays(ranges, angles))


def _merged(src: np.ndarray, idx: np.ndarray, seg: np.ndarray, win: np.ndarray) -> np.ndarray:
    """Rows of ``seg`` (``src == 0``) and ``win`` (``src == 1``) in the order of
    :func:`~detectors._learned_driver.window_merge`."""
    out = np.empty((src.shape[0], *seg.shape[1:]), dtype=seg.dtype)
    w = src == 1
    out[~w] = seg[idx[~w]]
    out[w] = win[idx[w]]
    return np.ascontiguousarray(out)


def _blas_forward(x: np.ndarray, layers) -> np.ndarray:
    """``(S, 3)`` float64 outputs: float32 matrix products in row chunks, BLAS on one thread."""
    out = np.empty((x.shape[0], layers[-1][0].shape[1]))
    last = len(layers) - 1
    with _one_blas_thread():
        for s in range(0, x.shape[0], _BLAS_CHUNK):
            h = x[s : s + _BLAS_CHUNK]
            for i, (w, b) in enumerate(layers):
                h = h @ w
                h += b
                if i < last:
                    np.maximum(h, 0.0, out=h)
            out[s : s + h.shape[0]] = h
    return out


_BLAS = {"libs": None, "loaded": False, "depth": 0, "saved": []}
_BLAS_LOCK = threading.Lock()


def _blas_controller():
    """threadpoolctl's controllers of the loaded BLAS libraries (found once), or None without
    threadpoolctl."""
    if not _BLAS["loaded"]:
        with _BLAS_LOCK:
            if not _BLAS["loaded"]:
                try:
                    from threadpoolctl import ThreadpoolController
                except ImportError:
                    libs = None
                else:
                    libs = ThreadpoolController().select(user_api="blas").lib_controllers
                _BLAS["libs"], _BLAS["loaded"] = libs, True
    return _BLAS["libs"]


@contextlib.contextmanager
def _one_blas_thread():
    """BLAS on one thread inside the block, the caller's thread counts restored afterwards.

    Matrix products of a few thousand 64-wide rows gain nothing from a second thread, and on a
    busy 2-core machine OpenBLAS's default of one thread per core made them ~8x slower (25 ms
    instead of 3 for a 64-robot batch). Nested and concurrent calls (threads) share one limit,
    set by the first to enter and restored by the last to leave. The library controllers are
    called directly: ``ThreadpoolController.limit`` costs ~25 us a call, this ~2 us.
    """
    libs = _blas_controller()
    with _BLAS_LOCK:
        if _BLAS["depth"] == 0:
            saved = []
            for lib in libs:
                n = lib.get_num_threads()
                if n != 1:
                    lib.set_num_threads(1)
                    saved.append((lib, n))
            _BLAS["saved"] = saved
        _BLAS["depth"] += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS["depth"] -= 1
            if _BLAS["depth"] == 0:
                for lib, n in _BLAS["saved"]:
                    lib.set_num_threads(n)
                _BLAS["saved"] = []


# --------------------------------------------------------------------------- training


@dataclass(frozen=True)
class TrainConfig:
    """Training of :class:`SegmentNet` (AdamW, BCE + smooth-L1 centre loss on kin segments).

    Attributes:
        hidden: hidden layer widths.
        epochs: maximum epochs.
        batch_size: segments per step.
        lr: peak AdamW learning rate of a one-cycle schedule over ``epochs``.
        weight_decay: AdamW weight decay.
        reg_weight: weight of the centre-regression loss.
        patience: stop after this many epochs without a better validation loss.
        max_seconds: stop after this much training time (0 = no limit).
        pos_weight: loss weight of kin segments (:func:`sample_weights`).
        hard_weight: loss weight of the hard negatives, kin-width prisms and cuboids (a 7 cm
            hexagon deviates from the housing's circle by <= 4.7 mm, about one beam's noise at 1 %).
    """

    hidden: tuple[int, ...] = (64, 64)
    epochs: int = 40
    batch_size: int = 1024
    lr: float = 3e-3
    weight_decay: float = 1e-4
    reg_weight: float = 0.5
    patience: int = 5
    max_seconds: float = 0.0
    pos_weight: float = 1.0
    hard_weight: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(self.hidden))
        for name in ("epochs", "batch_size", "patience"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"TrainConfig.{name} must be an integer >= 1, got {v!r}")
        for name in ("lr", "weight_decay", "reg_weight", "max_seconds", "pos_weight", "hard_weight"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ValueError(f"TrainConfig.{name} must be a finite number >= 0, got {v!r}")
        if self.lr <= 0 or self.pos_weight <= 0 or self.hard_weight <= 0:
            raise ValueError(
                f"TrainConfig.lr, pos_weight and hard_weight must be > 0, got {self.lr!r}, "
                f"{self.pos_weight!r}, {self.hard_weight!r}"
            )
        ModelConfig(1, self.hidden)  # validates hidden

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["hidden"] = list(self.hidden)
        return d

    @classmethod
    def from_dict(cls, d) -> TrainConfig:
        return config_from_dict(cls, d)


#: negatives weighted by TrainConfig.hard_weight (detectors.samples.CATEGORIES names)
HARD_CATEGORIES = ("kin_width_prism", "kin_width_box")


def sample_weights(labels, categories, config: TrainConfig) -> np.ndarray:
    """Per-segment loss weights: ``pos_weight`` for kin, ``hard_weight`` for the
    :data:`HARD_CATEGORIES` negatives, 1 otherwise (``categories``: codes into
    :data:`detectors.samples.CATEGORIES`)."""
    from .samples import CATEGORIES

    y = np.asarray(labels).reshape(-1) > 0
    hard = np.isin(np.asarray(categories), [CATEGORIES.index(c) for c in HARD_CATEGORIES]) & ~y
    w = np.ones(y.shape[0], dtype=np.float32)
    w[y] = config.pos_weight
    w[hard] = config.hard_weight
    return w
