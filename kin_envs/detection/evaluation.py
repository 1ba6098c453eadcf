"""Evaluate any kin detector against the world's ground truth (numpy / scipy only).

Ground truth comes from :class:`kin_envs.core.world.Scan` and the :class:`~kin_envs.core.scenes.Scene`
it was taken in:

* the **kin** of scan row ``row`` are the robots its lidar sees, ``scan.visible_robots(row)``: at
  least one *valid* beam (a reported range below ``range_max``) on their housing. A kin with no
  valid beam (occluded, out of range, every beam dropped) is not ground truth, so never "missed".
  Its centre in the observer frame comes from the poses in the scan (``scan.poses``, for robots
  that were scanned) or else from the scene (robots that have not moved since the world was built);
* the **source** of a detection is what its beams hit (``scan.hit_kind`` / ``scan.hit_index`` on
  the valid beams ``first_beam .. last_beam``): the object hit by a strict majority of them, else
  ``"mixed"`` (:func:`describe_hits`).

Detections are matched one-to-one to kin by the Hungarian algorithm on centre distance, pairs
farther apart than ``gate`` (default 0.1 m) not allowed (:func:`match_detections`). A matched
detection is a true positive, an unmatched one a false positive (labelled by its source), an
unmatched kin a false negative. With ``same_radius_separate=True`` false positives on cylinders of
the kin's radius (which no single scan can tell from a kin) are left out of the false positives
and counted on their own (:attr:`Metrics.same_radius`).

Binning (:meth:`Evaluation.by_distance`, :meth:`Evaluation.by_beams`): true positives and false
negatives fall in the bin of the kin's true range / number of valid beams; false positives in the
bin of the detection's range / beam count.

Frames and units: observer frame (x forward, y left), metres, radians CCW.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from detectors.base import Detection, KinDetector

from ..core.lidar import HitKind
from ..core.scenes import Scene
from ..core.world import Scan

__all__ = [
    "DEFAULT_GATE",
    "SAME_RADIUS_TOL",
    "DetectionOutcome",
    "Evaluation",
    "HitSource",
    "KinOutcome",
    "KinTruth",
    "Metrics",
    "describe_hits",
    "evaluate",
    "kin_truth",
    "match_detections",
    "segment_beams",
]

#: Default matching gate, m: a detection counts for a kin if their centres are this close.
DEFAULT_GATE = 0.1
#: A cylinder whose radius is within this of the kin's housing radius is a "same-radius" one, m.
SAME_RADIUS_TOL = 1e-3


# --------------------------------------------------------------------------- ground truth


@dataclass(frozen=True)
class KinTruth:
    """A kin seen by one scan row, in that observer's frame.

    Attributes:
        robot: the kin's robot index in the scene.
        x, y: its centre, m (x forward, y left).
        range: distance to its centre, m.
        bearing: direction of its centre, rad CCW, in (-pi, pi].
        n_beams: valid beams on its housing.
    """

    robot: int
    x: float
    y: float
    range: float
    bearing: float
    n_beams: int


@dataclass(frozen=True)
class HitSource:
    """What a set of beams hit (see :func:`describe_hits`).

    Attributes:
        kind: ``"kin"``, ``"cylinder"``, ``"prism"``, ``"box"``, ``"polygon"``, ``"wall"``,
            ``"boundary"``, ``"mixed"`` (no object holds a strict majority of the beams) or
            ``"nothing"`` (no beam hit anything).
        label: the key false positives are counted under, e.g. ``"prism 6 sides"``,
            ``"cylinder r=5 cm"``, ``"cylinder r=3.5 cm (kin radius)"``, ``"kin (outside gate)"``.
        index: robot index (kin) or obstacle index; -1 for boundary, mixed, nothing.
        same_radius: a cylinder of the kin's housing radius.
        size: cylinder radius, prism width (circumscribed diameter) or box width, m; NaN otherwise.
        sides: a prism's side count, 0 otherwise.
    """

    kind: str
    label: str
    index: int = -1
    same_radius: bool = False
    size: float = math.nan
    sides: int = 0


def segment_beams(first_beam: int, last_beam: int, n_beams: int) -> np.ndarray:
    """Beam indices ``first_beam .. last_beam`` in scan order, wrapping across the seam."""
    if not (0 <= first_beam < n_beams and 0 <= last_beam < n_beams):
        raise ValueError(
            f"beam indices must be in [0, {n_beams}), got first_beam={first_beam}, last_beam={last_beam}"
        )
    return (first_beam + np.arange((last_beam - first_beam) % n_beams + 1)) % n_beams


def _object_source(scene: Scene, kind: int, index: int) -> HitSource:
    if kind == HitKind.ROBOT:
        return HitSource("kin", "kin (outside gate)", index)
    if kind == HitKind.BOUNDARY:
        return HitSource("boundary", "arena boundary")
    if kind == HitKind.NONE:
        return HitSource("nothing", "nothing")
    o = scene.obstacles[index]
    if o.kind == "cylinder":
        if abs(o.radius - scene.robot.housing_radius) <= SAME_RADIUS_TOL:
            label = f"cylinder r={100 * scene.robot.housing_radius:g} cm (kin radius)"
            return HitSource("cylinder", label, index, True, o.radius)
        return HitSource("cylinder", f"cylinder r={round(100 * o.radius):d} cm", index, False, o.radius)
    if o.kind == "prism":
        return HitSource("prism", f"prism {o.sides} sides", index, size=o.width, sides=o.sides)
    if o.kind == "box":
        return HitSource("box", "box", index, size=o.width)
    return HitSource(o.kind, o.kind, index)


def describe_hits(scan: Scan, row: int, beams, scene: Scene) -> HitSource:
    """What beams ``beams`` of scan row ``row`` hit: the object a strict majority of them hit.

    Only valid beams (reported range below ``range_max``) count, as they are what a detector saw;
    if none is valid, the ground truth of all the given beams is used. Returns ``"mixed"`` when no
    object holds a strict majority and ``"nothing"`` when no beam hit anything.
    """
    b = np.asarray(beams, dtype=np.intp).reshape(-1)
    if b.size == 0:
        return HitSource("nothing", "nothing")
    valid = b[scan.ranges[row, b] < scan.range_max]
    if valid.size:
        b = valid
    kinds = scan.hit_kind[row, b].astype(np.int64)
    idx = scan.hit_index[row, b].astype(np.int64)
    counts = Counter(zip(kinds.tolist(), idx.tolist(), strict=True))
    (kind, index), n = counts.most_common(1)[0]
    if 2 * n <= b.size:
        return HitSource("mixed", "mixed")
    return _object_source(scene, kind, index)


def _robot_positions(scan: Scan, scene: Scene):
    where = {int(r): k for k, r in enumerate(np.asarray(scan.robots).tolist())}

    def position(robot: int) -> tuple[float, float]:
        if robot in where:
            x, y, _ = scan.poses[where[robot]]
            return float(x), float(y)
        r = scene.robots[robot]
        return r.x, r.y

    return position


def kin_truth(scan: Scan, row: int, scene: Scene) -> tuple[KinTruth, ...]:
    """The kin scan row ``row`` sees (at least one valid beam), sorted by robot index."""
    _check_pair(scan, scene, "kin_truth")
    if not 0 <= row < scan.ranges.shape[0]:
        raise ValueError(f"kin_truth: row must be in [0, {scan.ranges.shape[0]}), got {row}")
    position = _robot_positions(scan, scene)
    x0, y0, th = (float(v) for v in scan.poses[row])
    c, s = math.cos(th), math.sin(th)
    out = []
    for robot, n in sorted(scan.visible_robots(row).items()):
        wx, wy = position(robot)
        dx, dy = wx - x0, wy - y0
        x, y = c * dx + s * dy, -s * dx + c * dy
        out.append(KinTruth(int(robot), x, y, math.hypot(x, y), math.atan2(y, x), int(n)))
    return tuple(out)


# --------------------------------------------------------------------------- matching


def match_detections(det_xy, kin_xy, gate: float = DEFAULT_GATE) -> list[tuple[int, int, float]]:
    """One-to-one matching of detections to kin within ``gate`` m (Hungarian algorithm).

    Maximises the number of pairs closer than ``gate`` (pairs beyond it are forbidden) and, among
    those, minimises the summed centre distance. Returns ``(detection, kin, distance)`` triples.
    """
    gate = _check_gate(gate)
    d = np.asarray(det_xy, dtype=np.float64).reshape(-1, 2)
    k = np.asarray(kin_xy, dtype=np.float64).reshape(-1, 2)
    if d.shape[0] == 0 or k.shape[0] == 0:
        return []
    dist = np.hypot(d[:, None, 0] - k[None, :, 0], d[:, None, 1] - k[None, :, 1])
    ok = dist <= gate
    # a forbidden pair costs more than all allowed pairs together, so the assignment first
    # maximises the number of allowed pairs
    big = gate * (d.shape[0] + k.shape[0] + 1) + 1.0
    rows, cols = linear_sum_assignment(np.where(ok, dist, big))
    return [(int(i), int(j), float(dist[i, j])) for i, j in zip(rows, cols, strict=True) if ok[i, j]]


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class KinOutcome:
    """One ground-truth kin of one scan row and whether it was detected.

    ``scan`` indexes the evaluated ``(scan, scene)`` pairs; ``detection`` indexes
    :attr:`Evaluation.detections` (-1 if missed); ``error`` is the centre error, m (NaN if missed).
    """

    scan: int
    row: int
    noise: float
    truth: KinTruth
    detection: int = -1
    error: float = math.nan

    @property
    def detected(self) -> bool:
        return self.detection >= 0


@dataclass(frozen=True)
class DetectionOutcome:
    """One detection: matched to a kin (true positive) or not (false positive, with its source).

    ``kin`` is the matched robot index (-1 if unmatched), ``error`` the centre error, m (NaN if
    unmatched). ``bin_range`` / ``bin_beams`` are the values it is binned by: the kin's true range
    and valid beams when matched, else the detection's own.
    """

    scan: int
    row: int
    noise: float
    detection: Detection
    source: HitSource
    kin: int = -1
    error: float = math.nan
    bin_range: float = math.nan
    bin_beams: int = 0

    @property
    def matched(self) -> bool:
        return self.kin >= 0


@dataclass(frozen=True)
class Metrics:
    """Detection quality over a set of scans.

    Attributes:
        n_kin: ground-truth kin (with at least one valid beam).
        tp, fp, fn: true positives, false positives, false negatives (missed kin).
        same_radius: unmatched detections on same-radius cylinders. They are part of ``fp``
            unless the evaluation separates them (``same_radius_separate``).
        precision, recall: NaN when undefined (no detection / no kin).
        f1: ``2 tp / (2 tp + fp + fn)``; NaN only when there is neither a kin nor a detection.
        error_mean, error_median, error_p95: centre error of true positives, m (NaN if none).
    """

    n_kin: int
    tp: int
    fp: int
    fn: int
    same_radius: int
    precision: float
    recall: float
    f1: float
    error_mean: float
    error_median: float
    error_p95: float

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _metrics(kin: Sequence[KinOutcome], dets: Sequence[DetectionOutcome], separate: bool) -> Metrics:
    tp = sum(d.matched for d in dets)
    same = sum(1 for d in dets if not d.matched and d.source.same_radius)
    fp = len(dets) - tp - (same if separate else 0)
    fn = sum(not k.detected for k in kin)
    n_kin = len(kin)
    precision = tp / (tp + fp) if tp + fp else math.nan
    recall = (n_kin - fn) / n_kin if n_kin else math.nan
    # 2TP / (2TP + FP + FN): the harmonic mean of precision and recall, and 0 (not undefined) when
    # there are kin but no detections
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else math.nan
    err = np.array([d.error for d in dets if d.matched])
    if err.size:
        stats = float(err.mean()), float(np.median(err)), float(np.percentile(err, 95))
    else:
        stats = (math.nan,) * 3
    return Metrics(n_kin, tp, fp, fn, same, precision, recall, f1, *stats)


def _bin_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of each value in ``[edges[i], edges[i+1])`` (last bin closed), -1 outside."""
    i = np.searchsorted(edges, values, side="right") - 1
    i[values == edges[-1]] = len(edges) - 2
    i[(values < edges[0]) | (values > edges[-1]) | ~np.isfinite(values)] = -1
    return i


