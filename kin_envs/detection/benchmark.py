"""The kin detection benchmark: fixed, versioned splits and DROW / DR-SPAAM-style metrics.

Splits are data (:class:`SplitSpec`, :data:`SPLITS`), generated from seeds in a reserved range
(:data:`BENCHMARK_SEEDS`) that training data may not use (:func:`check_training_seeds`; the dataset
generator :func:`kin_envs.detection.dataset.make_scene` refuses them):

* ``paper``: the paper's Scenario I and II (:func:`kin_envs.scenes.paper_scenario`) at 0.3-1.5 m, the
  observer's heading jittered by up to half a beam so objects fall anywhere between beams;
* ``swarm``: 8-32 robots in ~6 m walled arenas with 10-30 obstacles (40 % of them exactly 7 cm wide:
  prisms, boxes, same-radius cylinders), driven for a few seconds by scripted commands towards
  shared gathering points (some by a wall) and random wandering before the scan, so robots cluster,
  touch each other and the walls, and occlude one another (:func:`swarm_scene`);
* ``lookalike``: an observer and 1-4 kin among 7 cm prisms of 3-6 sides at any orientation (boxes
  included), cylinders of 2.5-6 cm radius and cylinders of exactly the housing radius, at 0.3-5 m
  (:func:`lookalike_scene`).

Every split is scanned noise-free once from **every robot**; each :class:`Condition` (range noise
0 / 0.5 / 1 / 2 %, and beam dropout) then draws its own noise for the same scans.

**Ground truth.** A kin is *counted* in a scan when at least :data:`MIN_BEAMS` (2) valid beams (range
below the maximum) hit its housing. A kin seen by 1 valid beam is "don't care": it is not required,
and a detection matched to it is neither a true nor a false positive. **Matching**: Hungarian, a
detection and a kin match when their centres are at most :data:`GATE` (0.10 m) apart
(:mod:`detectors.metrics`). Unmatched detections on cylinders of exactly the housing radius (which
no single 2D scan can tell from a kin) are counted apart (``same_radius``), not as false positives.

**Metrics** (per detector, split, condition; overall, per distance bin :data:`DISTANCE_EDGES` and per
beams-on-target bin :data:`BEAM_EDGES`): average precision from the precision-recall curve over
``Detection.score`` (:func:`detectors.metrics.pr_curve`), P / R / F1 at the detector's shipped
operating point, centre error of the true positives, false positives per distractor kind and scans
per second (timed warm, inside ``detect_batch``). The PR curve needs candidates below the operating
point, so every detector also runs at a permissive operating point (:func:`permissive`: the
geometric detector with the shape threshold lifted, the learned one with ``threshold=0``).
Intervals: 95 % percentile bootstrap over scenes (``scipy.stats.bootstrap``).

Binning: a kin falls in the bin of its true centre distance / valid beams; for P / R / F1 a false
positive falls in the bin of the detection's own range / segment beams; for AP, kin outside the bin
become "don't care" and detections outside it count only when they match a counted kin.
"""

from __future__ import annotations

import dataclasses
import logging as _logging
import math
import sys
import time
import warnings
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from detectors.base import KinDetector
from detectors.features import config_from_dict
from detectors.metrics import increments, match, pr_from_increments

from .. import scenes
from ..core.lidar import HitKind, LidarSpec
from ..core.scenes import DetectionSceneConfig, RandomArenaConfig, Robot, Scene
from ..core.world import Scan, World
from .evaluation import SAME_RADIUS_TOL, describe_hits, kin_truth, segment_beams
from .seeds import BENCHMARK_SEEDS, check_training_seeds

_log = _logging.getLogger(__name__)

__all__ = [
    "BEAM_EDGES",
    "BENCHMARK_SEEDS",
    "BENCHMARK_VERSION",
    "CONDITIONS",
    "DISTANCE_EDGES",
    "GATE",
    "MIN_BEAMS",
    "MISS_REASONS",
    "SPLITS",
    "BenchmarkResults",
    "Condition",
    "LookalikeConfig",
    "PaperConfig",
    "SplitSample",
    "SplitSpec",
    "SwarmConfig",
    "check_training_seeds",
    "generate_split",
    "lookalike_scene",
    "paper_scene",
    "permissive",
    "run_benchmark",
    "split_from_dict",
    "swarm_scene",
]

#: Bumped whenever a split, a condition, the ground-truth rule or a metric changes.
BENCHMARK_VERSION = 1
#: Valid beams on a kin's housing for it to count as ground truth (1 beam: "don't care").
MIN_BEAMS = 2
#: Matching gate on the centre distance, m.
GATE = 0.10
#: kin closer than 0.3 m (touching robots) get their own bin: their housing is partly inside the
#: lidar's 0.15 m minimum range
DISTANCE_EDGES = (0.0, 0.3, 1.0, 2.0, 3.0, 5.0)
#: beams on target: 2, 3-4, 5-9, 10-19, 20+
BEAM_EDGES = (2, 3, 5, 10, 20, 361)
#: Geometric shape threshold of the permissive run, m: no segment that passes the diameter filter
#: has a summed residual near 1 km, so every one becomes a ranked candidate.
PERMISSIVE_F_THRESHOLD = 1e3


# --------------------------------------------------------------------------- configs


def _pair(owner: str, name: str, v, cast, lo):
    if not (isinstance(v, tuple | list) and len(v) == 2):
        raise ValueError(f"{owner}.{name} must be a (min, max) pair, got {v!r}")
    a, b = cast(v[0]), cast(v[1])
    if not (math.isfinite(a) and math.isfinite(b) and lo <= a <= b):
        raise ValueError(f"{owner}.{name} must satisfy {lo} <= min <= max, got {v!r}")
    return (a, b)


def _from_dict(cls, d):
    return config_from_dict(cls, d, lists_as_tuples=True)


def _to_dict(obj) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(obj).items()}


