"""Numba's on-disk cache: on a read-only install, and invalidated when a kernel it compiled in changes.

``@numba.njit(cache=True)`` needs somewhere to write: the package's ``__pycache__`` or the user's cache
directory under ``HOME``. With both unwritable (a system-wide install, a container with a read-only
home) numba refuses to decorate the function at import time ("no locator available"). Before any
cached function is defined, :func:`ensure_cache_dir` points numba at a writable temporary directory
in that case (unless the user set ``NUMBA_CACHE_DIR``); if there is none, compiled code is simply not
cached. Simulator-free, so both ``detectors`` and ``kin_envs`` call it.

Numba keys a cached function on its *own* source file only: a function that compiles in a kernel
from another file (the learned detector's fused driver calls :mod:`detectors.features`' and
:mod:`detectors._kernels`' kernels) kept running the old kernel from its cache after that file
changed, with the old speed or, worse, the old arithmetic (seen here: the driver ~10 % slower than
its own stages until the cache files were deleted). :func:`guard_dependencies` makes the cache stamp
of every cached function under a package directory include a digest of all the jitted source files
it may compile in, so any change to any of them recompiles (about as long as a fresh install's first
run) instead of silently reusing stale machine code.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

import numba

_log = logging.getLogger(__name__)


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


def _jit_sources_digest(dirs: tuple[str, ...]) -> bytes:
    """SHA-256 over the ``.py`` files under ``dirs`` that define jitted functions (path and content)."""
    h = hashlib.sha256()
    for d in dirs:
        for f in sorted(Path(d).rglob("*.py")):
            data = f.read_bytes()
            if b"numba" in data:  # only files that can hold kernels: edits elsewhere keep the cache
                h.update(str(f.relative_to(d)).encode() + b"\0" + data)
    return h.digest()


class _DependencyStamped:
    """Numba's own locator for a function, with the source stamp extended by the digest of the
    jitted sources it may compile in (everything else delegated)."""

    def __init__(self, inner, digest: bytes) -> None:
        self._inner = inner
        self._digest = digest

    def get_source_stamp(self):
        return (self._inner.get_source_stamp(), self._digest)

    def __getattr__(self, name):
        return getattr(self._inner, name)


#: package directory -> the directories whose jitted sources its cached functions may compile in
_GUARDED: dict[str, tuple[str, ...]] = {}
_DIGESTS: dict[tuple[str, ...], bytes] = {}


class _DependencyLocator:
    """A numba cache locator that applies only to functions under a :func:`guard_dependencies`
    directory; other functions fall through to numba's locators unchanged."""

    _numba_locators: list = []

    @classmethod
    def from_function(cls, py_func, py_file):
        path = os.path.abspath(py_file)
        deps = next((v for k, v in _GUARDED.items() if path.startswith(k + os.sep)), None)
        if deps is None:
            return None
        for loc in cls._numba_locators:
            inner = loc.from_function(py_func, py_file)
            if inner is not None:
                if deps not in _DIGESTS:  # once per process: files are not edited under a running program
                    _DIGESTS[deps] = _jit_sources_digest(deps)
                return _DependencyStamped(inner, _DIGESTS[deps])
        return None


def guard_dependencies(package_dir, also=()) -> bool:
    """Key the on-disk cache of every ``cache=True`` function under ``package_dir`` on the jitted
    sources of ``package_dir`` and the directories ``also`` (see the module docstring). Call it before
    the package's first ``@njit(cache=True)``. Returns False (caching as numba does it) when this numba
    keeps its locators elsewhere."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    locators = getattr(impl, "_locator_classes", None)
    if not isinstance(locators, list):
        _log.debug("numba %s: no locator list; cache stamps left to numba", numba.__version__)
        return False
    root = os.path.abspath(package_dir)
    _GUARDED[root] = tuple(sorted({root, *(os.path.abspath(a) for a in also)}))
    if _DependencyLocator not in locators:
        _DependencyLocator._numba_locators = list(locators)
        locators.insert(0, _DependencyLocator)
    return True


ensure_cache_dir(Path(__file__).resolve().parent)  # the detectors package itself
guard_dependencies(Path(__file__).resolve().parent)
