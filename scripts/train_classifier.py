"""Train the learned kin detector's segment classifier and evaluate it against the geometric detector.

Steps (all seeded by ``--seed``):

1. load a dataset written by ``scripts/make_dataset.py`` (its feature version must be this code's);
2. split it **by scene** into training and validation scenes; same-radius cylinders are left out of
   training (one scan cannot tell them from a kin: identical inputs with opposite labels);
3. train ``detectors.learned.SegmentNet`` (classification + centre regression) with early stopping on
   the validation loss; one CSV row per epoch (``train_log.csv``); candidate windows of datasets written
   with ``make_dataset.py --windows`` train with the segments (kin windows weighted ``--window-kin-weight``)
   but are left out of the segment thresholds and metrics: their own thresholds are calibrated apart
   (``window_validation.json``, checkpoint info ``window_thresholds``; README, "Issue 11, round 6");
4. the checkpoint's threshold: ``--threshold`` (0.5), or with ``--calibrate`` one per estimated
   scan-noise level (``--calib-noise-edges``; :func:`detectors.features.scan_noise`), the one with
   the best segment F1 on the validation scenes' detection scenes; validation metrics from the
   dataset with it: segment level and kin level (``validation.json``);
5. held-out sweep (``--eval-scenes`` > 0): new detection scenes with seeds from ``--eval-first-seed``
   (disjoint from training), every noise level of ``--eval-noise``, scanned from every robot; the
   learned detector (both positioning options) and the geometric detector run on the same scans;
   kin-level precision / recall / F1 per distance bin x noise level, same-radius cylinders apart,
   false positives per distractor kind, centre errors, throughput (``eval.json``, ``eval.md``);
6. the checkpoint (``--checkpoint``, default ``OUT/learned.pt``; positioning: the better option on the
   sweep, or ``--positioning``), its torch-free form ``<checkpoint>.npz`` (what ``LearnedKinDetector``
   reads; ``detectors.learned_torch.save_checkpoint``) and ``<checkpoint>.json`` next to it (command,
   configs, data, training and evaluation summary); ``run.json`` in ``--out``.

Everything goes to ``--out`` (default ``outputs/train_classifier``). The shipped model
(``detectors/checkpoints/learned_default.pt``) is replaced only with ``--replace-shipped``; any other
``--checkpoint`` inside ``detectors/checkpoints/`` is refused.

Example (the shipped model: train, compare, then replace it on purpose)::

    python scripts/make_dataset.py --out outputs/segments --scenes 3000
    python scripts/train_classifier.py --data outputs/segments --out outputs/train --eval-scenes 300
    python scripts/train_classifier.py --data outputs/segments --out outputs/train --eval-scenes 300 \\
        --replace-shipped
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

import detectors
from detectors.features import feature_names, observer_to_local
from detectors.fileio import LiveLog, write_json, write_text
from detectors.geometric import GeometricKinDetector
from kin_envs import World, scenes
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    noise_level,
    parse_json_object,
    script_logger,
    setup_logging,
    write_run_info,
)
from kin_envs.cli import progress as tqdm
from kin_envs.detection.dataset import (
    CATEGORIES,
    DatasetConfig,
    concat_records,
    label_scan,
    load_dataset,
    make_scene,
)

GATE = 0.1  # m: a detection matches a kin whose centre is this close
DISTANCE_BINS = (0.2, 0.3, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
EVAL_NOISE = (0.0, 0.005, 0.01, 0.02)
#: the sweep's scenes: kin.scenes.detection_scene with its default layout (3 kin, 12 distractors, 0.3-3 m)
EVAL_CONFIG = DatasetConfig(
    detection_prob=1.0, open_prob=0.0, n_kin=(3, 3), n_distractors=(12, 12), distance=(0.3, 3.0)
)
_KIN, _SAME = CATEGORIES.index("kin"), CATEGORIES.index("same_radius_cylinder")
#: the shipped model; the folder is written only with --replace-shipped (torch-free: no detectors.learned)
SHIPPED_DIR = Path(detectors.__file__).resolve().parent / "checkpoints"
SHIPPED_CHECKPOINT = SHIPPED_DIR / "learned_default.pt"
logger = script_logger(__file__)


def checkpoint_path(out: Path, checkpoint: Path | None, replace_shipped: bool) -> Path:
    """Where the checkpoint goes: ``--checkpoint``, else ``OUT/learned.pt``; the shipped model's folder
    only with ``--replace-shipped`` (``ValueError`` otherwise, before any work)."""
    if replace_shipped:
        if checkpoint is not None and checkpoint.resolve() != SHIPPED_CHECKPOINT:
            raise ValueError(f"--replace-shipped writes {SHIPPED_CHECKPOINT}; do not also give --checkpoint "
                             f"{checkpoint}")
        return SHIPPED_CHECKPOINT
    ckpt = checkpoint if checkpoint is not None else out / "learned.pt"
    if ckpt.suffix == ".npz":
        raise ValueError(f"--checkpoint {ckpt}: give the .pt path (its torch-free .npz form is written "
                         "beside it)")  # fmt: skip
    if ckpt.resolve().parent == SHIPPED_DIR:
        raise ValueError(f"--checkpoint {ckpt} is in the shipped models' folder {SHIPPED_DIR}: write it "
                         "elsewhere (default: OUT/learned.pt), or pass --replace-shipped to replace the "
                         "shipped model on purpose")
    return ckpt


def prf(tp: float, fp: float, fn: float) -> dict:
    p = tp / (tp + fp) if tp + fp else float("nan")
    r = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    return {"tp": int(tp), "fp": int(fp), "fn": int(fn), "precision": p, "recall": r, "f1": f1}


def bin_label(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g}"


def bin_index(d: np.ndarray) -> np.ndarray:
    """Distance bin of each value (-1 outside :data:`DISTANCE_BINS`)."""
    k = np.searchsorted(DISTANCE_BINS, d, side="right") - 1
    return np.where((k >= 0) & (k < len(DISTANCE_BINS) - 1), k, -1)


# --------------------------------------------------------------------------- data


def split_by_scene(seeds: np.ndarray, val_fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean mask of rows whose scene is a validation scene."""
    uniq = np.unique(seeds)
    n_val = max(1, int(round(val_fraction * len(uniq))))
    if n_val >= len(uniq):
        raise SystemExit(f"--val-fraction {val_fraction} leaves no training scene out of {len(uniq)}")
    return np.isin(seeds, rng.choice(uniq, n_val, replace=False))


