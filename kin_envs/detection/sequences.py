"""The sequence benchmark: kin tracking over time versus single-scan detection.

Episodes (seeded, versioned, seeds in the benchmark's reserved range, disjoint from its single-scan splits
and from training) are built from the detection benchmark's ``swarm`` and ``lookalike`` scene generators
(:mod:`kin_envs.detection.benchmark`) and then *run*: every robot is a scripted wanderer (constant speed,
heading re-drawn every second, backing off after a contact) except a share of kin that stay parked; static
look-alikes (7 cm prisms and boxes, cylinders of other radii and of exactly the housing radius) stay put.
Observers: every robot in ``swarm`` episodes, robot 0 (which wanders too) in ``lookalike`` ones. Each frame
(one ``World.step`` of 0.1 s) every observer's lidar is scanned with the episode's range noise, the
detector runs once permissively (its candidates feed :class:`detectors.tracking.KinTracker`, with the
world's noisy wheel odometry) and once at its operating point (the single-scan baseline).

**Ground truth and matching** are the detection benchmark's: a kin counts in a frame when at least
``MIN_BEAMS`` (2) valid beams hit its housing (1 beam: "don't care"), detections match within ``GATE``
(0.10 m, Hungarian, :func:`detectors.metrics.match`). Cylinders of exactly the housing radius are
"don't care" for P / R / F1 and reported on their own. The tracker reports a kin for every confirmed
track whose kin probability is at least its ``kin_threshold``.

**Metrics** (per split and noise level, tracker and single-scan detectors alike where they apply):

- per-frame P / R / F1 against *frames since the object came into view* (its current run of frames with
  >= 1 valid beam, binned 1, 2-4, 5-9, 10-19, 20+: the ``1, 2, 5, 10, 20`` columns) and against the
  distance bins of the detection benchmark; a false positive is binned by the object nearest to it (its
  visibility age and distance), or by the frame number when nothing is within 0.2 m;
- time to confirm a kin: frames from coming into view (>= 2 beams) to its first true positive;
- false tracks per minute of observation: distinct track ids reported as kin that never matched a kin;
- CLEAR MOT's MOTA, identity switches and IDF1 (``motmetrics``, per observer sequence, gate 0.10 m);
- same-radius cylinders: the share of frames in which a visible one is *not* reported, counted once
  every kin the observer has seen so far has moved at least 0.2 m;
- time: the tracker's update against the detector's per-frame time (all observers batched).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from detectors.base import KinDetector
from detectors.features import scan_noise, segment_batch
from detectors.metrics import match, prf1
from detectors.tracking import KinTracker, TrackerParams, segment_points

from ..core.lidar import HitKind
from ..core.scenes import Cylinder
from ..core.world import World
from .benchmark import (
    BENCHMARK_SEEDS,
    DISTANCE_EDGES,
    GATE,
    MIN_BEAMS,
    SPLITS,
    Condition,
    LookalikeConfig,
    SwarmConfig,
    apply_condition,
    lookalike_scene,
    permissive,
    swarm_scene,
)

__all__ = [
    "AGE_EDGES",
    "SEQUENCE_SPLITS",
    "SEQUENCE_VERSION",
    "SequenceConfig",
    "SequenceSpec",
    "episode",
    "run_sequences",
]

#: Bumped whenever an episode generator, the ground truth or a metric changes.
SEQUENCE_VERSION = 1
#: Frames since an object came into view: bins [1], [2, 5), [5, 10), [10, 20), [20, inf).
AGE_EDGES = (1, 2, 5, 10, 20)
SAME_RADIUS_TOL = 1e-3  # m
MOVED = 0.2  # m: "every kin in view has moved" (same-radius cylinder rejection)
_FRAME_S = 0.1


@dataclass(frozen=True)
class SequenceConfig:
    """How an episode runs.

    Attributes:
        frames: frames (0.1 s steps) per episode.
        parked_prob: share of kin that stay still for the whole episode (never the observer).
        speed: (min, max) forward speed of the wanderers, m/s.
        turn: largest yaw rate a wanderer re-draws every second, rad/s.
    """

    frames: int = 40
    parked_prob: float = 0.3
    speed: tuple[float, float] = (0.08, 0.25)
    turn: float = 1.2

    def __post_init__(self) -> None:
        if (
            isinstance(self.frames, bool)
            or not isinstance(self.frames, int)
            or not 1 <= self.frames <= 10_000
        ):
            raise ValueError(f"SequenceConfig.frames must be an integer in [1, 10000], got {self.frames!r}")
        if not (isinstance(self.parked_prob, int | float) and 0 <= self.parked_prob <= 1):
            raise ValueError(f"SequenceConfig.parked_prob must be in [0, 1], got {self.parked_prob!r}")
        sp = tuple(float(v) for v in self.speed)
        if len(sp) != 2 or not 0 <= sp[0] <= sp[1] <= 0.33:
            raise ValueError(
                f"SequenceConfig.speed must be (min, max), 0 <= min <= max <= 0.33 m/s, got {self.speed!r}"
            )
        object.__setattr__(self, "speed", sp)
        if not (isinstance(self.turn, int | float) and 0 <= self.turn <= 4):
            raise ValueError(f"SequenceConfig.turn must be in [0, 4] rad/s, got {self.turn!r}")


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence split: the scene generator's config, the run config and the seeds."""

    name: str
    scenes: SwarmConfig | LookalikeConfig
    run: SequenceConfig
    first_seed: int
    n_episodes: int
    reduced_episodes: int
    noise: tuple[float, ...] = (0.0, 0.005, 0.01)

    def seeds(self, n: int) -> range:
        if not (BENCHMARK_SEEDS.start <= self.first_seed and self.first_seed + n <= BENCHMARK_SEEDS.stop):
            raise ValueError(f"sequence split {self.name!r}: seeds leave the reserved range")
        return range(self.first_seed, self.first_seed + n)

    def to_dict(self) -> dict:
        def plain(obj):
            return {f.name: getattr(obj, f.name) for f in fields(obj)}

        return {
            "name": self.name, "scenes": plain(self.scenes), "run": plain(self.run),
            "first_seed": self.first_seed, "n_episodes": self.n_episodes,
            "reduced_episodes": self.reduced_episodes, "noise": list(self.noise),
        }  # fmt: skip


