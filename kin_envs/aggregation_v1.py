"""PettingZoo swarm aggregation env, importable the PettingZoo way::

    from kin_envs import aggregation_v1
    par = aggregation_v1.parallel_env(n_robots=16)   # ParallelEnv
    aec = aggregation_v1.env(n_robots=16)            # AECEnv (parallel_to_aec)

See :class:`kin_envs.envs.aggregation.AggregationEnv` for the specification (v1: fixed-shape
info; :mod:`kin_envs.aggregation_v0` keeps the variable-length info of v0).
"""

from kin_envs.envs.aggregation import AggregationConfig, AggregationEnv, env, parallel_env, raw_env

__all__ = ["AggregationConfig", "AggregationEnv", "env", "parallel_env", "raw_env"]
