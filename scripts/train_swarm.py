"""Train one PPO policy shared by every robot of the ``aggregation_v2`` swarm.

SuperSuit turns the PettingZoo parallel env into an SB3 vec env with one sub-env per robot
(``pettingzoo_env_to_vec_env_v1``) and concatenates ``--n-copies`` swarms
(``concat_vec_envs_v1``); every robot's experience trains the same network.

Seeding: SuperSuit's SB3 wrapper has no ``seed()``, so ``PPO(..., seed=...)`` cannot seed it. We
wrap the concatenated env ourselves (:func:`agents.sb3.shared_vec_env`): ``seed(s)`` is kept and
passed to the next ``reset()``, where swarm copy ``i`` is reset with ``s + i``; later episodes
continue each env's seeded RNG. Two runs with the same ``--seed`` give identical parameters.

Outputs in ``--out``: ``model.zip``, ``checkpoints/``, ``monitor.csv`` (SB3 ``VecMonitor``: one
row per robot-episode, its return), ``tb/`` (tensorboard) and ``run.json`` (command, config,
seed, versions, timing).

Example::

    python scripts/train_swarm.py --n-robots 8 --timesteps 1000000 --out runs/swarm
    python scripts/evaluate_policies.py --env aggregation_v2 --model runs/swarm/model.zip
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a file: make agents / kin_envs importable from the checkout
    sys.path.insert(0, str(ROOT))

from agents.hyperparams import hyperparams_for  # noqa: E402
from agents.sb3 import atomic_checkpoints  # noqa: E402
from detectors.fileio import atomic_write  # noqa: E402
from kin_envs import aggregation_v2  # noqa: E402
from kin_envs.cli import add_logging_args, parse_json_object, setup_logging, write_run_info  # noqa: E402

ENV_ID = "aggregation_v2"
#: the swarm's env kwargs unless --env-kwargs says otherwise: the detector channel in the observation
DEFAULT_ENV_KWARGS = {"obs_detections": "topk"}


@dataclass(frozen=True)
class SwarmTrainConfig:
    """Validated settings of one swarm training run (``from_dict`` rejects unknown keys)."""

    n_robots: int = 8
    env_kwargs: dict = field(default_factory=lambda: dict(DEFAULT_ENV_KWARGS))
    n_copies: int = 2
    total_timesteps: int = 400_000
    seed: int = 0
    checkpoint_freq: int = 200_000
    torch_threads: int = 1
    algo_kwargs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, lo in (("n_robots", 2), ("n_copies", 1), ("total_timesteps", 1), ("seed", 0),
                         ("checkpoint_freq", 0), ("torch_threads", 1)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not isinstance(self.env_kwargs, dict) or not isinstance(self.algo_kwargs, dict):
            raise ValueError("env_kwargs and algo_kwargs must be JSON objects (dicts)")
        if "n_robots" in self.env_kwargs:
            raise ValueError("give the swarm size as --n-robots, not in --env-kwargs")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SwarmTrainConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown SwarmTrainConfig key(s) {unknown}; valid: {sorted(names)}")
        return cls(**d)

    def make_env(self):
        """The PettingZoo parallel env (bad kwargs raise the env's ``ValueError``)."""
        return aggregation_v2.parallel_env(n_robots=self.n_robots, **self.env_kwargs)


def build_config(args: argparse.Namespace) -> SwarmTrainConfig:
    shipped = hyperparams_for(ENV_ID, "ppo")
    algo_kwargs = shipped["algo"]
    algo_kwargs.update(parse_json_object(args.hyperparams, "--hyperparams") or {})
    env_kwargs = parse_json_object(args.env_kwargs, "--env-kwargs")
    return SwarmTrainConfig.from_dict({
        "n_robots": args.n_robots,
        "env_kwargs": dict(DEFAULT_ENV_KWARGS) if env_kwargs is None else env_kwargs,
        "n_copies": args.n_copies if args.n_copies is not None else shipped["train"]["n_envs"],
        "total_timesteps": (args.timesteps if args.timesteps is not None
                            else shipped["train"]["total_timesteps"]),
        "seed": args.seed,
        "checkpoint_freq": args.checkpoint_freq,
        "torch_threads": args.torch_threads,
        "algo_kwargs": algo_kwargs,
    })


def make_model(cfg: SwarmTrainConfig, tensorboard_log: str | None = None):
    """The seeded vec env (VecMonitor on top) and the PPO model on it."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.sb3 import shared_vec_env

    valid = set(inspect.signature(PPO.__init__).parameters) - {"self", "policy", "env", "seed",
                                                                 "tensorboard_log", "verbose", "device"}
    unknown = sorted(set(cfg.algo_kwargs) - valid)
    if unknown:
        raise ValueError(f"unknown PPO hyperparameter(s) {unknown}; valid: {sorted(valid)}")
    venv = shared_vec_env(cfg.make_env(), cfg.n_copies)
    monitor = None if tensorboard_log is None else str(Path(tensorboard_log).parent / "monitor.csv")
    venv = VecMonitor(venv, filename=monitor)
    # PPO(seed=...) seeds torch/numpy/the action space and calls venv.seed(seed): our wrapper applies
    # it at the first reset
    model = PPO("MlpPolicy", venv, seed=cfg.seed, tensorboard_log=tensorboard_log, device="cpu",
                verbose=0, **cfg.algo_kwargs)
    return venv, model


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n-robots", type=int, default=8, help="robots per swarm (default: %(default)s)")
    p.add_argument("--env-kwargs", default=None,
                   help=f"aggregation_v2 kwargs, JSON object or file (default {DEFAULT_ENV_KWARGS})")
    p.add_argument("--n-copies", type=int, default=None, help="swarms run side by side (default: shipped)")
    p.add_argument("--timesteps", type=int, default=None,
                   help="total robot-steps (one swarm step of n robots = n; default: shipped)")
    p.add_argument("--hyperparams", default=None, help="PPO kwargs overriding the shipped ones, JSON")
    p.add_argument("--seed", type=int, default=0, help="seed of PPO and the swarm copies (copy i: seed + i)")
    p.add_argument("--checkpoint-freq", type=int, default=200_000, help="robot-steps between checkpoints")
    p.add_argument("--torch-threads", type=int, default=1,
                   help="torch threads (1: two threads on a busy 2-core machine ran 30x slower)")
    p.add_argument("--out", type=Path, default=Path("runs/train_swarm"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(p)
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Train; returns ``{"model": path, "run": run.json contents, "model_object": the PPO model}``."""
    args = parse_args(argv)
    setup_logging(args)
    cfg = build_config(args)
    cfg.make_env().close()  # validate the env kwargs before anything heavy

    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from kin_envs.cli import progress as tqdm

    torch.set_num_threads(cfg.torch_threads)
    from kin_envs.cli import check_output_dir

    out: Path = check_output_dir(args.out)  # a clear error before training, not a traceback

    def write_run(**fields) -> dict[str, Any]:
        env_kwargs = {"n_robots": cfg.n_robots, **cfg.env_kwargs}
        return write_run_info(out, args, config=cfg, seed=cfg.seed, argv=argv, script=__file__, algo="ppo",
                              env_id=ENV_ID, env_kwargs=env_kwargs, **fields)

    write_run(status="running")

    venv, model = make_model(cfg, tensorboard_log=str(out / "tb"))

    class TqdmCallback(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=cfg.total_timesteps, desc="swarm ppo", unit="robot-step",
                            disable=args.no_progress, mininterval=2.0)

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    callbacks = [TqdmCallback()]
    if cfg.checkpoint_freq > 0:
        every = max(cfg.checkpoint_freq // venv.num_envs, 1)  # calls: one per step of all robots
        callbacks.append(atomic_checkpoints(every, out / "checkpoints"))
    t0 = time.perf_counter()
    model.learn(total_timesteps=cfg.total_timesteps, callback=callbacks, tb_log_name="ppo")
    elapsed = time.perf_counter() - t0
    model_path = out / "model.zip"
    with atomic_write(model_path) as f:  # never half a model under the final name
        model.save(f)
    venv.close()
    run = write_run(status="done", train_seconds=round(elapsed, 1), timesteps=int(model.num_timesteps),
                    model=str(model_path))
    return {"model": model_path, "run": run, "model_object": model}


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