_B = BENCHMARK_SEEDS.start
#: The sequence splits (version :data:`SEQUENCE_VERSION`); seeds disjoint from the single-scan splits'.
SEQUENCE_SPLITS: dict[str, SequenceSpec] = {
    "swarm": SequenceSpec(
        "swarm", SwarmConfig(n_robots=(8, 16), motion_seconds=4.0), SequenceConfig(), _B + 30_000_000, 40, 3
    ),
    "lookalike": SequenceSpec(
        "lookalike", LookalikeConfig(distance=(0.3, 3.0)), SequenceConfig(), _B + 40_000_000, 120, 12
    ),
}
# the single-scan splits' seeds come first in the reserved range: keep them apart
assert all(
    s.first_seed >= max(p.first_seed + p.n_scenes for p in SPLITS.values()) for s in SEQUENCE_SPLITS.values()
)


@dataclass
class Episode:
    """A running episode: the world, its observers and its scripted wanderers."""

    world: World
    observers: np.ndarray
    parked: np.ndarray
    rng: np.random.Generator
    config: SequenceConfig
    condition: Condition
    _cmd: np.ndarray = field(default=None, repr=False)
    _backoff: np.ndarray = field(default=None, repr=False)

    def step(self, frame: int) -> None:
        w, c = self.world, self.config
        n = w.n_robots
        if self._cmd is None:
            self._cmd = np.zeros((n, 2))
            self._backoff = np.zeros(n, np.int64)
        if frame % int(round(1.0 / _FRAME_S)) == 0:  # re-draw every second
            self._cmd = np.c_[self.rng.uniform(*c.speed, n), self.rng.uniform(-c.turn, c.turn, n)]
        cmd = self._cmd.copy()
        hit = w.contacts != 0
        self._backoff[hit & (self._backoff == 0)] = 5
        back = self._backoff > 0
        cmd[back] = np.c_[np.full(back.sum(), -0.1), np.full(back.sum(), 2.0)]
        self._backoff[back] -= 1
        cmd[self.parked] = 0.0
        w.step(commands=cmd)

    def scan(self):
        """The observers' scans with the episode's range noise (drawn from the episode's RNG)."""
        clean = self.world.scan(robots=self.observers, noise=False)
        return apply_condition(clean, self.condition, self.rng, self.world.scene.lidar)


