"""Train one PPO policy shared by every robot of the ``aggregation_v2`` swarm with RLlib (Ray).

The RLlib counterpart of ``scripts/train_swarm.py`` for runs that outgrow one machine: the
PettingZoo parallel env goes through RLlib's ``ParallelPettingZooEnv``; every robot maps to the
single module ``shared`` (parameter sharing); ``--env-runners`` Ray actors sample swarms in
parallel (0: sample in this process) and the learner runs in this process. Without ``--address``
a local Ray starts (``--num-cpus``); with it the run joins an existing cluster (``ray start
--head`` on one machine, ``ray start --address=HEAD:6379`` on the others; kin-envs installed on
all of them).

RLlib's new API stack (ray 2.60): ``PPOConfig().environment(...).env_runners(num_env_runners=...)
.multi_agent(policies=..., policy_mapping_fn=...)``.

Seeding: ``--seed`` goes to ``config.debugging(seed=...)``: RLlib seeds Python, numpy and torch
in every process and env runner ``i`` resets its swarm with ``seed + i`` once; later episodes
continue that env's RNG. RLlib also keeps agent ids in sets, whose order follows Python's string
hash, so run as a command the script fixes ``PYTHONHASHSEED`` (0 unless set; a local Ray's workers
inherit it; on a cluster set it where ``ray start`` runs). Then the same command gives the same
run (checked with 0 and 1 env runner; with several, the order in which their samples reach the
learner may vary).

Outputs in ``--out``: ``checkpoint/`` (``Algorithm.save_to_path``; the policy alone is
``checkpoint/learner_group/learner/rl_module/shared``, loadable with
``ray.rllib.core.rl_module.RLModule.from_checkpoint``), ``metrics.jsonl`` (one line per
iteration) and ``run.json`` (command, config, seed, versions, timing).

Example::

    python scripts/train_swarm_rllib.py --n-robots 8 --env-runners 2 --iterations 200 --out runs/rllib
    python scripts/train_swarm_rllib.py --address auto --env-runners 32 --iterations 2000
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a file: make kin_envs importable from the checkout
    sys.path.insert(0, str(ROOT))

from detectors.fileio import LiveLog  # noqa: E402
from kin_envs import aggregation_v2  # noqa: E402
from kin_envs.cli import add_logging_args, script_logger, setup_logging, write_run_info  # noqa: E402
from kin_envs.cli import progress as tqdm  # noqa: E402
from kin_envs.distributed import ray_session, ship_by_value  # noqa: E402

ENV_NAME = "kin_envs_aggregation_v2"
POLICY_ID = "shared"
#: env kwargs unless --env-kwargs says otherwise: as scripts/train_swarm.py (detector channel on)
DEFAULT_ENV_KWARGS = {"obs_detections": "topk"}


def make_env(env_config: dict):
    """RLlib env creator (top level: env runners on other machines rebuild the env from it)."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    return ParallelPettingZooEnv(aggregation_v2.parallel_env(**env_config))


