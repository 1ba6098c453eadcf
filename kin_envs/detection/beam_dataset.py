"""Per-beam labelled scans for the beam kin detector (:mod:`detectors.beam_detector`), simulator side.

The same seeded scene mix as the segment dataset (:func:`kin_envs.detection.dataset.make_scene`, with
swarm scenes and beam dropout switched on by :data:`BEAM_DATASET_CONFIG`), but labels are per beam and
need no segmentation: a beam is **kin** when its reading is valid and it hit a robot's lidar housing,
and its target is that robot's centre in the observer frame. Beams on same-radius cylinders (identical
to a kin in one scan) are flagged so that training can leave them out.

Per scan row (arrays stacked over rows): ``ranges`` ``(n, 360)`` float32 (what the lidar reported),
``label`` int8, ``centre`` ``(n, 360, 2)`` float32 (NaN off kin), ``category`` int8 (index into
:data:`detectors.samples.CATEGORIES`, -1 nothing), ``noise``, ``dropout``, ``seed``, ``family``.
The on-disk format (``.npz`` shards + ``manifest.json``) is read by
:func:`detectors.beam_detector.load_beam_dataset`.
"""

from __future__ import annotations

import numpy as np

from detectors.samples import category_code

from ..core.lidar import HitKind
from ..core.world import World
from .dataset import DatasetConfig, _obstacle_table, make_scene
from .seeds import TRAINING_SEEDS, check_training_seeds

__all__ = ["BEAM_DATASET_CONFIG", "beam_records"]

#: The beam detector's training mix: a third swarm scenes, the rest detection scenes (kin among hard
#: look-alikes at 0.2-4 m, some without walls) and random arenas; noise 0-2 % (a quarter exactly 0),
#: a quarter of the scenes with 0-10 % beam dropout.
BEAM_DATASET_CONFIG = DatasetConfig(
    swarm_prob=0.35, zero_noise_prob=0.25, dropout_share=0.25, dropout=(0.0, 0.1), max_observers=8
)


def beam_records(seed: int, config: DatasetConfig | None = None) -> dict[str, np.ndarray]:
    """Scan one seeded scene from its observers and label every beam (see the module docstring).

    ``seed`` must lie in :data:`kin_envs.detection.seeds.TRAINING_SEEDS`.
    """
    check_training_seeds([seed], "beam_records(seed)", within=TRAINING_SEEDS)
    cfg = config or BEAM_DATASET_CONFIG
    scene, rng, info = make_scene(seed, cfg)
    world = info.pop("world", None) or World(scene, seed=rng)
    scan = world.scan(robots=info["observers"])
    poses = world.poses
    n_rows, n_beams = scan.ranges.shape
    valid = scan.ranges < scan.range_max
    kind, idx = scan.hit_kind, scan.hit_index.astype(np.int64)
    label = valid & (kind == HitKind.ROBOT)
    obst = _obstacle_table(scene)
    category = np.full((n_rows, n_beams), -1, np.int8)
    is_obst = (kind >= HitKind.CYLINDER) & (idx >= 0)
    category[is_obst] = obst["category"][idx[is_obst]]
    category[kind == HitKind.BOUNDARY] = category_code("boundary")
    category[kind == HitKind.ROBOT] = category_code("kin")
    centre = np.full((n_rows, n_beams, 2), np.nan, np.float32)
    rr, bb = np.nonzero(label)
    k = idx[rr, bb]
    obs = scan.poses[rr]
    dx, dy = poses[k, 0] - obs[:, 0], poses[k, 1] - obs[:, 1]
    c, s = np.cos(obs[:, 2]), np.sin(obs[:, 2])
    centre[rr, bb, 0] = c * dx + s * dy
    centre[rr, bb, 1] = -s * dx + c * dy
    fam = 2 if info["open"] else info["family"]
    return {
        "ranges": scan.ranges.astype(np.float32),
        "label": label.astype(np.int8),
        "centre": centre,
        "category": category,
        "noise": np.full(n_rows, info["noise"], np.float32),
        "dropout": np.full(n_rows, info["dropout"], np.float32),
        "seed": np.full(n_rows, seed, np.int64),
        "family": np.full(n_rows, fam, np.int8),
    }
