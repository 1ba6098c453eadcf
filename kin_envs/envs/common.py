"""Pieces shared by the Gymnasium and PettingZoo adapters.

Nothing here simulates anything: the world core (:mod:`kin_envs.core`) does the physics and the
lidar. This module turns its outputs into observations and infos and turns actions into wheel
speeds:

* :class:`CommonConfig`: the validated settings every env accepts (sensor, detector, observation,
  action, rendering);
* :class:`ObservationLayout` / :class:`ObservationBuilder`: the normalised scan, optional
  detector channel and frame stacking;
* :class:`ActionAdapter`: continuous or discrete actions → normalised wheel speeds, with checks;
* :func:`resolve_detector`, :func:`detect_rows`: the ``detector=`` argument and
  ``info["kin_detections"]`` (:func:`detection_arrays` is the one place that reads a detector's
  output);
* :func:`kin_truth_rows`: ``info["kin_truth"]``, the kin each robot's lidar actually sees
  (:func:`kin_truth_padded`: the same, padded, in one compiled pass, for the swarm's every step).

Info arrays are *columns*: a dict of equal-length 1-D numpy arrays, one entry per kin, nearest
first, padded to a fixed number of slots (:mod:`kin_envs.envs.info`). (Structured numpy arrays
would be neater, but Gymnasium's checker compares infos with ``np.allclose``, which cannot handle
them.)
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numba
import numpy as np
from gymnasium import spaces

from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.envs.info import DETECTION_FIELDS, KIN_TRUTH_FIELDS, PAD_VALUES, dict_maker

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
    "detect_one_padded",
    "detect_rows",
    "detect_rows_padded",
    "detection_arrays",
    "kin_truth",
    "kin_truth_padded",
    "kin_truth_rows",
    "resolve_detector",
    "run_detector",
    "split_rows",
]

ACTION_TYPES = ("continuous", "discrete")
OBS_DETECTION_MODES = ("topk", "mask")

#: Discrete action ``i`` → normalised (left, right) wheel speeds. Turning in place at half speed
#: is 2.06 rad/s (≈ 12° per 0.1 s step): fine enough to line up on a 7 cm target.
DISCRETE_ACTIONS = np.array(
    [[0.0, 0.0], [1.0, 1.0], [-0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]], dtype=np.float64
)
DISCRETE_ACTION_NAMES = ("stop", "forward", "turn_left", "turn_right", "back")

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
        max_detections: slots of ``info["kin_detections"]`` (fixed-shape info; further, farther
            detections are left out of the info, never out of the observation's ``"mask"``).
        action_type: ``"continuous"`` or ``"discrete"``.
        control_dt: seconds per step (the world's ``WorldConfig.control_dt``).
        render_size: longer side of rendered frames, pixels.
        render_beams: draw the lidar beams (and detections) of the observed robot.
        tracker: multi-frame kin tracking of the detections (:class:`detectors.KinTracker`, fed with
            the detector's operating-point detections and the robot's wheel odometry): ``None``/
            ``False`` (off), ``True`` (default parameters) or a dict of ``detectors.TrackerParams``
            fields plus optionally ``"kin_model"``: the track classifier, ``"learned"`` (the shipped one
            fitted on the learned detector's permissive candidates; v1's default), ``"geometric"`` (the
            shipped one fitted on the geometric detector's), ``"auto"`` (v2's default: ``"geometric"`` when
            the tracker gets the geometric detector's permissive candidates, else ``"learned"``), ``"hand"``
            (the hand-tuned fusion of the cues) or a path to a track-classifier JSON
            (``scripts/fit_track_classifier.py``), and optionally ``"feed"``: ``"accepted"`` (the
            detector's operating-point detections, all flagged accepted), ``"permissive"`` (what the
            track classifier is fitted on and the sequence benchmark runs: every candidate of the detector at
            its permissive operating point with its score and accepted flag, and each scan's noise estimate;
            ``info["kin_detections"]`` unchanged) or ``"auto"`` (``"permissive"`` where it costs no second
            detector call, i.e. the shipped geometric detector; ``"accepted"`` otherwise). The default is the
            env version's: ``"accepted"`` up to v1, ``"auto"`` from v2 (with the geometric detector under
            range noise the accepted feed's tracks are no better than its raw detections). Adds
            ``info["kin_tracks"]``. Needs a detector.
        max_tracks: slots of ``info["kin_tracks"]`` (fixed-shape info).
        obs_tracks: fill the observation's detection channel from the tracker's confirmed kin tracks
            (their centre; score = kin probability) instead of the frame's raw detections.
    """

    env_id: ClassVar[str] = "kin_envs"
    #: ``tracker["feed"]`` when not given: ``"accepted"`` up to the v1 ids, ``"auto"`` from v2
    default_tracker_feed: ClassVar[str] = "accepted"

    noise_sigma: float = 0.0
    dropout_prob: float = 0.0
    detector: Any = "geometric"
    frame_stack: int = 1
    obs_detections: str | bool | None = None
    obs_top_k: int = 3
    max_detections: int = 16
    action_type: str = "continuous"
    control_dt: float = 0.1
    render_size: int = 512
    render_beams: bool = True
    tracker: Any = None
    max_tracks: int = 16
    obs_tracks: bool = False

    def __post_init__(self) -> None:
        w = self.env_id
        check_float(w, "noise_sigma", self.noise_sigma, 0.0, 0.5)
        check_float(w, "dropout_prob", self.dropout_prob, 0.0, 0.99)
        check_int(w, "frame_stack", self.frame_stack, 1, 64)
        check_int(w, "obs_top_k", self.obs_top_k, 1, 64)
        check_int(w, "max_detections", self.max_detections, 1, 1024)
        check_float(w, "control_dt", self.control_dt, 0.02, 1.0)
        check_int(w, "render_size", self.render_size, 64, 4096)
        check_bool(w, "render_beams", self.render_beams)
        mode = self.obs_detections
        if mode is True:
            mode = "topk"
        elif mode is False:
            mode = None
        if mode is not None and mode not in OBS_DETECTION_MODES:
            raise ValueError(f"{w}: obs_detections must be None, False, True, 'topk' or 'mask', got {mode!r}")
        object.__setattr__(self, "obs_detections", mode)
        if self.action_type not in ACTION_TYPES:
            raise ValueError(f"{w}: action_type must be one of {ACTION_TYPES}, got {self.action_type!r}")
        if mode is not None and self.detector is None:
            raise ValueError(f"{w}: obs_detections={mode!r} needs a detector, but detector=None")
        if not (
            self.detector is None
            or isinstance(self.detector, str)
            or callable(getattr(self.detector, "detect", None))
        ):
            raise ValueError(
                f"{w}: detector must be 'geometric', 'learned', 'beam', None or an object with a "
                f"detect(ranges, angles) method, got {self.detector!r}"
            )
        if isinstance(self.detector, str) and self.detector not in ("geometric", "learned", "beam"):
            raise ValueError(
                f"{w}: detector must be 'geometric', 'learned', 'beam', None or a detector object, "
                f"got {self.detector!r}"
            )

        check_int(w, "max_tracks", self.max_tracks, 1, 1024)
        check_bool(w, "obs_tracks", self.obs_tracks)
        if self.tracker is False:
            object.__setattr__(self, "tracker", None)
        if self.tracker is not None:
            if self.tracker is not True and not isinstance(self.tracker, dict):
                raise ValueError(
                    f"{w}: tracker must be None, False, True or a dict of detectors.TrackerParams "
                    f"fields, got {self.tracker!r}"
                )
            if self.detector is None:
                raise ValueError(f"{w}: tracker={self.tracker!r} needs a detector, but detector=None")
            if isinstance(self.tracker, dict):
                _tracker_options(w, self.tracker)  # bad keys / values raise here, naming them
        if self.obs_tracks and (self.tracker is None or mode is None):
            raise ValueError(f"{w}: obs_tracks=True needs tracker=True and obs_detections ('topk' or 'mask')")

    def track_angles(self, angles):
        """``angles`` (the lidar's beams) where the observation reads a track's beams (the mask channel: a
        track marks the beams that would meet its housing), else ``None``: ``kin_envs.envs.tracks.track_rows``
        then skips working them out."""
        return angles if self.obs_detections == "mask" else None

    def make_tracker(self, n_observers: int = 1, detector=None):
        """The configured :class:`detectors.KinTracker` (imported lazily), or ``None``. ``detector``: the
        env's resolved detector, which ``kin_model="auto"`` (v2's default) reads."""
        if self.tracker is None:
            return None
        from detectors.tracking import KinTracker

        opts = {} if self.tracker is True else self.tracker
        params, kin_model = _tracker_options(self.env_id, opts)
        if "kin_model" not in opts and self.default_tracker_feed == "auto":
            kin_model = "auto"  # v2: the classifier fitted on the feed the tracker gets
        if isinstance(kin_model, str) and kin_model == "auto":
            from kin_envs.envs.tracks import auto_kin_model

            kin_model = auto_kin_model(self.tracker_feed, detector)
        return KinTracker(params, n_observers=n_observers, kin_model=kin_model)

    @property
    def tracker_feed(self) -> str | None:
        """``tracker["feed"]`` as asked: ``"accepted"``, ``"permissive"`` or ``"auto"`` (the version's
        :attr:`default_tracker_feed` when not given); ``None`` without a tracker."""
        if self.tracker is None:
            return None
        given = None if self.tracker is True else self.tracker.get("feed")
        return self.default_tracker_feed if given is None else given

    def lidar_spec(self) -> LidarSpec:
        return LidarSpec(noise_sigma=float(self.noise_sigma), dropout_prob=float(self.dropout_prob))


