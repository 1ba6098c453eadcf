"""Top-view renderer shared by the Gymnasium and PettingZoo envs (pygame, imported lazily).

World metres are mapped to pixels here only. Drawn: the arena, obstacles (interior walls darker),
robots (body circle, lidar housing, heading line), optionally one or more robots' lidar beams, and
detections as rings at the detected centre: green when the detection matches a real robot
(``kin_index >= 0``), red when it does not.
"""

from __future__ import annotations

import math
import os

import numpy as np
from gymnasium.error import DependencyNotInstalled

__all__ = ["Renderer", "import_pygame"]

_BG = (245, 245, 240)
_ARENA = (60, 60, 60)
_OBSTACLE = (150, 150, 150)
_WALL = (90, 90, 90)
_BEAM = (255, 170, 170)
_HIT = (220, 40, 40)
_HOUSING = (30, 30, 30)
_GOOD = (20, 170, 40)
_BAD = (220, 20, 20)
_TRACK = (30, 90, 230)
ROLE_COLORS = {
    "learner": (240, 140, 20),  # the controlled robot (single-agent envs)
    "kin": (40, 110, 220),
    "agent": (40, 110, 220),
}


def import_pygame():
    """Import pygame, or raise ``DependencyNotInstalled`` with the install hint."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError as e:
        raise DependencyNotInstalled(
            "rendering needs pygame, which is not installed: pip install kin-envs[viz]"
        ) from e
    return pygame


class Renderer:
    """Draws a :class:`~kin_envs.core.world.World` as an ``H x W x 3`` uint8 image or a window.

    Args:
        scene: the world's scene (arena and obstacles; static obstacles are drawn from it).
        render_mode: ``"rgb_array"`` or ``"human"``.
        size: pixels of the image's longer side.
        fps: frame rate of the ``"human"`` window.
        title: window title.
    """

    def __init__(
        self, scene, render_mode: str, size: int = 512, fps: int = 10, title: str = "kin_envs"
    ) -> None:
        if render_mode not in ("rgb_array", "human"):
            raise ValueError(f"Renderer: render_mode must be 'rgb_array' or 'human', got {render_mode!r}")
        self.pg = import_pygame()
        self.mode = render_mode
        self.fps = fps
        self.title = title
        w, h = scene.arena.width, scene.arena.height
        self.margin = 8
        self.scale = (size - 2 * self.margin) / max(w, h)
        self.hx, self.hy = w / 2, h / 2
        self.width = int(round(w * self.scale)) + 2 * self.margin
        self.height = int(round(h * self.scale)) + 2 * self.margin
        self.surface = self.pg.Surface((self.width, self.height))
        self.window = None
        self.clock = None
        self.set_scene(scene)

    def set_scene(self, scene) -> None:
        """Use a new scene of the same arena size (envs rebuild their world on every reset)."""
        self.scene = scene
        self.footprints = [o.footprint() for o in scene.obstacles]
        self.centres = np.array([o.center for o in scene.obstacles]).reshape(-1, 2)
        self.movable = [j for j, o in enumerate(scene.obstacles) if o.movable]

    # -- coordinates --------------------------------------------------------------------------
    def px(self, x, y):
        return (self.margin + (x + self.hx) * self.scale, self.margin + (self.hy - y) * self.scale)

    def _pts(self, xy: np.ndarray):
        return [self.px(float(x), float(y)) for x, y in xy]

    # -- drawing ------------------------------------------------------------------------------
    def render(self, world, roles=None, beams=(), detections=(), tracks=()):
        """Draw ``world`` and return the frame (``"rgb_array"``) or show it (``"human"``).

        Args:
            world: the world to draw.
            roles: per-robot role names (keys of ``ROLE_COLORS``); default all ``"agent"``.
            beams: ``(pose (3,), ranges (n_beams,), angles (n_beams,), range_max)`` tuples.
            detections: ``(pose (3,), columns)`` tuples, ``columns`` as ``info["kin_detections"]``.
            tracks: ``(pose (3,), columns)`` tuples of the tracker's kin tracks (``x``, ``y`` in the
                robot frame): drawn as a cross in a wider ring.
        """
        pg, surf, s = self.pg, self.surface, self.scale
        surf.fill(_BG)
        x0, y0 = self.px(-self.hx, self.hy)
        pg.draw.rect(
            surf,
            _ARENA,
            pg.Rect(round(x0), round(y0), round(2 * self.hx * s), round(2 * self.hy * s)),
            width=2,
        )
        obstacle_poses = world.obstacle_poses if self.movable else None
        for j, (o, (kind, geom)) in enumerate(zip(self.scene.obstacles, self.footprints, strict=True)):
            color = _WALL if o.kind == "wall" else _OBSTACLE
            if obstacle_poses is not None and j in self.movable:
                kind, geom = self._moved(kind, geom, j, obstacle_poses[j])
            if kind == "circle":
                pg.draw.circle(surf, color, self.px(geom[0], geom[1]), max(1.0, geom[2] * s))
            else:
                pg.draw.polygon(surf, color, self._pts(geom))
        for pose, ranges, angles, range_max in beams:
            x, y, th = (float(v) for v in pose)
            start = self.px(x, y)
            hit = ranges < range_max
            r, a = ranges[hit].astype(np.float64), angles[hit] + th
            ends = np.stack([x + r * np.cos(a), y + r * np.sin(a)], axis=1)
            for e in self._pts(ends):
                pg.draw.line(surf, _BEAM, start, e, 1)
            for e in self._pts(ends):
                surf.set_at((int(e[0]), int(e[1])), _HIT)
        spec = self.scene.robot
        poses = world.poses
        for i, (x, y, th) in enumerate(poses):
            role = roles[i] if roles is not None else "agent"
            c = self.px(x, y)
            pg.draw.circle(surf, ROLE_COLORS.get(role, ROLE_COLORS["agent"]), c, spec.body_radius * s)
            pg.draw.circle(surf, _HOUSING, c, max(1.0, spec.housing_radius * s))
            tip = self.px(x + spec.body_radius * math.cos(th), y + spec.body_radius * math.sin(th))
            pg.draw.line(surf, _HOUSING, c, tip, 2)
        ring = max(3.0, 2.0 * spec.housing_radius * s)
        for pose, cols in detections:
            x, y, th = (float(v) for v in pose)
            ct, st = math.cos(th), math.sin(th)
            for dx, dy, k in zip(cols["x"], cols["y"], cols["kin_index"], strict=True):
                c = self.px(x + ct * dx - st * dy, y + st * dx + ct * dy)
                pg.draw.circle(surf, _GOOD if k >= 0 else _BAD, c, ring, width=2)
        for pose, cols in tracks:
            x, y, th = (float(v) for v in pose)
            ct, st = math.cos(th), math.sin(th)
            for dx, dy in zip(cols["x"], cols["y"], strict=True):
                cx, cy = self.px(x + ct * dx - st * dy, y + st * dx + ct * dy)
                pg.draw.circle(surf, _TRACK, (cx, cy), 1.8 * ring, width=1)
                pg.draw.line(surf, _TRACK, (cx - ring, cy), (cx + ring, cy), 1)
                pg.draw.line(surf, _TRACK, (cx, cy - ring), (cx, cy + ring), 1)
        if self.mode == "human":
            self._show()
            return None
        return np.ascontiguousarray(np.transpose(pg.surfarray.array3d(surf), (1, 0, 2)))

    def _moved(self, kind, geom, j, pose):
        # footprint at the start, moved to the body's current pose (obstacle_poses: x, y, angle)
        cx, cy = self.centres[j]
        if kind == "circle":
            return kind, np.array([pose[0], pose[1], geom[2]])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        local = geom - (cx, cy)
        return kind, local @ np.array([[c, s], [-s, c]]) + pose[:2]

    def _show(self) -> None:
        pg = self.pg
        if self.window is None:
            pg.display.init()
            pg.display.set_caption(self.title)
            self.window = pg.display.set_mode((self.width, self.height))
            self.clock = pg.time.Clock()
        pg.event.pump()
        self.window.blit(self.surface, (0, 0))
        pg.display.flip()
        self.clock.tick(self.fps)

    def close(self) -> None:
        if self.window is not None:
            self.pg.display.quit()
            self.window = None