@dataclass(frozen=True)
class PaperConfig:
    """``paper`` split: Scenario I or II at a distance drawn uniformly from ``distance``.

    Attributes:
        scenarios: scenario numbers, drawn uniformly.
        distance: (min, max) distance of the arc, m.
        heading_jitter: the observer's heading is turned by up to this many beam steps (either way),
            so the objects fall anywhere between two beams.
    """

    scenarios: tuple[int, ...] = (1, 2)
    distance: tuple[float, float] = (0.3, 1.5)
    heading_jitter: float = 0.5

    def __post_init__(self) -> None:
        sc = tuple(self.scenarios)
        if not sc or any(s not in (1, 2) for s in sc):
            raise ValueError(
                f"PaperConfig.scenarios must be a non-empty tuple of 1 and/or 2, got {self.scenarios!r}"
            )
        object.__setattr__(self, "scenarios", sc)
        object.__setattr__(self, "distance", _pair("PaperConfig", "distance", self.distance, float, 0.0))
        if self.distance[0] < 0.3:
            raise ValueError(
                f"PaperConfig.distance must start at >= 0.3 m (the objects must fit), got {self.distance}"
            )
        if not (isinstance(self.heading_jitter, int | float) and 0 <= self.heading_jitter <= 0.5):
            raise ValueError(
                f"PaperConfig.heading_jitter must be in [0, 0.5] beams, got {self.heading_jitter!r}"
            )


@dataclass(frozen=True)
class SwarmConfig:
    """``swarm`` split: a walled arena of robots and clutter, robots driven before the scan.

    Attributes:
        n_robots, n_obstacles: (min, max) counts, inclusive.
        arena_size: (min, max) side of the square arena, m.
        kin_width_prob: share of obstacles exactly the kin's width (7 cm prisms and boxes, cylinders
            of the housing radius); see :class:`kin_envs.scenes.RandomArenaConfig`.
        kind_weights: relative frequency of cylinder, box, prism, interior wall.
        motion_seconds: simulated time the robots drive before the scan, s.
        n_gathering_points: (min, max) points the robots drive to (so they cluster).
        wall_point_prob: probability that a gathering point lies against the boundary wall.
        wander_prob: share of robots that wander with random commands instead.
    """

    n_robots: tuple[int, int] = (8, 32)
    n_obstacles: tuple[int, int] = (10, 30)
    arena_size: tuple[float, float] = (5.5, 6.5)
    kin_width_prob: float = 0.4
    kind_weights: tuple[float, float, float, float] = (0.35, 0.2, 0.35, 0.1)
    motion_seconds: float = 8.0
    n_gathering_points: tuple[int, int] = (1, 4)
    wall_point_prob: float = 0.4
    wander_prob: float = 0.25

    def __post_init__(self) -> None:
        o = "SwarmConfig"
        for name in ("n_robots", "n_obstacles", "n_gathering_points"):
            object.__setattr__(self, name, _pair(o, name, getattr(self, name), int, 0))
        object.__setattr__(self, "arena_size", _pair(o, "arena_size", self.arena_size, float, 1.0))
        if self.n_robots[0] < 2 or self.n_gathering_points[0] < 1:
            raise ValueError(f"{o}: n_robots must start at >= 2 and n_gathering_points at >= 1")
        for name in ("kin_width_prob", "wall_point_prob", "wander_prob"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0 <= v <= 1):
                raise ValueError(f"{o}.{name} must be a probability in [0, 1], got {v!r}")
        w = tuple(float(x) for x in self.kind_weights)
        if len(w) != 4 or min(w) < 0 or sum(w) <= 0:
            raise ValueError(f"{o}.kind_weights must be 4 non-negative weights, got {self.kind_weights!r}")
        object.__setattr__(self, "kind_weights", w)
        if not (isinstance(self.motion_seconds, int | float) and 0 <= self.motion_seconds <= 120):
            raise ValueError(f"{o}.motion_seconds must be in [0, 120] s, got {self.motion_seconds!r}")


@dataclass(frozen=True)
class LookalikeConfig:
    """``lookalike`` split: an observer and kin among 7 cm look-alikes.

    Attributes:
        n_kin, n_distractors: (min, max) counts, inclusive.
        distance: (min, max) distance of objects from the observer, m.
        weights: relative frequency of 7 cm prisms (3-6 sides), 7 x 7 cm boxes, cylinders of the
            housing radius, other cylinders (radius from ``cylinder_radius``).
        cylinder_radius: (min, max) radius of other cylinders, m (within 5 mm of the housing's
            redrawn).
    """

    n_kin: tuple[int, int] = (1, 4)
    n_distractors: tuple[int, int] = (6, 14)
    distance: tuple[float, float] = (0.3, 5.0)
    weights: tuple[float, float, float, float] = (0.5, 0.1, 0.2, 0.2)
    cylinder_radius: tuple[float, float] = (0.025, 0.06)

    def __post_init__(self) -> None:
        o = "LookalikeConfig"
        for name in ("n_kin", "n_distractors"):
            object.__setattr__(self, name, _pair(o, name, getattr(self, name), int, 0))
        for name in ("distance", "cylinder_radius"):
            object.__setattr__(self, name, _pair(o, name, getattr(self, name), float, 1e-3))
        w = tuple(float(x) for x in self.weights)
        if len(w) != 4 or min(w) < 0 or sum(w) <= 0:
            raise ValueError(f"{o}.weights must be 4 non-negative weights, got {self.weights!r}")
        object.__setattr__(self, "weights", w)


@dataclass(frozen=True)
class Condition:
    """A lidar condition: relative range noise ``noise`` (sigma / distance) and ``dropout`` probability."""

    noise: float = 0.0
    dropout: float = 0.0

    def __post_init__(self) -> None:
        LidarSpec(noise_sigma=self.noise, dropout_prob=self.dropout)  # validates both

    @property
    def name(self) -> str:
        s = f"noise {100 * self.noise:g} %"
        return s + (f", dropout {100 * self.dropout:g} %" if self.dropout else "")


#: Range noise 0 / 0.5 / 1 / 2 % without dropout, then 10 % beam dropout at 0 and 1 % noise.
CONDITIONS: tuple[Condition, ...] = (
    Condition(0.0),
    Condition(0.005),
    Condition(0.01),
    Condition(0.02),
    Condition(0.0, 0.1),
    Condition(0.01, 0.1),
)

_GENERATORS = {"paper": PaperConfig, "swarm": SwarmConfig, "lookalike": LookalikeConfig}


