"""Labelled lidar segments for the learned kin classifier, generated in the simulator (no torch).

A scene is scanned from several of its robots; every scan is pre-processed and segmented by the
geometric detector's own stages (:func:`detectors.features.segment_batch`) and each segment gets its
feature vector (:func:`detectors.features.segment_features`) and a label from the world's ground
truth (``Scan.hit_kind`` / ``Scan.hit_index`` of its beams).

**Labelling rule.** A segment's *object* is the one most of its beams hit (plurality; ties go to
the lower HitKind code, i.e. a robot). The segment is **kin** when strictly more than half of its
beams hit one robot's lidar housing. A segment where a robot is the plurality but not the majority
(a kin merged with the wall behind it, say) is a negative of category ``kin_minority``: no
positioning of such a segment is a kin centre, and the geometric detector rejects it too.

**Same-radius cylinders.** A cylinder whose radius is within :data:`SAME_RADIUS_TOL` of the housing
radius is geometrically identical to a kin in a single 2D scan (both are 3.5 cm circles). Its
segments are labelled non-kin, category ``same_radius_cylinder``, and flagged ``same_radius``;
training leaves them out (identical inputs with opposite labels would only pull every kin's
probability towards the class ratio) and evaluation reports them on their own.

Per segment: features, label, the kin's true centre (observer frame: x forward, y left), the object
and its details (HitKind, index, category, cylinder radius, prism sides, width), distance, number of
beams, noise level, scene seed and observer. Per scan, the *objects* table lists everything the scan
sees (robots and obstacles with at least one valid beam), which kin-level evaluation matches
detections against. The format and the category names are simulator-free: :mod:`detectors.samples`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from detectors.features import FeatureConfig, config_from_dict, segment_batch, segment_features
from detectors.samples import (
    CATEGORIES,
    DATASET_FORMAT,
    category_code,
    concat_records,
    load_dataset,
)
from detectors.windows import WindowConfig, candidate_windows, wide_segments

from .. import scenes
from ..core.lidar import HitKind, LidarSpec
from ..core.scenes import Box, Cylinder, DetectionSceneConfig, Prism, RandomArenaConfig, Scene
from ..core.world import World
from .seeds import check_training_seeds
from .swarm_scenes import SwarmSceneConfig, swarm_world

__all__ = [
    "CATEGORIES",
    "DATASET_FORMAT",
    "SAME_RADIUS_TOL",
    "DatasetConfig",
    "category_code",
    "make_scene",
    "label_scan",
    "window_labels",
    "scene_records",
    "concat_records",
    "load_dataset",
]

#: m: cylinders whose radius is this close to the housing radius count as "same radius".
SAME_RADIUS_TOL = 0.002
_WIDTH_TOL = 1e-4  # m: "exactly the kin's width" for prisms and boxes


def _pair(name: str, v, cast=float, lo=0.0):
    if not (isinstance(v, tuple | list) and len(v) == 2):
        raise ValueError(f"DatasetConfig.{name} must be a (min, max) pair, got {v!r}")
    a, b = cast(v[0]), cast(v[1])
    if not (lo <= a <= b) or not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"DatasetConfig.{name} must satisfy {lo} <= min <= max, got {v!r}")
    return (a, b)


@dataclass(frozen=True)
class DatasetConfig:
    """The random scene mix of the training data (all ranges inclusive, drawn per scene).

    Attributes:
        detection_prob: probability of a :func:`kin_envs.scenes.detection_scene` (an observer among
            kin and hard distractors: kin-width prisms and cuboids, cylinders of radius 2-12 cm
            including the housing's, walls and corners); otherwise a
            :func:`kin_envs.scenes.random_arena` (many robots, boxes and prisms of all sizes).
        n_kin: kin robots around the observer in a detection scene.
        n_distractors: distractors in a detection scene.
        distance: object distances from the observer in a detection scene, m.
        cylinder_radius: radius range of "other" cylinders in a detection scene, m.
        arena_robots, arena_obstacles: counts in a random arena.
        arena_size: side of a random arena, m.
        noise: relative range noise ``LidarSpec.noise_sigma`` (uniform in the range) ...
        zero_noise_prob: ... or exactly 0 with this probability (the paper's noise-free lidar).
        open_prob: probability that a detection scene has no boundary wall (the paper's empty Gazebo
            world: only the objects return beams).
        max_observers: robots scanned per scene (robot 0, the detection scene's observer, always).
        swarm_prob: probability of a swarm scene (:mod:`kin_envs.detection.swarm_scenes`: robots in
            clusters and at walls, driven a few steps) instead of the two families above; 0 (the
            default) draws nothing extra, so older configs give the same scenes as before.
        dropout: (min, max) beam dropout probability, drawn per scene with probability
            ``dropout_share`` (else 0); nothing is drawn when ``dropout_share`` is 0.
        dropout_share: share of scenes with beam dropout.
        bench_swarm_prob: probability of a scene from the benchmark's ``swarm`` generator
            (:func:`kin_envs.detection.benchmark.swarm_scene`, its default :class:`SwarmConfig`:
            8-32 robots driven into clusters and against walls), with a training seed;
        lookalike_prob: probability of a scene from the benchmark's ``lookalike`` generator
            (:func:`kin_envs.detection.benchmark.lookalike_scene`: kin among 7 cm prisms, boxes and
            cylinders). Both 0 (the default) draw nothing extra, so older configs give the same
            scenes as before. These two families are scanned noise-free, then the scene's noise and
            dropout are applied as the benchmark's conditions do
            (:func:`kin_envs.detection.benchmark.apply_condition`).
    """

    detection_prob: float = 0.8
    n_kin: tuple[int, int] = (1, 6)
    n_distractors: tuple[int, int] = (4, 18)
    distance: tuple[float, float] = (0.2, 4.0)
    cylinder_radius: tuple[float, float] = (0.02, 0.12)
    arena_robots: tuple[int, int] = (4, 24)
    arena_obstacles: tuple[int, int] = (8, 40)
    arena_size: tuple[float, float] = (4.0, 10.0)
    noise: tuple[float, float] = (0.0, 0.02)
    zero_noise_prob: float = 0.2
    open_prob: float = 0.15
    max_observers: int = 6
    swarm_prob: float = 0.0
    dropout: tuple[float, float] = (0.0, 0.1)
    dropout_share: float = 0.0
    bench_swarm_prob: float = 0.0
    lookalike_prob: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "detection_prob", "zero_noise_prob", "open_prob", "swarm_prob", "dropout_share",
            "bench_swarm_prob", "lookalike_prob",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ValueError(f"DatasetConfig.{name} must be a probability in [0, 1], got {v!r}")
        for name in ("n_kin", "n_distractors", "arena_robots", "arena_obstacles"):
            object.__setattr__(self, name, _pair(name, getattr(self, name), int, 0))
        for name in ("distance", "cylinder_radius", "arena_size", "noise", "dropout"):
            object.__setattr__(self, name, _pair(name, getattr(self, name), float, 0.0))
        if self.distance[0] <= 0 or self.cylinder_radius[0] <= 0 or self.arena_size[0] <= 0:
            raise ValueError("DatasetConfig: distance, cylinder_radius and arena_size must be > 0 m")
        if self.dropout[1] >= 1.0:
            raise ValueError(f"DatasetConfig.dropout must be < 1, got {self.dropout!r}")
        if self.noise[1] > 0.5:
            raise ValueError(f"DatasetConfig.noise must be <= 0.5 (relative), got {self.noise!r}")
        if self.bench_swarm_prob + self.lookalike_prob > 1.0:
            raise ValueError(
                f"DatasetConfig.bench_swarm_prob + lookalike_prob must be <= 1, got "
                f"{self.bench_swarm_prob!r} + {self.lookalike_prob!r}"
            )
        if self.arena_robots[0] < 1:
            raise ValueError(f"DatasetConfig.arena_robots must be >= 1, got {self.arena_robots!r}")
        if isinstance(self.max_observers, bool) or not isinstance(self.max_observers, int):
            raise ValueError(f"DatasetConfig.max_observers must be an int, got {self.max_observers!r}")
        if self.max_observers < 1:
            raise ValueError(f"DatasetConfig.max_observers must be >= 1, got {self.max_observers}")

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d) -> DatasetConfig:
        return config_from_dict(cls, d, lists_as_tuples=True)


def make_scene(seed: int, config: DatasetConfig | None = None, noise: float | None = None):
    """The scene of ``seed``: ``(scene, rng, info)``.

    One generator, ``numpy.random.default_rng(seed)``, draws the scene type, its parameters, the
    scene itself, the observers, and is then handed to the :class:`~kin_envs.World` for the lidar
    noise. ``noise`` overrides the drawn noise level (evaluation sweeps at fixed noise). Seeds
    reserved for the benchmark (:data:`kin_envs.detection.benchmark.BENCHMARK_SEEDS`) raise
    ``ValueError``.
    ``info``: ``family`` (0 detection scene, 1 random arena, 3 swarm scene, 4 the benchmark's swarm
    generator, 5 its lookalike generator), ``open`` (no boundary wall), ``noise``, ``dropout``,
    ``observers``, and for swarm scenes ``world`` (the driven world: its robots have moved away from
    ``scene``'s poses; for family 4 it scans noise-free and ``noise_free_world`` is set, the noise is
    applied afterwards as the benchmark does).
    """
    c = config or DatasetConfig()
    # training and validation data never use the benchmark's reserved seeds
    check_training_seeds([seed], "kin_envs.detection.dataset.make_scene")
    rng = np.random.default_rng(seed)
    detection = bool(rng.random() < c.detection_prob)
    sigma = 0.0 if rng.random() < c.zero_noise_prob else float(rng.uniform(*c.noise))
    open_world = bool(rng.random() < c.open_prob) and detection
    swarm = c.swarm_prob > 0 and bool(rng.random() < c.swarm_prob)
    dropout = 0.0
    if c.dropout_share > 0 and rng.random() < c.dropout_share:
        dropout = float(rng.uniform(*c.dropout))
    bench = None  # drawn last and only when asked for: older configs keep their scenes
    if c.bench_swarm_prob > 0 or c.lookalike_prob > 0:
        u = rng.random()
        if u < c.bench_swarm_prob:
            bench = "swarm"
        elif u < c.bench_swarm_prob + c.lookalike_prob:
            bench = "lookalike"
    if noise is not None:
        sigma = float(noise)
    lidar = LidarSpec(noise_sigma=sigma, dropout_prob=dropout)
    world = None
    if bench is not None:
        from . import benchmark  # lazy: the benchmark module is only needed for these families

        detection = open_world = swarm = False
        if bench == "swarm":
            world = benchmark.swarm_scene(rng)
            scene = world.scene
        else:
            scene = benchmark.lookalike_scene(rng).replace(lidar=lidar)
    elif swarm:
        detection = open_world = False
        world = swarm_world(rng, SwarmSceneConfig(), lidar)
        scene = world.scene
    elif detection:
        cfg = DetectionSceneConfig(
            n_kin=int(rng.integers(c.n_kin[0], c.n_kin[1] + 1)),
            n_distractors=int(rng.integers(c.n_distractors[0], c.n_distractors[1] + 1)),
            distance=c.distance,
            cylinder_radius=c.cylinder_radius,
        )
        scene = scenes.detection_scene(rng, cfg, lidar=lidar)
        if open_world:
            scene = scene.replace(arena=dataclasses.replace(scene.arena, walls=False))
    else:
        scene = scenes.random_arena(
            int(rng.integers(c.arena_robots[0], c.arena_robots[1] + 1)),
            int(rng.integers(c.arena_obstacles[0], c.arena_obstacles[1] + 1)),
            seed=rng,
            size=float(rng.uniform(*c.arena_size)),
            config=RandomArenaConfig(),
            lidar=lidar,
        )
    n = len(scene.robots)
    if n <= c.max_observers:
        observers = np.arange(n)
    elif detection:  # the designed observer first
        observers = np.concatenate(([0], 1 + rng.choice(n - 1, c.max_observers - 1, replace=False)))
    else:
        observers = np.sort(rng.choice(n, c.max_observers, replace=False))
    family = {"swarm": 4, "lookalike": 5}[bench] if bench else 3 if swarm else 0 if detection else 1
    info = {"family": family, "open": open_world, "noise": sigma, "dropout": dropout, "observers": observers}
    if world is not None:
        info["world"] = world  # already driven: scan this world, not a new one built from ``scene``
    if bench == "swarm":
        info["noise_free_world"] = True
    return scene, rng, info


# --- ground truth ---------------------------------------------------------------------------------


def _obstacle_table(scene: Scene) -> dict[str, np.ndarray]:
    """Per obstacle: category code, centre, cylinder radius, prism sides, width (m).

    One extra last entry (index ``len(obstacles)``) is a placeholder that non-obstacles index.
    """
    r = scene.robot.housing_radius
    n = len(scene.obstacles) + 1
    cat = np.full(n, category_code("boundary"), np.int8)
    cx, cy = np.zeros(n), np.zeros(n)
    radius, width = np.full(n, np.nan), np.full(n, np.nan)
    sides = np.zeros(n, np.int8)
    for j, o in enumerate(scene.obstacles):
        cx[j], cy[j] = o.center
        if isinstance(o, Cylinder):
            radius[j], width[j] = o.radius, 2 * o.radius
            same = abs(o.radius - r) <= SAME_RADIUS_TOL
            cat[j] = category_code("same_radius_cylinder" if same else "cylinder")
        elif isinstance(o, Prism):
            sides[j], width[j] = o.sides, o.width
            cat[j] = category_code("kin_width_prism" if abs(o.width - 2 * r) <= _WIDTH_TOL else "prism")
        elif isinstance(o, Box):
            sides[j], width[j] = 4, max(o.width, o.depth)
            kin_w = abs(o.width - 2 * r) <= _WIDTH_TOL and abs(o.depth - 2 * r) <= _WIDTH_TOL
            cat[j] = category_code("kin_width_box" if kin_w else "box")
        elif o.kind == "wall":
            cat[j] = category_code("wall")
        else:
            cat[j] = category_code("polygon")
    return {"category": cat, "cx": cx, "cy": cy, "radius": radius, "sides": sides, "width": width}


def _to_observer(poses_obs: np.ndarray, wx: np.ndarray, wy: np.ndarray):
    """World points → observer frames (x forward, y left); ``poses_obs`` per point ``(k, 3)``."""
    dx, dy = wx - poses_obs[:, 0], wy - poses_obs[:, 1]
    c, s = np.cos(poses_obs[:, 2]), np.sin(poses_obs[:, 2])
    return c * dx + s * dy, -s * dx + c * dy


def label_scan(scan, scene: Scene, batch, poses: np.ndarray) -> tuple[dict, dict]:
    """Labels of every segment of ``batch`` (the segmentation of ``scan.ranges``), and the objects
    each scan row sees.

    Args:
        scan: the :class:`~kin_envs.Scan` (ground truth ``hit_kind``, ``hit_index``).
        scene: its scene (obstacle details).
        batch: :func:`detectors.features.segment_batch` of ``scan.ranges``.
        poses: ``(n_robots, 3)`` all robots' poses when scanned.

    Returns:
        ``(segments, objects)``, dicts of equal-length arrays. ``segments`` (one entry per segment of
        ``batch``): ``label`` (1 kin), ``same_radius``, ``category``, ``hit_kind``, ``obj_index``,
        ``centre`` ``(S, 2)`` (kin centre in the observer frame, NaN otherwise), ``distance`` (m, to
        the object's centre; min range for walls and the boundary), ``obj_radius``, ``obj_sides``,
        ``obj_width``, ``dominant_fraction``, ``n_beams``, ``range_min``, ``row``.
        ``objects`` (one entry per object a row sees with >= 1 valid beam): ``row``, ``hit_kind``,
        ``obj_index``, ``category``, ``n_beams``, ``x``, ``y`` (centre, observer frame; NaN for walls
        and the boundary), ``distance``.
    """
    n_rows, n_beams = scan.ranges.shape
    obst = _obstacle_table(scene)
    n_obj = max(len(scene.robots), len(scene.obstacles)) + 1
    n_seg = batch.n_segments
    cnt = batch.count
    seg = np.repeat(np.arange(n_seg), cnt)
    offsets = np.zeros(n_seg, np.int64)
    np.cumsum(cnt[:-1], out=offsets[1:])
    k = np.arange(seg.shape[0]) - offsets[seg]
    beam = (batch.first[seg] + k) % n_beams
    row = batch.scan[seg]
    kind = scan.hit_kind[row, beam].astype(np.int64)
    idx = scan.hit_index[row, beam].astype(np.int64)
    key = kind * n_obj + (idx + 1)  # hit_index -1 (boundary) -> 0
    n_keys = (int(HitKind.WALL) + 1) * n_obj
    # per segment, the plurality object (lowest key on ties, so a robot wins a tie)
    pair, counts = np.unique(seg * n_keys + key, return_counts=True)
    pseg, pkey = pair // n_keys, pair % n_keys
    order = np.lexsort((pkey, -counts, pseg))
    first_of = np.ones(order.shape[0], bool)
    first_of[1:] = pseg[order][1:] != pseg[order][:-1]
    best = order[first_of]  # one per segment, in segment order
    dom_key, dom_count = pkey[best], counts[best]
    dom_kind, dom_idx = dom_key // n_obj, dom_key % n_obj - 1
    frac = dom_count / cnt
    is_robot = dom_kind == HitKind.ROBOT
    label = is_robot & (2 * dom_count > cnt)
    # corner: a wall segment whose beams hit more than one wall obstacle
    n_walls = np.bincount(pseg, weights=(pkey // n_obj == HitKind.WALL), minlength=n_seg)

    seg_row = batch.scan
    obs_pose = scan.poses[seg_row]
    category = np.full(n_seg, category_code("boundary"), np.int8)
    is_obst = (dom_kind >= HitKind.CYLINDER) & (dom_idx >= 0)
    category[is_obst] = obst["category"][dom_idx[is_obst]]
    category[(dom_kind == HitKind.WALL) & (n_walls > 1)] = category_code("corner")
    category[is_robot] = np.where(label[is_robot], category_code("kin"), category_code("kin_minority"))

    wx, wy = np.full(n_seg, np.nan), np.full(n_seg, np.nan)
    wx[is_robot], wy[is_robot] = poses[dom_idx[is_robot], 0], poses[dom_idx[is_robot], 1]
    take = np.where(is_obst, dom_idx, len(scene.obstacles))
    centred = is_obst & (obst["category"][take] != category_code("wall"))
    wx[centred], wy[centred] = obst["cx"][take[centred]], obst["cy"][take[centred]]
    ox, oy = _to_observer(obs_pose, wx, wy)
    range_min = np.minimum.reduceat(batch.ranges[row, beam], offsets)
    distance = np.where(np.isfinite(ox), np.hypot(ox, oy), range_min)
    centre = np.full((n_seg, 2), np.nan)
    centre[label] = np.stack([ox[label], oy[label]], axis=1)

    def obst_attr(name, fill):
        return np.where(is_obst, obst[name][take], fill)

    housing = scene.robot.housing_radius
    segments = {
        "label": label.astype(np.int8),
        "same_radius": category == category_code("same_radius_cylinder"),
        "category": category,
        "hit_kind": dom_kind.astype(np.int8),
        "obj_index": dom_idx.astype(np.int32),
        "centre": centre.astype(np.float32),
        "distance": distance.astype(np.float32),
        "obj_radius": np.where(is_robot, housing, obst_attr("radius", np.nan)).astype(np.float32),
        "obj_sides": obst_attr("sides", 0).astype(np.int8),
        "obj_width": np.where(is_robot, 2 * housing, obst_attr("width", np.nan)).astype(np.float32),
        "dominant_fraction": frac.astype(np.float32),
        "n_beams": cnt.astype(np.int16),
        "range_min": range_min.astype(np.float32),
        "row": seg_row.astype(np.int16),
    }

    # objects each row sees (valid beams only, as Scan.visible_robots)
    valid = scan.ranges < scan.range_max
    rows2 = np.broadcast_to(np.arange(n_rows)[:, None], valid.shape)[valid]
    okey = scan.hit_kind[valid].astype(np.int64) * n_obj + scan.hit_index[valid] + 1
    opair, ocount = np.unique(rows2 * n_keys + okey, return_counts=True)
    orow, okey = opair // n_keys, opair % n_keys
    okind, oidx = okey // n_obj, okey % n_obj - 1
    o_robot = okind == HitKind.ROBOT
    o_obst = (okind >= HitKind.CYLINDER) & (oidx >= 0)
    ocat = np.full(orow.shape[0], category_code("boundary"), np.int8)
    ocat[o_obst] = obst["category"][oidx[o_obst]]
    ocat[o_robot] = category_code("kin")
    owx, owy = np.full(orow.shape[0], np.nan), np.full(orow.shape[0], np.nan)
    owx[o_robot], owy[o_robot] = poses[oidx[o_robot], 0], poses[oidx[o_robot], 1]
    oc = o_obst & (ocat != category_code("wall"))
    owx[oc], owy[oc] = obst["cx"][oidx[oc]], obst["cy"][oidx[oc]]
    ox2, oy2 = _to_observer(scan.poses[orow], owx, owy)
    objects = {
        "row": orow.astype(np.int16),
        "hit_kind": okind.astype(np.int8),
        "obj_index": oidx.astype(np.int32),
        "category": ocat,
        "n_beams": ocount.astype(np.int16),
        "x": ox2.astype(np.float32),
        "y": oy2.astype(np.float32),
        "distance": np.hypot(ox2, oy2).astype(np.float32),
    }
    return segments, objects


def window_labels(segments: dict) -> np.ndarray:
    """The benchmark's ground-truth rule on :func:`label_scan` rows of candidate windows: kin when at
    least 2 (valid) beams of the window hit one housing and they are most of the window's beams."""
    n = np.asarray(segments["n_beams"], np.int64)
    dom = np.rint(np.asarray(segments["dominant_fraction"], np.float64) * n).astype(np.int64)
    kin = (np.asarray(segments["hit_kind"]) == HitKind.ROBOT) & (dom >= 2) & (2 * dom > n)
    return kin.astype(np.int8)


def scene_records(
    seed: int,
    config: DatasetConfig | None = None,
    feature_config: FeatureConfig | None = None,
    noise: float | None = None,
    observers=None,
    windows: WindowConfig | None = None,
):
    """Scan, segment, featurise and label one scene.

    Returns ``(segments, objects, info)``: the :func:`label_scan` dicts plus ``x`` (features),
    ``frames`` (local frames), ``fit_centre`` (the features' circle-fit centre) and the columns
    ``observer``, ``noise``, ``seed``, ``family`` (0 detection scene, 1 random arena, 2 detection
    scene without boundary wall, 3 swarm scene, 4 / 5 the benchmark's swarm / lookalike generators);
    ``info`` as :func:`make_scene` plus ``scan``, ``scene`` and
    ``batch``. ``observers`` overrides the scanned robots.

    With ``windows`` (issue 11, round 6) the candidate windows of every segment too wide for the
    learned detector's pre-gate (:func:`detectors.windows.candidate_windows`, the function the
    detector-side experiment calls) follow the segments as extra rows, column ``window`` 1 (0 for
    segments), labelled by :func:`window_labels`; ``info["windows"]`` holds them.
    """
    fc = feature_config or FeatureConfig()
    scene, rng, info = make_scene(seed, config, noise)
    if observers is not None:
        info["observers"] = np.asarray(observers, dtype=np.int64)
    world = info.pop("world", None) or World(scene, seed=rng)
    if info.pop("noise_free_world", False):  # the benchmark's swarm world: its lidar has no noise
        from .benchmark import Condition, apply_condition

        scan = apply_condition(
            world.scan(robots=info["observers"], noise=False),
            Condition(info["noise"], info["dropout"]), rng, scene.lidar,
        )  # fmt: skip
    else:
        scan = world.scan(robots=info["observers"])
    batch = segment_batch(scan.ranges, scan.angles, fc)
    feats = segment_features(batch, fc)
    segs, objs = label_scan(scan, scene, batch, world.poses)
    segs["x"] = feats.x
    segs["frames"] = feats.frames.astype(np.float32)
    segs["fit_centre"] = feats.fit_centre.astype(np.float32)
    if windows is not None:
        step = 2 * math.pi / scan.angles.shape[0]  # the lidar's full turn (LidarSpec)
        win = candidate_windows(batch, wide_segments(batch, step, fc.r), step, fc.r, windows, fc)
        wsegs, _ = label_scan(scan, scene, win.batch, world.poses)
        wsegs["label"] = window_labels(wsegs)
        wsegs["centre"][wsegs["label"] == 0] = np.nan
        wf = segment_features(win.batch, fc)
        wsegs["x"] = wf.x
        wsegs["frames"] = wf.frames.astype(np.float32)
        wsegs["fit_centre"] = wf.fit_centre.astype(np.float32)
        segs["window"] = np.zeros(segs["label"].shape[0], np.int8)
        wsegs["window"] = np.ones(wsegs["label"].shape[0], np.int8)
        segs = concat_records([segs, wsegs])
        info["windows"] = win
    for table in (segs, objs):
        m = table["row"].shape[0]
        table["observer"] = scan.robots[table["row"]].astype(np.int16)
        table["noise"] = np.full(m, info["noise"], np.float32)
        table["seed"] = np.full(m, seed, np.int64)
        table["family"] = np.full(m, 2 if info["open"] else info["family"], np.int8)
    info.update(scan=scan, scene=scene, batch=batch)
    return segs, objs, info