def policy_mapping_fn(agent_id, episode=None, **kwargs) -> str:
    """Every robot acts with, and trains, the one shared module."""
    return POLICY_ID


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-robots", type=int, default=8, help="robots per swarm (2-256)")
    p.add_argument("--max-cycles", type=int, default=500, help="steps per episode")
    p.add_argument(
        "--env-kwargs",
        default=None,
        help=f"more aggregation_v2 kwargs, JSON (default {json.dumps(DEFAULT_ENV_KWARGS)})",
    )
    p.add_argument("--iterations", type=int, default=100, help="PPO iterations (train() calls)")
    p.add_argument("--env-runners", type=int, default=2, help="Ray env-runner actors (0: sample here)")
    p.add_argument("--batch", type=int, default=4000, help="env steps per iteration (x robots agent steps)")
    p.add_argument("--minibatch", type=int, default=1000, help="SGD minibatch, env steps")
    p.add_argument("--epochs", type=int, default=10, help="SGD epochs per iteration")
    p.add_argument("--lr", type=float, default=3e-4, help="learning rate (default: %(default)s)")
    p.add_argument("--gamma", type=float, default=0.99, help="discount factor (default: %(default)s)")
    p.add_argument("--hidden", type=int, nargs="+", default=[256, 256], help="MLP layer sizes")
    p.add_argument("--seed", type=int, default=0, help="seed of RLlib, the env runners and the envs")
    p.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch threads of the learner (1: two threads on a busy 2-core machine ran 30x slower)",
    )
    p.add_argument("--address", default=None, help="join this Ray cluster (e.g. auto, host:6379)")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of a local Ray (default: all)")
    p.add_argument(
        "--checkpoint-every", type=int, default=0, help="also checkpoint every N iterations (0: end)"
    )
    p.add_argument("--out", type=Path, default=Path("runs/train_swarm_rllib"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    positive = {
        "n_robots": 2,
        "max_cycles": 1,
        "iterations": 1,
        "batch": 1,
        "minibatch": 1,
        "epochs": 1,
        "torch_threads": 1,
    }
    for name, lo in positive.items():
        if getattr(args, name) < lo:
            p.error(f"--{name.replace('_', '-')} must be >= {lo}, got {getattr(args, name)}")
    if args.env_runners < 0 or args.seed < 0 or args.checkpoint_every < 0:
        p.error("--env-runners, --seed and --checkpoint-every must be >= 0")
    if args.minibatch > args.batch:
        p.error(f"--minibatch ({args.minibatch}) must not exceed --batch ({args.batch})")
    if not (math.isfinite(args.lr) and args.lr > 0 and 0 < args.gamma <= 1) or min(args.hidden) < 1:
        p.error("--lr must be > 0, --gamma in (0, 1] and --hidden sizes >= 1")
    if args.num_cpus is not None and (args.num_cpus < 1 or args.address is not None):
        p.error("--num-cpus must be >= 1 and sizes a local Ray, not a cluster at --address")
    try:
        extra = json.loads(args.env_kwargs) if args.env_kwargs else {}
    except json.JSONDecodeError as e:
        p.error(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r} ({e})")
    if not isinstance(extra, dict):
        p.error(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r}")
    args.env_config = {
        **DEFAULT_ENV_KWARGS,
        **extra,
        "n_robots": args.n_robots,
        "max_cycles": args.max_cycles,
    }
    try:  # fail here, not inside an env runner: unknown names and bad values raise ValueError
        aggregation_v2.parallel_env(**args.env_config).close()
    except ValueError as e:
        p.error(f"--env-kwargs: {e}")
    return args


def build_config(args: argparse.Namespace):
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=args.env_config)
        .env_runners(num_env_runners=args.env_runners, num_cpus_per_env_runner=1)
        .multi_agent(policies={POLICY_ID}, policy_mapping_fn=policy_mapping_fn)
        .rl_module(
            model_config=DefaultModelConfig(fcnet_hiddens=list(args.hidden)),
            rl_module_spec=MultiRLModuleSpec(rl_module_specs={POLICY_ID: RLModuleSpec()}),
        )
        .training(
            train_batch_size_per_learner=args.batch,
            minibatch_size=args.minibatch,
            num_epochs=args.epochs,
            lr=args.lr,
            gamma=args.gamma,
        )  # fmt: skip
        .learners(num_learners=0)  # the learner runs in this process (CPU)
        .debugging(seed=args.seed)
    )


def _iteration_row(it: int, result: dict, seconds: float) -> dict:
    from ray.rllib.utils.metrics import (
        ENV_RUNNER_RESULTS,
        EPISODE_LEN_MEAN,
        EPISODE_RETURN_MEAN,
        NUM_ENV_STEPS_SAMPLED_LIFETIME,
        NUM_MODULE_STEPS_SAMPLED_LIFETIME,
    )

    runners = result.get(ENV_RUNNER_RESULTS, {})

    def num(x):
        return float(x) if isinstance(x, int | float) and math.isfinite(x) else None

    return {
        "iteration": it,
        "env_steps": int(result.get(NUM_ENV_STEPS_SAMPLED_LIFETIME, 0) or 0),
        "agent_steps": int(runners.get(NUM_MODULE_STEPS_SAMPLED_LIFETIME, {}).get(POLICY_ID, 0)),
        # swarm return: the sum over robots of their episode returns
        "episode_return_mean": num(runners.get(EPISODE_RETURN_MEAN)),
        "episode_len_mean": num(runners.get(EPISODE_LEN_MEAN)),
        "seconds": seconds,
    }


