"""Controllers for the kin envs, all behind one interface (:class:`agents.base.Policy`).

* :class:`RandomPolicy`: uniformly random actions;
* :class:`Wanderer`: obstacle-avoiding random walk from the scan;
* :class:`KinSeeker` (alias ``ScriptedKinSeeker``): steer to the detected kin, else wander;
* :class:`Aggregator`: swarm controller, drive to the nearest detected robot, else wander;
* :class:`agents.sb3.SB3Policy`: a trained Stable-Baselines3 model (import ``agents.sb3``; it
  loads SB3/torch lazily, so ``import agents`` stays torch-free).

Helpers: :func:`run_episode` (Gymnasium), :class:`PolicyGroup` and :func:`run_parallel_episode`
(PettingZoo parallel), :data:`agents.hyperparams.HYPERPARAMS` (shipped training settings).
"""

from agents.aggregator import Aggregator
from agents.base import (
    EpisodeStats,
    Policy,
    PolicyGroup,
    env_layout,
    make_rng,
    run_episode,
    run_parallel_episode,
    steer_to_action,
)
from agents.random_policy import RandomPolicy
from agents.seeker import KinSeeker
from agents.wander import Wanderer

ScriptedKinSeeker = KinSeeker

__all__ = [
    "Aggregator",
    "EpisodeStats",
    "KinSeeker",
    "Policy",
    "PolicyGroup",
    "RandomPolicy",
    "ScriptedKinSeeker",
    "Wanderer",
    "env_layout",
    "make_rng",
    "run_episode",
    "run_parallel_episode",
    "steer_to_action",
]
