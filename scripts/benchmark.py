"""Speed benchmarks, reported as ratios against baselines measured in the same run.

Sections (``--sections``, comma separated; default all available):

* ``lidar``: scans/s of the vectorised raycaster (one scan = one robot's 360 beams) for
  N = 1, 8, 64, 256 robots with 50 obstacles in a 10 x 10 m arena, against a naive loop of pymunk
  ``segment_query_first`` per beam on the same world; and physics steps/s.
* ``detector``: scans/s of the geometric detector (paper scenes, cluttered random arena).
* ``envs``: env steps/s for KinSeek and aggregation with 8, 64, 256 robots, with/without detector.
* ``learned``: batched scans/s of the learned detector (needs the ``train`` extra).

Writes ``benchmark.json`` and ``benchmark.md`` (plus the command and config) to ``--out``.
Never assert wall-clock times in tests; this script is where speed targets are checked.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kin_envs import World, scenes
from kin_envs.cli import add_logging_args, setup_logging, write_run_info
from kin_envs.core.world import LIDAR_QUERY_FILTER


def rate(fn: Callable[[], object], min_time: float) -> float:
    """Calls per second of ``fn`` (best of 3 timed runs of at least ``min_time`` / 3 s each)."""
    fn()  # warm-up (numba JIT, caches)
    best = 0.0
    for _ in range(3):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_time / 3:
                break
        best = max(best, n / dt)
    return best


def naive_scan(world: World, robot: int) -> np.ndarray:
    """The baseline: one pymunk ``segment_query_first`` per beam, in a Python loop."""
    import pymunk

    spec = world.scene.lidar
    x, y, th = world.poses[robot]
    flt = pymunk.ShapeFilter(
        group=robot + 1, categories=LIDAR_QUERY_FILTER.categories, mask=LIDAR_QUERY_FILTER.mask
    )
    out = np.full(spec.n_beams, spec.range_max)
    for i, a in enumerate(spec.angles):
        end = (x + spec.range_max * math.cos(th + a), y + spec.range_max * math.sin(th + a))
        info = world.space.segment_query_first((x, y), end, 0.0, flt)
        if info is not None:
            out[i] = info.alpha * spec.range_max
    return out


def bench_lidar(min_time: float, robots=(1, 8, 64, 256)) -> list[dict]:
    rows = []
    for n in robots:
        scene = scenes.random_arena(n, 50, seed=0, size=10.0)
        world = World(scene, seed=0)
        fast = rate(world.scan, min_time) * n
        k = min(n, 4)  # the naive loop is slow: time a few robots' scans
        naive = rate(lambda w=world, k=k: [naive_scan(w, i) for i in range(k)], min_time) * k
        cmd = np.tile([0.2, 0.5], (n, 1))
        steps = rate(lambda w=world, c=cmd: w.step(commands=c), min_time)
        rows.append(
            {
                "robots": n,
                "scans_per_s": fast,
                "naive_scans_per_s": naive,
                "ratio": fast / naive,
                "physics_steps_per_s": steps,
            }
        )
        print(
            f"  lidar N={n:4d}: {fast:10.0f} scans/s  naive {naive:7.0f}  x{fast / naive:6.1f}  "
            f"world.step {steps:8.1f}/s",
            flush=True,
        )
    return rows


def bench_detector(min_time: float) -> list[dict]:
    try:
        from detectors import GeometricKinDetector
    except ImportError as e:  # pragma: no cover - before the detector exists
        print(f"  detector: skipped ({e})")
        return []
    dets = {"with reports": GeometricKinDetector(), "detections only": GeometricKinDetector(reports=False)}
    rows = []
    cases = {
        f"paper_scenario_{'I' * k}_{d}m": scenes.paper_scenario(k, distance=d)
        for k in (1, 2)
        for d in scenes.PAPER_DISTANCES
    }
    cases["random_arena_64_robots_50_obstacles"] = scenes.random_arena(64, 50, seed=1)
    for name, scene in cases.items():
        scan = World(scene, seed=0).scan()
        ranges = scan.ranges.astype(np.float64)
        row = {"scene": name}
        for mode, det in dets.items():
            r = rate(lambda d=det, rr=ranges, aa=scan.angles: d.detect_batch(rr, aa), min_time) * len(ranges)
            row[mode] = r
        rows.append(row)
        print(
            f"  detector {name:40s} {row['with reports']:9.0f} scans/s with reports, "
            f"{row['detections only']:9.0f} detections only",
            flush=True,
        )
    return rows


def bench_envs(min_time: float) -> list[dict]:
    try:
        import gymnasium as gym

        from kin_envs import aggregation_v0
    except ImportError as e:  # pragma: no cover - before the envs exist
        print(f"  envs: skipped ({e})")
        return []
    rows = []
    for detector in (None, "geometric"):
        env = gym.make("kin_envs/KinSeek-v0", detector=detector)
        env.reset(seed=0)

        def step_seek(env=env):
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                env.reset()

        r = rate(step_seek, min_time)
        rows.append({"env": "KinSeek-v0", "robots": 1, "detector": str(detector), "steps_per_s": r})
        print(f"  KinSeek-v0 detector={detector!s:9s} {r:8.1f} steps/s", flush=True)
        for n in (8, 64, 256):
            penv = aggregation_v0.parallel_env(n_robots=n, detector=detector)
            penv.reset(seed=0)
            acts = {a: penv.action_space(a).sample() for a in penv.agents}

            def step_agg(penv=penv, acts=acts):
                _, _, _, trunc, _ = penv.step(acts)
                if any(trunc.values()):
                    penv.reset()

            r = rate(step_agg, min_time)
            rows.append({"env": "aggregation_v0", "robots": n, "detector": str(detector), "steps_per_s": r})
            print(f"  aggregation_v0 N={n:3d} detector={detector!s:9s} {r:8.1f} steps/s", flush=True)
    return rows


def bench_learned(min_time: float) -> list[dict]:
    try:
        from detectors.learned import LearnedKinDetector
    except ImportError as e:
        print(f"  learned: skipped ({e})")
        return []
    import torch

    torch.set_num_threads(1)
    det = LearnedKinDetector()
    scan = World(scenes.random_arena(64, 50, seed=1), seed=0).scan()
    ranges = np.tile(scan.ranges.astype(np.float64), (4, 1))
    r = rate(lambda: det.detect_batch(ranges, scan.angles), min_time) * ranges.shape[0]
    print(f"  learned detector, batch of {ranges.shape[0]} cluttered scans: {r:9.0f} scans/s")
    return [{"scene": "random_arena_64_robots_50_obstacles", "batch": ranges.shape[0], "scans_per_s": r}]


SECTIONS = {"lidar": bench_lidar, "detector": bench_detector, "envs": bench_envs, "learned": bench_learned}


def to_markdown(results: dict) -> str:
    lines = []
    if results.get("lidar"):
        lines += [
            "| robots | scans/s (vectorised) | scans/s (naive pymunk loop) | ratio | world.step/s |",
            "|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['robots']} | {r['scans_per_s']:,.0f} | {r['naive_scans_per_s']:,.0f} | "
            f"{r['ratio']:.0f}x | {r['physics_steps_per_s']:,.0f} |"
            for r in results["lidar"]
        ]
        lines.append("")
    if results.get("detector"):
        lines += [
            "| scene | geometric scans/s, with per-segment reports | detections only |",
            "|---|---:|---:|",
        ]
        lines += [
            f"| {r['scene']} | {r['with reports']:,.0f} | {r['detections only']:,.0f} |"
            for r in results["detector"]
        ]
        lines.append("")
    if results.get("envs"):
        lines += ["| env | robots | detector | steps/s |", "|---|---:|---|---:|"]
        lines += [
            f"| {r['env']} | {r['robots']} | {r['detector']} | {r['steps_per_s']:,.1f} |"
            for r in results["envs"]
        ]
        lines.append("")
    if results.get("learned"):
        lines += ["| learned detector | batch | scans/s |", "|---|---:|---:|"]
        lines += [f"| {r['scene']} | {r['batch']} | {r['scans_per_s']:,.0f} |" for r in results["learned"]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sections", default=",".join(SECTIONS), help="comma-separated: " + ", ".join(SECTIONS))
    p.add_argument("--min-time", type=float, default=1.5, help="seconds of timing per measurement")
    p.add_argument("--robots", type=int, nargs="+", default=[1, 8, 64, 256], help="lidar: robot counts")
    p.add_argument("--out", type=Path, default=Path("outputs/benchmark"),
                   help="output directory (default: %(default)s)")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        p.error(f"unknown section(s) {unknown}; expected some of {sorted(SECTIONS)}")
    if args.min_time <= 0 or min(args.robots) < 1:
        p.error("--min-time must be > 0 and --robots >= 1")
    results: dict = {
        "config": {
            "command": " ".join([sys.executable, *sys.argv]),
            "sections": sections,
            "min_time": args.min_time,
            "robots": args.robots,
            "python": platform.python_version(),
            "machine": platform.machine(),
        }
    }
    for s in sections:
        print(f"[{s}]", flush=True)
        results[s] = (
            SECTIONS[s](args.min_time, robots=args.robots) if s == "lidar" else SECTIONS[s](args.min_time)
        )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "benchmark.json").write_text(json.dumps(results, indent=2))
    write_run_info(args.out, args, config=results["config"], argv=argv, script=__file__)
    md = to_markdown(results)
    (args.out / "benchmark.md").write_text(md)
    print("\n" + md)
    print(f"wrote {args.out / 'benchmark.json'} and {args.out / 'benchmark.md'}")
    return results


if __name__ == "__main__":
    main()
