"""The learned kin detector's torch parts: its network, checkpoints (``.pt``), training, torch inference.

:mod:`detectors.learned` runs the detector without torch (the checkpoint's torch-free ``.npz`` form, the
network compiled or in numpy); this module, the learned detector's only one that imports torch (the
``train`` extra; the beam detector's training, :mod:`detectors.beam_training`, is the other), holds what
needs it:

* :class:`SegmentNet`, the MLP, and :func:`train_segment_net`, its training loop;
* :func:`save_checkpoint` / :func:`load_checkpoint`: the training format (``torch.save``), with the
  torch-free form written beside it (:func:`detectors.learned.write_npz_checkpoint`) on every save, and
  :func:`export_checkpoint` for a ``.pt`` written before that (``scripts/export_checkpoint.py``);
* :func:`forward`: ``LearnedKinDetector(inference="torch")``'s forward pass.

Its public names are also importable from :mod:`detectors.learned` (imported here on first use).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import math
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .features import FEATURE_VERSION, FeatureConfig, feature_names
from .fileio import atomic_write
from .learned import (
    _CHUNK,
    CHECKPOINT_FORMAT,
    CHECKPOINT_FORMAT_VERSION,
    DEFAULT_CHECKPOINT,
    POSITIONING,
    ModelConfig,
    TrainConfig,
    _check_versions,
    _check_weights,
    _checked_configs,
    _checked_operating_point,
    _CorruptWeights,
    _plain,
    check_thresholds,
    load_npz_checkpoint,
    npz_path,
    weights_digest,
    write_npz_checkpoint,
)

__all__ = [
    "SegmentNet",
    "export_checkpoint",
    "forward",
    "load_checkpoint",
    "load_checkpoint_arrays",
    "model_from_checkpoint",
    "save_checkpoint",
    "train_segment_net",
]

# --------------------------------------------------------------------------- model


class SegmentNet(nn.Module):
    """MLP on standardised segment features → ``(logit of p(kin), u, v)``.

    ``u, v`` is the kin centre in the segment's local frame (:mod:`detectors.features`), in units
    of the training targets' spread (``target_mean + target_std * output``). Normalisation stats
    are buffers set from the checkpoint, not learned.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        d = config.n_features
        for h in config.hidden:
            layers += [nn.Linear(d, h), nn.ReLU()]
            d = h
        self.body = nn.Sequential(*layers)
        self.head = nn.Linear(d, 3)
        self.register_buffer("x_mean", torch.zeros(config.n_features), persistent=False)
        self.register_buffer("x_std", torch.ones(config.n_features), persistent=False)
        self.register_buffer("t_mean", torch.zeros(2), persistent=False)
        self.register_buffer("t_std", torch.ones(2), persistent=False)

    def set_normalisation(self, x_mean, x_std, t_mean, t_std) -> None:
        for name, v, n in (
            ("x_mean", x_mean, self.config.n_features),
            ("x_std", x_std, self.config.n_features),
            ("t_mean", t_mean, 2),
            ("t_std", t_std, 2),
        ):
            t = torch.as_tensor(np.asarray(v, dtype=np.float32))
            if t.shape != (n,) or not torch.isfinite(t).all() or (name.endswith("std") and (t <= 0).any()):
                raise ValueError(
                    f"SegmentNet: {name} must be {n} finite values (std > 0), got shape {tuple(t.shape)}"
                )
            getattr(self, name).copy_(t)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.body((x - self.x_mean) / self.x_std))

    def normalisation(self) -> dict[str, list[float]]:
        return {k: getattr(self, k).tolist() for k in ("x_mean", "x_std", "t_mean", "t_std")}


# --------------------------------------------------------------------------- checkpoints


def _check_device(device) -> torch.device:
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError) as e:
        raise ValueError(f"device must be a torch device such as 'cpu' or 'cuda', got {device!r}") from e
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={device!r}: this torch build or machine has no CUDA device; use 'cpu'")
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda', got {device!r}")
    return dev


