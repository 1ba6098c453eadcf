"""The single-scan ceiling on the ``swarm`` split: an oracle likelihood-ratio classifier vs the learned one.

On scenes of the benchmark's ``swarm`` generator drawn with **training** seeds (never the benchmark's
reserved ones), scanned from every robot at each ``--noise`` level (the benchmark's noise draw), every
object seen by >= 2 valid beams within ``--bins`` (kin, 7 cm prisms and boxes, other prisms, boxes and
cylinders, wall and boundary pieces; same-radius cylinders left out, as the benchmark counts them apart)
gets the oracle's log-likelihood ratio against every shape the generator draws
(``kin_envs.detection.oracle.object_llr_swarm``: it knows the noise model, the shapes and which beams
hit each object, so segmentation is perfect). Its best F1 per distance bin, with one LLR threshold per
beam count (2, 3, 4, 5-9, >= 10: a prior by range, as a Bayes rule would use), is the ceiling estimate of
any single-scan classifier on these objects. The learned detectors (``--checkpoints``) are scored on the
same objects: an object is accepted when a detection's beams are mostly on it and overlap its beams
(a kin only when the detection is within 0.10 m of its centre). 95 % intervals: percentile bootstrap
over scenes (``scipy.stats.bootstrap``) at the chosen thresholds. The gap table counts, per bin, object
kind and beam count, the objects each classifier gets wrong.

Writes ``results.md``, ``results.json`` (every object's LLR and decisions) and ``run.json`` to ``--out``.

Example::

    python scripts/oracle_swarm.py --scenes 8 --noise 0.01 --out outputs/oracle_swarm_1
    python scripts/oracle_swarm.py --scenes 2 --noise 0 0.005 0.01 --checkpoints shipped my.pt
"""

from __future__ import annotations

import argparse
import math
import time
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
from kin_envs.detection.benchmark import GATE, SPLITS, Condition, _frames, _sample
from kin_envs.detection.evaluation import describe_hits, segment_beams
from kin_envs.detection.oracle import best_f1_grouped, scan_objects_llr
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds

_KIND = {"kin": HitKind.ROBOT, "prism": HitKind.PRISM, "box": HitKind.BOX, "cylinder": HitKind.CYLINDER,
         "wall": HitKind.WALL, "boundary": HitKind.BOUNDARY}  # fmt: skip
#: beam-count groups of the oracle's thresholds and of the gap table
BEAM_GROUPS = ((2, 3), (3, 4), (4, 5), (5, 10), (10, 10**6))


def beam_group(n: int) -> str:
    for lo, hi in BEAM_GROUPS:
        if lo <= n < hi:
            return f"{lo}" if hi == lo + 1 else (f"{lo}-{hi - 1}" if hi < 10**6 else f">={lo}")
    return "1"


def kind_group(label: str) -> str:
    return label if label in ("kin", "wall", "boundary", "other cylinder") else (
        "7 cm prism/box" if label.startswith("7 cm") else f"other {label}")  # fmt: skip


def accepted(detector, fr) -> dict:
    """``(frame, hit kind, index) -> [beam index arrays]`` of every detection of ``detector`` by the
    object its beams are mostly on (a kin only when the detection is within the gate of its centre)."""
    n = fr.ranges.shape[1]
    out: dict = {}
    for f, res in enumerate(detector.detect_batch(fr.ranges, fr.angles)):
        i, r = int(fr.scene_of[f]), int(fr.row_of[f])
        scan, scene = fr.scans[i], fr.samples[i].scene
        for d in res.detections:
            beams = segment_beams(d.first_beam, d.last_beam, n)
            src = describe_hits(scan, r, beams, scene)
            kind = _KIND.get(src.kind)
            if kind is None:
                continue
            idx = -1 if src.kind == "boundary" else int(src.index)
            if src.kind == "kin":
                k = np.flatnonzero(fr.kin["frame"] == f)
                k = k[fr.kin["robot"][k] == idx]
                if not (k.size and math.hypot(*(fr.kin["xy"][k[0]] - (d.x, d.y))) <= GATE):
                    continue
            out.setdefault((f, int(kind), idx), []).append(beams)
    return out