def save_checkpoint(algo, path: Path) -> Path:
    """``algo.save_to_path`` into a hidden directory beside ``path``, then renamed to ``path``: a
    checkpoint directory under its final name is always complete (RLlib writes its files one by one)."""
    path = path.resolve()
    tmp = path.with_name(f".{path.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    algo.save_to_path(str(tmp))
    if path.exists():  # an earlier run's checkpoint in the same --out
        shutil.rmtree(path)
    os.rename(tmp, path)
    return path


def main(argv=None) -> dict:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(args.torch_threads)

    from kin_envs.cli import check_output_dir

    out: Path = check_output_dir(args.out)  # a clear error before training, not a traceback
    t0 = time.perf_counter()
    rows: list[dict] = []
    with ray_session(args.address, args.num_cpus) as ray:  # without ray: ImportError with the pip hint
        from ray.tune.registry import register_env

        cpus = ray.cluster_resources().get("CPU", 0)
        if args.env_runners > cpus:
            raise ValueError(
                f"--env-runners {args.env_runners} needs as many CPUs, the Ray cluster has {cpus:g}; "
                "each env runner takes one CPU"
            )
        ship_by_value(make_env)  # env runners rebuild the env (and mapping fn) from this file
        register_env(ENV_NAME, make_env)
        config = build_config(args)
        algo = config.build_algo()
        metrics = LiveLog(out / "metrics.jsonl")  # flushed per line; whole lines only, even after Ctrl-C
        try:
            bar = tqdm(range(1, args.iterations + 1), desc="iterations", unit="it", disable=args.no_progress)
            for it in bar:
                t_it = time.perf_counter()
                row = _iteration_row(it, algo.train(), time.perf_counter() - t_it)
                rows.append(row)
                metrics.write(json.dumps(row) + "\n")
                ret = row["episode_return_mean"]
                bar.set_postfix(env_steps=row["env_steps"], ret="–" if ret is None else f"{ret:.2f}")
                if args.checkpoint_every and it % args.checkpoint_every == 0 and it < args.iterations:
                    save_checkpoint(algo, out / f"checkpoint_{it:06d}")
            metrics.close()
            checkpoint = save_checkpoint(algo, out / "checkpoint")
        finally:
            metrics.close()
            for tmp in out.glob(".checkpoint*.tmp"):  # a save cut short by Ctrl-C
                shutil.rmtree(tmp, ignore_errors=True)
            algo.stop()  # ends the env-runner actors before Ray shuts down
            with contextlib.suppress(OSError):  # the empty ~/ray_results/<time> every Algorithm makes
                Path(algo.logdir).rmdir()
        run = {
            "env": "aggregation_v2",
            "env_config": args.env_config,
            "python_hash_seed": os.environ.get("PYTHONHASHSEED"),
            "ray": {"address": args.address, "num_cpus": args.num_cpus, "cluster_cpus": cpus},
            "policy_id": POLICY_ID,
            "checkpoint": str(checkpoint),
            "module_checkpoint": str(checkpoint / "learner_group" / "learner" / "rl_module" / POLICY_ID),
            "iterations": len(rows),
            "final": rows[-1],
            "seconds": time.perf_counter() - t0,
        }
        run = write_run_info(out, args, config=config.to_dict(), seed=args.seed, argv=argv, script=__file__,
                             **run)
    ret = rows[-1]["episode_return_mean"]
    script_logger(__file__).info(
        f"{len(rows)} iterations, {rows[-1]['env_steps']} env steps in {run['seconds']:.1f} s; "
        f"swarm return {'–' if ret is None else f'{ret:.3f}'}; checkpoint {checkpoint}"
    )
    return {"run": run, "metrics": rows, "checkpoint": checkpoint}


if __name__ == "__main__":
    if "PYTHONHASHSEED" not in os.environ:  # see Seeding above: restart with a fixed string hash
        os.execve(sys.executable, [sys.executable, *sys.argv], {**os.environ, "PYTHONHASHSEED": "0"})
    try:
        main()
    except (ValueError, ImportError, ConnectionError) as e:
        sys.exit(f"train_swarm_rllib: error: {e}")
