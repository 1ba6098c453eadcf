"""Scenes as data: arena, robots with poses, obstacles with poses.

A :class:`Scene` is a frozen, validated value. It round-trips through plain dicts / JSON
(:meth:`Scene.to_dict`, :meth:`Scene.from_dict`); unknown keys and invalid values (negative sizes,
overlapping objects, an object outside the arena) raise ``ValueError`` naming the culprit.

Frames and units: world frame, metres, angles in radians counter-clockwise from the world x axis.
The arena is the axis-aligned rectangle ``[-width/2, width/2] x [-height/2, height/2]``.

Built-in scenes: :func:`paper_scenario` (the paper's Scenario I and II at any distance) and
:func:`random_arena` (seeded random clutter).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pymunk

from kin_envs.core._validate import (
    MAX_MAGNITUDE,
    FieldTypeError,
    check_bool,
    check_finite,
    check_interval,
    check_number,
    check_positive,
    check_sequence,
    check_weights,
    dataclass_from_dict,
    make_rng,
)
from kin_envs.core.lidar import HitKind, LidarSpec

__all__ = [
    "Arena",
    "RobotSpec",
    "Robot",
    "Cylinder",
    "Box",
    "Prism",
    "Polygon",
    "Wall",
    "Obstacle",
    "OBSTACLE_TYPES",
    "Scene",
    "RandomArenaConfig",
    "DetectionSceneConfig",
    "paper_scenario",
    "random_arena",
    "detection_scene",
]


@dataclass(frozen=True)
class RobotSpec:
    """The paper's robot (section 3): a differential-drive cylinder with a lidar on top.

    Attributes:
        body_radius: collision radius of the body, m (paper: 9 cm). Lidar beams pass above it.
        housing_radius: radius of the lidar housing at the body's centre, m (RPLIDAR A1: 3.5 cm).
            This 7 cm-wide circle is the only part of a robot another robot's lidar sees.
        wheel_base: distance between the two driven wheels, m.
        wheel_radius: driven wheel radius, m.
        max_wheel_speed: wheel speed limit, rad/s. With the defaults the top linear speed is
            ``wheel_radius * max_wheel_speed = 0.33 m/s`` and the top turn rate
            ``2 * v_max / wheel_base = 4.125 rad/s``.
        mass: body mass, kg.
        max_drive_force: traction force limit of the drive, N (what the wheels can push with).
        max_drive_torque: yaw torque limit of the drive, N·m.
    """

    body_radius: float = 0.09
    housing_radius: float = 0.035
    wheel_base: float = 0.16
    wheel_radius: float = 0.033
    max_wheel_speed: float = 10.0
    mass: float = 1.0
    max_drive_force: float = 20.0
    max_drive_torque: float = 2.0

    def __post_init__(self) -> None:
        check_positive("RobotSpec", **dataclasses.asdict(self))
        if self.housing_radius > self.body_radius:
            raise ValueError(
                f"RobotSpec: housing_radius={self.housing_radius} m must be <= body_radius="
                f"{self.body_radius} m"
            )

    @property
    def max_speed(self) -> float:
        """Top linear speed, m/s."""
        return self.wheel_radius * self.max_wheel_speed

    @property
    def max_turn_rate(self) -> float:
        """Top yaw rate (wheels in opposite directions), rad/s."""
        return 2.0 * self.max_speed / self.wheel_base


@dataclass(frozen=True)
class Arena:
    """Axis-aligned rectangle centred on the origin, m. ``walls`` adds the boundary wall."""

    width: float = 10.0
    height: float = 10.0
    walls: bool = True

    def __post_init__(self) -> None:
        check_positive("Arena", width=self.width, height=self.height)
        check_bool("Arena", "walls", self.walls)

    @property
    def half_extents(self) -> tuple[float, float]:
        return self.width / 2.0, self.height / 2.0

    def boundary_polygon(self) -> np.ndarray:
        """Inner face of the boundary wall, CCW ``(4, 2)``."""
        hx, hy = self.half_extents
        return np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])


@dataclass(frozen=True)
class Robot:
    """A robot's pose: centre ``(x, y)``, m, and heading ``theta``, rad CCW from +x."""

    x: float
    y: float
    theta: float = 0.0

    def __post_init__(self) -> None:
        check_finite("Robot", x=self.x, y=self.y, theta=self.theta)


def _rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class _Obstacle:
    """Base of obstacle kinds. ``movable`` obstacles are dynamic bodies of ``mass`` kg that robots
    can push (with floor friction); others are static."""

    kind: ClassVar[str] = ""
    hit_kind: ClassVar[HitKind] = HitKind.NONE

    def footprint(self) -> tuple[str, np.ndarray]:
        """``("circle", [cx, cy, r])`` or ``("polygon", vertices (k, 2) CCW)`` in the world frame (a fresh
        array: computed once per obstacle, since placement, validation and a world's build each ask)."""
        cached = self.__dict__.get("_footprint_cache")
        if cached is None:  # (a frozen dataclass: the cache bypasses __setattr__, and is not a field)
            cached = self.__dict__["_footprint_cache"] = self._footprint()
        return cached[0], cached[1].copy()

    def _footprint(self) -> tuple[str, np.ndarray]:
        raise NotImplementedError

    @property
    def center(self) -> tuple[float, float]:
        return (self.x, self.y)  # type: ignore[attr-defined]

    def to_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind, **dataclasses.asdict(self)}
        if "vertices" in d:
            d["vertices"] = [list(v) for v in d["vertices"]]
        return d

    def _check_common(self) -> None:
        check_finite(self.kind, x=self.x, y=self.y, theta=getattr(self, "theta", 0.0))  # type: ignore[attr-defined]
        check_positive(self.kind, mass=self.mass)  # type: ignore[attr-defined]
        check_bool(self.kind, "movable", self.movable)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Cylinder(_Obstacle):
    """Upright cylinder of ``radius`` m centred at ``(x, y)``."""

    kind: ClassVar[str] = "cylinder"
    hit_kind: ClassVar[HitKind] = HitKind.CYLINDER
    x: float = 0.0
    y: float = 0.0
    radius: float = 0.05
    movable: bool = False
    mass: float = 1.0

    def __post_init__(self) -> None:
        self._check_common()
        check_positive("cylinder", radius=self.radius)

    def _footprint(self):
        return "circle", np.array([self.x, self.y, self.radius])


