"""Small helpers shared by the command-line scripts (no heavy imports: stdlib and numpy only).

* :func:`parse_json_object`: a CLI value holding a JSON object inline or in a file;
* :func:`add_logging_args` / :func:`setup_logging`: the ``--verbose`` / ``--quiet`` flags of every script;
* :func:`progress`: a tqdm bar when tqdm is installed (the ``train`` / ``distributed`` extras), else the
  plain iterable, so that the scripts run on the core install;
* :func:`write_run_info`: the ``run.json`` every script writes next to its outputs (command, config,
  seed, package versions, git commit), written atomically;
* :func:`detector_from_name`: a ``--detector`` value (``geometric``, ``learned``, ``beam`` or
  ``module:Class``) -> a detector object (the detectors are imported lazily).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import importlib.util
import json
import logging
import math
import os
import platform
import subprocess
import sys
from collections.abc import Callable, Iterable
from importlib import metadata
from pathlib import Path
from typing import Any

from detectors.fileio import write_json

__all__ = [
    "add_logging_args",
    "defaults_formatter",
    "detector_from_name",
    "package_versions",
    "parse_json_object",
    "progress",
    "setup_logging",
    "to_plain",
    "write_run_info",
]

#: the loggers of the project's packages; the scripts log under ``kin_envs.scripts.<name>``
LOGGERS = ("kin_envs", "detectors", "agents")
#: distributions whose versions go into ``run.json`` when installed (read from metadata, never imported)
VERSIONED = (
    "kin-envs", "numpy", "scipy", "numba", "pymunk", "gymnasium", "pettingzoo", "torch",
    "stable-baselines3", "supersuit", "ray",
)  # fmt: skip
_ROOT = Path(__file__).resolve().parents[1]

#: Exit status of a script stopped by Ctrl-C (128 + SIGINT, the shell convention).
EXIT_INTERRUPTED = 130

#: Largest relative range noise a script option accepts (50 % of the distance), the bound the envs
#: (``CommonConfig.noise_sigma``) and ``DatasetConfig.noise`` use: past it a scan is noise.
MAX_NOISE = 0.5


#: The extra of pyproject.toml that installs each optional top-level package a script may import.
EXTRA_OF = {
    **dict.fromkeys(("torch", "stable_baselines3", "supersuit", "tensorboard", "threadpoolctl"), "train"),
    "tqdm": "train",  # (also in ros and distributed)
    **dict.fromkeys(("matplotlib", "pygame", "PIL"), "viz"),
    "imageio_ffmpeg": "video",
    "rosbags": "ros",
    "motmetrics": "tracking",
    "ray": "distributed",
    **dict.fromkeys(("pytest", "hypothesis", "filterpy"), "dev"),
}


def _installed(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def run_main(
    main: Callable[[], object],
    bad_input: tuple[type[BaseException], ...] = (ValueError, FileNotFoundError),
) -> None:
    """Run a script's ``main()``; Ctrl-C ends it with one line on stderr and exit status 130, and bad
    input (a ``ValueError``, e.g. ``--env-kwargs '{bad'``, or a ``FileNotFoundError``: an input file
    that does not exist) with one line and exit status 2, like argparse; so does a missing optional
    package (:data:`EXTRA_OF`), naming the extra to install. ``KIN_ENVS_TRACEBACK=1`` re-raises it with
    its traceback; ``bad_input=()`` leaves errors to the script.

    Inside the world's build and step (and scene validation) Ctrl-C is deferred to the end of that
    unit of work (:mod:`kin_envs.core.interrupts`), so the stop is always clean; outputs are written
    atomically, so nothing half-written is left under a final name.
    """
    from kin_envs.core import interrupts

    interrupts.install()
    try:
        main()
    except KeyboardInterrupt:
        _interrupted()
    except Exception as e:
        # A library's clean-up can fail while a Ctrl-C unwinds through it (zipfile's "Can't close the ZIP
        # file while there is an open writing handle" during an SB3 save): still an interrupt, not bad input
        if _raised_by_ctrl_c(e) or interrupts.was_interrupted():
            # ... or a C extension replaced the KeyboardInterrupt with its own error (matplotlib's Agg
            # renderer: "Invalid bounding box"), leaving no trace of it in the exception
            _interrupted()
        missing = (e.name or "").split(".")[0] if isinstance(e, ModuleNotFoundError) else ""
        if missing in EXTRA_OF and _installed(missing):  # a bad import inside an installed package: a bug
            missing = ""
        if not (isinstance(e, bad_input) or missing in EXTRA_OF):
            raise
        if os.environ.get("KIN_ENVS_TRACEBACK"):
            raise
        name = os.path.basename(sys.argv[0]) or "script"
        if missing in EXTRA_OF:  # a training script on the core install: say which extra, not a traceback
            print(f"{name}: error: this needs {missing}, which is not installed: "
                  f"pip install 'kin-envs[{EXTRA_OF[missing]}]'", file=sys.stderr)  # fmt: skip
            raise SystemExit(2) from None
        what = "an option is not valid JSON: " if isinstance(e, json.JSONDecodeError) else ""
        print(f"{name}: error: {what}{e}", file=sys.stderr)
        raise SystemExit(2) from None


def _raised_by_ctrl_c(e: BaseException) -> bool:
    """Whether a ``KeyboardInterrupt`` is among the exceptions ``e`` was raised while handling."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _interrupted() -> None:
    name = os.path.basename(sys.argv[0]) or "script"
    print(f"{name}: interrupted (Ctrl-C); finished outputs are intact, unfinished ones were not written",
          file=sys.stderr)
    raise SystemExit(EXIT_INTERRUPTED) from None


