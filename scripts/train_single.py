"""Train an SB3 agent (PPO, or SAC for continuous actions) on a registered kin env.

Hyperparameters come from :data:`agents.hyperparams.HYPERPARAMS` (keyed by env id and algorithm);
the command line overrides any of them. Everything is seeded by ``--seed``: the training envs
(env ``i`` gets ``seed + i``), the algorithm (torch, numpy, action space) and the evaluation env
(``seed + 10_000``, reseeded before every evaluation so each one plays the same episodes).

Outputs in ``--out``: ``model.zip`` (final), ``best/best_model.zip`` (best evaluation),
``checkpoints/``, ``eval/evaluations.npz`` (SB3's ``EvalCallback`` log: timesteps, returns,
lengths, successes), ``monitor/`` (per-episode CSVs of the training envs), ``tb/`` (tensorboard)
and ``run.json`` (command, config, seed, versions, timing, final evaluation).

Example::

    python scripts/train_single.py --env kin_envs/KinSeek-v2 --env-kwargs '{"obs_detections": "topk"}' \\
        --timesteps 300000 --out runs/seek_topk
    python scripts/train_single.py --env-kwargs '{"detector": null}' --out runs/seek_scan
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a file: make agents / kin_envs importable from the checkout
    sys.path.insert(0, str(ROOT))

import kin_envs  # noqa: E402,F401  (registers the env ids)
from agents.hyperparams import hyperparams_for  # noqa: E402
from agents.sb3 import ALGOS, algo_class, atomic_checkpoints, atomic_save_callback, resolve_policy_kwargs  # noqa: E402
from kin_envs.cli import (  # noqa: E402
    add_logging_args,
    parse_json_object,
    script_logger,
    setup_logging,
    write_run_info,
)

VEC_ENVS = ("dummy", "subproc")
EVAL_SEED_OFFSET = 10_000
#: where SB3's EvalCallback writes its log before it is renamed into eval/ (see make_callbacks)
LIVE_EVAL_DIR = ".live"


@dataclass(frozen=True)
class TrainConfig:
    """Validated settings of one training run (``from_dict`` rejects unknown keys)."""

    env_id: str = "kin_envs/KinSeek-v2"
    env_kwargs: dict = field(default_factory=dict)
    algo: str = "ppo"
    total_timesteps: int = 300_000
    n_envs: int = 8
    vec_env: str = "dummy"
    seed: int = 0
    eval_freq: int = 20_000
    eval_episodes: int = 50
    checkpoint_freq: int = 100_000
    torch_threads: int = 1
    algo_kwargs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        if self.vec_env not in VEC_ENVS:
            raise ValueError(f"vec_env must be one of {VEC_ENVS}, got {self.vec_env!r}")
        for name, lo in (("total_timesteps", 1), ("n_envs", 1), ("seed", 0), ("eval_freq", 0),
                         ("eval_episodes", 1), ("checkpoint_freq", 0), ("torch_threads", 1)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not isinstance(self.env_kwargs, dict) or not isinstance(self.algo_kwargs, dict):
            raise ValueError("env_kwargs and algo_kwargs must be JSON objects (dicts)")
        if self.env_id not in gymnasium.registry:
            raise ValueError(f"unknown env id {self.env_id!r}; registered kin envs: "
                             f"{sorted(k for k in gymnasium.registry if k.startswith('kin_envs/'))}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown TrainConfig key(s) {unknown}; valid: {sorted(names)}")
        return cls(**d)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def check_env_and_algo(cfg: TrainConfig) -> None:
    """Make the env once (bad env kwargs raise the env's ``ValueError``) and check the algorithm's
    keyword arguments against its signature."""
    env = gymnasium.make(cfg.env_id, **cfg.env_kwargs)
    try:
        if cfg.algo == "sac" and not isinstance(env.action_space, gymnasium.spaces.Box):
            raise ValueError(f"SAC needs continuous actions; {cfg.env_id} with {cfg.env_kwargs} has "
                             f"{env.action_space} (drop action_type='discrete' or use --algo ppo)")
    finally:
        env.close()
    cls = algo_class(cfg.algo)
    valid = set(inspect.signature(cls.__init__).parameters) - {"self", "policy", "env", "seed",
                                                                "tensorboard_log", "verbose", "device"}
    unknown = sorted(set(cfg.algo_kwargs) - valid)
    if unknown:
        raise ValueError(f"unknown {cfg.algo.upper()} hyperparameter(s) {unknown}; valid: {sorted(valid)}")


def build_config(args: argparse.Namespace) -> TrainConfig:
    shipped = hyperparams_for(args.env, args.algo)
    train, algo_kwargs = shipped["train"], shipped["algo"]
    algo_kwargs.update(parse_json_object(args.hyperparams, "--hyperparams") or {})
    d = {
        "env_id": args.env,
        "env_kwargs": parse_json_object(args.env_kwargs, "--env-kwargs") or {},
        "algo": args.algo,
        "total_timesteps": args.timesteps if args.timesteps is not None else train["total_timesteps"],
        "n_envs": args.n_envs if args.n_envs is not None else train["n_envs"],
        "vec_env": args.vec_env,
        "seed": args.seed,
        "eval_freq": args.eval_freq,
        "eval_episodes": args.eval_episodes,
        "checkpoint_freq": args.checkpoint_freq,
        "torch_threads": args.torch_threads,
        "algo_kwargs": algo_kwargs,
    }
    return TrainConfig.from_dict(d)


def make_callbacks(cfg: TrainConfig, out: Path, progress: bool):
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
    from stable_baselines3.common.env_util import make_vec_env

    from kin_envs.cli import progress as tqdm

    class SeededEvalCallback(EvalCallback):
        """Reseeds the eval env before each evaluation: every point of the curve plays the same
        episodes, so the curve shows the policy improving rather than layout luck. SB3 rewrites its log
        in place (``np.savez``); it writes it to ``eval/.live/`` here and each evaluation's log is
        renamed over ``eval/evaluations.npz``, so the file under the final name is always whole."""

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(cfg.seed + EVAL_SEED_OFFSET)
            keep_going = super()._on_step()
            live = out / "eval" / LIVE_EVAL_DIR / "evaluations.npz"
            if live.is_file():
                os.replace(live, out / "eval" / "evaluations.npz")
            return keep_going

    class TqdmCallback(BaseCallback):
        """Progress bar (SB3's progress_bar=True needs rich, which is not a dependency)."""

        def _on_training_start(self) -> None:
            self.bar = tqdm(total=cfg.total_timesteps, desc=f"{cfg.algo} {cfg.env_id}", unit="step",
                            disable=not progress, mininterval=2.0)

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    callbacks = [TqdmCallback()]
    if cfg.eval_freq > 0:
        eval_env = make_vec_env(cfg.env_id, n_envs=1, seed=cfg.seed + EVAL_SEED_OFFSET,
                                env_kwargs=cfg.env_kwargs)
        callbacks.append(SeededEvalCallback(
            eval_env, n_eval_episodes=cfg.eval_episodes, eval_freq=max(cfg.eval_freq // cfg.n_envs, 1),
            log_path=str(out / "eval" / LIVE_EVAL_DIR), deterministic=True, verbose=0,
            callback_on_new_best=atomic_save_callback(out / "best" / "best_model.zip"),
        ))
    if cfg.checkpoint_freq > 0:
        callbacks.append(atomic_checkpoints(max(cfg.checkpoint_freq // cfg.n_envs, 1), out / "checkpoints"))
    return callbacks


def final_evaluation(out: Path) -> dict[str, Any] | None:
    """Last point of the evaluation log (mean return, success rate)."""
    path = out / "eval" / "evaluations.npz"
    if not path.is_file():
        return None
    d = np.load(path)
    res = {"timesteps": int(d["timesteps"][-1]), "mean_return": float(d["results"][-1].mean()),
           "mean_length": float(d["ep_lengths"][-1].mean())}
    if "successes" in d and d["successes"].size:
        res["success_rate"] = float(d["successes"][-1].mean())
        res["best_success_rate"] = float(d["successes"].mean(axis=1).max())
    return res


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="kin_envs/KinSeek-v2", help="registered Gymnasium id")
    p.add_argument("--env-kwargs", default=None, help="env kwargs as a JSON object (or a JSON file)")
    p.add_argument("--algo", default="ppo", choices=ALGOS, help="SB3 algorithm (default: %(default)s)")
    p.add_argument("--timesteps", type=int, default=None, help="total env steps (default: shipped)")
    p.add_argument("--n-envs", type=int, default=None, help="parallel envs (default: shipped)")
    p.add_argument("--vec-env", default="dummy", choices=VEC_ENVS,
                   help="SB3 vec env: dummy (one process) or subproc (one process per env)")
    p.add_argument("--hyperparams", default=None,
                   help="algorithm kwargs overriding the shipped ones, JSON object (or file)")
    p.add_argument("--seed", type=int, default=0, help="seed of the model and the envs (eval env: +10,000)")
    p.add_argument("--eval-freq", type=int, default=20_000, help="env steps between evaluations (0 = off)")
    p.add_argument("--eval-episodes", type=int, default=50, help="episodes per evaluation")
    p.add_argument("--checkpoint-freq", type=int, default=100_000, help="env steps between checkpoints")
    p.add_argument("--torch-threads", type=int, default=1,
                   help="torch threads (1: two threads on a busy 2-core machine ran 30x slower)")
    p.add_argument("--out", type=Path, default=Path("runs/train_single"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar, no summary on stdout")
    add_logging_args(p)
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Train; returns ``{"model": path, "run": run.json contents, "model_object": the SB3 model}``."""
    args = parse_args(argv)
    setup_logging(args)
    cfg = build_config(args)
    check_env_and_algo(cfg)

    import torch
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    torch.set_num_threads(cfg.torch_threads)
    from kin_envs.cli import check_output_dir

    out: Path = check_output_dir(args.out)  # a clear error before training, not a traceback

    def write_run(**fields) -> dict[str, Any]:
        return write_run_info(out, args, config=cfg.to_dict(), seed=cfg.seed, argv=argv, script=__file__,
                              algo=cfg.algo, env_id=cfg.env_id, env_kwargs=cfg.env_kwargs, **fields)

    write_run(status="running")

    vec_cls = SubprocVecEnv if cfg.vec_env == "subproc" else DummyVecEnv
    env = make_vec_env(cfg.env_id, n_envs=cfg.n_envs, seed=cfg.seed, env_kwargs=cfg.env_kwargs,
                       vec_env_cls=vec_cls, monitor_dir=str(out / "monitor"))
    algo_kwargs = dict(cfg.algo_kwargs)
    if "policy_kwargs" in algo_kwargs:  # e.g. "agents.sb3:ScanConvExtractor" -> the class
        algo_kwargs["policy_kwargs"] = resolve_policy_kwargs(algo_kwargs["policy_kwargs"])
    model = algo_class(cfg.algo)("MlpPolicy", env, seed=cfg.seed, tensorboard_log=str(out / "tb"),
                                 device="cpu", verbose=0, **algo_kwargs)
    t0 = time.perf_counter()
    try:
        callbacks = make_callbacks(cfg, out, not args.no_progress)
        model.learn(total_timesteps=cfg.total_timesteps, callback=callbacks, tb_log_name=cfg.algo)
    finally:  # also after Ctrl-C: the evaluation log's scratch copy (maybe half-written) goes
        shutil.rmtree(out / "eval" / LIVE_EVAL_DIR, ignore_errors=True)
    elapsed = time.perf_counter() - t0
    model_path = out / "model.zip"
    from detectors.fileio import atomic_write

    with atomic_write(model_path) as f:  # never half a model under the final name
        model.save(f)
    env.close()
    run = write_run(status="done", train_seconds=round(elapsed, 1), timesteps=int(model.num_timesteps),
                    model=str(model_path), final_eval=final_evaluation(out))
    script_logger(__file__).info("wrote %s and %s", model_path, out / "run.json")
    if not args.no_progress:
        summary = {k: run[k] for k in ("model", "train_seconds", "timesteps", "final_eval")}
        print(json.dumps(summary, indent=2))
    return {"model": model_path, "run": run, "model_object": model}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