@dataclass(frozen=True)
class Box(_Obstacle):
    """Cuboid: ``width`` along its local x, ``depth`` along local y, m; rotated by ``theta``."""

    kind: ClassVar[str] = "box"
    hit_kind: ClassVar[HitKind] = HitKind.BOX
    x: float = 0.0
    y: float = 0.0
    width: float = 0.07
    depth: float = 0.07
    theta: float = 0.0
    movable: bool = False
    mass: float = 1.0

    def __post_init__(self) -> None:
        self._check_common()
        check_positive("box", width=self.width, depth=self.depth)

    def _footprint(self):
        w, d = self.width / 2, self.depth / 2
        local = np.array([[-w, -d], [w, -d], [w, d], [-w, d]])
        return "polygon", local @ _rot(self.theta).T + [self.x, self.y]


@dataclass(frozen=True)
class Prism(_Obstacle):
    """Regular prism with ``sides`` (3 = triangular, 5 = pentagonal, 6 = hexagonal …).

    ``width`` is the diameter of its circumscribed circle, m: a 7 cm-wide prism has its vertices on
    the lidar housing's 3.5 cm circle. One vertex points along ``theta``.
    """

    kind: ClassVar[str] = "prism"
    hit_kind: ClassVar[HitKind] = HitKind.PRISM
    x: float = 0.0
    y: float = 0.0
    sides: int = 6
    width: float = 0.07
    theta: float = 0.0
    movable: bool = False
    mass: float = 1.0

    def __post_init__(self) -> None:
        self._check_common()
        check_number("prism", "sides", self.sides, 3, math.inf, integer=True)
        if self.sides > 64:
            raise ValueError(f"prism: sides must be <= 64, got {self.sides!r}")
        check_positive("prism", width=self.width)

    def _footprint(self):
        a = self.theta + 2 * np.pi * np.arange(self.sides) / self.sides
        r = self.width / 2
        return "polygon", np.stack([self.x + r * np.cos(a), self.y + r * np.sin(a)], axis=1)


@dataclass(frozen=True)
class Polygon(_Obstacle):
    """Any convex polygon: ``vertices`` in its local frame (m), placed at ``(x, y)``, rotated by
    ``theta``. Vertices may be given in either winding; they are stored as given."""

    kind: ClassVar[str] = "polygon"
    hit_kind: ClassVar[HitKind] = HitKind.POLYGON
    x: float = 0.0
    y: float = 0.0
    vertices: tuple[tuple[float, float], ...] = ((0.05, 0.0), (-0.05, 0.05), (-0.05, -0.05))
    theta: float = 0.0
    movable: bool = False
    mass: float = 1.0

    def __post_init__(self) -> None:
        self._check_common()
        try:
            v = np.asarray(self.vertices, dtype=float)
        except (TypeError, ValueError) as e:
            raise ValueError(f"polygon: vertices must be (x, y) number pairs, got {self.vertices!r}") from e
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3 or not np.all(np.abs(v) <= MAX_MAGNITUDE):
            raise ValueError(f"polygon: vertices must be >= 3 finite (x, y) pairs, got {self.vertices!r}")
        object.__setattr__(self, "vertices", tuple((float(a), float(b)) for a, b in v))
        e = np.roll(v, -1, axis=0) - v
        cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
        if not (np.all(cross > 1e-12) or np.all(cross < -1e-12)):
            raise ValueError(f"polygon: vertices must form a strictly convex polygon, got {self.vertices!r}")

    def _footprint(self):
        v = np.asarray(self.vertices) @ _rot(self.theta).T + [self.x, self.y]
        if _signed_area(v) < 0:
            v = v[::-1]
        return "polygon", v


@dataclass(frozen=True)
class Wall(_Obstacle):
    """Interior wall from ``(x1, y1)`` to ``(x2, y2)`` (centre line), ``thickness`` m thick."""

    kind: ClassVar[str] = "wall"
    hit_kind: ClassVar[HitKind] = HitKind.WALL
    x1: float = 0.0
    y1: float = 0.0
    x2: float = 1.0
    y2: float = 0.0
    thickness: float = 0.05
    movable: bool = False
    mass: float = 5.0

    def __post_init__(self) -> None:
        check_finite("wall", x1=self.x1, y1=self.y1, x2=self.x2, y2=self.y2)
        check_positive("wall", thickness=self.thickness, mass=self.mass)
        check_bool("wall", "movable", self.movable)
        if math.hypot(self.x2 - self.x1, self.y2 - self.y1) <= 0:
            raise ValueError(f"wall: endpoints must differ, got ({self.x1}, {self.y1}) twice")

    @property
    def center(self) -> tuple[float, float]:
        return ((self.x1 + self.x2) / 2, (self.y1 + self.y2) / 2)

    def _footprint(self):
        p, q = np.array([self.x1, self.y1]), np.array([self.x2, self.y2])
        t = (q - p) / np.linalg.norm(q - p)
        nrm = np.array([-t[1], t[0]]) * self.thickness / 2
        return "polygon", np.array([p - nrm, q - nrm, q + nrm, p + nrm])


