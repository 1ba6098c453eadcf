"""Re-tune the tracker's kin-probability parameters (``detectors.TrackerParams``) for a detector.

These are the hand-tuned fusion's (``KinTracker(kin_model="hand")``); the default kin decision, the learned
track classifier, is fitted by ``scripts/fit_track_classifier.py``.

Records training-seed sequence episodes once per detector (``kin_envs.detection.sequences.training_split``:
the benchmark's ``swarm`` and ``lookalike`` generators with seeds outside its reserved range), then runs
``tune_tracker``'s coordinate descent over ``TUNING_GRID`` (or ``--grid``) on the replayed frames, the
objective being the tracker's per-frame F1 on kin in view >= 10 frames at 0.3-2 m (mean over the recorded
sets; with several ``--detectors`` one parameter set is tuned for all of them). Writes to ``--out``:

* ``params.json``: the tuned ``TrackerParams`` fields (``KinTracker(TrackerParams.from_dict(...))``);
* ``tuning.md``: the objective per recorded set for the defaults and the tuned parameters, and the
  tracker's error diagnosis (false positives and misses by cause) with the tuned parameters;
* ``log.json``: every evaluated parameter set; ``run.json``: command, arguments, versions, timing.

Example::

    python scripts/tune_tracker.py                                  # learned + geometric, 1 % noise
    python scripts/tune_tracker.py --detectors learned --swarm-episodes 2 --lookalike-episodes 10
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import add_logging_args, check_output_dir, setup_logging, write_run_info


def _fmt(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--detectors", nargs="+", default=["learned", "geometric"],
                   help="detectors feeding the tracker (geometric, learned, beam, module:Class); one "
                        "parameter set is tuned for all of them")  # fmt: skip
    p.add_argument("--swarm-episodes", type=int, default=2, help="training swarm episodes per detector")
    p.add_argument("--lookalike-episodes", type=int, default=10, help="training lookalike episodes per det.")
    p.add_argument("--first-seed", type=int, default=1000, help="first training seed (not a reserved one)")
    p.add_argument("--noise", type=float, default=0.01, help="relative lidar range noise (0.01 = 1 %%)")
    p.add_argument("--grid", type=json.loads, default=None,
                   help='JSON {"param": [values, ...]} to search instead of TUNING_GRID')  # fmt: skip
    p.add_argument("--passes", type=int, default=2, help="coordinate-descent passes over the grid")
    p.add_argument("--out", type=Path, default=Path("outputs/tune_tracker"), help="output directory")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads (learned detector)")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    for name in ("swarm_episodes", "lookalike_episodes", "passes"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if not 0 <= args.noise <= 0.05:
        p.error(f"--noise must be relative range noise in [0, 0.05] (0.01 = 1 %), got {args.noise}")
    try:
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    if "learned" in args.detectors:
        import torch

        torch.set_num_threads(args.torch_threads)
    from detectors.tracking import TrackerParams
    from kin_envs.cli import detector_from_name
    from kin_envs.detection import sequences as S

    grid = S.TUNING_GRID if args.grid is None else {k: tuple(v) for k, v in args.grid.items()}
    t0 = time.perf_counter()
    recorded, names = [], []
    from tqdm import tqdm

    for det_name in tqdm(args.detectors, desc="record episodes"):
        det = detector_from_name(det_name, what="--detectors")
        for split, n in (("swarm", args.swarm_episodes), ("lookalike", args.lookalike_episodes)):
            recorded.append(S.record_sequences(det, S.training_split(split, args.first_seed), n, args.noise))
            names.append(f"{det_name} / {split}")
    best, log = S.tune_tracker(recorded, grid, passes=args.passes, progress=True)
    default = TrackerParams()
    lines = [f"# Tracker tuning ({', '.join(args.detectors)}; noise {100 * args.noise:g} %)", "",
             "Objective: the tracker's per-frame F1 on kin in view >= 10 frames at 0.3-2 m (training seeds).",
             "",
             "| recorded set | defaults | tuned |", "|---|---|---|"]  # fmt: skip
    for name, rec in zip(names, recorded, strict=True):
        a = S.tune_objective(S.evaluate_sequences(rec, default, mot=False, singles=False, kin_model="hand"))
        r = S.evaluate_sequences(rec, best, mot=False, singles=False, diagnose=True, kin_model="hand")
        lines.append(f"| {name} | {_fmt(a)} | {_fmt(S.tune_objective(r))} |")
        rec.diagnosis = r["diagnosis"]
    changed = {k: getattr(best, k) for k in grid if getattr(best, k) != getattr(default, k)}
    lines += ["", f"Changed from the defaults: `{json.dumps(changed)}`", "",
              "Errors of the tuned tracker in the target window, by cause:", ""]  # fmt: skip
    for name, rec in zip(names, recorded, strict=True):
        lines.append(f"- {name}: " + ", ".join(f"{k} {v}" for k, v in rec.diagnosis.items()))
    write_json(args.out / "params.json", dataclasses.asdict(best))
    write_json(args.out / "log.json", log, default=float)
    with atomic_write(args.out / "tuning.md", "w") as f:
        f.write("\n".join(lines) + "\n")
    write_run_info(args.out, args, argv=argv, script=__file__, seconds=time.perf_counter() - t0)
    print("\n".join(lines))
    return {"params": dataclasses.asdict(best), "changed": changed}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
