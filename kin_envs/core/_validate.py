"""Small helpers that turn plain dicts into validated frozen dataclasses."""

from __future__ import annotations

import dataclasses
import math
from typing import Any


def dataclass_from_dict(cls: type, d: Any, where: str) -> Any:
    """Build ``cls(**d)``; unknown keys or a non-dict raise ``ValueError`` naming them."""
    if isinstance(d, cls):
        return d
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a dict for {cls.__name__}, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {unknown} for {cls.__name__}; expected a subset of {sorted(names)}"
        )
    return cls(**d)


def check_finite(where: str, **values: float) -> None:
    for name, v in values.items():
        if not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError(f"{where}: {name} must be a finite number, got {v!r}")


def check_positive(where: str, **values: float) -> None:
    check_finite(where, **values)
    for name, v in values.items():
        if v <= 0:
            raise ValueError(f"{where}: {name} must be > 0, got {v!r}")
