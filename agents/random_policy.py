"""Uniformly random actions: the floor every other policy must beat."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from agents.base import Policy, SeedLike

__all__ = ["RandomPolicy"]


class RandomPolicy(Policy):
    """Samples the action space with its own seeded RNG (never the space's or global state).

    Args:
        action_space: ``Box`` (uniform in its bounds) or ``Discrete``.
        seed: seed of the policy's RNG (``reset(seed)`` reseeds it).
    """

    name: ClassVar[str] = "random"
    shareable: ClassVar[bool] = True  # no memory: one instance may serve a whole swarm

    def __init__(self, action_space: spaces.Space, seed: SeedLike = None) -> None:
        if isinstance(action_space, spaces.Box):
            if not (np.isfinite(action_space.low).all() and np.isfinite(action_space.high).all()):
                raise ValueError(f"RandomPolicy: Box action space must be bounded, got {action_space}")
        elif not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"RandomPolicy: action space must be Box or Discrete, got {action_space}")
        self.action_space = action_space
        self.reset(seed)

    @classmethod
    def for_env(cls, env: Any, seed: SeedLike = None) -> RandomPolicy:
        """From a Gymnasium env or a PettingZoo env (the first agent's space: agents are alike)."""
        space = env.action_space
        if callable(space):
            space = space(env.possible_agents[0])
        return cls(space, seed=seed)

    def act(self, obs, info):
        s = self.action_space
        if isinstance(s, spaces.Discrete):
            return int(s.start + self.rng.integers(s.n))
        return self.rng.uniform(s.low, s.high).astype(s.dtype)