def episode(spec: SequenceSpec, seed: int, noise: float) -> Episode:
    """Episode ``seed`` of ``spec`` with lidar range noise ``noise`` (relative), ready for frame 0."""
    rng = np.random.default_rng(seed)
    if spec.name == "swarm":
        world = swarm_scene(rng, spec.scenes)  # robots already clustered, touching, at walls
        observers = np.arange(world.n_robots)
    else:
        world = World(lookalike_scene(rng, spec.scenes), seed=rng)
        observers = np.array([0])
    parked = rng.random(world.n_robots) < spec.run.parked_prob
    if spec.name == "lookalike":
        parked[0] = False  # the observer always moves
    return Episode(world, observers, parked, rng, spec.run, Condition(float(noise)))


# --------------------------------------------------------------------------- evaluation


def _bin(value: float, edges) -> int:
    return int(np.searchsorted(edges, value, side="right")) - 1


@dataclass
class _Counts:
    tp: int = 0
    fp: int = 0
    fn: int = 0

    def add(self, tp=0, fp=0, fn=0):
        self.tp, self.fp, self.fn = self.tp + tp, self.fp + fp, self.fn + fn

    def row(self) -> dict:
        p, r, f = prf1(self.tp, self.fp, self.fn)
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": p, "recall": r, "f1": f}


class _Observer:
    """Per-observer bookkeeping over an episode: visibility ages, kin motion, MOT accumulator."""

    def __init__(self, n_robots: int, n_obstacles: int, mot):
        self.age_robot = np.zeros(n_robots, np.int64)
        self.age_obst = np.zeros(n_obstacles, np.int64)
        self.since_seen = {}  # kin -> frames from coming into view (>= 2 beams), until first TP
        self.confirm_frames: list[int] = []
        self.false_ids: set[int] = set()
        self.true_ids: set[int] = set()
        self.seen_kin: set[int] = set()
        self.mot = mot


def _truth(scan, row: int, world: World, start_xy: np.ndarray, same_radius: np.ndarray):
    """Kin and object tables of one observer's frame, in its robot frame."""
    kind, index = scan.hit_kind[row], scan.hit_index[row]
    valid = scan.ranges[row] < scan.range_max
    x0, y0, th = scan.poses[row]
    c, s = math.cos(th), math.sin(th)

    def local(xy):
        d = np.asarray(xy, float).reshape(-1, 2) - (x0, y0)
        return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]]

    robots = index[valid & (kind == HitKind.ROBOT)]
    kin_ids, kin_beams = np.unique(robots, return_counts=True)
    poses = world.poses
    kin_xy = local(poses[kin_ids, :2])
    moved = np.hypot(*(poses[kin_ids, :2] - start_xy[kin_ids]).T)
    obst = index[valid & (kind != HitKind.ROBOT) & (kind != HitKind.NONE) & (index >= 0)]
    ob_ids = np.unique(obst)
    centres = np.array([world.scene.obstacles[j].center for j in ob_ids]).reshape(-1, 2)
    ob_xy = local(centres)
    sr = same_radius[ob_ids]
    return kin_ids, kin_beams, kin_xy, moved, ob_ids, ob_xy, sr


def _detections_of(result) -> tuple[np.ndarray, np.ndarray]:
    xy = np.array([[d.x, d.y] for d in result.detections]).reshape(-1, 2)
    return xy, np.array([d.score for d in result.detections])


