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
- look-alikes rejected by kind (``lookalikes_rejected``: prism, box, cylinder, same-radius, ...): the
  share of frames in which one in view for >= 20 frames at 0.3-2 m has no detection within ``GATE`` of
  its centre;
- time: the tracker's update against the detector's per-frame time (all observers batched).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

import numpy as np

from detectors.base import KinDetector
from detectors.features import scan_noise, segment_batch
from detectors.metrics import match, prf1
from detectors.tracking import TRACK_FEATURES, KinTracker, TrackerParams, TrackKinModel, segment_points

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
from .seeds import check_training_seeds

__all__ = [
    "AGE_EDGES",
    "SEQUENCE_SPLITS",
    "SEQUENCE_VERSION",
    "SequenceConfig",
    "SequenceSpec",
    "RecordedEpisodes",
    "episode",
    "evaluate_sequences",
    "fit_kin_model",
    "record_sequences",
    "run_sequences",
    "target_window",
    "track_samples",
    "tracking_cost",
    "tune_tracker",
    "training_split",
]

#: Bumped whenever an episode generator, the ground truth or a metric changes.
SEQUENCE_VERSION = 1
#: Frames since an object came into view: bins [1], [2, 5), [5, 10), [10, 20), [20, inf).
AGE_EDGES = (1, 2, 5, 10, 20)
SAME_RADIUS_TOL = 1e-3  # m
MOVED = 0.2  # m: "every kin in view has moved" (same-radius cylinder rejection)
LOOKALIKE_FRAMES = 20  # look-alikes rejected "after 20 frames" in view (the prism target)
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
    training: bool = False

    def seeds(self, n: int) -> range:
        seeds = range(self.first_seed, self.first_seed + n)
        if self.training:  # tuning / diagnosis episodes: never the benchmark's reserved seeds
            check_training_seeds(seeds, f"training sequence split {self.name!r}")
        elif not (BENCHMARK_SEEDS.start <= self.first_seed and self.first_seed + n <= BENCHMARK_SEEDS.stop):
            raise ValueError(f"sequence split {self.name!r}: seeds leave the reserved range")
        return seeds

    def to_dict(self) -> dict:
        def plain(obj):
            return {f.name: getattr(obj, f.name) for f in fields(obj)}

        return {
            "name": self.name, "scenes": plain(self.scenes), "run": plain(self.run),
            "first_seed": self.first_seed, "n_episodes": self.n_episodes,
            "reduced_episodes": self.reduced_episodes, "noise": list(self.noise), "training": self.training,
        }  # fmt: skip


def training_split(split: str, first_seed: int = 0) -> SequenceSpec:
    """The sequence split ``split`` with seeds from ``first_seed`` outside the benchmark's reserved range:
    the episodes to tune and diagnose the tracker on (the benchmark's own seeds stay unseen)."""
    if split not in SEQUENCE_SPLITS:
        raise ValueError(f"unknown sequence split {split!r}; expected one of {sorted(SEQUENCE_SPLITS)}")
    return replace(SEQUENCE_SPLITS[split], first_seed=int(first_seed), training=True)


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
    diagnose: bool = False,
    kin_model="learned",
    mot: bool = True,
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
        diagnose: add ``"diagnosis"``: the tracker's false positives and misses on kin in view for
            >= 10 frames at 0.3-2 m, by cause (:func:`_diagnose`).
        kin_model: the tracker's kin decision (:class:`detectors.tracking.KinTracker`): ``"learned"``
            (the shipped track classifier), ``"hand"`` (the hand-tuned fusion), a model or its path.
        mot: score CLEAR MOT (needs ``motmetrics``, the ``tracking`` extra); ``False``: ``"mot"`` is
            ``{}``.

    Returns a plain dict (JSON-serialisable) of tables; ``"frames"`` holds the recording if asked.
    """
    recorded = record_sequences(detector, split, n_episodes, noise, baselines, progress)  # checks arguments
    return evaluate_sequences(recorded, tracker_params, record=record, diagnose=diagnose, kin_model=kin_model,
                              mot=mot)  # fmt: skip


@dataclass
class _Frame:
    """One recorded frame: the tracker's inputs, the single-scan detections and the ground truth."""

    delta: np.ndarray
    cand: tuple  # (obs, xy, scores, points, owner, accepted) of the permissive run
    noise_est: np.ndarray
    singles: dict  # name -> list of (k, 2) detection positions per observer
    truth: list  # per observer: _truth(...) tuple
    moved_all: np.ndarray  # (n_robots,) distance each robot has moved from its start, m
    poses: np.ndarray
    scan0: np.ndarray


@dataclass
class RecordedEpisodes:
    """Episodes of one split and noise level, run once (worlds, scans, detectors, ground truth), so that
    trackers with different parameters can be evaluated on the very same frames (:func:`evaluate_sequences`,
    :func:`tune_tracker`)."""

    spec: SequenceSpec
    noise: float
    methods: list
    episodes: list  # of (n_observers, n_robots, obstacle kinds, parked, frames)
    detector_seconds: float
    warm_up: float