@dataclass(frozen=True)
class SplitSpec:
    """One benchmark split: a scene generator config and its seeds.

    Scene ``i`` uses seed ``first_seed + i`` (inside :data:`BENCHMARK_SEEDS`); ``n_scenes`` is the
    full size, ``reduced_scenes`` the main job's.
    """

    name: str
    config: PaperConfig | SwarmConfig | LookalikeConfig
    first_seed: int
    n_scenes: int
    reduced_scenes: int
    conditions: tuple[Condition, ...] = CONDITIONS

    def __post_init__(self) -> None:
        if self.name not in _GENERATORS:
            raise ValueError(f"SplitSpec.name must be one of {sorted(_GENERATORS)}, got {self.name!r}")
        if not isinstance(self.config, _GENERATORS[self.name]):
            raise ValueError(
                f"SplitSpec {self.name!r}: config must be a {_GENERATORS[self.name].__name__}, "
                f"got {type(self.config).__name__}"
            )
        for name in ("first_seed", "n_scenes", "reduced_scenes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < (0 if name == "first_seed" else 1):
                raise ValueError(f"SplitSpec.{name} must be a positive integer, got {v!r}")
        if not (
            BENCHMARK_SEEDS.start <= self.first_seed
            and self.first_seed + self.n_scenes <= BENCHMARK_SEEDS.stop
        ):
            raise ValueError(
                f"SplitSpec {self.name!r}: seeds {self.first_seed}..{self.first_seed + self.n_scenes - 1} "
                f"must lie in the reserved range [{BENCHMARK_SEEDS.start}, {BENCHMARK_SEEDS.stop})"
            )
        conds = tuple(self.conditions)
        if not conds or not all(isinstance(c, Condition) for c in conds):
            raise ValueError(
                f"SplitSpec.conditions must be a non-empty tuple of Condition, got {self.conditions!r}"
            )
        object.__setattr__(self, "conditions", conds)

    def seeds(self, n: int, seed_offset: int = 0) -> range:
        """Seeds of ``n`` scenes starting ``seed_offset`` scenes in (still inside the reserved range)."""
        first = self.first_seed + seed_offset
        if seed_offset < 0 or first + n > BENCHMARK_SEEDS.stop:
            raise ValueError(
                f"split {self.name!r}: seed_offset={seed_offset}, n={n} leaves the reserved seed range"
            )
        return range(first, first + n)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "config": _to_dict(self.config),
            "first_seed": self.first_seed,
            "n_scenes": self.n_scenes,
            "reduced_scenes": self.reduced_scenes,
            "conditions": [_to_dict(c) for c in self.conditions],
        }


def split_from_dict(d) -> SplitSpec:
    """Rebuild a :class:`SplitSpec` from :meth:`SplitSpec.to_dict` (unknown keys raise)."""
    if not isinstance(d, Mapping):
        raise ValueError(f"SplitSpec: expected a dict, got {type(d).__name__}")
    unknown = sorted(set(d) - {"name", "config", "first_seed", "n_scenes", "reduced_scenes", "conditions"})
    if unknown:
        raise ValueError(f"SplitSpec: unknown key(s) {unknown}")
    name = d.get("name")
    if name not in _GENERATORS:
        raise ValueError(f"SplitSpec.name must be one of {sorted(_GENERATORS)}, got {name!r}")
    return SplitSpec(
        name,
        _from_dict(_GENERATORS[name], d.get("config", {})),
        d.get("first_seed", -1),
        d.get("n_scenes", 0),
        d.get("reduced_scenes", 0),
        tuple(_from_dict(Condition, c) for c in d.get("conditions", [_to_dict(c) for c in CONDITIONS])),
    )


_B = BENCHMARK_SEEDS.start
#: The benchmark's splits (version :data:`BENCHMARK_VERSION`).
SPLITS: dict[str, SplitSpec] = {
    "paper": SplitSpec("paper", PaperConfig(), _B, n_scenes=400, reduced_scenes=60),
    "swarm": SplitSpec("swarm", SwarmConfig(), _B + 10_000_000, n_scenes=300, reduced_scenes=24),
    "lookalike": SplitSpec("lookalike", LookalikeConfig(), _B + 20_000_000, n_scenes=600, reduced_scenes=80),
}


# --------------------------------------------------------------------------- scene generators


def paper_scene(seed: int | np.random.Generator, config: PaperConfig | None = None) -> Scene:
    """A seeded ``paper`` scene: Scenario I or II at a random distance, observer heading jittered.

    Below ~0.4 m the paper's arc spacing (30° / 20°) would make neighbours overlap; there the
    spacing grows in 5° steps until they fit.
    """
    c = config or PaperConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    number = int(c.scenarios[int(rng.integers(len(c.scenarios)))])
    distance = float(rng.uniform(*c.distance))
    spacing = {1: 30.0, 2: 20.0}[number]  # the paper's arc spacing, widened where objects would overlap
    while True:
        try:
            scene = scenes.paper_scenario(number, distance=distance, spacing_deg=spacing)
            break
        except ValueError:
            if spacing >= 60.0:
                raise
            spacing += 5.0
    jitter = float(rng.uniform(-c.heading_jitter, c.heading_jitter)) * scene.lidar.resolution
    obs = scene.robots[0]
    robots = (Robot(obs.x, obs.y, obs.theta + jitter), *scene.robots[1:])
    return scene.replace(robots=robots)


def lookalike_scene(seed: int | np.random.Generator, config: LookalikeConfig | None = None) -> Scene:
    """A seeded ``lookalike`` scene (a :func:`kin_envs.scenes.detection_scene` of look-alikes)."""
    c = config or LookalikeConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    cfg = DetectionSceneConfig(
        n_kin=int(rng.integers(c.n_kin[0], c.n_kin[1] + 1)),
        n_distractors=int(rng.integers(c.n_distractors[0], c.n_distractors[1] + 1)),
        distance=c.distance,
        distractor_weights=(*c.weights, 0.0, 0.0),
        cylinder_radius=c.cylinder_radius,
    )
    return scenes.detection_scene(rng, cfg)


def _wall_point(rng, half: float, inset: float) -> tuple[float, float]:
    side = int(rng.integers(4))
    t = float(rng.uniform(-half + inset, half - inset))
    e = half - inset
    return [(t, e), (t, -e), (e, t), (-e, t)][side]


