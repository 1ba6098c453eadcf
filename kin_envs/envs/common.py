"""Pieces shared by the Gymnasium and PettingZoo adapters.

Nothing here simulates anything: the world core (:mod:`kin_envs.core`) does the physics and the
lidar. This module turns its outputs into observations and infos and turns actions into wheel
speeds:

* :class:`CommonConfig`: the validated settings every env accepts (sensor, detector, observation,
  action, rendering);
* :class:`ObservationLayout` / :class:`ObservationBuilder`: the normalised scan, optional
  detector channel and frame stacking;
* :class:`ActionAdapter`: continuous or discrete actions → normalised wheel speeds, with checks;
* :func:`resolve_detector`, :func:`run_detector`: the ``detector=`` argument and
  ``info["kin_detections"]``;
* :func:`kin_truth`: ``info["kin_truth"]``, the kin each robot's lidar actually sees.

Info arrays are *columns*: a dict of equal-length 1-D numpy arrays, one entry per kin, nearest
first. (Structured numpy arrays would be neater, but Gymnasium's checker compares infos with
``np.allclose``, which cannot handle them.)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from kin_envs.core.lidar import HitKind, LidarSpec

__all__ = [
    "ACTION_TYPES",
    "DETECTION_FIELDS",
    "DISCRETE_ACTIONS",
    "DISCRETE_ACTION_NAMES",
    "KIN_MATCH_TOLERANCE",
    "KIN_TRUTH_FIELDS",
    "OBS_DETECTION_MODES",
    "ActionAdapter",
    "CommonConfig",
    "ObservationBuilder",
    "ObservationLayout",
    "UnknownArgumentError",
    "config_from_kwargs",
    "kin_truth",
    "resolve_detector",
    "run_detector",
]

ACTION_TYPES = ("continuous", "discrete")
OBS_DETECTION_MODES = ("topk", "mask")

#: Discrete action ``i`` → normalised (left, right) wheel speeds. Turning in place at half speed
#: is 2.06 rad/s (≈ 12° per 0.1 s step): fine enough to line up on a 7 cm target.
DISCRETE_ACTIONS = np.array(
    [[0.0, 0.0], [1.0, 1.0], [-0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]], dtype=np.float64
)
DISCRETE_ACTION_NAMES = ("stop", "forward", "turn_left", "turn_right", "back")

KIN_TRUTH_FIELDS = ("index", "range", "bearing", "x", "y", "n_beams")
DETECTION_FIELDS = (
    "range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams", "kin_index",
)
#: A detection is counted correct when its centre is within this distance of a robot's centre, m.
#: Distractors keep >= 0.175 m from any robot centre (body radius + clearance + their size), so
#: 0.1 m never credits a detection on an obstacle to a robot.
KIN_MATCH_TOLERANCE = 0.1


class UnknownArgumentError(TypeError, ValueError):
    """An env got a keyword argument it does not know (both a ``TypeError``, as Python raises for
    unexpected keywords, and a ``ValueError``, as the project raises for bad input)."""


# --- validation helpers -------------------------------------------------------------------------


def check_int(where: str, name: str, v: Any, lo: int, hi: int | None = None) -> int:
    ok = isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)
    if not ok or v < lo or (hi is not None and v > hi):
        rng = f"in [{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ValueError(f"{where}: {name} must be an integer {rng}, got {v!r}")
    return int(v)


def check_float(
    where: str, name: str, v: Any, lo: float, hi: float = math.inf, lo_open: bool = False
) -> float:
    ok = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
    if ok:
        f = float(v)
        ok = math.isfinite(f) and (f > lo if lo_open else f >= lo) and f <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ValueError(f"{where}: {name} must be a finite number in {left}{lo}, {hi}], got {v!r}")
    return float(v)


def check_bool(where: str, name: str, v: Any) -> bool:
    if not isinstance(v, bool | np.bool_):
        raise ValueError(f"{where}: {name} must be True or False, got {v!r}")
    return bool(v)


def config_from_kwargs(cls: type, kwargs: dict[str, Any]):
    """``cls(**kwargs)``; unknown names raise :class:`UnknownArgumentError` listing the valid ones."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(kwargs) - names)
    if unknown:
        raise UnknownArgumentError(
            f"{cls.env_id}: unknown argument(s) {unknown}; valid arguments are "
            f"{sorted(names | {'render_mode'})}"
        )
    return cls(**kwargs)


