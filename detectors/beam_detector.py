"""Beam kin detector: a per-beam network over a window of neighbouring beams, with centre voting.

A DROW-style detector (Beyer et al., "DROW: Real-Time Deep Learning based Wheelchair Detection in 2D
Range Data", 2017; Jia et al., "DR-SPAAM", 2020) sized for a 7 cm lidar housing. It does **not** depend
on the paper's segmentation being right: no ``d_th`` jump rule decides which beams belong together, so a
kin touching a wall or another robot, partly occluded, or seen by two beams is still looked at beam by
beam.

1. **Cut-out** (:func:`beam_inputs`): for every valid beam ``i`` (0.0, NaN, inf and readings at or
   beyond ``d_max`` are no return), the range differences ``r[i+j] - r[i]`` of its ``half_window``
   neighbours on each side, squashed by ``asinh(d / 1 cm)`` (millimetre detail near 0, walls and
   no-return neighbours saturate); the signed curvature of the circles through nearby returns at a
   few beam spacings, in units of the housing's (a kin reads +1 at every spacing, a prism face 0, its
   corners large); ``r[i]``, ``log r[i]``; and the scan's relative range noise estimated from the
   second differences of all its smooth runs (residuals mean nothing without it). DROW normalises its
   cut-outs to a fixed metric window instead; a fixed beam window plus the range keeps the actual
   points (no resampling) and lets the network learn how a 7 cm circle looks at each distance.
2. **Per-beam network** (numpy, no torch at inference): a ReLU MLP gives ``p(beam hits a kin)`` and
   the kin's centre as an offset from the beam's return, in the beam's frame (along / across).
3. **Voting and grouping** (:func:`group_votes`, numba): consecutive beams with ``p >= vote_threshold``
   whose predicted centres lie within ``group_radius`` of their group's running mean are one
   detection (a one-beam gap is bridged); the centre is the ``p``-weighted mean of the votes and the
   score the mean ``p`` of the group. Groups, not segments: two touching robots vote for two centres
   18 cm apart and come out as two detections. A detection is reported when its score
   ``>= threshold`` (the checkpoint's calibrated value by default).

The checkpoint is an ``.npz`` (weights + a JSON header; :func:`load_beam_checkpoint` refuses a wrong
format, version or weight shape with a ``ValueError`` naming the file). Training code is in
:mod:`detectors.beam_training` (torch); it reads samples (:func:`load_beam_dataset`), never a world.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .base import Detection, DetectionResult, KinDetector, validate_batch, validate_scan
from .fileio import atomic_write
from .geometric import is_circular_sweep

__all__ = [
    "BEAM_CHECKPOINT_FORMAT",
    "BEAM_DATASET_FORMAT",
    "DEFAULT_BEAM_CHECKPOINT",
    "BeamConfig",
    "BeamKinDetector",
    "BeamModel",
    "beam_inputs",
    "group_votes",
    "load_beam_checkpoint",
    "load_beam_dataset",
    "save_beam_checkpoint",
]

BEAM_CHECKPOINT_FORMAT = "kin-envs/beam-kin-detector"
BEAM_CHECKPOINT_VERSION = 1
BEAM_DATASET_FORMAT = "kin-envs/beam-dataset"
#: The shipped model (``scripts/train_beam_detector.py --install``).
DEFAULT_BEAM_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "beam_default.npz"
_SQUASH = 0.01  # m: asinh scale of the range differences
_OFFSET_SCALE = 0.05  # m: unit of the regressed centre offset


@dataclass(frozen=True)
class BeamConfig:
    """Shape and post-processing of a beam detector (stored in its checkpoint).

    Attributes:
        half_window: neighbouring beams on each side in the cut-out.
        curvature_offsets, curvature_scales: signed curvature of the circle through the returns
            ``i+o-s, i+o, i+o+s`` for ``|o| <= curvature_offsets``, ``1 <= s <= curvature_scales``.
        hidden: ReLU hidden layer widths.
        d_max: readings at or beyond this are no return, m.
        vote_threshold: beams with ``p >= vote_threshold`` vote for a centre.
        group_radius: a vote joins a group if within this of the group's mean centre, m.
        max_gap: beams below ``vote_threshold`` bridged inside a group.
        min_votes: groups with fewer voting beams are dropped (the benchmark's ground truth needs 2
            valid beams on a kin; one beam says nothing about shape).
    """

    half_window: int = 8
    curvature_offsets: int = 2
    curvature_scales: int = 3
    hidden: tuple[int, ...] = (64, 32)
    d_max: float = 12.0
    vote_threshold: float = 0.3
    group_radius: float = 0.06
    max_gap: int = 1
    min_votes: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(self.hidden))
        if (
            isinstance(self.half_window, bool)
            or not isinstance(self.half_window, int)
            or self.half_window < 1
        ):
            raise ValueError(f"BeamConfig.half_window must be an int >= 1, got {self.half_window!r}")
        for name in ("curvature_offsets", "curvature_scales"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"BeamConfig.{name} must be an int >= 0, got {v!r}")
        if not self.hidden or not all(
            isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in self.hidden
        ):
            raise ValueError(f"BeamConfig.hidden must be one or more ints >= 1, got {self.hidden!r}")
        if not (math.isfinite(self.d_max) and self.d_max > 0):
            raise ValueError(f"BeamConfig.d_max must be a finite distance > 0 m, got {self.d_max!r}")
        if not 0.0 <= self.vote_threshold <= 1.0:
            raise ValueError(f"BeamConfig.vote_threshold must be in [0, 1], got {self.vote_threshold!r}")
        if not self.group_radius > 0:
            raise ValueError(f"BeamConfig.group_radius must be > 0 m, got {self.group_radius!r}")
        for name in ("max_gap", "min_votes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"BeamConfig.{name} must be an int >= 0, got {v!r}")

    @property
    def n_inputs(self) -> int:
        return 2 * self.half_window + (2 * self.curvature_offsets + 1) * self.curvature_scales + 3

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["hidden"] = list(self.hidden)
        return d

    @classmethod
    def from_dict(cls, d) -> BeamConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict):
            raise ValueError(f"BeamConfig: expected a dict, got {type(d).__name__}")
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"BeamConfig: unknown key(s) {unknown}; expected a subset of {sorted(names)}")
        return cls(**{k: tuple(v) if k == "hidden" else v for k, v in d.items()})


# --------------------------------------------------------------------------- cut-outs


@numba.njit(cache=True)
def _curvature(px, py, ok, i, j, k):
    """Signed curvature of the circle through points i, j, k, in units of the housing's (1 / 3.5 cm),
    clipped to +-3; 0 when a point has no return."""
    if not (ok[i] and ok[j] and ok[k]):
        return 0.0
    ax, ay = px[j] - px[i], py[j] - py[i]
    bx, by = px[k] - px[j], py[k] - py[j]
    cx, cy = px[k] - px[i], py[k] - py[i]
    den = math.sqrt((ax * ax + ay * ay) * (bx * bx + by * by) * (cx * cx + cy * cy))
    if den <= 1e-12:
        return 0.0
    kappa = 2.0 * (ax * by - ay * bx) / den * 0.035
    return min(3.0, max(-3.0, kappa))


@numba.njit(cache=True)
def _scan_noise(r, ok, circular):
    """Relative range noise of one scan from the second differences of smooth runs of beams (MAD)."""
    n = r.shape[0]
    vals = np.empty(n)
    m = 0
    for i in range(n):
        a, b = i - 1, i + 1
        if circular:
            a %= n
            b %= n
        if a < 0 or b >= n or not (ok[a] and ok[i] and ok[b]):
            continue
        if abs(r[a] - r[i]) > 0.05 or abs(r[b] - r[i]) > 0.05:
            continue
        vals[m] = abs(r[a] - 2.0 * r[i] + r[b]) / r[i]
        m += 1
    if m < 5:
        return 0.0
    return np.median(vals[:m]) / (0.6745 * math.sqrt(6.0))


@numba.njit(cache=True)
def _inputs_kernel(r, valid, angles, half, n_off, n_scale, circular, out_x, out_row, out_beam):
    b_n, n = r.shape
    sat = math.asinh(1.0 / _SQUASH)  # a no-return neighbour reads as 1 m farther
    px = np.empty(n)
    py = np.empty(n)
    m = 0
    for b in range(b_n):
        ok = valid[b]
        for i in range(n):
            px[i] = r[b, i] * math.cos(angles[i]) if ok[i] else 0.0
            py[i] = r[b, i] * math.sin(angles[i]) if ok[i] else 0.0
        noise = math.log(_scan_noise(r[b], ok, circular) + 1e-4)
        for i in range(n):
            if not ok[i]:
                continue
            ri = r[b, i]
            c = 0
            for j in range(-half, half + 1):
                if j == 0:
                    continue
                k = i + j
                if circular:
                    k %= n
                if k < 0 or k >= n or not ok[k]:
                    out_x[m, c] = sat
                else:
                    out_x[m, c] = math.asinh((r[b, k] - ri) / _SQUASH)
                c += 1
            # curvature of the returns around the beam, at several spacings (a kin: +1 at every one)
            for o in range(-n_off, n_off + 1):
                for s in range(1, n_scale + 1):
                    i0, i1, i2 = i + o - s, i + o, i + o + s
                    if circular:
                        i0, i1, i2 = i0 % n, i1 % n, i2 % n
                    if i0 < 0 or i2 >= n or i1 < 0 or i1 >= n or i0 >= n or i2 < 0:
                        out_x[m, c] = 0.0
                    else:
                        out_x[m, c] = _curvature(px, py, ok, i0, i1, i2)
                    c += 1
            out_x[m, c] = ri
            out_x[m, c + 1] = math.log(ri)
            out_x[m, c + 2] = noise
            out_row[m] = b
            out_beam[m] = i
            m += 1
    return m


def _valid(ranges: np.ndarray, d_max: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.isfinite(ranges) & (ranges > 0.0) & (ranges < d_max)


def beam_inputs(ranges, angles, config: BeamConfig | None = None, circular: bool = True):
    """Cut-outs of every valid beam of ``ranges (B, n)`` → ``(x (M, n_inputs) float32, row (M,), beam (M,))``.

    0.0, NaN, inf and readings ``>= d_max`` are no return (no cut-out; as a neighbour they saturate).
    """
    c = config or BeamConfig()
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if r.ndim != 2 or a.shape != (r.shape[1],):
        raise ValueError(
            f"beam_inputs: ranges must be (B, n_beams) and angles (n_beams,), got {r.shape}, {a.shape}"
        )
    valid = _valid(r, c.d_max)
    total = int(valid.sum())
    x = np.empty((total, c.n_inputs), np.float32)
    row = np.empty(total, np.int64)
    beam = np.empty(total, np.int64)
    _inputs_kernel(
        r, valid, a, c.half_window, c.curvature_offsets, c.curvature_scales, bool(circular), x, row, beam
    )
    return x, row, beam


# --------------------------------------------------------------------------- model


class BeamModel:
    """The per-beam MLP in numpy: ``forward(x) -> (logit (M,), offset (M, 2) in m, beam frame)``.

    ``weights``: ``[(W (in, out), b (out,)), ...]`` float32, last layer with 3 outputs; ``x_mean``,
    ``x_std``: input standardisation.
    """

    def __init__(self, config: BeamConfig, weights, x_mean, x_std) -> None:
        self.config = config
        dims = [config.n_inputs, *config.hidden, 3]
        if len(weights) != len(dims) - 1:
            raise ValueError(f"BeamModel: expected {len(dims) - 1} layers for {config}, got {len(weights)}")
        self.weights = []
        for k, (w, b) in enumerate(weights):
            w = np.ascontiguousarray(w, dtype=np.float32)
            b = np.ascontiguousarray(b, dtype=np.float32)
            if w.shape != (dims[k], dims[k + 1]) or b.shape != (dims[k + 1],):
                raise ValueError(
                    f"BeamModel: layer {k} must have W {(dims[k], dims[k + 1])} and b {(dims[k + 1],)}, "
                    f"got {w.shape} and {b.shape}"
                )
            if not (np.isfinite(w).all() and np.isfinite(b).all()):
                raise ValueError(f"BeamModel: layer {k} has non-finite weights")
            self.weights.append((w, b))
        self.x_mean = np.asarray(x_mean, np.float32).reshape(-1)
        self.x_std = np.asarray(x_std, np.float32).reshape(-1)
        if (
            self.x_mean.shape != (config.n_inputs,)
            or self.x_std.shape != (config.n_inputs,)
            or (not (self.x_std > 0).all())
        ):
            raise ValueError(
                f"BeamModel: x_mean / x_std must be {config.n_inputs} values (std > 0), got "
                f"{self.x_mean.shape} / {self.x_std.shape}"
            )
        # fold the standardisation into the first layer: one matmul less per batch
        w0, b0 = self.weights[0]
        self._w0 = (w0 / self.x_std[:, None]).astype(np.float32)
        self._b0 = (b0 - (self.x_mean / self.x_std) @ w0).astype(np.float32)

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = x @ self._w0
        h += self._b0
        np.maximum(h, 0.0, out=h)
        for w, b in self.weights[1:-1]:
            h = h @ w
            h += b
            np.maximum(h, 0.0, out=h)
        w, b = self.weights[-1]
        out = h @ w
        out += b
        return out[:, 0], out[:, 1:] * _OFFSET_SCALE


def _digest(model: BeamModel) -> str:
    """SHA-256 over every weight array (shape, bytes) and the input statistics, checked on load."""
    h = hashlib.sha256()
    for k, (w, b) in enumerate(model.weights):
        for name, a in ((f"W{k}", w), (f"b{k}", b)):
            h.update(f"{name}|{a.shape}|".encode())
            h.update(np.ascontiguousarray(a, np.float32).tobytes())
    for a in (model.x_mean, model.x_std):
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    return h.hexdigest()


def save_beam_checkpoint(path, model: BeamModel, *, threshold: float, info: dict | None = None) -> Path:
    """Write ``model`` and its reporting ``threshold`` as an ``.npz`` (atomically)."""
    if not (isinstance(threshold, int | float) and 0.0 <= threshold <= 1.0):
        raise ValueError(f"save_beam_checkpoint: threshold must be in [0, 1], got {threshold!r}")
    header = {
        "format": BEAM_CHECKPOINT_FORMAT,
        "format_version": BEAM_CHECKPOINT_VERSION,
        "config": model.config.to_dict(),
        "threshold": float(threshold),
        "weights_sha256": _digest(model),
        "info": json.loads(
            json.dumps(info or {}, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
        ),
    }
    arrays = {"header": np.frombuffer(json.dumps(header).encode(), np.uint8)}
    for k, (w, b) in enumerate(model.weights):
        arrays[f"W{k}"], arrays[f"b{k}"] = w, b
    arrays["x_mean"], arrays["x_std"] = model.x_mean, model.x_std
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as f:
        np.savez_compressed(f, **arrays)
    return path


def load_beam_checkpoint(path=None) -> tuple[BeamModel, dict]:
    """Load a checkpoint written by :func:`save_beam_checkpoint` → ``(model, header)``.

    ``FileNotFoundError`` if there is no file; ``ValueError`` naming the file if it is not a beam
    detector checkpoint, is of another format version, or its weights do not fit its config.
    """
    path = Path(DEFAULT_BEAM_CHECKPOINT if path is None else path)
    expected = (
        f"expected a beam kin detector checkpoint written by scripts/train_beam_detector.py "
        f"(format {BEAM_CHECKPOINT_FORMAT!r} version {BEAM_CHECKPOINT_VERSION})"
    )
    if not path.is_file():
        raise FileNotFoundError(f"beam detector checkpoint {path} does not exist; {expected}")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        header = json.loads(arrays.pop("header").tobytes().decode())
    except Exception as e:  # not an npz, or no / broken header
        raise ValueError(
            f"{path}: not a readable beam detector checkpoint ({type(e).__name__}: {e}); {expected}"
        ) from e
    if not isinstance(header, dict) or header.get("format") != BEAM_CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a beam kin detector checkpoint; {expected}")
    if header.get("format_version") != BEAM_CHECKPOINT_VERSION:
        raise ValueError(f"{path}: format version {header.get('format_version')!r}; {expected}")
    try:
        config = BeamConfig.from_dict(header["config"])
        n_layers = len(config.hidden) + 1
        weights = [(arrays[f"W{k}"], arrays[f"b{k}"]) for k in range(n_layers)]
        model = BeamModel(config, weights, arrays["x_mean"], arrays["x_std"])
        threshold = float(header["threshold"])
        if not 0.0 <= threshold <= 1.0:
            raise ValueError(f"threshold {threshold} is not in [0, 1]")
        if header.get("weights_sha256") != _digest(model):
            raise ValueError("the weights do not match their stored SHA-256 (corrupt file)")
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: inconsistent checkpoint ({type(e).__name__}: {e}); {expected}") from e
    header["path"] = str(path)
    return model, header


# --------------------------------------------------------------------------- voting


@numba.njit(cache=True)
def _group_kernel(p, cx, cy, vote, radius, max_gap, circular, out_row, out_f, out_i):
    """Per scan, groups of consecutive voting beams (see the module docstring). Returns the count."""
    b_n, n = p.shape
    m = 0
    for b in range(b_n):
        start = 0
        if circular:  # start after a non-voting beam so no group straddles the seam
            for i in range(n):
                if p[b, i] < vote:
                    start = (i + 1) % n
                    break
        open_ = False
        sw = swx = swy = sp = 0.0
        cnt = first = last = gap = 0
        for k in range(n + 1):
            close = k == n
            i = (start + k) % n
            if not close:
                pi = p[b, i]
                if pi >= vote:
                    if open_:
                        mx, my = swx / sw, swy / sw
                        if (cx[b, i] - mx) ** 2 + (cy[b, i] - my) ** 2 <= radius * radius:
                            sw += pi
                            swx += pi * cx[b, i]
                            swy += pi * cy[b, i]
                            sp += pi
                            cnt += 1
                            last = i
                            gap = 0
                            continue
                        close = True  # a different object's votes: close this group, open a new one
                    else:
                        open_ = True
                        sw, swx, swy, sp = pi, pi * cx[b, i], pi * cy[b, i], pi
                        cnt, first, last, gap = 1, i, i, 0
                        continue
                elif open_:
                    gap += 1
                    if gap <= max_gap:
                        continue
                    close = True
            if close and open_:
                out_row[m] = b
                out_f[m, 0] = swx / sw
                out_f[m, 1] = swy / sw
                out_f[m, 2] = sp / cnt
                out_i[m, 0] = first
                out_i[m, 1] = last
                out_i[m, 2] = cnt
                m += 1
                open_ = False
                if not (k == n) and p[b, i] >= vote:  # the beam that closed the group opens the next
                    open_ = True
                    sw, swx, swy, sp = p[b, i], p[b, i] * cx[b, i], p[b, i] * cy[b, i], p[b, i]
                    cnt, first, last, gap = 1, i, i, 0
    return m


def group_votes(p, cx, cy, config: BeamConfig | None = None, circular: bool = True):
    """Group per-beam votes ``p, cx, cy (B, n)`` into detections.

    Returns ``(row (D,), xy (D, 2), score (D,), beams (D, 3): first, last, n_votes)``.
    """
    c = config or BeamConfig()
    p = np.ascontiguousarray(p, np.float64)
    if p.ndim != 2 or np.shape(cx) != p.shape or np.shape(cy) != p.shape:
        raise ValueError(
            "group_votes: p, cx, cy must share one (B, n) shape, got "
            f"{p.shape}, {np.shape(cx)}, {np.shape(cy)}"
        )
    b_n, n = p.shape
    cap = b_n * n  # every voting beam may open its own group (votes for centres far apart)
    out_row = np.empty(cap, np.int64)
    out_f = np.empty((cap, 3), np.float64)
    out_i = np.empty((cap, 3), np.int64)
    m = _group_kernel(
        p, np.ascontiguousarray(cx, np.float64), np.ascontiguousarray(cy, np.float64), c.vote_threshold,
        c.group_radius, c.max_gap, bool(circular), out_row, out_f, out_i,
    )  # fmt: skip
    keep = out_i[:m, 2] >= c.min_votes
    return out_row[:m][keep], out_f[:m, :2][keep], out_f[:m, 2][keep], out_i[:m][keep]


# --------------------------------------------------------------------------- samples


def load_beam_dataset(path) -> tuple[dict[str, np.ndarray], dict]:
    """Read a per-beam dataset directory (``manifest.json`` + ``.npz`` shards, written by
    ``scripts/train_beam_detector.py`` from :mod:`kin_envs.detection.beam_dataset`) → ``(records, manifest)``.

    Records are stacked per scan row (plus the shared ``angles (n,)``): ``ranges (N, n)``,
    ``label (N, n)``, ``centre (N, n, 2)``,
    ``category (N, n)``, ``noise``, ``dropout``, ``seed``, ``family`` ``(N,)``.
    """
    root = Path(path)
    mpath = root / "manifest.json"
    if not mpath.is_file():
        raise FileNotFoundError(f"{mpath}: no beam dataset manifest")
    manifest = json.loads(mpath.read_text())
    if not isinstance(manifest, dict) or manifest.get("format") != BEAM_DATASET_FORMAT:
        raise ValueError(f"{mpath}: not a {BEAM_DATASET_FORMAT!r} manifest")
    parts = []
    for shard in manifest["shards"]:
        f = root / shard["file"]
        if not f.is_file():
            raise FileNotFoundError(f"{f}: shard listed in {mpath} is missing")
        with np.load(f) as z:
            parts.append({k: z[k] for k in z.files})
    if not parts:
        raise ValueError(f"{mpath}: the dataset has no shards")
    angles = parts[0].pop("angles")
    for p in parts[1:]:
        if not np.array_equal(p.pop("angles"), angles):
            raise ValueError(f"{mpath}: shards have different beam angles")
    records = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    records["angles"] = angles
    return records, manifest


# --------------------------------------------------------------------------- detector


class BeamKinDetector(KinDetector):
    """Kin detector from per-beam votes (see the module docstring).

    Args:
        checkpoint: path of a ``.npz`` checkpoint (default: the shipped ``beam_default.npz``).
        threshold: report a detection when its score ``>= threshold``; default the checkpoint's.

    ``Detection.score`` is the mean ``p(kin)`` of the beams that voted for it (higher = more
    kin-like); ``first_beam`` / ``last_beam`` / ``n_beams`` are its voting beams. Results carry no
    per-segment reports (``reports`` is empty: this detector has no segments).
    """

    def __init__(self, checkpoint=None, threshold: float | None = None) -> None:
        if threshold is not None and (
            isinstance(threshold, bool)
            or not isinstance(threshold, int | float)
            or not 0.0 <= threshold <= 1.0
        ):
            raise ValueError(f"BeamKinDetector: threshold must be a probability in [0, 1], got {threshold!r}")
        self.model, self.checkpoint = load_beam_checkpoint(checkpoint)
        self.config = self.model.config
        self.threshold = float(self.checkpoint["threshold"] if threshold is None else threshold)

    def permissive(self) -> BeamKinDetector:
        """This detector reporting every group (``threshold=0``), for precision-recall curves."""
        return BeamKinDetector(self.checkpoint["path"], threshold=0.0)

    def beam_probabilities(self, ranges, angles):
        """Per-beam ``p(kin)`` and voted centres ``(p, cx, cy)``, each ``(B, n)`` (0 / NaN off valid
        beams)."""
        r, a = validate_batch(ranges, angles)
        x, row, beam = beam_inputs(r, a, self.config, is_circular_sweep(a))
        logit, off = self.model.forward(x)
        p = np.zeros(r.shape)
        cx = np.full(r.shape, np.nan)
        cy = np.full(r.shape, np.nan)
        p[row, beam] = 1.0 / (1.0 + np.exp(-logit.astype(np.float64)))
        # the beam's return, then the offset along / across the beam
        ca, sa = np.cos(a[beam]), np.sin(a[beam])
        rr = r[row, beam]
        du, dv = off[:, 0].astype(np.float64), off[:, 1].astype(np.float64)
        cx[row, beam] = (rr + du) * ca - dv * sa
        cy[row, beam] = (rr + du) * sa + dv * ca
        return p, cx, cy

    def detect_arrays(self, ranges, angles) -> dict[str, np.ndarray]:
        """Detections of a batch as arrays: ``scan, x, y, range, bearing, score, first_beam, last_beam,
        n_beams`` (one entry per detection, scans in order)."""
        r, a = validate_batch(ranges, angles)
        if r.shape[0]:
            validate_scan(r[0], a)  # the angles (and row 0) as detect() checks them
        neg = r < 0.0
        if neg.any():
            b, i = (int(v[0]) for v in np.nonzero(neg))
            raise ValueError(
                f"ranges must be >= 0 metres (non-finite means no return), got ranges[{b}, {i}] = {r[b, i]}"
            )
        p, cx, cy = self.beam_probabilities(r, a)
        row, xy, score, beams = group_votes(p, cx, cy, self.config, is_circular_sweep(a))
        keep = score >= self.threshold
        x, y = xy[keep, 0], xy[keep, 1]
        return {
            "scan": row[keep],
            "x": x,
            "y": y,
            "range": np.hypot(x, y),
            "bearing": np.arctan2(y, x),
            "score": score[keep],
            "first_beam": beams[keep, 0],
            "last_beam": beams[keep, 1],
            "n_beams": beams[keep, 2],
        }

    def detect_batch(self, ranges, angles) -> list[DetectionResult]:
        d = self.detect_arrays(ranges, angles)
        b_n = np.asarray(ranges).shape[0]
        per: list[list[Detection]] = [[] for _ in range(b_n)]
        cols = [
            d[k].tolist()
            for k in ("scan", "range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams")
        ]
        for s, rng_, brg, x, y, sc, f, la, nb in zip(*cols, strict=True):
            per[s].append(Detection(rng_, brg, x, y, sc, f, la, nb))
        return [DetectionResult(dets, []) for dets in per]

    def detect(self, ranges, angles) -> DetectionResult:
        r, a = validate_scan(ranges, angles)
        return self.detect_batch(r[None, :], a)[0]