#: the track classifiers ``tracker={"kin_model": ...}`` names (any other string is a model JSON path)
TRACKER_KIN_MODELS = ("learned", "geometric", "hand", "auto")
#: what ``tracker={"feed": ...}`` feeds the tracker (see :class:`CommonConfig`)
TRACKER_FEEDS = ("accepted", "permissive", "auto")
_TRACKER_KEYS = ("kin_model", "feed")


def _tracker_options(where: str, opts: Mapping):
    """``(detectors.TrackerParams, kin_model)`` of a ``tracker`` dict: ``TrackerParams`` fields plus
    ``"kin_model"``; an unknown key or a bad value raises a ``ValueError`` naming it."""
    from pathlib import Path

    from detectors.tracking import TrackerParams, TrackKinModel

    names = sorted(f.name for f in dataclasses.fields(TrackerParams))
    bad = sorted(str(k) for k in opts if k not in _TRACKER_KEYS and k not in names)
    if bad:
        raise ValueError(f"{where}: tracker has unknown key(s) {bad}; expected 'kin_model', 'feed' or "
                         f"detectors.TrackerParams fields {names}")  # fmt: skip
    feed = opts.get("feed", "auto")
    if not (isinstance(feed, str) and feed in TRACKER_FEEDS):
        raise ValueError(f"{where}: tracker['feed'] must be one of {list(TRACKER_FEEDS)}, got {feed!r}")
    try:
        params = TrackerParams(**{k: v for k, v in opts.items() if k not in _TRACKER_KEYS})
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: tracker: {e}") from e
    kin_model = opts.get("kin_model", "learned")
    named = isinstance(kin_model, str) and kin_model in TRACKER_KIN_MODELS
    if named or isinstance(kin_model, TrackKinModel):
        return params, kin_model
    if not isinstance(kin_model, str | Path):
        raise ValueError(f"{where}: tracker['kin_model'] must be one of {list(TRACKER_KIN_MODELS)} or a path "
                         f"to a track-classifier JSON, got {kin_model!r}")  # fmt: skip
    try:
        return params, TrackKinModel.load(kin_model)  # loaded once: every reset reuses it
    except ValueError as e:
        raise ValueError(f"{where}: tracker['kin_model'] must be one of {list(TRACKER_KIN_MODELS)} or a path "
                         f"to a track-classifier JSON, got {kin_model!r}: {e}") from e


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
    ``detectors.LearnedKinDetector()`` (the shipped checkpoint's ``.npz`` form: no torch needed); ``"beam"`` →
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
                f"available ({e}); reinstall kin-envs (its base install runs the learned detector) or pass "
                "detector='geometric', None or a detector object"
            ) from e
        return LearnedKinDetector()
    if spec == "beam":
        from detectors.beam_detector import BeamKinDetector

        return BeamKinDetector()
    raise ValueError(f"{where}: unknown detector {spec!r}")