def few_beam_labels(label: np.ndarray, n_beams: np.ndarray, min_kin_beams: int) -> np.ndarray:
    """``label`` with kin segments of fewer than ``min_kin_beams`` beams made non-kin (the benchmark
    counts a kin from 2 valid beams: a 1-beam detection can never be a true positive there)."""
    return np.where(np.asarray(n_beams) < min_kin_beams, 0, label).astype(np.asarray(label).dtype)


def focus_weights(weight, n_beams, range_min, factor: float, beams, range_m) -> np.ndarray:
    """``weight`` times ``factor`` for every segment with ``beams[0] <= n_beams <= beams[1]`` whose
    nearest reading lies in ``[range_m[0], range_m[1])`` (kin and look-alikes alike: capacity for the
    few-beam regime, not a shifted threshold)."""
    n, r = np.asarray(n_beams), np.asarray(range_min)
    focus = (n >= beams[0]) & (n <= beams[1]) & (r >= range_m[0]) & (r < range_m[1])
    return np.where(focus, np.asarray(weight) * factor, weight).astype(np.float32)


def targets(segs: dict) -> np.ndarray:
    """Kin centres in each segment's local frame (NaN for non-kin)."""
    return observer_to_local(segs["frames"].astype(np.float64), segs["centre"].astype(np.float64)).astype(
        np.float32
    )


