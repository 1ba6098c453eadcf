"""The policy interface shared by every controller, and helpers that run policies on the envs.

A :class:`Policy` acts on what an env gives it: ``act(obs, info) -> action``. ``reset(seed)``
starts an episode (clears memory, reseeds the policy's one RNG). Policies work with the
continuous and the discrete action types of every kin env.

For the PettingZoo swarm, :class:`PolicyGroup` maps each agent to a policy: one instance per agent
for policies with per-agent memory (:meth:`PolicyGroup.per_agent`), or one shared instance for
memoryless ones (:meth:`PolicyGroup.shared`, batched through :meth:`Policy.act_many`).

Example::

    env = gymnasium.make("kin_envs/KinSeek-v2")
    stats = run_episode(env, KinSeeker.for_env(env), seed=0)

    par = aggregation_v2.parallel_env(n_robots=8)
    group = PolicyGroup.per_agent(lambda: Aggregator.for_env(par), par.possible_agents)
    result = run_parallel_episode(par, group, seed=0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from kin_envs.envs.common import ACTION_TYPES, DISCRETE_ACTION_NAMES, ObservationLayout

__all__ = [
    "EpisodeStats",
    "Policy",
    "PolicyGroup",
    "SeedLike",
    "env_layout",
    "make_rng",
    "run_episode",
    "run_parallel_episode",
    "steer_to_action",
]

SeedLike = int | np.integer | np.random.Generator | None
_ACTION = {name: i for i, name in enumerate(DISCRETE_ACTION_NAMES)}


def make_rng(seed: SeedLike, who: str = "policy") -> np.random.Generator:
    """A policy's RNG from an int seed, ``None`` (fresh entropy) or an existing generator."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or (isinstance(seed, int | np.integer) and not isinstance(seed, bool) and seed >= 0):
        return np.random.default_rng(seed)
    raise ValueError(f"{who}: seed must be a non-negative int, a numpy Generator or None, got {seed!r}")


def check_action_type(action_type: Any, who: str) -> str:
    if action_type not in ACTION_TYPES:
        raise ValueError(f"{who}: action_type must be one of {ACTION_TYPES}, got {action_type!r}")
    return action_type


def env_layout(env: Any) -> tuple[ObservationLayout, str]:
    """``(observation layout, action type)`` of a kin env: Gymnasium (wrapped or not), PettingZoo
    parallel or AEC."""
    u = getattr(env, "unwrapped", env)
    layout, config = getattr(u, "layout", None), getattr(u, "config", None)
    if not isinstance(layout, ObservationLayout) or not hasattr(config, "action_type"):
        raise ValueError(
            f"expected a kin_envs env (with .unwrapped.layout and .unwrapped.config), got {env!r}"
        )
    return layout, config.action_type


def steer_to_action(v: float, w: float, action_type: str):
    """Normalised forward speed ``v`` and turn ``w`` (both in [-1, 1], ``w`` > 0 = left) → action.

    Continuous: wheel speeds ``(v - w, v + w)`` scaled down together if one exceeds 1 (the turning
    radius is kept). Discrete: turn in place when the turn is sharp, else forward or stop.
    """
    if action_type == "discrete":
        if abs(w) > 0.3 or (v == 0.0 and w != 0.0):
            return _ACTION["turn_left"] if w > 0 else _ACTION["turn_right"]
        return _ACTION["forward"] if v > 0.0 else _ACTION["stop"]
    wheels = np.array([v - w, v + w])
    peak = np.abs(wheels).max()
    return (wheels / peak if peak > 1.0 else wheels).astype(np.float32)


class Policy:
    """A controller: ``reset(seed)`` at the start of an episode, then ``act(obs, info)`` each step.

    Subclasses implement :meth:`act` and, if they keep memory or draw random numbers,
    :meth:`reset` (call ``super().reset(seed)`` to get ``self.rng``).

    ``shareable``: whether one instance may act for several agents at once (memoryless policies);
    :class:`PolicyGroup` refuses to share a policy that is not.
    """

    name: ClassVar[str] = "policy"
    shareable: ClassVar[bool] = False

    def reset(self, seed: SeedLike = None) -> None:
        self.rng = make_rng(seed, type(self).__name__)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]):
        raise NotImplementedError

    def __call__(self, obs: np.ndarray, info: Mapping[str, Any] | None = None):
        return self.act(obs, {} if info is None else info)

    def act_many(self, obs: Sequence[np.ndarray], infos: Sequence[Mapping[str, Any]]) -> list:
        """Actions for several agents sharing this policy (memoryless policies only)."""
        if not self.shareable:
            raise ValueError(f"{type(self).__name__} keeps per-agent memory: use one instance per agent")
        return [self.act(o, i) for o, i in zip(obs, infos, strict=True)]