def detection_arrays(
    detector, ranges: np.ndarray, angles: np.ndarray, trusted: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``detector`` over every row of ``ranges`` in one call: ``(row (D,), table (D, 8))``.

    The one place where the envs read a detector's output: ``table`` holds
    :data:`DETECTION_FIELDS` ``[:8]`` (range .. n_beams) of each detection as float64, ``row`` the
    scan row it came from, in the detector's order. A detector with ``detect_arrays`` (a compact
    array result: ``scan``, ``range``, ``bearing``, ``x``, ``y``, ``score``, ``first_beam``,
    ``last_beam``, ``n_beams_on``, as attributes of ``detectors.BatchDetections`` or as a dict
    with ``n_beams``) is read without building per-detection objects.

    ``trusted=True`` (the envs, on their own lidar's scans: float64 ranges ``>= 0`` or inf, the
    lidar's fixed ``angles`` array) lets a shipped detector skip its per-call input checks
    (``_detect_arrays_trusted``, or ``_detect_table_trusted`` which returns ``(row, table)``
    itself); leave it False for any other input.
    """
    if trusted and (table := getattr(detector, "_detect_table_trusted", None)) is not None:
        return table(ranges, angles)  # the learned detector's compiled driver writes this table
    fast = getattr(detector, "_detect_arrays_trusted", None) if trusted else None
    if fast is not None:
        b = fast(ranges, angles)
    elif callable(getattr(detector, "detect_arrays", None)):
        b = detector.detect_arrays(ranges, angles)
    else:
        b = None
    if b is not None:
        # detectors.BatchDetections (attributes, ``n_beams_on``) or a plain dict of columns
        get = b.__getitem__ if isinstance(b, Mapping) else lambda k: getattr(b, k)
        beams = get("n_beams") if isinstance(b, Mapping) else b.n_beams_on
        tab = np.stack(
            [
                get("range"),
                get("bearing"),
                get("x"),
                get("y"),
                get("score"),
                get("first_beam"),
                get("last_beam"),
                beams,
            ],
            axis=1,
        )
        return np.asarray(get("scan"), dtype=np.int64), tab.astype(np.float64).reshape(-1, 8)
    if len(ranges) == 1 or not callable(getattr(detector, "detect_batch", None)):
        results = [detector.detect(r, angles) for r in ranges]
    else:
        results = detector.detect_batch(ranges, angles)
    owner, rows = [], []
    for b, res in enumerate(results):
        for d in res.detections:
            owner.append(b)
            rows.append((d.range, d.bearing, d.x, d.y, d.score, d.first_beam, d.last_beam, d.n_beams))
    return np.asarray(owner, dtype=np.int64), np.array(rows, dtype=np.float64).reshape(-1, 8)


def detect_rows(
    detector,
    ranges: np.ndarray,
    angles: np.ndarray,
    observers: np.ndarray,
    poses: np.ndarray,
    robot_world: np.ndarray | None = None,
    trusted: bool = False,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Detect kin in each row of ``ranges`` and match every detection to ground truth.

    Args:
        detector: object with ``detect`` (and optionally ``detect_batch``).
        ranges: ``(B, n_beams)`` scans, m.
        angles: ``(n_beams,)`` beam angles, rad.
        observers: ``(B,)`` robot index (into ``poses``) of each row.
        poses: ``(N, 3)`` all robots' poses (for the ``kin_index`` match).
        robot_world: ``(N,)`` world of each robot when ``poses`` stacks several worlds (a detection
            only matches robots of its observer's world); ``None`` = one world.
        trusted: the scans come from the env's own lidar (see :func:`detection_arrays`).

    Returns:
        ``(row, cols)``: flat columns (:data:`DETECTION_FIELDS`) sorted by row, then nearest
        first, and the row of each detection. ``kin_index`` is the robot (index into ``poses``)
        whose centre is within :data:`KIN_MATCH_TOLERANCE` of the detected centre (privileged
        ground truth, for evaluation and rendering), or -1 for a false detection.
    """
    owner_a, tab = detection_arrays(detector, ranges, angles, trusted)
    if not len(owner_a):  # nothing detected (most steps of a one-robot env): skip the matching
        cols = {name: np.zeros(0) for name in DETECTION_FIELDS[:5]}
        for name in DETECTION_FIELDS[5:8]:
            cols[name] = np.zeros(0, dtype=np.int64)
        cols["kin_index"] = np.zeros(0, dtype=np.int64)
        return np.zeros(0, dtype=np.int64), cols
    if len(ranges) == 1 and robot_world is None:
        return owner_a, _match_one_row(tab, int(np.asarray(observers)[0]), poses)
    if robot_world is None and (owner_a.size < 2 or bool((owner_a[1:] >= owner_a[:-1]).all())):
        # a swarm's step (rows in order, as the shipped detectors give them): one compiled call
        return owner_a, _match_rows(tab, owner_a, observers, poses)
    return owner_a, _match_rows_numpy(tab, owner_a, observers, poses, robot_world, len(ranges) == 1)


def _match_rows(tab: np.ndarray, owner: np.ndarray, observers, poses: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`_match_rows_numpy` for one world and ``owner`` sorted: each row's detections sorted and
    matched by :func:`_match_one_row_kernel` (the same values, ``tests/kin_envs/envs/
    test_detection_glue.py``), all rows in one compiled call instead of a ``(D, N)`` distance matrix
    and ~30 numpy calls (~0.9 -> ~0.3 ms per 64-robot step, ~1,600 detections, under load)."""
    flo, ints = _match_rows_kernel(
        np.ascontiguousarray(tab, dtype=np.float64), np.ascontiguousarray(owner, dtype=np.int64),
        np.ascontiguousarray(observers, dtype=np.int64), np.ascontiguousarray(poses, dtype=np.float64),
        KIN_MATCH_TOLERANCE**2,
    )  # fmt: skip
    return _detection_cols(flo, ints)


@numba.njit(cache=True, nogil=True)
def _match_rows_kernel(tab, owner, observers, poses, tol2):
    """:func:`_match_one_row_kernel` on each run of equal ``owner`` (non-decreasing) with observer
    ``observers[owner]``: ``(floats (5, D), ints (4, D))`` in row order, each row nearest first."""
    n_det = tab.shape[0]
    flo = np.empty((5, n_det))
    ints = np.empty((4, n_det), dtype=np.int64)
    i = 0
    while i < n_det:
        e = i
        while e < n_det and owner[e] == owner[i]:
            e += 1
        f, k = _match_one_row_kernel(tab[i:e], observers[owner[i]], poses, tol2)
        flo[:, i:e] = f
        ints[:, i:e] = k
        i = e
    return flo, ints


#: pad values of the int detection fields (first_beam, last_beam, n_beams, kin_index): _match_pad_kernel
_INT_PADS = np.array([PAD_VALUES[f] for f in DETECTION_FIELDS[5:]], dtype=np.int64)


def detect_rows_padded(
    detector,
    ranges: np.ndarray,
    angles: np.ndarray,
    observers: np.ndarray,
    poses: np.ndarray,
    slots: int,
    trusted: bool = False,
    hits: tuple[np.ndarray, np.ndarray] | None = None,
    flat: bool = True,
) -> tuple[tuple[np.ndarray, dict[str, np.ndarray]] | None, tuple[dict[str, np.ndarray], np.ndarray]]:
    """:func:`detect_rows` and its padded info columns in one: ``((row, cols), (padded, count))``, the
    same values as ``detect_rows(...)`` followed by :func:`kin_envs.envs.info.pad_rows` ``(row, cols,
    len(ranges), slots)`` (one world; ``tests/kin_envs/envs/test_detection_glue.py``).

    A swarm step's sorting, ground-truth matching and padding run in one compiled call
    (:func:`_match_pad_kernel`) instead of a matching call, ~20 numpy calls of padding and a dict of
    fresh arrays per field. ``hits``: the scan's ``(hit_kind, hit_index)`` (``(len(ranges), n_beams)``
    each, as :class:`kin_envs.core.world.Scan` has them): the robot a detection's first beam hit is
    tried first, which settles most matches without a search (the same values with or without it).
    The padded ``(len(ranges), slots)`` columns are rows of two fresh blocks (floats, ints), the flat
    columns rows of two more: every array is new on every call. ``flat=False``: the padded columns only
    (``None`` in place of ``(row, cols)``), for a step that reads nothing else (no tracker, no detection
    channel in the observation, no rendering): a row's detections past its ``slots`` are then neither
    matched nor copied."""
    owner, tab = detection_arrays(detector, ranges, angles, trusted)
    row, flo, ints, pf, pi, count = _match_pad(owner, tab, observers, poses, len(ranges), slots, hits, flat)
    padded = (_detection_cols(pf, pi), count)
    return ((row, _detection_cols(flo, ints)) if flat else None), padded


#: ``{field: value}`` over :data:`DETECTION_FIELDS` as one dict display (the same dict as ``dict(zip(...))``)
_DETECTION_DICT = dict_maker(DETECTION_FIELDS)


@functools.cache
def _learned_match_pad():
    """:func:`kin_envs.envs._detector_pad.learned_match_pad`, imported on first use (it imports the
    detectors package, which ``import kin_envs`` does not)."""
    from kin_envs.envs._detector_pad import learned_match_pad

    return learned_match_pad


def _padded_in_detector(detector, ranges, angles, observers, poses, slots: int, hits):
    """``(padded floats, padded ints, count)`` of :func:`_match_pad_kernel` (``flat=False``) on the detector's
    table, matched and padded inside the detector's own compiled call (a learned detector's
    ``_detect_table_then``: :func:`kin_envs.envs._detector_pad.learned_match_pad`), or ``None`` for a
    detector without it (then :func:`detection_arrays` and :func:`_match_pad`). The same values: one
    dispatch instead of two, and the table does not cross into Python and back.

    Taken for one observer's scan (:func:`detect_one_padded`: KinSeek's learned step 4-7 µs cheaper, same
    process, alternating blocks) but not for a swarm's batch, where the same call read 10-50 µs *slower* at
    64 robots (the driver's code compiled again inside the new function; not understood)."""
    then = getattr(detector, "_detect_table_then", None)
    if then is None:
        return None
    hit_kind, hit_index = _NO_HITS if hits is None else hits
    match = (np.ascontiguousarray(observers, dtype=np.int64), np.ascontiguousarray(poses, dtype=np.float64),
             KIN_MATCH_TOLERANCE**2, slots, _INT_PADS, hit_kind, hit_index, _ROBOT_HIT)  # fmt: skip
    return then(_learned_match_pad(), ranges, angles, match)


def _match_pad(owner, tab, observers, poses, n_rows: int, slots: int, hits, flat: bool):
    """:func:`_match_pad_kernel` on a detector's ``(owner, table)`` with the env's constants (one compiled
    signature: contiguous float64 / int64 inputs; no lidar hits when ``hits`` is None)."""
    hit_kind, hit_index = _NO_HITS if hits is None else hits
    return _match_pad_kernel(
        np.ascontiguousarray(tab, dtype=np.float64), np.ascontiguousarray(owner, dtype=np.int64),
        np.ascontiguousarray(observers, dtype=np.int64), np.ascontiguousarray(poses, dtype=np.float64),
        KIN_MATCH_TOLERANCE**2, n_rows, slots, _INT_PADS, hit_kind, hit_index, _ROBOT_HIT, bool(flat),
    )  # fmt: skip


def detect_one_padded(
    detector,
    ranges: np.ndarray,
    angles: np.ndarray,
    observer: int,
    poses: np.ndarray,
    slots: int,
    hits: tuple[np.ndarray, np.ndarray] | None = None,
    flat: bool = True,
) -> tuple[tuple[np.ndarray, dict[str, np.ndarray]] | None, dict[str, np.ndarray], int]:
    """One observer's detections on the env's own lidar scan (``ranges`` ``(1, n_beams)``, trusted; KinSeek
    / KinFollow every step): ``(flat (row, cols) or None, padded {field: (slots,)}, count)``, the values of
    :func:`detect_rows` then :func:`kin_envs.envs.info.pad_rows` ``(row, cols, 1, slots)`` with each padded
    field's one row (the single-robot envs' ``info["kin_detections"]``; ``tests/kin_envs/envs/
    test_detection_glue.py``). The match, the sort and the padding in one compiled call
    (:func:`_match_pad_kernel` on one row) instead of a matching call, a padding call and their dicts;
    ``flat=False`` as in :func:`detect_rows_padded`. Every array is new on every call."""
    if not flat and (res := _padded_in_detector(detector, ranges, angles, _one_observer(observer), poses,
                                                slots, hits)) is not None:  # fmt: skip
        pf, pi, count = res
        return None, _DETECTION_DICT(*pf.reshape(5, slots), *pi.reshape(4, slots)), int(count[0])
    owner, tab = detection_arrays(detector, ranges, angles, True)
    if not len(owner):  # nothing detected (most steps of a one-robot env): copies of the empty slots
        pf, pi = _empty_slots(slots)
        padded = dict(zip(DETECTION_FIELDS, (*pf.copy(), *pi.copy()), strict=True))
        if not flat:
            return None, padded, 0
        empty = _detection_cols(np.zeros((5, 0)), np.zeros((4, 0), dtype=np.int64))
        return (np.zeros(0, dtype=np.int64), empty), padded, 0
    observers = np.array([observer], dtype=np.int64)
    row, flo, ints, pf, pi, count = _match_pad(owner, tab, observers, poses, 1, slots, hits, flat)
    padded = dict(zip(DETECTION_FIELDS, (*pf.reshape(5, slots), *pi.reshape(4, slots)), strict=True))
    return ((row, _detection_cols(flo, ints)) if flat else None), padded, int(count[0])


@functools.lru_cache(maxsize=256)
def _one_observer(observer: int) -> np.ndarray:
    """``observers`` of one row, ``[observer]`` (read-only, kept: one allocation fewer per step)."""
    a = np.array([observer], dtype=np.int64)
    a.flags.writeable = False
    return a


@functools.lru_cache(maxsize=64)
def _empty_slots(slots: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only ``(5, slots)`` float and ``(4, slots)`` int blocks of empty detection slots (``PAD_VALUES``;
    callers copy them)."""
    pf = np.zeros((5, slots))
    pi = np.repeat(_INT_PADS[:, None], slots, axis=1)
    pf.flags.writeable = pi.flags.writeable = False
    return pf, pi


#: no lidar hits for _match_pad_kernel (every match searched), in the lidar's dtypes (int8, int32)
_NO_HITS = (np.zeros((0, 0), dtype=np.int8), np.zeros((0, 0), dtype=np.int32))
#: HitKind.ROBOT as the lidar's hit_kind dtype
_ROBOT_HIT = np.int8(HitKind.ROBOT.value)


def _detection_cols(flo: np.ndarray, ints: np.ndarray) -> dict[str, np.ndarray]:
    """:data:`DETECTION_FIELDS` as rows of a float block (range .. score) and an int block."""
    return dict(zip(DETECTION_FIELDS, (*flo, *ints), strict=True))


@numba.njit(cache=True, nogil=True, inline="always")
def _sort_by_range(tab, order, lo, hi):
    """Stable insertion sort of ``order[lo:hi]`` by the detections' range ``tab[order, 0]``, NaN last (as
    ``np.argsort(kind="stable")``): rows hold a handful to a few dozen detections."""
    for i in range(lo + 1, hi):
        oi = order[i]
        key = tab[oi, 0]
        j = i
        while j > lo:
            prev = tab[order[j - 1], 0]
            if prev > key or (math.isnan(prev) and not math.isnan(key)):
                order[j] = order[j - 1]
                j -= 1
            else:
                break
        order[j] = oi


#: rows longer than this are insertion-sorted (a swarm step's rows hold ~15 detections, rarely 40)
_RANK_SORT_MAX = 64


@numba.njit(cache=True, nogil=True, inline="always")
def _rank_sort_by_range(tab, order, lo, hi, keys, idx):
    """:func:`_sort_by_range` of ``order[lo:hi]`` by ranks counted without branches: a detection's place is
    the number of others before it in the stable order (``<=`` for the ones before it, ``<`` after), so no
    comparison's outcome steers the flow (the insertion sort's exits mispredict: the 64-robot learned call
    46-53 -> 39-47 µs in a warm loop, measured). A row with a NaN range takes :func:`_sort_by_range`
    (NaN last), and so does a row of more than :data:`_RANK_SORT_MAX` detections (the ranks' quadratic
    count). ``keys``, ``idx``: scratch of at least ``min(hi - lo, _RANK_SORT_MAX)``."""
    m = hi - lo
    if m > _RANK_SORT_MAX:
        _sort_by_range(tab, order, lo, hi)
        return
    nan = False
    for i in range(m):
        o = order[lo + i]
        k = tab[o, 0]
        keys[i] = k
        idx[i] = o
        nan |= k != k
    if nan:
        _sort_by_range(tab, order, lo, hi)
        return
    for i in range(m):
        ki = keys[i]
        c = 0
        for j in range(i):
            c += keys[j] <= ki
        for j in range(i + 1, m):
            c += keys[j] < ki
        order[lo + c] = idx[i]


@numba.njit(cache=True, nogil=True, inline="always")
def _take_detection(tab, t, k, flo, ints, ox, oy, c, s):
    """Column ``k`` of ``flo`` (range .. score) and ``ints[:3]`` (beams) from table row ``t``; returns the
    detection's centre in the world from the observer at ``(ox, oy)`` with heading cos/sin ``c, s`` (the
    numpy path's expressions, term by term)."""
    for f in range(5):
        flo[f, k] = tab[t, f]
    for f in range(3):
        ints[f, k] = np.int64(tab[t, 5 + f])
    return ox + c * tab[t, 2] - s * tab[t, 3], oy + s * tab[t, 2] + c * tab[t, 3]


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_kin_brute(wx, wy, obs, poses, tol2):
    """The match of one detection centre ``(wx, wy)`` (:func:`_match_one_row_kernel`'s, and
    :func:`_match_pad_kernel`'s where a pose is not finite): the nearest robot other than ``obs`` (the
    first of equals) within ``sqrt(tol2)``, -1 if none or a distance is NaN."""
    best = -1
    best_d2 = math.inf
    nan_first = -1
    for q in range(poses.shape[0]):
        dx = wx - poses[q, 0]
        dy = wy - poses[q, 1]
        d2 = dx * dx + dy * dy
        if q == obs:
            d2 = math.inf
        if math.isnan(d2):
            if nan_first < 0:
                nan_first = q
        elif best < 0 or d2 < best_d2:
            best = q
            best_d2 = d2
    return best if (nan_first < 0 and best >= 0 and best_d2 <= tol2) else -1


