"""PettingZoo swarm aggregation env, version 2 (the latest), importable the PettingZoo way::

    from kin_envs import aggregation_v2
    par = aggregation_v2.parallel_env(n_robots=16)   # ParallelEnv
    aec = aggregation_v2.env(n_robots=16)            # AECEnv (parallel_to_aec)

See :class:`kin_envs.envs.aggregation.AggregationEnv` for the specification and its Version History
(:mod:`kin_envs.aggregation_v1` and ``aggregation_v0`` stay available to reproduce earlier results).
"""

from kin_envs.envs.aggregation import AggregationConfig, AggregationEnv, env, parallel_env, raw_env

__all__ = ["AggregationConfig", "AggregationEnv", "env", "parallel_env", "raw_env"]
