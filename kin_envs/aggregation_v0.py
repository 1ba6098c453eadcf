"""PettingZoo swarm aggregation env, importable the PettingZoo way::

    from kin_envs import aggregation_v0
    par = aggregation_v0.parallel_env(n_robots=16)   # ParallelEnv
    aec = aggregation_v0.env(n_robots=16)            # AECEnv (parallel_to_aec)

See :class:`kin_envs.envs.aggregation.AggregationEnv` for the specification.
"""

from kin_envs.envs.aggregation import AggregationConfig, AggregationEnv, env, parallel_env, raw_env

__all__ = ["AggregationConfig", "AggregationEnv", "env", "parallel_env", "raw_env"]
