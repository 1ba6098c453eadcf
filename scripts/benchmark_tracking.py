"""The sequence benchmark (``kin_envs.detection.sequences``): kin tracking over time vs single scans.

Runs :class:`detectors.tracking.KinTracker` (fed by a detector run permissively, plus the detector's own
decisions at its operating point, and the world's noisy wheel odometry) and the single-scan detectors on
the seeded ``swarm`` and ``lookalike`` episodes at each range-noise level, and writes to ``--out``:

* ``results.md``: per split and noise, the issue's target window (kin in view >= 10 frames at 0.3-2 m:
  P / R / F1 overall and per distance bin), P / R / F1 against frames since the kin came into view
  (1, 2, 5, 10, 20) and against distance, for the tracker and each single-scan detector; time to
  confirm; false tracks per minute; MOTA / IDF1 / identity switches; same-radius cylinders rejected once
  every kin in view has moved >= 0.2 m; the tracker against the single scan in the target window (kin
  frames each got right, the causes of the tracker's misses where the single scan was right, false
  positives of both by object); tracker vs detector time per frame; and the tracking cost at
  ``--cost-robots`` (64) observers: the tracker's update against the permissive detector feeding it, timed
  alternately on the same frames, warm, compile time apart (``--cost-robots 0`` skips it);
* ``results.json``: the same as data;
* ``f1_vs_frames.png``: F1 against frames observed, tracker vs single-scan detectors;
* ``tracks.gif``: one episode with the observer's scan and its tracks drawn (``--no-gif`` to skip);
* ``run.json``: command, arguments, version, split specs, versions, timing.

Example::

    python scripts/benchmark_tracking.py                            # reduced size (the main job's)
    python scripts/benchmark_tracking.py --full --out outputs/benchmark_tracking_full
    python scripts/benchmark_tracking.py --splits lookalike --episodes 4 --noise 0.01
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    detector_from_name,
    progress,
    script_logger,
    setup_logging,
    write_run_info,
)
from kin_envs.detection.sequences import (
    AGE_EDGES,
    SEQUENCE_SPLITS,
    SEQUENCE_VERSION,
    run_sequences,
    target_window,
    tracking_cost,
)

logger = script_logger(__file__)
_NO_MOT = "motmetrics is not installed: pip install kin-envs[tracking]"

_AGE_NAMES = [
    f"{a}" if b - a == 1 else f"{a}-{b - 1}" for a, b in zip(AGE_EDGES[:-1], AGE_EDGES[1:], strict=True)
] + [f"{AGE_EDGES[-1]}+"]


def _f(v) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}"


def _prf(row) -> str:
    return f"{_f(row['precision'])} / {_f(row['recall'])} / {_f(row['f1'])}"


def _diagnosis_lines(d: dict | None) -> list[str]:
    """The tracker against the single scan in the target window (``sequences._diagnose``), in two lines."""
    if not d:
        return []
    v = {k: d.get(f"vs_single:{k}", 0) for k in ("both_tp", "tracker_only", "single_only", "both_fn")}

    def by(prefix):
        items = sorted(((k[len(prefix) :], n) for k, n in d.items() if k.startswith(prefix)),
                       key=lambda x: -x[1])  # fmt: skip
        return ", ".join(f"{k} {n}" for k, n in items) or "none"

    return [f"- target window, kin frames: both right {v['both_tp']}, tracker only {v['tracker_only']}, "
            f"single scan only {v['single_only']} (the tracker's cause: {by('lost:')}), both wrong "
            f"{v['both_fn']}",
            f"- target window, false positives by object: tracker {by('fp:')}; single scan "
            f"{by('single_fp:')}"]  # fmt: skip


def report(results: list[dict], cost: dict | None = None) -> str:
    lines = [
        f"# Sequence benchmark (version {SEQUENCE_VERSION})",
        "",
        "P / R / F1 per frame; a kin counts with >= 2 valid beams, detections match within 0.10 m. "
        "`tracker` = KinTracker on the detector's candidates + its operating-point decisions + wheel "
        "odometry.",
    ]
    for r in results:
        lines += ["", f"## {r['split']}, range noise {100 * r['noise']:g} % "
                      f"({r['episodes']} episodes, {r['observer_frames']} observer-frames)", ""]  # fmt: skip
        tw = target_window(r)
        bins = [k for k in next(iter(tw.values())) if k != "all"]
        lines += ["Target window: kin in view >= 10 frames at 0.3-2 m (P / R / F1):", ""]
        lines += ["| method | all | " + " | ".join(f"{b} m" for b in bins) + " |",
                  "|---|---|" + "---|" * len(bins)]  # fmt: skip
        for m, rows in tw.items():
            lines.append(f"| {m} | {_prf(rows['all'])} | " + " | ".join(_prf(rows[b]) for b in bins) + " |")
        lines += ["", "Frames since the kin came into view:", ""]
        lines += ["| method | " + " | ".join(_AGE_NAMES) + " |", "|---|" + "---|" * len(_AGE_NAMES)]
        for m, rows in r["by_age"].items():
            lines.append(f"| {m} | " + " | ".join(_prf(x) for x in rows) + " |")
        lines += ["", "Distance (m):", ""]
        from kin_envs.detection.benchmark import DISTANCE_EDGES

        names = [f"{a:g}-{b:g}" for a, b in zip(DISTANCE_EDGES[:-1], DISTANCE_EDGES[1:], strict=True)]
        lines += ["| method | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for m, rows in r["by_distance"].items():
            lines.append(f"| {m} | " + " | ".join(_prf(x) for x in rows) + " |")
        sr = ", ".join(f"{m} {_f(v[0])} ({v[1]} frames)" for m, v in r["same_radius_rejected"].items())
        lk = "; ".join(f"{m}: " + ", ".join(f"{k} {_f(v[0])}" for k, v in d.items())
                       for m, d in r.get("lookalikes_rejected", {}).items())  # fmt: skip
        mot, sec = r["mot"], r["seconds"]
        lines += [
            "",
            f"- time to confirm a kin: median {_f(r['confirm_frames']['median'])} frames, mean "
            f"{_f(r['confirm_frames']['mean'])} ({r['confirm_frames']['n']} kin)",
            f"- false kin tracks per minute of observation: {_f(r['false_tracks_per_minute'])}",
            (f"- CLEAR MOT (tracker): MOTA {_f(mot['mota'])}, IDF1 {_f(mot['idf1'])}, "
             f"identity switches {mot['num_switches']}" if mot
             else f"- CLEAR MOT (tracker): not scored ({_NO_MOT})"),
            f"- same-radius cylinders rejected once every kin in view moved >= 0.2 m: {sr}",
            f"- look-alikes in view >= 20 frames at 0.3-2 m, share of frames not reported, by kind: {lk}",
            *_diagnosis_lines(r.get("diagnosis")),
            f"- per frame, all observers: detector {1e3 * sec['detector_per_frame']:.2f} ms, tracker "
            f"{1e3 * sec['tracker_per_frame']:.2f} ms "
            f"({100 * sec['tracker_per_frame'] / max(sec['detector_per_frame'], 1e-12):.0f} %), timed warm "
            f"(compile / start-up: {sec['warm_up']:.1f} s)",
        ]
    if cost:
        lines += [
            "", f"## Tracking cost at {cost['n_robots']} observers", "",
            f"Per frame ({cost['frames']} frames of a {cost['n_robots']}-robot swarm after the first "
            f"{cost['skipped']} (steady state), "
            f"{cost['candidates_per_frame']:.0f} candidates per frame, best of the passes, warm): permissive "
            f"detector {1e3 * cost['detector_per_frame']:.2f} ms, "
            f"tracker {1e3 * cost['tracker_per_frame']:.2f} ms "
            f"= **{100 * cost['ratio']:.0f} %** of the detector's time (compile / start-up "
            f"{cost['warm_up']:.1f} s, apart); the fixed-shape outputs an env reads (`track_arrays`, "
            f"which evaluates the kin decision) {1e3 * cost.get('outputs_per_frame', math.nan):.2f} ms.",
            "", "By the process's CPU clock (other jobs on a loaded machine do not count): permissive "
            f"detector {1e3 * cost['detector_cpu_per_frame']:.2f} ms, "
            f"tracker {1e3 * cost['tracker_cpu_per_frame']:.2f} ms = **{100 * cost['ratio_cpu']:.0f} %**; "
            "the shipped detector's own batched call (`detect_arrays`, what an env calls) "
            f"{1e3 * cost['shipped_cpu_per_frame']:.2f} ms: the tracker is "
            f"**{100 * cost['ratio_shipped_cpu']:.0f} %** of it; `track_arrays` "
            f"{1e3 * cost['outputs_cpu_per_frame']:.2f} ms. What an env pays per step with `tracker=True` "
            "(the update and `track_arrays`; the kin decision's compiled part runs in the update's call "
            "when the outputs of the frame before were read): "
            f"**{100 * cost.get('ratio_total_shipped_cpu', math.nan):.0f} %** of `detect_arrays`, "
            f"{100 * cost.get('ratio_total_cpu', math.nan):.0f} % of the permissive detector.",
        ]  # fmt: skip
        if "alt_cpu_per_frame" in cost:
            kw = ", ".join(f"{k}={v}" for k, v in cost["alt_params"].items())
            lines += [
                "", f"With `TrackerParams({kw})` (the per-frame circle fits warm-started at the candidate's "
                "centre; `--cost-warm-fits`, same passes): tracker "
                f"{1e3 * cost['alt_cpu_per_frame']:.2f} ms = **{100 * cost['ratio_alt_cpu']:.0f} %** of the "
                f"permissive detector, **{100 * cost['ratio_alt_shipped_cpu']:.0f} %** of the shipped one.",
            ]  # fmt: skip
        if cost.get("env"):
            lines += env_cost_lines(cost["env"])
    return "\n".join(lines) + "\n"


#: what :func:`env_cost` times in each env: ``(label, module or class path, attribute)``; an attribute the
#: code no longer has is skipped (the envs' entry points stay: ``track_update``, ``track_info``)
_ENV_PROBES = {
    "aggregation_v2": [("detector", "kin_envs.envs.aggregation", "detect_rows_padded"),
                       ("detector", "kin_envs.envs.tracks.PermissiveFeed", "detect"),
                       ("detector", "kin_envs.envs.tracks.PermissiveFeed", "detect_padded"),  # (+ padding)
                       ("detector", "kin_envs.envs.aggregation", "pad_rows"),  # (a detector without it)
                       ("update", "kin_envs.envs.tracks", "track_update"),
                       ("info", "kin_envs.envs.tracks", "track_info")],
    "KinSeek-v2": [("detector", "kin_envs.envs.base", "detect_one_padded"),
                   ("detector", "kin_envs.envs.tracks.PermissiveFeed", "detect"),
                   ("update", "kin_envs.envs.tracks", "track_update"),
                   ("info", "kin_envs.envs.tracks", "track_info")],
    "vector": [("detector", "kin_envs.envs.vector", "detection_arrays"),
               ("detector", "kin_envs.envs.vector", "match_pad_worlds"),
               ("detector", "kin_envs.envs.tracks.PermissiveFeed", "detect"),
               ("update", "kin_envs.envs.tracks.VectorTracker", "update"),
               ("info", "kin_envs.envs.vector", "track_info")],
}
#: inside the update and the info (the same in every env)
_PART_PROBES = [("segment_points", "detectors.tracking", "segment_points"),
                ("update_batch", "detectors.tracking.KinTracker", "update_batch"),
                ("update_batch", "detectors.tracking.KinTracker", "_update_segments_trusted"),  # the envs'
                ("update_kernel", "detectors.tracking", "_update_kernel"),
                ("update_kernel", "detectors.tracking", "_update_segments_kernel"),
                ("track_arrays", "detectors.tracking.KinTracker", "track_arrays"),
                ("track_arrays", "detectors.tracking.KinTracker", "_track_block")]  # fmt: skip


def _resolve(path: str):
    import importlib

    try:
        return importlib.import_module(path)
    except ImportError:
        mod, _, name = path.rpartition(".")
        return getattr(importlib.import_module(mod), name)


class _Probes:
    """CPU-clock wrappers (``time.process_time_ns``) around named calls, installed on entry and removed on
    exit: ``ns[label]`` sums each label's calls (a nested call of the same label counts once)."""

    def __init__(self, probes) -> None:
        self.probes, self.ns, self._saved, self.on = probes, {}, [], False

    def __enter__(self):
        for label, path, attr in self.probes:
            owner = _resolve(path)
            if attr not in vars(owner):
                continue
            f = vars(owner)[attr]
            self.ns.setdefault(label, 0)
            self._saved.append((owner, attr, f))
            setattr(owner, attr, self._wrap(label, f))
        return self

    def _wrap(self, label, f):
        clock, ns, depth = time.process_time_ns, self.ns, {label: 0}

        def timed(*a, **k):
            if not self.on or depth[label]:
                return f(*a, **k)
            depth[label] += 1
            t = clock()
            try:
                return f(*a, **k)
            finally:
                ns[label] += clock() - t
                depth[label] -= 1

        return timed

    def __exit__(self, *exc) -> None:
        for owner, attr, f in reversed(self._saved):
            setattr(owner, attr, f)


