"""Controllers for the kin envs, all behind one interface (:class:`agents.base.Policy`).

* :class:`RandomPolicy`: uniformly random actions;
* :class:`Wanderer`: obstacle-avoiding random walk from the scan;
* :class:`KinSeeker` (alias ``ScriptedKinSeeker``): steer to the detected kin, else wander;
* :class:`Aggregator`: swarm controller, drive to the nearest detected robot, else wander;
* :class:`agents.sb3.SB3Policy`: a trained Stable-Baselines3 model (import ``agents.sb3``; it
  loads SB3/torch lazily, so ``import agents`` stays torch-free).

Helpers: :func:`run_episode` (Gymnasium), :class:`PolicyGroup` and :func:`run_parallel_episode`
(PettingZoo parallel), :data:`agents.hyperparams.HYPERPARAMS` (shipped training settings).

Logs through the ``agents`` logger. ``import kin_envs`` (which every module here does) checks that this
package is kin-envs' own: an unrelated distribution named ``agents`` exists (kin_envs._toplevel).
"""

import logging

__kin_envs_package__ = True
logging.getLogger(__name__).addHandler(logging.NullHandler())

import kin_envs as _kin_envs  # noqa: E402,F401  (runs the top-level package check first)
from agents.aggregator import Aggregator  # noqa: E402
from agents.base import (  # noqa: E402
    EpisodeStats,
    Policy,
    PolicyGroup,
    env_layout,
    make_rng,
    run_episode,
    run_parallel_episode,
    steer_to_action,
)
from agents.random_policy import RandomPolicy  # noqa: E402
from agents.seeker import KinSeeker  # noqa: E402
from agents.wander import Wanderer  # noqa: E402

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
