"""Seeded evaluation sweep of lidar kin detectors (precision, recall, F1, centre error, speed).

Scenes: ``kin_envs.scenes.detection_scene`` (an observer among kin robots and hard distractors:
kin-width prisms and cuboids, same-radius and other cylinders, walls and corners) with kin and
distractors at 0.3-3 m. Scene ``i`` is drawn by ``numpy.random.default_rng(first_seed + i)``,
which then also draws the lidar noise of each noise level in turn; the default first seed,
1_000_000, keeps evaluation scenes disjoint from the training data (``scripts/make_dataset.py``
starts at seed 0). Every scene is scanned from the observer (robot 0) once per noise level
(relative range sigma: 0, 0.5, 1, 2 %).

Detectors (``--detectors``): ``geometric`` (the paper's, :class:`detectors.GeometricKinDetector`),
``learned`` (:class:`detectors.learned.LearnedKinDetector`, the shipped checkpoint), ``beam``
(:class:`detectors.beam_detector.BeamKinDetector`) or any ``module:Class`` path constructed without
arguments (:func:`kin_envs.cli.detector_from_name`). All are scored by
:func:`kin_envs.detection.evaluation.evaluate` (Hungarian matching within ``--gate`` m) and also run on the
paper's two scenarios at 0.5, 0.8 and 1.2 m.

Writes to ``--out``: ``results.md`` (tables), ``results.json``, ``f1_vs_distance.png``,
``centre_error_vs_distance.png`` and ``run.json`` (command, configuration, seeds, timings).
Detectors are timed warm: each is built and called once before the sweep, and that start-up time
(construction + first call, incl. numba compilation) is reported on its own line.

The work unit is one scene (build, scan at every noise level, detect, score: :func:`scene_unit`),
run by :func:`kin_envs.distributed.map_seeds` in this process (``--backend local``) or as Ray
tasks (``--backend ray``: a local Ray with ``--num-cpus`` workers, or the cluster at
``--address``); both give the same results.

Example::

    python scripts/evaluate_detectors.py --detectors geometric learned --scenes 2000
    python scripts/evaluate_detectors.py --scenes 100000 --backend ray --address auto
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from detectors.base import KinDetector
from detectors.fileio import atomic_write, write_json, write_text
from kin_envs import World, scenes
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    detector_from_name,
    noise_level,
    script_logger,
    setup_logging,
    write_run_info,
)
from kin_envs.cli import progress as tqdm
from kin_envs.core.lidar import LidarSpec
from kin_envs.core.scenes import DetectionSceneConfig
from kin_envs.detection.evaluation import DEFAULT_GATE, Evaluation, Metrics, evaluate
from kin_envs.distributed import BACKENDS, cached, map_seeds

FIRST_SEED = 1_000_000
log = script_logger(__file__)
DEFAULT_SCENES = 1000
NOISE_LEVELS = (0.0, 0.005, 0.01, 0.02)
#: valid beams on the kin: 1, 2, 3, 4, 5-6, 7-9, 10+ (a kin at 0.3 m gets about 13 at 1°)
BEAM_EDGES = (1, 2, 3, 4, 5, 7, 10, 361)


# --------------------------------------------------------------------------- detectors


# --------------------------------------------------------------------------- data


def scene_pairs(seed: int, noise_levels, config: DetectionSceneConfig) -> list:
    """``(scan, scene)`` pairs of one scene: drawn by ``default_rng(seed)``, which then draws the
    lidar noise of each noise level in turn; scanned from robot 0."""
    rng = np.random.default_rng(seed)
    scene = scenes.detection_scene(rng, config)
    pairs = []
    for nz in noise_levels:
        s = scene.replace(lidar=LidarSpec(noise_sigma=float(nz)))
        pairs.append((World(s, seed=rng).scan(robots=[0]), s))
    return pairs


def sweep_pairs(n_scenes: int, first_seed: int, noise_levels, config: DetectionSceneConfig, progress=True):
    """``(scan, scene)`` pairs: every scene at every noise level, scanned from robot 0."""
    pairs = []
    for i in tqdm(range(n_scenes), desc="scenes", unit="scene", disable=not progress):
        pairs.extend(scene_pairs(first_seed + i, noise_levels, config))
    return pairs


@dataclasses.dataclass(frozen=True)
class Sweep:
    """What every work unit shares (sent to each Ray worker once)."""

    first_seed: int
    noise_levels: tuple[float, ...]
    config: DetectionSceneConfig
    detectors: tuple[str, ...]
    gate: float
    separate: bool
    torch_threads: int


def warm_up(detector: KinDetector) -> float:
    """Seconds of ``detector``'s first ``detect_batch`` (numba compilation or loading its cache,
    first torch call), on one noise-free paper scan: the sweep then times warm detection only."""
    scan = World(scenes.paper_scenario(2, distance=0.8)).scan(robots=[0])
    t0 = time.perf_counter()
    detector.detect_batch(scan.ranges.astype(np.float64), scan.angles)
    return time.perf_counter() - t0


def build_detectors(names, torch_threads: int = 1) -> tuple[dict[str, KinDetector], dict[str, float]]:
    """Build and warm up the detectors: ``({name: detector}, {name: start-up seconds})``, start-up
    being construction (checkpoint loading) plus the first call (:func:`warm_up`)."""
    detectors, startup = {}, {}
    for name in names:
        t0 = time.perf_counter()
        detectors[name] = detector_from_name(name, what="--detectors")
        built = time.perf_counter() - t0
        if "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(torch_threads)
        startup[name] = built + warm_up(detectors[name])
    return detectors, startup


def _build_detectors(sweep: Sweep) -> dict[str, KinDetector]:
    return build_detectors(sweep.detectors, sweep.torch_threads)[0]


def scene_unit(i: int, sweep: Sweep) -> tuple[dict[str, Evaluation], float]:
    """The sweep's work unit: scene ``i`` at every noise level, through every detector, scored.

    Returns ``({detector: evaluation of this scene's scans}, seconds spent building and scanning)``;
    :func:`merge_scenes` joins the units' evaluations in scene order.
    """
    # detectors are built once per process (worker), not once per scene
    detectors = cached(
        ("evaluate_detectors", sweep.detectors, sweep.torch_threads), lambda: _build_detectors(sweep)
    )
    t0 = time.perf_counter()
    pairs = scene_pairs(sweep.first_seed + i, sweep.noise_levels, sweep.config)
    t_data = time.perf_counter() - t0
    evals = {
        name: evaluate(det, pairs, gate=sweep.gate, same_radius_separate=sweep.separate, name=name)
        for name, det in detectors.items()
    }
    return evals, t_data


def merge_scenes(parts: list[Evaluation], pairs_per_scene: int) -> Evaluation:
    """One evaluation from per-scene ones (in scene order), indexed as if evaluated in one call:
    scan ``k`` of scene ``s`` becomes scan ``s * pairs_per_scene + k``; ``seconds`` add up."""
    kin, dets = [], []
    for s, ev in enumerate(parts):
        scan0, det0 = s * pairs_per_scene, len(dets)
        dets.extend(dataclasses.replace(d, scan=scan0 + d.scan) for d in ev.detections)
        kin.extend(
            dataclasses.replace(k, scan=scan0 + k.scan, detection=det0 + k.detection if k.detected else -1)
            for k in ev.kin
        )
    return dataclasses.replace(
        parts[0],
        kin=tuple(kin),
        detections=tuple(dets),
        n_scans=sum(ev.n_scans for ev in parts),
        seconds=sum(ev.seconds for ev in parts),
    )


def paper_pairs(distances=scenes.PAPER_DISTANCES):
    """The paper's scenarios, noise-free, scanned from the observer: ``(pairs, labels)``."""
    pairs, labels = [], []
    for k in (1, 2):
        for d in distances:
            scene = scenes.paper_scenario(k, distance=d)
            pairs.append((World(scene).scan(robots=[0]), scene))
            labels.append(("I" * k, d))
    return pairs, labels


# --------------------------------------------------------------------------- tables


def _f(x: float, digits: int = 3) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _cm(x: float) -> str:
    return "–" if math.isnan(x) else f"{100 * x:.2f}"


def _pct(x: float) -> str:
    return f"{100 * x:g} %"


def _bin_label(lo: float, hi: float, integer: bool = False) -> str:
    if not integer:
        return f"{lo:.1f}–{hi:.1f} m"
    lo, hi = int(lo), int(hi)
    if hi >= 361:
        return f"{lo}+"
    return f"{lo}" if hi - lo == 1 else f"{lo}–{hi - 1}"


def _metric_cells(m: Metrics) -> str:
    return (
        f"{m.n_kin} | {_f(m.precision)} | {_f(m.recall)} | {_f(m.f1)} | {_cm(m.error_mean)} | "
        f"{_cm(m.error_median)} | {_cm(m.error_p95)}"
    )


_METRIC_HEAD = "kin | precision | recall | F1 | err mean (cm) | err median (cm) | err p95 (cm)"


def markdown(evals: dict[str, Evaluation], dist_edges, noise_levels, paper: list[dict], info: dict) -> str:
    names = list(evals)
    lines = [
        "# Kin detector evaluation",
        "",
        f"{info['scenes']} random detection scenes (`kin_envs.scenes.detection_scene`, seeds "
        f"{info['first_seed']}–{info['first_seed'] + info['scenes'] - 1}, disjoint from the training seeds "
        f"starting at 0), each scanned from the observer at noise levels "
        f"{', '.join(_pct(n) for n in noise_levels)}: {info['scans']} scans. Kin and distractors at "
        f"{info['config']['distance'][0]:g}–{info['config']['distance'][1]:g} m. "
        f"Matching gate {info['gate']:g} m"
        + (
            "; detections on same-radius cylinders are left out of the false positives."
            if info["separate"]
            else "."
        )
        + " A kin with no valid beam on it is not counted.",
        "",
        "## Per noise level",
        "",
        "| detector | noise | kin | TP | FP | FN | precision | recall | F1 | on same-radius cyl. "
        "| precision excl. those | F1 excl. those | err mean (cm) | err median (cm) | err p95 (cm) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, ev in evals.items():
        for nz in noise_levels:
            sub = ev.select(noise=nz)
            m, mx = sub.metrics(False), sub.metrics(True)
            lines.append(
                f"| {name} | {_pct(nz)} | {m.n_kin} | {m.tp} | {m.fp} | {m.fn} | {_f(m.precision)} | "
                f"{_f(m.recall)} | {_f(m.f1)} | {m.same_radius} | {_f(mx.precision)} | {_f(mx.f1)} | "
                f"{_cm(m.error_mean)} | {_cm(m.error_median)} | {_cm(m.error_p95)} |"
            )
    lines += ["", "## Per distance bin and noise level", ""]
    for name, ev in evals.items():
        lines += [f"**{name}**", "", f"| noise | distance | {_METRIC_HEAD} |", "|---:|---|" + "---:|" * 7]
        for nz in noise_levels:
            for lo, hi, m in ev.select(noise=nz).by_distance(dist_edges):
                lines.append(f"| {_pct(nz)} | {_bin_label(lo, hi)} | {_metric_cells(m)} |")
        lines.append("")
    lines += ["## Per number of valid beams on the kin (all noise levels)", ""]
    lines += [f"| detector | beams | {_METRIC_HEAD} |", "|---|---|" + "---:|" * 7]
    for name, ev in evals.items():
        for lo, hi, m in ev.by_beams(BEAM_EDGES):
            lines.append(f"| {name} | {_bin_label(lo, hi, True)} | {_metric_cells(m)} |")
    lines += ["", "## False positives per distractor kind", ""]
    cols = [(name, nz) for name in names for nz in noise_levels]
    fps = {(name, nz): evals[name].select(noise=nz).false_positives() for name, nz in cols}
    kinds = sorted(
        {k for c in fps.values() for k in c}, key=lambda k: (-sum(c.get(k, 0) for c in fps.values()), k)
    )
    lines.append("| source | " + " | ".join(f"{n} @ {_pct(nz)}" for n, nz in cols) + " |")
    lines.append("|---|" + "---:|" * len(cols))
    for k in kinds:
        lines.append(f"| {k} | " + " | ".join(str(fps[c].get(k, 0)) for c in cols) + " |")
    lines.append("| **total** | " + " | ".join(str(sum(fps[c].values())) for c in cols) + " |")
    lines += ["", "## Speed (time inside `detect_batch`, one call per scene, this machine)", ""]
    lines += ["| detector | scans | seconds | scans/s |", "|---|---:|---:|---:|"]
    for name, ev in evals.items():
        lines.append(f"| {name} | {ev.n_scans} | {ev.seconds:.2f} | {ev.scans_per_second:.0f} |")
    startup = info.get("startup_seconds", {})
    if startup:
        lines += [
            "",
            "Detectors timed warm. Start-up, apart (construction + first call, incl. numba compilation "
            "or loading its cache): " + ", ".join(f"{n} {s:.2f} s" for n, s in startup.items()) + ".",
        ]
    lines += ["", "## Paper scenarios (noise-free)", ""]
    lines += ["| detector | scenario | distance | kin detected | false positives |", "|---|---|---:|---|---|"]
    for row in paper:
        fp = ", ".join(f"{v} × {k}" for k, v in row["false_positives"].items()) or "none"
        lines.append(
            f"| {row['detector']} | {row['scenario']} | {row['distance']:g} m | "
            f"{'yes' if row['kin_detected'] else '**no**'} | {fp} |"
        )
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- plots


def plot(evals: dict[str, Evaluation], dist_edges, noise_levels, out: Path) -> list[Path]:
    try:
        import matplotlib
    except ImportError:  # the viz extra; tables and JSON do not need it (e.g. a .[distributed] install)
        log.warning("no figures: matplotlib is not installed (pip install kin-envs[viz])")
        return []

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = 0.5 * (np.asarray(dist_edges[:-1]) + np.asarray(dist_edges[1:]))
    paths = []
    for what, fname in (("f1", "f1_vs_distance.png"), ("error", "centre_error_vs_distance.png")):
        fig, axes = plt.subplots(
            1, len(noise_levels), figsize=(3.2 * len(noise_levels), 3.2), sharey=True, squeeze=False
        )
        for ax, nz in zip(axes[0], noise_levels, strict=True):
            for k, (name, ev) in enumerate(evals.items()):
                bins = ev.select(noise=nz).by_distance(dist_edges)
                colour = f"C{k}"
                if what == "f1":
                    ax.plot(centres, [m.f1 for *_, m in bins], "o-", color=colour, label=name)
                else:
                    ax.plot(
                        centres,
                        [100 * m.error_median for *_, m in bins],
                        "o-",
                        color=colour,
                        label=f"{name} median",
                    )
                    ax.plot(
                        centres,
                        [100 * m.error_p95 for *_, m in bins],
                        "s--",
                        color=colour,
                        alpha=0.6,
                        label=f"{name} 95th pct",
                    )
            ax.set_title(f"noise {_pct(nz)}", fontsize=9)
            ax.set_xlabel("kin distance (m)")
            ax.grid(alpha=0.3)
        axes[0, 0].set_ylabel("F1" if what == "f1" else "centre error (cm)")
        if what == "f1":
            axes[0, 0].set_ylim(0, 1.02)
        else:
            axes[0, 0].set_yscale("log")
        axes[0, -1].legend(fontsize=7)
        fig.tight_layout()
        with atomic_write(out / fname) as f:
            fig.savefig(f, format="png", dpi=110)
        plt.close(fig)
        paths.append(out / fname)
    return paths


# --------------------------------------------------------------------------- main


def _load_config(text: str | None) -> DetectionSceneConfig:
    if text is None:
        return DetectionSceneConfig()
    p = Path(text)
    try:
        d = json.loads(p.read_text() if p.is_file() else text)
    except json.JSONDecodeError as e:
        raise ValueError(f"--scene-config must be a JSON object or a JSON file, got {text!r} ({e})") from e
    if not isinstance(d, dict):
        raise ValueError(f"--scene-config must be a JSON object, got {d!r}")
    return DetectionSceneConfig.from_dict(d)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--detectors",
        nargs="+",
        default=["geometric"],
        help="geometric, learned, beam or module:Class (default: geometric)",
    )
    ap.add_argument("--scenes", type=int, default=DEFAULT_SCENES, help="random scenes in the sweep")
    ap.add_argument(
        "--first-seed",
        type=int,
        default=FIRST_SEED,
        help="seed of scene 0 (scene i: first_seed + i); keep clear of training seeds",
    )
    ap.add_argument(
        "--noise",
        type=noise_level,
        nargs="+",
        default=list(NOISE_LEVELS),
        help="relative range noise levels (0.01 = 1 %% of the distance)",
    )
    ap.add_argument("--gate", type=float, default=DEFAULT_GATE, help="matching gate, m")
    ap.add_argument(
        "--separate-same-radius",
        action="store_true",
        help="leave detections on same-radius cylinders out of the false positives",
    )
    ap.add_argument(
        "--scene-config", default=None, help="DetectionSceneConfig overrides: JSON object or file"
    )
    ap.add_argument("--torch-threads", type=int, default=1, help="torch threads for learned detectors")
    ap.add_argument("--out", type=Path, default=Path("outputs/evaluation"), help="output directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    ap.add_argument(
        "--backend", choices=BACKENDS, default="local",
        help="run the scenes here (local) or as Ray tasks (ray: pip install kin-envs[distributed])",
    )  # fmt: skip
    ap.add_argument("--address", default=None, help="ray: join this cluster (e.g. auto, host:6379)")
    ap.add_argument("--num-cpus", type=int, default=None, help="ray: CPUs of a local Ray (default: all)")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    if not (math.isfinite(args.gate) and args.gate > 0):
        raise ValueError(f"--gate must be a finite distance > 0 m, got {args.gate!r}")
    if args.scenes < 1 or args.first_seed < 0 or args.torch_threads < 1:
        raise ValueError(
            "--scenes and --torch-threads must be >= 1 and --first-seed >= 0, got "
            f"{args.scenes}, {args.torch_threads}, {args.first_seed}"
        )
    if args.backend == "local" and (args.address is not None or args.num_cpus is not None):
        raise ValueError("--address and --num-cpus need --backend ray")
    if args.num_cpus is not None and (args.num_cpus < 1 or args.address is not None):
        raise ValueError(
            f"--num-cpus must be >= 1 and sizes a local Ray (not one at --address), got {args.num_cpus}"
        )
    noise_levels = sorted(set(args.noise))
    config = _load_config(args.scene_config)
    out: Path = check_output_dir(args.out)  # before the detectors' warm-up and the sweep
    # fail before the sweep; warm, so that the sweep's timings leave compilation out
    detectors, startup = build_detectors(args.detectors, args.torch_threads)
    for name, sec in startup.items():
        print(f"{name}: start-up (construction + first call, incl. numba compilation) {sec:.2f} s")
    sweep = Sweep(
        args.first_seed, tuple(noise_levels), config, tuple(args.detectors), args.gate,
        args.separate_same_radius, args.torch_threads,
    )  # fmt: skip
    # this process's units reuse the detectors built above
    cached(("evaluate_detectors", sweep.detectors, sweep.torch_threads), lambda: detectors)
    t0 = time.perf_counter()
    units = map_seeds(
        scene_unit, range(args.scenes), args.backend, args=(sweep,), address=args.address,
        num_cpus=args.num_cpus, progress=not args.no_progress, desc="scenes", unit="scene",
    )  # fmt: skip
    t_sweep = time.perf_counter() - t0
    t_data = sum(t for _, t in units)
    evals = {name: merge_scenes([u[name] for u, _ in units], len(noise_levels)) for name in detectors}
    ppairs, plabels = paper_pairs()
    paper_rows = []
    for name, det in detectors.items():
        pev = evaluate(det, ppairs, gate=args.gate, same_radius_separate=args.separate_same_radius, name=name)
        for i, (sc, d) in enumerate(plabels):
            sub = pev.select(scans=[i])
            m = sub.metrics()
            paper_rows.append(
                {
                    "detector": name,
                    "scenario": sc,
                    "distance": d,
                    "kin_detected": m.tp == m.n_kin,
                    "false_positives": sub.false_positives(),
                    "metrics": m.as_dict(),
                }
            )
    lo, hi = config.distance
    dist_edges = np.round(np.linspace(lo, hi, 10), 6).tolist()
    info = {
        "scenes": args.scenes,
        "first_seed": args.first_seed,
        "scans": args.scenes * len(noise_levels),
        "gate": args.gate,
        "separate": args.separate_same_radius,
        "config": dataclasses.asdict(config),
        "startup_seconds": startup,
    }
    md = markdown(evals, dist_edges, noise_levels, paper_rows, info)
    write_text(out / "results.md", md)
    figures = [str(p) for p in plot(evals, dist_edges, noise_levels, out)]
    results = {
        "detectors": {
            name: {
                "overall": ev.metrics().as_dict(),
                "scans": ev.n_scans,
                "seconds": ev.seconds,
                "scans_per_second": ev.scans_per_second,
                "startup_seconds": startup[name],
                "per_noise": {str(nz): ev.select(noise=nz).metrics().as_dict() for nz in noise_levels},
                "per_noise_excluding_same_radius": {
                    str(nz): ev.select(noise=nz).metrics(True).as_dict() for nz in noise_levels
                },
                "per_distance": {
                    str(nz): [
                        {"lo": a, "hi": b, **m.as_dict()}
                        for a, b, m in ev.select(noise=nz).by_distance(dist_edges)
                    ]
                    for nz in noise_levels
                },
                "per_beams": [{"lo": a, "hi": b, **m.as_dict()} for a, b, m in ev.by_beams(BEAM_EDGES)],
                "false_positives": {str(nz): ev.select(noise=nz).false_positives() for nz in noise_levels},
            }
            for name, ev in evals.items()
        },
        "paper_scenarios": paper_rows,
        "distance_edges": dist_edges,
        "beam_edges": list(BEAM_EDGES),
        "figures": figures,
    }
    run = {
        "detectors": {name: f"{type(d).__module__}.{type(d).__qualname__}" for name, d in detectors.items()},
        "scene_config": dataclasses.asdict(config),
        "noise_levels": noise_levels,
        "seeds": {
            "first": args.first_seed,
            "count": args.scenes,
            "rule": "scene i: numpy.random.default_rng(first + i) draws detection_scene(rng, scene_config), "
            "then the lidar noise of each noise level in ascending order",
            "training_seeds": "scripts/make_dataset.py starts at seed 0; keep 'first' above the seeds "
            "used for training",
        },
        # data: building and scanning, summed over the units (and so over workers); sweep: wall time
        "seconds": {"data": t_data, "sweep": t_sweep, "total": time.perf_counter() - t0},
    }
    write_json(out / "results.json", _plain(results), allow_nan=False)
    run = write_run_info(out, args, config=config, seed=args.first_seed, argv=argv, script=__file__, **run)
    print(md)
    log.info(
        f"wrote {out}/results.md, results.json, run.json and {len(figures)} figures "
        f"in {run['seconds']['total']:.1f} s"
    )
    return {"evaluations": evals, "results": results, "run": run, "markdown": md}


def _plain(o):
    """JSON-ready copy: numpy scalars to Python, NaN (undefined metric) to null."""
    if isinstance(o, dict):
        return {str(k): _plain(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_plain(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


if __name__ == "__main__":
    from kin_envs.cli import run_main

    try:
        run_main(main, bad_input=())
    # bad input, Ray not installed, no cluster at --address: a message, not a traceback; exit status 2
    # as every script's bad input (argparse's convention)
    except (ValueError, ImportError, ConnectionError, FileNotFoundError) as e:
        print(f"evaluate_detectors: error: {e}", file=sys.stderr)
        sys.exit(2)