def swarm_scene(seed: int | np.random.Generator, config: SwarmConfig | None = None) -> World:
    """A seeded ``swarm`` world after ``config.motion_seconds`` of driving (ready to scan).

    Robots start spread over a :func:`kin_envs.scenes.random_arena`; each drives to one of a few
    shared gathering points (some against the boundary wall) with a proportional heading controller
    and a little steering noise, or wanders with random commands re-drawn every second, so robots
    end up in clusters, against walls and obstacles, and hidden behind one another. Returns the
    :class:`~kin_envs.World` (its ``scene`` holds the start poses; ``world.poses`` the current ones).
    """
    c = config or SwarmConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    size = float(rng.uniform(*c.arena_size))
    n_robots = int(rng.integers(c.n_robots[0], c.n_robots[1] + 1))
    n_obst = int(rng.integers(c.n_obstacles[0], c.n_obstacles[1] + 1))
    arena_cfg = RandomArenaConfig(kind_weights=c.kind_weights, kin_width_prob=c.kin_width_prob)
    scene = scenes.random_arena(n_robots, n_obst, seed=rng, size=size, config=arena_cfg)
    world = World(scene, seed=rng)
    half = 0.5 * size
    n_pts = int(rng.integers(c.n_gathering_points[0], c.n_gathering_points[1] + 1))
    points = np.array(
        [
            _wall_point(rng, half, 0.15) if rng.random() < c.wall_point_prob
            else tuple(rng.uniform(-0.6 * half, 0.6 * half, 2))
            for _ in range(n_pts)
        ]
    )  # fmt: skip
    goal = rng.integers(n_pts, size=n_robots)
    wander = rng.random(n_robots) < c.wander_prob
    spec = scene.robot
    v_max = spec.max_wheel_speed * spec.wheel_radius
    steps = int(round(c.motion_seconds / world.config.control_dt))
    per_second = max(1, int(round(1.0 / world.config.control_dt)))
    wander_cmd = np.zeros((n_robots, 2))
    for k in range(steps):
        if k % per_second == 0:
            wander_cmd = np.stack(
                [rng.uniform(0.0, v_max, n_robots), rng.uniform(-2.0, 2.0, n_robots)], axis=1
            )
        p = world.poses
        to = points[goal] - p[:, :2]
        err = np.arctan2(to[:, 1], to[:, 0]) - p[:, 2]
        err = np.arctan2(np.sin(err), np.cos(err))
        cmd = np.stack(
            [v_max * np.clip(np.cos(err), 0.0, 1.0), 3.0 * err + rng.normal(0.0, 0.3, n_robots)], axis=1
        )
        cmd[wander] = wander_cmd[wander]
        world.step(commands=cmd)
    return world


@dataclass(frozen=True, eq=False)
class SplitSample:
    """One benchmark scene: its seed, its scene (obstacles; robots at the start) and the noise-free
    scan of every robot at scan time (``scan.poses``: where the robots were)."""

    seed: int
    scene: Scene
    scan: Scan


def _sample(split: SplitSpec, seed: int) -> SplitSample:
    rng = np.random.default_rng(seed)
    if split.name == "swarm":
        world = swarm_scene(rng, split.config)
    else:
        scene = (
            paper_scene(rng, split.config) if split.name == "paper" else lookalike_scene(rng, split.config)
        )
        world = World(scene, seed=rng)
    return SplitSample(seed, world.scene, world.scan(noise=False))


def generate_split(
    split: str | SplitSpec, n_scenes: int | None = None, seed_offset: int = 0, progress: bool = False
) -> list[SplitSample]:
    """The scenes of a split: ``n_scenes`` (default: its full size) from ``first_seed + seed_offset``."""
    spec = SPLITS[split] if isinstance(split, str) and split in SPLITS else split
    if not isinstance(spec, SplitSpec):
        raise ValueError(f"unknown split {split!r}; expected one of {sorted(SPLITS)} or a SplitSpec")
    n = spec.n_scenes if n_scenes is None else n_scenes
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n_scenes must be an integer >= 1, got {n_scenes!r}")
    seeds = spec.seeds(n, seed_offset)
    it = seeds
    if progress:  # a bar with tqdm (train / ros extras), silent on the core install
        from kin_envs.cli import progress as _bar

        it = _bar(seeds, desc=f"generate {spec.name}", leave=False)
    return [_sample(spec, s) for s in it]


def apply_condition(
    scan: Scan, condition: Condition, rng: np.random.Generator, spec: LidarSpec | None = None
) -> Scan:
    """``scan`` (noise-free) as a lidar with ``condition`` would report it (as :meth:`World.scan`):
    Gaussian range noise of ``condition.noise`` times the true range, readings outside
    ``[range_min, range_max]`` or dropped (probability ``condition.dropout``) read ``range_max``."""
    spec = spec or LidarSpec()
    if condition.noise == 0 and condition.dropout == 0:
        return scan
    ranges = scan.ranges.copy()
    hit = np.isfinite(scan.true_ranges)
    d = scan.true_ranges[hit].astype(np.float64)
    if condition.noise > 0:
        d += rng.normal(0.0, 1.0, d.size) * condition.noise * d
    invalid = (d < spec.range_min) | (d > spec.range_max)
    if condition.dropout > 0:
        invalid |= rng.random(d.size) < condition.dropout
    d[invalid] = spec.range_max
    ranges[hit] = d
    return dataclasses.replace(scan, ranges=ranges)


# --------------------------------------------------------------------------- detectors


def permissive(detector: KinDetector) -> KinDetector:
    """The detector at a permissive operating point, for the PR curve.

    A detector may define ``permissive()`` returning it; the geometric detector gets
    ``F_threshold`` = :data:`PERMISSIVE_F_THRESHOLD` (its score ``F_th / (F_th + F)`` still ranks by
    the shape error ``F``; only the diameter filter and the 3-beam minimum remain), the learned
    detector ``threshold=0`` (every segment, scored by ``p(kin)``). Any other detector is used as it
    is (its curve then ends at its operating point).
    """
    own = getattr(detector, "permissive", None)
    if callable(own):
        return own()
    from detectors.geometric import GeometricKinDetector

    if isinstance(detector, GeometricKinDetector):
        params = dataclasses.replace(detector.params, F_threshold=PERMISSIVE_F_THRESHOLD)
        return GeometricKinDetector(params, reports=False)
    learned = sys.modules.get("detectors.learned")  # loaded iff a learned detector exists
    if learned is not None and isinstance(detector, learned.LearnedKinDetector):
        return learned.LearnedKinDetector(
            detector.checkpoint["path"], threshold=0.0, device=detector.device,
            positioning=detector.positioning, reports=False, pre_gate=getattr(detector, "pre_gate", True),
            windows=getattr(detector, "windows", None),
            suppress_duplicates=getattr(detector, "suppress_duplicates", True),
        )  # fmt: skip
    return detector