def record_sequences(
    detector: KinDetector,
    split: str | SequenceSpec,
    n_episodes: int | None = None,
    noise: float = 0.01,
    baselines: Mapping[str, KinDetector] | None = None,
    progress: bool = False,
) -> RecordedEpisodes:
    """Run the episodes of ``split`` and record every frame's tracker inputs, single-scan detections and
    ground truth (arguments as :func:`run_sequences`)."""
    spec = SEQUENCE_SPLITS[split] if isinstance(split, str) and split in SEQUENCE_SPLITS else split
    if not isinstance(spec, SequenceSpec):
        raise ValueError(f"unknown sequence split {split!r}; expected one of {sorted(SEQUENCE_SPLITS)}")
    n = spec.reduced_episodes if n_episodes is None else n_episodes
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if not (isinstance(noise, int | float) and 0 <= noise <= 0.05):
        raise ValueError(f"noise must be a relative range noise in [0, 0.05], got {noise!r}")
    perm = permissive(detector)
    singles = {"single": detector, **dict(baselines or {})}
    t_warm = _warm_up([perm, *singles.values()], None)
    t_det = 0.0
    episodes = []
    seeds = spec.seeds(n)
    it = seeds
    if progress:  # a bar with tqdm (train / ros extras), silent on the core install
        from kin_envs.cli import progress as _bar

        it = _bar(seeds, desc=f"sequences {spec.name} noise {100 * noise:g} %", leave=False)
    for seed in it:
        ep = episode(spec, seed, noise)
        w = ep.world
        obs_idx = ep.observers
        same_radius = np.array(
            [isinstance(o, Cylinder) and abs(o.radius - w.scene.robot.housing_radius) <= SAME_RADIUS_TOL
             for o in w.scene.obstacles], bool,
        ).reshape(-1)  # fmt: skip
        start_xy = w.poses[:, :2].copy()
        frames = []
        for frame in range(spec.run.frames):
            if frame:
                ep.step(frame)
                delta = w.odometry_delta[obs_idx].copy()
            else:
                delta = np.zeros((len(obs_idx), 3))
            scan = ep.scan()
            t0 = time.perf_counter()
            cand = perm.detect_batch(scan.ranges, scan.angles)
            t_det += time.perf_counter() - t0
            single_res = {name: d.detect_batch(scan.ranges, scan.angles) for name, d in singles.items()}
            cands = _candidates(cand, scan, single_res["single"])
            # the scan's own noise estimate, as on a real robot (the tracker's default where it has too few)
            est, count = scan_noise(segment_batch(scan.ranges, scan.angles))
            frames.append(_Frame(
                delta=delta, cand=cands, noise_est=np.where(count >= 5, est, np.nan),
                singles={name: [_detections_of(r)[0] for r in res] for name, res in single_res.items()},
                truth=[_truth(scan, row, w, start_xy, same_radius) for row in range(len(obs_idx))],
                moved_all=np.hypot(*(w.poses[:, :2] - start_xy).T), poses=w.poses.copy(),
                scan0=scan.ranges[0].copy(),
            ))  # fmt: skip
        kinds = [o.kind for o in w.scene.obstacles]
        episodes.append((len(obs_idx), w.n_robots, w.n_obstacles, kinds, ep.parked.copy(), frames))
    return RecordedEpisodes(spec, float(noise), ["tracker", *singles], episodes, t_det, t_warm)