def f1_ci(acc, y, scene, n_scenes: int, n_resamples: int, seed: int) -> tuple[float, list]:
    """F1 of the decisions ``acc`` against labels ``y`` and its 95 % bootstrap interval over scenes."""
    from scipy.stats import bootstrap

    tp = np.bincount(scene[acc & y], minlength=n_scenes).astype(float)
    fp = np.bincount(scene[acc & ~y], minlength=n_scenes).astype(float)
    fn = np.bincount(scene[~acc & y], minlength=n_scenes).astype(float)
    f1 = 2 * tp.sum() / max(2 * tp.sum() + fp.sum() + fn.sum(), 1)
    if n_resamples == 0 or n_scenes < 2:
        return float(f1), [math.nan, math.nan]

    def stat(a, b, c, axis=-1):
        t = 2 * a.sum(axis=axis)
        return t / np.maximum(t + b.sum(axis=axis) + c.sum(axis=axis), 1)

    res = bootstrap((tp, fp, fn), stat, paired=True, n_resamples=n_resamples, method="percentile",
                    random_state=np.random.default_rng(seed))  # fmt: skip
    return float(f1), [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--first-seed", type=int, default=630_000,
                    help="seed of scene 0 (a training seed, < 1,000,000; the benchmark's are refused)")
    ap.add_argument("--scenes", type=int, default=8, help="number of scenes")
    ap.add_argument("--noise", type=noise_level, nargs="+", default=[0.0, 0.005, 0.01],
                    help="relative range noise levels (sigma / range)")
    ap.add_argument("--bins", type=float, nargs="+", default=[0.3, 1.0, 2.0, 3.0],
                    help="distance bin edges, m (objects by their centre's distance; wall pieces by "
                         "their nearest point)")
    ap.add_argument("--checkpoints", nargs="*", default=["shipped"],
                    help="learned checkpoints scored on the same objects ('shipped' = the default one)")
    ap.add_argument("--starts", type=int, default=2, help="orientation starts per polygon / box fit")
    ap.add_argument("--resamples", type=int, default=500, help="bootstrap resamples (0: no intervals)")
    ap.add_argument("--out", type=Path, default=Path("outputs/oracle_swarm"), help="output directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    seeds = range(args.first_seed, args.first_seed + max(args.scenes, 0))
    edges = args.bins
    try:
        if args.scenes < 1 or args.starts < 1 or args.resamples < 0:
            raise ValueError(f"--scenes and --starts must be >= 1 and --resamples >= 0, got {args.scenes}, "
                             f"{args.starts}, {args.resamples}")  # fmt: skip
        check_distance_bins(edges)
        check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
        check_output_dir(args.out)
    except ValueError as e:
        ap.error(str(e))
    write_run_info(args.out, args, seed=args.first_seed, argv=argv, script=__file__)
    t0 = time.perf_counter()
    samples = [_sample(SPLITS["swarm"], s) for s in tqdm(seeds, desc="scenes", disable=args.no_progress)]
    dets = {}
    if args.checkpoints:
        from detectors.learned import LearnedKinDetector

        dets = {
            ck: LearnedKinDetector(None if ck == "shipped" else ck, reports=False) for ck in args.checkpoints
        }
    bins = list(zip(edges[:-1], edges[1:], strict=True))
    res = {"seeds": [seeds[0], seeds[-1]], "bins": bins, "levels": {}}
    lines = [
        f"# Oracle vs learned on the `swarm` generator (training seeds {seeds[0]}-{seeds[-1]}), objects seen "
        "by >= 2 beams, same-radius cylinders left out",
        "", "| noise | bin | kin / other objects | oracle F1 [95 % CI] (P / R), thresholds per beam count | "
        + " | ".join(f"learned `{c}` F1 [95 % CI] (P / R)" for c in dets) + " |",
        "|---|---|---|---|" + "---|" * len(dets),
    ]  # fmt: skip
    gap_lines = ["", "Errors per object kind and beams on it (oracle at its thresholds / learned "
                 f"`{next(iter(dets), '-')}`): missed kin, accepted others", "",
                 "| noise | bin | kind | beams | objects | oracle wrong | learned wrong |",
                 "|---|---|---|---|---|---|---|"]  # fmt: skip
    for k, nz in enumerate(args.noise):
        ci = {0.0: 0, 0.005: 1, 0.01: 2, 0.02: 3}.get(nz, 9 + k)  # the benchmark's noise draw per level
        fr = _frames(samples, Condition(nz), ci)
        objs = []
        for f in tqdm(range(fr.ranges.shape[0]), desc=f"oracle {100 * nz:g} %", disable=args.no_progress):
            i, r = int(fr.scene_of[f]), int(fr.row_of[f])
            objs += scan_objects_llr(fr.scans[i], fr.samples[i].scene, r, nz, (edges[0], edges[-1]), frame=f,
                                     n_starts=args.starts, split="swarm")  # fmt: skip
        y = np.array([o.kin for o in objs], dtype=bool)
        scene = np.array([int(fr.scene_of[o.frame]) for o in objs], dtype=np.int64)
        dist = np.array([o.distance for o in objs])
        grp = np.array([beam_group(o.n_beams) for o in objs])
        llr = np.array([o.llr_all for o in objs])
        learned = {}
        for name, det in dets.items():
            acc = accepted(det, fr)
            learned[name] = np.array([
                any(np.intersect1d(b, o.beams).size for b in acc.get((o.frame, o.hit_kind, o.index), ()))
                for o in objs
            ], dtype=bool)  # fmt: skip
        level = res["levels"][str(nz)] = {"bins": []}
        for lo, hi in bins:
            m = (dist >= lo) & (dist < hi)
            if not y[m].any():
                continue
            orc = best_f1_grouped(llr[m], y[m], grp[m])
            acc_o = np.zeros(m.sum(), bool)
            for g, t in orc["thresholds"].items():
                acc_o |= (grp[m] == g) & (llr[m] >= t)
            f1, ci95 = f1_ci(acc_o, y[m], scene[m], len(samples), args.resamples, 0)
            row = {"lo": lo, "hi": hi, "kin": int(y[m].sum()), "others": int((~y[m]).sum()),
                   "oracle": {**orc, "f1_ci": ci95}, "learned": {}}  # fmt: skip
            cells = []
            for name, a in learned.items():
                lf1, lci = f1_ci(a[m], y[m], scene[m], len(samples), args.resamples, 0)
                tp = int((a[m] & y[m]).sum())
                p_, r_ = tp / max(int(a[m].sum()), 1), tp / int(y[m].sum())
                row["learned"][name] = {"f1": lf1, "f1_ci": lci, "precision": p_, "recall": r_}
                cells.append(f"{lf1:.3f} [{lci[0]:.2f}, {lci[1]:.2f}] ({p_:.2f} / {r_:.2f})")
            level["bins"].append(row)
            ths = ", ".join(f"{g}: {t:.2g}" for g, t in orc["thresholds"].items())
            lines.append(f"| {100 * nz:g} % | {lo:g}-{hi:g} m | {row['kin']} / {row['others']} | "
                         f"**{orc['f1']:.3f}** [{ci95[0]:.2f}, {ci95[1]:.2f}] ({orc['precision']:.2f} / "
                         f"{orc['recall']:.2f}); {ths} | " + " | ".join(cells) + " |")  # fmt: skip
            first = next(iter(learned.values()), None)
            kinds = np.array([kind_group(o.label) for o, mm in zip(objs, m, strict=True) if mm])
            for kg in sorted(set(kinds.tolist()), key=lambda s: (s != "kin", s)):
                for g in sorted(set(grp[m][kinds == kg].tolist())):
                    sel = (kinds == kg) & (grp[m] == g)
                    wrong_o = int((acc_o[sel] != y[m][sel]).sum())
                    wrong_l = "–" if first is None else int((first[m][sel] != y[m][sel]).sum())
                    if wrong_o or (first is not None and wrong_l):
                        gap_lines.append(f"| {100 * nz:g} % | {lo:g}-{hi:g} m | {kg} | {g} | "
                                         f"{int(sel.sum())} | {wrong_o} | {wrong_l} |")  # fmt: skip
        level["objects"] = [{**o.__dict__, "beams": list(o.beams),
                             **{f"learned_{n}": bool(a[j]) for n, a in learned.items()}}
                            for j, o in enumerate(objs)]  # fmt: skip
    res["seconds"] = round(time.perf_counter() - t0, 1)
    write_text(args.out / "results.md", "\n".join(lines + gap_lines) + "\n")
    write_json(args.out / "results.json", res)
    return res


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
