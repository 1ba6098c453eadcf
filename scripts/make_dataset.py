"""Generate labelled lidar segments for the learned kin classifier.

Seeded random scenes (``kin_envs.detection.dataset.DatasetConfig``: detection scenes - an observer among kin,
kin-width prisms 3-6 sides and cuboids, cylinders of radius 2-12 cm including the lidar housing's,
walls and corners at 0.2-4 m - and random arenas), range noise 0-2 %, scanned from up to six robots
each, segmented by the geometric detector's own segmentation and labelled from the scan's ground
truth (rule and fields: ``kin_envs/detection/dataset.py``). Scene ``i`` uses seed ``first_seed + i``.

Writes to ``--out``: ``shard_XXXXX.npz`` (compressed; ``seg_*`` per-segment and ``obj_*`` per-visible-
object columns) and ``manifest.json`` (format, feature version and config, dataset config, seeds,
counts per class and category, every shard's counts and SHA-256, timing, command line). Every file is
written atomically and the manifest last: a directory without a manifest is an unfinished run, and
``load_dataset`` checks each shard against it. A non-empty ``--out`` is refused unless ``--overwrite``,
which first deletes the old manifest and shards.

Each scene is one work unit of :func:`kin_envs.distributed.imap_seeds`: run here (``--backend
local``) or as Ray tasks (``--backend ray``, a local Ray with ``--num-cpus`` workers or the cluster
at ``--address``), with identical shards.

Example::

    python scripts/make_dataset.py --out outputs/segments --scenes 3000
    python scripts/make_dataset.py --out outputs/segments --scenes 300000 --backend ray --address auto
"""

from __future__ import annotations

import argparse
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

from detectors.features import FEATURE_VERSION, FeatureConfig, feature_names
from detectors.fileio import atomic_write, sha256_file, write_json
from detectors.samples import CATEGORIES, DATASET_FORMAT, DATASET_FORMAT_VERSION, concat_records
from detectors.windows import WindowConfig
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    parse_json_object,
    run_main,
    script_logger,
    setup_logging,
    write_run_info,
)
from kin_envs.detection.dataset import DatasetConfig, scene_records
from kin_envs.detection.seeds import check_training_seeds
from kin_envs.distributed import BACKENDS, imap_seeds

_SHARD = re.compile(r"shard_\d{5}\.npz|\.(shard_\d{5}\.npz|manifest\.json)\..*\.tmp")


def scene_unit(seed: int, cfg: DatasetConfig, fcfg: FeatureConfig, windows=None) -> tuple[dict, dict]:
    """The work unit: one scene's segment and object records (its scan and scene stay behind)."""
    segs, objs, _ = scene_records(seed, cfg, fcfg, windows=windows)
    return segs, objs


def write_shard(path: Path, segs: dict, objs: dict) -> str:
    """Write one shard atomically; returns its SHA-256."""
    with atomic_write(path) as f:
        np.savez_compressed(
            f, **{f"seg_{k}": v for k, v in segs.items()}, **{f"obj_{k}": v for k, v in objs.items()}
        )
    return sha256_file(path)


