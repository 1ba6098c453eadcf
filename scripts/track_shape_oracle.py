"""How separable are *still* kin from still look-alikes at all? An oracle bound for the tracker's shape cues.

Records training-seed sequence episodes (``kin_envs.detection.sequences.training_split``; the shipped
learned detector feeding the tracker, as ``scripts/fit_track_classifier.py`` does) and, for every still
object an observer sees (parked or stuck kin, 7 cm prisms, boxes, cylinders of other radii; same-radius
cylinders and walls left out) once it has been in view (>= 2 beams) for ``--frames`` frames at 0.3-2 m,
scores the beams that hit it with the generalised log-likelihood ratio "housing circle" vs "best
look-alike outline" under the lidar's range-noise model (``kin_envs.detection.shape_oracle``), ego-motion
compensated with the observer's odometry (``--true-poses``: with its true poses, no drift). Its ROC (kin vs
look-alikes) bounds what any per-track shape cue can do; the script prints it next to the track
classifier's kin probability and the mean detector score on the very same objects.

Writes ``oracle.md`` (tables), ``samples.json`` (one row per object and frame count) and ``run.json``
to ``--out``. Analysis, not a hot path: on 2 shared cores at load ~6, the default 4 swarm + 24 lookalike
episodes take ~20 min (one centre), ``--per-frame`` ~30 min; ``--range-only`` is ~2x faster::

    python scripts/track_shape_oracle.py --per-frame

``--ceiling``: the per-frame F1 an *oracle tracker* could reach on the sequence benchmark's target window
(kin in view >= 10 frames, 0.3-2 m; ``kin_envs.detection.shape_oracle.ceiling_records`` / ``f1_ceiling``):
every kin that has moved 2 cm found, every wall and large obstacle rejected, still kin and 7 cm look-alikes
decided by the shape LLR summed over every frame so far (a centre per frame, true headings), with the
F1-best threshold per distance bin. No detector and no tracker run; ~1.5 min per swarm episode, seconds per
lookalike one. With ``--compare`` (a ``benchmark_tracking.py`` ``results.json``) it prints the tracker's
and the single scan's F1 on the same window beside it::

    python scripts/track_shape_oracle.py --ceiling --benchmark-seeds --noise 0 0.005 0.01 \
        --compare outputs/benchmark_tracking/results.json
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import add_logging_args, check_output_dir, setup_logging, write_run_info


def _f(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}"


def tables(samples: list[dict], frames=(10, 20)) -> list[str]:
    """Markdown rows: per split and frame count, AUC / kin kept at 95 % look-alikes rejected / look-alikes
    kept at 95 % kin kept, of the oracle LLR, the track classifier's probability and the mean score."""
    from kin_envs.detection.shape_oracle import roc_summary

    lines = ["| split | frames | still kin / look-alikes | statistic | AUC | kin kept at 95 % rejected | "
             "look-alikes kept at 95 % kin kept |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for split in sorted({s["split"] for s in samples}):
        for fr in frames:
            rows = [s for s in samples if s["split"] == split and s["frames"] == fr]
            pos = [s for s in rows if s["kin"]]
            neg = [s for s in rows if not s["kin"]]
            for name, key in (("oracle shape LLR", "llr"), ("track classifier", "track_prob"),
                              ("mean score logit", "mean_logit")):  # fmt: skip
                r = roc_summary([s[key] for s in pos], [s[key] for s in neg])
                lines.append(f"| {split} | {fr} | {len(pos)} / {len(neg)} | {name} | {_f(r['auc'])} | "
                             f"{_f(r['tpr_at_fpr05'])} | {_f(r['fpr_at_tpr95'])} |")  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--detector", default="learned",
                   help="detector feeding the tracker (geometric, learned, beam, module:Class)")
    p.add_argument("--swarm-episodes", type=int, default=4,
                   help="swarm episodes (with --benchmark-seeds: the reduced benchmark's 3)")
    p.add_argument("--lookalike-episodes", type=int, default=24,
                   help="lookalike episodes (with --benchmark-seeds: the reduced benchmark's 12)")
    p.add_argument("--first-seed", type=int, default=1000, help="first training seed (not a reserved one)")
    p.add_argument("--noise", type=float, nargs="+", default=[0.01],
                   help="relative lidar range noise (0.01 = 1 %%); several only with --ceiling")
    p.add_argument("--frames", type=int, nargs="+", default=[10, 20],
                   help="score each object once it has been in view this many frames")  # fmt: skip
    p.add_argument("--still", type=float, default=0.02, help="a kin is still if it moved less than this, m")
    p.add_argument("--true-poses", action="store_true",
                   help="ego-motion from the observer's true poses (no odometry drift) instead of odometry")
    p.add_argument("--per-frame", action="store_true",
                   help="fit each hypothesis' centre per frame (immune to odometry drift; shape kept)")
    p.add_argument("--range-only", action="store_true",
                   help="score only the range residuals, not the beams' silhouette (which beams hit)")
    p.add_argument("--benchmark-seeds", action="store_true",
                   help="run the benchmark's reduced episodes (reserved seeds) instead: report the bound "
                        "once, never choose a cue on them")  # fmt: skip
    p.add_argument("--full", action="store_true",
                   help="with --ceiling --benchmark-seeds: every episode of the benchmark's splits (40 "
                        "swarm + 120 lookalike, ~45 min at one noise level), not the reduced")  # fmt: skip
    p.add_argument("--ceiling", action="store_true",
                   help="the oracle tracker's per-frame F1 on the target window instead of the ROC tables")
    p.add_argument("--centre", choices=("frame", "one"), default="frame",
                   help="with --ceiling: a centre per frame, or one centre over all frames (~3x slower)")
    p.add_argument("--compare", type=Path, default=None,
                   help="with --ceiling: a benchmark_tracking.py results.json to print beside the ceiling")
    p.add_argument("--out", type=Path, default=Path("outputs/track_shape_oracle"), help="output directory")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads (learned detector)")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    if min(args.swarm_episodes, args.lookalike_episodes) < 0:
        p.error("--swarm-episodes and --lookalike-episodes must be >= 0")
    if any(f < 2 for f in args.frames):
        p.error(f"--frames must be >= 2, got {args.frames}")
    if args.ceiling:
        if not all(0 <= v <= 0.05 for v in args.noise):
            p.error(f"--noise must be relative range noise in [0, 0.05] (0.01 = 1 %), got {args.noise}")
    elif len(args.noise) != 1 or not 0 < args.noise[0] <= 0.05:
        p.error(f"--noise must be one relative range noise in (0, 0.05] (0.01 = 1 %), got {args.noise}")
    if args.full and not (args.ceiling and args.benchmark_seeds):
        p.error("--full needs --ceiling --benchmark-seeds")
    if args.compare is not None and not (args.ceiling and args.compare.is_file()):
        p.error(f"--compare needs --ceiling and an existing results.json, got {args.compare}")
    if not args.still > 0:
        p.error(f"--still must be > 0 m, got {args.still}")
    try:
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    if args.ceiling:
        return ceiling(args, argv)
    args.noise = args.noise[0]
    if args.detector == "learned":
        import torch

        torch.set_num_threads(args.torch_threads)
    from kin_envs.cli import detector_from_name
    from kin_envs.detection import sequences as S
    from kin_envs.detection.shape_oracle import oracle_samples

    t0 = time.perf_counter()
    det = detector_from_name(args.detector, what="--detector")
    samples = []
    for split, n in (("swarm", args.swarm_episodes), ("lookalike", args.lookalike_episodes)):
        if n:
            if args.benchmark_seeds:  # the reduced benchmark's episodes
                spec, n = S.SEQUENCE_SPLITS[split], None
            else:
                spec = S.training_split(split, args.first_seed)
            rec = S.record_sequences(det, spec, n, args.noise)
            samples += oracle_samples(rec, frames=args.frames, still=args.still, true_poses=args.true_poses,
                                      per_frame=args.per_frame, angle_sigma=0.0 if args.range_only else 5e-4,
                                      progress=True, benchmark_seeds=args.benchmark_seeds)  # fmt: skip
    ego = "true poses (no drift)" if args.true_poses else "odometry"
    ego += ", one centre per frame" if args.per_frame else ", one centre"
    ego += ", range residuals only" if args.range_only else ", range residuals + beam silhouettes"
    seeds = "benchmark seeds (reduced)" if args.benchmark_seeds else f"training seeds from {args.first_seed}"
    lines = [f"# Shape oracle: still kin vs still look-alikes ({args.detector}; noise "
             f"{100 * args.noise:g} %; ego-motion from {ego}; {seeds})", "",
             "Objects in view >= 2 beams for the given frames, at 0.3-2 m, still (kin moved < "
             f"{args.still:g} m); same-radius cylinders left out.", "",
             *tables(samples, args.frames)]  # fmt: skip
    _save(args, argv, t0, ("samples.json", samples), ("oracle.md", lines))
    return {"samples": samples, "lines": lines}


