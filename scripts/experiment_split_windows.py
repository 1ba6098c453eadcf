"""Issue 11, rounds 5-6 experiment: housing-width windows inside segments too wide for the pre-gate.

At 0.3-1 m most of the swarm's missed kin are merged by the paper's segmentation (``d_th`` = 0.1 m)
with a wall or a touching neighbour into one segment wider than a housing; the pre-gate drops it and the
kin has no candidate. This script measures how much **candidate windows** inside such segments recover
(:func:`detectors.windows.candidate_windows`, the function the dataset writer calls with
``make_dataset.py --windows``): each window is scored by the learned network and accepted at
``max(segment threshold, window threshold)``; a window whose centre lies within two housing radii of a
kept detection is dropped. Rows:

* ``shipped``: the learned detector (``--checkpoint``, default the shipped one) without windows;
* ``shipped + r5 windows >= W``: round 5's windows (every local range minimum) scored by the same
  network, accepted at ``W`` (``--window-threshold``); with ``--shipped-round6`` also ``shipped + r6
  windows >= W`` (round 6's anchor, the same network);
* with ``--new-checkpoint`` (a network trained on windows): ``new`` without windows, and ``new +
  windows`` with round 6's noise-robust anchor (``--anchor``, default ``WindowConfig()``) at the
  checkpoint's own calibrated window thresholds.

``--anchor-stats`` also counts windows per scan and the merged kin that get a kin window for both
anchors. It runs the breakdown of ``diagnose_learned.py`` (the benchmark's swarm generator with
**training** seeds, its matching rules) and writes ``results.json``, ``results.md`` and ``run.json``
to ``--out``::

    python scripts/experiment_split_windows.py --scenes 30 --noise 0 0.005 0.01 --anchor-stats \\
        --new-checkpoint outputs/r6/train/calibrated.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np

from detectors.fileio import write_json, write_text
from detectors.windows import WindowConfig, candidate_windows, wide_segments
from kin_envs.cli import (
    add_logging_args,
    check_distance_bins,
    check_output_dir,
    noise_level,
    parse_json_object,
    setup_logging,
    write_run_info,
)
from kin_envs.cli import progress as tqdm
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds

ROUND5 = WindowConfig(anchor="local", sag=0.0, sag_noise=0.0)  # every local minimum, as round 5


def window_threshold_values(checkpoint: dict) -> dict | None:
    """The window thresholds ``scripts/train_classifier.py`` calibrated for a checkpoint trained on
    windows (``info["window_thresholds"]``), or None."""
    return (checkpoint.get("info") or {}).get("window_thresholds")


def split_detector(
    checkpoint=None, window_threshold="calibrated", config: WindowConfig = ROUND5, threshold=None,
    cascade=None, cascade_windows: bool = False,
):
    """The learned detector plus candidate windows (:func:`detectors.windows.candidate_windows`) in
    the segments its pre-gate drops, each scored by the same network and accepted at ``max(segment
    threshold, window threshold)``; ``window_threshold`` a probability, or ``"calibrated"``: the
    checkpoint's per-noise window thresholds (:func:`window_threshold_values`). The Python reference of
    the detector's own compiled windows (round 7, ``LearnedKinDetector(windows=...)``, which this one turns
    off for its segments); ``cascade_windows``: windows of batches of >= 2 scans first go through the
    detector's cascade, as there."""
    from detectors.base import Detection, DetectionResult, wrap_angle
    from detectors.features import _cascade, _segment_batch, local_to_observer, scan_noise, segment_features
    from detectors.learned import LearnedKinDetector

    class SplitWindows(LearnedKinDetector):
        def permissive(self):
            return split_detector(
                self.checkpoint["path"], self.window_threshold, self.split_config, threshold=0.0,
                cascade_windows=self.cascade_windows,
            )

        def _window_thresholds(self, log_noise: np.ndarray) -> np.ndarray:
            if self.window_threshold != "calibrated":
                return np.full(log_noise.shape[0], float(self.window_threshold))
            wt = window_threshold_values(self.checkpoint)
            if wt is None:
                raise ValueError(f"{self.checkpoint['path']}: no calibrated window thresholds (train it on "
                                 "windows: make_dataset.py --windows); give --window-threshold values")
            sigma = np.exp(log_noise.astype(np.float64)) - 1e-4
            edges = np.asarray(wt["noise_edges"])
            return np.asarray(wt["values"])[np.searchsorted(edges, sigma, side="right")]

        def detect_batch(self, ranges, angles):
            res = self.results(self.detect_arrays(ranges, angles))
            rb, a = self._check(ranges, angles)
            batch = _segment_batch(rb, a, self.feature_config, self._circular)
            r = float(self.feature_config.r)
            step = 2 * math.pi / a.shape[0]  # as the dataset writer (a full turn of beams)
            wide = wide_segments(batch, step, r)
            win = candidate_windows(batch, wide, step, r, self.split_config, self.feature_config)
            self.counts["scans"] += rb.shape[0]
            self.counts["wide"] += int(wide.size)
            self.counts["windows"] += win.n_windows
            if win.n_windows == 0:
                return res
            sub = win.batch
            if self.cascade_windows and self.cascade:  # stage 1 on the windows too
                noise = scan_noise(sub, self.feature_config)
                _, s1 = _cascade(sub, self.feature_config, np.arange(sub.n_segments), self._trig, noise,
                                 self._cascade["model"])  # fmt: skip
                passed = np.flatnonzero(s1 >= self._cascade["threshold"])
                sub = dataclasses.replace(sub, **{k: getattr(sub, k)[passed] for k in (
                    "scan", "first", "count", "prev_beam", "next_beam", "prev_nearer", "next_nearer")})
                if sub.n_segments == 0:
                    return res
            feats = segment_features(sub, self.feature_config)
            out = self._forward(feats.x)
            p = 1.0 / (1.0 + np.exp(-out[:, 0]))
            noise = feats.x[:, self._noise_col]
            seg_thr = self._by_beams(self._thresholds(noise), noise, feats.x[:, self._range_col])
            thr = np.maximum(seg_thr, self._window_thresholds(noise))
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

    det = SplitWindows(checkpoint, reports=False, threshold=threshold, cascade=cascade, windows=False)
    # (not ``window_config``: that is the detector's own compiled windows' setting, off here)
    det.window_threshold, det.split_config, det.cascade_windows = window_threshold, config, cascade_windows
    det.counts = {"scans": 0, "wide": 0, "windows": 0, "accepted": 0}
    return det