Obstacle = Cylinder | Box | Prism | Polygon | Wall
OBSTACLE_TYPES: dict[str, type] = {c.kind: c for c in (Cylinder, Box, Prism, Polygon, Wall)}


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def obstacle_from_dict(d: Any, where: str = "obstacle") -> Obstacle:
    if not isinstance(d, dict) or "kind" not in d:
        raise ValueError(f"{where}: expected a dict with a 'kind' key, got {d!r}")
    kind = d["kind"]
    if not isinstance(kind, str) or kind not in OBSTACLE_TYPES:  # a list would be unhashable
        raise ValueError(f"{where}: unknown obstacle kind {kind!r}; expected one of {sorted(OBSTACLE_TYPES)}")
    rest = {k: v for k, v in d.items() if k != "kind"}
    if "vertices" in rest:
        rest["vertices"] = tuple(tuple(v) for v in rest["vertices"])
    return dataclass_from_dict(OBSTACLE_TYPES[kind], rest, f"{where} ({kind})")


# --- overlap checks: pymunk's own collision queries on temporary shapes --------------------------

_OVERLAP_TOL = 1e-9


def _pm_shape(kind: str, geom: np.ndarray, body: pymunk.Body, inflate: float = 0.0) -> pymunk.Shape:
    if kind == "circle":
        return pymunk.Circle(body, float(geom[2]) + inflate, (float(geom[0]), float(geom[1])))
    return pymunk.Poly(body, [tuple(map(float, p)) for p in geom], radius=inflate)


class _OverlapIndex:
    """Incrementally add footprints and ask whether a new one overlaps any placed one.

    pymunk decides every overlap, but only for footprints whose bounding circles come within
    ``_PREFILTER_GAP`` of each other: farther apart, pymunk cannot report a penetration deeper than
    ``_OVERLAP_TOL`` (the answer is the same, without building the shapes). The pymunk space is built
    lazily, with the placed shapes added in placement order, so its answers (and their order) are
    those of a space built eagerly."""

    def __init__(self) -> None:
        self.space: pymunk.Space | None = None
        self.labels: dict[pymunk.Shape, str] = {}
        self._placed: list[tuple[str, np.ndarray, str]] = []
        self._in_space = 0  # how many of _placed are in self.space
        self._bounds: list[tuple[float, float, float]] = []  # bounding circle of each placed footprint

    def hits(self, kind: str, geom: np.ndarray, inflate: float = 0.0, ignore=lambda label: False):
        x, y, r = _bounding_circle(kind, geom)
        reach = r + inflate + _PREFILTER_GAP
        if not any(math.hypot(x - bx, y - by) <= reach + br for bx, by, br in self._bounds):
            return []
        space = self._sync()
        probe = _pm_shape(kind, geom, space.static_body, inflate)
        out = []
        for info in space.shape_query(probe):
            label = self.labels[info.shape]
            if ignore(label):
                continue
            pts = info.contact_point_set.points
            if pts and min(p.distance for p in pts) < -_OVERLAP_TOL:
                out.append(label)
        return out

    def add(self, kind: str, geom: np.ndarray, label: str) -> None:
        self._placed.append((kind, geom, label))
        self._bounds.append(_bounding_circle(kind, geom))

    def _sync(self) -> pymunk.Space:
        """The pymunk space with every placed footprint in it (added in placement order)."""
        if self.space is None:
            self.space = pymunk.Space()
        for kind, geom, label in self._placed[self._in_space :]:
            shape = _pm_shape(kind, geom, self.space.static_body)
            self.space.add(shape)
            self.labels[shape] = label
        self._in_space = len(self._placed)
        return self.space


#: Bounding circles farther apart than this (m) are not given to pymunk: rounding in its distance
#: (~1e-15 m at these sizes) cannot turn a gap of 1e-7 m into a penetration deeper than _OVERLAP_TOL.
_PREFILTER_GAP = 1e-7


def _bounding_circle(kind: str, geom: np.ndarray) -> tuple[float, float, float]:
    """``(x, y, r)``: a circle containing the footprint (polygons: around their vertices' mean; plain
    Python: numpy's per-call overhead dominated on a few vertices)."""
    if kind == "circle":
        x, y, r = geom.tolist()
        return x, y, r
    pts = geom.tolist()
    cx = sum(p[0] for p in pts) / len(pts)
    cy = sum(p[1] for p in pts) / len(pts)
    r = max(math.hypot(p[0] - cx, p[1] - cy) for p in pts)
    return cx, cy, r * (1 + 1e-12) + 1e-12


def _inside_arena(kind: str, geom: np.ndarray, arena: Arena) -> bool:
    hx, hy = arena.half_extents
    if kind == "circle":
        x, y, r = geom.tolist()
        return -hx <= x - r and x + r <= hx and -hy <= y - r and y + r <= hy
    # (the same float64 comparisons as numpy's, without its per-call overhead on a few vertices)
    return all(abs(x) <= hx and abs(y) <= hy for x, y in geom.tolist())


