"""Stable-Baselines3 adapter: a trained model as an :class:`agents.Policy`, for either API.

SB3, SuperSuit and torch are imported lazily, inside the functions that need them, so
``import agents`` stays torch-free.

Example::

    policy = SB3Policy.load("runs/seek/model.zip")            # PPO or SAC, read from the zip
    env = gymnasium.make("kin_envs/KinSeek-v2", obs_detections="topk")
    policy.check_env(env)                                     # ValueError if the spaces differ
    obs, info = env.reset(seed=0); action = policy.act(obs, info)

    par = aggregation_v2.parallel_env(n_robots=8, obs_detections="topk")
    group = PolicyGroup.shared(policy.check_env(par), par.possible_agents)  # one batched call per step
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from agents.base import Policy, SeedLike

__all__ = [
    "ALGOS",
    "SB3Policy",
    "resolve_policy_kwargs",
    "SeededSB3VecEnv",
    "algo_class",
    "atomic_checkpoints",
    "atomic_save_callback",
    "detect_algo",
    "shared_vec_env",
]

ALGOS = ("ppo", "sac")


def algo_class(name: str):
    """``"ppo"`` / ``"sac"`` → the SB3 class (imports SB3)."""
    if name not in ALGOS:
        raise ValueError(f"unknown algorithm {name!r}; expected one of {ALGOS}")
    import stable_baselines3

    return {"ppo": stable_baselines3.PPO, "sac": stable_baselines3.SAC}[name]


def detect_algo(path: str | Path) -> str:
    """Which algorithm saved ``path``: ``run.json`` next to it if it names one, else the policy class
    recorded in the zip (SAC's policies live in ``stable_baselines3.sac``)."""
    path = Path(path)
    run = path.parent / "run.json"
    if run.is_file():
        algo = json.loads(run.read_text()).get("algo")
        if algo in ALGOS:
            return algo
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a Stable-Baselines3 model zip ({e})") from e
    module = str((data.get("policy_class") or {}).get("__module__", ""))
    return "sac" if module.startswith("stable_baselines3.sac") else "ppo"


class SB3Policy(Policy):
    """A trained SB3 model as a memoryless policy (frame stacking happens inside the env).

    Args:
        model: an SB3 algorithm instance (``PPO``, ``SAC``, ...).
        deterministic: act with the mode of the action distribution (evaluation) or sample.
    """

    name: ClassVar[str] = "trained"
    shareable: ClassVar[bool] = True

    def __init__(self, model: Any, deterministic: bool = True) -> None:
        if not hasattr(model, "predict") or not hasattr(model, "observation_space"):
            raise ValueError(f"SB3Policy: model must be a Stable-Baselines3 model, got {model!r}")
        self.model = model
        self.deterministic = bool(deterministic)
        self.reset(None)

    @classmethod
    def load(cls, path: str | Path, algo: str | None = None, deterministic: bool = True) -> SB3Policy:
        """Load a saved model (``algo`` ``"ppo"``/``"sac"``; ``None`` = :func:`detect_algo`)."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"SB3Policy.load: no model file at {path}")
        model = algo_class(algo or detect_algo(path)).load(path, device="cpu")
        return cls(model, deterministic=deterministic)

    def check_env(self, env: Any) -> SB3Policy:
        """Raise ``ValueError`` unless the model's spaces match ``env``'s (Gymnasium or PettingZoo);
        returns ``self``."""
        obs_space, act_space = env.observation_space, env.action_space
        if callable(obs_space):  # PettingZoo: per-agent spaces (all alike in the kin envs)
            agent = env.possible_agents[0]
            obs_space, act_space = obs_space(agent), act_space(agent)
        m_obs, m_act = self.model.observation_space, self.model.action_space
        if m_obs.shape != obs_space.shape:
            raise ValueError(
                f"SB3Policy: the model expects observations of shape {m_obs.shape}, the env gives "
                f"{obs_space.shape}; make the env with the kwargs the model was trained with "
                "(its run.json: env_kwargs, e.g. obs_detections / frame_stack / detector)"
            )
        same_kind = type(m_act) is type(act_space) and (
            m_act.shape == act_space.shape if isinstance(act_space, spaces.Box) else m_act.n == act_space.n
        )
        if not same_kind:
            raise ValueError(
                f"SB3Policy: the model acts in {m_act}, the env expects {act_space}; make the env with "
                "the action_type the model was trained with"
            )
        return self

    def reset(self, seed: SeedLike = None) -> None:
        # the model samples with torch's RNG when deterministic=False; seed it for reproducibility
        if seed is not None and not self.deterministic and not isinstance(seed, np.random.Generator):
            import torch

            torch.manual_seed(int(seed))

    def _predict(self, obs: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(obs, deterministic=self.deterministic)
        return action

    def act(self, obs, info):
        return self._convert(self._predict(np.asarray(obs, dtype=np.float32)))

    def act_many(self, obs, infos) -> list:
        actions = self._predict(np.stack([np.asarray(o, dtype=np.float32) for o in obs]))
        return [self._convert(a) for a in actions]

    def _convert(self, a: np.ndarray):
        if isinstance(self.model.action_space, spaces.Discrete):
            return int(np.asarray(a).reshape(()))
        return np.asarray(a, dtype=np.float32)


# --- PettingZoo swarm -> SB3 vec env (SuperSuit), with working seeds -------------------------------


def _seeded_wrapper_class():
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

    class _Seeded(SB3VecEnvWrapper):
        """SuperSuit's SB3 wrapper has no ``seed()``: SB3 (``PPO(seed=...)``, ``set_random_seed``)
        calls ``env.seed(seed)`` and expects the seed to apply at the next ``reset()``. Keep it and
        pass it to the concatenated PettingZoo envs (copy ``i`` gets ``seed + i``)."""

        def __init__(self, venv) -> None:
            super().__init__(venv)
            self._pending_seed: int | None = None

        def seed(self, seed: int | None = None) -> list[int | None]:
            self._pending_seed = None if seed is None else int(seed)
            return [seed] * self.num_envs

        def get_attr(self, attr_name: str, indices=None) -> list:
            if attr_name == "render_mode":
                # SuperSuit's vec envs have none: every SB3 wrapper on top (VecMonitor in train_swarm.py)
                # warned "The `render_mode` attribute is not defined" and took None, as here
                n = 1 if isinstance(indices, int) else len(list(indices)) if indices is not None else None
                return [None] * (self.num_envs if n is None else n)
            return super().get_attr(attr_name, indices)

        def reset(self, seed: int | None = None, options: dict | None = None):
            if seed is not None:
                self._pending_seed = int(seed)
            seed, self._pending_seed = self._pending_seed, None
            observations, self.reset_infos = self.venv.reset(seed=seed, options=options)
            return observations

    return _Seeded


def SeededSB3VecEnv(venv):  # noqa: N802 (a class built lazily: SuperSuit imports SB3)
    """Wrap SuperSuit's concatenated vec env (``concat_vec_envs_v1(..., base_class="gymnasium")``)
    for SB3 with a working ``seed()``."""
    return _seeded_wrapper_class()(venv)


def shared_vec_env(parallel_env: Any, n_copies: int = 1, seed: int | None = None):
    """A PettingZoo parallel env → SB3 ``VecEnv`` with one sub-env per agent per copy (a shared
    policy), via SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1``.

    ``seed`` (if given) applies at the first ``reset()``; SB3's ``seed()`` works too.
    """
    if not (isinstance(n_copies, int) and n_copies >= 1):
        raise ValueError(f"shared_vec_env: n_copies must be an integer >= 1, got {n_copies!r}")
    import supersuit

    vec = supersuit.pettingzoo_env_to_vec_env_v1(parallel_env)
    # base_class="gymnasium", then our SB3 wrapper: identical to base_class="stable_baselines3"
    # except for seed()
    venv = SeededSB3VecEnv(supersuit.concat_vec_envs_v1(vec, n_copies, num_cpus=0, base_class="gymnasium"))
    if seed is not None:
        venv.seed(seed)
    return venv


# --- a 1-D convolutional feature extractor over the scan ----------------------------------------


def atomic_checkpoints(save_freq: int, save_path, name_prefix: str = "model"):
    """SB3's ``CheckpointCallback`` (``{name_prefix}_{steps}_steps.zip`` every ``save_freq`` calls) with
    each checkpoint written through :func:`detectors.fileio.atomic_write`: a Ctrl-C or a crash while
    saving leaves no half-written zip under a checkpoint's name (SB3 writes straight to it)."""
    from stable_baselines3.common.callbacks import CheckpointCallback

    from detectors.fileio import atomic_write

    class AtomicCheckpointCallback(CheckpointCallback):
        def _on_step(self) -> bool:
            if self.n_calls % self.save_freq == 0:
                with atomic_write(self._checkpoint_path(extension="zip")) as f:
                    self.model.save(f)
            return True

    return AtomicCheckpointCallback(save_freq=save_freq, save_path=str(save_path), name_prefix=name_prefix)


def atomic_save_callback(path):
    """A callback that saves the model to ``path`` atomically each time it is called: for
    ``EvalCallback(callback_on_new_best=...)`` instead of its ``best_model_save_path`` (a plain save)."""
    from stable_baselines3.common.callbacks import BaseCallback

    from detectors.fileio import atomic_write

    path = Path(path)

    class AtomicSave(BaseCallback):
        def _on_step(self) -> bool:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(path) as f:
                self.model.save(f)
            return True

    return AtomicSave()


def resolve_policy_kwargs(policy_kwargs: dict | None) -> dict | None:
    """``features_extractor_class`` given as ``"module:Name"`` (JSON-friendly) → the class."""
    if not policy_kwargs or not isinstance(policy_kwargs.get("features_extractor_class"), str):
        return policy_kwargs
    import importlib

    spec = policy_kwargs["features_extractor_class"]
    module, sep, name = spec.partition(":")
    try:
        cls = getattr(importlib.import_module(module), name) if sep else None
    except (ImportError, AttributeError):
        cls = None
    if cls is None:
        raise ValueError(f"features_extractor_class must be 'module:Class' naming an importable class, "
                         f"got {spec!r} (e.g. 'agents.sb3:ScanConvExtractor')")
    return {**policy_kwargs, "features_extractor_class": cls}


def _make_scan_conv_extractor():
    import torch
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from torch import nn

    class ScanConvExtractor(BaseFeaturesExtractor):
        """Circular 1-D convolutions over the scan (frames as channels), the rest of each frame
        (the detector channel, if any) through a small linear layer, concatenated.

        A kin's housing is a small bump a few beams wide anywhere in the 360° scan: convolutions
        share one bump detector over all bearings, which an MLP on raw beams must learn per beam.
        Circular padding because beam 359 neighbours beam 0.

        Args:
            n_beams: beams per frame (360); ``frame_stack``: frames in an observation.
            features_dim: output size.
        """

        def __init__(self, observation_space, n_beams: int = 360, frame_stack: int = 1,
                     features_dim: int = 256) -> None:
            super().__init__(observation_space, features_dim)
            dim = int(np.prod(observation_space.shape))
            if dim % frame_stack or dim // frame_stack < n_beams:
                raise ValueError(f"ScanConvExtractor: observation size {dim} is not "
                                 f"frame_stack={frame_stack} frames of >= n_beams={n_beams} values")
            self.n_beams, self.frame_stack = n_beams, frame_stack
            self.extra = dim // frame_stack - n_beams
            c = frame_stack
            self.conv = nn.Sequential(
                nn.Conv1d(c, 16, 7, padding=3, padding_mode="circular"), nn.ReLU(),
                nn.Conv1d(16, 32, 5, stride=2, padding=2, padding_mode="circular"), nn.ReLU(),
                nn.Conv1d(32, 32, 5, stride=2, padding=2, padding_mode="circular"), nn.ReLU(),
                nn.MaxPool1d(2),  # 360 -> 45 positions: about 8 degrees each, keeps the bearing
                nn.Flatten(),
            )
            with torch.no_grad():
                n_conv = self.conv(torch.zeros(1, c, n_beams)).shape[1]
            n_extra = self.extra * frame_stack
            self.head = nn.Sequential(nn.Linear(n_conv + (64 if n_extra else 0), features_dim), nn.ReLU())
            self.extra_net = nn.Sequential(nn.Linear(n_extra, 64), nn.ReLU()) if n_extra else None

        def forward(self, obs):
            frames = obs.reshape(obs.shape[0], self.frame_stack, self.n_beams + self.extra)
            # near obstacles matter most: 1 - range/12 puts them at the large values
            feats = [self.conv(1.0 - frames[:, :, : self.n_beams])]
            if self.extra_net is not None:
                feats.append(self.extra_net(frames[:, :, self.n_beams :].reshape(obs.shape[0], -1)))
            return self.head(torch.cat(feats, dim=1))

    ScanConvExtractor.__module__ = __name__
    ScanConvExtractor.__qualname__ = "ScanConvExtractor"
    return ScanConvExtractor


def __getattr__(name: str):
    # Built on first access so that ``import agents.sb3`` stays torch-free, yet pickled models can
    # name the class as ``agents.sb3.ScanConvExtractor`` (unpickling imports it from here).
    if name == "ScanConvExtractor":
        cls = _make_scan_conv_extractor()
        globals()[name] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