def window_truth(fr, wb) -> tuple[np.ndarray, np.ndarray]:
    """``(label, robot)`` of every window of ``wb`` (a SegmentBatch over the frames ``fr``) by the
    benchmark's ground-truth rule (:func:`kin_envs.detection.dataset.window_labels`: >= 2 beams on one
    housing, most of the window); robot -1 where not kin."""
    from kin_envs.core.lidar import HitKind

    n = fr.ranges.shape[1]
    cnt = wb.count.astype(np.int64)
    seg = np.repeat(np.arange(cnt.size), cnt)
    off = np.zeros(cnt.size, np.int64)
    np.cumsum(cnt[:-1], out=off[1:])
    beam = (wb.first[seg] + np.arange(seg.size) - off[seg]) % n
    f = wb.scan[seg]
    kind = np.empty(seg.size, np.int64)
    idx = np.empty(seg.size, np.int64)
    for k in np.unique(f).tolist():  # frames -> their scene's Scan row
        m = f == k
        sc, row = fr.scans[int(fr.scene_of[k])], int(fr.row_of[k])
        kind[m], idx[m] = sc.hit_kind[row, beam[m]], sc.hit_index[row, beam[m]]
    rob = kind == HitKind.ROBOT
    pair, c = np.unique(seg[rob] * (idx.max() + 2) + idx[rob], return_counts=True)
    ws, who = pair // (idx.max() + 2), pair % (idx.max() + 2)
    best = np.zeros(cnt.size, np.int64)
    robot = np.full(cnt.size, -1)
    for a, b, k in zip(ws.tolist(), who.tolist(), c.tolist(), strict=True):
        if k > best[a]:
            best[a], robot[a] = k, b
    label = (best >= 2) & (2 * best > cnt)
    return label, np.where(label, robot, -1)