@dataclass(frozen=True)
class Scene:
    """Everything a :class:`~kin_envs.core.world.World` is built from.

    Attributes:
        robots: robot poses; robot ``i`` is index ``i`` in scans and ground truth.
        obstacles: obstacles; obstacle ``j`` is index ``j`` in ground truth.
        arena: the arena rectangle (and whether it has a boundary wall).
        robot: physical spec shared by all robots.
        lidar: lidar spec shared by all robots.
        name: free text.

    Validation (``ValueError``): every robot body and obstacle lies inside the arena, no two
    objects overlap (touching is fine; interior walls may cross each other to form corners).
    """

    robots: tuple[Robot, ...] = ()
    obstacles: tuple[Obstacle, ...] = ()
    arena: Arena = field(default_factory=Arena)
    robot: RobotSpec = field(default_factory=RobotSpec)
    lidar: LidarSpec = field(default_factory=LidarSpec)
    name: str = ""

    def __post_init__(self) -> None:
        self._check_fields()
        self._check_layout()

    @classmethod
    def _placed(cls, **fields) -> Scene:
        """A scene whose layout is valid by construction (every field given): its fields are checked, its
        layout is not checked again. For :func:`random_arena`'s :class:`_Placer`, which is stricter than
        :meth:`_check_layout` (the same pymunk overlap test with ``clearance >= 0`` added, inside an arena
        shrunk by it, interior walls not allowed to cross), and for a valid scene's cylinders made
        thinner in place; the check could not fail (skipping it saved a fifth of a KinSeek reset's scene)."""
        scene = object.__new__(cls)
        for f in dataclasses.fields(cls):
            object.__setattr__(scene, f.name, fields.pop(f.name))
        if fields:
            raise TypeError(f"Scene._placed: unknown fields {sorted(fields)}")
        scene._check_fields()
        return scene

    def _check_fields(self) -> None:
        for name, cls in (("arena", Arena), ("robot", RobotSpec), ("lidar", LidarSpec), ("name", str)):
            if not isinstance(getattr(self, name), cls):
                raise FieldTypeError(
                    f"scene.{name}: expected {cls.__name__}, got {type(getattr(self, name)).__name__}"
                )
        for name in ("robots", "obstacles"):
            value = getattr(self, name)
            if isinstance(value, str | bytes | dict) or not hasattr(value, "__iter__"):
                raise FieldTypeError(f"scene.{name}: expected a sequence, got {type(value).__name__}")
            object.__setattr__(self, name, tuple(value))
        for i, r in enumerate(self.robots):
            if not isinstance(r, Robot):
                raise ValueError(f"scene.robots[{i}]: expected a Robot, got {type(r).__name__}")
        for j, o in enumerate(self.obstacles):
            if not isinstance(o, tuple(OBSTACLE_TYPES.values())):
                raise ValueError(f"scene.obstacles[{j}]: expected an obstacle, got {type(o).__name__}")

    def robot_footprint(self, i: int) -> np.ndarray:
        r = self.robots[i]
        return np.array([r.x, r.y, self.robot.body_radius])

    def _check_layout(self) -> None:
        index = _OverlapIndex()
        for i in range(len(self.robots)):
            geom = self.robot_footprint(i)
            label = f"robots[{i}] at ({geom[0]:.3f}, {geom[1]:.3f})"
            if not _inside_arena("circle", geom, self.arena):
                raise ValueError(
                    f"scene: {label} (body radius {geom[2]} m) is outside the arena {self.arena}"
                )
            clash = index.hits("circle", geom)
            if clash:
                raise ValueError(f"scene: {label} overlaps {clash[0]}")
            index.add("circle", geom, label)
        for j, o in enumerate(self.obstacles):
            kind, geom = o.footprint()
            cx, cy = o.center
            label = f"obstacles[{j}] ({o.kind} at ({cx:.3f}, {cy:.3f}))"
            if not _inside_arena(kind, geom, self.arena):
                raise ValueError(f"scene: {label} is outside the arena {self.arena}")
            is_wall = isinstance(o, Wall)
            clash = index.hits(kind, geom, ignore=lambda lab, w=is_wall: w and "(wall" in lab)
            if clash:
                raise ValueError(f"scene: {label} overlaps {clash[0]}")
            index.add(kind, geom, label)

    # -- data round trip -------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON-serialisable dict (``Scene.from_dict(s.to_dict()) == s``)."""
        return {
            "name": self.name,
            "arena": dataclasses.asdict(self.arena),
            "robot": dataclasses.asdict(self.robot),
            "lidar": dataclasses.asdict(self.lidar),
            "robots": [dataclasses.asdict(r) for r in self.robots],
            "obstacles": [o.to_dict() for o in self.obstacles],
        }

    @classmethod
    def from_dict(cls, d: Any) -> Scene:
        """Inverse of :meth:`to_dict`; unknown keys anywhere raise ``ValueError``."""
        if not isinstance(d, dict):
            raise ValueError(f"scene: expected a dict, got {type(d).__name__}")
        known = {"name", "arena", "robot", "lidar", "robots", "obstacles"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"scene: unknown key(s) {unknown}; expected a subset of {sorted(known)}")
        robots = d.get("robots", [])
        obstacles = d.get("obstacles", [])
        if not isinstance(robots, Sequence) or not isinstance(obstacles, Sequence):
            raise ValueError("scene: 'robots' and 'obstacles' must be lists")
        return cls(
            name=str(d.get("name", "")),
            arena=dataclass_from_dict(Arena, d.get("arena", {}), "scene.arena"),
            robot=dataclass_from_dict(RobotSpec, d.get("robot", {}), "scene.robot"),
            lidar=dataclass_from_dict(LidarSpec, d.get("lidar", {}), "scene.lidar"),
            robots=tuple(dataclass_from_dict(Robot, r, f"scene.robots[{i}]") for i, r in enumerate(robots)),
            obstacles=tuple(obstacle_from_dict(o, f"scene.obstacles[{j}]") for j, o in enumerate(obstacles)),
        )

    def to_json(self, **kw) -> str:
        return json.dumps(self.to_dict(), **kw)

    @classmethod
    def from_json(cls, text: str) -> Scene:
        return cls.from_dict(json.loads(text))

    def replace(self, **changes) -> Scene:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


