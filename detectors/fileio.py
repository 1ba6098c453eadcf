"""Atomic file output: nothing half-written is ever left under a final name.

Every file the project writes (checkpoints, dataset shards, manifests, tables, figures, run records) goes
through :func:`atomic_write`: the data goes to a temporary file in the same directory, is flushed to disk,
then renamed over the final name (``os.replace`` is atomic on POSIX and Windows). An exception or Ctrl-C
inside the block removes the temporary file and leaves any previous file untouched. Simulator-free, so
both ``detectors`` (checkpoints) and ``kin_envs`` / the scripts use it.

A log that grows during a run (a training log read with ``tail -f``) cannot be written in one go:
:class:`LiveLog` flushes every line as it is written, and on closing - after success, an exception or
Ctrl-C - atomically replaces the file with every whole line written, so that no torn last line is left.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["LiveLog", "atomic_write", "write_json", "write_text", "sha256_file"]


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing; rename it to ``path`` when the block succeeds.

    ``mode`` is ``"wb"`` (bytes) or ``"w"`` (UTF-8 text). The parent directory must exist.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_write: mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path.parent}: output directory does not exist")
    # The name is chosen before the file exists, so a Ctrl-C at any moment after its creation (even
    # inside the open call) is covered by the cleanup below; mkstemp would leave that window open.
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the usual mode (umask applies)
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if mode == "w" else {})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    """Remove a temporary file, even if a second Ctrl-C lands during the removal."""
    while True:
        try:
            os.unlink(tmp)
            return
        except FileNotFoundError:
            return
        except KeyboardInterrupt:
            continue


class LiveLog:
    """A text log written line by line under its final name, made whole when it is closed.

    ``write(s)`` (callers write whole lines, e.g. ``csv.writer`` rows or JSON lines) writes and flushes at
    once, so the file can be followed while the run goes. ``close()`` (also on leaving a ``with`` block by
    an exception or ``KeyboardInterrupt``) rewrites the file atomically from memory with the whole lines
    written, so an interrupted write leaves no torn last line. Logs are small (one line per epoch or
    iteration), so keeping them in memory costs nothing. Newlines are written as given (``newline=""``).
    """

    def __init__(self, path) -> None:
        self.path = Path(path)
        self._parts: list[str] = []
        self._f = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115  (closed in close())

    def write(self, s: str) -> int:
        if not isinstance(s, str):
            raise TypeError(f"LiveLog.write: expected str, got {type(s).__name__}")
        self._parts.append(s)
        self._f.write(s)
        self._f.flush()
        return len(s)

    def close(self) -> None:
        if self._f.closed:
            return
        self._f.close()
        text = "".join(self._parts)
        with atomic_write(self.path, "wb") as f:
            f.write(text[: text.rfind("\n") + 1].encode("utf-8"))  # whole lines only

    def __enter__(self) -> LiveLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_json(path, obj, **dump_kwargs) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    dump_kwargs.setdefault("indent", 2)
    with atomic_write(path, "w") as f:
        json.dump(obj, f, **dump_kwargs)
        f.write("\n")


def write_text(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_write(path, "w") as f:
        f.write(text)


def sha256_file(path, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()