def save_checkpoint(
    path,
    model: SegmentNet,
    feature_config: FeatureConfig,
    *,
    positioning: str = "regression",
    angular_resolution: float = 2 * math.pi / 360,
    thresholds: dict | None = None,
    info: dict | None = None,
) -> Path:
    """Write ``model`` with everything needed to use it (see :func:`load_checkpoint`) to ``path`` (a
    ``.pt``, ``torch.save``), and its torch-free form, what ``LearnedKinDetector`` reads, beside it
    (:func:`detectors.learned.npz_path`: ``<path without .pt>.npz``, the same weights bit for bit, the
    ``.pt``'s SHA-256 recorded). Each file is written atomically (a temporary name, then a rename).

    ``thresholds``: the calibrated ``p(kin)`` thresholds per estimated scan-noise level,
    ``{"noise_edges": [e_1, ..., e_k], "values": [t_0, ..., t_k]}`` (a scan whose noise estimate
    :func:`detectors.features.scan_noise` lies in ``[e_j, e_{j+1})`` uses ``t_j``); default 0.5 for all.
    Optionally also by the beams a housing would return at the segment's range (:func:`expected_beams`):
    ``"beam_edges": [b_1, ..., b_m]`` (increasing) and ``"table"``, ``k + 1`` rows of ``m + 1``
    thresholds (row: noise bin, column: expected-beams bin, ``[b_i, b_{i+1})``); ``"values"`` then
    stays as the per-noise summary that older code reads.
    """
    if positioning not in POSITIONING:
        raise ValueError(f"positioning must be one of {POSITIONING}, got {positioning!r}")
    thresholds = check_thresholds(thresholds)
    names = feature_names(feature_config)
    if model.config.n_features != len(names):
        raise ValueError(
            f"save_checkpoint: model takes {model.config.n_features} features, the feature config gives "
            f"{len(names)}"
        )
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"save_checkpoint: {path} is a directory; expected a file path (e.g. {path}/m.pt)")
    if path.suffix == ".npz":
        raise ValueError(f"save_checkpoint: {path} is the name of the npz form; give the .pt path (the npz "
                         "is written beside it)")  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    bad = [k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        raise ValueError(f"save_checkpoint: parameter(s) {bad} hold NaN or inf; refusing to write {path}")
    nrm = model.normalisation()
    payload = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "feature_config": feature_config.to_dict(),
        "feature_names": names,
        "model_config": model.config.to_dict(),
        "state_dict": state,
        "normalisation": nrm,
        "weights_sha256": weights_digest(state, nrm),
        "positioning": positioning,
        "angular_resolution": float(angular_resolution),
        "thresholds": thresholds,
        "info": _plain(info or {}),
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getvalue()
    with atomic_write(path) as f:  # a crash or Ctrl-C never leaves half a checkpoint under the name
        f.write(data)
    # the npz names the .pt bytes it belongs to: one left from an earlier save (a Ctrl-C between the two
    # writes) is never taken for this one's
    write_npz_checkpoint(npz_path(path), payload, _source(path, data))
    return path


def _source(path: Path, data: bytes) -> dict:
    return {"file": path.name, "sha256": hashlib.sha256(data).hexdigest()}


def export_checkpoint(path=None, out=None) -> Path:
    """Write the torch-free form of the ``.pt`` checkpoint at ``path`` (default: the shipped one) to
    ``out`` (default: beside it, :func:`detectors.learned.npz_path`), for a checkpoint written before
    :func:`save_checkpoint` wrote it (``scripts/export_checkpoint.py``). The ``.pt`` is loaded and
    checked as :func:`load_checkpoint` does; the npz holds the same weights bit for bit (its
    ``weights_sha256`` is the ``.pt``'s, checked on reading it back here) and the ``.pt``'s SHA-256.
    Returns the npz's path."""
    p = Path(DEFAULT_CHECKPOINT if path is None else path)
    out = npz_path(p) if out is None else Path(out)
    if out.suffix != ".npz" or out.resolve() == p.resolve():
        raise ValueError(f"export_checkpoint: the output {out} must be an .npz path other than {p}")
    _, ck = load_checkpoint(p)  # (raises naming the path if it is missing or not a checkpoint)
    write_npz_checkpoint(out, ck, _source(p, p.read_bytes()))
    load_npz_checkpoint(out)  # read back: its arrays match the .pt's weights_sha256
    return out


def load_checkpoint(path=None, device="cpu") -> tuple[SegmentNet, dict]:
    """Load a checkpoint written by :func:`save_checkpoint` → ``(model in eval mode, checkpoint dict)``.

    Raises ``FileNotFoundError`` if there is no file at ``path`` and ``ValueError`` naming the path
    if it is not a torch checkpoint, not a learned-detector checkpoint, of another
    ``FEATURE_VERSION``, or if the weights do not fit the stated input size.
    """
    path = Path(DEFAULT_CHECKPOINT if path is None else path)
    dev = _check_device(device)
    expected = (
        f"expected a learned kin detector checkpoint written by scripts/train_classifier.py "
        f"(format {CHECKPOINT_FORMAT!r}, feature version {FEATURE_VERSION})"
    )
    if path.is_dir():
        raise ValueError(f"learned detector checkpoint {path} is a directory, not a file; {expected}")
    if not path.is_file():
        raise FileNotFoundError(f"learned detector checkpoint {path} does not exist; {expected}")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a file that is not a checkpoint
        raise ValueError(
            f"{path}: not a readable torch checkpoint ({type(e).__name__}: {e}); {expected}"
        ) from e
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a learned kin detector checkpoint; {expected}")
    _check_versions(ck, path, expected)
    try:
        fc, mc = _checked_configs(ck)
        nrm = ck["normalisation"]
        model = SegmentNet(mc)
        model.load_state_dict(ck["state_dict"])
        _check_weights(ck["state_dict"], nrm, ck.get("weights_sha256"))
        model.set_normalisation(nrm["x_mean"], nrm["x_std"], nrm["t_mean"], nrm["t_std"])
        res, thresholds = _checked_operating_point(ck)
    except _CorruptWeights as e:
        raise ValueError(f"{path}: corrupt checkpoint: {e}; refusing to load it") from e
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise ValueError(f"{path}: inconsistent checkpoint ({type(e).__name__}: {e}); {expected}") from e
    ck["feature_config"] = fc
    ck["model_config"] = mc
    ck["angular_resolution"] = res
    ck["thresholds"] = thresholds
    ck["path"] = str(path)
    return model.to(dev).eval(), ck


def load_checkpoint_arrays(path=None) -> dict:
    """:func:`load_checkpoint`'s checkpoint dict with numpy arrays as ``state_dict`` (what
    :func:`detectors.learned.load_inference_checkpoint` returns for a ``.pt`` without its npz)."""
    _, ck = load_checkpoint(path)
    ck["state_dict"] = {k: v.detach().cpu().numpy() for k, v in ck["state_dict"].items()}
    ck["npz"] = None
    return ck


def model_from_checkpoint(ck: dict, device="cpu") -> SegmentNet:
    """The :class:`SegmentNet` (eval mode, on ``device``) of a checkpoint dict with numpy or torch
    parameters (:func:`detectors.learned.load_inference_checkpoint`, :func:`load_checkpoint`): the same
    weights bit for bit."""
    dev = _check_device(device)
    model = SegmentNet(ck["model_config"])
    model.load_state_dict({k: torch.as_tensor(np.array(v)) for k, v in ck["state_dict"].items()})
    nrm = ck["normalisation"]
    model.set_normalisation(nrm["x_mean"], nrm["x_std"], nrm["t_mean"], nrm["t_std"])
    return model.to(dev).eval()


@contextlib.contextmanager
def _torch_threads(n: int):
    """Run torch ops on ``n`` intra-op threads, restoring the caller's setting afterwards.

    The network is tiny: on a busy machine each extra thread only adds contention (2 threads on a
    shared 2-core machine made a forward pass 10-30x slower than 1).
    """
    prev = torch.get_num_threads()
    if prev != n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if prev != n:
            torch.set_num_threads(prev)


def forward(model: SegmentNet, x: np.ndarray, device, threads: int) -> np.ndarray:
    """``(S, 3)`` float64 outputs of ``model`` for ``(S, F)`` float32 features, on ``device`` and
    ``threads`` torch threads (the caller's setting restored afterwards)."""
    with torch.inference_mode(), _torch_threads(threads):
        xt = torch.from_numpy(x).to(device)
        # row chunks keep the activations in cache (2x faster than one 26k-row chain)
        return torch.cat([model(c) for c in xt.split(_CHUNK)]).cpu().numpy().astype(np.float64)


# --------------------------------------------------------------------------- training


def _losses(model: SegmentNet, x, y, t, tm, reg_weight: float, w=None):
    out = model(x)
    if w is None:
        bce = nn.functional.binary_cross_entropy_with_logits(out[:, 0], y)
    else:
        bce = (
            nn.functional.binary_cross_entropy_with_logits(out[:, 0], y, reduction="none") * w
        ).sum() / w.sum()
    if tm.any():
        tn = (t[tm] - model.t_mean) / model.t_std
        reg = nn.functional.smooth_l1_loss(out[tm, 1:3], tn)
    else:
        reg = out.new_zeros(())
    return bce, reg, out


def train_segment_net(
    train: dict[str, np.ndarray],
    val: dict[str, np.ndarray],
    config: TrainConfig | None = None,
    seed: int = 0,
    log=None,
    progress: bool = True,
) -> tuple[SegmentNet, list[dict]]:
    """Train a :class:`SegmentNet`.

    Args:
        train, val: ``x`` (N, F) float32 features, ``y`` (N,) 0/1 labels, ``target`` (N, 2) kin
            centre in the local frame (NaN for non-kin; those rows get no centre loss); optional
            ``weight`` (N,) per-segment classification loss weights (:func:`sample_weights`).
        config: hyper-parameters.
        seed: seeds torch (initialisation, shuffling).
        log: called with each epoch's record (dict) as it completes.
        progress: tqdm progress bars.

    Returns the model with the weights of the best validation epoch (eval mode) and the per-epoch
    records: ``epoch, train_loss, train_bce, train_reg, val_loss, val_bce, val_reg, val_accuracy,
    val_f1, seconds``.
    """
    from tqdm import tqdm

    cfg = config or TrainConfig()
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)

    def tensors(d, name):
        x = np.asarray(d["x"], dtype=np.float32)
        y = np.asarray(d["y"], dtype=np.float32).reshape(-1)
        t = np.asarray(d["target"], dtype=np.float32).reshape(-1, 2)
        if x.ndim != 2 or x.shape[0] != y.shape[0] or t.shape[0] != y.shape[0] or x.shape[0] == 0:
            raise ValueError(
                f"train_segment_net: {name} needs x (N, F), y (N,), target (N, 2) with N >= 1, got "
                f"{x.shape}, {y.shape}, {t.shape}"
            )
        if not np.isfinite(x).all():
            raise ValueError(f"train_segment_net: {name} features contain non-finite values")
        tm = np.isfinite(t).all(axis=1) & (y > 0.5)
        w = d.get("weight")
        if w is not None:
            w = np.asarray(w, dtype=np.float32).reshape(-1)
            if w.shape != y.shape or not (np.isfinite(w).all() and (w > 0).all()):
                raise ValueError(f"train_segment_net: {name} weight must be (N,) finite values > 0")
            w = torch.from_numpy(w)
        return (
            torch.from_numpy(x),
            torch.from_numpy(y),
            torch.from_numpy(np.nan_to_num(t)),
            torch.from_numpy(tm),
            w,
        )

    xt, yt, tt, mt, wt = tensors(train, "train")
    xv, yv, tv, mv, wv = tensors(val, "val")
    if xv.shape[1] != xt.shape[1]:
        raise ValueError(f"train_segment_net: train has {xt.shape[1]} features, val {xv.shape[1]}")
    if cfg.batch_size > xt.shape[0]:
        # one step per epoch on less than a batch: almost surely a config meant for another dataset
        raise ValueError(
            f"train_segment_net: TrainConfig.batch_size={cfg.batch_size} is larger than the "
            f"{xt.shape[0]} training segments; use batch_size <= {xt.shape[0]} or more data"
        )
    model = SegmentNet(ModelConfig(int(xt.shape[1]), cfg.hidden))
    x_mean, x_std = xt.mean(0), xt.std(0)
    x_std = torch.where(x_std > 1e-6, x_std, torch.ones_like(x_std))  # constant features pass through
    if mt.any():
        t_mean, t_std = tt[mt].mean(0), tt[mt].std(0).clamp_min(1e-3)
    else:
        t_mean, t_std = torch.zeros(2), torch.ones(2)
    model.set_normalisation(x_mean, x_std, t_mean, t_std)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = math.ceil(xt.shape[0] / cfg.batch_size)
    total_steps = cfg.epochs * steps_per_epoch
    # OneCycleLR divides by pct_start * total_steps - 1: 0.1 x 10 steps is a ZeroDivisionError
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=cfg.lr, total_steps=total_steps, pct_start=0.1 if total_steps != 10 else 0.2,
        final_div_factor=20,
    )  # fmt: skip
    best, best_state, bad_epochs, history = math.inf, None, 0, []
    t0 = time.perf_counter()
    epochs = tqdm(range(1, cfg.epochs + 1), desc="epochs", disable=not progress)
    for epoch in epochs:
        model.train()
        perm = torch.randperm(xt.shape[0], generator=gen)
        sums = np.zeros(3)
        for k in tqdm(range(steps_per_epoch), desc=f"epoch {epoch}", leave=False, disable=not progress):
            i = perm[k * cfg.batch_size : (k + 1) * cfg.batch_size]
            bce, reg, _ = _losses(
                model, xt[i], yt[i], tt[i], mt[i], cfg.reg_weight, None if wt is None else wt[i]
            )
            loss = bce + cfg.reg_weight * reg
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            sums += (loss.item(), bce.item(), reg.item())
        model.eval()
        with torch.inference_mode():
            vb, vr, out = _losses(model, xv, yv, tv, mv, cfg.reg_weight, wv)
            pred = out[:, 0] > 0
            tp = float((pred & (yv > 0.5)).sum())
            fp = float((pred & (yv < 0.5)).sum())
            fn = float((~pred & (yv > 0.5)).sum())
        vloss = float(vb) + cfg.reg_weight * float(vr)
        rec = {
            "epoch": epoch,
            "train_loss": sums[0] / steps_per_epoch,
            "train_bce": sums[1] / steps_per_epoch,
            "train_reg": sums[2] / steps_per_epoch,
            "val_loss": vloss,
            "val_bce": float(vb),
            "val_reg": float(vr),
            "val_accuracy": float((pred == (yv > 0.5)).float().mean()),
            "val_f1": 2 * tp / max(2 * tp + fp + fn, 1.0),
            "seconds": time.perf_counter() - t0,
        }
        history.append(rec)
        if log is not None:
            log(rec)
        epochs.set_postfix(val_loss=f"{vloss:.4f}", val_f1=f"{rec['val_f1']:.4f}")
        if vloss < best - 1e-5:
            best, bad_epochs = vloss, 0
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        else:
            bad_epochs += 1
        if bad_epochs >= cfg.patience or (cfg.max_seconds and rec["seconds"] > cfg.max_seconds):
            break
    if best_state is not None:
        model.load_state_dict(best_state)
    return model.eval(), history