def _check_edges(edges, what: str) -> np.ndarray:
    e = np.asarray(edges, dtype=np.float64).reshape(-1)
    if e.size < 2 or np.isnan(e).any() or np.any(np.diff(e) <= 0):
        raise ValueError(f"{what}: bin edges must be >= 2 strictly increasing numbers, got {list(edges)!r}")
    return e


@dataclass(frozen=True)
class Evaluation:
    """Everything :func:`evaluate` found, plus summaries.

    Attributes:
        kin: one outcome per ground-truth kin per scan row.
        detections: one outcome per detection.
        gate: matching gate, m.
        same_radius_separate: false positives on same-radius cylinders are counted apart.
        n_scans: scan rows evaluated (one row = one observer's scan).
        seconds: wall time spent inside the detector's ``detect_batch``.
        detector: the detector's name.
    """

    kin: tuple[KinOutcome, ...]
    detections: tuple[DetectionOutcome, ...]
    gate: float = DEFAULT_GATE
    same_radius_separate: bool = False
    n_scans: int = 0
    seconds: float = 0.0
    detector: str = ""
    noise_levels: tuple[float, ...] = field(default=())

    @property
    def scans_per_second(self) -> float:
        return self.n_scans / self.seconds if self.seconds > 0 else math.nan

    def metrics(self, same_radius_separate: bool | None = None) -> Metrics:
        """Precision, recall, F1 and centre error over everything."""
        sep = self.same_radius_separate if same_radius_separate is None else same_radius_separate
        return _metrics(self.kin, self.detections, sep)

    def select(self, noise: float | None = None, scans: Iterable[int] | None = None) -> Evaluation:
        """The outcomes of one noise level and / or of some scans (indices into the pairs)."""
        keep_scans = None if scans is None else set(scans)

        def keep(o) -> bool:
            return (noise is None or math.isclose(o.noise, noise, abs_tol=1e-12)) and (
                keep_scans is None or o.scan in keep_scans
            )

        kin = tuple(k for k in self.kin if keep(k))
        dets = tuple(d for d in self.detections if keep(d))
        return replace(self, kin=kin, detections=dets)

    def _binned(self, kin_values, det_values, edges) -> list[tuple[float, float, Metrics]]:
        kb = _bin_index(np.asarray(kin_values, dtype=np.float64), edges)
        db = _bin_index(np.asarray(det_values, dtype=np.float64), edges)
        out = []
        for i in range(len(edges) - 1):
            kin = [k for k, b in zip(self.kin, kb.tolist(), strict=True) if b == i]
            dets = [d for d, b in zip(self.detections, db.tolist(), strict=True) if b == i]
            out.append((float(edges[i]), float(edges[i + 1]), _metrics(kin, dets, self.same_radius_separate)))
        return out

    def by_distance(self, edges) -> list[tuple[float, float, Metrics]]:
        """Metrics per range bin ``[lo, hi)`` (last bin closed), m: ``(lo, hi, metrics)``."""
        e = _check_edges(edges, "by_distance")
        return self._binned([k.truth.range for k in self.kin], [d.bin_range for d in self.detections], e)

    def by_beams(self, edges) -> list[tuple[float, float, Metrics]]:
        """Metrics per bin of valid beams on the kin (detections: beams on their segment)."""
        e = _check_edges(edges, "by_beams")
        return self._binned([k.truth.n_beams for k in self.kin], [d.bin_beams for d in self.detections], e)

    def by_noise(self) -> dict[float, Metrics]:
        """Metrics per lidar noise level (relative range sigma), ascending."""
        levels = sorted({o.noise for o in (*self.kin, *self.detections)} | set(self.noise_levels))
        return {lv: self.select(noise=lv).metrics() for lv in levels}

    def false_positives(self) -> dict[str, int]:
        """False positives per source label, most frequent first (same-radius cylinders are left
        out when the evaluation separates them)."""
        c = Counter(
            d.source.label
            for d in self.detections
            if not d.matched and not (self.same_radius_separate and d.source.same_radius)
        )
        return dict(sorted(c.items(), key=lambda kv: (-kv[1], kv[0])))


