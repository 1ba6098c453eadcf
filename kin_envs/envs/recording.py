"""Record an episode of any kin env (Gymnasium or PettingZoo parallel) to a GIF or an MP4.

Gymnasium's own ``gymnasium.wrappers.RecordVideo`` works for the single-agent envs but needs moviepy;
the swarm (PettingZoo) has no such wrapper. :func:`record_episode` runs one seeded episode of either
kind with ``render_mode="rgb_array"`` and writes its frames with :class:`VideoWriter`:

* ``.gif``: Pillow (the ``viz`` extra); frames are kept in memory as palette images (1 byte per pixel:
  a 300-step episode at 256 px is ~20 MB); Pillow merges identical consecutive frames (their
  durations add up, so the timing is kept);
* ``.mp4``: H.264 through ``imageio-ffmpeg`` (the ``video`` extra, which ships an ffmpeg binary);
  frames are streamed to ffmpeg.

The file appears under its final name only when complete (written under a temporary name, then
renamed). Rendering needs pygame (the ``viz`` extra), as for ``render()``.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from detectors.fileio import atomic_write

__all__ = ["VideoWriter", "record_episode"]

log = logging.getLogger(__name__)
FORMATS = (".gif", ".mp4")


class VideoWriter:
    """Write ``H x W x 3`` uint8 frames to ``path`` (``.gif`` or ``.mp4``) at ``fps`` frames per second.

    Use as a context manager (or call :meth:`close`); on an exception inside the block nothing is
    written under ``path``.
    """

    def __init__(self, path, fps: float = 10) -> None:
        self.path = Path(path)
        self.suffix = self.path.suffix.lower()
        if self.suffix not in FORMATS:
            raise ValueError(f"VideoWriter: {self.path}: expected a {' or '.join(FORMATS)} file name")
        if not (isinstance(fps, int | float) and np.isfinite(fps) and fps > 0):
            raise ValueError(f"VideoWriter: fps must be a number > 0, got {fps!r}")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"{self.path.parent}: output directory does not exist")
        self.fps = float(fps)
        self.frames = 0
        self._shape: tuple[int, ...] | None = None
        self._images: list = []
        self._ffmpeg = None
        self._tmp: Path | None = None
        if self.suffix == ".gif":
            try:
                from PIL import Image
            except ImportError as e:
                raise ImportError("writing a GIF needs Pillow: pip install kin-envs[viz]") from e
            self._image = Image
        else:
            try:
                import imageio_ffmpeg
            except ImportError as e:
                raise ImportError("writing an MP4 needs imageio-ffmpeg: pip install kin-envs[video] (or "
                                  "write a .gif)") from e
            self._imageio_ffmpeg = imageio_ffmpeg

    def append(self, frame) -> None:
        """Add one frame (``H x W x 3`` uint8, the same size as the first)."""
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"VideoWriter: expected an H x W x 3 uint8 frame, got {frame.dtype} "
                             f"{frame.shape}")
        if self._shape is None:
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"VideoWriter: frame {self.frames} has shape {frame.shape}, the first "
                             f"{self._shape}")
        if self.suffix == ".gif":
            img = self._image.fromarray(frame)
            self._images.append(img.convert("P", palette=self._image.Palette.ADAPTIVE, colors=256))
        else:
            if self._ffmpeg is None:
                self._start_ffmpeg(frame.shape)
            self._ffmpeg.send(np.ascontiguousarray(frame))
        self.frames += 1

    def _start_ffmpeg(self, shape) -> None:
        h, w = shape[:2]
        self._tmp = self.path.with_name(f".{self.path.stem}.{os.getpid()}.tmp.mp4")
        # macro_block_size=2: H.264 with yuv420p needs even sizes; ffmpeg pads odd ones by a pixel
        self._ffmpeg = self._imageio_ffmpeg.write_frames(
            str(self._tmp), (w, h), fps=self.fps, codec="libx264", pix_fmt_out="yuv420p", macro_block_size=2,
        )  # fmt: skip
        self._ffmpeg.send(None)  # starts ffmpeg

    def close(self) -> Path:
        """Finish the file; returns its path. Raises ``ValueError`` when no frame was added."""
        if self.frames == 0:
            self.abort()
            raise ValueError(f"VideoWriter: no frames to write to {self.path}")
        if self.suffix == ".gif":
            first, *rest = self._images
            with atomic_write(self.path, "wb") as f:
                first.save(f, format="GIF", save_all=True, append_images=rest,
                           duration=round(1000 / self.fps), loop=0)
            self._images = []
        else:
            self._ffmpeg.close()  # waits for ffmpeg to finish the file
            self._ffmpeg = None
            os.replace(self._tmp, self.path)
        log.info("wrote %s (%d frames, %g fps)", self.path, self.frames, self.fps)
        return self.path

    def abort(self) -> None:
        """Discard everything; leaves no file behind."""
        self._images = []
        if self._ffmpeg is not None:
            with contextlib.suppress(Exception):
                self._ffmpeg.close()
            self._ffmpeg = None
        if self._tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self._tmp)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _is_parallel(env) -> bool:
    return hasattr(env, "possible_agents") and not hasattr(env, "agent_selection")


def record_episode(env, path, policy: Any = None, seed: int | None = None, max_steps: int | None = None,
                   fps: float | None = None) -> dict[str, Any]:
    """Run one episode of ``env`` and write its rendered frames to ``path`` (``.gif`` or ``.mp4``).

    Args:
        env: a Gymnasium env or a PettingZoo **parallel** env, made with ``render_mode="rgb_array"``.
        path: the output file; its suffix picks the format.
        policy: an object with ``act(obs, info)`` (and optionally ``reset(seed)``) such as the
            controllers of ``agents`` (a ``PolicyGroup`` for the swarm), or a callable
            ``policy(obs, info)``; it returns an action (Gymnasium) or a dict of actions per agent
            (PettingZoo). Default: uniformly random actions from the action spaces, seeded by ``seed``.
        seed: the reset seed (same seed, same episode, same file).
        max_steps: stop after this many steps (default: when the episode ends).
        fps: frames per second of the file (default: the env's ``metadata["render_fps"]``, else 10).

    Returns ``{"path", "frames", "steps", "return"}``: one frame after the reset and one per step;
    ``return`` is the episode return (summed over agents for the swarm).
    """
    if getattr(env, "render_mode", None) != "rgb_array":
        raise ValueError(f"record_episode: make the env with render_mode='rgb_array', got "
                         f"{getattr(env, 'render_mode', None)!r}")
    bad_steps = isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1
    if max_steps is not None and bad_steps:
        raise ValueError(f"record_episode: max_steps must be an int >= 1 or None, got {max_steps!r}")
    fps = fps if fps is not None else getattr(env, "metadata", {}).get("render_fps", 10)
    parallel = _is_parallel(env)
    act: Callable | None
    if policy is None:
        act = None
    elif hasattr(policy, "act"):
        if hasattr(policy, "reset"):
            policy.reset(seed)
        act = policy.act
    elif callable(policy):
        act = policy
    else:
        raise TypeError(f"record_episode: policy must have act(obs, info) or be callable, got "
                        f"{type(policy).__name__}")
    rng_seed = 0 if seed is None else seed
    obs, info = env.reset(seed=seed)
    if act is None:  # seeded random actions, independent of the env's own RNG
        if parallel:
            for k, agent in enumerate(env.possible_agents):
                env.action_space(agent).seed(rng_seed + k)
        else:
            env.action_space.seed(rng_seed)
    steps, total = 0, 0.0
    with VideoWriter(path, fps) as writer:
        writer.append(env.render())
        while max_steps is None or steps < max_steps:
            if parallel:
                if not env.agents:
                    break
                actions = (act(obs, info) if act is not None
                           else {a: env.action_space(a).sample() for a in env.agents})
                obs, rewards, terms, truncs, info = env.step(actions)
                total += float(sum(rewards.values()))
                done = not env.agents
            else:
                action = act(obs, info) if act is not None else env.action_space.sample()
                obs, reward, term, trunc, info = env.step(action)
                total += float(reward)
                done = term or trunc
            steps += 1
            writer.append(env.render())
            if done:
                break
    return {"path": writer.path, "frames": writer.frames, "steps": steps, "return": total}
