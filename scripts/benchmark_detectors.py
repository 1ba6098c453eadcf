"""The kin detection benchmark (``kin_envs.detection.benchmark``): AP, P / R / F1, PR curves.

Runs detectors on the benchmark's fixed splits (``paper``, ``swarm``, ``lookalike``; seeds reserved
for the benchmark) at every lidar condition (range noise 0 / 0.5 / 1 / 2 %, 10 % beam dropout) and
writes to ``--out``:

* ``results.md``: per split and condition, per detector and bin (all, distance, beams on target):
  AP, P / R / F1 at the shipped operating point with 95 % bootstrap intervals over scenes, peak F1,
  centre error; false positives per distractor kind; scans/s;
* ``results.json``: the same as data (``BenchmarkResults.to_dict()``);
* ``pr_<split>.png``: precision-recall curves, one panel per condition, every detector (operating
  point marked);
* ``run.json``: command, arguments, benchmark version, split configs and seeds, versions, timing.

Sizes: the reduced size (default; what the main job runs), ``--full`` (the benchmark's full size)
or ``--scenes N`` per split. Detectors: ``geometric``, ``learned``, ``beam`` or ``module:Class``
(as ``scripts/evaluate_detectors.py``).

Example::

    python scripts/benchmark_detectors.py --detectors geometric learned
    python scripts/benchmark_detectors.py --detectors geometric learned --full --out outputs/benchmark_full
    python scripts/benchmark_detectors.py --splits swarm --scenes 10 --noise 0.01
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    detector_from_name,
    noise_level,
    script_logger,
    setup_logging,
)
from kin_envs.detection.benchmark import (
    BENCHMARK_VERSION,
    CONDITIONS,
    GATE,
    MIN_BEAMS,
    SPLITS,
    BenchmarkResults,
    Condition,
    run_benchmark,
)

# --------------------------------------------------------------------------- report


def _f(v, digits=2) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _ci(v, ci, digits=2) -> str:
    s = _f(v, digits)
    if s == "–" or ci is None or any(c is None or (isinstance(c, float) and math.isnan(c)) for c in ci):
        return s
    return f"{s} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def _bin_name(r) -> str:
    if r["bin"] == "all":
        return "all"
    if r["bin"] == "distance":
        return f"{r['lo']:g}–{r['hi']:g} m"
    hi = int(r["hi"]) - 1
    return (
        f"{int(r['lo'])} beams"
        if hi == int(r["lo"])
        else f"{int(r['lo'])}–{hi} beams"
        if hi < 360
        else f"≥ {int(r['lo'])} beams"
    )


def headline_table(res: BenchmarkResults, split: str, detectors, conditions) -> list[str]:
    """One row per condition x detector: AP and F1 (95 % CI) overall and per distance bin."""
    dist = [r for r in res.rows if r["split"] == split and r["bin"] == "distance"]
    edges = sorted({(r["lo"], r["hi"]) for r in dist})
    head = "| condition | detector | all: AP / P / R / F1 | " + " | ".join(
        f"{lo:g}–{hi:g} m: AP / F1 [95 % CI]" for lo, hi in edges
    )
    lines = [head + " |", "|---|---|---|" + "---|" * len(edges)]
    for c in conditions:
        for d in detectors:
            rows = res.select(split=split, detector=d, noise=c.noise, dropout=c.dropout)
            if not rows:
                continue
            a = next(r for r in rows if r["bin"] == "all")
            cells = [
                f"{_f(a['ap'])} / {_f(a['precision'])} / {_f(a['recall'])} / **{_ci(a['f1'], a['f1_ci'])}**"
            ]
            for lo, _hi in edges:
                b = next((r for r in rows if r["bin"] == "distance" and r["lo"] == lo), None)
                cells.append(
                    "–" if b is None or b["n_kin"] == 0 else f"{_f(b['ap'])} / {_ci(b['f1'], b['f1_ci'])}"
                )
            lines.append(f"| {c.name} | {d} | " + " | ".join(cells) + " |")
    return lines


def report(res: BenchmarkResults, detectors, conditions, seconds: float) -> str:
    cfg = res.config
    out = [
        f"# Kin detection benchmark v{BENCHMARK_VERSION}",
        "",
        f"Size: {cfg['size']}; gate {GATE} m (Hungarian on centres); a kin counts when >= {MIN_BEAMS} valid "
        "beams hit its housing (1 beam: don't care); same-radius cylinder detections counted apart. "
        f"95 % percentile bootstrap over scenes ({cfg['n_resamples']} resamples). AP from the permissive "
        "run (ranked by Detection.score), P / R / F1 at the shipped operating point. "
        f"Total {seconds:.0f} s.",
        "",
    ]
    for split, info in cfg["splits"].items():
        out += [
            f"## {split}: {info['n_scenes']} scenes, seeds {info['seeds'][0]}–{info['seeds'][1]}",
            "",
            *headline_table(res, split, detectors, conditions),
            "",
        ]
        for c in conditions:
            out += [f"### {split}, {c.name}", ""]
            out += [
                "| detector | bin | kin | AP [95 % CI] | P [95 % CI] | R [95 % CI] | F1 [95 % CI] | peak F1 "
                "| centre error median / p95, cm |",
                "|---|---|---:|---|---|---|---|---:|---|",
            ]
            for d in detectors:
                for r in res.select(split=split, detector=d, noise=c.noise, dropout=c.dropout):
                    if r["n_kin"] == 0 and r["bin"] != "all":
                        continue
                    out.append(
                        f"| {d} | {_bin_name(r)} | {r['n_kin']} | {_ci(r['ap'], r['ap_ci'])} | "
                        f"{_ci(r['precision'], r['precision_ci'])} | {_ci(r['recall'], r['recall_ci'])} | "
                        f"{_ci(r['f1'], r['f1_ci'])} | {_f(r['peak_f1'])} | "
                        f"{_f(100 * r['error_median'])} / {_f(100 * r['error_p95'])} |"
                    )
            out.append("")
            for d in detectors:
                ex = res.extras.get((d, split, c.name))
                if ex is None:
                    continue
                fps = ", ".join(f"{k}: {v}" for k, v in ex["false_positives"].items()) or "none"
                miss = ", ".join(f"{k}: {v}" for k, v in ex["misses"].items() if v) or "none"
                out.append(
                    f"- {d}: {ex['n_scans']} scans, {ex['scans_per_second']:.0f} scans/s (warm, shipped "
                    f"operating point); false positives by kind: {fps}; on same-radius cylinders (apart): "
                    f"{ex['same_radius']} (of {ex['same_radius_seen']} seen by >= 2 beams); "
                    f"missed kin: {miss}"
                )
            out.append("")
    return "\n".join(out)


def plot_pr(res: BenchmarkResults, split: str, detectors, conditions, path: Path) -> None:
    """PR curves of one split, one panel per condition; written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(conditions)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.8 * rows), squeeze=False)
    for ax, c in zip(axes.flat, conditions, strict=False):
        for d in detectors:
            ex = res.extras.get((d, split, c.name))
            if not ex or not ex["pr_curve"]:
                continue
            pr = ex["pr_curve"]
            a = res.select(split=split, detector=d, noise=c.noise, dropout=c.dropout, bin="all")[0]
            (line,) = ax.plot(
                [0.0, *pr["recall"]], [pr["precision"][0], *pr["precision"]], label=f"{d} (AP {a['ap']:.2f})"
            )
            r, p = pr["op"]
            if not (math.isnan(r) or math.isnan(p)):
                ax.plot([r], [p], "o", color=line.get_color())
        ax.set_title(f"{split}, {c.name}", fontsize=10)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("recall")
        ax.set_ylabel("precision")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(f"Kin detection benchmark v{BENCHMARK_VERSION}: {split} (dot: shipped operating point)")
    fig.tight_layout()
    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> BenchmarkResults:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--detectors", nargs="+", default=["geometric", "learned"],
        help="detectors to benchmark: geometric, learned, beam or module:Class",
    )  # fmt: skip
    p.add_argument("--splits", nargs="+", default=list(SPLITS), choices=list(SPLITS), help="splits to run")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--full", action="store_true", help="the benchmark's full size (default: reduced)")
    size.add_argument("--scenes", type=int, default=None, help="scenes per split instead of a named size")
    p.add_argument(
        "--noise", type=noise_level, nargs="+", default=None,
        help="range noise levels to run instead of the benchmark's conditions (no dropout)",
    )  # fmt: skip
    p.add_argument(
        "--seed-offset", type=int, default=0, help="start this many scenes into each split's seeds"
    )
    p.add_argument(
        "--resamples", type=int, default=500, help="bootstrap resamples for the intervals (0: none)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads for learned detectors")
    p.add_argument("--out", type=Path, default=Path("outputs/benchmark_detectors"), help="output directory")
    p.add_argument("--no-plots", action="store_true", help="skip the PR-curve PNGs")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    if args.scenes is not None and args.scenes < 1:
        p.error(f"--scenes must be >= 1, got {args.scenes}")
    if args.resamples < 0 or args.seed_offset < 0:
        p.error(f"--resamples and --seed-offset must be >= 0, got {args.resamples} and {args.seed_offset}")
    if not args.no_plots and importlib.util.find_spec("matplotlib") is None:
        # the viz extra draws the PR curves; the tables and JSON do not need it (as reproduce_paper.py)
        script_logger(__file__).warning("no PR plots: matplotlib is not installed (kin-envs[viz])")
        args.no_plots = True
    try:
        detectors = {
            name.rsplit(":", 1)[-1] if ":" in name else name: detector_from_name(name, what="--detectors")
            for name in args.detectors
        }
    except ValueError as e:
        p.error(str(e))
    try:  # before the benchmark: an unwritable --out must not cost a whole run
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    if sys.modules.get("torch") is not None:  # (None: an import that failed or was blocked)
        sys.modules["torch"].set_num_threads(args.torch_threads)
    conditions = tuple(Condition(float(n)) for n in args.noise) if args.noise else CONDITIONS
    size_arg = "full" if args.full else (args.scenes if args.scenes is not None else "reduced")
    t0 = time.perf_counter()
    res = run_benchmark(
        detectors, args.splits, size_arg, conditions, args.seed_offset,
        n_resamples=args.resamples, seed=args.seed, progress=not args.quiet,
    )  # fmt: skip
    seconds = time.perf_counter() - t0
    names = list(detectors)
    with atomic_write(args.out / "results.md", "w") as fh:
        fh.write(report(res, names, conditions, seconds))
    write_json(args.out / "results.json", _plain(res.to_dict()))
    if not args.no_plots:
        for split in args.splits:
            plot_pr(res, split, names, conditions, args.out / f"pr_{split}.png")
    write_json(
        args.out / "run.json",
        _plain(
            {
                "command": " ".join(
                    ["python scripts/benchmark_detectors.py", *(sys.argv[1:] if argv is None else argv)]
                ),
                "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
                "benchmark": res.config,
                "seconds": seconds,
                "python": platform.python_version(),
                "numpy": np.__version__,
            }
        ),
    )
    if not args.quiet:
        print(f"benchmark done in {seconds:.0f} s -> {args.out}/results.md")
    return res


def _plain(obj):
    """JSON-safe: NaN -> None, tuples -> lists, numpy scalars -> Python."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)  # Ctrl-C: exit 130 with one line; bad input: one line, exit 2