def _run(detector: KinDetector, ranges: np.ndarray, angles: np.ndarray, batch: int):
    """All rows through ``detect_batch`` in batches: ``(results, seconds)``, after a warm-up call."""
    detector.detect_batch(ranges[: min(8, len(ranges))], angles)  # compile / allocate first
    out, seconds = [], 0.0
    for s in range(0, ranges.shape[0], batch):
        t0 = time.perf_counter()
        out.extend(detector.detect_batch(ranges[s : s + batch], angles))
        seconds += time.perf_counter() - t0
    return out, seconds


def _table(results) -> dict[str, np.ndarray]:
    rows = [
        (f, d.score, d.x, d.y, d.range, d.n_beams, d.first_beam)
        for f, res in enumerate(results)
        for d in res.detections
    ]
    a = np.array(rows, dtype=np.float64).reshape(-1, 7)
    return {
        "frame": a[:, 0].astype(np.int64),
        "score": a[:, 1],
        "xy": a[:, 2:4],
        "range": a[:, 4],
        "n_beams": a[:, 5].astype(np.int64),
        "first": a[:, 6].astype(np.int64),
    }


# --------------------------------------------------------------------------- evaluation of one condition


@dataclass(frozen=True, eq=False)
class _Frames:
    """All scan rows of a split under one condition, with their ground truth."""

    ranges: np.ndarray  # (F, n)
    angles: np.ndarray
    scene_of: np.ndarray  # (F,) scene index of each frame
    scans: list  # per scene: the condition's Scan
    samples: list
    row_of: np.ndarray  # (F,) row within its scene's scan
    kin: dict  # frame, xy, range, n_beams, care
    same_radius_beam: np.ndarray  # (F, n) valid beam on a same-radius cylinder
    same_radius_seen: int  # (frame, same-radius cylinder) pairs with >= MIN_BEAMS valid beams
    valid: np.ndarray  # (F, n)


def _frames(samples: Sequence[SplitSample], condition: Condition, cond_index: int) -> _Frames:
    scans, scene_of, row_of = [], [], []
    kf, kxy, kr, kb, krob = [], [], [], [], []
    srb = []
    seen = 0
    f = 0
    for i, smp in enumerate(samples):
        rng = np.random.default_rng((smp.seed, cond_index))
        scan = apply_condition(smp.scan, condition, rng, smp.scene.lidar)
        scans.append(scan)
        n_rows = scan.ranges.shape[0]
        radius = np.array(
            [
                getattr(o, "radius", math.nan) if o.kind == "cylinder" else math.nan
                for o in smp.scene.obstacles
            ]
            + [math.nan]
        )
        same = np.abs(radius - smp.scene.robot.housing_radius) <= SAME_RADIUS_TOL
        valid = scan.ranges < scan.range_max
        is_cyl = scan.hit_kind == HitKind.CYLINDER
        on_same = valid & is_cyl & same[np.where(is_cyl, scan.hit_index, -1)]
        srb.append(on_same)
        rows_, cyl_ = np.nonzero(on_same)
        _, per_obj = np.unique(rows_ * (len(radius) + 1) + scan.hit_index[rows_, cyl_], return_counts=True)
        seen += int((per_obj >= MIN_BEAMS).sum())
        for r in range(n_rows):
            for k in kin_truth(scan, r, smp.scene):
                kf.append(f + r)
                kxy.append((k.x, k.y))
                kr.append(k.range)
                kb.append(k.n_beams)
                krob.append(k.robot)
        scene_of.extend([i] * n_rows)
        row_of.extend(range(n_rows))
        f += n_rows
    ranges = np.concatenate([s.ranges for s in scans]).astype(np.float64)
    nb = np.asarray(kb, np.int64)
    kin = {
        "frame": np.asarray(kf, np.int64),
        "xy": np.asarray(kxy, np.float64).reshape(-1, 2),
        "range": np.asarray(kr, np.float64),
        "n_beams": nb,
        "care": nb >= MIN_BEAMS,
        "robot": np.asarray(krob, np.int64),
    }
    return _Frames(
        ranges, scans[0].angles, np.asarray(scene_of), scans, list(samples), np.asarray(row_of),
        kin, np.concatenate(srb), seen, ranges < scans[0].range_max,
    )  # fmt: skip


def _beam_fraction(mask: np.ndarray, valid: np.ndarray, frame, first, count) -> np.ndarray:
    """Fraction of each segment's valid beams (``first``, ``count``, wrapping) where ``mask``."""
    n = mask.shape[1]
    cm = np.concatenate([np.zeros((mask.shape[0], 1)), np.cumsum(np.concatenate([mask, mask], 1), 1)], 1)
    cv = np.concatenate([np.zeros((mask.shape[0], 1)), np.cumsum(np.concatenate([valid, valid], 1), 1)], 1)
    end = first + np.minimum(count, n)
    m = cm[frame, end] - cm[frame, first]
    v = cv[frame, end] - cv[frame, first]
    return np.where(v > 0, m / np.maximum(v, 1), 0.0)


#: Score thresholds the AP intervals are computed at (the point estimate uses every score).
_CI_LEVELS = 1000