def evaluate_sequences(
    recorded: RecordedEpisodes,
    tracker_params: TrackerParams | None = None,
    record: int | None = None,
    diagnose: bool = False,
    mot: bool = True,
    singles: bool = True,
    kin_model="learned",
) -> dict:
    """Run the tracker over recorded episodes and score it and the single-scan detectors (the tables of
    :func:`run_sequences`). ``mot=False`` skips CLEAR MOT and ``singles=False`` the single-scan detectors'
    scores (for tuning); ``kin_model`` is the tracker's (:class:`detectors.tracking.KinTracker`)."""
    if mot:
        import motmetrics as mm
    spec, methods = recorded.spec, recorded.methods if singles else ["tracker"]
    by_age = {m: [_Counts() for _ in AGE_EDGES] for m in methods}
    by_dist = {m: [_Counts() for _ in DISTANCE_EDGES[:-1]] for m in methods}
    by_age_dist = {m: defaultdict(_Counts) for m in methods}
    sr_frames = {m: [0, 0] for m in methods}  # [frames checked, frames rejected]
    # look-alikes in view >= LOOKALIKE_FRAMES frames at 0.3-2 m, by kind: [frames checked, not reported]
    kind_frames = {m: defaultdict(lambda: [0, 0]) for m in methods}
    accs, observers_all = [], []
    t_trk = 0.0
    frames_total = observer_frames = 0
    recording = []
    diag = defaultdict(int)
    t_warm = recorded.warm_up + _warm_up([], tracker_params)
    for e_idx, (n_obs, n_robots, n_obst, kinds, parked, frames) in enumerate(recorded.episodes):
        tracker = KinTracker(tracker_params, n_observers=n_obs, kin_model=kin_model)
        book = [_Observer(n_robots, n_obst, mm.MOTAccumulator(auto_id=True) if mot else None)
                for _ in range(n_obs)]  # fmt: skip
        for frame, fr in enumerate(frames):
            ob, xy, sc, pts, own, acc = fr.cand
            noise_est = np.where(np.isnan(fr.noise_est), tracker.params.range_noise, fr.noise_est)
            t0 = time.perf_counter()
            tracker.update_batch(ob, xy, sc, fr.delta, _FRAME_S, pts, own, noise_est, accepted=acc)
            t_trk += time.perf_counter() - t0
            frames_total += 1
            observer_frames += n_obs
            arrays = tracker.track_arrays(64)
            if record == e_idx:
                recording.append({"poses": fr.poses, "scan": fr.scan0,
                                  "tracks": arrays["tracks"][0][arrays["mask"][0]].copy()})  # fmt: skip
            for row in range(n_obs):
                bk = book[row]
                kin_ids, kin_beams, kin_xy, moved, ob_ids, ob_xy, sr = fr.truth[row]
                # visibility ages (>= 1 valid beam), reset when out of view
                vis_r = np.zeros(n_robots, bool)
                vis_r[kin_ids] = True
                bk.age_robot = np.where(vis_r, bk.age_robot + 1, 0)
                vis_o = np.zeros(n_obst, bool)
                vis_o[ob_ids] = True
                bk.age_obst = np.where(vis_o, bk.age_obst + 1, 0)
                counted = kin_beams >= MIN_BEAMS
                bk.seen_kin.update(kin_ids[counted].tolist())
                gt_xy = np.r_[kin_xy, ob_xy[sr]]
                gt_ignore = np.r_[~counted, np.ones(int(sr.sum()), bool)]
                ages = np.r_[bk.age_robot[kin_ids], bk.age_obst[ob_ids[sr]]]
                all_moved = bool(bk.seen_kin) and bool(
                    np.all(fr.moved_all[np.fromiter(bk.seen_kin, np.int64)] >= MOVED)
                )
                tr = arrays["tracks"][row][arrays["mask"][row]]
                is_kin = (tr[:, 8] > 0) & (tr[:, 6] >= tracker.params.kin_threshold)
                dets = {"tracker": (tr[is_kin, 1:3], tr[is_kin, 0].astype(np.int64))}
                for name, per_obs in fr.singles.items():
                    if singles:
                        dets[name] = (per_obs[row], None)
                matches = {}
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
                    old = np.flatnonzero((bk.age_obst[ob_ids] >= LOOKALIKE_FRAMES)
                                         & (np.hypot(ob_xy[:, 0], ob_xy[:, 1]) >= 0.3)
                                         & (np.hypot(ob_xy[:, 0], ob_xy[:, 1]) < 2.0))  # fmt: skip
                    for j in old:  # rejected: no detection within the gate of its centre
                        near = dxy.shape[0] and np.hypot(*(dxy - ob_xy[j]).T).min() <= GATE
                        c = kind_frames[name]["same-radius" if sr[j] else kinds[ob_ids[j]]]
                        c[0] += 1
                        c[1] += int(not near)
                    if all_moved:
                        for g in range(kin_xy.shape[0], gt_xy.shape[0]):
                            if ages[g] >= 1:
                                sr_frames[name][0] += 1
                                sr_frames[name][1] += int(not matched_gt[g])
                    matches[name] = (m, dxy)
                    if name == "tracker":
                        _track_bookkeeping(bk, m, ids, kin_ids, counted, kin_xy, dxy, frame)
                if diagnose:
                    f = tracker.track_features(row)  # which tracks were updated this frame
                    updated = set(f["id"][f["features"][:, TRACK_FEATURES.index("hit")] > 0].tolist())
                    hidden = np.setdiff1d(np.delete(np.arange(n_robots), row), kin_ids)
                    x0, y0, th = fr.poses[row]
                    hd = fr.poses[hidden, :2] - (x0, y0)
                    c, s = math.cos(th), math.sin(th)
                    hidden_xy = np.c_[c * hd[:, 0] + s * hd[:, 1], -s * hd[:, 0] + c * hd[:, 1]]
                    _diagnose(diag, *matches["tracker"], tr, tracker.params.kin_threshold, kin_ids, counted,
                              kin_xy, bk.age_robot[kin_ids], ob_ids, ob_xy, bk.age_obst[ob_ids], kinds,
                              parked, xy[ob == row], moved=moved, hidden_xy=hidden_xy, updated=updated,
                              single=matches.get("single"), frame=frame)  # fmt: skip
        accs.extend(b.mot for b in book)
        observers_all.extend(book)
    mot_summary = _mot_summary(mm, accs) if mot else {}
    confirm = [f for b in observers_all for f in b.confirm_frames]
    minutes = observer_frames * _FRAME_S / 60.0  # of observation, summed over observers
    n_frames = max(frames_total, 1)
    out = {
        "split": spec.name, "noise": recorded.noise, "episodes": len(recorded.episodes),
        "frames": frames_total, "observer_frames": observer_frames,
        "version": SEQUENCE_VERSION,
        "spec": spec.to_dict(),
        "by_age": {m: [c.row() for c in v] for m, v in by_age.items()},
        "by_distance": {m: [c.row() for c in v] for m, v in by_dist.items()},
        "by_age_distance": {
            m: {f"{a},{d}": c.row() for (a, d), c in v.items()} for m, v in by_age_dist.items()
        },
        "same_radius_rejected": {m: (v[1] / v[0] if v[0] else math.nan, v[0]) for m, v in sr_frames.items()},
        "lookalikes_rejected": {m: {k: (c[1] / c[0], c[0]) for k, c in sorted(v.items())}
                                for m, v in kind_frames.items()},  # fmt: skip
        "confirm_frames": {"median": float(np.median(confirm)) if confirm else math.nan,
                           "mean": float(np.mean(confirm)) if confirm else math.nan, "n": len(confirm)},
        "false_tracks_per_minute": (
            sum(len(b.false_ids - b.true_ids) for b in observers_all) / minutes if minutes else math.nan
        ),
        "mot": mot_summary,
        "seconds": {"warm_up": t_warm, "detector_per_frame": recorded.detector_seconds / n_frames,
                    "tracker_per_frame": t_trk / n_frames},
    }  # fmt: skip
    if record is not None:
        out["recording"] = recording
    if diagnose:
        out["diagnosis"] = dict(sorted(diag.items()))
    return out