def predict(model, x: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``p(kin)`` and regressed centres (observer frame) of dataset rows."""
    import torch

    from detectors.features import local_to_observer

    with torch.inference_mode():
        out = torch.cat([model(c) for c in torch.from_numpy(x).split(8192)]).numpy().astype(np.float64)
    nrm = model.normalisation()
    uv = np.asarray(nrm["t_mean"]) + np.asarray(nrm["t_std"]) * out[:, 1:3]
    return 1.0 / (1.0 + np.exp(-out[:, 0])), local_to_observer(frames.astype(np.float64), uv)


CALIB_NOISE_EDGES = (0.0015, 0.004, 0.0075, 0.015)
_CALIB_GRID = np.round(np.arange(0.2, 0.91, 0.01), 2)
_CALIB_MIN_KIN = 200  # kin segments a noise bin needs for its own threshold (else 0.5)


def scan_noise_of(x: np.ndarray, fcfg) -> np.ndarray:
    """The scan-noise estimate of each segment's scan, from its feature vector."""
    return np.exp(x[:, feature_names(fcfg).index("log_scan_noise")].astype(np.float64)) - 1e-4


def calibrate_thresholds(p, y, sigma, edges) -> dict:
    """Per noise bin (``sigma`` binned by ``edges``), the grid threshold with the best segment F1
    (every non-kin segment given is a negative; the caller chooses which segments to pass)."""
    edges = [float(e) for e in edges]
    b = np.searchsorted(np.asarray(edges), sigma, side="right")
    values, info = [], []
    for k in range(len(edges) + 1):
        m = b == k
        pk, yk = p[m], y[m]
        n_kin = int(yk.sum())
        if n_kin < _CALIB_MIN_KIN:
            values.append(0.5)
            info.append({"segments": int(m.sum()), "kin": n_kin, "f1": None, "f1_at_0.5": None})
            continue
        acc = pk[None, :] >= _CALIB_GRID[:, None]
        tp = (acc & yk).sum(1)
        f1 = 2 * tp / (acc.sum(1) + n_kin)
        j = int(np.argmax(f1))
        values.append(float(_CALIB_GRID[j]))
        f05 = float(f1[int(np.argmin(np.abs(_CALIB_GRID - 0.5)))])
        info.append({"segments": int(m.sum()), "kin": n_kin, "f1": float(f1[j]), "f1_at_0.5": f05})
    return {"noise_edges": edges, "values": values, "info": info}


_WINDOW_GRID = np.round(np.arange(0.2, 0.9951, 0.005), 3)
_WINDOW_MIN_KIN = 50  # kin windows a noise bin needs for its own threshold (else the pooled one)


def _one_window_config(manifests) -> dict | None:
    """The window config the datasets' candidate windows were cut with, if they name one (else None)."""
    named = [m["windows"] for m in manifests if m.get("windows") is not None]
    return named[0] if named and all(w == named[0] for w in named) else None


def calibrate_window_thresholds(p, y, sigma, edges) -> dict:
    """The candidate windows' own ``p(kin)`` thresholds (issue 11, round 6): per scan-noise bin the grid
    value with the best window F1 (kin windows found against windows accepted), the pooled one where a
    bin has fewer than :data:`_WINDOW_MIN_KIN` kin windows. A window is accepted at ``max(segment
    threshold, window threshold)``."""
    def best(pk, yk):
        acc = pk[None, :] >= _WINDOW_GRID[:, None]
        f1 = 2 * (acc & yk).sum(1) / np.maximum(acc.sum(1) + yk.sum(), 1)
        j = int(np.argmax(f1))
        return float(_WINDOW_GRID[j]), float(f1[j])

    edges = [float(e) for e in edges]
    pooled, f_pooled = best(p, y)
    b = np.searchsorted(np.asarray(edges), sigma, side="right")
    values, info = [], []
    for k in range(len(edges) + 1):
        m = b == k
        n_kin = int(y[m].sum())
        v, f = best(p[m], y[m]) if n_kin >= _WINDOW_MIN_KIN else (pooled, None)
        values.append(v)
        info.append({"windows": int(m.sum()), "kin": n_kin, "f1": f})
    return {"noise_edges": edges, "values": values, "pooled": pooled, "pooled_f1": f_pooled,
            "windows": int(y.size), "kin": int(y.sum()), "info": info}  # fmt: skip


def validation_metrics(segs: dict, objs: dict, p: np.ndarray, xy: np.ndarray, thr) -> dict:
    """Segment-level and kin-level metrics on the validation scenes of the dataset (``thr``: one
    threshold or one per segment)."""
    acc = p >= thr
    y = segs["label"] == 1
    same = segs["same_radius"]
    out = {"segments": prf((acc & y & ~same).sum(), (acc & ~y & ~same).sum(), (~acc & y).sum())}
    out["segments"]["accepted_per_category"] = {
        c: float(acc[segs["category"] == k].mean())
        for k, c in enumerate(CATEGORIES)
        if (segs["category"] == k).any()
    }
    err = np.hypot(*(xy - segs["centre"]).T)
    hit = acc & y & (err <= GATE)
    # kin level: a visible kin is found if one of its (majority) segments is accepted within the gate
    kin = objs["category"] == _KIN
    key = lambda s, o, i: (s.astype(np.int64) * 1000 + o) * 10000 + i  # noqa: E731
    found = np.isin(
        key(objs["seed"], objs["observer"], objs["obj_index"])[kin],
        key(segs["seed"], segs["observer"], segs["obj_index"])[hit],
    )
    fp = (acc & ~hit & ~same).sum()
    out["kin"] = prf(found.sum(), fp, (~found).sum())
    out["centre_error_m"] = {
        "median": float(np.median(err[hit])) if hit.any() else None,
        "p90": float(np.percentile(err[hit], 90)) if hit.any() else None,
    }
    out["threshold"] = thr if np.isscalar(thr) else "calibrated per noise level"
    return out


# --------------------------------------------------------------------------- held-out sweep


def match(det_xy: np.ndarray, truth_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Greedy one-to-one matching within :data:`GATE`, nearest pairs first.

    Returns ``(det_to_truth (k,), error (k,))`` with -1 / NaN for unmatched detections.
    """
    k, m = det_xy.shape[0], truth_xy.shape[0]
    d2t, err = np.full(k, -1), np.full(k, np.nan)
    if k == 0 or m == 0:
        return d2t, err
    dist = np.hypot(det_xy[:, None, 0] - truth_xy[None, :, 0], det_xy[:, None, 1] - truth_xy[None, :, 1])
    used = np.zeros(m, bool)
    for flat in np.argsort(dist, axis=None):
        i, j = divmod(int(flat), m)
        if dist[i, j] > GATE:
            break
        if d2t[i] < 0 and not used[j]:
            d2t[i], err[i], used[j] = j, dist[i, j], True
    return d2t, err


class Tally:
    """Counts per (detector, noise, distance bin) for the sweep tables."""

    def __init__(self, names):
        shape = (len(names), len(EVAL_NOISE), len(DISTANCE_BINS) - 1)
        self.names = list(names)
        self.c = {
            k: np.zeros(shape, np.int64)
            for k in ("tp", "fp", "fn", "tp2", "fp2", "fn2", "same_seen", "same_detected")
        }
        self.fp_cat = np.zeros((len(names), len(EVAL_NOISE), len(CATEGORIES)), np.int64)
        self.errors = {n: [[] for _ in EVAL_NOISE] for n in names}

    def add(self, name: str, ni: int, dets, objs_row: dict, seg_cat: dict) -> None:
        di = self.names.index(name)
        det_xy = np.array([(d.x, d.y) for d in dets]).reshape(-1, 2)
        det_rng = np.array([d.range for d in dets])
        kin = objs_row["category"] == _KIN
        same = objs_row["category"] == _SAME
        truth = np.concatenate(
            [
                np.stack([objs_row["x"][kin], objs_row["y"][kin]], 1),
                np.stack([objs_row["x"][same], objs_row["y"][same]], 1),
            ]
        )
        n_kin = int(kin.sum())
        kin_dist, kin_beams = objs_row["distance"][kin], objs_row["n_beams"][kin]
        d2t, err = match(det_xy, truth)
        c = self.c
        for j, (dist, nb) in enumerate(zip(kin_dist, kin_beams, strict=True)):
            b = bin_index(np.array([dist]))[0]
            if b < 0:
                continue
            found = bool((d2t == j).any())
            c["tp" if found else "fn"][di, ni, b] += 1
            if nb >= 2:
                c["tp2" if found else "fn2"][di, ni, b] += 1
        for j, dist in enumerate(objs_row["distance"][same]):
            b = bin_index(np.array([dist]))[0]
            if b >= 0:
                c["same_seen"][di, ni, b] += 1
                c["same_detected"][di, ni, b] += int((d2t == n_kin + j).any())
        fp = d2t < 0
        for i in np.flatnonzero(fp):
            b = bin_index(det_rng[i : i + 1])[0]
            if b >= 0:
                c["fp"][di, ni, b] += 1
                c["fp2"][di, ni, b] += 1
            self.fp_cat[di, ni, seg_cat.get(dets[i].first_beam, CATEGORIES.index("boundary"))] += 1
        self.errors[name][ni] += err[(d2t >= 0) & (d2t < n_kin)].tolist()

    def table(self, name: str, ge2: bool) -> list[dict]:
        di = self.names.index(name)
        s = "2" if ge2 else ""
        rows = []
        for ni, nz in enumerate(EVAL_NOISE):
            for b in range(len(DISTANCE_BINS) - 1):
                r = prf(self.c["tp" + s][di, ni, b], self.c["fp" + s][di, ni, b], self.c["fn" + s][di, ni, b])
                rows.append({"noise": nz, "bin": bin_label(DISTANCE_BINS[b], DISTANCE_BINS[b + 1]), **r})
        return rows

    def pooled(self, name: str, ni: int, lo: float, hi: float, ge2: bool = False) -> dict:
        di = self.names.index(name)
        s = "2" if ge2 else ""
        sel = [
            b for b in range(len(DISTANCE_BINS) - 1) if DISTANCE_BINS[b] >= lo and DISTANCE_BINS[b + 1] <= hi
        ]
        return prf(*(int(self.c[k + s][di, ni, sel].sum()) for k in ("tp", "fp", "fn")))


def sweep(detectors: dict, n_scenes: int, first_seed: int, progress: bool) -> Tally:
    """Run every detector on the same held-out scans (see the module docstring)."""
    tally = Tally(detectors)
    jobs = [(ni, nz, first_seed + i) for ni, nz in enumerate(EVAL_NOISE) for i in range(n_scenes)]
    for ni, nz, seed in tqdm(jobs, desc="held-out sweep", disable=not progress):
        scene, rng, info = make_scene(seed, EVAL_CONFIG, noise=nz)
        world = World(scene, seed=rng)
        scan = world.scan(robots=info["observers"])
        from detectors.features import segment_batch

        batch = segment_batch(scan.ranges, scan.angles)
        segs, objs = label_scan(scan, scene, batch, world.poses)
        for name, det in detectors.items():
            results = det.detect_batch(scan.ranges, scan.angles)
            for row, res in enumerate(results):
                in_row = objs["row"] == row
                o = {k: v[in_row] for k, v in objs.items()}
                srow = segs["row"] == row
                seg_cat = dict(zip(batch.first[srow].tolist(), segs["category"][srow].tolist(), strict=True))
                tally.add(name, ni, res.detections, o, seg_cat)
    return tally


def throughput(det, n_rep: int = 5) -> float:
    """Scans/s of ``detect_batch`` on 256 cluttered scans (as ``scripts/benchmark.py``)."""
    scan = World(scenes.random_arena(64, 50, seed=1), seed=0).scan()
    ranges = np.tile(scan.ranges.astype(np.float64), (4, 1))
    det.detect_batch(ranges, scan.angles)
    best = math.inf
    for _ in range(n_rep):
        t0 = time.perf_counter()
        det.detect_batch(ranges, scan.angles)
        best = min(best, time.perf_counter() - t0)
    return ranges.shape[0] / best


def fmt(v) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"


def markdown(ev: dict) -> str:
    names = ev["detectors"]
    lines = [
        "# Held-out sweep",
        "",
        f"Scenes per noise level: {ev['scenes_per_noise']} (seeds from "
        f"{ev['first_seed']}), scanned from every robot; a detection matches a kin within {GATE} m.",
        "",
    ]
    for title, key in (("All visible kin (>= 1 beam)", "table"), ("Kin hit by >= 2 beams", "table_ge2")):
        lines += [
            f"## {title}: F1 / precision / recall",
            "",
            "| noise | distance m | " + " | ".join(names) + " |",
            "|---|---|" + "---|" * len(names),
        ]
        rows = {n: ev[key][n] for n in names}
        for k in range(len(rows[names[0]])):
            r0 = rows[names[0]][k]
            cells = [
                f"{fmt(rows[n][k]['f1'])} / {fmt(rows[n][k]['precision'])} / {fmt(rows[n][k]['recall'])}"
                for n in names
            ]
            lines.append(f"| {r0['noise']:g} | {r0['bin']} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += [
        "## Same-radius cylinders (reported apart): fraction detected as kin",
        "",
        "| noise | distance m | seen | " + " | ".join(names) + " |",
        "|---|---|---|" + "---|" * len(names),
    ]
    for r in ev["same_radius"]:
        lines.append(
            f"| {r['noise']:g} | {r['bin']} | {r['seen']} | " + " | ".join(fmt(r[n]) for n in names) + " |"
        )
    lines += [
        "",
        "## False positives per distractor kind (all noise levels)",
        "",
        "| kind | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for c in CATEGORIES:
        if any(ev["fp_per_category"][n].get(c, 0) for n in names):
            lines.append(
                f"| {c} | " + " | ".join(str(ev["fp_per_category"][n].get(c, 0)) for n in names) + " |"
            )
    lines += [
        "",
        "## Centre error of matched kin, m (median / p90)",
        "",
        "| noise | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for ni, nz in enumerate(EVAL_NOISE):
        lines.append(
            f"| {nz:g} | "
            + " | ".join(
                f"{fmt(ev['centre_error'][n][ni]['median'])} / {fmt(ev['centre_error'][n][ni]['p90'])}"
                for n in names
            )
            + " |"
        )
    lines += ["", "## Targets", "", "```", json.dumps(ev["targets"], indent=2), "```", ""]
    return "\n".join(lines)


def evaluate(ckpt: Path, args, progress: bool) -> dict:
    from detectors.learned import LearnedKinDetector

    dets = {
        "learned": LearnedKinDetector(ckpt, args.threshold, positioning="regression", reports=False),
        "learned_fit": LearnedKinDetector(ckpt, args.threshold, positioning="fit", reports=False),
        "geometric": GeometricKinDetector(reports=False),
    }
    t0 = time.perf_counter()
    tally = sweep(dets, args.eval_scenes, args.eval_first_seed, progress)
    names = list(dets)
    ev = {
        "detectors": names,
        "scenes_per_noise": args.eval_scenes,
        "first_seed": args.eval_first_seed,
        "scene_config": EVAL_CONFIG.to_dict(),
        "gate_m": GATE,
        "threshold": "calibrated" if args.threshold is None else args.threshold,
        "table": {n: tally.table(n, False) for n in names},
        "table_ge2": {n: tally.table(n, True) for n in names},
    }
    ev["same_radius"] = []
    for ni, nz in enumerate(EVAL_NOISE):
        for b in range(len(DISTANCE_BINS) - 1):
            seen = int(tally.c["same_seen"][0, ni, b])
            row = {"noise": nz, "bin": bin_label(DISTANCE_BINS[b], DISTANCE_BINS[b + 1]), "seen": seen}
            for di, n in enumerate(names):
                row[n] = tally.c["same_detected"][di, ni, b] / seen if seen else float("nan")
            ev["same_radius"].append(row)
    ev["fp_per_category"] = {
        n: {c: int(tally.fp_cat[di, :, k].sum()) for k, c in enumerate(CATEGORIES)}
        for di, n in enumerate(names)
    }
    ev["centre_error"] = {
        n: [
            {
                "median": float(np.median(e)) if e else None,
                "p90": float(np.percentile(e, 90)) if e else None,
                "mean": float(np.mean(e)) if e else None,
                "n": len(e),
            }
            for e in tally.errors[n]
        ]
        for n in names
    }
    all_err = {
        n: np.concatenate([np.asarray(e, float) for e in tally.errors[n]]) for n in ("learned", "learned_fit")
    }
    # the better positioning: lower mean centre error over every matched kin of the sweep (same
    # classification, so the same segments up to gate effects), F1 as tie-break
    ni1 = EVAL_NOISE.index(0.01)
    f1 = {n: tally.pooled(n, ni1, 0.3, 2.0)["f1"] for n in names}
    mean_err = {n: float(all_err[n].mean()) if all_err[n].size else math.inf for n in all_err}
    ev["positioning"] = {
        "mean_error_m": {"regression": mean_err["learned"], "fit": mean_err["learned_fit"]},
        "f1_1pct_0.3_2m": {"regression": f1["learned"], "fit": f1["learned_fit"]},
        "better": "regression"
        if (mean_err["learned"], -f1["learned"]) <= (mean_err["learned_fit"], -f1["learned_fit"])
        else "fit",
    }
    failing = []
    for ni, nz in enumerate(EVAL_NOISE):
        for b in range(len(DISTANCE_BINS) - 1):
            if DISTANCE_BINS[b] < 0.3 or DISTANCE_BINS[b + 1] > 3.0:
                continue
            lf = ev["table_ge2"]["learned"][ni * (len(DISTANCE_BINS) - 1) + b]["f1"]
            gf = ev["table_ge2"]["geometric"][ni * (len(DISTANCE_BINS) - 1) + b]["f1"]
            if not (lf > gf) and not (math.isnan(gf) and not math.isnan(lf)):
                failing.append(
                    {
                        "noise": nz,
                        "bin": bin_label(DISTANCE_BINS[b], DISTANCE_BINS[b + 1]),
                        "learned_f1": lf,
                        "geometric_f1": gf,
                    }
                )
    ev["targets"] = {
        "learned_f1_1pct_noise_0.3_2m": tally.pooled("learned", ni1, 0.3, 2.0),
        "geometric_f1_1pct_noise_0.3_2m": tally.pooled("geometric", ni1, 0.3, 2.0),
        "bins_where_learned_not_above_geometric_ge2_beams": failing,
        "learned_scans_per_s": throughput(LearnedKinDetector(ckpt, args.threshold)),
        "learned_scans_per_s_no_reports": throughput(dets["learned"]),
        "geometric_scans_per_s": throughput(GeometricKinDetector()),
    }
    ev["seconds"] = time.perf_counter() - t0
    return ev


# --------------------------------------------------------------------------- main


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, type=Path, nargs="+",
                    help="dataset directory or directories (scripts/make_dataset.py; same feature config, "
                    "disjoint seeds), concatenated")
    ap.add_argument("--keep-easy", type=float, default=1.0,
                    help="keep this random fraction of the arena-boundary and wall segments in training, "
                    "each weighted 1 / fraction (they are most of the data and the easiest negatives: a "
                    "smaller share trains faster at the same expected loss); validation keeps them all")
    ap.add_argument("--min-kin-beams", type=int, default=1,
                    help="kin segments with fewer beams are trained as non-kin (2: the benchmark's "
                    "ground-truth rule, a kin counts with >= 2 valid beams: a 1-beam detection is never a "
                    "true positive)")
    ap.add_argument("--window-kin-weight", type=float, default=1.0,
                    help="loss weight factor of the kin candidate windows (rows with window = 1, written by "
                    "make_dataset.py --windows; ~2 %% of the windows are kin); their threshold is calibrated "
                    "apart from the segments' (checkpoint info window_thresholds)")
    ap.add_argument("--no-windows", action="store_true",
                    help="leave the datasets' candidate windows out (segments only, as before round 6)")
    ap.add_argument("--focus-weight", type=float, default=1.0,
                    help="loss weight of every segment (kin and not) with --focus-beams beams whose nearest "
                    "reading is in --focus-range: training capacity spent on the few-beam regime")
    ap.add_argument("--focus-beams", type=int, nargs=2, default=[2, 3], metavar=("MIN", "MAX"),
                    help="beam-count range of --focus-weight (inclusive)")
    ap.add_argument("--focus-range", type=float, nargs=2, default=[1.0, 2.0], metavar=("MIN", "MAX"),
                    help="nearest-reading range of --focus-weight, m")
    ap.add_argument("--out", type=Path, default=Path("outputs/train_classifier"),
                    help="output directory for the checkpoint, logs and evaluation (default: %(default)s)")
    ap.add_argument("--checkpoint", type=Path, default=None,
                    help="checkpoint path (default: OUT/learned.pt; not inside detectors/checkpoints/)")
    ap.add_argument("--replace-shipped", action="store_true",
                    help=f"write the checkpoint over the shipped model {SHIPPED_CHECKPOINT.name} "
                    "(detectors/checkpoints/), which the learned detector loads by default; its cascade "
                    "(learned_default.cascade.json) is tied to the old weights and stays off until "
                    "refitted: scripts/fit_cascade.py --replace-shipped")
    ap.add_argument("--seed", type=int, default=0, help="seed of the split, initialisation and shuffling")
    ap.add_argument("--config", default=None, help="TrainConfig overrides: JSON object or file")
    ap.add_argument("--val-fraction", type=float, default=0.15, help="fraction of scenes for validation")
    ap.add_argument(
        "--threshold", type=float, default=0.5, help="p(kin) threshold for the checkpoint and metrics"
    )
    ap.add_argument(
        "--calibrate",
        action="store_true",
        help="instead of --threshold: one threshold per scan-noise level, chosen on the validation scenes",
    )
    ap.add_argument(
        "--calib-noise-edges",
        type=noise_level,
        nargs="*",
        default=list(CALIB_NOISE_EDGES),
        help="scan-noise bin edges of the threshold calibration (relative sigma)",
    )
    ap.add_argument(
        "--calib-families", type=int, nargs="+", default=[0, 2, 3, 4, 5],
        help="scene families whose validation segments choose the thresholds (0 detection scene, 1 random "
        "arena, 2 open detection scene, 3 swarm scene, 4 / 5 the benchmark's swarm / lookalike generators)",
    )
    ap.add_argument(
        "--calib-same-radius", choices=("apart", "negative"), default="apart",
        help="same-radius cylinder segments in the calibration: left out, as the benchmark counts them apart "
        "(apart), or negatives (the previous rule)",
    )
    ap.add_argument(
        "--positioning",
        choices=("auto", "regression", "fit"),
        default="auto",
        help="positioning stored in the checkpoint (auto: the better on the sweep)",
    )
    ap.add_argument(
        "--eval-scenes", type=int, default=0, help="held-out scenes per noise level (0: no sweep)"
    )
    ap.add_argument("--eval-first-seed", type=int, default=1_000_000, help="first seed of the held-out sweep")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1: best on a busy machine)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    if not 0 < args.val_fraction < 1:
        ap.error(f"--val-fraction must be in (0, 1), got {args.val_fraction}")
    if not 0 < args.keep_easy <= 1:
        ap.error(f"--keep-easy must be in (0, 1], got {args.keep_easy}")
    if not (math.isfinite(args.window_kin_weight) and args.window_kin_weight > 0):
        ap.error(f"--window-kin-weight must be > 0, got {args.window_kin_weight}")
    if args.min_kin_beams < 1 or not (math.isfinite(args.focus_weight) and args.focus_weight > 0):
        ap.error(f"--min-kin-beams must be >= 1 and --focus-weight > 0, got {args.min_kin_beams}, "
                 f"{args.focus_weight}")
    if args.eval_scenes < 0 or args.threads < 1:
        ap.error("--eval-scenes must be >= 0 and --threads >= 1")
    try:
        ckpt = checkpoint_path(args.out, args.checkpoint, args.replace_shipped)
    except ValueError as e:
        ap.error(str(e))
    import torch

    from detectors.learned import TrainConfig, npz_path, sample_weights
    from detectors.learned_torch import save_checkpoint, train_segment_net

    try:
        tcfg = TrainConfig.from_dict(parse_json_object(args.config, "--config") or {})
    except ValueError as e:
        ap.error(str(e))
    try:  # before loading and training: an unwritable --out / --checkpoint must not cost a run
        check_output_dir(args.out)
        if args.checkpoint is not None:
            if args.checkpoint.is_dir():
                raise ValueError(f"--checkpoint {args.checkpoint} is a directory; expected a file path")
            check_output_dir(args.checkpoint.parent, "--checkpoint's directory")
    except ValueError as e:
        ap.error(str(e))
    torch.set_num_threads(args.threads)
    progress = not args.no_progress
    command = [sys.executable, *sys.argv] if argv is None else ["train_classifier.py", *map(str, argv)]
    write_run_info(args.out, args, config=tcfg, seed=args.seed,
                   argv=argv, script=__file__, checkpoint=ckpt)
    t_start = time.perf_counter()

    try:
        segs, objs, manifest, manifests = load_datasets(args.data)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(f"train_classifier.py: {e}") from None
    fcfg = _feature_config(manifest)
    if args.no_windows:
        segs = {k: v[segs["window"] == 0] for k, v in segs.items()}
    win = segs["window"] == 1
    rng = np.random.default_rng(args.seed)
    is_val = split_by_scene(segs["seed"], args.val_fraction, rng)
    tgt = targets(segs)
    keep = ~segs["same_radius"]  # indistinguishable from kin in one scan: not a training negative

    segs["label"] = few_beam_labels(segs["label"], segs["n_beams"], args.min_kin_beams)
    weight = focus_weights(sample_weights(segs["label"], segs["category"], tcfg), segs["n_beams"],
                           segs["range_min"], args.focus_weight, args.focus_beams, args.focus_range)
    weight = np.where(win & (segs["label"] == 1), weight * args.window_kin_weight, weight).astype(np.float32)
    if args.keep_easy < 1:  # a share of the easy negatives, up-weighted (validation keeps them all)
        easy = np.isin(segs["category"], [CATEGORIES.index("boundary"), CATEGORIES.index("wall")])
        drop = easy & ~is_val & (rng.random(easy.shape[0]) >= args.keep_easy)
        keep &= ~drop
        weight = np.where(easy & ~is_val, weight / args.keep_easy, weight).astype(np.float32)

    def part(m):
        return {"x": segs["x"][m], "y": segs["label"][m], "target": tgt[m], "weight": weight[m]}

    log_path = args.out / "train_log.csv"
    with LiveLog(log_path) as f:  # flushed per row; whole rows only, even after Ctrl-C
        writer = None

        def log(rec):
            nonlocal writer
            if writer is None:
                writer = csv.DictWriter(f, fieldnames=list(rec))
                writer.writeheader()
            writer.writerow(rec)

        t0 = time.perf_counter()
        model, history = train_segment_net(
            part(keep & ~is_val), part(keep & is_val), tcfg, args.seed, log, progress
        )
        train_seconds = time.perf_counter() - t0

    val_seeds = np.unique(segs["seed"][is_val])
    vw = {k: v[is_val & win] for k, v in segs.items()}  # the validation scenes' windows
    vs = {k: v[is_val & ~win] for k, v in segs.items()}
    vo = {k: v[np.isin(objs["seed"], val_seeds)] for k, v in objs.items()}
    p, xy = predict(model, vs["x"], vs["frames"])
    sigma = scan_noise_of(vs["x"], fcfg)
    if args.calibrate:
        args.threshold = None  # the detectors of the sweep use the checkpoint's thresholds
        detection = np.isin(vs["family"], args.calib_families)
        if args.calib_same_radius == "apart":  # as the benchmark: not a false positive
            detection &= ~vs["same_radius"]
        thresholds = calibrate_thresholds(
            p[detection], vs["label"][detection] == 1, sigma[detection], sorted(args.calib_noise_edges)
        )
    else:
        thresholds = {"noise_edges": [], "values": [args.threshold]}
    window_thresholds = None
    if vw["label"].size:
        pw, _ = predict(model, vw["x"], vw["frames"])
        cal = np.isin(vw["family"], args.calib_families) & ~vw["same_radius"]
        window_thresholds = calibrate_window_thresholds(
            pw[cal], vw["label"][cal] == 1, scan_noise_of(vw["x"][cal], fcfg), sorted(args.calib_noise_edges)
        )
        write_json(args.out / "window_validation.json", window_thresholds)
    seg_thr = np.asarray(thresholds["values"])[
        np.searchsorted(np.asarray(thresholds["noise_edges"]), sigma, side="right")
    ]
    val = validation_metrics(vs, vo, p, xy, seg_thr)
    write_json(args.out / "validation.json", val)

    lidar_res = 2 * math.pi / 360  # the dataset's lidar (LidarSpec default, RPLIDAR A1)
    info = {
        "command": command,
        "seed": args.seed,
        "train_config": tcfg.to_dict(),
        "data": [
            {
                "path": str(path),
                "seeds": m["seeds"],
                "counts": m["counts"],
                "dataset_config": m["dataset_config"],
                "command": m.get("command"),
                "seconds": m.get("seconds"),
            }
            for path, m in zip(args.data, manifests, strict=True)
        ],
        "keep_easy": args.keep_easy,
        "min_kin_beams": args.min_kin_beams,
        "focus": {"weight": args.focus_weight, "beams": args.focus_beams, "range_m": args.focus_range},
        "split": {
            "val_fraction": args.val_fraction,
            "val_scenes": int(len(val_seeds)),
            "train_segments": int((keep & ~is_val).sum()),
            "val_segments": int((keep & is_val).sum()),
        },
        "epochs_run": len(history),
        "train_seconds": round(train_seconds, 1),
        "validation": val,
        "thresholds": thresholds,
        "window_kin_weight": args.window_kin_weight,
        "windows": [m.get("windows") for m in manifests],
        "window_thresholds": window_thresholds,
        # what LearnedKinDetector cuts its candidate windows with (detectors.learned.window_settings):
        # the datasets' one config; None (windows off) without windows or with several configs
        "window_config": _one_window_config(manifests) if window_thresholds is not None else None,
    }
    positioning = "regression" if args.positioning == "auto" else args.positioning
    ev = None
    if args.eval_scenes:
        # the sweep loads a provisional checkpoint under a hidden name: until the final one below is
        # written, nothing under the checkpoint's name claims an evaluation it has not had
        provisional = ckpt.with_name(f".{ckpt.stem}.pre-eval{ckpt.suffix}")
        try:
            save_checkpoint(provisional, model, fcfg, positioning=positioning, angular_resolution=lidar_res,
                            thresholds=thresholds, info=info)  # fmt: skip
            ev = evaluate(provisional, args, progress)
        finally:
            provisional.unlink(missing_ok=True)
            npz_path(provisional).unlink(missing_ok=True)  # its torch-free form, written beside it
        write_json(args.out / "eval.json", ev)
        write_text(args.out / "eval.md", markdown(ev))
        if args.positioning == "auto":
            positioning = ev["positioning"]["better"]
        info["evaluation"] = {
            k: ev[k] for k in ("targets", "positioning", "centre_error", "scenes_per_noise", "first_seed")
        }
    save_checkpoint(
        ckpt,
        model,
        fcfg,
        positioning=positioning,
        angular_resolution=lidar_res,
        thresholds=thresholds,
        info=info,
    )
    info["positioning"] = positioning
    info["total_seconds"] = round(time.perf_counter() - t_start, 1)
    info["python"], info["torch"] = platform.python_version(), torch.__version__
    sidecar = {"checkpoint": str(ckpt), "feature_config": fcfg.to_dict(), **info}
    write_json(ckpt.with_suffix(".json"), sidecar)
    write_json(args.out / "config.json", sidecar)  # last: the run's record
    logger.info(
        f"checkpoint {ckpt} ({ckpt.stat().st_size / 1e3:.0f} kB), positioning {positioning}; "
        f"validation kin F1 {val['kin']['f1']:.3f}; training {train_seconds:.0f} s"
    )
    if ev is not None:
        t = ev["targets"]
        logger.info(
            f"held-out 1 % noise, 0.3-2 m: learned F1 {t['learned_f1_1pct_noise_0.3_2m']['f1']:.3f}, "
            f"geometric {t['geometric_f1_1pct_noise_0.3_2m']['f1']:.3f}; "
            f"learned {t['learned_scans_per_s']:.0f} scans/s"
        )
    return sidecar


def load_datasets(paths) -> tuple[dict, dict, dict, list[dict]]:
    """Several datasets as one: ``(segments, objects, first manifest, manifests)``. They must share
    the feature config and use disjoint scene seeds (rows are keyed by seed)."""
    parts = [load_dataset(p) for p in paths]
    manifests = [m for _, _, m in parts]
    for p, m in zip(paths[1:], manifests[1:], strict=True):
        if m["feature_config"] != manifests[0]["feature_config"]:
            raise ValueError(f"{p}: feature config {m['feature_config']} differs from {paths[0]}'s")
    seen: set = set()
    for p, (segs, _, _) in zip(paths, parts, strict=True):
        s = set(np.unique(segs["seed"]).tolist())
        if s & seen:
            raise ValueError(f"{p}: scene seeds overlap another --data directory's (e.g. {min(s & seen)})")
        seen |= s
    for segs, _, _ in parts:  # datasets written without --windows: segments only
        segs.setdefault("window", np.zeros(segs["label"].shape[0], np.int8))
    if len(parts) == 1:
        return parts[0][0], parts[0][1], manifests[0], manifests
    segs = concat_records([s for s, _, _ in parts])
    objs = concat_records([o for _, o, _ in parts])
    return segs, objs, manifests[0], manifests


def _feature_config(manifest: dict):
    from detectors.features import FeatureConfig

    return FeatureConfig.from_dict(manifest["feature_config"])


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