# --- the paper's scenarios ----------------------------------------------------------------------

#: Scenario I (paper figure 10), right to left as seen by the observer; None = the kin robot.
SCENARIO_I_LAYOUT: tuple[dict | None, ...] = (
    {"kind": "cylinder", "radius": 0.03},
    {"kind": "cylinder", "radius": 0.05},
    None,
    {"kind": "cylinder", "radius": 0.09},
    {"kind": "cylinder", "radius": 0.11},
)

#: Scenario II (paper figure 11): every distractor is 7 cm wide (the lidar housing's diameter);
#: the same-radius cylinder stands just left of the kin (the paper's false positive, "No: 3").
#: Orientations are not part of the layout: :func:`paper_scenario` turns every prism and the cuboid
#: so that a flat face squarely faces the observer.
SCENARIO_II_LAYOUT: tuple[dict | None, ...] = (
    {"kind": "prism", "sides": 6, "width": 0.07},
    {"kind": "prism", "sides": 3, "width": 0.07},
    {"kind": "box", "width": 0.07, "depth": 0.07},
    None,
    {"kind": "cylinder", "radius": 0.035},
    {"kind": "prism", "sides": 5, "width": 0.07},
    {"kind": "prism", "sides": 6, "width": 0.07},
)

PAPER_DISTANCES: tuple[float, ...] = (0.5, 0.8, 1.2)
#: Nominal angle between neighbouring objects on the arc, degrees, per scenario.
_DEFAULT_SPACING_DEG = {1: 30.0, 2: 20.0}


def paper_scenario(
    number: int, distance: float = 0.5, spacing_deg: float | None = None, lidar: LidarSpec | None = None
) -> Scene:
    """The paper's Scenario I (``number=1``) or II (``number=2``) at ``distance`` m.

    Robot 0 is the observer at the origin facing +x; robot 1 is the kin, straight ahead at
    ``distance`` (so centred on beam 0). The distractors stand on the same arc (same distance from
    the observer), nominally ``spacing_deg`` apart (default 30° for I, 20° for II), right to left as
    in the paper's figures:

    * I: cylinders of radius 3, 5 cm | kin | 9, 11 cm (figure 10);
    * II: hexagonal, triangular prism, cuboid | kin | cylinder r = 3.5 cm, pentagonal, hexagonal
      prism, all 7 cm wide (figure 11).

    The paper gives no exact bearings or orientations, and at 1° resolution the outcome for the
    3 cm cylinder and for the 7 cm prisms depends on where an object falls between the beams. One
    rule places everything, for both scenarios and every distance:

    * every distractor is **centred between two beams**: its nominal bearing is moved away from
      the kin to the midpoint of the two beams around it (30° -> 30.5° at 1° resolution), so the
      beams fall symmetrically on it; the kin is on beam 0 (its outcome does not depend on the
      alignment);
    * every prism and the cuboid is turned so that **a flat face squarely faces the observer**
      (the widest silhouette: a 7 cm hexagon or cuboid then shows its full 7 cm, like the kin).

    Of the two symmetric alignments (on a beam, between two) this is the one under which the
    geometric detector reproduces figures 10 and 11 (0.5 m) exactly; centred on a beam, the 3 cm
    cylinder passes both filters at 0.5 and 1.2 m. At 0.8 and 1.2 m a few outcomes differ from the
    paper's claims under any single alignment: ``scripts/reproduce_paper.py`` prints the outcomes
    and how often each one comes out as in the paper over random sub-beam offsets and orientations.

    The arena has no boundary wall (Gazebo's empty world): beams that miss read max range.
    Too small a distance or spacing for the objects to fit raises ``ValueError``.
    """
    if number not in (1, 2):
        raise ValueError(f"paper_scenario: number must be 1 or 2, got {number!r}")
    check_positive("paper_scenario", distance=float(distance))
    layout = SCENARIO_I_LAYOUT if number == 1 else SCENARIO_II_LAYOUT
    spacing = math.radians(_DEFAULT_SPACING_DEG[number] if spacing_deg is None else spacing_deg)
    lidar = lidar or LidarSpec()
    res = lidar.resolution
    mid = len(layout) // 2
    robots = [Robot(0.0, 0.0, 0.0)]
    obstacles = []
    for k, item in enumerate(layout):
        if item is None:
            robots.append(Robot(float(distance), 0.0, math.pi))  # the kin faces the observer
            continue
        nominal = (k - mid) * spacing  # CCW positive: k < mid is on the observer's right
        # midway between the two beams around the nominal bearing, mirrored about the kin; the
        # 1e-9 keeps exact multiples of the resolution (30°) from rounding down through float error
        bearing = math.copysign((math.floor(abs(nominal) / res + 1e-9) + 0.5) * res, nominal)
        x, y = distance * math.cos(bearing), distance * math.sin(bearing)
        pose = {"x": x, "y": y}
        if item["kind"] == "prism":  # a vertex points along theta: turn half a side further
            pose["theta"] = bearing + math.pi + math.pi / item["sides"]
        elif item["kind"] == "box":
            pose["theta"] = bearing
        obstacles.append(obstacle_from_dict({**item, **pose}))
    size = max(3.0, 2 * distance + 1.0)
    return Scene(
        robots=tuple(robots),
        obstacles=tuple(obstacles),
        arena=Arena(size, size, walls=False),
        lidar=lidar,
        name=f"paper_scenario_{'I' * number}_{distance:g}m",
    )


