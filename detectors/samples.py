"""Labelled lidar segments as data: the category names and the on-disk dataset format.

Simulator-free (numpy only): a dataset written by ``scripts/make_dataset.py`` (from the simulator,
:mod:`kin_envs.detection.dataset`) or by anyone who labels real scans the same way is read here, and
the learned detector's training code reads these samples, never a world.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .features import FEATURE_VERSION, FeatureConfig, feature_names
from .fileio import sha256_file

__all__ = [
    "CATEGORIES",
    "DATASET_FORMAT",
    "DATASET_FORMAT_VERSION",
    "category_code",
    "concat_records",
    "load_dataset",
]

#: Segment / object categories (``category`` codes are indices into this tuple).
CATEGORIES: tuple[str, ...] = (
    "kin",  # a robot's lidar housing
    "same_radius_cylinder",  # cylinder of the housing's radius: indistinguishable in one scan
    "kin_width_prism",  # regular prism, circumscribed diameter = the housing's
    "kin_width_box",  # 7 x 7 cm cuboid
    "cylinder",  # any other cylinder
    "prism",  # any other prism
    "box",  # any other cuboid
    "polygon",
    "wall",  # one interior wall
    "corner",  # two or more interior walls in one segment
    "boundary",  # the arena's boundary wall
    "kin_minority",  # a robot is the plurality of the beams but not the majority
)
_CAT = {name: k for k, name in enumerate(CATEGORIES)}
DATASET_FORMAT = "kin-envs/segment-dataset"
#: 2: the manifest lists every shard's segment / object counts and SHA-256 (checked on load).
DATASET_FORMAT_VERSION = 2

def category_code(name: str) -> int:
    """Index of ``name`` in :data:`CATEGORIES` (``ValueError`` for an unknown name)."""
    if name not in _CAT:
        raise ValueError(f"unknown category {name!r}; expected one of {CATEGORIES}")
    return _CAT[name]


def concat_records(parts: list[dict]) -> dict:
    """Concatenate a list of record dicts column by column."""
    if not parts:
        return {}
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


# --- loading ------------------------------------------------------------------------------------


def load_dataset(path, feature_config: FeatureConfig | None = None) -> tuple[dict, dict, dict]:
    """Read a dataset directory written by ``scripts/make_dataset.py``.

    Returns ``(segments, objects, manifest)`` with every shard concatenated. Raises
    ``FileNotFoundError`` for a missing directory / manifest / shard and ``ValueError`` for a
    manifest of another format or version, another ``FEATURE_VERSION`` or (if given) another feature
    config, and for a shard whose checksum or counts differ from the manifest's or that cannot be
    read (the message names the shard).
    """
    root = Path(path)
    mpath = root / "manifest.json"
    if not mpath.is_file():
        raise FileNotFoundError(f"{mpath}: no dataset manifest (write one with scripts/make_dataset.py)")
    try:
        manifest = json.loads(mpath.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{mpath}: not a readable JSON manifest ({e})") from e
    if not isinstance(manifest, dict) or manifest.get("format") != DATASET_FORMAT:
        raise ValueError(f"{mpath}: not a {DATASET_FORMAT!r} manifest")
    if manifest.get("format_version") != DATASET_FORMAT_VERSION:
        raise ValueError(
            f"{mpath}: dataset format version {manifest.get('format_version')!r} is not "
            f"{DATASET_FORMAT_VERSION} (shard checksums); regenerate it with scripts/make_dataset.py"
        )
    if manifest.get("feature_version") != FEATURE_VERSION:
        raise ValueError(
            f"{mpath}: dataset has feature version {manifest.get('feature_version')!r}, this code computes "
            f"version {FEATURE_VERSION}; regenerate it with scripts/make_dataset.py"
        )
    fc = FeatureConfig.from_dict(manifest["feature_config"])
    if feature_config is not None and fc != feature_config:
        raise ValueError(f"{mpath}: dataset feature config {fc} differs from the requested {feature_config}")
    if manifest.get("feature_names") != feature_names(fc):
        raise ValueError(f"{mpath}: feature names differ from feature version {FEATURE_VERSION}'s")
    segs, objs = [], []
    for shard in manifest["shards"]:
        f = root / shard["file"]
        if not f.is_file():
            raise FileNotFoundError(f"{f}: dataset shard listed in {mpath} is missing")
        if sha256_file(f) != shard.get("sha256"):
            raise ValueError(f"{f}: dataset shard does not match its SHA-256 in {mpath} (corrupt, replaced)")
        try:
            with np.load(f) as z:
                s = {k[4:]: z[k] for k in z.files if k.startswith("seg_")}
                o = {k[4:]: z[k] for k in z.files if k.startswith("obj_")}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise ValueError(f"{f}: unreadable dataset shard ({type(e).__name__}: {e})") from e
        counts = (len(next(iter(s.values()), [])), len(next(iter(o.values()), [])))
        if counts != (shard.get("n_segments"), shard.get("n_objects")):
            raise ValueError(
                f"{f}: shard holds {counts[0]} segments and {counts[1]} objects, {mpath} says "
                f"{shard.get('n_segments')} and {shard.get('n_objects')}"
            )
        segs.append(s)
        objs.append(o)
    return concat_records(segs), concat_records(objs), manifest
