"""Slow reference lidar: one pymunk ``segment_query_first`` per beam (the independent oracle)."""

from __future__ import annotations

import math

import numpy as np

from kin_envs.core.lidar import HitKind
from kin_envs.core.world import LIDAR_QUERY_FILTER, World


def oracle_scan(world: World, robot: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-beam pymunk query from robot ``robot``: ``(distance, kind, index)`` arrays.

    ``distance`` is ``inf`` where nothing is hit within range.
    """
    import pymunk

    spec = world.scene.lidar
    x, y, th = world.poses[robot]
    start = (float(x), float(y))
    # the robot's own shapes share group robot+1: a query in that group ignores them
    flt = pymunk.ShapeFilter(
        group=robot + 1, categories=LIDAR_QUERY_FILTER.categories, mask=LIDAR_QUERY_FILTER.mask
    )
    owners = {}
    for i, b in enumerate(world.robot_bodies):
        owners[b] = (HitKind.ROBOT, i)
    for j, b in enumerate(world.obstacle_bodies):
        owners[b] = (world.scene.obstacles[j].hit_kind, j)
    dist = np.full(spec.n_beams, np.inf)
    kind = np.zeros(spec.n_beams, dtype=np.int8)
    index = np.full(spec.n_beams, -1, dtype=np.int32)
    for i, a in enumerate(spec.angles):
        d = th + a
        end = (x + spec.range_max * math.cos(d), y + spec.range_max * math.sin(d))
        info = world.space.segment_query_first(start, end, 0.0, flt)
        if info is None:
            continue
        dist[i] = info.alpha * spec.range_max
        kind[i], index[i] = owners.get(info.shape.body, (HitKind.BOUNDARY, -1))
    return dist, kind, index
