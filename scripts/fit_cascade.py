"""Fit the learned detector's cascade: a cheap first stage that spares most segments the full model.

The full model (features + network) costs ~1 us per segment; most segments of a cluttered scan are
plainly not a housing. The cascade's first stage scores each segment the pre-gate keeps from
:data:`detectors.features.CASCADE_FEATURES` (segment size, range, the paper's eqs. 4-5 widths,
chord, context beams, scan noise: no circle fit, no local frame) with a one-hidden-layer network, and
only segments scoring at least its threshold go on to the features and the network.

This script, on scenes drawn like the checkpoint's training data (training seeds only, never the
benchmark's reserved ones):

1. on ``--scenes`` fitting scenes, computes every pre-gated segment's stage-1 inputs and the full
   model's decision at the lowest of the checkpoint's ``p(kin)`` thresholds, and trains the stage-1
   network (seeded) to score the segments the full model accepts high;
2. chooses the threshold on the fitting scenes only: the ``(1 - --fit-retention)`` quantile of the
   scores of the kin segments the full model accepts;
3. validates the written cascade end to end on ``--val-scenes`` other scenes: the detector with and
   without it, every kin segment the full model accepts that the cascade loses (requirement: at
   most ``1 - --retention``, i.e. >= 99.9 % kept), and the share of segments that skip the model.

Writes ``learned.cascade.json`` (the stage-1 model), ``results.json``, ``results.md`` and ``run.json``
to ``--out``; ``--replace-shipped`` also installs the cascade next to the shipped checkpoint
(``detectors/checkpoints/learned_default.cascade.json``), only if the requirement is met::

    python scripts/fit_cascade.py --out outputs/cascade            # ~2 min on 2 busy cores
    python scripts/fit_cascade.py --out outputs/cascade --replace-shipped
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

#: noise bins of the table (relative range noise drawn per scene), as scripts/validate_pre_gate.py
NOISE_BINS = ((0.0, 0.0), (1e-9, 0.005), (0.005, 0.01), (0.01, 0.015), (0.015, 0.021))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=int, default=1600, help="fitting scenes (each scans several robots)")
    p.add_argument(
        "--first-seed", type=int, default=200_400,
        help="first fitting scene seed (training seeds; the shipped checkpoint trained on 0-2999 and "
        "100000-103599)",
    )  # fmt: skip
    p.add_argument("--val-scenes", type=int, default=400, help="validation scenes (other seeds)")
    p.add_argument("--val-first-seed", type=int, default=200_000, help="first validation scene seed")
    p.add_argument("--hidden", type=int, default=16, help="hidden units of the stage-1 network")
    p.add_argument("--epochs", type=int, default=40, help="Adam epochs of the stage-1 fit")
    p.add_argument("--batch-size", type=int, default=4096, help="segments per Adam step")
    p.add_argument("--pos-weight", type=float, default=20.0, help="loss weight of accepted segments")
    p.add_argument(
        "--fit-retention", type=float, default=0.9995,
        help="share of the fitting scenes' accepted kin segments the threshold keeps (a margin over "
        "--retention)",
    )  # fmt: skip
    p.add_argument(
        "--retention", type=float, default=0.999,
        help="requirement on the validation scenes: share of accepted kin segments kept",
    )
    p.add_argument("--seed", type=int, default=0, help="torch seed of the stage-1 fit")
    p.add_argument(
        "--checkpoint", type=Path, default=None, help="learned checkpoint (default: the shipped one)"
    )
    p.add_argument("--out", type=Path, default=Path("outputs/cascade"), help="output directory")
    p.add_argument(
        "--replace-shipped", action="store_true",
        help="also write the cascade next to the checkpoint (detectors/checkpoints/...cascade.json) if "
        "the validation meets --retention",
    )  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_logging_args(p)
    args = p.parse_args(argv)
    if min(args.scenes, args.val_scenes, args.hidden, args.epochs, args.batch_size) < 1:
        p.error("--scenes, --val-scenes, --hidden, --epochs and --batch-size must be >= 1")
    if not (0.0 < args.retention <= 1.0 and 0.0 < args.fit_retention <= 1.0) or args.pos_weight <= 0:
        p.error("--retention and --fit-retention must be in (0, 1], --pos-weight > 0")
    fit = range(args.first_seed, args.first_seed + args.scenes)
    val = range(args.val_first_seed, args.val_first_seed + args.val_scenes)
    if set(fit) & set(val):
        p.error(f"fitting seeds {fit.start}-{fit.stop - 1} and validation seeds {val.start}-{val.stop - 1} "
                "overlap")
    check_training_seeds(fit, "--first-seed")
    check_training_seeds(val, "--val-first-seed")
    return args


def _dataset_config(checkpoint):
    """The training data's scene mix, from the checkpoint's JSON card if it has one (as
    scripts/validate_pre_gate.py)."""
    from kin_envs.detection.dataset import DatasetConfig

    card = Path(checkpoint["path"]).with_suffix(".json")
    if card.is_file():
        data = json.loads(card.read_text()).get("data", {})
        if isinstance(data, list):  # several --data directories: the first (base) mix
            data = data[0] if data else {}
        if data.get("dataset_config"):
            return DatasetConfig.from_dict(data["dataset_config"])
    return DatasetConfig(swarm_prob=0.35, dropout_share=0.25)


def _scenes(seeds, det, progress: bool, desc: str):
    """``(seed, noise, batch, scan, kin labels, windows)`` of each scene with segments (the checkpoint's
    mix); ``windows``: with the detector's candidate windows (``det.windows``), ``(Windows, kin labels)``
    of those the pre-gate's bound keeps (as the detector does), else None."""
    from tqdm import tqdm

    from kin_envs.detection.dataset import scene_records

    config = _dataset_config(det.checkpoint)
    for seed in tqdm(seeds, desc=desc, disable=not progress):
        segs, _, info = scene_records(seed, config, det.feature_config, windows=det.window_config)
        if info["batch"].n_segments:
            label = segs["label"] > 0
            win = None
            if det.windows:
                is_win = segs["window"] == 1
                w = info["windows"]
                ok = np.flatnonzero(w.batch.count <= det.gate(w.batch))
                win = (_subset(w.batch, ok), label[is_win][ok])
                label = label[~is_win]
            yield seed, float(info["noise"]), info["batch"], info["scan"], label, win


