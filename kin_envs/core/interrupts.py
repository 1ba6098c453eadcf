"""Ctrl-C that never lands inside pymunk.

pymunk runs Python callbacks from C (space queries, and the finalisers that free a space or body).
A ``KeyboardInterrupt`` raised inside one is printed and *swallowed* by cffi (the program carries on,
or later aborts on a half-freed Chipmunk object). So the SIGINT handler installed here raises
``KeyboardInterrupt`` only where that is safe:

* inside :func:`atomic` sections (the world's build and step, scene validation) it only sets a flag,
  and the section raises ``KeyboardInterrupt`` when it ends, so a world is never left half-stepped;
* inside any pymunk frame outside such a section (a finaliser run by the garbage collector) it
  re-delivers the signal a few milliseconds later.

The handler is installed in the main thread the first time a section runs, and only in place of
Python's default handler (a handler set by the application is left alone, and then the application
decides what Ctrl-C does).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import pymunk

__all__ = ["atomic", "install", "was_interrupted"]

_PYMUNK_DIR = str(Path(pymunk.__file__).resolve().parent)
_depth = 0
_pending = False
#: whether this handler has raised a KeyboardInterrupt in this process (see :func:`was_interrupted`)
_raised = False


def was_interrupted() -> bool:
    """Whether the handler has raised a ``KeyboardInterrupt`` in this process. A C extension that runs
    Python code can replace the ``KeyboardInterrupt`` with an error of its own (matplotlib's Agg
    renderer: ``ValueError: Invalid bounding box``), leaving no trace of the Ctrl-C in the exception:
    callers ask this instead."""
    return _raised


def _in_pymunk(frame) -> bool:
    while frame is not None:
        if frame.f_code.co_filename.startswith(_PYMUNK_DIR):
            return True
        frame = frame.f_back
    return False


def _handler(signum, frame) -> None:
    global _pending, _raised
    if _depth > 0:
        _pending = True
        return
    if _in_pymunk(frame):
        retry = threading.Timer(0.005, os.kill, (os.getpid(), signal.SIGINT))
        retry.daemon = True
        retry.start()
        return
    _raised = True
    raise KeyboardInterrupt


def install() -> bool:
    """Install the handler if SIGINT still has Python's default handler (main thread only).
    Returns whether the handler is active."""
    current = signal.getsignal(signal.SIGINT)
    if current is _handler:
        return True
    if current is not signal.default_int_handler or threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(signal.SIGINT, _handler)
    return True


@contextlib.contextmanager
def atomic() -> Iterator[None]:
    """A block that Ctrl-C does not interrupt; a Ctrl-C during it raises when it ends.

    Signal handlers run in the main thread only, so in other threads this is a no-op."""
    global _depth, _pending, _raised
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if signal.getsignal(signal.SIGINT) is not _handler:
        install()
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _pending:
            _pending = False
            _raised = True
            raise KeyboardInterrupt