class PolicyGroup:
    """Policies for the agents of a PettingZoo parallel env: ``act(observations, infos) -> actions``.

    Agents mapped to the same shareable instance are batched through :meth:`Policy.act_many`.
    """

    def __init__(self, policies: Mapping[str, Policy]) -> None:
        if not policies:
            raise ValueError("PolicyGroup: needs at least one agent -> policy entry")
        seen: dict[int, str] = {}
        for agent, p in policies.items():
            if not isinstance(p, Policy):
                raise ValueError(f"PolicyGroup: policy of {agent!r} must be an agents.Policy, got {p!r}")
            if id(p) in seen and not p.shareable:
                raise ValueError(
                    f"PolicyGroup: {type(p).__name__} keeps per-agent memory but is shared by "
                    f"{seen[id(p)]!r} and {agent!r}; use PolicyGroup.per_agent"
                )
            seen.setdefault(id(p), agent)
        self.policies = dict(policies)

    @classmethod
    def per_agent(cls, factory: Callable[[], Policy], agents: Sequence[str]) -> PolicyGroup:
        """One fresh instance per agent."""
        return cls({a: factory() for a in agents})

    @classmethod
    def shared(cls, policy: Policy, agents: Sequence[str]) -> PolicyGroup:
        """One memoryless instance for every agent (e.g. a trained shared policy)."""
        return cls(dict.fromkeys(agents, policy))

    def reset(self, seed: SeedLike = None) -> None:
        """Reseed every distinct policy from one seed (independent child streams, agent order)."""
        unique = list({id(p): p for p in self.policies.values()}.values())
        root = make_rng(seed, "PolicyGroup")
        for p, child in zip(unique, root.spawn(len(unique)), strict=True):
            p.reset(child)

    def act(self, observations: Mapping[str, np.ndarray], infos: Mapping[str, Mapping]) -> dict:
        missing = [a for a in observations if a not in self.policies]
        if missing:
            raise ValueError(f"PolicyGroup: no policy for agent(s) {missing[:5]}")
        groups: dict[int, list[str]] = {}
        for a in observations:
            groups.setdefault(id(self.policies[a]), []).append(a)
        actions = {}
        for agents in groups.values():
            p = self.policies[agents[0]]
            if len(agents) == 1:
                actions[agents[0]] = p.act(observations[agents[0]], infos.get(agents[0], {}))
            else:
                out = p.act_many([observations[a] for a in agents], [infos.get(a, {}) for a in agents])
                actions.update(zip(agents, out, strict=True))
        return {a: actions[a] for a in observations}  # env's agent order


@dataclass
class EpisodeStats:
    """One Gymnasium episode: return, length, success, collision steps, steps to success."""

    episode_return: float
    length: int
    success: bool
    collisions: int
    time_to_success: int | None
    final_info: dict = field(repr=False, default_factory=dict)


def run_episode(env, policy: Policy, seed: int, max_steps: int | None = None) -> EpisodeStats:
    """Run one seeded episode of a Gymnasium env (policy reset with the same seed)."""
    obs, info = env.reset(seed=seed)
    policy.reset(seed)
    total, n, collisions, success = 0.0, 0, 0, False
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, info))
        total += float(reward)
        n += 1
        collisions += bool(info.get("collision", False))
        success = success or bool(info.get("is_success", False))
        if terminated or truncated or (max_steps is not None and n >= max_steps):
            break
    return EpisodeStats(total, n, success, collisions, n if success else None, info)


def run_parallel_episode(
    env,
    group: PolicyGroup,
    seed: int,
    on_step: Callable[[Any, int], None] | None = None,
    max_cycles: int | None = None,
) -> dict[str, Any]:
    """Run one seeded episode of a PettingZoo parallel env.

    ``on_step(env, cycle)`` is called after every step (e.g. to record ``env.state()``).
    Returns ``{"returns": {agent: return}, "length": cycles, "collisions": {agent: steps}}``.
    """
    observations, infos = env.reset(seed=seed)
    group.reset(seed)
    returns = dict.fromkeys(observations, 0.0)
    collisions = dict.fromkeys(observations, 0)
    n = 0
    while env.agents:
        observations, rewards, terms, truncs, infos = env.step(group.act(observations, infos))
        n += 1
        for a, r in rewards.items():
            returns[a] += float(r)
            rt = infos.get(a, {}).get("reward_terms", {})
            collisions[a] += bool(rt.get("collision", 0.0))
        if on_step is not None:
            on_step(env, n)
        if max_cycles is not None and n >= max_cycles:
            break
        done = {a for a in observations if terms.get(a) or truncs.get(a)}
        observations = {a: o for a, o in observations.items() if a not in done}
        if not observations:
            break
    return {"returns": returns, "length": n, "collisions": collisions}


def front_min(ranges: np.ndarray, angles: np.ndarray, half_width: float = math.radians(35.0)) -> float:
    """Nearest reading within ``±half_width`` of the heading, m."""
    return float(ranges[np.abs(angles) < half_width].min())