@numba.njit(cache=True, nogil=True, inline="always")
def _min_separation2(poses, xs, xs_order):
    """The smallest squared distance between two robots' centres (``inf`` for one robot), each pair's
    computed as the match computes distances, in a sweep over the robots sorted by x (``xs``,
    ``xs_order``): a pair whose x gap alone reaches the minimum so far ends its robot's scan."""
    n_rob = xs.shape[0]
    smin2 = math.inf
    for a in range(n_rob):
        qa = xs_order[a]
        for b in range(a + 1, n_rob):
            dx = xs[b] - xs[a]
            if dx * dx >= smin2:
                break
            dy = poses[xs_order[b], 1] - poses[qa, 1]
            d2 = dx * dx + dy * dy
            if d2 < smin2:
                smin2 = d2
    return smin2


@numba.njit(cache=True, nogil=True, inline="always")
def _detection_blocks(n_flat, n_rows, slots, int_pads):
    """``(row (n_flat,), floats (5, n_flat), ints (4, n_flat), padded floats (5, n_rows, slots), padded
    ints (4, n_rows, slots))``, the padded blocks filled with ``pad_rows``' values (``int_pads``; the
    floats' pad is 0), the flat ones to be written by :func:`_put_detection`."""
    row = np.empty(n_flat, dtype=np.int64)
    flo = np.empty((5, n_flat))
    ints = np.empty((4, n_flat), dtype=np.int64)
    pf = np.zeros((5, n_rows, slots))
    pi = np.empty((4, n_rows, slots), dtype=np.int64)
    for f in range(4):
        pi[f] = int_pads[f]
    return row, flo, ints, pf, pi


