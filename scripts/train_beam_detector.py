"""Generate per-beam data, train the beam kin detector, calibrate its threshold, write a checkpoint.

Steps (all seeded; every seed is a training seed, disjoint from the evaluation and benchmark seeds):

1. data: ``--scenes`` scenes from ``--first-seed`` (:mod:`kin_envs.detection.beam_dataset`: swarm
   scenes, detection scenes and random arenas, noise 0-2 %, some with beam dropout) written as ``.npz``
   shards + ``manifest.json`` under ``OUT/data`` (or read from ``--data``);
2. training (:mod:`detectors.beam_training`, torch, ``--threads``);
3. threshold: the detection score that maximises F1 on the validation scenes (the last
   ``--val-fraction`` of the scenes; matching within 0.1 m, same-radius cylinders left out);
4. ``OUT/beam.npz`` (the checkpoint), ``OUT/train_log.csv``, ``OUT/run.json``; ``--install`` also
   copies the checkpoint over the shipped ``detectors/checkpoints/beam_default.npz``.

    python scripts/train_beam_detector.py --out outputs/beam_detector --scenes 3000
"""

from __future__ import annotations

import argparse
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from detectors.beam_detector import (
    BEAM_DATASET_FORMAT,
    DEFAULT_BEAM_CHECKPOINT,
    BeamConfig,
    BeamKinDetector,
    group_votes,
    load_beam_dataset,
    save_beam_checkpoint,
)
from detectors.fileio import atomic_write, sha256_file, write_json
from detectors.samples import category_code
from kin_envs.cli import add_logging_args, check_output_dir, parse_json_object, setup_logging
from kin_envs.cli import progress as tqdm
from kin_envs.detection.beam_dataset import BEAM_DATASET_CONFIG, beam_records
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds


def make_data(out: Path, first_seed: int, n_scenes: int, shard_scenes: int, progress: bool) -> dict:
    """Write ``n_scenes`` scenes' beam records as shards, then the manifest (with checksums)."""
    seeds = range(first_seed, first_seed + n_scenes)
    check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
    out.mkdir(parents=True, exist_ok=True)
    shards, parts = [], []
    t0 = time.perf_counter()
    for k, seed in enumerate(tqdm(seeds, desc="scenes", unit="scene", disable=not progress)):
        parts.append(beam_records(seed))
        if len(parts) == shard_scenes or k == n_scenes - 1:
            name = f"shard_{len(shards):05d}.npz"
            rec = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
            with atomic_write(out / name) as f:
                np.savez_compressed(f, angles=_angles(), **rec)
            shards.append(
                {
                    "file": name,
                    "first_seed": int(seed) - len(parts) + 1,
                    "n_scenes": len(parts),
                    "n_scans": int(rec["ranges"].shape[0]),
                    "sha256": sha256_file(out / name),
                }
            )
            parts = []
    manifest = {
        "format": BEAM_DATASET_FORMAT,
        "dataset_config": BEAM_DATASET_CONFIG.to_dict(),
        "seeds": {"first": first_seed, "count": n_scenes},
        "shards": shards,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    write_json(out / "manifest.json", manifest)
    return manifest


def _angles() -> np.ndarray:
    from kin_envs.core.lidar import LidarSpec

    return LidarSpec().angles


def split_rows(records: dict, val_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Training / validation rows, split by scene (the last scenes validate)."""
    seeds = np.unique(records["seed"])
    n_val = max(1, int(round(val_fraction * seeds.size))) if val_fraction > 0 else 0
    val_seeds = seeds[seeds.size - n_val :]
    is_val = np.isin(records["seed"], val_seeds)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def subset(records: dict, rows: np.ndarray) -> dict:
    return {k: (v if k == "angles" else v[rows]) for k, v in records.items()}


def truth_of(records: dict, row: int) -> np.ndarray:
    """Kin centres a scan row sees (>= 1 valid beam): unique per-beam centre targets."""
    c = records["centre"][row][records["label"][row] > 0]
    return np.unique(c, axis=0) if c.size else np.zeros((0, 2))


def score_table(det: BeamKinDetector, records: dict, batch: int = 512) -> dict:
    """Every group (any score) of the validation scans with its match status → arrays for threshold
    calibration: ``score``, ``tp`` (matched), ``same`` (a same-radius cylinder's), and ``n_kin``."""
    scores, tps, sames = [], [], []
    n_kin = 0
    angles = records["angles"]
    same_code = category_code("same_radius_cylinder")
    n = angles.shape[0]
    for s in range(0, records["ranges"].shape[0], batch):
        r = records["ranges"][s : s + batch].astype(np.float64)
        p, cx, cy = det.beam_probabilities(r, angles)
        row, xy, score, beams = group_votes(p, cx, cy, det.config)
        order = np.argsort(-score, kind="stable")  # match best-scored first, like a threshold sweep
        row, xy, score, beams = row[order], xy[order], score[order], beams[order]
        for b in range(r.shape[0]):
            truth = truth_of(records, s + b)
            n_kin += truth.shape[0]
            m = np.flatnonzero(row == b)
            if m.size == 0:
                continue
            # greedy in score order: a detection takes the nearest free kin within the gate
            tp = np.zeros(m.size, bool)
            free = np.ones(truth.shape[0], bool)
            for k, j in enumerate(m):
                if truth.shape[0]:
                    d = np.hypot(*(truth - xy[j]).T)
                    d[~free] = np.inf
                    i = int(np.argmin(d))
                    if d[i] <= 0.1:
                        tp[k], free[i] = True, False
            first, last = beams[m, 0], beams[m, 1]
            cat = records["category"][s + b]
            mid = ((first + ((last - first) % n) // 2) % n).astype(np.int64)
            scores.append(score[m])
            tps.append(tp)
            sames.append(~tp & (cat[mid] == same_code))
    return {
        "score": np.concatenate(scores) if scores else np.zeros(0),
        "tp": np.concatenate(tps) if tps else np.zeros(0, bool),
        "same": np.concatenate(sames) if sames else np.zeros(0, bool),
        "n_kin": n_kin,
    }


def calibrate(table: dict) -> tuple[float, dict]:
    """The score threshold with the best F1 (same-radius false positives left out)."""
    keep = ~table["same"]
    s, tp = table["score"][keep], table["tp"][keep]
    order = np.argsort(-s)
    s, tp = s[order], tp[order]
    ctp = np.cumsum(tp)
    cfp = np.cumsum(~tp)
    fn = table["n_kin"] - ctp
    f1 = 2 * ctp / np.maximum(2 * ctp + cfp + fn, 1)
    k = int(np.argmax(f1))
    thr = float(s[k])
    prec = ctp / np.maximum(ctp + cfp, 1)
    ap = float(np.sum(np.diff(np.concatenate(([0.0], ctp / max(table["n_kin"], 1)))) * prec))
    return thr, {
        "f1": float(f1[k]),
        "precision": float(prec[k]),
        "recall": float(ctp[k] / max(table["n_kin"], 1)),
        "ap": ap,
        "n_kin": int(table["n_kin"]),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("outputs/beam_detector"), help="output directory")
    ap.add_argument(
        "--data", type=Path, default=None, help="existing beam dataset directory (skip generation)"
    )
    ap.add_argument("--scenes", type=int, default=3000, help="scenes to generate (training + validation)")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first scene (a training seed)")
    ap.add_argument("--shard-scenes", type=int, default=500, help="scenes per .npz shard")
    ap.add_argument("--val-fraction", type=float, default=0.1, help="share of the scenes for validation")
    ap.add_argument("--model-config", default=None, help="BeamConfig overrides: JSON object or file")
    ap.add_argument("--config", default=None, help="BeamTrainConfig overrides: JSON object or file")
    ap.add_argument("--seed", type=int, default=0, help="seed of initialisation, subsampling and shuffling")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1: best on a busy machine)")
    ap.add_argument("--install", action="store_true", help="also replace the shipped beam_default.npz")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    try:  # before generating data and training: an unwritable --out must not cost a whole run
        check_output_dir(args.out)
    except ValueError as e:
        ap.error(str(e))
    import torch

    from detectors.beam_training import BeamTrainConfig, beam_training_set, train_beam_model

    torch.set_num_threads(args.threads)
    bcfg = BeamConfig.from_dict(parse_json_object(args.model_config, "--model-config") or {})
    tcfg = BeamTrainConfig.from_dict(parse_json_object(args.config, "--config") or {})
    t0 = time.perf_counter()
    data_dir = args.data or args.out / "data"
    if args.data is None:
        make_data(data_dir, args.first_seed, args.scenes, args.shard_scenes, not args.no_progress)
    t_data = time.perf_counter() - t0
    records, manifest = load_beam_dataset(data_dir)
    check_training_seeds(records["seed"], f"seeds in {data_dir}", within=TRAINING_SEEDS)
    tr, va = split_rows(records, args.val_fraction)
    rng = np.random.default_rng(args.seed)
    x, y, t, w = beam_training_set(subset(records, tr), bcfg, tcfg.easy_keep, rng)
    print(f"{len(x)} training beams ({int(y.sum())} kin) from {tr.size} scans; {va.size} validation scans")
    lines = ["epoch,loss,seconds"]

    def log(h):
        lines.append(f"{h['epoch']},{h['loss']:.6f},{h['seconds']:.1f}")
        if not args.no_progress:
            print(f"epoch {h['epoch']}: loss {h['loss']:.4f} ({h['seconds']:.0f} s)", flush=True)

    t1 = time.perf_counter()
    model, history = train_beam_model(x, y, t, w, bcfg, tcfg, seed=args.seed, log=log)
    t_train = time.perf_counter() - t1
    ckpt = args.out / "beam.npz"
    info = {
        "dataset": manifest.get("seeds"),
        "train_config": tcfg.to_dict(),
        "seed": args.seed,
        "train_seconds": round(t_train, 1),
        "torch_threads": args.threads,
    }
    save_beam_checkpoint(ckpt, model, threshold=0.5, info=info)
    val = {}
    if va.size:
        det = BeamKinDetector(ckpt)
        thr, val = calibrate(score_table(det, subset(records, va)))
        info["validation"] = val
        save_beam_checkpoint(ckpt, model, threshold=thr, info=info)
        print(
            f"validation: threshold {thr:.3f}, F1 {val['f1']:.3f} (P {val['precision']:.3f} / R "
            f"{val['recall']:.3f}), AP {val['ap']:.3f}"
        )
    with atomic_write(args.out / "train_log.csv", "w") as f:
        f.write("\n".join(lines) + "\n")
    if args.install:
        shutil.copyfile(ckpt, DEFAULT_BEAM_CHECKPOINT)
    run = {
        "command": [sys.executable, *sys.argv] if argv is None else ["train_beam_detector.py", *argv],
        "model_config": bcfg.to_dict(),
        "train_config": tcfg.to_dict(),
        "seed": args.seed,
        "data": str(data_dir),
        "data_seconds": round(t_data, 1),
        "train_seconds": round(t_train, 1),
        "epochs": len(history),
        "validation": val,
        "checkpoint": str(ckpt),
        "sha256": sha256_file(ckpt),
        "installed": bool(args.install),
        "python": platform.python_version(),
        "torch": torch.__version__,
    }
    write_json(args.out / "run.json", run)
    return run


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)  # Ctrl-C: exit 130 with one line; bad input: one line, exit 2
