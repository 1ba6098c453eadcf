"""Issue 11, round 5 experiment: housing-width windows inside segments too wide for the pre-gate.

At 0.3-1 m most of the swarm's missed kin are merged by the paper's segmentation (``d_th`` = 0.1 m)
with a wall or a touching neighbour into one segment wider than a housing; the pre-gate drops it and the
kin has no candidate. This script measures how much a **candidate window** per range minimum inside such
a segment recovers: from every local range minimum ``d_m``, the window extends over the beams within
``--depth`` x r of ``d_m`` and at most half a housing's beam span (at ``d_m``) either side; windows of
>= 2 beams that are not the whole segment and pass the pre-gate's bound are classified by the
**unchanged** shipped network and accepted at ``max(threshold, --window-threshold)``; a window whose
centre lies within two housing radii of a kept detection is dropped. The windows are made by a Python
loop (an experiment, not the detector's hot path).

It runs the breakdown of ``diagnose_learned.py`` (the benchmark's swarm generator with **training** seeds,
its matching rules) for the shipped detector and for each window threshold, and writes ``results.json``,
``results.md`` and ``run.json`` to ``--out``::

    python scripts/experiment_split_windows.py --scenes 10 --noise 0.005 0.01 --window-threshold 0.9 0.995
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from detectors.fileio import write_json, write_text
from kin_envs.cli import (
    add_logging_args,
    check_distance_bins,
    check_output_dir,
    noise_level,
    setup_logging,
    write_run_info,
)
from kin_envs.cli import progress as tqdm
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds


def window_rows(ranges, angles_step: float, r: float, depth: float, scan, first, count, prev_beam, next_beam,
                prev_nearer, next_nearer) -> list[tuple]:  # fmt: skip
    """Candidate windows ``(scan, first, count, prev, next, prev_nearer, next_nearer)`` inside the given
    segments (arrays of equal length; ``ranges`` the pre-processed ``(B, n)`` scans), see the module
    docstring."""
    n = ranges.shape[1]
    rows = []
    for s in range(len(scan)):
        b, f, c = int(scan[s]), int(first[s]), int(count[s])
        idx = (f + np.arange(c)) % n
        d = ranges[b, idx]
        for j in range(c):
            if (j > 0 and d[j] > d[j - 1]) or (j < c - 1 and d[j] >= d[j + 1]):
                continue  # not a local minimum (ties: the last beam of a flat bottom)
            dm = d[j]
            w = int(math.floor(math.asin(min(r / (dm + r), 1.0)) / angles_step)) + 1
            a0 = a1 = j
            while a0 > 0 and j - a0 + 1 <= w and d[a0 - 1] - dm <= depth * r:
                a0 -= 1
            while a1 < c - 1 and a1 + 1 - j <= w and d[a1 + 1] - dm <= depth * r:
                a1 += 1
            if a1 - a0 + 1 < 2 or (a0 == 0 and a1 == c - 1):
                continue
            prev = int(idx[a0 - 1]) if a0 > 0 else int(prev_beam[s])
            nxt = int(idx[a1 + 1]) if a1 < c - 1 else int(next_beam[s])
            pn = bool(d[a0 - 1] < d[a0]) if a0 > 0 else bool(prev_nearer[s])
            nn = bool(d[a1 + 1] < d[a1]) if a1 < c - 1 else bool(next_nearer[s])
            rows.append((b, int(idx[a0]), a1 - a0 + 1, prev, nxt, pn, nn))
    return rows


def split_detector(checkpoint=None, window_threshold: float = 0.995, depth: float = 1.0, threshold=None):
    """The shipped learned detector plus candidate windows in too-wide segments (module docstring)."""
    from detectors import _kernels as _k
    from detectors.base import Detection, DetectionResult, wrap_angle
    from detectors.features import SegmentBatch, _segment_batch, local_to_observer, segment_features
    from detectors.learned import LearnedKinDetector

    class SplitWindows(LearnedKinDetector):
        def permissive(self):
            return split_detector(self.checkpoint["path"], self.window_threshold, self.depth, threshold=0.0)

        def detect_batch(self, ranges, angles):
            arr = self.detect_arrays(ranges, angles)
            res = self.results(arr)
            rb, a = self._check(ranges, angles)
            batch = _segment_batch(rb, a, self.feature_config, self._circular)
            wide = np.flatnonzero(arr.seg_stage == _k.DIAMETER)
            cols = (batch.scan, batch.first, batch.count, batch.prev_beam, batch.next_beam,
                    batch.prev_nearer, batch.next_nearer)  # fmt: skip
            r = float(self.feature_config.r)
            rows = window_rows(batch.ranges, self._step, r, self.depth, *(v[wide] for v in cols))
            self.counts["scans"] += rb.shape[0]
            self.counts["wide"] += int(wide.size)
            self.counts["windows"] += len(rows)
            if not rows:
                return res
            w = np.array(sorted(rows, key=lambda t: t[0]), dtype=np.int64)
            sub = SegmentBatch(ranges=batch.ranges, angles=batch.angles, circular=batch.circular,
                               scan=w[:, 0].copy(), first=w[:, 1].copy(), count=w[:, 2].copy(),
                               prev_beam=w[:, 3].copy(), next_beam=w[:, 4].copy(),
                               prev_nearer=w[:, 5].astype(bool),
                               next_nearer=w[:, 6].astype(bool))  # fmt: skip
            feats = segment_features(sub, self.feature_config)
            out = self._forward(feats.x)
            p = 1.0 / (1.0 + np.exp(-out[:, 0]))
            thr = np.maximum(self._thresholds(feats.scan_x[:, 0])[sub.scan], self.window_threshold)
            sel = np.flatnonzero((p >= thr) & (sub.count <= self.gate(sub)))
            if sel.size == 0:
                return res
            xy = local_to_observer(feats.frames[sel], self._t_mean + self._t_std * out[sel, 1:3])
            new: dict[int, list] = {}
            for o in np.argsort(-p[sel], kind="stable").tolist():  # best first
                s, b = int(sel[o]), int(sub.scan[sel[o]])
                x, y = float(xy[o, 0]), float(xy[o, 1])
                if any(
                    math.hypot(x - q.x, y - q.y) < self._dup_radius
                    for q in res[b].detections + new.get(b, [])
                ):
                    continue
                f, c = int(sub.first[s]), int(sub.count[s])
                last = (f + c - 1) % batch.angles.shape[0]
                bearing = float(wrap_angle(math.atan2(y, x)))
                new.setdefault(b, []).append(
                    Detection(math.hypot(x, y), bearing, x, y, float(p[s]), f, last, c)
                )
            self.counts["accepted"] += sum(len(v) for v in new.values())
            return [DetectionResult(r.detections + new[b]) if b in new else r for b, r in enumerate(res)]

    det = SplitWindows(checkpoint, reports=False, threshold=threshold)
    det.window_threshold, det.depth = float(window_threshold), float(depth)
    det.counts = {"scans": 0, "wide": 0, "windows": 0, "accepted": 0}
    return det


def _diagnose_learned():
    """``scripts/diagnose_learned.py`` as a module (the scripts folder is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "diagnose_learned", Path(__file__).with_name("diagnose_learned.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--checkpoint", type=Path, default=None, help="learned checkpoint (default: the shipped one)"
    )
    ap.add_argument("--scenes", type=int, default=10, help="scenes of the benchmark's swarm generator")
    ap.add_argument(
        "--first-seed",
        type=int,
        default=600_000,
        help="seed of scene 0 (a training seed < 1,000,000; the benchmark's are refused)",
    )
    ap.add_argument(
        "--noise",
        type=noise_level,
        nargs="+",
        default=[0.005, 0.01],
        help="range-noise levels (relative sigma)",
    )
    ap.add_argument(
        "--window-threshold",
        type=float,
        nargs="+",
        default=[0.9, 0.97, 0.995],
        help="least p(kin) of an accepted window (one run each)",
    )
    ap.add_argument(
        "--depth",
        type=float,
        default=1.0,
        help="a window holds the beams within DEPTH x housing radius of its range minimum",
    )
    ap.add_argument("--bins", type=float, nargs="+", default=[0.3, 1.0, 2.0], help="distance bin edges, m")
    ap.add_argument("--out", type=Path, default=Path("outputs/split_windows"), help="output directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    seeds = range(args.first_seed, args.first_seed + max(args.scenes, 1))
    edges = args.bins
    try:
        if args.scenes < 1:
            raise ValueError(f"--scenes must be >= 1, got {args.scenes}")
        if not all(0.0 <= w <= 1.0 for w in args.window_threshold):
            raise ValueError(f"--window-threshold must be in [0, 1], got {args.window_threshold}")
        if not args.depth > 0:
            raise ValueError(f"--depth must be > 0, got {args.depth}")
        check_distance_bins(edges)
        check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
        check_output_dir(args.out)
    except ValueError as e:
        ap.error(str(e))
    import torch

    from detectors.learned import LearnedKinDetector
    from kin_envs.detection.benchmark import SPLITS, Condition, _sample

    torch.set_num_threads(1)
    diagnose = _diagnose_learned().diagnose
    write_run_info(args.out, args, seed=args.first_seed, argv=argv, script=__file__)
    samples = [_sample(SPLITS["swarm"], s) for s in tqdm(seeds, desc="scenes", disable=args.no_progress)]
    bins = list(zip(edges[:-1], edges[1:], strict=True))
    levels = {0.0: 0, 0.005: 1, 0.01: 2, 0.02: 3}  # the benchmark's noise draw per level
    dets = [("shipped", LearnedKinDetector(args.checkpoint, reports=False))]
    dets += [
        (f"windows >= {w:g}", split_detector(args.checkpoint, w, args.depth)) for w in args.window_threshold
    ]
    res: dict = {}
    lines = [f"# Candidate windows in too-wide segments, swarm generator, seeds {seeds[0]}-{seeds[-1]}", "",
             "| detector | noise | bin | kin | found | FP | F1 | misses: no candidate | FP kinds |",
             "|---|---|---|---:|---:|---:|---:|---:|---|"]  # fmt: skip
    for name, det in tqdm(dets, desc="detectors", disable=args.no_progress):
        res[name] = {}
        for nz in args.noise:
            per = diagnose(det, samples, Condition(nz), levels.get(nz, 9), bins)
            res[name][f"{100 * nz:g} %"] = per
            for b, r in per.items():
                nc = sum(v for k, v in r["miss_causes"].items() if k.startswith("no candidate"))
                lines.append(f"| {name} | {100 * nz:g} % | {b} | {r['counted_kin']} | {r['found']} "
                             f"| {r['fp']} | {r['f1']:.3f} | {nc} | {r['fp_kinds']} |")  # fmt: skip
        if hasattr(det, "counts"):
            res[name]["counts"] = dict(det.counts)
    lines.append("")
    for name, r in res.items():
        if "counts" in r:
            c = r["counts"]
            lines.append(f"- {name}: per scan {c['wide'] / max(c['scans'], 1):.1f} too-wide segments, "
                         f"{c['windows'] / max(c['scans'], 1):.1f} windows; {c['accepted']} windows accepted "
                         f"(both runs of each noise level: operating point and permissive)")  # fmt: skip
    write_text(args.out / "results.md", "\n".join(lines) + "\n")
    write_json(args.out / "results.json", res)
    return res


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