def _ap_with_ci(score, dtp, dfp, scene_of_det, n_gt_scene, n_scenes, n_resamples, rng):
    """AP and its 95 % percentile bootstrap interval over scenes (the interval from the curve at
    up to :data:`_CI_LEVELS` score quantiles)."""
    keep = (dtp != 0) | (dfp != 0)
    score, dtp, dfp, sod = score[keep], dtp[keep], dfp[keep], scene_of_det[keep]
    n_gt = float(n_gt_scene.sum())
    if n_gt <= 0:
        return math.nan, (math.nan, math.nan), None
    curve = pr_from_increments(score, dtp, dfp, n_gt)
    ap = curve.ap
    if n_resamples <= 0 or n_scenes < 2:
        return ap, (math.nan, math.nan), curve
    # per scene, cumulative TP / FP at (at most _CI_LEVELS) descending score thresholds: a resample
    # is then one matrix product with how often each scene was drawn
    levels = np.unique(score)[::-1]
    if levels.size > _CI_LEVELS:
        levels = np.unique(np.quantile(score, np.linspace(0.0, 1.0, _CI_LEVELS)))[::-1]
    # detection j counts from the first level <= its score on
    k0 = levels.size - np.searchsorted(levels[::-1], score, side="right")
    tp_hist = np.zeros((n_scenes, levels.size))
    fp_hist = np.zeros((n_scenes, levels.size))
    np.add.at(tp_hist, (sod, k0), dtp)
    np.add.at(fp_hist, (sod, k0), dfp)
    tp_cum, fp_cum = np.cumsum(tp_hist, axis=1), np.cumsum(fp_hist, axis=1)

    def statistic(idx, axis=-1):
        idx = np.asarray(idx).astype(np.int64)
        shape = idx.shape[:-1]
        idx = idx.reshape(-1, idx.shape[-1])
        m = idx.shape[0]
        cnt = np.bincount((idx + n_scenes * np.arange(m)[:, None]).ravel(), minlength=m * n_scenes)
        cnt = cnt.reshape(m, n_scenes).astype(float)
        # einsum, not a BLAS product: BLAS threads only add contention on a busy machine
        ng = np.einsum("ij,j->i", cnt, n_gt_scene)
        tp, fp = np.einsum("ij,jk->ik", cnt, tp_cum), np.einsum("ij,jk->ik", cnt, fp_cum)
        with np.errstate(invalid="ignore", divide="ignore"):
            prec = tp / (tp + fp)
            rec = tp / ng[:, None]
        # before the first accepted detection precision is undefined: the curve starts at the
        # first defined point, extended to recall 0 at its precision (as average_precision)
        defined = np.isfinite(prec)
        first = np.where(defined.any(axis=1), defined.argmax(axis=1), prec.shape[1] - 1)
        p0 = np.take_along_axis(prec, first[:, None], axis=1)
        prec = np.where(defined, prec, p0)
        rec = np.where(defined, rec, 0.0)
        r = np.concatenate([np.zeros((m, 1)), rec], axis=1)
        p = np.concatenate([p0, prec], axis=1)
        ap = np.sum(np.diff(r, axis=1) * 0.5 * (p[:, 1:] + p[:, :-1]), axis=1)
        ap = np.where(ng > 0, np.where(defined.any(axis=1), ap, 0.0), np.nan)
        return ap.reshape(shape)

    ci = _bootstrap((np.arange(n_scenes),), statistic, n_resamples, rng)
    return ap, ci, curve


def _bootstrap(data, statistic, n_resamples, rng) -> tuple[float, float]:
    from scipy import stats  # imported here: scipy.stats is slow to import

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            res = stats.bootstrap(
                data, statistic, n_resamples=n_resamples, vectorized=True, paired=len(data) > 1,
                method="percentile", random_state=rng, batch=50,
            )  # fmt: skip
        except ValueError:
            return (math.nan, math.nan)
    lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return (lo, hi)


def _ratio_ci(num, den, n_resamples, rng) -> tuple[float, float]:
    """Bootstrap interval of ``sum(num) / sum(den)`` over scenes (per-scene counts)."""
    num, den = np.asarray(num, float), np.asarray(den, float)
    if num.size < 2 or n_resamples <= 0 or den.sum() <= 0:
        return (math.nan, math.nan)

    def statistic(n, d, axis=-1):
        sn, sd = n.sum(axis=axis), d.sum(axis=axis)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(sd > 0, sn / np.where(sd > 0, sd, 1), np.nan)

    return _bootstrap((num, den), statistic, n_resamples, rng)


#: Why a counted kin was missed at the operating point (:func:`_miss_reasons`).
MISS_REASONS = (
    "below operating point",
    "merged with another object",
    "centre off by > gate",
    "no candidate",
)


def _miss_reasons(fr: _Frames, rk: dict, kin: dict, missed: np.ndarray) -> dict:
    """Where each missed kin was lost, judged from the permissive run (detector-agnostic):

    * ``below operating point``: a permissive detection matches it (within the gate): the
      score / threshold rejected it;
    * ``merged with another object``: a permissive candidate covers its beams, but they are a
      minority of that segment (merged with a wall, an obstacle or another robot);
    * ``centre off by > gate``: a candidate whose beams are mostly on it, centred too far away;
    * ``no candidate``: no permissive detection touches it (e.g. the geometric diameter filter, or
      fewer beams than the detector's minimum).
    """
    out = dict.fromkeys(MISS_REASONS, 0)
    if missed.size == 0:
        return out
    n = fr.ranges.shape[1]
    order = np.argsort(rk["frame"], kind="stable")
    fs = rk["frame"][order]
    for k in missed.tolist():
        f = int(kin["frame"][k])
        di = order[np.searchsorted(fs, f, "left") : np.searchsorted(fs, f, "right")]
        if di.size and (np.hypot(*(rk["xy"][di] - kin["xy"][k]).T) <= GATE).any():
            out["below operating point"] += 1
            continue
        i, r = int(fr.scene_of[f]), int(fr.row_of[f])
        scan = fr.scans[i]
        on_kin = (scan.hit_kind[r] == HitKind.ROBOT) & (scan.hit_index[r] == kin["robot"][k]) & fr.valid[f]
        reason = "no candidate"
        for j in di.tolist():
            beams = (rk["first"][j] + np.arange(min(int(rk["n_beams"][j]), n))) % n
            hits = int(on_kin[beams].sum())
            if hits:
                merged = 2 * hits <= int(fr.valid[f, beams].sum())
                reason = "merged with another object" if merged else "centre off by > gate"
                if not merged:
                    break
        out[reason] += 1
    return out