@dataclass(frozen=True, kw_only=True)
class CommonConfig:
    """Settings shared by every env (see each env's docstring, section Arguments).

    Attributes:
        noise_sigma: relative Gaussian range noise of the lidar (0.01 = 1 % of the distance).
        dropout_prob: probability that a reading is dropped (reads ``range_max``).
        detector: ``"geometric"`` (the paper's detector), ``"learned"``, ``None`` (off) or an
            object with ``detect(ranges, angles)`` (and optionally ``detect_batch``).
        frame_stack: number of consecutive frames in one observation (oldest first).
        obs_detections: ``None``/``False`` (scan only), ``"topk"``/``True`` or ``"mask"``.
        obs_top_k: detection slots in the ``"topk"`` encoding.
        action_type: ``"continuous"`` or ``"discrete"``.
        control_dt: seconds per step (the world's ``WorldConfig.control_dt``).
        render_size: longer side of rendered frames, pixels.
        render_beams: draw the lidar beams (and detections) of the observed robot.
    """

    env_id: ClassVar[str] = "kin_envs"

    noise_sigma: float = 0.0
    dropout_prob: float = 0.0
    detector: Any = "geometric"
    frame_stack: int = 1
    obs_detections: str | bool | None = None
    obs_top_k: int = 3
    action_type: str = "continuous"
    control_dt: float = 0.1
    render_size: int = 512
    render_beams: bool = True

    def __post_init__(self) -> None:
        w = self.env_id
        check_float(w, "noise_sigma", self.noise_sigma, 0.0, 0.5)
        check_float(w, "dropout_prob", self.dropout_prob, 0.0, 0.99)
        check_int(w, "frame_stack", self.frame_stack, 1, 64)
        check_int(w, "obs_top_k", self.obs_top_k, 1, 64)
        check_float(w, "control_dt", self.control_dt, 0.02, 1.0)
        check_int(w, "render_size", self.render_size, 64, 4096)
        check_bool(w, "render_beams", self.render_beams)
        mode = self.obs_detections
        if mode is True:
            mode = "topk"
        elif mode is False:
            mode = None
        if mode is not None and mode not in OBS_DETECTION_MODES:
            raise ValueError(
                f"{w}: obs_detections must be None, False, True, 'topk' or 'mask', got {mode!r}"
            )
        object.__setattr__(self, "obs_detections", mode)
        if self.action_type not in ACTION_TYPES:
            raise ValueError(
                f"{w}: action_type must be one of {ACTION_TYPES}, got {self.action_type!r}"
            )
        if mode is not None and self.detector is None:
            raise ValueError(
                f"{w}: obs_detections={mode!r} needs a detector, but detector=None"
            )
        if not (self.detector is None or isinstance(self.detector, str)
                or callable(getattr(self.detector, "detect", None))):
            raise ValueError(
                f"{w}: detector must be 'geometric', 'learned', 'beam', None or an object with a "
                f"detect(ranges, angles) method, got {self.detector!r}"
            )
        if isinstance(self.detector, str) and self.detector not in ("geometric", "learned", "beam"):
            raise ValueError(
                f"{w}: detector must be 'geometric', 'learned', 'beam', None or a detector object, "
                f"got {self.detector!r}"
            )

    def lidar_spec(self) -> LidarSpec:
        return LidarSpec(noise_sigma=float(self.noise_sigma), dropout_prob=float(self.dropout_prob))


# --- detector -----------------------------------------------------------------------------------


def check_render_mode(render_mode: str | None, modes: list[str], where: str) -> str | None:
    """Validate ``render_mode``; for a real mode import pygame now, so a missing install fails at
    construction with the install hint rather than at the first frame."""
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"{where}: render_mode must be None or one of {modes}, got {render_mode!r}")
    if render_mode is not None:
        from kin_envs.envs.rendering import import_pygame

        import_pygame()
    return render_mode


