"""Evaluate policies over the same seeded episodes: a markdown table with 95 % CIs and learning curves.

Single-robot envs (``--env kin_envs/KinSeek-v2``): success rate (Wilson interval, scipy's
``binomtest``), return, collision steps and steps to success (bootstrap BCa intervals of the mean,
which stay within the range of the data; steps to success over successful episodes).

Swarm (``--env aggregation_v2``; ``aggregation_v1`` and ``aggregation_v0`` are accepted too): cluster metrics
averaged over the last ``--metric-cycles`` cycles of each episode: mean distance from each robot to its
nearest other robot, and the largest-cluster fraction (robots linked when their centres are within
``--link-radius``; the size of the largest connected group / n), plus the per-robot return;
bootstrap intervals over episodes.

Policies: ``--policies`` names built-in ones (``random``, ``wander``, ``scripted``,
``aggregator``); ``--model [NAME=]PATH`` adds trained SB3 models (repeatable). A model is run in
the env kwargs recorded in its ``run.json`` (so a scan-only model gets a scan-only env); the
built-in policies use ``--env-kwargs``. Episode ``k`` uses seed ``--first-seed + k`` for every
policy: same layouts for all (the detector draws no random numbers).

Outputs in ``--out``: ``results.md``, ``results.json``, ``learning_curve.png`` (from each model's
``eval/evaluations.npz`` or ``monitor.csv``) and ``run.json``.

Example::

    python scripts/evaluate_policies.py --env kin_envs/KinSeek-v2 --episodes 200 \\
        --model ppo-topk=runs/seek_topk/model.zip --model ppo-scan=runs/seek_scan/model.zip
    python scripts/evaluate_policies.py --env aggregation_v2 --n-robots 8 --model runs/swarm/model.zip
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a file: make agents / kin_envs importable from the checkout
    sys.path.insert(0, str(ROOT))

import gymnasium  # noqa: E402

import kin_envs  # noqa: E402,F401  (registers the env ids)
from agents import (  # noqa: E402
    Aggregator,
    KinSeeker,
    PolicyGroup,
    RandomPolicy,
    Wanderer,
    run_episode,
    run_parallel_episode,
)
from detectors.fileio import atomic_write, write_json, write_text  # noqa: E402
from kin_envs import aggregation_v0, aggregation_v1, aggregation_v2  # noqa: E402
from kin_envs.cli import add_logging_args, check_output_dir, script_logger, setup_logging, write_run_info  # noqa: E402
from kin_envs.cli import progress as tqdm  # noqa: E402

SWARM_ID = "aggregation_v2"
#: the PettingZoo swarm ids: v2 (the latest), v1 (v2 with the tracker fed "accepted") and v0 (kept to
#: reproduce earlier runs)
SWARM_ENVS = {"aggregation_v2": aggregation_v2, "aggregation_v1": aggregation_v1,
              "aggregation_v0": aggregation_v0}  # fmt: skip
BUILTIN = {"random": RandomPolicy, "wander": Wanderer, "scripted": KinSeeker, "aggregator": Aggregator}
DEFAULT_POLICIES = {"single": ["random", "scripted"], "swarm": ["random", "wander", "aggregator"]}
DEFAULT_SWARM_KWARGS = {"obs_detections": "topk"}
log = script_logger(__file__)


# --- statistics ---------------------------------------------------------------------------------

#: resamples of the bootstrap intervals (BCa); seeded, so the tables are reproducible
N_RESAMPLES = 9999


def proportion_ci(k: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (scipy's ``binomtest``); within [0, 1]."""
    if n == 0:
        return (math.nan, math.nan)
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=conf, method="wilson")
    return (float(ci.low), float(ci.high))