def track_samples(
    recorded: RecordedEpisodes, tracker_params: TrackerParams | None = None, distance=(0.0, 5.0)
) -> dict[str, np.ndarray]:
    """The track-level kin classifier's training rows: the recorded episodes replayed through the tracker;
    every frame, every confirmed track of every observer within ``distance`` (m; every track the
    tracker may report, not only the target window's, so that the model does not extrapolate) gives its
    :data:`detectors.tracking.TRACK_FEATURES` and a label **as the benchmark scores a report there**: 1 if it
    lies within ``GATE`` of another robot that has at least ``MIN_BEAMS`` valid beams in the observer's scan
    of this frame; rows within ``GATE`` of a robot with fewer (but some) beams are left out ("don't care",
    as in the metric); else 0 (obstacles, same-radius cylinders, walls, and robots hidden from the
    observer this frame: a track that coasts on an occluded kin is a false positive per frame).

    Returns ``X`` (n, F), ``y`` (n,), ``range`` (n,), ``episode`` (n,) and ``window`` (n,): the row is in
    the target window as the benchmark bins it (the object the track lies on, the nearest within 0.2 m, in
    view for >= 10 frames; no object: frame >= 10; and 0.3-2 m away). Refuses episodes on the benchmark's
    reserved seeds (record :func:`training_split` episodes): the classifier must never see the benchmark."""
    if not isinstance(recorded, RecordedEpisodes):
        raise TypeError(f"track_samples: recorded must be RecordedEpisodes, got {type(recorded).__name__}")
    if not recorded.spec.training:
        raise ValueError(f"track_samples: episodes of split {recorded.spec.name!r} use the benchmark's "
                         "reserved seeds; fit on training_split(...) episodes only")  # fmt: skip
    recorded.spec.seeds(len(recorded.episodes))  # training seeds: never the reserved range
    X, y, rng_, ep_, win_ = [], [], [], [], []
    lo, hi = 0.3, 2.0  # the target window's distances
    for e_idx, (n_obs, n_robots, n_obst, _kinds, _parked, frames) in enumerate(recorded.episodes):
        tracker = KinTracker(tracker_params, n_observers=n_obs, kin_model="hand")  # features only
        age_r = np.zeros((n_obs, n_robots), np.int64)  # frames in view (>= 1 valid beam), as evaluated
        age_o = np.zeros((n_obs, n_obst), np.int64)
        for frame, fr in enumerate(frames):
            ob, xy, sc, pts, own, acc = fr.cand
            noise_est = np.where(np.isnan(fr.noise_est), tracker.params.range_noise, fr.noise_est)
            tracker.update_batch(ob, xy, sc, fr.delta, _FRAME_S, pts, own, noise_est, accepted=acc)
            for row in range(n_obs):  # observer ``row`` is robot ``row`` (swarm: all robots; lookalike: 0)
                kin_ids, kin_beams, kin_xy, _moved, ob_ids, ob_xy, _sr = fr.truth[row]
                vis = np.zeros(n_robots, bool)
                vis[kin_ids] = True
                age_r[row] = np.where(vis, age_r[row] + 1, 0)
                vis = np.zeros(n_obst, bool)
                vis[ob_ids] = True
                age_o[row] = np.where(vis, age_o[row] + 1, 0)
                t = tracker.track_features(row)
                d = np.hypot(t["xy"][:, 0], t["xy"][:, 1])
                keep = t["confirmed"] & (d >= distance[0]) & (d < distance[1])
                if not keep.any():
                    continue
                txy = t["xy"][keep]
                x0, y0, th = fr.poses[row]
                others = np.delete(fr.poses[:, :2], row, axis=0) - (x0, y0)
                c, s = math.cos(th), math.sin(th)
                kin = np.c_[c * others[:, 0] + s * others[:, 1], -s * others[:, 0] + c * others[:, 1]]
                beams = np.zeros(n_robots, np.int64)
                beams[kin_ids] = kin_beams
                beams = np.delete(beams, row)
                d2 = np.hypot(txy[:, None, 0] - kin[None, :, 0], txy[:, None, 1] - kin[None, :, 1])
                j = d2.argmin(1) if kin.shape[0] else np.zeros(txy.shape[0], np.int64)
                near = d2.min(1) <= GATE if kin.shape[0] else np.zeros(txy.shape[0], bool)
                b = beams[j] if kin.shape[0] else np.zeros(txy.shape[0], np.int64)
                label = near & (b >= MIN_BEAMS)
                use = ~(near & (b > 0) & (b < MIN_BEAMS))  # a kin with one beam: "don't care"
                # the target window as the benchmark bins a report: by the nearest object within 0.2 m
                obj = np.r_[kin_xy, ob_xy].reshape(-1, 2)
                age = np.r_[age_r[row][kin_ids], age_o[row][ob_ids]]
                if obj.shape[0]:
                    do = np.hypot(txy[:, None, 0] - obj[None, :, 0], txy[:, None, 1] - obj[None, :, 1])
                    jo = do.argmin(1)
                    oage = np.where(do.min(1) <= 0.2, age[jo], frame + 1)
                    orng = np.where(do.min(1) <= 0.2, np.hypot(obj[jo, 0], obj[jo, 1]), d[keep])
                else:
                    oage, orng = np.full(txy.shape[0], frame + 1), d[keep]
                win = (oage >= 10) & (orng >= lo) & (orng < hi)
                X.append(t["features"][keep][use])
                y.append(label[use])
                rng_.append(d[keep][use])
                ep_.append(np.full(int(use.sum()), e_idx))
                win_.append(win[use])
    F = len(TRACK_FEATURES)
    cat = lambda a, shape: np.concatenate(a) if a else np.zeros(shape)  # noqa: E731
    return {"X": cat(X, (0, F)), "y": cat(y, 0).astype(bool), "range": cat(rng_, 0),
            "episode": cat(ep_, 0).astype(np.int64), "window": cat(win_, 0).astype(bool)}  # fmt: skip


