"""Where a detector loses kin on the benchmark's swarm generator: false positives by kind, misses by cause.

On scenes of the benchmark's ``swarm`` generator drawn with **training** seeds (never the reserved ones),
at each ``--noise`` level, the detector runs at its operating point and the benchmark's rules match its
detections (gate 0.10 m, kin counted with >= 2 valid beams, same-radius cylinders apart). Per distance bin
(``--bins``; false positives by the detection's range, misses by the kin's):

* false positives by what their beams hit: 7 cm prism / box, same-radius or other cylinder, other prism /
  box, wall or boundary fragment, a kin more than 0.10 m from the detection ("kin outside gate"), mixed;
* misses by cause (the benchmark's permissive run): score below the threshold (>= 3 or <= 2 beams),
  merged with another object, centre off by > gate, no candidate; "(occluded)" when the kin has fewer
  than 60 % of the beams an unoccluded housing gets at its range.

Writes ``results.json``, ``results.md`` and ``run.json`` to ``--out``::

    python scripts/diagnose_learned.py --scenes 30 --noise 0.005 0.01
    python scripts/diagnose_learned.py --positioning fit --out outputs/diagnose_fit
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
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
from kin_envs.core.lidar import HitKind
from kin_envs.detection.benchmark import (
    GATE,
    SPLITS,
    Condition,
    _beam_fraction,
    _frames,
    _miss_reasons,
    _run,
    _sample,
    _table,
    permissive,
)
from kin_envs.detection.evaluation import describe_hits, segment_beams
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds

OCCLUDED = 0.6  # share of an unoccluded housing's beams below which a kin counts as occluded
BEAM_BINS = ((2, 2), (3, 3), (4, 5), (6, 10_000))  # beams on target of the stage breakdown
NEAR = 0.1  # p(kin) this far below the threshold counts as "near the threshold"


def fp_kind(src) -> str:
    """The false-positive class of a :class:`~kin_envs.detection.evaluation.HitSource`."""
    if src.kind == "kin":
        return "kin outside gate"
    if src.kind in ("prism", "box"):
        return f"{'7 cm' if abs(src.size - 0.07) < 1e-3 else 'other'} {src.kind}"
    if src.kind == "cylinder":
        return "same-radius cylinder" if src.same_radius else "other cylinder"
    if src.kind in ("wall", "boundary", "polygon"):
        return "wall / boundary fragment"
    return src.kind


def diagnose(det, samples, cond: Condition, cond_index: int, bins) -> dict:
    """The breakdown of one condition (see the module docstring)."""
    from detectors.metrics import match

    fr = _frames(samples, cond, cond_index)
    op = _table(_run(det, fr.ranges, fr.angles, 256)[0])
    rk = _table(_run(permissive(det), fr.ranges, fr.angles, 256)[0])
    kin, n = fr.kin, fr.ranges.shape[1]
    sr = _beam_fraction(fr.same_radius_beam, fr.valid, op["frame"], op["first"], op["n_beams"]) > 0.5
    tp = np.zeros(op["score"].shape[0], bool)
    ign = np.zeros_like(tp)
    kin_hit = np.zeros(kin["frame"].shape[0], bool)
    for f in np.unique(op["frame"]).tolist():
        di, ki = np.flatnonzero(op["frame"] == f), np.flatnonzero(kin["frame"] == f)
        m = match(op["xy"][di], kin["xy"][ki], GATE, ~kin["care"][ki], sr[di])
        tp[di], ign[di] = m.tp, m.ignored
        kin_hit[ki[m.gt[m.tp]]] = True
    fp = ~(tp | ign)
    step = 2 * math.pi / n
    expected = 2 * np.arcsin(np.minimum(1.0, 0.035 / np.maximum(kin["range"], 1e-9))) / step
    occluded = kin["n_beams"] < OCCLUDED * expected
    out = {}
    for lo, hi in bins:
        sel = np.flatnonzero(fp & (op["range"] >= lo) & (op["range"] < hi))
        kinds = Counter()
        for j in sel.tolist():
            f = int(op["frame"][j])
            i, r = int(fr.scene_of[f]), int(fr.row_of[f])
            last = int((op["first"][j] + op["n_beams"][j] - 1) % n)
            beams = segment_beams(int(op["first"][j]), last, n)
            kinds[fp_kind(describe_hits(fr.scans[i], r, beams, fr.samples[i].scene))] += 1
        k_in = kin["care"] & (kin["range"] >= lo) & (kin["range"] < hi)
        missed = np.flatnonzero(k_in & ~kin_hit)
        causes = Counter()
        for k in missed.tolist():
            reason = next(c for c, v in _miss_reasons(fr, rk, kin, np.array([k])).items() if v)
            if reason == "below operating point":
                few = kin["n_beams"][k] <= 2
                reason = "score below threshold, " + ("<= 2 beams" if few else ">= 3 beams")
            causes[reason + (" (occluded)" if occluded[k] else "")] += 1
        found = int((k_in & kin_hit).sum())
        out[f"{lo:g}-{hi:g} m"] = {
            "counted_kin": int(k_in.sum()), "found": found, "missed": int(missed.size), "fp": int(sel.size),
            "f1": 2 * found / max(2 * found + sel.size + missed.size, 1),
            "fp_kinds": dict(kinds.most_common()), "miss_causes": dict(causes.most_common()),
            "occluded_share": float(occluded[k_in].mean()) if k_in.any() else None,
        }  # fmt: skip
    return out


def _beam_bin(nb: int) -> str:
    lo, hi = next(b for b in BEAM_BINS if b[0] <= nb <= b[1]) if nb >= 2 else (nb, nb)
    return f"{lo}" if lo == hi else (f">= {lo}" if hi >= 10_000 else f"{lo}-{hi}")


def _new_row() -> dict:
    return {"kin": 0, "found": 0, "causes": Counter(), "tp_det": 0, "fp": 0, "fp_kinds": Counter(),
            "fp_margin": Counter()}


def stage_breakdown(det, samples, cond: Condition, cond_index: int, bins) -> dict:
    """Every counted kin and false positive of one condition by beams on target and by the pipeline
    stage that decided it (the detector's own per-segment stages, ``detect_arrays``):

    * a missed kin: ``merged`` (its beams are at most half of the segment holding most of them),
      ``pre-gate``, ``cascade``, ``threshold`` (``near``: p(kin) within :data:`NEAR` below it),
      ``duplicate`` (suppressed for a neighbour), ``centre off`` (accepted, centre > gate away),
      ``matching`` (accepted within the gate, matched to another kin); ``split`` is appended when its
      beams are spread over several segments. p(kin) of cascade-dropped segments comes from the same
      checkpoint run without cascade and pre-gate (same segmentation, checked).
    * a false positive: by beams, by what its beams hit and by p(kin) margin over the threshold;
      true positives by the detection's beams beside them (``tp_det``; kin are binned by their own).
    """
    from detectors.learned import LearnedKinDetector
    from detectors.metrics import match

    fr = _frames(samples, cond, cond_index)
    a = det.detect_arrays(fr.ranges, fr.angles)
    full = LearnedKinDetector(det.checkpoint["path"], reports=False, positioning=det.positioning,
                              cascade=False, pre_gate=False, suppress_duplicates=False).detect_arrays(
        fr.ranges, fr.angles)  # fmt: skip
    if not (np.array_equal(a.seg_first, full.seg_first) and np.array_equal(a.seg_scan, full.seg_scan)):
        raise RuntimeError("the two runs segmented differently")
    kin, n = fr.kin, fr.ranges.shape[1]
    nf = fr.ranges.shape[0]
    seg_of = np.full((nf, n), -1, np.int64)  # segment of every beam
    for s in range(a.n_segments):
        seg_of[a.seg_scan[s], (a.seg_first[s] + np.arange(min(int(a.seg_count[s]), n))) % n] = s
    sv = a.seg_values
    p_op, thr = sv["p_kin"], sv["threshold"]
    p_all = full.seg_values["p_kin"]
    casc = sv.get("cascade_score", np.full(a.n_segments, np.nan))
    dup = sv.get("duplicate_of", np.full(a.n_segments, -1))  # -1: not a duplicate
    det_of_seg = np.full(a.n_segments, -1, np.int64)
    det_of_seg[a.segment] = np.arange(a.n_detections)
    dxy = np.stack([a.x, a.y], 1)
    sr = _beam_fraction(fr.same_radius_beam, fr.valid, a.scan, a.first_beam, a.n_beams_on) > 0.5
    tp, ign = np.zeros(a.n_detections, bool), np.zeros(a.n_detections, bool)
    kin_hit = np.zeros(kin["frame"].shape[0], bool)
    for f in np.unique(a.scan).tolist():
        di, ki = np.flatnonzero(a.scan == f), np.flatnonzero(kin["frame"] == f)
        m = match(dxy[di], kin["xy"][ki], GATE, ~kin["care"][ki], sr[di])
        tp[di], ign[di] = m.tp, m.ignored
        kin_hit[ki[m.gt[m.tp]]] = True
    fp = ~(tp | ign)
    out = {}
    for lo, hi in bins:
        k_in = np.flatnonzero(kin["care"] & (kin["range"] >= lo) & (kin["range"] < hi))
        per_beams: dict = {}
        for k in k_in.tolist():
            row = per_beams.setdefault(_beam_bin(int(kin["n_beams"][k])), _new_row())
            row["kin"] += 1
            if kin_hit[k]:
                row["found"] += 1
                continue
            f = int(kin["frame"][k])
            i, r = int(fr.scene_of[f]), int(fr.row_of[f])
            scan = fr.scans[i]
            on = (scan.hit_kind[r] == HitKind.ROBOT) & (scan.hit_index[r] == kin["robot"][k]) & fr.valid[f]
            segs = seg_of[f, on]
            segs = segs[segs >= 0]
            if segs.size == 0:
                row["causes"]["no segment"] += 1
                continue
            ids, cnt = np.unique(segs, return_counts=True)
            s = int(ids[np.argmax(cnt)])
            beams = (a.seg_first[s] + np.arange(min(int(a.seg_count[s]), n))) % n
            split = " (split)" if ids.size > 1 else ""
            if 2 * int(cnt.max()) <= int(fr.valid[f, beams].sum()):
                cause = "merged"
            elif a.seg_stage[s] == 1:
                cause = "pre-gate"
            elif a.seg_stage[s] == 2:
                cause = "too few points"
            elif dup[s] >= 0:
                cause = "duplicate"
            elif a.seg_stage[s] != 0:
                p = p_all[s]
                where = "cascade" if np.isnan(p_op[s]) and np.isfinite(casc[s]) else "threshold"
                cause = f"{where}, {'near' if p >= thr[s] - NEAR else 'far'}"
            else:
                j = det_of_seg[s]
                cause = "centre off" if np.hypot(*(dxy[j] - kin["xy"][k])) > GATE else "matching"
            row["causes"][cause + split] += 1
        sel = np.flatnonzero(fp & (a.range >= lo) & (a.range < hi))
        for j in sel.tolist():
            f, s = int(a.scan[j]), int(a.segment[j])
            row = per_beams.setdefault(_beam_bin(int(a.n_beams_on[j])), _new_row())
            row["fp"] += 1
            i, r = int(fr.scene_of[f]), int(fr.row_of[f])
            beams = segment_beams(int(a.first_beam[j]), int(a.last_beam[j]), n)
            row["fp_kinds"][fp_kind(describe_hits(fr.scans[i], r, beams, fr.samples[i].scene))] += 1
            row["fp_margin"]["near" if p_op[s] < thr[s] + NEAR else "far"] += 1
        for j in np.flatnonzero(tp & (a.range >= lo) & (a.range < hi)).tolist():
            per_beams.setdefault(_beam_bin(int(a.n_beams_on[j])), _new_row())["tp_det"] += 1
        for row in per_beams.values():
            for key in ("causes", "fp_kinds", "fp_margin"):
                row[key] = dict(row[key].most_common())
            row["f1"] = 2 * row["found"] / max(row["kin"] + row["found"] + row["fp"], 1)
        order = lambda kv: int(kv[0].split()[-1].split("-")[0])  # noqa: E731
        out[f"{lo:g}-{hi:g} m"] = dict(sorted(per_beams.items(), key=order))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=None,
                    help="learned checkpoint (default: the shipped one)")
    ap.add_argument("--positioning", choices=("regression", "fit"), default=None,
                    help="positioning (default: the checkpoint's)")
    ap.add_argument("--scenes", type=int, default=30, help="scenes of the benchmark's swarm generator")
    ap.add_argument("--first-seed", type=int, default=600_000,
                    help="seed of scene 0 (a training seed < 1,000,000; the benchmark's are refused)")
    ap.add_argument("--noise", type=noise_level, nargs="+", default=[0.005, 0.01],
                    help="range-noise levels (relative sigma)")
    ap.add_argument("--bins", type=float, nargs="+", default=[0.3, 1.0, 2.0], help="distance bin edges, m")
    ap.add_argument("--out", type=Path, default=Path("outputs/diagnose_learned"), help="output directory")
    ap.add_argument("--stages", action="store_true",
                    help="also break every kin and false positive down by beams on target and by the "
                    "pipeline stage that decided it (pre-gate, cascade, threshold, suppression, ...)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    seeds = range(args.first_seed, args.first_seed + max(args.scenes, 1))
    edges = args.bins
    try:
        if args.scenes < 1:
            raise ValueError(f"--scenes must be >= 1, got {args.scenes}")
        check_distance_bins(edges)
        check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
        check_output_dir(args.out)
    except ValueError as e:
        ap.error(str(e))
    from detectors.learned import LearnedKinDetector

    det = LearnedKinDetector(args.checkpoint, reports=False, positioning=args.positioning)
    write_run_info(args.out, args, seed=args.first_seed, argv=argv, script=__file__)
    samples = [_sample(SPLITS["swarm"], s) for s in tqdm(seeds, desc="scenes", disable=args.no_progress)]
    bins = list(zip(edges[:-1], edges[1:], strict=True))
    levels = {0.0: 0, 0.005: 1, 0.01: 2, 0.02: 3}  # the benchmark's noise draw per level
    res = {
        f"{100 * nz:g} %": diagnose(det, samples, Condition(nz), levels.get(nz, 9), bins) for nz in args.noise
    }
    lines = [f"# Error breakdown, swarm generator, seeds {seeds[0]}-{seeds[-1]}, {det.checkpoint['path']}",
             ""]  # fmt: skip
    for nz, per in res.items():
        for b, r in per.items():
            lines.append(f"- noise {nz}, {b}: {r['counted_kin']} kin, {r['found']} found, F1 {r['f1']:.3f}; "
                         f"FP {r['fp']}: {r['fp_kinds']}; misses {r['missed']}: {r['miss_causes']}")
    if args.stages:
        res["stages"] = {
            f"{100 * nz:g} %": stage_breakdown(det, samples, Condition(nz), levels.get(nz, 9), bins)
            for nz in args.noise
        }
        lines += ["", "## By beams on target and pipeline stage", "",
                  "| noise | bin | beams | kin | found | missed: cause | TP, FP (detection's beams) "
                  "| FP: hit / margin |", "|---|---|---|---:|---:|---|---:|---|"]  # fmt: skip
        for nz, per in res["stages"].items():
            for b, rows in per.items():
                for nb, r in rows.items():
                    lines.append(f"| {nz} | {b} | {nb} | {r['kin']} | {r['found']} | {r['causes']} "
                                 f"| {r['tp_det']}, {r['fp']} | {r['fp_kinds']} / {r['fp_margin']} |")
    write_text(args.out / "results.md", "\n".join(lines) + "\n")
    write_json(args.out / "results.json", res)
    return res


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