def anchor_stats(samples, cond, cond_index: int, configs: dict, bins, feature_config=None) -> dict:
    """Per window config: windows per scan, kin windows, and how many of the **merged** counted kin
    (the segment holding most of their beams has them as at most half of its beams, as
    ``diagnose_learned.py --stages``) get a kin window, per distance bin."""
    from detectors.features import FeatureConfig, segment_batch
    from kin_envs.core.lidar import HitKind
    from kin_envs.detection.benchmark import _frames

    fc = feature_config or FeatureConfig()
    fr = _frames(samples, cond, cond_index)
    batch = segment_batch(fr.ranges, fr.angles, fc)
    n = fr.ranges.shape[1]
    step = 2 * math.pi / n
    wide = wide_segments(batch, step, fc.r)
    is_wide = np.zeros(batch.n_segments, bool)
    is_wide[wide] = True
    seg_of = np.full(fr.ranges.shape, -1, np.int64)
    for s in range(batch.n_segments):
        seg_of[batch.scan[s], (batch.first[s] + np.arange(batch.count[s])) % n] = s
    kin = fr.kin
    merged = []  # (kin index, bin, its segment is wide)
    for k in np.flatnonzero(kin["care"]).tolist():
        bi = next((i for i, (lo, hi) in enumerate(bins) if lo <= kin["range"][k] < hi), None)
        if bi is None:
            continue
        f = int(kin["frame"][k])
        sc, row = fr.scans[int(fr.scene_of[f])], int(fr.row_of[f])
        on = (sc.hit_kind[row] == HitKind.ROBOT) & (sc.hit_index[row] == kin["robot"][k]) & fr.valid[f]
        segs = seg_of[f, on]
        segs = segs[segs >= 0]
        if segs.size == 0:
            continue
        ids, c = np.unique(segs, return_counts=True)
        s = int(ids[np.argmax(c)])
        if 2 * int(c.max()) <= int(batch.count[s]):
            merged.append((k, bi, bool(is_wide[s])))
    n_scans = fr.ranges.shape[0]
    out = {"scans": n_scans, "wide_per_scan": wide.size / n_scans, "configs": {}}
    for name, cfg in configs.items():
        win = candidate_windows(batch, wide, step, fc.r, cfg, fc)
        label, robot = window_truth(fr, win.batch)
        got = set(zip(win.batch.scan[label].tolist(), robot[label].tolist(), strict=True))
        per_bin = {}
        for bi, (lo, hi) in enumerate(bins):
            mk = [(k, w) for k, b, w in merged if b == bi]
            hit = [(int(kin["frame"][k]), int(kin["robot"][k])) in got for k, _ in mk]
            per_bin[f"{lo:g}-{hi:g} m"] = {"merged": len(mk), "in_wide": sum(w for _, w in mk),
                                           "with_window": int(sum(hit))}  # fmt: skip
        out["configs"][name] = {"windows_per_scan": win.n_windows / n_scans, "kin_windows": int(label.sum()),
                                "merged_kin": per_bin}  # fmt: skip
    return out