def _evaluate_condition(
    name: str,
    shipped,
    ranked,
    fr: _Frames,
    n_resamples: int,
    rng: np.random.Generator,
    same_radius_separate: bool,
) -> tuple[list[dict], dict]:
    """Metric rows (overall and per bin) and extras (FP kinds, PR curve) of one detector."""
    n_scenes = len(fr.samples)
    kin = fr.kin
    kin_scene = fr.scene_of[kin["frame"]]
    results_op, seconds = shipped
    results_rk, _ = ranked

    # -- operating point: one matching per frame
    op = _table(results_op)
    count = op["n_beams"]
    sr_op = _beam_fraction(fr.same_radius_beam, fr.valid, op["frame"], op["first"], count) > 0.5
    if not same_radius_separate:
        sr_op[:] = False
    tp = np.zeros(op["score"].shape[0], bool)
    ign = np.zeros_like(tp)
    err = np.full(tp.shape, np.nan)
    det_kin = np.full(tp.shape, -1, np.int64)
    kin_hit = np.zeros(kin["frame"].shape[0], bool)
    kin_err = np.full(kin["frame"].shape[0], np.nan)
    do, ko = np.argsort(op["frame"], kind="stable"), np.argsort(kin["frame"], kind="stable")
    fd, fk = op["frame"][do], kin["frame"][ko]
    for f in np.union1d(fd, fk).tolist():
        di = do[np.searchsorted(fd, f, "left") : np.searchsorted(fd, f, "right")]
        ki = ko[np.searchsorted(fk, f, "left") : np.searchsorted(fk, f, "right")]
        if di.size == 0:
            continue
        m = match(op["xy"][di], kin["xy"][ki], GATE, ~kin["care"][ki], sr_op[di])
        tp[di], ign[di], err[di] = m.tp, m.ignored, m.distance
        hit = m.gt >= 0
        det_kin[di[hit]] = ki[m.gt[hit]]
        kin_hit[ki[m.gt[m.tp]]] = True
        kin_err[ki[m.gt[m.tp]]] = m.distance[m.tp]
    fp = ~(tp | ign)
    same_radius = (~tp) & sr_op
    op_scene = fr.scene_of[op["frame"]]
    # a TP is binned by its kin, a FP by itself
    det_bin_range = np.where(det_kin >= 0, kin["range"][np.maximum(det_kin, 0)], op["range"])
    det_bin_beams = np.where(det_kin >= 0, kin["n_beams"][np.maximum(det_kin, 0)], count)

    # -- ranked (permissive) run
    rk = _table(results_rk)
    sr_rk = _beam_fraction(fr.same_radius_beam, fr.valid, rk["frame"], rk["first"], rk["n_beams"]) > 0.5
    if not same_radius_separate:
        sr_rk[:] = False
    rk_scene = fr.scene_of[rk["frame"]]

    rows = []
    curves = {}
    bins = [("all", -math.inf, math.inf)]
    bins += [("distance", lo, hi) for lo, hi in zip(DISTANCE_EDGES[:-1], DISTANCE_EDGES[1:], strict=True)]
    bins += [("beams", lo, hi) for lo, hi in zip(BEAM_EDGES[:-1], BEAM_EDGES[1:], strict=True)]
    for kind, lo, hi in bins:
        if kind == "all":
            k_in = np.ones(kin["frame"].shape[0], bool)
            op_in = np.ones(tp.shape[0], bool)
            rk_in = np.ones(rk["score"].shape[0], bool)
        elif kind == "distance":
            k_in = (kin["range"] >= lo) & (kin["range"] < hi)
            op_in = (det_bin_range >= lo) & (det_bin_range < hi)
            rk_in = (rk["range"] >= lo) & (rk["range"] < hi)
        else:
            k_in = (kin["n_beams"] >= lo) & (kin["n_beams"] < hi)
            op_in = (det_bin_beams >= lo) & (det_bin_beams < hi)
            rk_in = (rk["n_beams"] >= lo) & (rk["n_beams"] < hi)
        counted = kin["care"] & k_in
        n_kin_s = np.bincount(kin_scene[counted], minlength=n_scenes)
        tp_s = np.bincount(op_scene[tp & op_in], minlength=n_scenes)
        fp_s = np.bincount(op_scene[fp & op_in], minlength=n_scenes)
        fn_s = n_kin_s - np.bincount(kin_scene[counted & kin_hit], minlength=n_scenes)
        TP, FP, FN = int(tp_s.sum()), int(fp_s.sum()), int(fn_s.sum())
        P = TP / (TP + FP) if TP + FP else math.nan
        R = TP / (TP + FN) if TP + FN else math.nan
        F1 = 2 * TP / (2 * TP + FP + FN) if TP + FP + FN else math.nan
        e = kin_err[counted & kin_hit]
        gt_ignore = ~counted
        det_ignore = (~rk_in) | sr_rk
        dtp, dfp = increments(
            rk["score"], rk["frame"], rk["xy"], kin["frame"], kin["xy"], GATE, gt_ignore, det_ignore
        )
        do_ci = n_resamples if kind != "beams" else 0
        ap, ap_ci, curve = _ap_with_ci(
            rk["score"], dtp, dfp, rk_scene, n_kin_s.astype(float), n_scenes, do_ci, rng
        )
        if kind == "all" and curve is not None:
            curves = {"recall": curve.recall.tolist(), "precision": curve.precision.tolist(), "op": [R, P]}
        rows.append(
            {
                "bin": kind,
                "lo": lo,
                "hi": hi,
                "n_kin": int(n_kin_s.sum()),
                "tp": TP,
                "fp": FP,
                "fn": FN,
                "same_radius": int((same_radius & op_in).sum()),
                "precision": P,
                "recall": R,
                "f1": F1,
                "precision_ci": _ratio_ci(tp_s, tp_s + fp_s, n_resamples, rng),
                "recall_ci": _ratio_ci(tp_s, tp_s + fn_s, n_resamples, rng),
                "f1_ci": _ratio_ci(2 * tp_s, 2 * tp_s + fp_s + fn_s, n_resamples, rng),
                "ap": ap,
                "ap_ci": ap_ci,
                "peak_f1": curve.peak_f1 if curve is not None else math.nan,
                "error_mean": float(e.mean()) if e.size else math.nan,
                "error_median": float(np.median(e)) if e.size else math.nan,
                "error_p95": float(np.percentile(e, 95)) if e.size else math.nan,
            }
        )
    misses = _miss_reasons(fr, rk, kin, np.flatnonzero(kin["care"] & ~kin_hit))
    # false positives by source (operating point)
    kinds = Counter()
    n = fr.ranges.shape[1]
    for j in np.flatnonzero(fp).tolist():
        f = int(op["frame"][j])
        i, r = int(fr.scene_of[f]), int(fr.row_of[f])
        last = int((op["first"][j] + count[j] - 1) % n)
        src = describe_hits(fr.scans[i], r, segment_beams(int(op["first"][j]), last, n), fr.samples[i].scene)
        kinds[src.label] += 1
    extras = {
        "false_positives": dict(sorted(kinds.items(), key=lambda kv: (-kv[1], kv[0]))),
        "same_radius": int(same_radius.sum()),
        "n_scans": int(fr.ranges.shape[0]),
        "same_radius_seen": fr.same_radius_seen,
        "n_dont_care": int((~kin["care"]).sum()),
        "seconds": seconds,
        "scans_per_second": fr.ranges.shape[0] / seconds if seconds > 0 else math.nan,
        "pr_curve": curves,
        "misses": misses,
    }
    return rows, extras


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class BenchmarkResults:
    """What :func:`run_benchmark` measured.

    Attributes:
        rows: one dict per detector x split x condition x bin: ``detector, split, noise, dropout,
            bin`` (``"all"``, ``"distance"``, ``"beams"``), ``lo, hi`` (bin edges, m or beams),
            ``n_kin, tp, fp, fn, same_radius, precision, recall, f1`` (+ ``_ci`` 95 % intervals),
            ``ap, ap_ci, peak_f1, error_mean, error_median, error_p95`` (m).
        extras: per ``(detector, split, condition name)``: ``false_positives`` by kind,
            ``same_radius`` (detections on same-radius cylinders) and ``same_radius_seen`` (such
            cylinders seen by >= 2 valid beams, per scan), ``n_scans``, ``n_dont_care``,
            ``scans_per_second``, ``misses`` (:data:`MISS_REASONS`), ``pr_curve`` (recall,
            precision, op = the operating point's recall, precision).
        config: version, splits (``SplitSpec.to_dict``), sizes, seeds, gate, rules.
    """

    rows: tuple[dict, ...]
    extras: dict = field(default_factory=dict)
    config: dict = field(default_factory=dict)

    def select(self, **where) -> list[dict]:
        """Rows whose fields equal ``where`` (floats compared with a tolerance)."""

        def ok(r):
            for k, v in where.items():
                x = r.get(k)
                if isinstance(v, float) and isinstance(x, float):
                    if not math.isclose(x, v, abs_tol=1e-12):
                        return False
                elif x != v:
                    return False
            return True

        return [r for r in self.rows if ok(r)]

    def to_dict(self) -> dict:
        return {
            "config": self.config,
            "rows": list(self.rows),
            "extras": {" | ".join(k): v for k, v in self.extras.items()},
        }