#: Operating points :func:`fit_kin_model` tries (the model's probability at which a track is called kin).
KIN_MODEL_THRESHOLDS = (0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)


def fit_kin_model(
    recorded: list[RecordedEpisodes],
    tracker_params: TrackerParams | None = None,
    hidden=(8,),
    l2: float = 1e-3,
    min_frames: int = 3,
    thresholds=KIN_MODEL_THRESHOLDS,
    info: dict | None = None,
    tol: float = 0.001,
    outside_weight: float = 0.5,
    hit_only: bool = True,
) -> tuple[TrackKinModel, list[dict]]:
    """Fit the track-level kin classifier (:class:`detectors.tracking.TrackKinModel`) on training-seed
    episodes: :func:`track_samples` of each recorded set, each set weighing the same in the loss (a swarm
    set has many more tracks than a look-alike one) and, within a set, rows outside the target window
    ``outside_weight`` times a row inside it (the model serves the window first, without extrapolating
    elsewhere) and, with ``hit_only``, tracks not updated this frame are not kin (:class:`TrackKinModel`),
    then the operating point: the threshold in
    ``thresholds`` with the best mean :func:`tune_objective` over the sets (the model's output is shifted
    so that it is ``kin_prob`` 0.5): the highest threshold within ``tol`` of the best (where the objective
    is flat, fewer false kin reports: on held-out training seeds, 1 % noise, p >= 0.4 against 0.35, equal
    on the fitted episodes, kept swarm F1 (0.882 vs 0.885) and gave lookalike 0.772 vs 0.759, same-radius
    cylinders rejected 0.85 / 0.99 vs 0.80 / 0.97 and 7 cm prisms 0.90 / 0.94 vs 0.86 / 0.92).
    Deterministic for given episodes.

    Returns the model and one row per threshold (``threshold``, ``objective``, ``per_set``)."""
    if not recorded:
        raise ValueError("fit_kin_model: need at least one RecordedEpisodes")
    if not (isinstance(outside_weight, int | float) and 0 < outside_weight <= 1):
        raise ValueError(f"fit_kin_model: outside_weight must be in (0, 1], got {outside_weight!r}")
    samples = [track_samples(r, tracker_params) for r in recorded]
    samples = [s for s in samples if s["y"].size]
    if not samples:
        raise ValueError("fit_kin_model: the recorded episodes gave no confirmed tracks")
    X = np.concatenate([s["X"] for s in samples])
    y = np.concatenate([s["y"] for s in samples])
    w = [np.where(s["window"], 1.0, float(outside_weight)) for s in samples]
    w = np.concatenate([v / v.sum() for v in w])
    names = [f"{r.spec.name}@{r.spec.first_seed}x{len(r.episodes)}" for r in recorded]
    base = TrackKinModel.fit(X, y, w, hidden=hidden, l2=l2, min_frames=min_frames, hit_only=hit_only,
                             info={**(info or {}), "sets": names, "rows": int(y.size),
                                   "outside_weight": outside_weight,
                                   "kin_share": float(y.mean())})  # fmt: skip
    rows = []
    for thr in thresholds:
        m = base.shifted(float(thr))
        per = [tune_objective(evaluate_sequences(r, tracker_params, mot=False, singles=False, kin_model=m))
               for r in recorded]  # fmt: skip
        rows.append({"threshold": float(thr), "objective": float(np.mean(per)), "per_set": per})
    top = max(r["objective"] for r in rows)
    chosen = max(r["threshold"] for r in rows if r["objective"] >= top - tol)
    return base.shifted(chosen), rows