def mean_ci(x, conf: float = 0.95, seed: int = 0) -> tuple[float, float, float]:
    """``(mean, low, high)``: bootstrap (BCa, ``scipy.stats.bootstrap``) interval of the mean.

    Counts, distances and fractions are bounded and often skewed (most episodes with 0 collisions, a
    few with many), where a Student t interval can leave the possible range (e.g. below 0). The bounds
    of a bootstrap interval are means of resamples, so they stay within [min(x), max(x)]. NaN bounds
    below 2 samples; a zero-width interval when all values are equal.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return (math.nan, math.nan, math.nan)
    m = float(x.mean())
    if x.size < 2:
        return (m, math.nan, math.nan)
    if np.ptp(x) == 0:  # the bootstrap distribution is a point (BCa would warn and give NaN)
        return (m, m, m)
    res = stats.bootstrap((x,), np.mean, confidence_level=conf, n_resamples=N_RESAMPLES, method="BCa",
                          vectorized=True, rng=np.random.default_rng(seed))
    lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    # BCa can fail on tiny or extreme samples (NaN): fall back to the percentile interval
    if not (math.isfinite(lo) and math.isfinite(hi)):
        res = stats.bootstrap((x,), np.mean, confidence_level=conf, n_resamples=N_RESAMPLES,
                              method="percentile", vectorized=True, rng=np.random.default_rng(seed))
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return (m, lo, hi)


# --- swarm metrics ------------------------------------------------------------------------------


def cluster_metrics(xy: np.ndarray, link_radius: float) -> tuple[float, float]:
    """``(mean nearest-neighbour distance m, largest-cluster fraction)`` of robot centres ``(n, 2)``.

    Robots within ``link_radius`` of each other are linked; a cluster is a connected component of
    that graph (``scipy.sparse.csgraph.connected_components``).
    """
    n = len(xy)
    d = np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    nearest = float(d.min(axis=1).mean())
    _, labels = connected_components(csr_matrix(d <= link_radius), directed=False)
    return nearest, float(np.bincount(labels).max() / n)


# --- policies -----------------------------------------------------------------------------------


def parse_model_arg(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep:
        path = text
        p = Path(text)
        name = p.parent.name if p.stem in ("model", "best_model") else p.stem
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--model {text!r}: no file at {path}")
    return name, path


def model_env_kwargs(path: Path, fallback: dict) -> dict:
    """The env kwargs a model was trained with (its ``run.json``), else ``fallback``."""
    for run in (path.parent / "run.json", path.parent.parent / "run.json"):
        if run.is_file():
            return dict(json.loads(run.read_text()).get("env_kwargs", {}))
    return dict(fallback)


def make_builtin(name: str, env, swarm: bool):
    if name not in BUILTIN:
        raise ValueError(f"unknown policy {name!r}; built-in policies: {sorted(BUILTIN)} "
                         "(trained ones go in --model)")
    cls = BUILTIN[name]
    if swarm:
        agents = env.possible_agents
        if cls is RandomPolicy:
            return PolicyGroup.shared(RandomPolicy.for_env(env), agents)
        return PolicyGroup.per_agent(lambda: cls.for_env(env), agents)
    return cls.for_env(env)


def make_env(env_id: str, kwargs: dict, n_robots: int):
    if env_id in SWARM_ENVS:
        kw = {k: v for k, v in kwargs.items() if k != "n_robots"}
        return SWARM_ENVS[env_id].parallel_env(n_robots=n_robots, **kw)
    if env_id not in gymnasium.registry:
        raise ValueError(f"unknown env id {env_id!r}; expected {SWARM_ID!r} or a registered id such as "
                         "'kin_envs/KinSeek-v2'")
    return gymnasium.make(env_id, **kwargs)


# --- evaluation ---------------------------------------------------------------------------------


def evaluate_single(env, policy, seeds, desc: str, progress: bool) -> dict[str, Any]:
    eps = [run_episode(env, policy, int(s)) for s in tqdm(seeds, desc=desc, disable=not progress)]
    n, k = len(eps), sum(e.success for e in eps)
    tts = [e.time_to_success for e in eps if e.success]
    return {
        "episodes": n,
        "success_rate": k / n, "success_ci": proportion_ci(k, n),
        "return": mean_ci([e.episode_return for e in eps]),
        "collisions": mean_ci([e.collisions for e in eps]),
        "time_to_success": mean_ci(tts),
        "per_episode": [{"seed": int(s), "success": e.success, "return": e.episode_return,
                         "length": e.length, "collisions": e.collisions}
                        for s, e in zip(seeds, eps, strict=True)],
    }


def evaluate_swarm(env, group, seeds, link_radius: float, metric_cycles: int, desc: str,
                   progress: bool) -> dict[str, Any]:
    max_cycles = env.config.max_cycles
    first = max(1, max_cycles - metric_cycles + 1)
    nn, frac, ret, coll, rows = [], [], [], [], []
    for s in tqdm(seeds, desc=desc, disable=not progress):
        acc: list[tuple[float, float]] = []

        def record(e, cycle: int, acc=acc) -> None:
            if cycle >= first:
                acc.append(cluster_metrics(e.state()[:, :2].astype(np.float64), link_radius))

        res = run_parallel_episode(env, group, int(s), on_step=record)
        a = np.array(acc)
        nn.append(float(a[:, 0].mean()))
        frac.append(float(a[:, 1].mean()))
        ret.append(float(np.mean(list(res["returns"].values()))))
        coll.append(float(np.mean(list(res["collisions"].values()))))
        rows.append({"seed": int(s), "nearest": nn[-1], "largest_cluster": frac[-1], "return": ret[-1],
                     "collisions": coll[-1]})
    return {"episodes": len(seeds), "nearest": mean_ci(nn), "largest_cluster": mean_ci(frac),
            "return": mean_ci(ret), "collisions": mean_ci(coll), "per_episode": rows}


# --- reporting ----------------------------------------------------------------------------------


def fmt_ci(m: float, lo: float, hi: float, digits: int = 2) -> str:
    if math.isnan(m):
        return "–"
    if math.isnan(lo):
        return f"{m:.{digits}f}"
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def markdown_table(results: dict[str, dict], swarm: bool, meta: dict[str, Any]) -> str:
    if swarm:
        head = (f"| policy | nearest-neighbour distance, m (lower = tighter) | largest-cluster fraction "
                f"(link {meta['link_radius']} m) | return per robot | collision steps per robot |")
        lines = [head, "|---|---|---|---|---|"]
        for name, r in results.items():
            lines.append(f"| {name} | {fmt_ci(*r['nearest'])} | {fmt_ci(*r['largest_cluster'])} | "
                         f"{fmt_ci(*r['return'], 1)} | {fmt_ci(*r['collisions'], 1)} |")
    else:
        lines = ["| policy | success rate | return | collision steps | steps to success |",
                 "|---|---|---|---|---|"]
        for name, r in results.items():
            lines.append(f"| {name} | {fmt_ci(r['success_rate'], *r['success_ci'])} | "
                         f"{fmt_ci(*r['return'])} | {fmt_ci(*r['collisions'], 1)} | "
                         f"{fmt_ci(*r['time_to_success'], 1)} |")
    how = ("bootstrap BCa over episodes; swarm metrics averaged over the last "
           f"{meta['metric_cycles']} cycles of each episode" if swarm
           else "Wilson for the success rate, bootstrap BCa for means")
    note = (f"\n{meta['episodes']} episodes per policy, seeds {meta['first_seed']}–"
            f"{meta['first_seed'] + meta['episodes'] - 1}; 95 % intervals in brackets ({how}).\n")
    return "\n".join(lines) + "\n" + note


def load_curve(model_path: Path) -> dict[str, np.ndarray] | None:
    """Learning curve next to a model: ``eval/evaluations.npz`` (train_single) or ``monitor.csv``
    / ``monitor/*.monitor.csv`` (rolling mean training return)."""
    d = model_path.parent
    if d.name in ("checkpoints", "best"):  # a checkpoint: the logs are in the run directory
        d = d.parent
    npz = d / "eval" / "evaluations.npz"
    if npz.is_file():
        z = np.load(npz)
        out = {"timesteps": z["timesteps"], "return": z["results"].mean(axis=1)}
        if "successes" in z and z["successes"].size:
            out["success"] = z["successes"].mean(axis=1)
        return out
    files = sorted((d / "monitor").glob("*.monitor.csv"))
    if (d / "monitor.csv").is_file():
        files.append(d / "monitor.csv")
    rows = []
    for f in files:
        with f.open() as fh:
            fh.readline()  # JSON header
            rows += [(float(r["t"]), float(r["r"]), int(r["l"])) for r in csv.DictReader(fh)]
    if not rows:
        return None
    rows.sort()
    t, r, l = map(np.array, zip(*rows, strict=True))
    w = max(1, len(r) // 50)
    smooth = np.convolve(r, np.ones(w) / w, mode="valid")
    return {"timesteps": np.cumsum(l)[w - 1 :], "return": smooth}


def plot_curves(curves: dict[str, dict], path: Path) -> bool:
    if not curves:
        return False
    try:
        import matplotlib
    except ImportError:  # the viz extra: the tables do not need it
        log.warning("no learning_curve.png: matplotlib is not installed (pip install kin-envs[viz])")
        return False

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_success = any("success" in c for c in curves.values())
    fig, axes = plt.subplots(1, 2 if has_success else 1, figsize=(11 if has_success else 6, 4), squeeze=False)
    for name, c in curves.items():
        axes[0, 0].plot(c["timesteps"], c["return"], label=name)
        if "success" in c:
            axes[0, 1].plot(c["timesteps"], c["success"], label=name)
    axes[0, 0].set(xlabel="training steps", ylabel="mean episode return", title="return")
    if has_success:
        axes[0, 1].set(xlabel="training steps", ylabel="success rate (eval env)", title="success",
                       ylim=(-0.02, 1.02))
    for ax in axes[0]:
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    return True


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="kin_envs/KinSeek-v2",
                   help=f"a registered id or {SWARM_ID!r} (or aggregation_v1, aggregation_v0)")
    p.add_argument("--env-kwargs", default=None, help="env kwargs of the built-in policies, JSON object")
    p.add_argument("--policies", nargs="*", default=None,
                   help=f"built-in policies {sorted(BUILTIN)} (default: {DEFAULT_POLICIES})")
    p.add_argument("--model", action="append", default=[], help="[NAME=]PATH of a trained SB3 model")
    p.add_argument("--episodes", type=int, default=None, help="episodes per policy (default 100; swarm 20)")
    p.add_argument("--first-seed", type=int, default=1_000_000,
                   help="seed of the first episode (default far from training and eval seeds)")
    p.add_argument("--n-robots", type=int, default=8, help="swarm size")
    p.add_argument("--max-cycles", type=int, default=None, help="swarm episode length (default: the env's)")
    p.add_argument("--link-radius", type=float, default=0.5, help="swarm: cluster link radius, m")
    p.add_argument("--metric-cycles", type=int, default=50, help="swarm: average metrics over the last N")
    p.add_argument("--out", type=Path, default=Path("outputs/evaluate_policies"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads for the SB3 models")
    p.add_argument("--no-progress", action="store_true", help="no progress bars, no table on stdout")
    add_logging_args(p)
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate; returns ``{"results": {policy: metrics}, "markdown": table, "out": dir}``."""
    args = parse_args(argv)
    setup_logging(args)
    swarm = args.env in SWARM_ENVS
    if args.env_kwargs:
        base_kwargs = json.loads(args.env_kwargs)
        if not isinstance(base_kwargs, dict):
            raise ValueError(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r}")
    else:
        base_kwargs = dict(DEFAULT_SWARM_KWARGS) if swarm else {}
    if swarm and args.max_cycles is not None:
        base_kwargs["max_cycles"] = args.max_cycles
    episodes = args.episodes if args.episodes is not None else (20 if swarm else 100)
    for name, v, lo in (("--episodes", episodes, 1), ("--first-seed", args.first_seed, 0),
                        ("--metric-cycles", args.metric_cycles, 1),
                        ("--torch-threads", args.torch_threads, 1)):
        if v < lo:
            raise ValueError(f"{name} must be >= {lo}, got {v}")
    if not args.link_radius > 0:
        raise ValueError(f"--link-radius must be > 0 m, got {args.link_radius}")
    names = args.policies if args.policies is not None else DEFAULT_POLICIES["swarm" if swarm else "single"]
    out: Path = check_output_dir(args.out)  # before the episodes: an unwritable --out fails now
    models = [parse_model_arg(m) for m in args.model]
    seeds = np.arange(args.first_seed, args.first_seed + episodes)
    progress = not args.no_progress
    results: dict[str, dict] = {}
    curves: dict[str, dict] = {}
    used_kwargs: dict[str, dict] = {}

    def evaluate(name: str, env, policy) -> dict:
        if swarm:
            return evaluate_swarm(env, policy, seeds, args.link_radius, args.metric_cycles, name, progress)
        return evaluate_single(env, policy, seeds, name, progress)

    for name in names:
        env = make_env(args.env, base_kwargs, args.n_robots)
        used_kwargs[name] = base_kwargs
        results[name] = evaluate(name, env, make_builtin(name, env, swarm))
        env.close()
    if models:
        import torch

        from agents.sb3 import SB3Policy

        torch.set_num_threads(args.torch_threads)
        for name, path in models:
            kw = model_env_kwargs(path, base_kwargs)
            if swarm and args.max_cycles is not None:
                kw["max_cycles"] = args.max_cycles
            env = make_env(args.env, kw, args.n_robots)
            policy = SB3Policy.load(path).check_env(env)
            used_kwargs[name] = kw
            results[name] = evaluate(name, env, PolicyGroup.shared(policy, env.possible_agents)
                                     if swarm else policy)
            env.close()
            curve = load_curve(path)
            if curve is not None:
                curves[name] = curve

    meta = {"episodes": episodes, "first_seed": args.first_seed, "link_radius": args.link_radius,
            "metric_cycles": args.metric_cycles}
    md = f"## {args.env}" + (f", {args.n_robots} robots" if swarm else "") + "\n\n"
    md += markdown_table(results, swarm, meta)
    write_text(out / "results.md", md)
    write_json(out / "results.json", {"env": args.env, "results": results}, indent=1, default=float)
    plotted = plot_curves(curves, out / "learning_curve.png")
    write_run_info(out, args, config={"env": args.env, "episodes": episodes}, seed=args.first_seed,
                   argv=argv, script=__file__,
                   env_kwargs=used_kwargs, seeds=[int(seeds[0]), int(seeds[-1])],
                   models={n: str(p) for n, p in models})
    log.info("wrote %s", ", ".join(str(out / f) for f in ("results.md", "results.json", "run.json")))
    if progress:
        print(md)
    return {"results": results, "markdown": md, "out": out,
            "learning_curve": out / "learning_curve.png" if plotted else None}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
