"""Small helpers shared by the command-line scripts (no heavy imports)."""

from __future__ import annotations

import json
from pathlib import Path


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