def _diagnose(diag, m, dxy, tr, kin_threshold, kin_ids, counted, kin_xy, kin_age, ob_ids, ob_xy, ob_age,
              kinds_all, parked, cand_xy, moved=None, hidden_xy=None, updated=None, single=None,
              frame=10) -> None:  # fmt: skip
    """Count the tracker's errors on objects in view >= 10 frames at 0.3-2 m (the targets' window) by cause.

    False positives, by the nearest object within 0.2 m: ``fp:duplicate`` (a kin already matched by
    another track), ``fp:lagging`` (an unmatched kin, but beyond the gate), ``fp:<obstacle kind>``
    (prism, box, cylinder, ...), ``fp:hidden_kin`` (within the gate of a robot that has no valid beam in
    this frame: occluded; ``hidden_xy``), ``fp:none``; suffix ``_coast`` when the track was not updated
    this frame (``updated``: the ids updated). Misses of a counted kin: ``fn:unconfirmed`` (a track within
    the gate, not yet confirmed), ``fn:low_kin_parked`` / ``fn:low_kin_stuck`` / ``fn:low_kin_moving`` (a
    confirmed track whose kin probability is below the threshold; the kin parked, a wanderer that has
    not moved 0.1 m from its start (``moved``), or one that has), ``fn:lagging`` (the nearest track within
    0.2 m but outside the gate), ``fn:no_track`` (the permissive detector had a candidate within the
    gate) and ``fn:no_candidate``.

    With ``single`` (the single-scan detector's ``(match, positions)`` on the same frame): the window's
    kin frames as ``vs_single:both_tp`` / ``both_fn`` / ``tracker_only`` / ``single_only``, the misses
    where the single scan was right by the same causes (``lost:<cause>``), and the single scan's false
    positives by the same kinds (``single_fp:<kind>``)."""
    r = np.hypot(kin_xy[:, 0], kin_xy[:, 1])
    in_win = (kin_age >= 10) & (r >= 0.3) & (r < 2.0)
    n_k = kin_xy.shape[0]

    def matched(mm):
        out = np.zeros(n_k, bool)
        for g in mm.gt[mm.gt >= 0]:
            if g < n_k:
                out[g] = True
        return out

    matched_kin = matched(m)
    kinds = [kinds_all[j] for j in ob_ids]

    def fp_causes(mm, pos, mk):
        out = []
        for d in np.flatnonzero(mm.fp):
            p = pos[d]
            dk = np.hypot(*(kin_xy - p).T) if n_k else np.zeros(0)
            do = np.hypot(*(ob_xy - p).T) if ob_xy.shape[0] else np.zeros(0)
            jk = int(np.argmin(dk)) if dk.size else -1
            jo = int(np.argmin(do)) if do.size else -1
            if jk >= 0 and dk[jk] <= 0.2 and (jo < 0 or dk[jk] <= do[jo]):
                if in_win[jk]:
                    out.append((d, "duplicate" if mk[jk] else "lagging"))
            elif jo >= 0 and do[jo] <= 0.2:
                ro = float(np.hypot(*ob_xy[jo]))
                if ob_age[jo] >= 10 and 0.3 <= ro < 2.0:
                    out.append((d, kinds[jo]))
            elif 0.3 <= float(np.hypot(*p)) < 2.0 and frame >= 9:
                hid = hidden_xy is not None and hidden_xy.shape[0] > 0
                hid = hid and np.hypot(*(hidden_xy - p).T).min() <= GATE
                out.append((d, "hidden_kin" if hid else "none"))
        return out

    ids = tr[:, 0].astype(np.int64) if tr.shape[0] else np.zeros(0, np.int64)
    rep = np.flatnonzero((tr[:, 8] > 0) & (tr[:, 6] >= kin_threshold)) if tr.shape[0] else np.zeros(0, int)
    for d, c in fp_causes(m, dxy, matched_kin):
        coast = updated is not None and int(ids[rep[d]]) not in updated if rep.size > d else False
        diag[f"fp:{c}{'_coast' if coast else ''}"] += 1
    single_kin = None
    if single is not None:
        single_kin = matched(single[0])
        for _, c in fp_causes(single[0], single[1], single_kin):
            diag[f"single_fp:{c}"] += 1
    for g in np.flatnonzero(in_win & counted):
        g = int(g)
        if single_kin is not None:
            key = {(True, True): "both_tp", (False, False): "both_fn", (True, False): "tracker_only",
                   (False, True): "single_only"}[(bool(matched_kin[g]), bool(single_kin[g]))]  # fmt: skip
            diag[f"vs_single:{key}"] += 1
        if matched_kin[g]:
            continue
        diag["fn:total"] += 1
        d = np.hypot(*(tr[:, 1:3] - kin_xy[g]).T) if tr.shape[0] else np.zeros(0)
        if d.size and d.min() <= GATE:
            t = tr[int(np.argmin(d))]
            if t[8] <= 0:
                cause = "unconfirmed"
            elif t[6] < kin_threshold:
                still = moved is not None and moved[g] < 0.1
                cause = "low_kin_" + ("parked" if parked[kin_ids[g]] else "stuck" if still else "moving")
            else:
                cause = "other"  # e.g. the match went to a neighbour
        elif d.size and d.min() <= 0.2:
            cause = "lagging"
        elif cand_xy.shape[0] and np.hypot(*(cand_xy - kin_xy[g]).T).min() <= GATE:
            cause = "no_track"
        else:
            cause = "no_candidate"
        diag[f"fn:{cause}"] += 1
        if single_kin is not None and single_kin[g]:
            diag[f"lost:{cause}"] += 1
    diag["tp"] += int((in_win & matched_kin & counted).sum())


def _warm_up(detectors, tracker_params) -> float:
    """Compile / allocate everything once before timing (numba kernels, torch): seconds taken."""
    from ..core import scenes

    t0 = time.perf_counter()
    scan = World(scenes.paper_scenario(1, distance=0.5), seed=0).scan()
    for d in detectors:
        d.detect_batch(scan.ranges, scan.angles)
    tr = KinTracker(tracker_params, n_observers=2, kin_model="hand")  # the kernels; the kin decision is numpy
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
    if bk.mot is not None:
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