def _sizes(size, split: SplitSpec) -> int:
    if size == "full":
        return split.n_scenes
    if size == "reduced":
        return split.reduced_scenes
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size must be 'reduced', 'full' or an integer >= 1, got {size!r}")
    return size


def run_benchmark(
    detectors: Mapping[str, KinDetector],
    splits: Sequence[str] | str = ("paper", "swarm", "lookalike"),
    size: str | int = "reduced",
    conditions: Sequence[Condition] | None = None,
    seed_offset: int = 0,
    *,
    n_resamples: int = 500,
    same_radius_separate: bool = True,
    permissive_detectors: Mapping[str, KinDetector] | None = None,
    batch_size: int = 256,
    seed: int = 0,
    progress: bool = False,
    samples: Mapping[str, Sequence[SplitSample]] | None = None,
) -> BenchmarkResults:
    """Run the benchmark: every detector on every split and condition.

    Args:
        detectors: name -> detector at its shipped operating point (P / R / F1, speed).
        splits: split names (:data:`SPLITS`).
        size: ``"reduced"`` (the main job's), ``"full"`` or a number of scenes per split.
        conditions: lidar conditions (default: each split's, :data:`CONDITIONS`).
        seed_offset: start this many scenes into each split's seed block (a fresh draw).
        n_resamples: bootstrap resamples for the intervals (0: no intervals).
        same_radius_separate: unmatched detections on same-radius cylinders are counted apart.
        permissive_detectors: name -> the detector's ranked run (default :func:`permissive`).
        batch_size: scans per ``detect_batch`` call.
        seed: seed of the bootstrap.
        progress: tqdm progress bars.
        samples: pre-generated scenes per split (:func:`generate_split`), e.g. to share them.
    """
    if not isinstance(detectors, Mapping) or not detectors:
        raise ValueError(f"detectors must be a non-empty dict name -> KinDetector, got {detectors!r}")
    for k, d in detectors.items():
        if not callable(getattr(d, "detect_batch", None)):
            raise ValueError(f"detector {k!r} has no detect_batch(ranges, angles); expected a KinDetector")
    names = [splits] if isinstance(splits, str) else list(splits)
    for s in names:
        if s not in SPLITS:
            raise ValueError(f"unknown split {s!r}; expected one of {sorted(SPLITS)}")
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, int) or n_resamples < 0:
        raise ValueError(f"n_resamples must be an integer >= 0, got {n_resamples!r}")
    ranked = {k: (permissive_detectors or {}).get(k) or permissive(d) for k, d in detectors.items()}
    rng = np.random.default_rng(seed)
    rows: list[dict] = []
    extras: dict = {}
    used: dict = {}
    for split_name in names:
        spec = SPLITS[split_name]
        n = _sizes(size, spec)
        smp = (samples or {}).get(split_name)
        t0 = time.perf_counter()
        if smp is None:
            smp = generate_split(spec, n, seed_offset, progress)
        gen_s = time.perf_counter() - t0
        conds = tuple(conditions) if conditions is not None else spec.conditions
        used[split_name] = {
            "spec": spec.to_dict(),
            "n_scenes": len(smp),
            "seeds": [int(smp[0].seed), int(smp[-1].seed)],
            "generation_seconds": gen_s,
        }
        for ci, cond in enumerate(conds):
            fr = _frames(smp, cond, ci)
            for det_name, det in detectors.items():
                shipped = _run(det, fr.ranges, fr.angles, batch_size)
                rk = _run(ranked[det_name], fr.ranges, fr.angles, batch_size)
                det_rows, ex = _evaluate_condition(
                    det_name, shipped, rk, fr, n_resamples, rng, same_radius_separate
                )
                for r in det_rows:
                    rows.append(
                        {
                            "detector": det_name,
                            "split": split_name,
                            "noise": cond.noise,
                            "dropout": cond.dropout,
                            **r,
                        }
                    )
                extras[(det_name, split_name, cond.name)] = ex
                if progress:
                    a = det_rows[0]
                    _log.info(
                        f"  {split_name:9s} {cond.name:24s} {det_name:10s} AP {a['ap']:.3f}  "
                        f"P/R/F1 {a['precision']:.2f}/{a['recall']:.2f}/{a['f1']:.2f}  "
                        f"{ex['scans_per_second']:.0f} scans/s",
                    )
    config = {
        "benchmark_version": BENCHMARK_VERSION,
        "size": size,
        "seed_offset": seed_offset,
        "splits": used,
        "gate_m": GATE,
        "min_beams": MIN_BEAMS,
        "distance_edges_m": list(DISTANCE_EDGES),
        "beam_edges": list(BEAM_EDGES),
        "same_radius_separate": same_radius_separate,
        "n_resamples": n_resamples,
        "bootstrap": "95 % percentile bootstrap over scenes (scipy.stats.bootstrap)",
        "bootstrap_seed": seed,
        "permissive": {k: type(v).__name__ for k, v in ranked.items()},
    }
    return BenchmarkResults(tuple(rows), extras, config)