def _diagnose_learned():
    """``scripts/diagnose_learned.py`` as a module (the scripts folder is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "diagnose_learned", Path(__file__).with_name("diagnose_learned.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _fmt(v) -> str:
    return v if isinstance(v, str) else f"{v:g}"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--checkpoint", type=Path, default=None, help="learned checkpoint (default: the shipped one)"
    )
    ap.add_argument(
        "--new-checkpoint", type=Path, default=None,
        help="a checkpoint trained on candidate windows (make_dataset.py --windows): adds the rows 'new' (no "
        "windows) and 'new + windows' (--anchor windows at its calibrated window thresholds)",
    )  # fmt: skip
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
        nargs="*",
        default=[0.995],
        help="least p(kin) of an accepted window of --checkpoint, with round 5's windows (one run each)",
    )
    ap.add_argument(
        "--depth",
        type=float,
        default=1.0,
        help="a window holds the beams within DEPTH x housing radius of its range minimum",
    )
    ap.add_argument(
        "--anchor", default=None, metavar="JSON",
        help="WindowConfig overrides of the round-6 windows (default: detectors.windows.WindowConfig())",
    )  # fmt: skip
    ap.add_argument(
        "--shipped-round6", action="store_true",
        help="also run --checkpoint with round 6's windows at each --window-threshold (the anchor without "
        "the retraining)",
    )  # fmt: skip
    ap.add_argument(
        "--anchor-stats", action="store_true",
        help="also count windows per scan and the merged kin that get a kin window, for round 5's and "
        "round 6's anchors (no detector run)",
    )  # fmt: skip
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
        r5 = WindowConfig(anchor="local", depth=args.depth, sag=0.0, sag_noise=0.0)
        r6 = WindowConfig(**(parse_json_object(args.anchor, "--anchor") or {}))
        check_distance_bins(edges)
        check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
        check_output_dir(args.out)
    except (ValueError, TypeError) as e:
        ap.error(str(e))
    import torch

    from detectors.learned import LearnedKinDetector
    from kin_envs.detection.benchmark import SPLITS, Condition, _sample

    torch.set_num_threads(1)
    diagnose = _diagnose_learned().diagnose
    write_run_info(args.out, args, config={"round5": r5.to_dict(), "round6": r6.to_dict()},
                   seed=args.first_seed, argv=argv, script=__file__)  # fmt: skip
    samples = [_sample(SPLITS["swarm"], s) for s in tqdm(seeds, desc="scenes", disable=args.no_progress)]
    bins = list(zip(edges[:-1], edges[1:], strict=True))
    levels = {0.0: 0, 0.005: 1, 0.01: 2, 0.02: 3}  # the benchmark's noise draw per level
    res: dict = {}
    lines = [f"# Candidate windows in too-wide segments, swarm generator, seeds {seeds[0]}-{seeds[-1]}", ""]
    if args.anchor_stats:
        res["anchor_stats"] = {
            f"{100 * nz:g} %": anchor_stats(samples, Condition(nz), levels.get(nz, 9),
                                            {"round 5": r5, "round 6": r6}, bins)  # fmt: skip
            for nz in args.noise
        }
        lines += ["| noise | anchor | windows per scan | kin windows | merged kin with a kin window, per bin "
                  "(merged: in wide segments) |", "|---|---|---:|---:|---|"]  # fmt: skip
        for nz, st in res["anchor_stats"].items():
            for name, c in st["configs"].items():
                mk = ", ".join(f"{b}: {v['with_window']} / {v['merged']} ({v['in_wide']})"
                               for b, v in c["merged_kin"].items())  # fmt: skip
                lines.append(f"| {nz} | {name} | {c['windows_per_scan']:.1f} | {c['kin_windows']} | {mk} |")
        lines.append("")
    dets = [("shipped", LearnedKinDetector(args.checkpoint, reports=False))]
    for w in args.window_threshold:
        dets.append((f"shipped + r5 windows >= {w:g}", split_detector(args.checkpoint, w, r5)))
        if args.shipped_round6:
            dets.append((f"shipped + r6 windows >= {w:g}", split_detector(args.checkpoint, w, r6)))
    if args.new_checkpoint is not None:
        dets += [("new", LearnedKinDetector(args.new_checkpoint, reports=False)),
                 ("new + windows", split_detector(args.new_checkpoint, "calibrated", r6))]  # fmt: skip
    lines += ["| detector | noise | bin | kin | found | FP | F1 | misses: no candidate | FP kinds |",
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