def target_window(result: dict, min_frames: int = 10, distance: tuple[float, float] = (0.3, 2.0)) -> dict:
    """Per-frame P / R / F1 of each method on objects in view for ``>= min_frames`` frames within
    ``distance`` (the issue's target window), overall and per distance bin (``result["by_age_distance"]``).

    Returns ``{method: {"all": row, "<lo>-<hi>": row, ...}}`` with rows as in ``by_age``."""
    a0 = _bin(min_frames, AGE_EDGES)
    if AGE_EDGES[a0] != min_frames:
        raise ValueError(f"min_frames must be one of {AGE_EDGES}, got {min_frames!r}")
    lo, hi = distance[0] - 1e-9, distance[1] + 1e-9
    E = DISTANCE_EDGES
    bins = [b for b in range(len(E) - 1) if E[b] >= lo and E[b + 1] <= hi]
    out = {}
    for m, cells in result["by_age_distance"].items():
        tot = _Counts()
        rows = {}
        for b in bins:
            c = _Counts()
            for a in range(a0, len(AGE_EDGES)):
                r = cells.get(f"{a},{b}")
                if r:
                    c.add(r["tp"], r["fp"], r["fn"])
            tot.add(c.tp, c.fp, c.fn)
            rows[f"{DISTANCE_EDGES[b]:g}-{DISTANCE_EDGES[b + 1]:g}"] = c.row()
        out[m] = {"all": tot.row(), **rows}
    return out


#: What :func:`tune_tracker` searches by default: the kin-probability cues' weights and the thresholds, the
#: parameters whose best values depend on the detector feeding the tracker (its score calibration).
TUNING_GRID: dict[str, tuple] = {
    "score_prior": (0.3, 0.5, 0.7, 0.85),
    "score_weight": (0.0, 0.5, 1.0),
    "accept_llr": (0.0, 1.0, 2.0),
    "reject_llr": (0.0, -1.0, -2.0),
    "score_gain": (2.0, 4.0, 8.0),
    "score_per_metre": (0.0, 0.5, 1.0),
    "static_penalty": (0.0, -2.0, -4.0, -8.0),
    "resid_clamp": (0.0, 2.0),
    "shape_clamp": (0.0, 2.0),
    "kin_threshold": (0.3, 0.5, 0.7),
}


def tune_objective(result: dict) -> float:
    """The tuning objective of one split: the tracker's F1 on kin in view >= 10 frames at 0.3-2 m."""
    f = target_window(result)["tracker"]["all"]["f1"]
    return 0.0 if math.isnan(f) else float(f)


def tune_tracker(
    recorded: list[RecordedEpisodes],
    grid: Mapping[str, tuple] | None = None,
    base: TrackerParams | None = None,
    passes: int = 2,
    progress: bool = False,
) -> tuple[TrackerParams, list[dict]]:
    """Coordinate descent over ``grid`` (default :data:`TUNING_GRID`) from ``base`` for the hand-tuned
    fusion (``kin_model="hand"``; the learned track classifier is fitted by :func:`fit_kin_model`): each
    parameter in turn takes the grid value that maximises the mean :func:`tune_objective` over the
    ``recorded`` episode sets
    (training seeds: :func:`training_split`), ``passes`` times. Re-run it for a new detector checkpoint.

    Returns the best parameters and the log of every evaluation (``params``, ``objective``, and
    ``per_set``: the objective on each recorded set, in order).
    """
    grid = dict(TUNING_GRID if grid is None else grid)
    names = {f.name for f in fields(TrackerParams)}
    if set(grid) - names:
        raise ValueError(f"tune_tracker: unknown parameter(s) {sorted(set(grid) - names)}")
    if not recorded:
        raise ValueError("tune_tracker: need at least one RecordedEpisodes")
    best = base or TrackerParams()
    log: list[dict] = []
    cache: dict = {}

    def score(p: TrackerParams) -> float:
        key = tuple(getattr(p, n) for n in sorted(names))
        if key not in cache:
            per = [tune_objective(evaluate_sequences(r, p, mot=False, singles=False, kin_model="hand"))
                   for r in recorded]  # fmt: skip
            cache[key] = float(np.mean(per))
            log.append({"params": {n: getattr(p, n) for n in grid}, "objective": cache[key], "per_set": per})
        return cache[key]

    best_score = score(best)
    steps = [(n, v) for _ in range(passes) for n in grid for v in grid[n]]
    it = steps
    if progress:
        from kin_envs.cli import progress as _bar

        it = _bar(steps, desc="tune tracker", leave=False)
    for name, value in it:
        try:
            cand = replace(best, **{name: value})
        except ValueError:
            continue  # an invalid combination (e.g. thresholds out of order)
        s = score(cand)
        if s > best_score + 1e-9:
            best, best_score = cand, s
    return best, log