def run_sequences(
    detector: KinDetector,
    split: str | SequenceSpec = "lookalike",
    n_episodes: int | None = None,
    noise: float = 0.01,
    tracker_params: TrackerParams | None = None,
    baselines: Mapping[str, KinDetector] | None = None,
    progress: bool = False,
    record: int | None = None,
) -> dict:
    """Run the sequence benchmark on one split at one noise level (see the module docstring).

    Args:
        detector: the per-frame detector feeding the tracker (run permissively) — also a baseline.
        split: ``"swarm"``, ``"lookalike"`` or a :class:`SequenceSpec`.
        n_episodes: episodes (default: the split's reduced size).
        noise: lidar range noise, relative.
        tracker_params: the tracker's parameters.
        baselines: further single-scan detectors to score, by name (at their operating points).
        progress: tqdm progress bar.
        record: keep the frames (scans, tracks, truth) of this episode index for an animation.

    Returns a plain dict (JSON-serialisable) of tables; ``"frames"`` holds the recording if asked.
    """
    spec = SEQUENCE_SPLITS[split] if isinstance(split, str) and split in SEQUENCE_SPLITS else split
    if not isinstance(spec, SequenceSpec):
        raise ValueError(f"unknown sequence split {split!r}; expected one of {sorted(SEQUENCE_SPLITS)}")
    n = spec.reduced_episodes if n_episodes is None else n_episodes
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if not (isinstance(noise, int | float) and 0 <= noise <= 0.05):
        raise ValueError(f"noise must be a relative range noise in [0, 0.05], got {noise!r}")
    import motmetrics as mm

    perm = permissive(detector)
    singles = {"single": detector, **dict(baselines or {})}
    t_warm = _warm_up([perm, *singles.values()], tracker_params)
    methods = ["tracker", *singles]
    by_age = {m: [_Counts() for _ in AGE_EDGES] for m in methods}
    by_dist = {m: [_Counts() for _ in DISTANCE_EDGES[:-1]] for m in methods}
    by_age_dist = {m: defaultdict(_Counts) for m in methods}
    sr_frames = {m: [0, 0] for m in methods}  # [frames checked, frames rejected]
    accs, observers_all = [], []
    t_det = t_trk = 0.0
    frames_total = observer_frames = 0
    recording = []
    seeds = spec.seeds(n)
    it = seeds
    if progress:
        from tqdm import tqdm

        it = tqdm(seeds, desc=f"sequences {spec.name} noise {100 * noise:g} %", leave=False)
    for e_idx, seed in enumerate(it):
        ep = episode(spec, seed, noise)
        w = ep.world
        obs_idx = ep.observers
        same_radius = np.array(
            [isinstance(o, Cylinder) and abs(o.radius - w.scene.robot.housing_radius) <= SAME_RADIUS_TOL
             for o in w.scene.obstacles], bool,
        ).reshape(-1)  # fmt: skip
        tracker = KinTracker(tracker_params, n_observers=len(obs_idx))
        start_xy = w.poses[:, :2].copy()
        book = [_Observer(w.n_robots, w.n_obstacles, mm.MOTAccumulator(auto_id=True)) for _ in obs_idx]
        for frame in range(spec.run.frames):
            if frame:
                ep.step(frame)
                delta = w.odometry_delta[obs_idx]
            else:
                delta = np.zeros((len(obs_idx), 3))
            scan = ep.scan()
            t0 = time.perf_counter()
            cand = perm.detect_batch(scan.ranges, scan.angles)
            t_det += time.perf_counter() - t0
            single_res = {name: d.detect_batch(scan.ranges, scan.angles) for name, d in singles.items()}
            ob, xy, sc, pts, own, acc = _candidates(cand, scan, single_res["single"])
            # the scan's own noise estimate, as on a real robot (the tracker's default where it has too few)
            est, count = scan_noise(segment_batch(scan.ranges, scan.angles))
            noise_est = np.where(count >= 5, est, tracker.params.range_noise)
            t0 = time.perf_counter()
            tracker.update_batch(ob, xy, sc, delta, _FRAME_S, pts, own, noise_est, accepted=acc)
            t_trk += time.perf_counter() - t0
            frames_total += 1
            observer_frames += len(obs_idx)
            arrays = tracker.track_arrays(64)
            if record == e_idx:
                recording.append(
                    {
                        "poses": w.poses.copy(),
                        "scan": scan.ranges[0].copy(),
                        "tracks": arrays["tracks"][0][arrays["mask"][0]].copy(),
                    }
                )  # noqa: E501
            for row in range(len(obs_idx)):
                bk = book[row]
                kin_ids, kin_beams, kin_xy, moved, ob_ids, ob_xy, sr = _truth(
                    scan, row, w, start_xy, same_radius
                )
                # visibility ages (>= 1 valid beam), reset when out of view
                vis_r = np.zeros(w.n_robots, bool)
                vis_r[kin_ids] = True
                bk.age_robot = np.where(vis_r, bk.age_robot + 1, 0)
                vis_o = np.zeros(w.n_obstacles, bool)
                vis_o[ob_ids] = True
                bk.age_obst = np.where(vis_o, bk.age_obst + 1, 0)
                counted = kin_beams >= MIN_BEAMS
                bk.seen_kin.update(kin_ids[counted].tolist())
                gt_xy = np.r_[kin_xy, ob_xy[sr]]
                gt_ignore = np.r_[~counted, np.ones(int(sr.sum()), bool)]
                ages = np.r_[bk.age_robot[kin_ids], bk.age_obst[ob_ids[sr]]]
                all_moved = bool(
                    all(np.hypot(*(w.poses[k, :2] - start_xy[k])) >= MOVED for k in bk.seen_kin)
                ) and bool(bk.seen_kin)
                tr = arrays["tracks"][row][arrays["mask"][row]]
                is_kin = (tr[:, 8] > 0) & (tr[:, 6] >= tracker.params.kin_threshold)
                dets = {"tracker": (tr[is_kin, 1:3], tr[is_kin, 0].astype(np.int64))}
                for name, res in single_res.items():
                    dets[name] = (_detections_of(res[row])[0], None)
                for name, (dxy, ids) in dets.items():
                    m = match(dxy, gt_xy, GATE, gt_ignore=gt_ignore)
                    matched_gt = np.zeros(gt_xy.shape[0], bool)
                    matched_gt[m.gt[m.gt >= 0]] = True
                    for g in range(kin_xy.shape[0]):
                        if not counted[g]:
                            continue
                        a = _bin(ages[g], AGE_EDGES)
                        db = _bin(float(np.hypot(*kin_xy[g])), DISTANCE_EDGES)
                        tp = int(matched_gt[g])
                        by_age[name][a].add(tp=tp, fn=1 - tp)
                        if 0 <= db < len(DISTANCE_EDGES) - 1:
                            by_dist[name][db].add(tp=tp, fn=1 - tp)
                            by_age_dist[name][(a, db)].add(tp=tp, fn=1 - tp)
                    for d in np.flatnonzero(m.fp):
                        a, dist = _fp_bin(
                            dxy[d], kin_xy, ob_xy, np.r_[bk.age_robot[kin_ids]], bk.age_obst[ob_ids], frame
                        )
                        by_age[name][a].add(fp=1)
                        db = _bin(dist, DISTANCE_EDGES)
                        if 0 <= db < len(DISTANCE_EDGES) - 1:
                            by_dist[name][db].add(fp=1)
                            by_age_dist[name][(a, db)].add(fp=1)
                    if all_moved:
                        for g in range(kin_xy.shape[0], gt_xy.shape[0]):
                            if ages[g] >= 1:
                                sr_frames[name][0] += 1
                                sr_frames[name][1] += int(not matched_gt[g])
                    if name == "tracker":
                        _track_bookkeeping(bk, m, ids, kin_ids, counted, kin_xy, dxy, frame)
        accs.extend(b.mot for b in book)
        observers_all.extend(book)
    mot = _mot_summary(mm, accs)
    confirm = [f for b in observers_all for f in b.confirm_frames]
    minutes = observer_frames * _FRAME_S / 60.0  # of observation, summed over observers
    out = {
        "split": spec.name, "noise": noise, "episodes": n, "frames": frames_total,
        "observer_frames": observer_frames,
        "version": SEQUENCE_VERSION,
        "spec": spec.to_dict(),
        "by_age": {m: [c.row() for c in v] for m, v in by_age.items()},
        "by_distance": {m: [c.row() for c in v] for m, v in by_dist.items()},
        "by_age_distance": {
            m: {f"{a},{d}": c.row() for (a, d), c in v.items()} for m, v in by_age_dist.items()
        },
        "same_radius_rejected": {m: (v[1] / v[0] if v[0] else math.nan, v[0]) for m, v in sr_frames.items()},
        "confirm_frames": {"median": float(np.median(confirm)) if confirm else math.nan,
                           "mean": float(np.mean(confirm)) if confirm else math.nan, "n": len(confirm)},
        "false_tracks_per_minute": (
            sum(len(b.false_ids - b.true_ids) for b in observers_all) / minutes if minutes else math.nan
        ),
        "mot": mot,
        "seconds": {"warm_up": t_warm, "detector_per_frame": t_det / max(frames_total, 1),
                    "tracker_per_frame": t_trk / max(frames_total, 1)},
    }  # fmt: skip
    if record is not None:
        out["recording"] = recording
    return out