@numba.njit(cache=True, nogil=True, inline="always")
def _put_detection(tab, t, r, k, slot, slots, kin, flat, row, flo, ints, pf, pi):
    """Table row ``t`` of scan row ``r``, matched to robot ``kin`` (-1: none), into flat column ``k``
    (when ``flat``) and padded slot ``slot`` of row ``r`` (when ``slot < slots``); shared by the
    single-env and the vector env's kernels so that both write the same columns."""
    if flat:
        row[k] = r
        for f in range(5):
            flo[f, k] = tab[t, f]
        for f in range(3):
            ints[f, k] = np.int64(tab[t, 5 + f])
        ints[3, k] = kin
    if slot < slots:
        for f in range(5):
            pf[f, r, slot] = tab[t, f]
        for f in range(3):
            pi[f, r, slot] = np.int64(tab[t, 5 + f])
        pi[3, r, slot] = kin


@numba.njit(cache=True, nogil=True)
def _match_pad_kernel(
    tab, owner, observers, poses, tol2, n_rows, slots, int_pads, hit_kind, hit_index, robot_kind, flat=True
):
    """:func:`detect_rows_padded`'s work: ``(row (D,), floats (5, D), ints (4, D), padded floats (5,
    n_rows, slots), padded ints (4, n_rows, slots), count (n_rows,))``; ``flat=False``: the flat three empty
    (``D = 0``) and each row's detections past its ``slots`` skipped (neither matched nor copied).

    Detections grouped by ``owner`` (a stable counting sort: any order of rows is accepted), each row's
    sorted by range as :func:`_match_one_row_kernel` sorts them (stable, NaN last) and matched as it
    matches them: the nearest robot other than the observer, the first of equals, when within
    ``sqrt(tol2)``; the padded blocks hold each row's first ``slots`` (``pad_rows``' pad values
    elsewhere). Poses with a non-finite x or y take the brute force (:func:`_nearest_kin_brute`).
    Two ways to the same match:

    * the lidar's candidate: the robot that the detection's first beam hit (``hit_kind ==
      robot_kind``, ``hit_index``: the scan's ``(n_rows, n_beams)`` arrays, or ``(0, 0)`` arrays for
      none). Robots' centres are at least ``S`` apart (this call's smallest separation, ``S²`` from
      :func:`_min_separation2`), so a candidate closer than ``S / 2`` to the detected centre is
      strictly nearer than any other robot (triangle inequality); the test ``4 d² (1 + 1e-9) < S²``
      leaves a margin far above the rounding of ``d²``, ``S²`` and every other robot's distance.
      Within the tolerance it is the match, whichever robot the lidar named (a wrong candidate only
      fails the test). ~95 % of a swarm step's detections, no search, well-predicted branches: ~20 %
      off this call in a 64-robot step, measured;
    * otherwise the robots whose x lies within the tolerance (robots sorted by x, a binary search per
      detection: ~2 candidates instead of every robot), keeping the smallest (distance, index): the
      brute force's nearest-first-of-equals whenever it is within the tolerance, the same arithmetic
      per candidate."""
    n_det = tab.shape[0]
    n_rob = poses.shape[0]
    for i in range(n_det):
        if owner[i] < 0 or owner[i] >= n_rows:
            raise ValueError("detection rows must be scan rows in [0, len(ranges))")
    # stable counting sort by row
    start = np.zeros(n_rows + 1, dtype=np.int64)
    for i in range(n_det):
        start[owner[i] + 1] += 1
    for r in range(n_rows):
        start[r + 1] += start[r]
    fill = start[:-1].copy()
    order = np.empty(n_det, dtype=np.int64)
    for i in range(n_det):
        r = owner[i]
        order[fill[r]] = i
        fill[r] += 1
    # robots sorted by x for the windowed match (all poses finite), else the brute force
    finite = True
    for q in range(n_rob):
        if not (math.isfinite(poses[q, 0]) and math.isfinite(poses[q, 1])):
            finite = False
    xs_order = np.argsort(poses[:, 0]) if finite else np.arange(n_rob)
    xs = np.empty(n_rob)
    for j in range(n_rob):
        xs[j] = poses[xs_order[j], 0]
    # a candidate's x is within the tolerance (with a margin for the rounding of dx, d2)
    reach = math.sqrt(tol2) * 1.000001 + 1e-9
    hits = finite and hit_kind.shape[0] == n_rows and hit_index.shape == hit_kind.shape
    n_beams = hit_kind.shape[1]
    sep2 = _min_separation2(poses, xs, xs_order) if hits else 0.0

    row, flo, ints, pf, pi = _detection_blocks(n_det if flat else 0, n_rows, slots, int_pads)
    count = np.empty(n_rows, dtype=np.int64)
    longest = 0
    for r in range(n_rows):
        longest = max(longest, min(start[r + 1] - start[r], _RANK_SORT_MAX))
    keys = np.empty(longest)
    idx = np.empty(longest, dtype=np.int64)
    for r in range(n_rows):
        lo, hi = start[r], start[r + 1]
        count[r] = min(hi - lo, slots)
        _rank_sort_by_range(tab, order, lo, hi, keys, idx)  # a row holds a few dozen detections
        if hi == lo:
            continue
        obs = observers[r]
        th = poses[obs, 2]
        c = math.cos(th)
        s = math.sin(th)
        ox = poses[obs, 0]
        oy = poses[obs, 1]
        # without the flat columns, a row's detections past its slots are not needed at all
        for k in range(lo, hi if flat else min(hi, lo + slots)):
            t = order[k]
            wx = ox + c * tab[t, 2] - s * tab[t, 3]  # the numpy path's expressions, term by term
            wy = oy + s * tab[t, 2] + c * tab[t, 3]
            found = False
            best = -1
            if hits:
                b0 = np.int64(tab[t, 5])  # the first beam
                if 0 <= b0 < n_beams and hit_kind[r, b0] == robot_kind:
                    q = np.int64(hit_index[r, b0])
                    if 0 <= q < n_rob and q != obs:
                        dx = wx - poses[q, 0]
                        dy = wy - poses[q, 1]
                        d2 = dx * dx + dy * dy
                        if d2 <= tol2 and d2 * 4.000000004 < sep2:
                            best = q
                            found = True
            if found:
                pass
            elif not finite:
                best = _nearest_kin_brute(wx, wy, obs, poses, tol2)
            elif not (math.isfinite(wx) and math.isfinite(wy)):
                best = -1  # every distance NaN or inf: the brute force matches nothing
            else:
                best_d2 = math.inf
                a, b = 0, n_rob  # first robot with x >= wx - reach
                x_lo = wx - reach
                while a < b:
                    m = (a + b) >> 1
                    if xs[m] < x_lo:
                        a = m + 1
                    else:
                        b = m
                x_hi = wx + reach
                while a < n_rob and xs[a] <= x_hi:
                    q = xs_order[a]
                    a += 1
                    if q == obs:
                        continue
                    dx = wx - poses[q, 0]
                    dy = wy - poses[q, 1]
                    d2 = dx * dx + dy * dy
                    if d2 <= tol2 and (d2 < best_d2 or (d2 == best_d2 and q < best)):
                        best = q
                        best_d2 = d2
            _put_detection(tab, t, r, k, k - lo, slots, best, flat, row, flo, ints, pf, pi)
    return row, flo, ints, pf, pi, count