def resolve_detector(spec: Any, where: str = "kin_envs"):
    """The ``detector=`` argument → a detector object or ``None``.

    ``"geometric"`` → ``detectors.GeometricKinDetector(reports=False)`` (the env only needs the
    detections, and per-segment reports cost most of the detector's time); ``"learned"`` →
    ``detectors.LearnedKinDetector()`` if that exists (it needs the ``train`` extra); ``"beam"`` →
    ``detectors.beam_detector.BeamKinDetector()`` (numpy only). The
    ``detectors`` package is imported here, lazily, so ``import kin_envs`` stays light.
    """
    if spec is None or not isinstance(spec, str):
        return spec
    if spec == "geometric":
        from detectors import GeometricKinDetector

        return GeometricKinDetector(reports=False)
    if spec == "learned":
        try:
            from detectors import LearnedKinDetector
        except ImportError as e:
            raise ValueError(
                f"{where}: detector='learned' needs detectors.LearnedKinDetector, which is not "
                f"available ({e}); install the train extra (pip install kin-envs[train]) or pass "
                "detector='geometric', None or a detector object"
            ) from e
        return LearnedKinDetector()
    if spec == "beam":
        from detectors.beam_detector import BeamKinDetector

        return BeamKinDetector()
    raise ValueError(f"{where}: unknown detector {spec!r}")


def _empty_detections() -> dict[str, np.ndarray]:
    return {
        k: np.zeros(0, dtype=np.int64 if k in ("first_beam", "last_beam", "n_beams", "kin_index")
                    else np.float64)
        for k in DETECTION_FIELDS
    }


def run_detector(
    detector, ranges: np.ndarray, angles: np.ndarray, observers: np.ndarray, poses: np.ndarray
) -> list[dict[str, np.ndarray]]:
    """Detect kin in each row of ``ranges`` and match every detection to ground truth.

    Args:
        detector: object with ``detect`` (and optionally ``detect_batch``).
        ranges: ``(B, n_beams)`` scans, m.
        angles: ``(n_beams,)`` beam angles, rad.
        observers: ``(B,)`` robot index of each row.
        poses: ``(n_robots, 3)`` all robots' poses (for the ``kin_index`` match).

    Returns:
        One column dict per row (fields :data:`DETECTION_FIELDS`, nearest first). ``kin_index``
        is the robot whose centre is within :data:`KIN_MATCH_TOLERANCE` of the detected centre
        (privileged ground truth, for evaluation and rendering), or -1 for a false detection.
    """
    if len(ranges) == 1 or not callable(getattr(detector, "detect_batch", None)):
        results = [detector.detect(r, angles) for r in ranges]
    else:
        results = detector.detect_batch(ranges, angles)
    owner, rows = [], []
    for b, res in enumerate(results):
        for d in res.detections:
            owner.append(b)
            rows.append((d.range, d.bearing, d.x, d.y, d.score, d.first_beam, d.last_beam,
                         d.n_beams))
    if not rows:
        return [_empty_detections() for _ in results]
    tab = np.array(rows, dtype=np.float64)
    owner_a = np.asarray(owner)
    obs_idx = np.asarray(observers)[owner_a]
    px, py, th = poses[obs_idx, 0], poses[obs_idx, 1], poses[obs_idx, 2]
    c, s = np.cos(th), np.sin(th)
    wx = px + c * tab[:, 2] - s * tab[:, 3]
    wy = py + s * tab[:, 2] + c * tab[:, 3]
    d2 = (wx[:, None] - poses[None, :, 0]) ** 2 + (wy[:, None] - poses[None, :, 1]) ** 2
    d2[np.arange(len(obs_idx)), obs_idx] = np.inf  # never match the observer itself
    nearest = np.argmin(d2, axis=1)
    ok = d2[np.arange(len(nearest)), nearest] <= KIN_MATCH_TOLERANCE**2
    kin_index = np.where(ok, nearest, -1)
    # nearest first within each row: sort by (row, range)
    order = np.lexsort((tab[:, 0], owner_a))
    tab, owner_a, kin_index = tab[order], owner_a[order], kin_index[order]
    cols = {name: tab[:, k].copy() for k, name in enumerate(DETECTION_FIELDS[:5])}
    for k, name in enumerate(DETECTION_FIELDS[5:8], start=5):
        cols[name] = tab[:, k].astype(np.int64)
    cols["kin_index"] = kin_index.astype(np.int64)
    bounds = np.searchsorted(owner_a, np.arange(len(results) + 1)).tolist()
    return [
        {name: col[lo:hi] for name, col in cols.items()}
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)
    ]


# --- ground truth -------------------------------------------------------------------------------