def _save(args, argv, t0: float, data: tuple[str, object], table: tuple[str, list[str]]) -> None:
    """Write the data (JSON) and the table (markdown) atomically, then the run record; print the table."""
    write_json(args.out / data[0], data[1])
    with atomic_write(args.out / table[0], "w") as f:
        f.write("\n".join(table[1]) + "\n")
    write_run_info(args.out, args, argv=argv, script=__file__, seed=args.first_seed,
                   seconds=time.perf_counter() - t0)  # fmt: skip
    print("\n".join(table[1]))


def _window(result: dict) -> dict:
    from kin_envs.detection.sequences import target_window

    return target_window(result)


def ceiling_tables(results: dict, compare: list | None = None) -> list[str]:
    """Markdown: per split and noise, the oracle tracker's F1 (its interval, P / R) on the target window,
    per distance bin, without shape evidence, the rows it counts, 7 cm prisms rejected after 20 frames,
    same-radius cylinders rejected once every kin seen moved (at 0.3-2 m); and, from a benchmark run's
    ``results`` (``compare``), the tracker's and the single scan's F1 on the same window and its rejection
    figures."""
    from kin_envs.detection.benchmark import DISTANCE_EDGES

    bench = {}
    for r in compare or []:
        w = {**_window(r), "_result": r}
        bench[(r["split"], round(float(r["noise"]), 6))] = w
    lines = ["| split | noise | ceiling F1 [95 % interval over episodes] (P / R) | 0.3-1 m | 1-2 m | "
             "no shape cue | kin rows: moving / still | look-alike rows | prisms rejected >= 20 frames | "
             "same-radius rejected | tracker F1 (0.3-1 / 1-2 m) | single scan | tracker: prisms / "
             "same-radius rejected |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for (split, noise), c in sorted(results.items()):
        bins = {f"{DISTANCE_EDGES[b]:g}-{DISTANCE_EDGES[b + 1]:g}": v for b, v in c["by_distance"].items()}
        pr = [v for k, v in c["rejected"].items() if k.startswith("prism")]
        prism = (sum(v[0] * v[1] for v in pr) / sum(v[1] for v in pr), sum(v[1] for v in pr)) if pr else None
        b = bench.get((split, round(noise, 6)))
        trk = (f"{_f(b['tracker']['all']['f1'])} ({_f(b['tracker']['0.3-1']['f1'])} / "
               f"{_f(b['tracker']['1-2']['f1'])})" if b else "–")  # fmt: skip
        single = _f(b["single"]["all"]["f1"]) if b and "single" in b else "–"
        sr = c["same_radius_rejected"]
        rej = "–"
        if b:
            lr = b["_result"]["lookalikes_rejected"].get("tracker", {})
            tp = [v for k, v in lr.items() if k == "prism"]
            tsr = b["_result"]["same_radius_rejected"].get("tracker")
            rej = (f"{'–' if not tp else f'{100 * tp[0][0]:.0f} %'} / "
                   f"{'–' if not tsr or not tsr[1] else f'{100 * tsr[0]:.0f} % of {tsr[1]}'}")  # fmt: skip
        lines.append(
            f"| {split} | {100 * noise:g} % | **{_f(c['f1'])}** [{_f(c['f1_ci'][0])}, {_f(c['f1_ci'][1])}] "
            f"({_f(c['precision'])} / {_f(c['recall'])}) | "
            f"{_f(bins.get('0.3-1', {}).get('f1'))} | {_f(bins.get('1-2', {}).get('f1'))} | "
            f"{_f(c['f1_no_shape'])} | {c['moving_kin_rows']} / {c['still_kin_rows']} | "
            f"{c['lookalike_rows']} | "
            f"{'–' if prism is None else f'{100 * prism[0]:.0f} % of {prism[1]}'} | "
            f"{'–' if not sr[1] else f'{100 * sr[0]:.0f} % of {sr[1]}'} | {trk} | {single} | {rej} |"
        )
    return lines


def ceiling(args, argv) -> dict:
    """``--ceiling``: the oracle tracker's per-frame F1 per split and noise (see the module docstring)."""
    import json

    from kin_envs.detection import sequences as S
    from kin_envs.detection.shape_oracle import ceiling_records, f1_ceiling

    t0 = time.perf_counter()
    compare = json.loads(args.compare.read_text())["results"] if args.compare else None
    results, records = {}, {}
    for split, n in (("swarm", args.swarm_episodes), ("lookalike", args.lookalike_episodes)):
        if not n:
            continue
        spec = S.SEQUENCE_SPLITS[split] if args.benchmark_seeds else S.training_split(split, args.first_seed)
        if args.benchmark_seeds:  # the reduced benchmark's episodes, or (--full) all of them
            n = spec.n_episodes if args.full else spec.reduced_episodes
        for noise in args.noise:
            rows = ceiling_records(spec, n, noise, still=args.still,
                                   centre=args.centre, progress=True,
                                   benchmark_seeds=args.benchmark_seeds)  # fmt: skip
            results[(split, float(noise))] = f1_ceiling(rows)
            records[f"{split} {noise:g}"] = rows
    seeds = (f"benchmark seeds ({'full' if args.full else 'reduced'})" if args.benchmark_seeds
             else f"training seeds from {args.first_seed}")  # fmt: skip
    lines = [f"# The oracle tracker's per-frame F1 on the target window ({seeds})", "",
             "Kin in view >= 10 frames at 0.3-2 m (the sequence benchmark's window and ground truth). A kin "
             f"that moved >= {args.still:g} m since the observer first saw it is always found; walls and "
             "large obstacles always rejected; still kin and 7 cm look-alikes decided by the shape LLR over "
             "every frame so far (" + ("one centre over all frames, true poses" if args.centre == "one" else
             "centre per frame, true headings") + "), the F1-best threshold per distance bin.",
             "", *ceiling_tables(results, compare)]  # fmt: skip
    out = {f"{k[0]} {k[1]:g}": v for k, v in results.items()}
    _save(args, argv, t0, ("ceiling.json", {"ceiling": out, "records": records}), ("ceiling.md", lines))
    return {"ceiling": out, "lines": lines}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
