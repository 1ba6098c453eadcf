"""Gymnasium and PettingZoo adapters of the world core.

``register_envs()`` registers the Gymnasium ids (string entry points: importing this package
does not import the env modules, torch or pygame):

* ``kin_envs/KinSeek-v0``: :class:`kin_envs.envs.kin_seek.KinSeekEnv`
* ``kin_envs/KinFollow-v0``: :class:`kin_envs.envs.kin_follow.KinFollowEnv`

The PettingZoo swarm is :mod:`kin_envs.aggregation_v0` (``env``, ``parallel_env``, ``raw_env``).
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "register_envs"]

ENV_IDS = {
    "kin_envs/KinSeek-v0": "kin_envs.envs.kin_seek:KinSeekEnv",
    "kin_envs/KinFollow-v0": "kin_envs.envs.kin_follow:KinFollowEnv",
}


def register_envs() -> None:
    """Register the Gymnasium ids (idempotent)."""
    import gymnasium

    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point)
