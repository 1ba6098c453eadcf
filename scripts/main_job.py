"""The main job (``make run``): the paper reproduction, the detection and the sequence benchmarks.

1. ``scripts/reproduce_paper.py``: the paper's Scenario I and II at 0.5, 0.8 and 1.2 m with the
   geometric detector, the layout sensitivity and the noise study (0.5 % and 1 % range noise), and
   the paper's figures -> ``outputs/reproduce_paper/``.
2. ``scripts/benchmark_detectors.py``: geometric vs learned (the shipped checkpoint) on the
   detection benchmark (``paper``, ``swarm``, ``lookalike`` splits x noise / dropout; AP, P / R / F1
   with bootstrap intervals, PR curves) at its reduced size (``--full``: the full size) ->
   ``outputs/benchmark_detectors/``. It supersedes the former ``scripts/evaluate_detectors.py`` sweep
   in the main job; that script stays for large seeded sweeps (``evaluate_detectors.py --backend ray``).
3. ``scripts/benchmark_tracking.py``: the sequence benchmark (``swarm`` and ``lookalike`` episodes with
   moving observers and kin, 0 and 1 % range noise): the multi-frame ``KinTracker`` vs the single-scan
   detectors, at its reduced size (``--full``: the full size), and the tracking cost at 64 observers
   -> ``outputs/benchmark_tracking/``.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parent
if str(SCRIPTS.parent) not in sys.path:  # run as a file: make kin_envs importable from the checkout
    sys.path.insert(0, str(SCRIPTS.parent))

from kin_envs.cli import add_logging_args, check_output_dir, setup_logging, write_run_info  # noqa: E402


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"kin_envs_script_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("outputs"), help="parent output directory")
    p.add_argument(
        "--scenes", type=int, default=None,
        help="detection benchmark: scenes per split (default: its reduced size)",
    )  # fmt: skip
    p.add_argument("--full", action="store_true", help="run both benchmarks at their full size")
    p.add_argument("--quick", action="store_true", help="tiny sizes, for smoke tests")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    if args.full and args.scenes is not None:
        p.error("--full and --scenes are exclusive")
    # refused here, not by the detection benchmark after the paper reproduction's minutes of work
    if args.scenes is not None and args.scenes < 1:
        p.error(f"--scenes must be >= 1, got {args.scenes}")
    try:
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    write_run_info(args.out, args, argv=argv, script=__file__)
    results = {}
    t0 = time.perf_counter()
    repro_argv = ["--out", str(args.out / "reproduce_paper"), "--noise", "0.005", "0.01"]
    verbosity = ["--verbose"] if args.verbose else ["--quiet"] if args.quiet else []
    repro_argv += verbosity
    if args.quick:
        repro_argv += ["--repeats", "3", "--draws", "4", "--no-figures"]
    print("== 1/3 paper reproduction ==", flush=True)
    results["reproduce_paper"] = _load("reproduce_paper").main(repro_argv)
    print("== 2/3 detection benchmark: geometric vs learned ==", flush=True)
    bench_argv = ["--detectors", "geometric", "learned", "--out", str(args.out / "benchmark_detectors")]
    if args.full:
        bench_argv.append("--full")
    elif args.scenes is not None or args.quick:
        bench_argv += ["--scenes", str(args.scenes if args.scenes is not None else 2)]
    if args.quick:
        bench_argv += ["--noise", "0", "0.01", "--resamples", "50", "--no-plots"]
    results["benchmark_detectors"] = _load("benchmark_detectors").main([*bench_argv, *verbosity])
    print("== 3/3 sequence benchmark: tracker vs single scans ==", flush=True)
    seq_argv = ["--out", str(args.out / "benchmark_tracking"), "--noise", "0", "0.01"]
    if args.full:
        seq_argv.append("--full")
    elif args.quick:
        seq_argv += ["--episodes", "1", "--splits", "lookalike", "--no-gif", "--cost-robots", "8"]
    results["benchmark_tracking"] = _load("benchmark_tracking").main([*seq_argv, *verbosity])
    print(f"\nmain job done in {time.perf_counter() - t0:.0f} s. Outputs:")
    print(f"  {args.out / 'reproduce_paper'}/reproduction.md  (tables; figure*.png: the paper's figures)")
    print(f"  {args.out / 'benchmark_detectors'}/results.md   (benchmark: geometric vs learned; pr_*.png)")
    print(f"  {args.out / 'benchmark_tracking'}/results.md    (tracker vs single scans; png, gif)")
    return results


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
