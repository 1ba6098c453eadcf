"""Run seeded work units locally or on a Ray cluster, with the same results.

A *work unit* is whatever one call of a top-level function needs: a scene seed, ``(seed, config)``,
an arena index. :func:`map_seeds` runs ``fn(unit, *args)`` for every unit and returns the results
in input order, either in this process (``backend="local"``) or as one Ray task per unit
(``backend="ray"``): on a local Ray started for the call (``num_cpus`` workers) or on an existing
cluster (``address``, e.g. ``"auto"`` or ``"10.0.0.1:6379"`` after ``ray start --head``). Each unit
is seeded by its own content, never by the worker that runs it, so both backends give identical
results.

Ray is optional (``pip install kin-envs[distributed]``) and only imported when the Ray backend is
used; ``import kin_envs`` never imports this module.

Example::

    from kin_envs.distributed import map_seeds

    def scene_stats(seed: int, n_robots: int) -> int:  # top level: workers import or receive it
        ...

    stats = map_seeds(scene_stats, range(1000), backend="ray", num_cpus=2, args=(8,))
"""

from __future__ import annotations

import inspect
import itertools
import logging
import socket
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["BACKENDS", "cached", "imap_seeds", "map_seeds", "ray_session", "ship_by_value"]

BACKENDS = ("local", "ray")
U = TypeVar("U")
R = TypeVar("R")
log = logging.getLogger(__name__)

_INSTALL_HINT = "pip install kin-envs[distributed]"
# per-process objects built by cached(): this module is imported by name on every worker, so the
# dict lives once per worker process and is never shipped with a task
_CACHE: dict[Any, Any] = {}


def cached(key, factory: Callable[[], R]) -> R:
    """``factory()``, built once per process and ``key``: for expensive objects a work unit needs
    (detectors, models) that should be built once per worker, not once per unit."""
    if key not in _CACHE:
        _CACHE[key] = factory()
    return _CACHE[key]


def _import_ray():
    try:
        import ray
    except ImportError as e:
        raise ImportError(f"Ray is not installed (backend 'ray', RLlib scripts): {_INSTALL_HINT}") from e
    return ray


@contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """A connected ``ray`` module for the ``with`` block; shut down afterwards if started here.

    ``address`` joins an existing cluster (``"host:port"`` of a ``ray start --head``, or ``"auto"``
    for one on this machine); without it a local Ray starts with ``num_cpus`` CPUs (default: all).
    An already initialised Ray (the caller's own session) is used as it is, whatever ``address``
    and ``num_cpus`` say, and left running.
    """
    ray = _import_ray()
    if ray.is_initialized():
        yield ray
        return
    if address is not None and num_cpus is not None:
        raise ValueError(
            "num_cpus applies to a local Ray only; an existing cluster at --address has its own CPUs"
        )
    if num_cpus is not None and (isinstance(num_cpus, bool) or not isinstance(num_cpus, int) or num_cpus < 1):
        raise ValueError(f"num_cpus must be an int >= 1, got {num_cpus!r}")
    if address is None:
        log.info("starting a local Ray (%s CPUs)", "all" if num_cpus is None else num_cpus)
        # light local instance: no dashboard; worker output not mirrored (errors still propagate)
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    else:
        _check_reachable(address)
        log.info("joining the Ray cluster at %s", address)
        try:
            ray.init(address=address, log_to_driver=False)
        except ConnectionError as e:
            raise ConnectionError(
                f"cannot join the Ray cluster at {address!r}: is `ray start --head` running there? With "
                "token authentication (what `ray start` turns on since ray 2.59) this machine also needs "
                "RAY_AUTH_MODE=token and the cluster's token (`ray get-auth-token` on the head, "
                f"RAY_AUTH_TOKEN here). Ray said: {e}"
            ) from e
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_reachable(address: str, timeout: float = 10.0) -> None:
    """Fail fast on a ``host:port`` where nothing listens: ``ray.init`` waits many minutes there."""
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return  # "auto" and other forms: Ray resolves those itself
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise ConnectionError(
            f"cannot join the Ray cluster at {address!r}: nothing answers there ({e}); "
            "start it with `ray start --head --port PORT` on that machine"
        ) from e


def _check_fn(fn) -> None:
    # Ray ships functions by pickling; a lambda or nested function works locally but is the first
    # thing to break on a cluster, so both backends demand a module-level function.
    if not inspect.isfunction(fn) and not inspect.isbuiltin(fn):
        raise TypeError(f"map_seeds: fn must be a top-level function, got {type(fn).__name__}")
    if fn.__name__ == "<lambda>" or "<locals>" in fn.__qualname__:
        raise TypeError(
            f"map_seeds: fn must be a top-level (module-level) function that workers can receive, "
            f"got {fn.__qualname__!r}"
        )


def _importable_by_name(module: str) -> bool:
    """Can a fresh process import ``module`` by name? (Asks the finders, not ``sys.modules``.)"""
    top = module.partition(".")[0]
    for finder in sys.meta_path:
        find = getattr(finder, "find_spec", None)
        try:
            if find is not None and find(top, None) is not None:
                return True
        except Exception:  # a broken third-party finder says nothing about this module
            continue
    return False


def ship_by_value(obj) -> None:
    """Make Ray send the module defining ``obj`` (a function or class) by value if workers could
    not import it by name.

    Scripts run as ``__main__`` are pickled by value anyway; a script loaded from its path under a
    made-up name (tests, notebooks) would be pickled by reference and fail to import on workers.
    """
    name = getattr(obj, "__module__", None)
    mod = sys.modules.get(name) if name else None
    if mod is not None and name != "__main__" and not _importable_by_name(name):
        _import_ray().cloudpickle.register_pickle_by_value(mod)


