"""The single-scan limit among 7 cm look-alikes: an oracle likelihood-ratio classifier vs the learned one.

On scenes of a benchmark generator (``lookalike`` or ``swarm``) drawn with **training** seeds (never the
benchmark's reserved ones), scanned from every robot at one range-noise level, every kin, 7 cm prism,
7 x 7 cm box and other cylinder (same-radius cylinders left out) seen by >= 2 valid beams within
``--distance`` gets the oracle's log-likelihood ratio (``kin_envs.detection.oracle``: it knows the noise
model, the candidate shapes and which beams hit the object). Its best F1 over every threshold is the
ceiling of any single-scan classifier on these objects. The learned detectors (``--checkpoints``) are
scored on the same objects: an object is accepted when a detection's beams are mostly on it (and, for a
kin, matched within 0.10 m). Writes ``results.json``, ``results.md`` and ``run.json`` to ``--out``.

Example::

    python scripts/oracle_lookalike.py --scenes 200 --noise 0.01 --distance 0.3 1.0
    python scripts/oracle_lookalike.py --split swarm --scenes 3 --distance 1 2 --checkpoints shipped
"""

from __future__ import annotations

import argparse
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np

from detectors.fileio import write_json, write_text
from kin_envs.cli import add_logging_args, check_output_dir, noise_level, setup_logging, write_run_info
from kin_envs.cli import progress as tqdm
from kin_envs.core.lidar import HitKind
from kin_envs.detection.benchmark import GATE, SPLITS, Condition, _frames, _sample
from kin_envs.detection.evaluation import describe_hits, segment_beams
from kin_envs.detection.oracle import best_f1, scan_objects_llr
from kin_envs.detection.seeds import TRAINING_SEEDS, check_training_seeds

_KIND = {"kin": HitKind.ROBOT, "prism": HitKind.PRISM, "box": HitKind.BOX, "cylinder": HitKind.CYLINDER}