def kin_truth(scan, poses: np.ndarray) -> list[dict[str, np.ndarray]]:
    """The kin each scanned robot's lidar actually sees: ``scan.visible_robots`` for every row at
    once, with their true centre positions.

    Returns one column dict per scan row (fields :data:`KIN_TRUTH_FIELDS`, nearest first):
    ``index`` robot index, ``range`` centre distance m, ``bearing`` rad CCW in the observer's
    frame, ``x``/``y`` m in the observer's frame (x forward, y left), ``n_beams`` valid beams on
    its lidar housing (>= 1).
    """
    n_rows, n_robots = scan.ranges.shape[0], poses.shape[0]
    seen = (scan.hit_kind == HitKind.ROBOT.value) & (scan.ranges < scan.range_max)
    base = (np.arange(n_rows) * n_robots)[:, None]
    counts = np.bincount((scan.hit_index + base)[seen], minlength=n_rows * n_robots)
    pairs = np.flatnonzero(counts)  # (observer row, seen robot) pairs, grouped by row
    rows, idx = np.divmod(pairs, n_robots)
    n_beams = counts[pairs]
    op = scan.poses
    dx, dy = poses[idx, 0] - op[rows, 0], poses[idx, 1] - op[rows, 1]
    c, s = np.cos(op[:, 2])[rows], np.sin(op[:, 2])[rows]
    rng = np.sqrt(dx * dx + dy * dy)
    # nearest first within each row; one argsort of a composite key beats lexsort here
    order = np.argsort(rows * (2.0 * scan.range_max + 1.0) + rng, kind="stable")
    rows, idx, n_beams, rng, dx, dy, c, s = (
        a[order] for a in (rows, idx, n_beams, rng, dx, dy, c, s)
    )
    x, y = c * dx + s * dy, c * dy - s * dx
    bearing = np.arctan2(y, x)
    bounds = np.searchsorted(rows, np.arange(n_rows + 1)).tolist()
    return [
        {"index": idx[lo:hi], "range": rng[lo:hi], "bearing": bearing[lo:hi], "x": x[lo:hi],
         "y": y[lo:hi], "n_beams": n_beams[lo:hi]}
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)
    ]


# --- observations -------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObservationLayout:
    """Where things are in an observation vector.

    An observation is ``frame_stack`` frames concatenated, oldest first, each ``frame_dim`` long:
    the scan ``ranges / range_max`` (``n_beams`` values in [0, 1], beam ``i`` at ``angles[i]``),
    then the detector channel if any:

    * ``"topk"``: ``top_k`` slots, nearest detection first, each ``[present, range / range_max,
      sin(bearing), cos(bearing)]``; empty slots are all zero;
    * ``"mask"``: ``n_beams`` values, 1 on the beams of a detected kin's segment, else 0.
    """

    n_beams: int
    range_max: float
    angles: np.ndarray
    frame_stack: int = 1
    detections: str | None = None
    top_k: int = 3

    @property
    def detection_dim(self) -> int:
        if self.detections == "topk":
            return 4 * self.top_k
        return self.n_beams if self.detections == "mask" else 0

    @property
    def frame_dim(self) -> int:
        return self.n_beams + self.detection_dim

    @property
    def dim(self) -> int:
        return self.frame_stack * self.frame_dim

    def newest_scan(self, obs: np.ndarray) -> np.ndarray:
        """Ranges in metres of the newest frame of ``obs`` (``(..., dim)``)."""
        obs = np.asarray(obs)
        start = (self.frame_stack - 1) * self.frame_dim
        return obs[..., start : start + self.n_beams].astype(np.float64) * self.range_max