def prepare_out_dir(out: Path, overwrite: bool) -> str | None:
    """Create ``out`` or, with ``overwrite``, clear a previous dataset from it; returns an error or
    ``None``. The manifest goes first, so an interrupted rerun never leaves an old manifest beside
    new shards."""
    try:
        check_output_dir(out)
    except ValueError as e:
        return str(e)
    entries = list(out.iterdir())
    if not entries:
        return None
    if not overwrite:
        return f"--out {out} is not empty; pass --overwrite to replace the dataset in it"
    ours = [p for p in entries if p.name in ("manifest.json", "run.json") or _SHARD.fullmatch(p.name)]
    other = sorted(p.name for p in entries if p not in ours)
    if other:
        return f"--out {out} holds files that are not a dataset's ({other[:5]}); not deleting them"
    (out / "manifest.json").unlink(missing_ok=True)
    for p in ours:
        p.unlink(missing_ok=True)
    return None


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path, help="output directory (created)")
    ap.add_argument("--scenes", type=int, default=3000, help="number of scenes")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of scene 0 (scene i: first_seed + i)")
    ap.add_argument("--shard-scenes", type=int, default=500, help="scenes per .npz shard")
    ap.add_argument("--config", default=None, help="DatasetConfig overrides: JSON object or file")
    ap.add_argument("--feature-config", default=None, help="FeatureConfig overrides: JSON object or file")
    ap.add_argument("--windows", nargs="?", const="{}", default=None, metavar="JSON",
                    help="also write the candidate windows of segments too wide for the learned detector's "
                    "pre-gate (detectors.windows; column window = 1), optionally with WindowConfig overrides "
                    "(JSON object or file)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace the dataset in a non-empty --out (deletes its manifest, then shards)")
    ap.add_argument("--backend", choices=BACKENDS, default="local", help="scenes here or as Ray tasks")
    ap.add_argument("--address", default=None, help="ray: join this cluster (e.g. auto, host:6379)")
    ap.add_argument("--num-cpus", type=int, default=None, help="ray: CPUs of a local Ray (default: all)")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    if args.scenes < 1 or args.shard_scenes < 1 or args.first_seed < 0:
        ap.error("--scenes and --shard-scenes must be >= 1 and --first-seed >= 0")
    try:  # the benchmark's scenes stay unseen by training
        check_training_seeds(range(args.first_seed, args.first_seed + args.scenes), "--first-seed/--scenes")
    except ValueError as e:
        ap.error(str(e))
    if args.backend == "local" and (args.address is not None or args.num_cpus is not None):
        ap.error("--address and --num-cpus need --backend ray")
    if args.num_cpus is not None and (args.num_cpus < 1 or args.address is not None):
        ap.error("--num-cpus must be >= 1 and sizes a local Ray, not a cluster at --address")
    try:
        cfg = DatasetConfig.from_dict(parse_json_object(args.config, "--config") or {})
        fcfg = FeatureConfig.from_dict(parse_json_object(args.feature_config, "--feature-config") or {})
        wcfg = None
        if args.windows is not None:
            wcfg = WindowConfig.from_dict(parse_json_object(args.windows, "--windows") or {})
    except ValueError as e:
        ap.error(str(e))
    problem = prepare_out_dir(args.out, args.overwrite)
    if problem:
        ap.error(problem)
    write_run_info(args.out, args, config={"dataset": cfg, "features": fcfg}, seed=args.first_seed, argv=argv,
                   script=__file__)
    t0 = time.perf_counter()
    shards, seg_parts, obj_parts = [], [], []
    label_counts = np.zeros(2, np.int64)
    cat_counts = np.zeros(len(CATEGORIES), np.int64)
    n_same = n_seg = n_obj = 0
    n_win = np.zeros(2, np.int64)  # windows: not kin, kin

    def flush(first_seed: int, n_scenes: int) -> None:
        nonlocal seg_parts, obj_parts, n_seg, n_obj
        segs, objs = concat_records(seg_parts), concat_records(obj_parts)
        name = f"shard_{len(shards):05d}.npz"
        digest = write_shard(args.out / name, segs, objs)
        m = int(segs["label"].shape[0])
        shards.append(
            {
                "file": name,
                "first_seed": first_seed,
                "n_scenes": n_scenes,
                "n_segments": m,
                "n_objects": int(objs["row"].shape[0]),
                "sha256": digest,
            }
        )
        n_seg += m
        n_obj += int(objs["row"].shape[0])
        seg_parts, obj_parts = [], []

    shard_first = args.first_seed
    try:  # results stream back in seed order; only a window of scenes is held at a time
        units = imap_seeds(
            scene_unit, range(args.first_seed, args.first_seed + args.scenes), args.backend,
            args=(cfg, fcfg, wcfg), address=args.address, num_cpus=args.num_cpus,
            progress=not args.no_progress, desc="scenes", unit="scene",
        )  # fmt: skip
    except ImportError as e:  # --backend ray without ray installed
        ap.error(str(e))
    for i, (segs, objs) in enumerate(units):
        seed = args.first_seed + i
        seg_parts.append(segs)
        obj_parts.append(objs)
        label_counts += np.bincount(segs["label"], minlength=2)
        cat_counts += np.bincount(segs["category"], minlength=len(CATEGORIES))
        n_same += int(segs["same_radius"].sum())
        if "window" in segs:
            n_win += np.bincount(segs["label"][segs["window"] == 1], minlength=2)
        if len(seg_parts) == args.shard_scenes or i == args.scenes - 1:
            flush(shard_first, len(seg_parts))
            shard_first = seed + 1
    seconds = time.perf_counter() - t0
    manifest = {
        "format": DATASET_FORMAT,
        "format_version": DATASET_FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "feature_config": fcfg.to_dict(),
        "feature_names": feature_names(fcfg),
        "dataset_config": cfg.to_dict(),
        "windows": None if wcfg is None else wcfg.to_dict(),
        "seeds": {"first": args.first_seed, "count": args.scenes},
        "shards": shards,
        "counts": {
            "segments": n_seg,
            "objects": n_obj,
            "kin": int(label_counts[1]),
            "non_kin": int(label_counts[0]),
            "same_radius_cylinder": n_same,
            "windows": int(n_win.sum()),
            "kin_windows": int(n_win[1]),
            "per_category": {c: int(k) for c, k in zip(CATEGORIES, cat_counts, strict=True)},
        },
        "seconds": round(seconds, 2),
        "command": [sys.executable, *sys.argv] if argv is None else ["make_dataset.py", *argv],
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    write_json(args.out / "manifest.json", manifest)  # last: it vouches for the shards above
    script_logger(__file__).info(
        f"{n_seg} segments ({label_counts[1]} kin, {n_same} same-radius cylinder) from {args.scenes} scenes "
        f"in {seconds:.1f} s -> {args.out}"
    )
    return manifest


if __name__ == "__main__":
    run_main(main)