def _progress(total: int, desc: str, unit: str, enabled: bool):
    if enabled:
        try:
            from tqdm import tqdm
        except ImportError:  # tqdm comes with the train/distributed extras; the core does without
            pass
        else:
            return tqdm(total=total, desc=desc, unit=unit)
    return None


def map_seeds(
    fn: Callable[..., R],
    units: Iterable[U],
    backend: str = "local",
    *,
    args: tuple = (),
    address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    desc: str = "units",
    unit: str = "unit",
    chunksize: int = 1,
    max_in_flight: int | None = None,
) -> list[R]:
    """``[fn(u, *args) for u in units]``, in input order, on the chosen backend.

    Args:
        fn: a top-level (module-level) function; it must seed everything it draws from the unit.
        units: the work units (seeds, tuples, ...), each picklable.
        backend: ``"local"`` (this process, in order) or ``"ray"`` (one Ray task per unit).
        args: extra arguments shared by all units; with Ray they are stored once (``ray.put``)
            instead of being sent with every task.
        address: Ray only: join an existing cluster; default: use the caller's Ray session if one
            is running, else start a local Ray for this call and shut it down afterwards.
        num_cpus: Ray only: CPUs of that local Ray (default: all of this machine's).
        progress: tqdm bar over completed units.
        desc, unit: the bar's label and unit name.
        chunksize: Ray only: consecutive units per task (default 1: a task per unit). A Ray task
            costs about a millisecond, so units much shorter than that are better run in chunks.
        max_in_flight: Ray only: tasks submitted or finished but not yet handed over, at most
            (default: 4 per cluster CPU, at least 16), so millions of units never sit in the
            scheduler or in memory at once.

    A failing unit raises its exception here (with Ray, a ``RayTaskError`` that is also an
    instance of the original exception class), after cancelling the tasks still queued.
    """
    return list(
        imap_seeds(
            fn, units, backend, args=args, address=address, num_cpus=num_cpus, progress=progress,
            desc=desc, unit=unit, chunksize=chunksize, max_in_flight=max_in_flight,
        )
    )  # fmt: skip


def imap_seeds(
    fn: Callable[..., R],
    units: Iterable[U],
    backend: str = "local",
    *,
    args: tuple = (),
    address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    desc: str = "units",
    unit: str = "unit",
    chunksize: int = 1,
    max_in_flight: int | None = None,
) -> Iterator[R]:
    """:func:`map_seeds` as an iterator: each result as soon as it and all before it are done,
    so a consumer (writing shards, say) holds only a window of results and overlaps with the
    workers. Arguments are checked now; the work starts at the first ``next()``. A Ray started
    here is shut down when the iterator is exhausted or closed (use it in a ``for`` loop or
    ``contextlib.closing``)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    _check_fn(fn)
    if not isinstance(args, tuple):
        raise TypeError(f"map_seeds: args must be a tuple, got {type(args).__name__}")
    for name, v in (("chunksize", chunksize), ("max_in_flight", max_in_flight)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise ValueError(f"map_seeds: {name} must be an int >= 1, got {v!r}")
    if backend == "local" and (address is not None or num_cpus is not None):
        raise ValueError("address and num_cpus apply to the 'ray' backend only")
    units = list(units)
    if backend == "ray":
        _import_ray()  # fail now, not at the first next()
        return _imap_ray(fn, units, args, address, num_cpus, progress, desc, unit, chunksize, max_in_flight)
    return _imap_local(fn, units, args, progress, desc, unit)


def _imap_local(fn, units: list, args: tuple, progress: bool, desc: str, unit: str) -> Iterator:
    bar = _progress(len(units), desc, unit, progress)
    try:
        for u in units:
            result = fn(u, *args)
            if bar is not None:
                bar.update(1)
            yield result
    finally:
        if bar is not None:
            bar.close()


def _run_chunk(chunk: list, fn, *args) -> list:
    return [fn(u, *args) for u in chunk]


def _imap_ray(fn, units: list, args, address, num_cpus, progress, desc, unit, chunksize, max_in_flight):
    with ray_session(address, num_cpus) as ray:
        ship_by_value(fn)
        # units are seeded, so Ray may safely re-run a task whose worker or node died (its default)
        if chunksize == 1:
            task, head = ray.remote(num_cpus=1)(fn), ()
        else:
            task, head = ray.remote(num_cpus=1)(_run_chunk), (ray.put(fn),)
        shared = [*head, *(ray.put(a) for a in args)]  # stored once; top-level refs arrive as values
        if max_in_flight is None:
            max_in_flight = max(16, 4 * int(ray.cluster_resources().get("CPU", 1)))
        starts = iter(range(0, len(units), chunksize))
        pending: dict = {}  # ref -> first unit index of its chunk
        finished: dict[int, list] = {}  # first unit index -> results, until their turn comes
        turn = 0  # the next unit index to hand over
        bar = _progress(len(units), desc, unit, progress)
        try:
            while True:
                # the window counts finished-but-waiting chunks too: one slow unit cannot make the
                # results behind it pile up without bound
                for i in itertools.islice(starts, max(0, max_in_flight - len(pending) - len(finished))):
                    work = units[i] if chunksize == 1 else units[i : i + chunksize]
                    pending[task.remote(work, *shared)] = i
                if not pending:
                    break
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i, value = pending.pop(ref), ray.get(ref)
                    finished[i] = [value] if chunksize == 1 else value
                    if bar is not None:
                        bar.update(len(finished[i]))
                while turn in finished:
                    chunk = finished.pop(turn)
                    turn += len(chunk)
                    yield from chunk
        finally:
            for ref in pending:  # failed or abandoned: do not leave the cluster busy
                ray.cancel(ref)
            if bar is not None:
                bar.close()
