"""Fit the tracker's track-level kin classifier (``detectors.tracking.TrackKinModel``) for a detector.

Records training-seed sequence episodes (``kin_envs.detection.sequences.training_split``: the benchmark's
``swarm`` and ``lookalike`` generators, seeds outside its reserved range) with the detector feeding the
tracker, replays them through the tracker and fits a small network (one tanh layer of 8 units; ``--hidden``
with no sizes: a logistic regression) over the tracks' features (``detectors.tracking.TRACK_FEATURES``) with
scipy's L-BFGS, each recorded set weighing the same and rows outside the target window ``--outside-weight``
as much as rows inside it; a row is labelled kin where the benchmark would score a report as a true
positive (``sequences.track_samples``); then picks the operating point that maximises the mean per-frame
F1 on kin in view >= 10 frames at 0.3-2 m over the sets (``sequences.fit_kin_model``). Deterministic for
a given detector checkpoint; 2-5 minutes on 2 shared cores (recording, then the operating point's replays).
Writes to ``--out``:

* ``tracker_kin.json``: the model (load with ``KinTracker(kin_model=path)``); ``--ship`` also writes it to
  the shipped ``detectors/checkpoints/tracker_kin_default.json`` (``KinTracker(kin_model="learned")``), or
  with ``--detector geometric`` to ``tracker_kin_geometric.json`` (``kin_model="geometric"``, the v2 envs'
  choice for that detector's permissive feed);
* ``fit.md``: the objective per operating point and set, and the hand-tuned fusion's for comparison;
* ``run.json``: command, arguments, versions, timing.

Re-run it whenever the detector checkpoint changes::

    python scripts/fit_track_classifier.py --ship
    python scripts/fit_track_classifier.py --detector geometric --ship
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

from detectors.fileio import atomic_write, sha256_file, write_json
from kin_envs.cli import add_logging_args, check_output_dir, setup_logging, write_run_info


def _fmt(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--detector", default="learned",
                   help="detector feeding the tracker (geometric, learned, beam, module:Class)")  # fmt: skip
    p.add_argument("--swarm-episodes", type=int, default=4, help="training swarm episodes")
    p.add_argument("--lookalike-episodes", type=int, default=24, help="training lookalike episodes")
    p.add_argument("--first-seed", type=int, default=1000, help="first training seed (not a reserved one)")
    p.add_argument("--frames", type=int, default=None, help="frames per episode (default: the splits' 40)")
    p.add_argument("--noise", type=float, default=0.01, help="relative lidar range noise (0.01 = 1 %%)")
    p.add_argument("--hidden", type=int, nargs="*", default=[8],
                   help="hidden layer sizes of the classifier (no sizes: logistic regression)")  # fmt: skip
    p.add_argument("--l2", type=float, default=1e-3, help="L2 penalty on the weights")
    p.add_argument("--outside-weight", type=float, default=0.5,
                   help="weight of a training row outside the target window (inside: 1)")  # fmt: skip
    p.add_argument("--min-frames", type=int, default=3,
                   help="tracks seen in fewer frames take the detector's own decision")  # fmt: skip
    p.add_argument("--tol", type=float, default=0.001,
                   help="operating point: the highest threshold within this of the best objective")
    p.add_argument("--report-coasting", action="store_true",
                   help="let tracks not updated this frame keep the model's kin probability (default: 0)")
    p.add_argument("--ship", action="store_true",
                   help="also write the model to detectors/checkpoints/tracker_kin_default.json")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("outputs/fit_track_classifier"), help="output directory")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads (learned detector)")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    for name in ("swarm_episodes", "lookalike_episodes"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.frames is not None and args.frames < 2:
        p.error(f"--frames must be >= 2, got {args.frames}")
    if args.min_frames < 0 or any(h < 1 for h in args.hidden) or not args.l2 >= 0:
        p.error("--min-frames must be >= 0, --hidden sizes >= 1 and --l2 >= 0")
    if not 0 <= args.tol < 1:
        p.error(f"--tol must be in [0, 1), got {args.tol}")
    if not 0 < args.outside_weight <= 1:
        p.error(f"--outside-weight must be in (0, 1], got {args.outside_weight}")
    if not 0 <= args.noise <= 0.05:
        p.error(f"--noise must be relative range noise in [0, 0.05] (0.01 = 1 %), got {args.noise}")
    try:
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    if args.detector == "learned":
        import torch

        torch.set_num_threads(args.torch_threads)
    from tqdm import tqdm

    from detectors.tracking import DEFAULT_KIN_MODEL, GEOMETRIC_KIN_MODEL
    from kin_envs.cli import detector_from_name
    from kin_envs.detection import sequences as S

    shipped = {"learned": DEFAULT_KIN_MODEL, "geometric": GEOMETRIC_KIN_MODEL}
    if args.ship and args.detector not in shipped:
        p.error(f"--ship writes the shipped classifier of the learned or the geometric detector, got "
                f"--detector {args.detector!r}")  # fmt: skip
    t0 = time.perf_counter()
    det = detector_from_name(args.detector, what="--detector")
    recorded = []
    for split, n in tqdm((("swarm", args.swarm_episodes), ("lookalike", args.lookalike_episodes)),
                         desc="record episodes"):  # fmt: skip
        spec = S.training_split(split, args.first_seed)
        if args.frames is not None:
            spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=args.frames))
        recorded.append(S.record_sequences(det, spec, n, args.noise))
    t_rec = time.perf_counter() - t0
    info = {"detector": args.detector, "noise": args.noise, "first_seed": args.first_seed,
            "episodes": [args.swarm_episodes, args.lookalike_episodes], "frames": args.frames}
    ck = getattr(det, "checkpoint", None)  # the learned detector's: which weights the model was fitted for
    ck = ck.get("path") if isinstance(ck, dict) else None
    if isinstance(ck, str | Path) and Path(ck).is_file():
        info["detector_checkpoint_sha256"] = sha256_file(ck)
    model, rows = S.fit_kin_model(recorded, hidden=tuple(args.hidden), l2=args.l2, min_frames=args.min_frames,
                                  info=info, outside_weight=args.outside_weight,
                                  hit_only=not args.report_coasting, tol=args.tol)  # fmt: skip
    hand = [S.tune_objective(S.evaluate_sequences(r, mot=False, singles=False, kin_model="hand"))
            for r in recorded]  # fmt: skip
    names = [r.spec.name for r in recorded]
    lines = [f"# Track classifier fit ({args.detector}; noise {100 * args.noise:g} %; "
             f"{args.swarm_episodes} swarm + {args.lookalike_episodes} lookalike training episodes)", "",
             "Objective: the tracker's per-frame F1 on kin in view >= 10 frames at 0.3-2 m (training seeds).",
             "", "| operating point | mean | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names),
             "| hand-tuned fusion | " + _fmt(sum(hand) / len(hand)) + " | "
             + " | ".join(_fmt(v) for v in hand) + " |"]  # fmt: skip
    for r in rows:
        mark = " (chosen)" if r["threshold"] == model.info["threshold"] else ""
        lines.append(f"| p >= {r['threshold']:g}{mark} | {_fmt(r['objective'])} | "
                     + " | ".join(_fmt(v) for v in r["per_set"]) + " |")  # fmt: skip
    weights = model.layers[0][0][:, 0] if len(model.layers) == 1 else None
    if weights is not None:
        from detectors.tracking import TRACK_FEATURES

        pairs = zip(TRACK_FEATURES, weights, strict=True)
        lines += ["", "Weights (standardised features): " + ", ".join(f"{n} {w:+.2f}" for n, w in pairs)]
    write_json(args.out / "tracker_kin.json", model.to_dict())
    if args.ship:
        write_json(shipped[args.detector], model.to_dict())
    with atomic_write(args.out / "fit.md", "w") as f:
        f.write("\n".join(lines) + "\n")
    write_run_info(args.out, args, argv=argv, script=__file__, seed=args.first_seed,
                   seconds=time.perf_counter() - t0, record_seconds=t_rec)  # fmt: skip
    print("\n".join(lines))
    return {"model": model.to_dict(), "thresholds": rows, "hand": hand}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
