"""Numba's on-disk cache on a read-only install.

``@numba.njit(cache=True)`` needs somewhere to write: the package's ``__pycache__`` or the user's cache
directory under ``HOME``. With both unwritable (a system-wide install, a container with a read-only
home) numba refuses to decorate the function at import time ("no locator available"). Before any
cached function is defined, :func:`ensure_cache_dir` points numba at a writable temporary directory
in that case (unless the user set ``NUMBA_CACHE_DIR``); if there is none, compiled code is simply not
cached. Simulator-free, so both ``detectors`` and ``kin_envs`` call it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numba


def _writable_dir(d: Path) -> bool:
    """``d`` exists and is writable, or can be created."""
    while not d.exists():
        d = d.parent
    return os.access(d, os.W_OK | os.X_OK)


def ensure_cache_dir(package_dir) -> str | None:
    """Make ``cache=True`` work for modules in ``package_dir``; returns the cache directory chosen
    (``None`` when numba's own locators can write)."""
    if numba.config.CACHE_DIR:
        return None
    pycache = Path(package_dir) / "__pycache__"
    home_cache = Path(os.path.expanduser("~")) / ".cache"
    if _writable_dir(pycache) or _writable_dir(home_cache):
        return None
    d = Path(tempfile.gettempdir()) / f"kin-envs-numba-cache-{os.getuid() if hasattr(os, 'getuid') else 0}"
    try:
        d.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        d = Path(tempfile.mkdtemp(prefix="kin-envs-numba-cache-"))
    numba.config.CACHE_DIR = str(d)
    return str(d)


ensure_cache_dir(Path(__file__).resolve().parent)  # the detectors package itself