def noise_level(text: str) -> float:
    """argparse ``type=`` of a relative range-noise option: a number in ``[0, MAX_NOISE]`` (0.01 =
    1 % of the distance); anything else is an argparse error naming the option."""
    import argparse
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a relative noise level, got {text!r}") from None
    if not (math.isfinite(v) and 0.0 <= v <= MAX_NOISE):
        raise argparse.ArgumentTypeError(
            f"noise levels must be in [0, {MAX_NOISE:g}] (relative: 0.01 = 1 % of the distance), got {text}"
        )
    return v


def check_output_dir(path, what: str = "--out") -> Path:
    """Create ``path`` (a directory) and check it is writable *before* any computation; a clear
    ``ValueError`` naming the option otherwise."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{what} {p} is a file, not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"{what} {p} cannot be created ({e.strerror})") from e
    if not os.access(p, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {p} is not writable")
    return p


def check_distance_bins(edges, what: str = "--bins") -> list[float]:
    """Distance bin edges (m): at least two, increasing, the first >= 0; a clear ``ValueError`` naming the
    option otherwise."""
    edges = [float(e) for e in edges]
    if len(edges) < 2 or edges[0] < 0 or any(b <= a for a, b in zip(edges, edges[1:], strict=False)):
        raise ValueError(f"{what} must be >= 2 increasing distances >= 0, got {edges}")
    return edges


def parse_json_object(text: str | None, what: str) -> dict | None:
    """A CLI value holding a JSON object inline or the path of a JSON file; ``None`` when empty.

    Raises ``ValueError`` naming the option (``what``) when it is not valid JSON or not an object.
    """
    if not text:
        return None
    p = Path(text)
    src = p.read_text() if p.is_file() else text
    try:
        d = json.loads(src)
    except json.JSONDecodeError as e:
        raise ValueError(f"{what}: expected a JSON object or a JSON file path, got {text!r} ({e})") from e
    if not isinstance(d, dict):
        raise ValueError(f"{what}: expected a JSON object, got {type(d).__name__}: {text!r}")
    return d


# --- logging ------------------------------------------------------------------------------------


def detector_from_name(name: str, *, checkpoint=None, reports: bool = False, what: str = "--detector"):
    """``"geometric"``, ``"learned"``, ``"beam"`` or ``"module:Class"`` -> a detector instance.

    ``checkpoint`` (a path; default: the shipped one) applies to ``learned`` and ``beam`` only.
    ``reports`` builds the per-segment reports of the geometric and learned detectors (they cost time
    and no script scores them). Raises ``ValueError`` naming ``what`` for an unknown name, a detector
    that cannot be imported or built (no or a bad checkpoint; a ``.pt`` without its ``.npz`` and no
    torch), or an object without ``detect_batch``.
    """
    if not isinstance(name, str):
        raise TypeError(f"{what}: expected a detector name (str), got {type(name).__name__}")
    if checkpoint is not None and name not in ("learned", "beam"):
        raise ValueError(f"{what} {name!r}: a checkpoint applies to 'learned' and 'beam' only")
    if name == "geometric":
        from detectors import GeometricKinDetector

        return GeometricKinDetector(reports=reports)
    if name == "learned":
        try:
            from detectors.learned import LearnedKinDetector
        except ImportError as e:  # a broken install (the learned detector needs no torch)
            raise ValueError(
                f"detector 'learned' is unavailable: cannot import detectors.learned ({e})"
            ) from e
        try:
            return LearnedKinDetector(checkpoint, reports=reports)
        except (OSError, ValueError) as e:  # no or bad checkpoint
            raise ValueError(f"detector 'learned' is unavailable: {e}") from e
    if name == "beam":
        from detectors.beam_detector import BeamKinDetector

        try:
            return BeamKinDetector(checkpoint)
        except (OSError, ValueError) as e:
            raise ValueError(f"detector 'beam' is unavailable: {e}") from e
    if ":" in name:
        import importlib

        module, _, cls_name = name.partition(":")
        try:
            cls = getattr(importlib.import_module(module), cls_name)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"detector {name!r}: cannot import {cls_name} from {module} ({e})") from e
        try:
            det = cls()
        except Exception as e:  # whatever the constructor raises, say which detector failed
            raise ValueError(f"detector {name!r}: {cls_name}() failed ({type(e).__name__}: {e})") from e
        if not callable(getattr(det, "detect_batch", None)):
            raise ValueError(f"detector {name!r}: {cls_name} has no detect_batch(ranges, angles)")
        return det
    raise ValueError(
        f"unknown detector {name!r} ({what}); expected 'geometric', 'learned', 'beam' or a "
        "'module:Class' path"
    )


def defaults_formatter(base: type[argparse.HelpFormatter]) -> type[argparse.HelpFormatter]:
    """``base`` (a help formatter class) that ends each option's help with ``(default: ...)`` where the
    help does not name its default already; flags (``store_true``), positionals and ``None`` defaults
    are left alone."""

    class DefaultsFormatter(base):
        def _get_help_string(self, action: argparse.Action) -> str:
            text = action.help or ""
            d = action.default
            if (not text or not action.option_strings or d is None or d is argparse.SUPPRESS
                    or isinstance(d, bool) or "default" in text.lower()):
                return text
            return text + " (default: %(default)s)"

    return DefaultsFormatter


def add_logging_args(parser: argparse.ArgumentParser) -> None:
    """Add ``-v/--verbose`` (debug messages) and ``-q/--quiet`` (warnings and errors only), and make
    ``--help`` show each option's default (:func:`defaults_formatter`; every script calls this)."""
    if not getattr(parser.formatter_class, "_shows_defaults", False):
        parser.formatter_class = defaults_formatter(parser.formatter_class)
        parser.formatter_class._shows_defaults = True
    g = parser.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="store_true", help="also log debug messages")
    g.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only")


