"""Small helpers that turn plain dicts into validated frozen dataclasses and check field values.

Every check names the class and field. A value of the wrong *type* raises :class:`FieldTypeError`,
which is both a ``TypeError`` (Python's convention) and a ``ValueError`` (the project's: bad input is
a ``ValueError``), so callers catching either see it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

import numpy as np

#: Largest magnitude accepted for a length, coordinate or mass (SI units). Far beyond any arena, and
#: small enough that products of a few such values never overflow float64 inside pymunk.
MAX_MAGNITUDE = 1e6


class FieldTypeError(TypeError, ValueError):
    """A config field or argument has the wrong type."""


def dataclass_from_dict(cls: type, d: Any, where: str) -> Any:
    """Build ``cls(**d)``; unknown keys or a non-dict raise ``ValueError`` naming them."""
    if isinstance(d, cls):
        return d
    if not isinstance(d, dict):
        raise FieldTypeError(f"{where}: expected a dict for {cls.__name__}, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names, key=repr)
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {unknown} for {cls.__name__}; expected a subset of {sorted(names)}"
        )
    return cls(**d)


def make_rng(seed: Any, where: str) -> np.random.Generator:
    """The RNG of ``seed``: ``None``, an integer >= 0, a ``SeedSequence`` or a ``Generator`` (used as is,
    shared with the caller). Anything else raises naming ``where`` and the value, before numpy's own
    message ("expected non-negative integer"), which names neither."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise FieldTypeError(
            f"{where}: seed must be None, an integer >= 0 or a numpy Generator, "
            f"got {type(seed).__name__} {seed!r}"
        )
    if seed < 0:
        raise ValueError(f"{where}: seed must be >= 0, got {seed}")
    return np.random.default_rng(int(seed))


def _is_real(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and type(v).__name__ != "bool_"


def check_number(
    where: str, name: str, v: Any, lo: float = -MAX_MAGNITUDE, hi: float = MAX_MAGNITUDE,
    *, lo_open: bool = False, integer: bool = False,
) -> None:
    """``v`` must be a real number (an integer if ``integer``) in ``[lo, hi]`` (``(lo, hi]`` if
    ``lo_open``); raises :class:`FieldTypeError` for a wrong type, ``ValueError`` for a bad value."""
    kind = "an integer" if integer else "a finite number"
    if not _is_real(v) or (integer and not isinstance(v, numbers.Integral)):
        raise FieldTypeError(f"{where}: {name} must be {kind}, got {type(v).__name__} {v!r}")
    f = float(v)
    if not math.isfinite(f) or not ((f > lo) if lo_open else (f >= lo)) or f > hi:
        if lo_open:
            bounds = f"> {lo:g} and <= {hi:g}"
        elif hi == math.inf or hi >= 1e300:
            bounds = f">= {lo:g}"
        else:
            bounds = f"in [{lo:g}, {hi:g}]"
        what = f"{kind} " if integer or not math.isfinite(f) else ""
        raise ValueError(f"{where}: {name} must be {what}{bounds}, got {v!r}")


def check_bool(where: str, name: str, v: Any) -> None:
    if not isinstance(v, bool) and type(v).__name__ != "bool_":
        raise FieldTypeError(f"{where}: {name} must be True or False, got {type(v).__name__} {v!r}")


def check_finite(where: str, **values: float) -> None:
    """Each value is a real number with ``|v| <= MAX_MAGNITUDE``."""
    for name, v in values.items():
        check_number(where, name, v)


def check_positive(where: str, **values: float) -> None:
    """Each value is a real number in ``(0, MAX_MAGNITUDE]``."""
    for name, v in values.items():
        check_number(where, name, v, 0.0, lo_open=True)


def check_sequence(where: str, name: str, v: Any, n: int | None = None, *, min_len: int = 0) -> tuple:
    """``v`` is a list / tuple / 1-D array (of ``n`` items if given, at least ``min_len``); returned
    as a tuple (frozen configs store tuples)."""
    if isinstance(v, str | bytes) or not isinstance(v, tuple | list) and type(v).__name__ != "ndarray":
        what = f"{n} numbers" if n is not None else "numbers"
        raise FieldTypeError(
            f"{where}: {name} must be a list or tuple of {what}, got {type(v).__name__} {v!r}"
        )
    t = tuple(v)
    if (n is not None and len(t) != n) or len(t) < min_len:
        expected = f"exactly {n}" if n is not None else f"at least {min_len}"
        raise ValueError(f"{where}: {name} must hold {expected} item(s), got {len(t)}: {v!r}")
    return t


def check_interval(where: str, name: str, v: Any, lo: float = 0.0, hi: float = MAX_MAGNITUDE) -> tuple:
    """``v`` is ``(min, max)`` with ``lo < min <= max <= hi``; returned as a tuple of floats."""
    a, b = check_sequence(where, name, v, 2)
    check_number(where, f"{name}[0]", a, lo, hi, lo_open=True)
    check_number(where, f"{name}[1]", b, lo, hi, lo_open=True)
    if a > b:
        raise ValueError(f"{where}: {name} must be (min, max) with min <= max, got {v!r}")
    return (a, b)


def check_weights(where: str, name: str, v: Any, n: int) -> tuple:
    """``v`` is ``n`` relative weights: finite, >= 0, not all 0."""
    t = check_sequence(where, name, v, n)
    for i, w in enumerate(t):
        check_number(where, f"{name}[{i}]", w, 0.0)
    if sum(float(w) for w in t) <= 0:
        raise ValueError(f"{where}: {name} must not all be 0, got {v!r}")
    return t