def tracking_cost(
    detector: KinDetector,
    n_robots: int = 64,
    frames: int = 30,
    tracker_params: TrackerParams | None = None,
    seed: int = 7,
    repeats: int = 3,
    skip: int = 10,
    kin_model="learned",
    alt_params: TrackerParams | None = None,
) -> dict:
    """Time the tracker against the per-frame detector feeding it, ``n_robots`` observers batched: one
    swarm episode (a training seed, a ``n_robots``-robot arena) is recorded once, then the permissive
    detector's ``detect_batch`` on each frame's scans and the tracker's ``update_batch`` on its candidates
    are timed alternately, warm (compile time reported apart), on the frames after the first ``skip`` (the
    steady state: the tracker's arrays have grown to the scene's number of tracks, a one-off per run),
    best of ``repeats`` passes (a shared machine slows passes unevenly; both sides of the ratio come from
    the same passes).

    Returns seconds per frame for both, their ratio, the warm-up and the mean candidates per frame, and
    ``outputs_per_frame``: :meth:`~detectors.tracking.KinTracker.track_arrays` (16 slots, what an env reads;
    it evaluates ``kin_model``), timed apart (not in the ratio; ``ratio_total_*``: update and outputs
    together, what an env pays per step — the kin decision's compiled part runs in the update's call when the
    frame before's outputs were read, so only the sum compares across versions). Each is timed by the wall
    clock and by the process's CPU clock (``*_cpu_*``: a loaded machine's other jobs do not count), and the
    shipped detector itself (its batched array path, ``detect_arrays``, which an env calls) is timed on the
    same frames (``shipped_*``, ``ratio_shipped_cpu``: the tracker's update against it). ``alt_params``: a
    second tracker with these parameters is timed in the same passes on the same candidates (``alt_*``: e.g.
    the per-frame fits warm-started, ``TrackerParams(frame_fit_iterations=2, frame_fit_warm_start=1)``)."""
    if isinstance(n_robots, bool) or not isinstance(n_robots, int) or n_robots < 2:
        raise ValueError(f"n_robots must be an integer >= 2, got {n_robots!r}")
    if not 0 <= int(skip) < int(frames):
        raise ValueError(f"skip must be in [0, frames), got {skip!r} for {frames!r} frames")
    side = max(6.0, 1.1 * math.sqrt(n_robots))  # the swarm split's density
    spec = training_split("swarm", seed)
    spec = replace(spec, scenes=replace(spec.scenes, n_robots=(n_robots, n_robots), arena_size=(side, side)),
                   run=replace(spec.run, frames=int(frames)))  # fmt: skip
    ep = episode(spec, spec.first_seed, 0.01)
    w = ep.world
    scans, deltas = [], []
    for frame in range(spec.run.frames):
        if frame:
            ep.step(frame)
        deltas.append(w.odometry_delta.copy() if frame else np.zeros((w.n_robots, 3)))
        scans.append(ep.scan())
    perm = permissive(detector)
    t0 = time.perf_counter()
    _warm_up([perm], tracker_params)
    shipped = getattr(detector, "detect_arrays", detector.detect_batch)  # the batched array path if any
    shipped(scans[0].ranges, scans[0].angles)
    warm = time.perf_counter() - t0
    keys = ("det", "trk", "out", "ship", "alt")
    best = {(k, c): math.inf for k in keys for c in ("wall", "cpu")}
    n_cand = 0

    def clocks():
        return time.perf_counter(), time.process_time()

    for _ in range(max(1, int(repeats))):
        tracker = KinTracker(tracker_params, n_observers=w.n_robots, kin_model=kin_model)
        alt = None if alt_params is None else KinTracker(alt_params, n_observers=w.n_robots,
                                                         kin_model=kin_model)  # fmt: skip
        tot = dict.fromkeys(best, 0.0)
        n_cand = 0
        for f, (scan, delta) in enumerate(zip(scans, deltas, strict=True)):
            t = [clocks()]
            res = perm.detect_batch(scan.ranges, scan.angles)
            t.append(clocks())
            ob, xy, sc, pts, own, _ = _candidates(res, scan)
            n_cand += ob.size
            t.append(clocks())
            tracker.update_batch(ob, xy, sc, delta, _FRAME_S, pts, own)
            t.append(clocks())
            tracker.track_arrays(16)
            t.append(clocks())
            shipped(scan.ranges, scan.angles)
            t.append(clocks())
            if alt is not None:
                alt.update_batch(ob, xy, sc, delta, _FRAME_S, pts, own)
            t.append(clocks())
            if f >= skip:
                for key, (a, b) in zip(keys, [(0, 1), (2, 3), (3, 4), (4, 5), (5, 6)], strict=True):
                    tot[key, "wall"] += t[b][0] - t[a][0]
                    tot[key, "cpu"] += t[b][1] - t[a][1]
        best = {k: min(best[k], tot[k]) for k in best}
    n = max(len(scans) - skip, 1)
    return {"n_robots": w.n_robots, "frames": n, "skipped": int(skip),
            "detector_per_frame": best["det", "wall"] / n, "tracker_per_frame": best["trk", "wall"] / n,
            "ratio": best["trk", "wall"] / best["det", "wall"], "warm_up": warm,
            "outputs_per_frame": best["out", "wall"] / n,
            "detector_cpu_per_frame": best["det", "cpu"] / n, "tracker_cpu_per_frame": best["trk", "cpu"] / n,
            "outputs_cpu_per_frame": best["out", "cpu"] / n,
            "ratio_cpu": best["trk", "cpu"] / max(best["det", "cpu"], 1e-12),
            "shipped_per_frame": best["ship", "wall"] / n, "shipped_cpu_per_frame": best["ship", "cpu"] / n,
            "ratio_shipped_cpu": best["trk", "cpu"] / max(best["ship", "cpu"], 1e-12),
            "ratio_total_cpu": (best["trk", "cpu"] + best["out", "cpu"]) / max(best["det", "cpu"], 1e-12),
            "ratio_total_shipped_cpu": (best["trk", "cpu"] + best["out", "cpu"])
            / max(best["ship", "cpu"], 1e-12),
            "candidates_per_frame": n_cand / len(scans),
            **({} if alt_params is None else {
                "alt_params": {k: getattr(alt_params, k)
                               for k in ("frame_fit_iterations", "frame_fit_warm_start")},
                "alt_cpu_per_frame": best["alt", "cpu"] / n,
                "ratio_alt_cpu": best["alt", "cpu"] / max(best["det", "cpu"], 1e-12),
                "ratio_alt_shipped_cpu": best["alt", "cpu"] / max(best["ship", "cpu"], 1e-12)})}  # fmt: skip