# --- seeded random arenas -----------------------------------------------------------------------


@dataclass(frozen=True)
class RandomArenaConfig:
    """Mix of obstacles for :func:`random_arena`. Probabilities are relative weights.

    Attributes:
        kind_weights: relative frequency of ``cylinder, box, prism, wall``.
        kin_width_prob: probability that a cylinder / box / prism is exactly the kin's width
            (cylinder radius = housing radius; box 7 x 7 cm; prism circumscribed diameter 7 cm).
        cylinder_radius: (min, max) radius of other cylinders, m.
        box_size: (min, max) side of other boxes, m.
        prism_width: (min, max) width of other prisms, m.
        prism_sides: side counts drawn uniformly.
        wall_length: (min, max) interior wall length, m.
        wall_thickness: interior wall thickness, m.
        clearance: minimum gap between any two objects (and to the arena edge), m.
        max_attempts: placement tries per object before giving up.
    """

    kind_weights: tuple[float, float, float, float] = (0.35, 0.2, 0.35, 0.1)
    kin_width_prob: float = 0.4
    cylinder_radius: tuple[float, float] = (0.02, 0.15)
    box_size: tuple[float, float] = (0.05, 0.4)
    prism_width: tuple[float, float] = (0.05, 0.3)
    prism_sides: tuple[int, ...] = (3, 4, 5, 6)
    wall_length: tuple[float, float] = (0.5, 2.0)
    wall_thickness: float = 0.05
    clearance: float = 0.05
    max_attempts: int = 500

    def __post_init__(self) -> None:
        w = "RandomArenaConfig"
        # lists (from JSON) become tuples, so the config stays frozen and hashable
        object.__setattr__(self, "kind_weights", check_weights(w, "kind_weights", self.kind_weights, 4))
        check_number(w, "kin_width_prob", self.kin_width_prob, 0.0, 1.0)
        for name in ("cylinder_radius", "box_size", "prism_width", "wall_length"):
            object.__setattr__(self, name, check_interval(w, name, getattr(self, name)))
        sides = check_sequence(w, "prism_sides", self.prism_sides, min_len=1)
        for i, n in enumerate(sides):
            check_number(w, f"prism_sides[{i}]", n, 3, 1000, integer=True)
        object.__setattr__(self, "prism_sides", sides)
        check_positive(w, wall_thickness=self.wall_thickness)
        check_number(w, "clearance", self.clearance, 0.0)
        check_number(w, "max_attempts", self.max_attempts, 1, 10**7, integer=True)

    @classmethod
    def from_dict(cls, d: dict) -> RandomArenaConfig:
        """From a plain dict (e.g. JSON); unknown keys raise ``ValueError`` naming them."""
        return dataclass_from_dict(cls, d, "RandomArenaConfig")


#: random_arena's robot spec when none is given (a frozen value: one instance, validated once)
_DEFAULT_ROBOT = RobotSpec()


def _random_obstacle(rng: np.random.Generator, cfg: RandomArenaConfig, spec: RobotSpec, x, y,
                     p: np.ndarray | None = None) -> Obstacle:  # fmt: skip
    """One obstacle at ``(x, y)``; ``p``: ``cfg.kind_weights`` normalised (computed here if not given)."""
    kind = rng.choice(4, p=np.asarray(cfg.kind_weights) / sum(cfg.kind_weights) if p is None else p)
    theta = float(rng.uniform(-math.pi, math.pi))
    kin = rng.random() < cfg.kin_width_prob
    kin_w = 2 * spec.housing_radius
    if kind == 0:
        r = spec.housing_radius if kin else float(rng.uniform(*cfg.cylinder_radius))
        return Cylinder(x=x, y=y, radius=r)
    if kind == 1:
        w, d = (kin_w, kin_w) if kin else rng.uniform(*cfg.box_size, size=2)
        return Box(x=x, y=y, width=float(w), depth=float(d), theta=theta)
    if kind == 2:
        w = kin_w if kin else float(rng.uniform(*cfg.prism_width))
        return Prism(x=x, y=y, sides=int(rng.choice(cfg.prism_sides)), width=w, theta=theta)
    length = float(rng.uniform(*cfg.wall_length))
    dx, dy = 0.5 * length * math.cos(theta), 0.5 * length * math.sin(theta)
    return Wall(x1=x - dx, y1=y - dy, x2=x + dx, y2=y + dy, thickness=cfg.wall_thickness)


