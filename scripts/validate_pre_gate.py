"""Check the learned detector's pre-gate on training-seed scenes: what does it drop?

The pre-gate (``LearnedKinDetector(pre_gate=True)``, the default) drops a segment before its features
and the network when it has more beams than a 7 cm housing can return at its range (see the
detector's docstring). This script measures, on scenes drawn like the shipped checkpoint's training
data (its ``dataset_config``; seeds outside the training seeds and the benchmark's reserved ones),
every segment's ``p(kin)`` *without* the gate and which segments the gate would drop:

* kin segments (labelled kin: most of their beams on one robot's housing) the network accepts that
  the gate drops: the requirement is <= 0.1 % of the accepted kin;
* all kin segments the gate drops (whatever the network says), and the non-kin the network accepted
  that the gate drops (false positives it removes);
* the share of segments and of beams that no longer reach the features and the network.

Writes ``results.json``, ``results.md`` and ``run.json`` to ``--out``::

    python scripts/validate_pre_gate.py --scenes 400 --out outputs/pre_gate
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import add_logging_args, check_output_dir, setup_logging, write_run_info
from kin_envs.detection.seeds import check_training_seeds

#: noise bins of the table (relative range noise drawn per scene)
NOISE_BINS = ((0.0, 0.0), (1e-9, 0.005), (0.005, 0.01), (0.01, 0.015), (0.015, 0.021))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=int, default=400, help="scenes to draw (each scans several robots)")
    p.add_argument(
        "--first-seed", type=int, default=100_000,
        help="first scene seed (the shipped checkpoint trained on seeds 0-2999; the benchmark's "
        "reserved seeds are refused)",
    )  # fmt: skip
    p.add_argument(
        "--checkpoint", type=Path, default=None, help="learned checkpoint (default: the shipped one)"
    )
    p.add_argument("--out", type=Path, default=Path("outputs/pre_gate"), help="output directory")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(p)
    args = p.parse_args(argv)
    if args.scenes < 1:
        p.error(f"--scenes must be >= 1, got {args.scenes}")
    check_training_seeds(range(args.first_seed, args.first_seed + args.scenes), "--first-seed")
    return args


def _dataset_config(checkpoint):
    """The training data's scene mix, from the checkpoint's JSON card if it has one."""
    from kin_envs.detection.dataset import DatasetConfig

    card = Path(checkpoint["path"]).with_suffix(".json")
    if card.is_file():
        d = json.loads(card.read_text()).get("data", {}).get("dataset_config")
        if d:
            return DatasetConfig.from_dict(d)
    return DatasetConfig(swarm_prob=0.35, dropout_share=0.25)


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    setup_logging(args)
    out = check_output_dir(args.out)
    from tqdm import tqdm

    from detectors.learned import LearnedKinDetector
    from detectors.samples import CATEGORIES
    from kin_envs.detection.dataset import scene_records

    det = LearnedKinDetector(args.checkpoint, reports=False, pre_gate=False)
    fc = det.feature_config
    config = _dataset_config(det.checkpoint)
    keys = ("segments", "beams", "gated", "gated_beams", "kin", "kin_accepted", "kin_gated",
            "kin_accepted_gated", "nonkin_accepted", "nonkin_accepted_gated")  # fmt: skip
    totals = {k: 0 for k in keys}
    per_noise = {b: dict.fromkeys(keys, 0) for b in NOISE_BINS}
    by_category: dict[str, int] = {}
    t0 = time.perf_counter()
    seeds = range(args.first_seed, args.first_seed + args.scenes)
    for seed in tqdm(seeds, desc="scenes", disable=args.no_progress):
        segs, _, info = scene_records(seed, config, fc)
        batch = info["batch"]
        if batch.n_segments == 0:
            continue
        scan = info["scan"]
        # every segment through the network (no gate): the same segments as the labels' batch
        b2, feats, p, _ = det.predict_segments(scan.ranges, scan.angles)
        assert np.array_equal(b2.first, batch.first) and np.array_equal(b2.scan, batch.scan)
        acc = p >= det.segment_thresholds(feats)
        gated = batch.count > det.gate(batch)
        kin = segs["label"] > 0
        c = {
            "segments": batch.n_segments, "beams": int(batch.count.sum()), "gated": int(gated.sum()),
            "gated_beams": int(batch.count[gated].sum()), "kin": int(kin.sum()),
            "kin_accepted": int((kin & acc).sum()), "kin_gated": int((kin & gated).sum()),
            "kin_accepted_gated": int((kin & acc & gated).sum()),
            "nonkin_accepted": int((~kin & acc).sum()),
            "nonkin_accepted_gated": int((~kin & acc & gated).sum()),
        }  # fmt: skip
        noise = float(info["noise"])
        nb = next(b for b in NOISE_BINS if b[0] <= noise <= b[1])
        for k, v in c.items():
            totals[k] += v
            per_noise[nb][k] += v
        for code in np.unique(segs["category"][gated]):
            name = CATEGORIES[int(code)]
            by_category[name] = by_category.get(name, 0) + int((segs["category"][gated] == code).sum())
    seconds = time.perf_counter() - t0

    def shares(c):
        return {
            **c,
            "gated_share": c["gated"] / max(c["segments"], 1),
            "gated_beams_share": c["gated_beams"] / max(c["beams"], 1),
            "kin_accepted_gated_share": c["kin_accepted_gated"] / max(c["kin_accepted"], 1),
            "kin_gated_share": c["kin_gated"] / max(c["kin"], 1),
        }

    result = {
        "totals": shares(totals),
        "per_noise": {f"{lo:g}-{hi:g}": shares(c) for (lo, hi), c in per_noise.items()},
        "gated_by_category": dict(sorted(by_category.items(), key=lambda kv: -kv[1])),
        "seeds": [seeds.start, seeds.stop - 1],
        "checkpoint": det.checkpoint["path"],
        "bounds": {"slack": _gate_constants()[0], "margin_beams": _gate_constants()[1]},
        "seconds": seconds,
        "requirement_met": shares(totals)["kin_accepted_gated_share"] <= 0.001,
    }
    write_json(out / "results.json", result)
    with atomic_write(out / "results.md", "w") as f:
        f.write(to_markdown(result))
    write_run_info(out, args, seed=[seeds.start, seeds.stop - 1], argv=argv, results=result["totals"])
    if not args.quiet:
        print(to_markdown(result))
    return result


def _gate_constants() -> tuple[float, int]:
    from detectors.learned import PRE_GATE_MARGIN, PRE_GATE_SLACK

    return PRE_GATE_SLACK, PRE_GATE_MARGIN


def to_markdown(result: dict) -> str:
    lines = [
        "| scene noise | segments | dropped | beams dropped | kin | kin accepted | accepted kin dropped | "
        "kin dropped | non-kin accepted dropped |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, c in list(result["per_noise"].items()) + [("all", result["totals"])]:
        if not c["segments"]:
            continue
        lines.append(
            f"| {name} | {c['segments']:,} | {c['gated']:,} ({100 * c['gated_share']:.1f} %) | "
            f"{100 * c['gated_beams_share']:.1f} % | {c['kin']:,} | {c['kin_accepted']:,} | "
            f"{c['kin_accepted_gated']} ({100 * c['kin_accepted_gated_share']:.3f} %) | {c['kin_gated']} | "
            f"{c['nonkin_accepted_gated']} of {c['nonkin_accepted']:,} |"
        )
    lines.append("")
    lines.append(
        "Dropped segments by category: "
        + ", ".join(f"{k} {v:,}" for k, v in result["gated_by_category"].items())
    )
    lines.append(
        f"Seeds {result['seeds'][0]}-{result['seeds'][1]}; requirement (<= 0.1 % of the accepted kin "
        f"dropped): {'met' if result['requirement_met'] else 'NOT met'}."
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