def _warm_up(detectors, tracker_params) -> float:
    """Compile / allocate everything once before timing (numba kernels, torch): seconds taken."""
    from ..core import scenes

    t0 = time.perf_counter()
    scan = World(scenes.paper_scenario(1, distance=0.5), seed=0).scan()
    for d in detectors:
        d.detect_batch(scan.ranges, scan.angles)
    tr = KinTracker(tracker_params, n_observers=2)
    pts = np.array([[1.0, 0.0], [1.01, 0.01], [0.99, -0.01]] * 3)
    xy = [[1.0, 0.0], [2.0, 0.0], [1.0, 0.5]]
    for _ in range(3):
        tr.update_batch([0, 1, 0], xy, [0.9, 0.9, 0.9], np.zeros((2, 3)), 0.1, pts, np.repeat([0, 1, 2], 3),
                        accepted=[True, True, False])  # fmt: skip
    return time.perf_counter() - t0


def _candidates(results, scan, operating=None):
    """Flatten one frame's detection results into the tracker's batch arrays (points from the segments);
    ``operating``: the same detector's results at its operating point, for the ``accepted`` flags."""
    dets = [(row, d) for row, res in enumerate(results) for d in res.detections]
    ob = np.array([row for row, _ in dets], np.int64)
    xy = np.array([(d.x, d.y) for _, d in dets], np.float64).reshape(-1, 2)
    sc = np.array([d.score for _, d in dets], np.float64)
    first = np.array([d.first_beam for _, d in dets], np.int64)
    last = np.array([d.last_beam for _, d in dets], np.int64)
    pts, own = segment_points(scan.ranges, scan.angles, ob, first, last, scan.range_max)
    if operating is None:
        return ob, xy, sc, pts, own, None
    taken = {(row, d.first_beam, d.last_beam) for row, res in enumerate(operating) for d in res.detections}
    accepted = np.array([(row, d.first_beam, d.last_beam) in taken for row, d in dets], bool)
    return ob, xy, sc, pts, own, accepted