class _Placer:
    """Rejection sampling of non-overlapping objects with pymunk overlap queries."""

    def __init__(self, arena: Arena, clearance: float, max_attempts: int, spec: RobotSpec, who: str):
        w, h = arena.width, arena.height
        c = clearance
        self.inner = Arena(w - 2 * c, h - 2 * c) if min(w, h) > 2 * c else arena
        self.arena, self.clearance, self.max_attempts = arena, clearance, max_attempts
        self.spec, self.who = spec, who
        self.index = _OverlapIndex()

    def fits(self, obj) -> bool:
        parts = obj if isinstance(obj, tuple) else (obj,)
        shapes = []
        for part in parts:
            if isinstance(part, Robot):
                shapes.append(("circle", np.array([part.x, part.y, self.spec.body_radius])))
            else:
                shapes.append(part.footprint())
        for kind, geom in shapes:
            if not _inside_arena(kind, geom, self.inner) or self.index.hits(
                kind, geom, inflate=self.clearance
            ):
                return False
        return True

    def place(self, make, sample_xy, what: str):
        """``make(x, y)`` an object (or a tuple of parts placed together) at sampled points until it fits."""
        for _ in range(self.max_attempts):
            obj = make(*sample_xy())
            if not self.fits(obj):
                continue
            for k, part in enumerate(obj if isinstance(obj, tuple) else (obj,)):
                if isinstance(part, Robot):
                    self.index.add("circle", np.array([part.x, part.y, self.spec.body_radius]), f"{what}.{k}")
                else:
                    self.index.add(*part.footprint(), f"{what}.{k}")
            return obj
        raise ValueError(
            f"{self.who}: could not place {what} after {self.max_attempts} attempts: the objects do not fit "
            f"in a {self.arena.width} x {self.arena.height} m arena with {self.clearance} m clearance; "
            "use a larger size or fewer objects"
        )


def random_arena(
    n_robots: int = 8,
    n_obstacles: int = 20,
    seed: int | np.random.Generator | None = 0,
    size: float | tuple[float, float] = 10.0,
    config: RandomArenaConfig | dict | None = None,
    robot: RobotSpec | None = None,
    lidar: LidarSpec | None = None,
) -> Scene:
    """A seeded random arena: ``n_robots`` robots and ``n_obstacles`` mixed obstacles.

    Obstacles mix cylinders, boxes, regular prisms (3–6 sides) and interior walls of random sizes,
    a fraction of them exactly the kin's width (see :class:`RandomArenaConfig`). Robots get uniform
    random headings. Placement is rejection sampling with pymunk overlap queries, so nothing
    overlaps and everything keeps ``config.clearance`` from everything else and from the boundary.
    The same ``seed`` always gives the same scene. Raises ``ValueError`` when the objects cannot fit.
    """
    # a dict (e.g. from JSON) is accepted and validated like the dataclass
    cfg = dataclass_from_dict(RandomArenaConfig, {} if config is None else config, "random_arena")
    spec = robot or _DEFAULT_ROBOT
    if not isinstance(n_robots, int | np.integer) or n_robots < 0:
        raise ValueError(f"random_arena: n_robots must be an integer >= 0, got {n_robots!r}")
    if not isinstance(n_obstacles, int | np.integer) or n_obstacles < 0:
        raise ValueError(f"random_arena: n_obstacles must be an integer >= 0, got {n_obstacles!r}")
    rng = make_rng(seed, "random_arena")
    w, h = (size, size) if np.isscalar(size) else size
    arena = Arena(float(w), float(h), walls=True)
    hx, hy = arena.half_extents
    placer = _Placer(arena, cfg.clearance, cfg.max_attempts, spec, "random_arena")

    def uniform_xy():
        return float(rng.uniform(-hx, hx)), float(rng.uniform(-hy, hy))

    p = np.asarray(cfg.kind_weights) / sum(cfg.kind_weights)
    obstacles = [
        placer.place(lambda x, y: _random_obstacle(rng, cfg, spec, x, y, p), uniform_xy, f"obstacle {j}")
        for j in range(n_obstacles)
    ]
    robots = [
        placer.place(
            lambda x, y: Robot(x, y, float(rng.uniform(-math.pi, math.pi))), uniform_xy, f"robot {i}"
        )
        for i in range(n_robots)
    ]
    return Scene._placed(
        robots=tuple(robots),
        obstacles=tuple(obstacles),
        arena=arena,
        robot=spec,
        lidar=lidar or LidarSpec(),
        name=f"random_arena(n_robots={n_robots}, n_obstacles={n_obstacles})",
    )


# --- scenes for kin-detection evaluation and training data --------------------------------------


@dataclass(frozen=True)
class DetectionSceneConfig:
    """Layout of :func:`detection_scene`: an observer, kin robots and hard distractors around it.

    Attributes:
        n_kin: kin robots around the observer.
        n_distractors: obstacles around the observer.
        distance: (min, max) distance from the observer to object centres, m (uniform).
        distractor_weights: relative frequency of ``kin_width_prism`` (3–6 sides, circumscribed
            diameter = the housing's, any orientation), ``kin_width_box`` (7 x 7 cm cuboid),
            ``same_radius_cylinder`` (radius = housing radius: indistinguishable in one scan),
            ``other_cylinder`` (radius drawn from ``cylinder_radius``), ``wall`` and ``corner``
            (two walls meeting at a right angle).
        cylinder_radius: (min, max) radius of other cylinders, m; values within 5 mm of the housing
            radius are redrawn so "other" stays distinguishable.
        wall_length: (min, max) wall length, m.
        clearance: minimum gap between objects, m.
        arena_margin: the arena is a square of side ``2 * distance[1] + 2 * arena_margin``.
        max_attempts: placement tries per object.
    """

    n_kin: int = 3
    n_distractors: int = 12
    distance: tuple[float, float] = (0.3, 3.0)
    distractor_weights: tuple[float, float, float, float, float, float] = (0.35, 0.1, 0.1, 0.25, 0.1, 0.1)
    cylinder_radius: tuple[float, float] = (0.02, 0.12)
    wall_length: tuple[float, float] = (0.4, 1.5)
    clearance: float = 0.03
    arena_margin: float = 0.5
    max_attempts: int = 300

    DISTRACTOR_KINDS: ClassVar[tuple[str, ...]] = (
        "kin_width_prism",
        "kin_width_box",
        "same_radius_cylinder",
        "other_cylinder",
        "wall",
        "corner",
    )

    def __post_init__(self) -> None:
        w = "DetectionSceneConfig"
        check_number(w, "n_kin", self.n_kin, 0, 10_000, integer=True)
        check_number(w, "n_distractors", self.n_distractors, 0, 10_000, integer=True)
        object.__setattr__(self, "distance", check_interval(w, "distance", self.distance))
        object.__setattr__(
            self, "distractor_weights", check_weights(w, "distractor_weights", self.distractor_weights, 6)
        )
        for name in ("cylinder_radius", "wall_length"):
            object.__setattr__(self, name, check_interval(w, name, getattr(self, name)))
        check_number(w, "clearance", self.clearance, 0.0)
        check_number(w, "arena_margin", self.arena_margin, 0.0)
        check_number(w, "max_attempts", self.max_attempts, 1, 10**7, integer=True)

    @classmethod
    def from_dict(cls, d: dict) -> DetectionSceneConfig:
        """From a plain dict (e.g. JSON); unknown keys raise ``ValueError`` naming them."""
        return dataclass_from_dict(cls, d, "DetectionSceneConfig")


