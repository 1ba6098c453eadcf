"""Swarm-like scenes for the learned detectors' training data and diagnostics (simulator side).

A swarm scene is what a robot of a real swarm sees: 8-16 robots in a small walled arena with clutter,
many obstacles exactly the housing's width (7 cm prisms, cuboids and same-radius cylinders), and
robots **in clusters** (bodies touching or a few cm apart) and **at walls / obstacles** (bodies
touching them) - the layouts where the paper's segmentation (``d_th = 0.1 m``) merges a kin's few
beams with its neighbour's. Robots can then drive for a few control steps (random commands), so they
end up pushed against walls and each other by the physics, at arbitrary headings.

Seeds: the benchmark (:mod:`kin_envs.detection.benchmark`, when present) reserves its own seed range;
training data drawn with this module uses :data:`kin_envs.detection.seeds.TRAINING_SEEDS` only
(``check_training_seeds(..., within=TRAINING_SEEDS)``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..core.lidar import LidarSpec
from ..core.scenes import Arena, RandomArenaConfig, Robot, RobotSpec, Scene, _Placer, _random_obstacle
from ..core.world import World

__all__ = ["SwarmSceneConfig", "swarm_scene", "swarm_world"]


def _pair(name, v, cast):
    if not (isinstance(v, tuple | list) and len(v) == 2 and cast(v[0]) <= cast(v[1])):
        raise ValueError(f"SwarmSceneConfig.{name} must be a (min, max) pair with min <= max, got {v!r}")
    return (cast(v[0]), cast(v[1]))


@dataclass(frozen=True)
class SwarmSceneConfig:
    """Random swarm layout (ranges inclusive, drawn per scene).

    Attributes:
        n_robots, n_obstacles: counts.
        size: side of the square arena, m.
        kin_width_prob: share of cylinders / boxes / prisms exactly the housing's width.
        cluster_prob: probability that a robot is placed next to an already placed robot (bodies
            ``cluster_gap`` apart).
        wall_prob: probability that a robot is placed touching the boundary wall (gap ``cluster_gap``).
        cluster_gap: (min, max) gap between touching bodies, m.
        steps: (min, max) control steps driven with random commands before scanning.
    """

    n_robots: tuple[int, int] = (8, 16)
    n_obstacles: tuple[int, int] = (10, 30)
    size: tuple[float, float] = (4.0, 7.0)
    kin_width_prob: float = 0.5
    cluster_prob: float = 0.35
    wall_prob: float = 0.2
    cluster_gap: tuple[float, float] = (0.001, 0.05)
    steps: tuple[int, int] = (0, 10)

    def __post_init__(self) -> None:
        for name in ("n_robots", "n_obstacles", "steps"):
            object.__setattr__(self, name, _pair(name, getattr(self, name), int))
        for name in ("size", "cluster_gap"):
            object.__setattr__(self, name, _pair(name, getattr(self, name), float))
        for name in ("kin_width_prob", "cluster_prob", "wall_prob"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ValueError(f"SwarmSceneConfig.{name} must be a probability, got {v!r}")
        if self.n_robots[0] < 1 or self.n_obstacles[0] < 0 or self.steps[0] < 0 or self.size[0] <= 1.0:
            raise ValueError(f"SwarmSceneConfig: invalid counts or size in {self}")

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d) -> SwarmSceneConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict) or set(d) - names:
            raise ValueError(
                f"SwarmSceneConfig: unknown key(s) {sorted(set(d) - names)}; expected {sorted(names)}"
            )
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def swarm_scene(
    rng: np.random.Generator,
    config: SwarmSceneConfig | None = None,
    lidar: LidarSpec | None = None,
    robot: RobotSpec | None = None,
) -> Scene:
    """A seeded swarm scene (see the module docstring); all randomness from ``rng``."""
    c = config or SwarmSceneConfig()
    spec = robot or RobotSpec()
    size = float(rng.uniform(*c.size))
    arena = Arena(size, size, walls=True)
    hx = arena.half_extents[0]
    acfg = RandomArenaConfig(kin_width_prob=c.kin_width_prob, clearance=0.0, wall_length=(0.4, 1.5))
    # obstacles keep 5 cm from each other; robots only need not to overlap (they may touch)
    obst_placer = _Placer(arena, 0.05, 300, spec, "swarm_scene")
    placer = _Placer(arena, 0.0, 300, spec, "swarm_scene")

    def uniform_xy():
        return float(rng.uniform(-hx, hx)), float(rng.uniform(-hx, hx))

    obstacles = []
    for j in range(int(rng.integers(c.n_obstacles[0], c.n_obstacles[1] + 1))):
        try:
            o = obst_placer.place(lambda x, y: _random_obstacle(rng, acfg, spec, x, y), uniform_xy, f"o{j}")
        except ValueError:
            break  # arena full: fewer obstacles
        placer.index.add(*o.footprint(), f"o{j}")
        obstacles.append(o)
    robots: list[Robot] = []
    rb = spec.body_radius

    def robot_xy():
        u = rng.random()
        gap = float(rng.uniform(*c.cluster_gap))
        if robots and u < c.cluster_prob:  # next to a placed robot
            other = robots[int(rng.integers(len(robots)))]
            b = float(rng.uniform(-math.pi, math.pi))
            return other.x + (2 * rb + gap) * math.cos(b), other.y + (2 * rb + gap) * math.sin(b)
        if u < c.cluster_prob + c.wall_prob:  # touching a boundary wall
            side = int(rng.integers(4))
            t = float(rng.uniform(-hx + rb, hx - rb))
            d = hx - rb - gap
            return [(d, t), (-d, t), (t, d), (t, -d)][side]
        return uniform_xy()

    for i in range(int(rng.integers(c.n_robots[0], c.n_robots[1] + 1))):
        try:
            r = placer.place(
                lambda x, y: Robot(x, y, float(rng.uniform(-math.pi, math.pi))), robot_xy, f"r{i}"
            )
        except ValueError:
            break
        robots.append(r)
    return Scene(
        robots=tuple(robots),
        obstacles=tuple(obstacles),
        arena=arena,
        robot=spec,
        lidar=lidar or LidarSpec(),
        name=f"swarm_scene(n_robots={len(robots)}, n_obstacles={len(obstacles)})",
    )


def swarm_world(rng: np.random.Generator, config: SwarmSceneConfig | None = None, lidar=None) -> World:
    """A :func:`swarm_scene` in a :class:`World` (lidar noise drawn from ``rng``), driven for a few
    random control steps so that robots press against walls, obstacles and each other."""
    c = config or SwarmSceneConfig()
    scene = swarm_scene(rng, c, lidar)
    world = World(scene, seed=rng)
    n_steps = int(rng.integers(c.steps[0], c.steps[1] + 1))
    if n_steps:
        spec = scene.robot
        cmd = np.stack(
            [
                rng.uniform(0.3, 1.0, len(scene.robots)) * spec.max_speed,
                rng.uniform(-0.5, 0.5, len(scene.robots)) * spec.max_turn_rate,
            ],
            axis=1,
        )
        for _ in range(n_steps):
            world.step(commands=cmd)
    return world
