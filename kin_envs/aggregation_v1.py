"""PettingZoo swarm aggregation env, version 1, importable the PettingZoo way::

    from kin_envs import aggregation_v1
    par = aggregation_v1.parallel_env(n_robots=16)   # ParallelEnv
    aec = aggregation_v1.env(n_robots=16)            # AECEnv (parallel_to_aec)

v1 is v2 except that ``tracker=True`` feeds the tracker the detector's accepted detections; kept to
reproduce earlier results: new code should use :mod:`kin_envs.aggregation_v2`. See
:class:`kin_envs.envs.aggregation.AggregationEnv` for the specification and its Version History.
"""

from kin_envs.envs.aggregation import AggregationConfigV1 as AggregationConfig
from kin_envs.envs.aggregation import AggregationEnvV1 as AggregationEnv
from kin_envs.envs.aggregation import env_v1 as env
from kin_envs.envs.aggregation import parallel_env_v1 as parallel_env
from kin_envs.envs.aggregation import raw_env_v1 as raw_env

__all__ = ["AggregationConfig", "AggregationEnv", "env", "parallel_env", "raw_env"]
