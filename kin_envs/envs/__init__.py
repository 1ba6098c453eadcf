"""Gymnasium and PettingZoo adapters of the world core.

``register_envs()`` registers the Gymnasium ids (string entry points: importing this package
does not import the env modules, torch or pygame):

* ``kin_envs/KinSeek-v2``: :class:`kin_envs.envs.kin_seek.KinSeekEnv`
* ``kin_envs/KinFollow-v2``: :class:`kin_envs.envs.kin_follow.KinFollowEnv`
* ``kin_envs/KinSeek-v1``, ``kin_envs/KinFollow-v1``: the same whose ``tracker=True`` feeds the tracker the
  detector's accepted detections (v2: ``"auto"``)
* ``kin_envs/KinSeek-v0``, ``kin_envs/KinFollow-v0``: v1 with the v0 (variable-length) info

The v1 and v2 ids have a native vector entry point (:class:`kin_envs.envs.vector.KinVectorEnv`), so
``gymnasium.make_vec(id, num_envs=K)`` steps K worlds with one lidar and one detector call.
The PettingZoo swarm is :mod:`kin_envs.aggregation_v2` (and ``aggregation_v1``, ``aggregation_v0``).

:func:`unpad_detections` / :func:`unpad_kin_truth` turn the fixed-shape (padded) info entries
back into variable-length columns.
"""

from __future__ import annotations

from kin_envs.envs.info import unpad_detections, unpad_kin_truth

__all__ = ["ENV_IDS", "VECTOR_ENTRY_POINTS", "register_envs", "unpad_detections", "unpad_kin_truth"]

ENV_IDS = {
    "kin_envs/KinSeek-v2": "kin_envs.envs.kin_seek:KinSeekEnv",
    "kin_envs/KinFollow-v2": "kin_envs.envs.kin_follow:KinFollowEnv",
    "kin_envs/KinSeek-v1": "kin_envs.envs.kin_seek:KinSeekEnvV1",
    "kin_envs/KinFollow-v1": "kin_envs.envs.kin_follow:KinFollowEnvV1",
    "kin_envs/KinSeek-v0": "kin_envs.envs.kin_seek:KinSeekEnvV0",
    "kin_envs/KinFollow-v0": "kin_envs.envs.kin_follow:KinFollowEnvV0",
}
#: ids with a native vector env (``gymnasium.make_vec``)
VECTOR_ENTRY_POINTS = {
    "kin_envs/KinSeek-v2": "kin_envs.envs.vector:KinSeekVectorEnv",
    "kin_envs/KinFollow-v2": "kin_envs.envs.vector:KinFollowVectorEnv",
    "kin_envs/KinSeek-v1": "kin_envs.envs.vector:KinSeekVectorEnvV1",
    "kin_envs/KinFollow-v1": "kin_envs.envs.vector:KinFollowVectorEnvV1",
}


def register_envs() -> None:
    """Register the Gymnasium ids (idempotent)."""
    import gymnasium

    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id, entry_point=entry_point,
                vector_entry_point=VECTOR_ENTRY_POINTS.get(env_id),
            )