def _match_rows_numpy(tab, owner_a, observers, poses, robot_world, one_row=False) -> dict[str, np.ndarray]:
    """:func:`detect_rows`' columns for several rows (the general path and the reference of
    :func:`_match_rows`)."""
    obs_idx = np.asarray(observers, dtype=np.int64)[owner_a]
    px, py, th = poses[obs_idx, 0], poses[obs_idx, 1], poses[obs_idx, 2]
    c, s = np.cos(th), np.sin(th)
    wx = px + c * tab[:, 2] - s * tab[:, 3]
    wy = py + s * tab[:, 2] + c * tab[:, 3]
    d2 = (wx[:, None] - poses[None, :, 0]) ** 2 + (wy[:, None] - poses[None, :, 1]) ** 2
    d2[np.arange(len(obs_idx)), obs_idx] = np.inf  # never match the observer itself
    if robot_world is not None:
        d2[robot_world[None, :] != robot_world[obs_idx][:, None]] = np.inf
    if len(obs_idx):
        nearest = np.argmin(d2, axis=1)
        ok = d2[np.arange(len(nearest)), nearest] <= KIN_MATCH_TOLERANCE**2
        kin_index = np.where(ok, nearest, -1)
    else:
        kin_index = np.zeros(0, dtype=np.int64)
    # nearest first within each row: sort by (row, range)
    # (one row: a stable sort by range alone is the same order, cheaper than lexsort)
    order = np.argsort(tab[:, 0], kind="stable") if one_row else np.lexsort((tab[:, 0], owner_a))
    tab, kin_index = tab[order], kin_index[order]
    cols = {name: tab[:, k].copy() for k, name in enumerate(DETECTION_FIELDS[:5])}
    for k, name in enumerate(DETECTION_FIELDS[5:8], start=5):
        cols[name] = tab[:, k].astype(np.int64)
    cols["kin_index"] = kin_index.astype(np.int64)
    return cols