# --------------------------------------------------------------------------- evaluation


def _check_gate(gate) -> float:
    if (
        isinstance(gate, bool)
        or not isinstance(gate, int | float | np.floating)
        or not (math.isfinite(gate) and gate > 0)
    ):
        raise ValueError(f"gate must be a finite distance > 0 m, got {gate!r}")
    return float(gate)


def _check_pair(scan, scene, where: str) -> None:
    if not isinstance(scan, Scan):
        raise ValueError(f"{where}: expected a kin_envs Scan, got {type(scan).__name__}")
    if not isinstance(scene, Scene):
        raise ValueError(f"{where}: expected a kin_envs Scene, got {type(scene).__name__}")
    robots = np.asarray(scan.robots)
    if robots.size and (robots.min() < 0 or robots.max() >= len(scene.robots)):
        raise ValueError(
            f"{where}: the scan's robots {robots.tolist()} are not all robots of the scene "
            f"({len(scene.robots)} robots): wrong scene for this scan?"
        )


def evaluate(
    detector: KinDetector,
    pairs: Sequence[tuple[Scan, Scene]],
    *,
    gate: float = DEFAULT_GATE,
    same_radius_separate: bool = False,
    batch_size: int = 512,
    name: str | None = None,
) -> Evaluation:
    """Run ``detector`` on every row of every scan and score it against the ground truth.

    Args:
        detector: anything with the :class:`~detectors.base.KinDetector` interface; its
            ``detect_batch(ranges (B, n), angles (n,))`` is called on up to ``batch_size`` rows at a
            time (consecutive rows sharing one beam layout).
        pairs: ``(scan, scene)`` pairs: each scan with the scene its world was built from. The
            noise level of a pair is ``scene.lidar.noise_sigma``.
        gate: matching gate, m.
        same_radius_separate: count false positives on same-radius cylinders apart.
        name: detector name for reports (default: its class name).
    """
    gate = _check_gate(gate)
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"evaluate: batch_size must be an int >= 1, got {batch_size!r}")
    if not callable(getattr(detector, "detect_batch", None)):
        raise ValueError(
            f"evaluate: detector {detector!r} has no detect_batch(ranges, angles); "
            "expected a detectors.KinDetector"
        )
    pairs = list(pairs)
    rows: list[tuple[int, int]] = []
    for i, p in enumerate(pairs):
        if not (isinstance(p, tuple | list) and len(p) == 2):
            raise ValueError(f"evaluate: pairs[{i}] must be a (scan, scene) pair, got {type(p).__name__}")
        _check_pair(p[0], p[1], f"evaluate: pairs[{i}]")
        rows.extend((i, r) for r in range(p[0].ranges.shape[0]))
    results = []
    seconds = 0.0
    start = 0
    while start < len(rows):
        angles = pairs[rows[start][0]][0].angles
        stop = start + 1
        while (
            stop < len(rows)
            and stop - start < batch_size
            and np.array_equal(pairs[rows[stop][0]][0].angles, angles)
        ):
            stop += 1
        ranges = np.stack([pairs[i][0].ranges[r] for i, r in rows[start:stop]])
        t0 = time.perf_counter()
        out = detector.detect_batch(ranges, angles)
        seconds += time.perf_counter() - t0
        if len(out) != stop - start:
            raise ValueError(
                f"evaluate: detector returned {len(out)} results for a batch of {stop - start} scans"
            )
        results.extend(out)
        start = stop
    kin_out: list[KinOutcome] = []
    det_out: list[DetectionOutcome] = []
    for (i, r), res in zip(rows, results, strict=True):
        scan, scene = pairs[i]
        noise = float(scene.lidar.noise_sigma)
        truth = kin_truth(scan, r, scene)
        dets = list(res.detections)
        matches = match_detections([(d.x, d.y) for d in dets], [(k.x, k.y) for k in truth], gate)
        by_det = {di: (ki, e) for di, ki, e in matches}
        by_kin = {ki: (di, e) for di, ki, e in matches}
        n = scan.ranges.shape[1]
        first = len(det_out)
        for di, d in enumerate(dets):
            if di in by_det:
                ki, e = by_det[di]
                k = truth[ki]
                src = HitSource("kin", "kin", k.robot)
                det_out.append(DetectionOutcome(i, r, noise, d, src, k.robot, e, k.range, k.n_beams))
            else:
                src = describe_hits(scan, r, segment_beams(d.first_beam, d.last_beam, n), scene)
                det_out.append(DetectionOutcome(i, r, noise, d, src, -1, math.nan, d.range, d.n_beams))
        for ki, k in enumerate(truth):
            di, e = by_kin.get(ki, (-1, math.nan))
            kin_out.append(KinOutcome(i, r, noise, k, first + di if di >= 0 else -1, e))
    levels = tuple(sorted({float(s.lidar.noise_sigma) for _, s in pairs}))
    return Evaluation(
        tuple(kin_out),
        tuple(det_out),
        gate,
        bool(same_radius_separate),
        len(rows),
        seconds,
        name or type(detector).__name__,
        levels,
    )
