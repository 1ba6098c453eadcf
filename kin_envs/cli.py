"""Small helpers shared by the command-line scripts (no heavy imports)."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

#: Exit status of a script stopped by Ctrl-C (128 + SIGINT, the shell convention).
EXIT_INTERRUPTED = 130


def run_main(main: Callable[[], object], bad_input: tuple[type[BaseException], ...] = (ValueError,)) -> None:
    """Run a script's ``main()``; Ctrl-C ends it with one line on stderr and exit status 130, and bad
    input (a ``ValueError``, e.g. ``--env-kwargs '{bad'``) with one line and exit status 2, like argparse.
    ``KIN_ENVS_TRACEBACK=1`` re-raises the ``ValueError`` with its traceback; ``bad_input=()`` leaves
    errors to the script.

    Inside the world's build and step (and scene validation) Ctrl-C is deferred to the end of that
    unit of work (:mod:`kin_envs.core.interrupts`), so the stop is always clean; outputs are written
    atomically, so nothing half-written is left under a final name.
    """
    from kin_envs.core import interrupts

    interrupts.install()
    try:
        main()
    except bad_input as e:
        if os.environ.get("KIN_ENVS_TRACEBACK"):
            raise
        name = os.path.basename(sys.argv[0]) or "script"
        what = "an option is not valid JSON: " if isinstance(e, json.JSONDecodeError) else ""
        print(f"{name}: error: {what}{e}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:
        name = os.path.basename(sys.argv[0]) or "script"
        print(f"{name}: interrupted (Ctrl-C); finished outputs are intact, unfinished ones were not written",
              file=sys.stderr)
        raise SystemExit(EXIT_INTERRUPTED) from None


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