def _stepper(name: str, env, seed: int):
    """``env`` reset with ``seed``; a function that steps it with random actions (resetting at an end)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    if name == "aggregation_v2":
        spaces = [env.action_space(a) for a in env.possible_agents]
        for s in spaces:
            s.seed(int(rng.integers(1 << 31)))

        def step():
            env.step({a: s.sample() for a, s in zip(env.possible_agents, spaces, strict=True)})
            if not env.agents:
                env.reset(seed=int(rng.integers(1 << 31)))

        return step
    env.action_space.seed(seed)

    def step():
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if name != "vector" and (term or trunc):  # (the vector env resets its sub-envs itself)
            env.reset(seed=int(rng.integers(1 << 31)))

    return step


def env_cost(detector: str = "geometric", n_robots: int = 64, steps: int = 300, warm: int = 30,
             seed: int = 0, noise: float = 0.01, feed: str | None = None) -> dict:
    """What the tracker costs as the envs pay it: per step (CPU clock, µs), the detector call, the tracker's
    update (``track_update``) and its info (``track_info``, ``kin_tracks``), and inside them
    ``segment_points``, ``KinTracker.update_batch`` or the envs' trusted entry
    (``_update_segments_trusted``), its compiled call and ``track_arrays``,
    timed by ``time.process_time_ns`` wrappers around the calls the env makes (:data:`_ENV_PROBES`), over
    ``steps`` steps after ``warm`` untimed ones (the first step's compile / start-up time apart), random
    actions. Three envs: aggregation_v2 at ``n_robots`` robots, KinSeek-v2 (one observer) and the native
    vector env of KinSeek-v2 at ``n_robots`` sub-envs; each with ``detector`` and ``tracker=True``
    (``feed``: ``tracker={"feed": feed}``; None: the envs' default, ``"auto"``), range noise ``noise``."""
    import gymnasium as gym

    import kin_envs  # noqa: F401  (registers the ids)
    from kin_envs import aggregation_v2

    if steps < 1 or warm < 1:
        raise ValueError(f"env_cost: steps and warm must be >= 1, got {steps!r} and {warm!r}")
    tracker = True if feed is None else {"feed": feed}
    out = {"detector": detector, "feed": feed or "default (auto)", "n_robots": int(n_robots),
           "steps": int(steps), "warm": int(warm), "noise": float(noise), "envs": {}}  # fmt: skip
    makers = {
        "aggregation_v2": lambda: aggregation_v2.parallel_env(n_robots=n_robots, detector=detector,
                                                              tracker=tracker, noise_sigma=noise),
        "KinSeek-v2": lambda: gym.make("kin_envs/KinSeek-v2", detector=detector, tracker=tracker,
                                       noise_sigma=noise),
        "vector": lambda: gym.make_vec("kin_envs/KinSeek-v2", num_envs=n_robots, detector=detector,
                                       tracker=tracker, noise_sigma=noise),
    }  # fmt: skip
    for name, make in makers.items():
        # the first step (compiles what the process has not compiled yet) before the probes: a compiled
        # kernel that calls another one must see the real one, not a probe, when it compiles
        t0 = time.process_time()
        env = make()
        step = _stepper(name, env, seed)
        step()
        first = time.process_time() - t0
        with _Probes(_ENV_PROBES[name] + _PART_PROBES) as pr:
            for _ in range(warm - 1):
                step()
            pr.on = True
            t0 = time.process_time()
            for _ in range(steps):
                step()
            total = time.process_time() - t0
            pr.on = False
            env.close()
        us = {k: v / 1e3 / steps for k, v in pr.ns.items()}
        det = us.get("detector", 0.0)
        trk = us.get("update", 0.0) + us.get("info", 0.0)
        out["envs"][name] = {"us_per_step": us, "step_us": 1e6 * total / steps, "first_step_s": first,
                             "ratio": trk / det if det > 0 else math.nan}  # fmt: skip
    return out


def env_cost_lines(cost: dict) -> list[str]:
    """:func:`env_cost` as a markdown table."""
    envs = cost["envs"]
    n = cost["n_robots"]
    heads = {"aggregation_v2": f"aggregation_v2 ({n} robots)", "KinSeek-v2": "KinSeek-v2",
             "vector": f"vector KinSeek-v2 (K = {n})"}  # fmt: skip
    rows = [("detector call", "detector"), ("tracker update (`track_update`)", "update"),
            ("… `segment_points`", "segment_points"),
            ("… `KinTracker.update_batch` / the envs' entry (`_update_segments_trusted`)", "update_batch"),
            ("… … its compiled call", "update_kernel"), ("tracker info (`track_info`)", "info"),
            ("… `track_arrays`", "track_arrays")]  # fmt: skip
    lines = ["", f"## What the tracker costs in the envs ({cost['detector']} detector, {cost['feed']} feed)",
             "", f"µs per step, CPU clock (`time.process_time_ns` around the env's calls), {cost['steps']} "
             f"steps after {cost['warm']} (warm; the first step's compile / start-up apart), random actions, "
             f"range noise {100 * cost['noise']:g} %:", "",
             "| µs per step | " + " | ".join(heads[e] for e in envs) + " |",
             "|---|" + "---:|" * len(envs)]  # fmt: skip
    for title, key in rows:
        vals = [envs[e]["us_per_step"].get(key) for e in envs]
        if all(v is None for v in vals):
            continue
        lines.append(f"| {title} | " + " | ".join("–" if v is None else f"{v:,.0f}" for v in vals) + " |")
    lines.append("| **tracker (update + info) / detector** | "
                 + " | ".join(f"**{100 * envs[e]['ratio']:.0f} %**" for e in envs) + " |")  # fmt: skip
    lines.append("| whole step | " + " | ".join(f"{envs[e]['step_us']:,.0f}" for e in envs) + " |")
    lines.append("| first step (compile / start-up), s | "
                 + " | ".join(f"{envs[e]['first_step_s']:.1f}" for e in envs) + " |")  # fmt: skip
    return lines


def plot_f1(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.4), squeeze=False)
    for ax, r in zip(axes[0], results, strict=True):
        for m, rows in r["by_age"].items():
            ax.plot(range(len(rows)), [x["f1"] for x in rows], marker="o", label=m)
        ax.set_xticks(range(len(_AGE_NAMES)), _AGE_NAMES)
        ax.set_xlabel("frames since the kin came into view")
        ax.set_ylabel("F1")
        ax.set_ylim(0, 1)
        ax.set_title(f"{r['split']}, noise {100 * r['noise']:g} %", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


def animate(recording: list[dict], path: Path, range_max: float = 12.0) -> None:
    """A GIF of the observer's scan (points) and tracks (circles; green = reported kin)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import PillowWriter

    from kin_envs.core.lidar import LidarSpec

    ang = LidarSpec().angles
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    writer = PillowWriter(fps=8)
    tmp = path.with_name(f".{path.name}.tmp.gif")
    try:
        with writer.saving(fig, str(tmp), dpi=80):
            for k, fr in enumerate(recording):
                ax.clear()
                r = fr["scan"]
                ok = r < range_max
                ax.scatter(r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok]), s=3, c="0.3")
                for t in fr["tracks"]:
                    kin = t[8] > 0 and t[6] >= 0.5
                    ax.add_patch(plt.Circle((t[1], t[2]), 0.06, fill=False, lw=1.5 if kin else 0.8,
                                            color="tab:green" if kin else "tab:red"))  # fmt: skip
                    if kin:
                        ax.annotate(f"{int(t[0])}", (t[1] + 0.07, t[2] + 0.07), fontsize=7, color="tab:green")
                ax.plot([0], [0], marker=(3, 0, -90), ms=10, color="tab:blue")
                ax.set_xlim(-2.5, 2.5)
                ax.set_ylim(-2.5, 2.5)
                ax.set_aspect("equal")
                ax.set_title(f"frame {k}: scan (grey), tracks (green: kin)", fontsize=8)
                writer.grab_frame()
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--splits", nargs="+", default=list(SEQUENCE_SPLITS), choices=list(SEQUENCE_SPLITS),
                   help="sequence splits to run")  # fmt: skip
    p.add_argument("--noise", nargs="+", type=float, default=None,
                   help="relative range noise levels (default: each split's, 0 / 0.5 / 1 %%)")  # fmt: skip
    p.add_argument("--episodes", type=int, default=None, help="episodes per split (default: reduced size)")
    p.add_argument("--full", action="store_true", help="each split's full number of episodes")
    p.add_argument(
        "--detector",
        default="learned",
        help="detector feeding the tracker: geometric, learned, beam or module:Class",
    )
    p.add_argument(
        "--baselines", nargs="*", default=["geometric"], help="further single-scan detectors to score"
    )
    p.add_argument("--out", type=Path, default=Path("outputs/benchmark_tracking"), help="output directory")
    p.add_argument("--no-gif", action="store_true", help="skip the animation")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads (learned detector)")
    p.add_argument("--kin-model", default="auto",
                   help="the tracker's kin decision: auto (the shipped track classifier fitted on "
                        "--detector's permissive candidates: geometric for the geometric detector, else "
                        "learned), learned, geometric, hand (the hand-tuned fusion) or a model JSON "
                        "path")  # fmt: skip
    p.add_argument("--tracker-params", default=None,
                   help="TrackerParams fields as JSON for the tracker of every part, e.g. "
                        "'{\"birth_min_score\": 0.6}' (default: the shipped defaults)")  # fmt: skip
    p.add_argument("--cost-robots", type=int, default=64,
                   help="observers of the tracking-cost measurement (0: skip it)")  # fmt: skip
    p.add_argument("--cost-warm-fits", action="store_true",
                   help="also time a tracker whose per-frame fits start at the candidate's centre (2 steps) "
                        "in the same passes of the cost measurement")  # fmt: skip
    p.add_argument("--cost-env-steps", type=int, default=300,
                   help="steps of the in-env cost measurement (aggregation_v2 at --cost-robots robots, "
                        "KinSeek-v2, its native vector env at --cost-robots sub-envs; --detector, "
                        "tracker=True; 0: skip it)")  # fmt: skip
    p.add_argument("--cost-env-feed", default=None, choices=["auto", "accepted", "permissive"],
                   help="the tracker's feed in the in-env cost measurement (default: the envs' own, auto)")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    if args.full and args.episodes is not None:
        p.error("--full and --episodes are exclusive")
    if args.episodes is not None and args.episodes < 1:
        p.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.cost_robots != 0 and args.cost_robots < 2:
        p.error(f"--cost-robots must be 0 (skip) or >= 2, got {args.cost_robots}")
    if args.cost_env_steps < 0:
        p.error(f"--cost-env-steps must be >= 0 (0: skip), got {args.cost_env_steps}")
    for nz in args.noise or []:
        if not 0 <= nz <= 0.05:
            p.error(f"--noise must be relative range noise in [0, 0.05] (0.01 = 1 %), got {nz}")
    try:  # before the episodes: an unwritable --out must not cost a whole run
        check_output_dir(args.out)
        from detectors.tracking import KinTracker

        if args.kin_model != "auto":
            KinTracker(kin_model=args.kin_model)  # a bad --kin-model fails before the episodes
        tracker_params = None
        if args.tracker_params is not None:
            from detectors.tracking import TrackerParams

            try:
                tracker_params = TrackerParams.from_dict(json.loads(args.tracker_params))
            except json.JSONDecodeError as e:
                msg = f"--tracker-params must be a JSON object, got {args.tracker_params!r}: {e}"
                raise ValueError(msg) from None
    except (ValueError, TypeError) as e:
        p.error(str(e))
    # the learned detector runs without torch (its npz): set torch's threads only where torch is installed
    wants_torch = "torch" in sys.modules or args.detector == "learned" or "learned" in args.baselines
    if wants_torch and importlib.util.find_spec("torch") is not None:
        import torch

        torch.set_num_threads(args.torch_threads)
    detector = detector_from_name(args.detector)
    if args.kin_model == "auto":  # the classifier fitted on this detector's permissive candidates
        from kin_envs.envs.tracks import auto_kin_model

        args.kin_model = auto_kin_model("permissive", detector)
    baselines = {n: detector_from_name(n, what="--baselines") for n in args.baselines if n != args.detector}
    # CLEAR MOT needs the tracking extra: without it, the rest of the benchmark (not a traceback at the end
    # of the first split, minutes into `make run`'s step 3 after an install without that extra)
    mot = importlib.util.find_spec("motmetrics") is not None
    if not mot:
        logger.warning(f"CLEAR MOT (MOTA / IDF1) not scored: {_NO_MOT}")
    figures = importlib.util.find_spec("matplotlib") is not None  # the viz extra; tables without it
    if not figures:
        logger.warning("no f1_vs_frames.png / tracks.gif: matplotlib is not installed (kin-envs[viz])")
    t0 = time.perf_counter()
    results, recording = [], None
    jobs = [(s, nz) for s in args.splits for nz in (args.noise or SEQUENCE_SPLITS[s].noise)]
    for split, nz in progress(jobs, desc="sequence benchmark"):  # a bar with tqdm (train / ros extras)
        spec = SEQUENCE_SPLITS[split]
        n = spec.n_episodes if args.full else args.episodes
        want_gif = figures and not args.no_gif and recording is None and split == "lookalike" and nz > 0
        r = run_sequences(detector, split, n, nz, tracker_params, baselines=baselines,
                          record=0 if want_gif else None, kin_model=args.kin_model, diagnose=True,
                          mot=mot)  # fmt: skip
        if want_gif:
            recording = r.pop("recording")
        results.append(r)
    cost = None
    if args.cost_robots:
        from detectors.tracking import TrackerParams

        alt = TrackerParams(frame_fit_iterations=2, frame_fit_warm_start=1) if args.cost_warm_fits else None
        cost = tracking_cost(detector, n_robots=args.cost_robots, tracker_params=tracker_params,
                             kin_model=args.kin_model, alt_params=alt)  # fmt: skip
        if args.cost_env_steps:
            cost["env"] = env_cost(args.detector, n_robots=args.cost_robots, steps=args.cost_env_steps,
                                   warm=min(30, args.cost_env_steps), feed=args.cost_env_feed)  # fmt: skip
    with atomic_write(args.out / "results.md", "w") as f:
        f.write(report(results, cost))
    write_json(args.out / "results.json", {"results": results, "cost": cost}, default=float)
    if figures:
        plot_f1(results, args.out / "f1_vs_frames.png")
    if recording:
        animate(recording, args.out / "tracks.gif")

    write_run_info(
        args.out, args, argv=argv, script=__file__, sequence_version=SEQUENCE_VERSION,
        splits={s: SEQUENCE_SPLITS[s].to_dict() for s in args.splits}, seconds=time.perf_counter() - t0,
    )
    print(report(results, cost))
    return results


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)  # Ctrl-C: exit 130 with one line; bad input: one line, exit 2