def _subset(batch, rows):
    """The segments ``rows`` of a SegmentBatch."""
    import dataclasses

    cols = ("scan", "first", "count", "prev_beam", "next_beam", "prev_nearer", "next_nearer")
    return dataclasses.replace(batch, **{k: getattr(batch, k)[rows] for k in cols})


def window_scores(det, wb) -> tuple[np.ndarray, np.ndarray]:
    """``(p(kin), window threshold)`` of the candidate windows ``wb`` (a SegmentBatch) as the detector
    scores them (the same network; it accepts a window at max(segment threshold, window threshold of the
    scan's noise))."""
    from detectors.features import segment_features

    feats = segment_features(wb, det.feature_config)
    p = 1.0 / (1.0 + np.exp(-det._forward(feats.x)[:, 0]))
    return p, det.window_thresholds(feats.x[:, det._noise_col])


def collect(seeds, det, min_p: float, progress: bool) -> dict[str, np.ndarray]:
    """Stage-1 inputs ``x`` of every pre-gated segment, the full model's acceptance at ``min_p``
    (``acc``) and the kin labels; with candidate windows also theirs (accepted at max(``min_p``, the
    window threshold)), ``window`` marking their rows."""
    from detectors.features import cascade_features

    xs, accs, kins, wins = [], [], [], []
    for _, _, batch, scan, kin, win in _scenes(seeds, det, progress, "fitting scenes"):
        _, _, p, _ = det.predict_segments(scan.ranges, scan.angles)
        keep = np.flatnonzero(batch.count <= det.gate(batch))
        xs.append(cascade_features(batch, det.feature_config, keep))
        accs.append(p[keep] >= min_p)
        kins.append(kin[keep])
        wins.append(np.zeros(keep.size, bool))
        if win is not None and win[0].n_segments:
            wb, w_kin = win
            pw, w_thr = window_scores(det, wb)
            xs.append(cascade_features(wb, det.feature_config, np.arange(wb.n_segments)))
            accs.append(pw >= np.maximum(w_thr, min_p))
            kins.append(w_kin)
            wins.append(np.ones(wb.n_segments, bool))
    return {"x": np.concatenate(xs), "acc": np.concatenate(accs), "kin": np.concatenate(kins),
            "window": np.concatenate(wins)}  # fmt: skip