def _match_one_row(tab: np.ndarray, obs: int, poses: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`detect_rows`'s columns for one observer (KinSeek/KinFollow every step): one compiled
    call (:func:`_match_one_row_kernel`) instead of ~20 numpy calls on a few detections."""
    flo, ints = _match_one_row_kernel(
        np.ascontiguousarray(tab, dtype=np.float64), obs, np.ascontiguousarray(poses, dtype=np.float64),
        KIN_MATCH_TOLERANCE**2,
    )  # fmt: skip
    return _detection_cols(flo, ints)


@numba.njit(cache=True, nogil=True)
def _match_one_row_kernel(tab, obs, poses, tol2):
    """:func:`_match_one_row_numpy` compiled: ``(floats (5, D), ints (4, D))``, the same values.

    A stable sort by range (NaN last, as ``np.argsort``), then each detection's centre in the world
    (the same expressions, term by term) matched to the nearest other robot (the first of equals,
    as ``np.argmin``) within ``sqrt(tol2)``. Fresh arrays on every call."""
    n_det = tab.shape[0]
    order = np.arange(n_det)
    _sort_by_range(tab, order, 0, n_det)  # a handful of detections
    flo = np.empty((5, n_det))
    ints = np.empty((4, n_det), dtype=np.int64)
    th = poses[obs, 2]
    c = math.cos(th)
    s = math.sin(th)
    for k in range(n_det):
        wx, wy = _take_detection(tab, order[k], k, flo, ints, poses[obs, 0], poses[obs, 1], c, s)
        ints[3, k] = _nearest_kin_brute(wx, wy, obs, poses, tol2)
    return flo, ints


def _match_one_row_numpy(tab: np.ndarray, obs: int, poses: np.ndarray) -> dict[str, np.ndarray]:
    """The numpy reference of :func:`_match_one_row` (tests compare the two): the same arithmetic
    as :func:`detect_rows`' general path (the observer's cos/sin as 1-element arrays), sorted first
    as matching is per detection."""
    tab = tab[np.argsort(tab[:, 0], kind="stable")]
    th = poses[obs : obs + 1, 2]
    c, s = np.cos(th), np.sin(th)
    wx = poses[obs, 0] + c * tab[:, 2] - s * tab[:, 3]
    wy = poses[obs, 1] + s * tab[:, 2] + c * tab[:, 3]
    d2 = (wx[:, None] - poses[None, :, 0]) ** 2 + (wy[:, None] - poses[None, :, 1]) ** 2
    d2[:, obs] = np.inf  # never match the observer itself
    nearest = np.argmin(d2, axis=1)
    ok = d2[np.arange(len(nearest)), nearest] <= KIN_MATCH_TOLERANCE**2
    cols_t = tab.T.copy()  # one block; each field a row of it (no two fields overlap)
    ints = cols_t[5:8].astype(np.int64)
    cols = {name: cols_t[k] for k, name in enumerate(DETECTION_FIELDS[:5])}
    for k, name in enumerate(DETECTION_FIELDS[5:8]):
        cols[name] = ints[k]
    cols["kin_index"] = np.where(ok, nearest, -1).astype(np.int64)
    return cols


def split_rows(row: np.ndarray, cols: dict[str, np.ndarray], n_rows: int) -> list[dict[str, np.ndarray]]:
    """Flat columns sorted by row → one column dict per row (the variable-length layout)."""
    bounds = np.searchsorted(row, np.arange(n_rows + 1)).tolist()
    return [
        {name: col[lo:hi] for name, col in cols.items()}
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)
    ]


def run_detector(
    detector, ranges: np.ndarray, angles: np.ndarray, observers: np.ndarray, poses: np.ndarray
) -> list[dict[str, np.ndarray]]:
    """:func:`detect_rows` as one column dict per row (fields :data:`DETECTION_FIELDS`, nearest
    first, variable length)."""
    row, cols = detect_rows(detector, ranges, angles, observers, poses)
    return split_rows(row, cols, len(ranges))


# --- ground truth -------------------------------------------------------------------------------


def kin_truth_rows(scan, poses: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The kin each scanned robot's lidar actually sees, for every row at once, as flat columns
    (:data:`KIN_TRUTH_FIELDS`) sorted by row, then nearest first, and the row of each entry.

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
    rows, idx, n_beams, rng, dx, dy, c, s = (a[order] for a in (rows, idx, n_beams, rng, dx, dy, c, s))
    x, y = c * dx + s * dy, c * dy - s * dx
    bearing = np.arctan2(y, x)
    cols = {
        "index": idx.astype(np.int64),
        "range": rng,
        "bearing": bearing,
        "x": x,
        "y": y,
        "n_beams": n_beams.astype(np.int64),
    }
    return rows, cols


def kin_truth_padded(scan, poses: np.ndarray, slots: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``pad_rows(*kin_truth_rows(scan, poses), n_rows, slots)`` (:func:`kin_envs.envs.info.pad_rows`):
    ``(padded (n_rows, slots) columns, count (n_rows,))``, the same values
    (``tests/kin_envs/envs/test_swarm_glue.py``), for the swarm's every step.

    One compiled pass over the lidar's own arrays (:func:`_kin_truth_pad_kernel`: each row's beams
    counted per robot, its robots sorted by the same composite key, the first ``slots`` written
    into padded blocks) instead of ~40 numpy calls over ``(n_rows, n_beams)`` temporaries; the
    headings' cos/sin and the bearings' ``arctan2`` stay numpy's (the same functions, bit for bit).
    The columns are rows of two fresh blocks (floats, ints). Poses that are not all finite take the
    numpy path."""
    op = scan.poses
    ranges = scan.ranges
    # the comparison numpy makes in kin_truth_rows: a Python float range_max is cast to the ranges'
    # dtype (NEP 50); float32 -> float64 is exact, so the kernel compares in float64
    below = float(np.asarray(scan.range_max, dtype=np.result_type(ranges.dtype, scan.range_max)))
    th = op[:, 2]
    ok, pf, pi, count = _kin_truth_pad_kernel(
        scan.hit_kind, scan.hit_index, ranges, below, np.int8(HitKind.ROBOT.value), op, poses, np.cos(th),
        np.sin(th), 2.0 * scan.range_max + 1.0, slots,
    )  # fmt: skip
    if not ok:
        from kin_envs.envs.info import pad_rows

        return pad_rows(*kin_truth_rows(scan, poses), ranges.shape[0], slots)
    np.arctan2(pf[3], pf[2], out=pf[1])  # bearing = arctan2(y, x); empty slots: arctan2(0, 0) = 0
    return dict(zip(KIN_TRUTH_FIELDS, (pi[0], pf[0], pf[1], pf[2], pf[3], pi[1]), strict=True)), count


