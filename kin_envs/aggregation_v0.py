"""PettingZoo swarm aggregation env, version 0 (variable-length info), importable the PettingZoo way::

    from kin_envs import aggregation_v0
    par = aggregation_v0.parallel_env(n_robots=16)   # ParallelEnv
    aec = aggregation_v0.env(n_robots=16)            # AECEnv (parallel_to_aec)

Kept to reproduce earlier results; new code should use :mod:`kin_envs.aggregation_v2` (fixed-shape
info). See :class:`kin_envs.envs.aggregation.AggregationEnv` for the specification.
"""

from kin_envs.envs.aggregation import AggregationConfig
from kin_envs.envs.aggregation import AggregationEnvV0 as AggregationEnv
from kin_envs.envs.aggregation import env_v0 as env
from kin_envs.envs.aggregation import parallel_env_v0 as parallel_env
from kin_envs.envs.aggregation import raw_env_v0 as raw_env

__all__ = ["AggregationConfig", "AggregationEnv", "env", "parallel_env", "raw_env"]