def fit_stage1(data: dict, hidden: int, epochs: int, batch_size: int, pos_weight: float, seed: int) -> tuple:
    """A ``len(CASCADE_FEATURES) -> hidden -> 1`` network (float64 export ``(mean, std, w1, b1, w2,
    b2)``) trained by Adam (cosine learning rate) on weighted BCE to score accepted segments high."""
    import torch

    x = data["x"]
    mean, std = x.mean(0), x.std(0)
    std = np.where(std > 1e-9, std, 1.0)
    torch.manual_seed(seed)
    torch.set_num_threads(1)  # a 12-16-1 network: more threads only contend on a shared machine
    xt = torch.tensor((x - mean) / std, dtype=torch.float32)
    y = torch.tensor(data["acc"], dtype=torch.float32)
    w = torch.where(y > 0, pos_weight, 1.0)
    nn = torch.nn
    net = nn.Sequential(nn.Linear(x.shape[1], hidden), nn.ReLU(), nn.Linear(hidden, 1))
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(seed)
    n_steps = epochs * -(-xt.shape[0] // batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, n_steps)
    for _ in range(epochs):
        for i in torch.randperm(xt.shape[0], generator=gen).split(batch_size):
            opt.zero_grad()
            bce = nn.functional.binary_cross_entropy_with_logits(net(xt[i])[:, 0], y[i], reduction="none")
            (bce * w[i]).mean().backward()
            opt.step()
            sched.step()
    f64 = lambda t: t.detach().numpy().astype(np.float64)  # noqa: E731
    b2 = float(net[2].bias.detach()[0])
    return mean, std, f64(net[0].weight), f64(net[0].bias), f64(net[2].weight)[0], b2


def stage1_scores(model: tuple, x: np.ndarray) -> np.ndarray:
    mean, std, w1, b1, w2, b2 = model
    return np.maximum((x - mean) / std @ w1.T + b1, 0.0) @ w2 + b2


def validate(seeds, det_full, det_cas, progress: bool) -> dict:
    """The detector with the cascade against the same detector without, per noise bin. With candidate
    windows, the windows' detections too (``window_*``: a detection whose segment the pre-gate dropped;
    kin by its window's label), and ``kin_accepted`` / ``kin_accepted_lost`` count segments and windows."""
    keys = ("scenes", "segments", "gated", "cascaded", "kin", "kin_accepted", "kin_accepted_lost",
            "accepted", "accepted_lost", "accepted_gained", "windows", "window_kin", "window_accepted",
            "window_kin_accepted", "window_kin_accepted_lost", "window_accepted_lost",
            "window_accepted_gained")  # fmt: skip
    per = {b: dict.fromkeys(keys, 0) for b in NOISE_BINS}
    for _, noise, batch, scan, kin, win in _scenes(seeds, det_full, progress, "validation scenes"):
        full = det_full.detect_arrays(scan.ranges, scan.angles)
        cas = det_cas.detect_arrays(scan.ranges, scan.angles)
        assert np.array_equal(full.seg_first, batch.first) and np.array_equal(cas.seg_first, batch.first)
        a_full, a_cas = full.seg_stage == 0, cas.seg_stage == 0
        gated = full.seg_stage == 1
        c = {
            "scenes": 1, "segments": batch.n_segments, "gated": int(gated.sum()),
            "cascaded": int((np.isnan(cas.seg_values["p_kin"]) & ~gated).sum()), "kin": int(kin.sum()),
            "kin_accepted": int((kin & a_full).sum()),
            "kin_accepted_lost": int((kin & a_full & ~a_cas).sum()),
            "accepted": int(a_full.sum()), "accepted_lost": int((a_full & ~a_cas).sum()),
            "accepted_gained": int((a_cas & ~a_full).sum()),
        }  # fmt: skip
        if win is not None:
            wb, w_kin = win
            kin_keys = set(zip(wb.scan[w_kin].tolist(), wb.first[w_kin].tolist(), wb.count[w_kin].tolist(),
                               strict=True))  # fmt: skip

            def window_dets(a):
                w = a.seg_stage[a.segment] == 1  # (a window's segment is one the pre-gate dropped)
                return set(zip(a.scan[w].tolist(), a.first_beam[w].tolist(), a.n_beams_on[w].tolist(),
                               strict=True))

            w_full, w_cas = window_dets(full), window_dets(cas)
            c.update({
                "windows": wb.n_segments, "window_kin": len(kin_keys), "window_accepted": len(w_full),
                "window_kin_accepted": len(w_full & kin_keys),
                "window_kin_accepted_lost": len((w_full - w_cas) & kin_keys),
                "window_accepted_lost": len(w_full - w_cas), "window_accepted_gained": len(w_cas - w_full),
            })  # fmt: skip
            c["kin_accepted"] += c["window_kin_accepted"]
            c["kin_accepted_lost"] += c["window_kin_accepted_lost"]
        nb = next(b for b in NOISE_BINS if b[0] <= noise <= b[1])
        for k, v in c.items():
            per[nb][k] += v
    tot = {k: sum(c[k] for c in per.values()) for k in keys}

    def shares(c):
        return {
            **c,
            "cascaded_share": c["cascaded"] / max(c["segments"], 1),
            "cascaded_of_gate_kept": c["cascaded"] / max(c["segments"] - c["gated"], 1),
            "kin_accepted_kept": 1.0 - c["kin_accepted_lost"] / max(c["kin_accepted"], 1),
            "window_kin_accepted_kept": 1.0 - c["window_kin_accepted_lost"] / max(c["window_kin_accepted"],
                                                                                  1),
        }

    return {"totals": shares(tot), "per_noise": {f"{lo:g}-{hi:g}": shares(c) for (lo, hi), c in per.items()}}


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    setup_logging(args)
    out = check_output_dir(args.out)
    from detectors.features import CASCADE_FEATURES, FEATURE_VERSION
    from detectors.learned import (
        CASCADE_FORMAT,
        CASCADE_FORMAT_VERSION,
        LearnedKinDetector,
        cascade_path,
    )

    progress = not args.no_progress
    t0 = time.perf_counter()
    det = LearnedKinDetector(args.checkpoint, reports=False, cascade=False)
    min_p = float(det._noise_thresholds.min())
    fit_seeds = range(args.first_seed, args.first_seed + args.scenes)
    val_seeds = range(args.val_first_seed, args.val_first_seed + args.val_scenes)
    data = collect(fit_seeds, det, min_p, progress)
    model = fit_stage1(data, args.hidden, args.epochs, args.batch_size, args.pos_weight, args.seed)
    s = stage1_scores(model, data["x"])
    ref = s[data["acc"] & data["kin"]]  # (segments and candidate windows)
    if ref.size == 0:
        raise ValueError(
            "fit_cascade: the fitting scenes hold no kin segment the model accepts; use more --scenes"
        )
    # just below the quantile: float64 sums in the kernel may differ from numpy's in the last bits
    threshold = float(np.quantile(ref, 1.0 - args.fit_retention)) - 1e-9
    fit_stats = {
        "segments_after_pre_gate": int(s.size),
        "accepted": int(data["acc"].sum()),
        "kin_accepted": int(ref.size),
        "kin_accepted_kept": float((ref >= threshold).mean()),
        "accepted_kept": float((s[data["acc"]] >= threshold).mean()),
        "cascaded_share": float((s < threshold).mean()),
        "windows": int(data["window"].sum()),
        "window_kin_accepted": int((data["acc"] & data["kin"] & data["window"]).sum()),
        "window_kin_accepted_kept": float((s[data["acc"] & data["kin"] & data["window"]] >= threshold).mean())
        if (data["acc"] & data["kin"] & data["window"]).any() else None,
    }
    mean, std, w1, b1, w2, b2 = model
    card = {
        "format": CASCADE_FORMAT,
        "format_version": CASCADE_FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "features": list(CASCADE_FEATURES),
        "checkpoint_weights_sha256": det.checkpoint.get("weights_sha256"),
        "mean": mean.tolist(), "std": std.tolist(), "w1": w1.tolist(), "b1": b1.tolist(),
        "w2": w2.tolist(), "b2": b2,
        "threshold": threshold,
        "min_p_threshold": min_p,
        "info": {
            "fit_seeds": [fit_seeds.start, fit_seeds.stop - 1],
            "val_seeds": [val_seeds.start, val_seeds.stop - 1],
            "fit": fit_stats,
            "config": {k: v for k, v in vars(args).items() if k in ("hidden", "epochs", "batch_size",
                                                                     "pos_weight", "fit_retention", "seed")},
        },
    }  # fmt: skip
    card_path = out / "learned.cascade.json"
    write_json(card_path, card)
    det_cas = LearnedKinDetector(args.checkpoint, reports=False, cascade=card_path)
    val = validate(val_seeds, det, det_cas, progress)
    met = val["totals"]["kin_accepted_kept"] >= args.retention
    card["info"]["validation"] = val["totals"]
    write_json(card_path, card)
    shipped = None
    if args.replace_shipped:
        if not met:
            raise SystemExit(
                f"fit_cascade: validation kept {val['totals']['kin_accepted_kept']:.5f} of the accepted kin "
                f"segments (< --retention {args.retention}); not replacing the shipped cascade"
            )
        shipped = cascade_path(det.checkpoint["path"])
        write_json(shipped, card)
    result = {
        "fit": fit_stats,
        "validation": val,
        "threshold": threshold,
        "min_p_threshold": min_p,
        "requirement": args.retention,
        "requirement_met": met,
        "checkpoint": det.checkpoint["path"],
        "cascade": str(card_path),
        "shipped": None if shipped is None else str(shipped),
        "seconds": time.perf_counter() - t0,
    }
    write_json(out / "results.json", result)
    with atomic_write(out / "results.md", "w") as f:
        f.write(to_markdown(result))
    write_run_info(out, args, seed=args.seed, argv=argv, results=result["validation"]["totals"])
    if not args.quiet:
        print(to_markdown(result))
    return result


def to_markdown(result: dict) -> str:
    fit = result["fit"]
    lines = [
        f"Fitting scenes: {fit['segments_after_pre_gate']:,} segments after the pre-gate, "
        f"{fit['kin_accepted']:,} kin segments the full model accepts; threshold {result['threshold']:.4f} "
        f"keeps {100 * fit['kin_accepted_kept']:.3f} % of them and skips {100 * fit['cascaded_share']:.1f} % "
        "of the segments.",
        "",
        "| scene noise (validation) | segments | pre-gate | cascade | of the pre-gate's survivors | "
        "kin accepted | lost | kept | accepted lost / gained |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    v = result["validation"]
    for name, c in list(v["per_noise"].items()) + [("all", v["totals"])]:
        if not c["segments"]:
            continue
        lines.append(
            f"| {name} | {c['segments']:,} | {c['gated']:,} | {c['cascaded']:,} "
            f"({100 * c['cascaded_share']:.1f} %) | {100 * c['cascaded_of_gate_kept']:.1f} % | "
            f"{c['kin_accepted']:,} | {c['kin_accepted_lost']} | {100 * c['kin_accepted_kept']:.3f} % | "
            f"{c['accepted_lost']} / {c['accepted_gained']} |"
        )
    lines.append("")
    t = v["totals"]
    if t.get("windows"):
        lines += [
            f"Candidate windows (validation): {t['windows']:,} cut, {t['window_accepted']:,} accepted, "
            f"of them {t['window_kin_accepted']:,} kin; the cascade loses {t['window_kin_accepted_lost']} "
            "of those "
            f"({100 * t['window_kin_accepted_kept']:.3f} % kept; counted in 'kin accepted' above) and "
            f"{t['window_accepted_lost']} / gains {t['window_accepted_gained']} accepted windows.",
            "",
        ]
    lines.append(
        f"Requirement (>= {100 * result['requirement']:g} % of the accepted kin segments kept on the "
        f"validation seeds): {'met' if result['requirement_met'] else 'NOT met'}."
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