@numba.njit(cache=True, nogil=True)
def _kin_truth_pad_kernel(hit_kind, hit_index, ranges, below, robot_kind, op, poses, c, s, key_scale, slots):
    """:func:`kin_truth_padded`'s blocks: ``(ok, floats (4, n_rows, slots): range, bearing (0 here), x,
    y; ints (2, n_rows, slots): index, n_beams; count (n_rows,))``; ``ok`` False (empty blocks) if a
    position in ``poses`` or ``op`` is not finite.

    :func:`kin_truth_rows` term by term: a row's beams with ``hit_kind == robot_kind`` and ``range <
    below`` counted per robot; its robots sorted by ``row * key_scale + range`` (stable from ascending
    robot index, as the global stable argsort of that key orders a row's robots), the first ``slots``
    kept."""
    n_rows, n_beams = ranges.shape
    n_rob = poses.shape[0]
    finite = True
    for q in range(n_rob):
        finite &= math.isfinite(poses[q, 0]) and math.isfinite(poses[q, 1])
    for r in range(n_rows):
        finite &= math.isfinite(op[r, 0]) and math.isfinite(op[r, 1])
    if not finite:  # NaN keys: the numpy path's global sort order (the caller falls back to it)
        return False, np.zeros((4, 0, slots)), np.zeros((2, 0, slots), dtype=np.int64), np.zeros(0, np.int64)
    pf = np.zeros((4, n_rows, slots))
    pi = np.empty((2, n_rows, slots), dtype=np.int64)
    pi[0] = -1  # PAD_VALUES["index"]; n_beams pads with 0
    pi[1] = 0
    count = np.empty(n_rows, dtype=np.int64)
    beams = np.zeros(n_rob, dtype=np.int64)  # per robot, this row's beams (reset after the row)
    seen = np.empty(n_rob, dtype=np.int64)  # this row's robots, first-hit order
    dxs = np.empty(n_rob)
    dys = np.empty(n_rob)
    rngs = np.empty(n_rob)
    keys = np.empty(n_rob)
    order = np.empty(n_rob, dtype=np.int64)
    for r in range(n_rows):
        k = 0
        for b in range(n_beams):
            if hit_kind[r, b] == robot_kind and ranges[r, b] < below:
                q = hit_index[r, b]
                if q < 0 or q >= n_rob:
                    raise ValueError("a robot hit's hit_index must be a robot index in [0, len(poses))")
                if beams[q] == 0:
                    seen[k] = q
                    k += 1
                beams[q] += 1
        ox = op[r, 0]
        oy = op[r, 1]
        m = 0  # order[:m]: the row's nearest so far, sorted by (key, robot index), at most ``slots``
        for j in range(k):
            q = seen[j]
            dx = poses[q, 0] - ox
            dy = poses[q, 1] - oy
            rng = np.sqrt(dx * dx + dy * dy)
            dxs[j] = dx
            dys[j] = dy
            rngs[j] = rng
            key = r * key_scale + rng
            keys[j] = key
            # (key, robot index) order: the stable sort of the robots in index order; robots beyond the
            # first ``slots`` are never written, so a full buffer's farther candidates stop at one test
            t = m
            while t > 0:
                o = order[t - 1]
                if keys[o] > key or (keys[o] == key and seen[o] > q):
                    t -= 1
                else:
                    break
            if t < slots:
                for u in range(min(m, slots - 1), t, -1):
                    order[u] = order[u - 1]
                order[t] = j
                m = min(m + 1, slots)
        count[r] = m
        cr = c[r]
        sr = s[r]
        for t in range(m):
            j = order[t]
            q = seen[j]
            pi[0, r, t] = q
            pi[1, r, t] = beams[q]
            pf[0, r, t] = rngs[j]
            pf[2, r, t] = cr * dxs[j] + sr * dys[j]
            pf[3, r, t] = cr * dys[j] - sr * dxs[j]
        for j in range(k):
            beams[seen[j]] = 0
    return True, pf, pi, count


def kin_truth(scan, poses: np.ndarray) -> list[dict[str, np.ndarray]]:
    """:func:`kin_truth_rows` as one column dict per scan row (variable length)."""
    rows, cols = kin_truth_rows(scan, poses)
    return split_rows(rows, cols, scan.ranges.shape[0])


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

    def frame(
        self, ranges: np.ndarray, detections: tuple[np.ndarray, dict[str, np.ndarray]] | None
    ) -> np.ndarray:
        """``(B, frame_dim)`` float32 from ``(B, n_beams)`` ranges and the flat detections
        ``(row, cols)`` of :func:`detect_rows` (sorted by row, nearest first)."""
        L = self.layout
        out = np.empty((ranges.shape[0], L.frame_dim), dtype=np.float32)
        np.clip(ranges * np.float32(1.0 / L.range_max), 0.0, 1.0, out=out[:, : L.n_beams])
        if L.detections is None:
            return out
        det = out[:, L.n_beams :]
        det[:] = 0.0
        row, cols = detections
        if row.size == 0:
            return out
        if L.detections == "topk":
            rank = np.arange(row.size) - np.searchsorted(row, row)
            keep = rank < L.top_k
            r, k = row[keep], 4 * rank[keep]
            b = cols["bearing"][keep]
            det[r, k] = 1.0
            det[r, k + 1] = np.minimum(cols["range"][keep] / L.range_max, 1.0)
            det[r, k + 2] = np.sin(b)
            det[r, k + 3] = np.cos(b)
        else:
            # beams first..last of each detection (wrapping across beam 0) via a difference array
            n = L.n_beams
            first, last = cols["first_beam"], cols["last_beam"]
            wrap = first > last
            diff = np.zeros((ranges.shape[0], n + 1), dtype=np.int32)
            np.add.at(diff, (row, first), 1)
            np.add.at(diff, (row, np.where(wrap, n, last + 1)), -1)
            np.add.at(diff, (row[wrap], np.zeros(int(wrap.sum()), dtype=np.int64)), 1)
            np.add.at(diff, (row[wrap], last[wrap] + 1), -1)
            det[:] = np.cumsum(diff[:, :n], axis=1) > 0
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
                f"{self.where}: {who} must be 2 numbers (left, right wheel speed in [-1, 1]), got {action!r}"
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
