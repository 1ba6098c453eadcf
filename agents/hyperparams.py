"""Shipped training hyperparameters, as data keyed by env id, then algorithm.

Each entry has ``"train"`` (the script's settings: ``n_envs``, ``total_timesteps``, ``eval_freq``,
...) and ``"algo"`` (keyword arguments of the SB3 algorithm; ``policy_kwargs`` included). The
training scripts validate both and let the command line override any key
(``--hyperparams '{"learning_rate": 1e-3}'``, ``--timesteps``, ...). Plain data only: no torch here.
"""

from __future__ import annotations

import copy
from typing import Any

__all__ = ["HYPERPARAMS", "hyperparams_for"]

_SINGLE_PPO = {
    "train": {"n_envs": 8, "total_timesteps": 300_000},
    # 8 envs x 256 steps = 2048 samples per update; episodes are <= 300 steps
    "algo": {
        "n_steps": 256, "batch_size": 256, "n_epochs": 10, "learning_rate": 3e-4, "gamma": 0.99,
        "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0,
        "policy_kwargs": {"net_arch": {"pi": [128, 128], "vf": [128, 128]}},
    },
}
_SINGLE_SAC = {
    "train": {"n_envs": 1, "total_timesteps": 100_000},
    "algo": {
        "learning_rate": 3e-4, "buffer_size": 200_000, "batch_size": 256, "learning_starts": 2_000,
        "gamma": 0.99, "tau": 0.005, "train_freq": 1, "gradient_steps": 1,
        "policy_kwargs": {"net_arch": [256, 256]},
    },
}

HYPERPARAMS: dict[str, dict[str, dict[str, dict[str, Any]]]] = {
    "kin_envs/KinSeek-v0": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    "kin_envs/KinFollow-v0": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    # v1 and v2: the same task and dynamics (v1: the info layout changed; v2: the tracker's default feed)
    "kin_envs/KinSeek-v1": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    "kin_envs/KinFollow-v1": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    "kin_envs/KinSeek-v2": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    "kin_envs/KinFollow-v2": {"ppo": _SINGLE_PPO, "sac": _SINGLE_SAC},
    "aggregation_v0": {
        "ppo": {
            # n_envs = copies of the whole swarm; every robot is one SB3 env of the shared policy
            "train": {"n_envs": 2, "total_timesteps": 400_000},
            "algo": {
                "n_steps": 128, "batch_size": 512, "n_epochs": 5, "learning_rate": 3e-4,
                "gamma": 0.99, "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0,
                "policy_kwargs": {"net_arch": {"pi": [128, 128], "vf": [128, 128]}},
            },
        },
    },
}
HYPERPARAMS["aggregation_v1"] = HYPERPARAMS["aggregation_v2"] = HYPERPARAMS["aggregation_v0"]


def hyperparams_for(env_id: str, algo: str) -> dict[str, dict[str, Any]]:
    """A deep copy of the shipped ``{"train": ..., "algo": ...}`` for ``env_id`` and ``algo``."""
    if env_id not in HYPERPARAMS:
        raise ValueError(f"no shipped hyperparameters for env {env_id!r}; known: {sorted(HYPERPARAMS)}")
    table = HYPERPARAMS[env_id]
    if algo not in table:
        raise ValueError(f"no shipped {algo!r} hyperparameters for {env_id!r}; known: {sorted(table)}")
    return copy.deepcopy(table[algo])