def _detection_distractor(rng, cfg: DetectionSceneConfig, spec: RobotSpec, x: float, y: float):
    w = np.asarray(cfg.distractor_weights, dtype=float)
    kind = cfg.DISTRACTOR_KINDS[rng.choice(6, p=w / w.sum())]
    theta = float(rng.uniform(-math.pi, math.pi))
    kin_w = 2 * spec.housing_radius
    if kind == "kin_width_prism":
        return Prism(x=x, y=y, sides=int(rng.integers(3, 7)), width=kin_w, theta=theta)
    if kind == "kin_width_box":
        return Box(x=x, y=y, width=kin_w, depth=kin_w, theta=theta)
    if kind == "same_radius_cylinder":
        return Cylinder(x=x, y=y, radius=spec.housing_radius)
    if kind == "other_cylinder":
        while True:
            r = float(rng.uniform(*cfg.cylinder_radius))
            if abs(r - spec.housing_radius) > 0.005:
                return Cylinder(x=x, y=y, radius=r)
    length = float(rng.uniform(*cfg.wall_length))
    t = 0.05
    c, s = math.cos(theta), math.sin(theta)
    if kind == "wall":
        return Wall(
            x1=x - 0.5 * length * c,
            y1=y - 0.5 * length * s,
            x2=x + 0.5 * length * c,
            y2=y + 0.5 * length * s,
            thickness=t,
        )
    # corner: two walls from (x, y), at right angles, meeting flush
    other = float(rng.uniform(*cfg.wall_length))
    return (
        Wall(x1=x - 0.5 * t * c, y1=y - 0.5 * t * s, x2=x + length * c, y2=y + length * s, thickness=t),
        Wall(x1=x + 0.5 * t * s, y1=y - 0.5 * t * c, x2=x - other * s, y2=y + other * c, thickness=t),
    )


def detection_scene(
    seed: int | np.random.Generator | None = 0,
    config: DetectionSceneConfig | dict | None = None,
    lidar: LidarSpec | None = None,
    robot: RobotSpec | None = None,
) -> Scene:
    """An observer (robot 0, at the origin, random heading) among kin robots and hard distractors.

    Kin robots (robots ``1..n_kin``) and distractors are placed at distances drawn uniformly from
    ``config.distance`` and uniform bearings, without overlaps. Distractors are the ones the paper's
    detector must reject: kin-width prisms and cuboids, cylinders of other radii, walls and corners,
    plus same-radius cylinders (which no single scan can tell from a kin). Objects nearer the
    observer naturally occlude farther ones, kin included. Used by the detector evaluation sweep and
    the learned classifier's training data; seeded, so the same seed gives the same scene.
    """
    cfg = dataclass_from_dict(DetectionSceneConfig, {} if config is None else config, "detection_scene")
    spec = robot or RobotSpec()
    rng = make_rng(seed, "detection_scene")
    side = 2 * cfg.distance[1] + 2 * cfg.arena_margin
    arena = Arena(side, side, walls=True)
    placer = _Placer(arena, cfg.clearance, cfg.max_attempts, spec, "detection_scene")
    observer = Robot(0.0, 0.0, float(rng.uniform(-math.pi, math.pi)))
    placer.place(lambda x, y: observer, lambda: (0.0, 0.0), "observer")

    def polar_xy():
        d = float(rng.uniform(*cfg.distance))
        b = float(rng.uniform(-math.pi, math.pi))
        return d * math.cos(b), d * math.sin(b)

    robots = [observer] + [
        placer.place(lambda x, y: Robot(x, y, float(rng.uniform(-math.pi, math.pi))), polar_xy, f"kin {i}")
        for i in range(cfg.n_kin)
    ]
    obstacles: list = []
    for j in range(cfg.n_distractors):
        obj = placer.place(
            lambda x, y: _detection_distractor(rng, cfg, spec, x, y), polar_xy, f"distractor {j}"
        )
        obstacles.extend(obj if isinstance(obj, tuple) else (obj,))
    return Scene(
        robots=tuple(robots),
        obstacles=tuple(obstacles),
        arena=arena,
        robot=spec,
        lidar=lidar or LidarSpec(),
        name=f"detection_scene(n_kin={cfg.n_kin}, n_distractors={cfg.n_distractors})",
    )