def accepted_objects(detector, fr) -> set[tuple[int, int, int]]:
    """``(frame, hit kind, index)`` of every object a detection of ``detector`` lies on (a kin only
    when the detection is within the benchmark's gate of its centre)."""
    n = fr.ranges.shape[1]
    out = set()
    for f, res in enumerate(detector.detect_batch(fr.ranges, fr.angles)):
        i, r = int(fr.scene_of[f]), int(fr.row_of[f])
        scan, scene = fr.scans[i], fr.samples[i].scene
        for d in res.detections:
            src = describe_hits(scan, r, segment_beams(d.first_beam, d.last_beam, n), scene)
            kind = _KIND.get(src.kind)
            if kind is None:
                continue
            if src.kind == "kin":
                k = np.flatnonzero(fr.kin["frame"] == f)
                k = k[fr.kin["robot"][k] == src.index]
                if not (k.size and math.hypot(*(fr.kin["xy"][k[0]] - (d.x, d.y))) <= GATE):
                    continue
            out.add((f, int(kind), int(src.index)))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("lookalike", "swarm"), default="lookalike",
                    help="benchmark generator the scenes are drawn from (with training seeds)")
    ap.add_argument("--first-seed", type=int, default=620_000,
                    help="seed of scene 0 (a training seed, < 1,000,000; the benchmark's are refused)")
    ap.add_argument("--scenes", type=int, default=200, help="number of scenes")
    ap.add_argument("--noise", type=noise_level, default=0.01, help="relative range noise (sigma / range)")
    ap.add_argument("--distance", type=float, nargs=2, default=(0.3, 1.0), metavar=("LO", "HI"),
                    help="objects whose centre is this far from the observer, m")
    ap.add_argument("--checkpoints", nargs="*", default=["shipped"],
                    help="learned checkpoints scored on the same objects ('shipped' = the default one)")
    ap.add_argument("--starts", type=int, default=4, help="orientation starts per polygon fit")
    ap.add_argument("--out", type=Path, default=Path("outputs/oracle_lookalike"), help="output directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    seeds = range(args.first_seed, args.first_seed + max(args.scenes, 0))
    try:
        if args.scenes < 1 or args.starts < 1:
            raise ValueError(f"--scenes and --starts must be >= 1, got {args.scenes}, {args.starts}")
        if not 0 <= args.distance[0] < args.distance[1]:
            raise ValueError(f"--distance must be 0 <= LO < HI, got {args.distance}")
        check_training_seeds(seeds, "--first-seed/--scenes", within=TRAINING_SEEDS)
        check_output_dir(args.out)
    except ValueError as e:
        ap.error(str(e))
    write_run_info(args.out, args, seed=args.first_seed, argv=argv, script=__file__)
    t0 = time.perf_counter()
    samples = [_sample(SPLITS[args.split], s) for s in tqdm(seeds, desc="scenes", disable=args.no_progress)]
    ci = {0.0: 0, 0.005: 1, 0.01: 2, 0.02: 3}.get(args.noise, 9)  # the benchmark's noise draw per level
    fr = _frames(samples, Condition(args.noise), ci)
    objs = []
    for f in tqdm(range(fr.ranges.shape[0]), desc="oracle", disable=args.no_progress):
        i, r = int(fr.scene_of[f]), int(fr.row_of[f])
        objs += scan_objects_llr(fr.scans[i], fr.samples[i].scene, r, args.noise, tuple(args.distance),
                                 frame=f, n_starts=args.starts)  # fmt: skip
    y = np.array([o.kin for o in objs], dtype=bool)
    if not y.any():
        raise SystemExit(f"oracle_lookalike.py: no kin at {args.distance} m in these scenes; more --scenes")
    no_cyl = np.array([o.label != "other cylinder" for o in objs])
    res = {
        "split": args.split, "noise": args.noise, "distance": list(args.distance),
        "seeds": [seeds[0], seeds[-1]], "objects": dict(Counter(o.label for o in objs)),
        "oracle": {
            "prisms_boxes": best_f1([o.llr for o in objs if o.label != "other cylinder"], y[no_cyl]),
            "all": best_f1([o.llr_all for o in objs], y),
        },
        "learned": {},
    }  # fmt: skip
    thr = res["oracle"]["all"]["threshold"]
    per = {}
    for o in objs:
        per.setdefault(o.label, []).append(o.llr_all >= thr)
    res["oracle_accepts_at_best_f1"] = {k: float(np.mean(v)) for k, v in sorted(per.items())}
    if args.checkpoints:
        from detectors.learned import LearnedKinDetector

        for ck in args.checkpoints:
            acc = accepted_objects(LearnedKinDetector(None if ck == "shipped" else ck, reports=False), fr)
            a = np.array([(o.frame, o.hit_kind, o.index) in acc for o in objs])
            row = {}
            for key, m in (("prisms_boxes", no_cyl), ("all", np.ones_like(no_cyl))):
                tp, fp, fn = int((a & y & m).sum()), int((a & ~y & m).sum()), int((~a & y & m).sum())
                row[key] = {"f1": 2 * tp / max(2 * tp + fp + fn, 1), "tp": tp, "fp": fp, "fn": fn}
            res["learned"][ck] = row
    res["seconds"] = time.perf_counter() - t0
    lines = [
        f"# Oracle vs learned, `{args.split}` generator (training seeds {seeds[0]}-{seeds[-1]}), noise "
        f"{100 * args.noise:g} %, objects at {args.distance[0]:g}-{args.distance[1]:g} m with >= 2 beams",
        "", "objects: " + ", ".join(f"{k} {v}" for k, v in sorted(res["objects"].items())), "",
        "| negatives | oracle best F1 (P / R) | "
        + " | ".join(f"learned `{c}` F1" for c in res["learned"]) + " |",
        "|---|---|" + "---|" * len(res["learned"]),
    ]  # fmt: skip
    for key, name in (("prisms_boxes", "7 cm prisms and boxes"), ("all", "and other cylinders")):
        o = res["oracle"][key]
        lines.append(f"| {name} | {o['f1']:.3f} ({o['precision']:.2f} / {o['recall']:.2f}) | "
                     + " | ".join(f"{v[key]['f1']:.3f}" for v in res["learned"].values()) + " |")
    write_text(args.out / "results.md", "\n".join(lines) + "\n")
    write_json(args.out / "results.json", {**res, "rows": [o.__dict__ for o in objs]})
    return res


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