class ObservationBuilder:
    """Builds batches of observations ``(B, layout.dim)`` float32 and keeps the frame stack."""

    def __init__(self, layout: ObservationLayout) -> None:
        self.layout = layout
        lo = np.zeros(layout.frame_dim, dtype=np.float32)
        if layout.detections == "topk":
            lo[layout.n_beams :] = np.tile(np.array([0, 0, -1, -1], np.float32), layout.top_k)
        self._low = np.tile(lo, layout.frame_stack)
        self._stack: np.ndarray | None = None

    def make_space(self) -> spaces.Box:
        high = np.ones(self.layout.dim, dtype=np.float32)
        return spaces.Box(low=self._low.copy(), high=high, dtype=np.float32)

    def frame(self, ranges: np.ndarray, detections: list[dict] | None) -> np.ndarray:
        """``(B, frame_dim)`` float32 from ``(B, n_beams)`` ranges and per-row detection columns."""
        L = self.layout
        out = np.empty((ranges.shape[0], L.frame_dim), dtype=np.float32)
        np.clip(ranges * np.float32(1.0 / L.range_max), 0.0, 1.0, out=out[:, : L.n_beams])
        if L.detections is None:
            return out
        det = out[:, L.n_beams :]
        det[:] = 0.0
        for b, d in enumerate(detections):
            k = min(len(d["range"]), L.top_k) if L.detections == "topk" else len(d["range"])
            if k == 0:
                continue
            if L.detections == "topk":
                slots = det[b].reshape(L.top_k, 4)
                slots[:k, 0] = 1.0
                slots[:k, 1] = np.minimum(d["range"][:k] / L.range_max, 1.0)
                slots[:k, 2] = np.sin(d["bearing"][:k])
                slots[:k, 3] = np.cos(d["bearing"][:k])
            else:
                for first, last in zip(d["first_beam"], d["last_beam"], strict=True):
                    if first <= last:
                        det[b, first : last + 1] = 1.0
                    else:  # the segment wraps across beam 0
                        det[b, first:] = 1.0
                        det[b, : last + 1] = 1.0
        return out

    def reset(self, frame: np.ndarray) -> np.ndarray:
        """Start a new episode: every stacked frame is the first one."""
        self._stack = np.repeat(frame[:, None, :], self.layout.frame_stack, axis=1)
        return self._stack.reshape(frame.shape[0], -1).copy()

    def push(self, frame: np.ndarray) -> np.ndarray:
        if self.layout.frame_stack == 1:
            return frame  # already a fresh array
        self._stack[:, :-1] = self._stack[:, 1:]
        self._stack[:, -1] = frame
        return self._stack.reshape(frame.shape[0], -1).copy()


# --- actions ------------------------------------------------------------------------------------


class ActionAdapter:
    """Actions → normalised (left, right) wheel speeds in [-1, 1] (times ``max_wheel_speed``).

    ``"continuous"``: ``Box(-1, 1, (2,), float32)``, values outside [-1, 1] are clipped.
    ``"discrete"``: ``Discrete(5)``, see :data:`DISCRETE_ACTIONS` / :data:`DISCRETE_ACTION_NAMES`.
    NaN / infinite values, wrong shapes and out-of-range discrete actions raise ``ValueError``.
    """

    def __init__(self, action_type: str, where: str) -> None:
        self.action_type = action_type
        self.where = where

    def make_space(self) -> spaces.Space:
        if self.action_type == "discrete":
            return spaces.Discrete(len(DISCRETE_ACTIONS))
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def one(self, action: Any, who: str = "action") -> np.ndarray:
        """One action → ``(2,)`` float64 normalised wheel speeds."""
        if self.action_type == "discrete":
            return DISCRETE_ACTIONS[self._index(action, who)]
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"{self.where}: {who} must be 2 numbers (left, right wheel speed in [-1, 1]), "
                f"got {action!r}"
            ) from e
        if a.shape != (2,):
            raise ValueError(
                f"{self.where}: {who} must have shape (2,) (left, right wheel speed in [-1, 1]), "
                f"got shape {a.shape}"
            )
        if not np.isfinite(a).all():
            raise ValueError(f"{self.where}: {who} must be finite numbers, got {a.tolist()}")
        return np.clip(a, -1.0, 1.0)

    def many(self, actions: list, names: list[str]) -> np.ndarray:
        """Actions of several robots → ``(n, 2)``; errors name the offending agent."""
        if self.action_type == "continuous":
            try:
                a = np.asarray(actions, dtype=np.float64)
                if a.shape == (len(names), 2) and np.isfinite(a).all():
                    return np.clip(a, -1.0, 1.0)
            except (TypeError, ValueError):
                pass
        return np.stack([self.one(a, f"action of {n!r}") for a, n in zip(actions, names, strict=True)])

    def _index(self, action: Any, who: str) -> int:
        a = action
        if isinstance(a, np.ndarray) and a.size == 1 and np.issubdtype(a.dtype, np.integer):
            a = a.reshape(()).item()
        if isinstance(a, int | np.integer) and not isinstance(a, bool | np.bool_):
            if 0 <= a < len(DISCRETE_ACTIONS):
                return int(a)
        raise ValueError(
            f"{self.where}: {who} must be an integer in [0, {len(DISCRETE_ACTIONS)}) "
            f"({', '.join(f'{i}={n}' for i, n in enumerate(DISCRETE_ACTION_NAMES))}), got {action!r}"
        )