def _fp_bin(xy, kin_xy, ob_xy, kin_age, ob_age, frame) -> tuple[int, float]:
    """Age bin and distance of a false positive: those of the nearest object within 0.2 m."""
    cand = np.r_[kin_xy, ob_xy].reshape(-1, 2)
    ages = np.r_[kin_age, ob_age]
    if cand.shape[0]:
        d = np.hypot(*(cand - xy).T)
        j = int(np.argmin(d))
        if d[j] <= 0.2:
            return _bin(max(int(ages[j]), 1), AGE_EDGES), float(np.hypot(*cand[j]))
    return _bin(frame + 1, AGE_EDGES), float(np.hypot(*xy))


def _track_bookkeeping(bk: _Observer, m, ids, kin_ids, counted, kin_xy, dxy, frame) -> None:
    n_k = kin_xy.shape[0]
    for d in range(dxy.shape[0]):
        g = m.gt[d]
        if 0 <= g < n_k:
            bk.true_ids.add(int(ids[d]))
        elif m.fp[d]:
            bk.false_ids.add(int(ids[d]))
    # time to confirm: frames from coming into view (>= 2 beams) to the first true positive
    tp_kin = {int(kin_ids[g]) for g in m.gt[m.tp] if g < n_k}
    for g in range(n_k):
        k = int(kin_ids[g])
        if not counted[g]:
            continue
        if k not in bk.since_seen:
            bk.since_seen[k] = 0
        if bk.since_seen[k] >= 0:
            bk.since_seen[k] += 1
            if k in tp_kin:
                bk.confirm_frames.append(bk.since_seen[k])
                bk.since_seen[k] = -1  # done
    # CLEAR MOT: counted kin against the tracker's kin tracks (gate GATE)
    gt_ids = [int(kin_ids[g]) for g in range(n_k) if counted[g]]
    gxy = kin_xy[counted[:n_k]]
    dist = (
        np.hypot(gxy[:, None, 0] - dxy[None, :, 0], gxy[:, None, 1] - dxy[None, :, 1])
        if len(gxy) and len(dxy)
        else np.zeros((len(gxy), len(dxy)))
    )
    dist = np.where(dist <= GATE, dist, np.nan)
    bk.mot.update(gt_ids, [int(i) for i in ids], dist)


def _mot_summary(mm, accs) -> dict:
    accs = [a for a in accs if len(a.events)]
    if not accs:
        return {"mota": math.nan, "idf1": math.nan, "num_switches": 0, "n_sequences": 0}
    mh = mm.metrics.create()
    summary = mh.compute_many(accs, metrics=["mota", "idf1", "num_switches"], generate_overall=True)
    row = summary.loc["OVERALL"]
    return {"mota": float(row["mota"]), "idf1": float(row["idf1"]), "num_switches": int(row["num_switches"]),
            "n_sequences": len(accs)}  # fmt: skip