def setup_logging(args: argparse.Namespace | None = None, *, verbose: bool = False,
                  quiet: bool = False) -> int:
    """Set the level of the project's loggers from ``--verbose`` / ``--quiet``; returns the level.

    The library only creates loggers (with a ``NullHandler``); a script calls this once. A stderr
    handler is added to the root logger only when none is configured, so an application's (or
    pytest's) logging set-up is left alone.
    """
    if args is not None:
        verbose, quiet = getattr(args, "verbose", False), getattr(args, "quiet", False)
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")  # no-op when handlers exist
    for name in LOGGERS:
        logging.getLogger(name).setLevel(level)
    return level


def script_logger(file: str) -> logging.Logger:
    """The logger of a script: ``kin_envs.scripts.<file stem>``."""
    return logging.getLogger(f"kin_envs.scripts.{Path(file).stem}")


# --- progress -----------------------------------------------------------------------------------


class _NoBar:
    """What the scripts use of a tqdm bar, doing nothing (tqdm is not installed)."""

    def __init__(self, iterable=None, total=None, **_):
        self.iterable, self.total, self.n = iterable, total, 0

    def __iter__(self):
        return iter(self.iterable if self.iterable is not None else ())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n=1):
        self.n += n

    def set_postfix(self, *args, **kwargs):
        pass

    def set_description(self, *args, **kwargs):
        pass

    def close(self):
        pass


def progress(iterable: Iterable | None = None, **kwargs):
    """``tqdm(iterable, **kwargs)`` when tqdm is installed, else an object with the same use
    (iteration, ``update``, ``set_postfix``, ``close``) that shows nothing."""
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm comes with the train / distributed extras, not the core
        return _NoBar(iterable, **kwargs)
    return tqdm(iterable, **kwargs)


# --- run records --------------------------------------------------------------------------------


def to_plain(obj: Any) -> Any:
    """JSON-ready copy: dataclasses and mappings to dicts, paths to strings, numpy values to Python,
    tuples and sets to lists, non-finite floats to ``None``."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_plain(dataclasses.asdict(obj))
    if isinstance(obj, dict):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        return [to_plain(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, bool | int | str) or obj is None:
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    tolist = getattr(obj, "tolist", None)  # numpy scalars and arrays, without importing numpy here
    if callable(tolist):
        return to_plain(tolist())
    return repr(obj)


def package_versions() -> dict[str, str]:
    """Python, platform and the installed versions of :data:`VERSIONED` (from package metadata)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


@functools.lru_cache(maxsize=1)
def _git_commit() -> str | None:
    if not (_ROOT / ".git").exists():  # an installed copy, not a checkout
        return None
    try:
        r = subprocess.run(["git", "-C", str(_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True,
                           timeout=10, check=False)
        dirty = subprocess.run(["git", "-C", str(_ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    if r.returncode != 0:
        return None
    return r.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


def _script_path(script: str | None) -> str | None:
    if script is None:
        return None
    p = Path(script).resolve()
    try:
        return str(p.relative_to(_ROOT))
    except ValueError:
        return str(p)


def write_run_info(out_dir, args: argparse.Namespace | dict | None = None, *, config: Any = None,
                   seed: Any = None, argv: list[str] | None = None, script: str | None = None,
                   filename: str = "run.json", **fields: Any) -> dict:
    """Write ``out_dir/filename`` (default ``run.json``) atomically and return what was written.

    Keys: ``script``; ``command`` (``sys.argv`` when ``argv`` is ``None``, else the script and
    ``argv``: the call ``main(argv)``); ``cwd``; ``args`` (the parsed command line); ``config`` (the
    resolved configuration, e.g. a dataclass); ``seed``; ``versions`` (:func:`package_versions`);
    ``git_commit`` (``-dirty`` when the checkout has changes; ``None`` outside a checkout); ``time``
    (UTC); then ``fields`` as given (results, timings, status). Values go through :func:`to_plain`.
    Call it again (e.g. with ``status="done"``) to replace the file.
    """
    out_dir = Path(out_dir)
    script = _script_path(script)
    if argv is None:
        command = [sys.executable, *sys.argv]
    else:
        command = [sys.executable, *([script] if script else []), *map(str, argv)]
    info = {
        "script": script,
        "command": command,
        "cwd": os.getcwd(),
        "args": vars(args) if isinstance(args, argparse.Namespace) else args,
        "config": config,
        "seed": seed,
        "versions": package_versions(),
        "git_commit": _git_commit(),
        "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        **fields,
    }
    info = to_plain(info)
    write_json(out_dir / filename, info, allow_nan=False)
    return info
