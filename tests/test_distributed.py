"""kin_envs.distributed: the local and Ray backends give the same results; errors; Ray is shut down.

Tests marked ``distributed`` need Ray (``.venv-ray``, ``make test-distributed``) and are skipped
where it is not installed.
"""

import functools
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from kin_envs.distributed import cached, imap_seeds, map_seeds, ray_session

RAY_REASON = "ray is not installed here; the distributed tests run in .venv-ray (make test-distributed)"


# work units: top level, so Ray workers can import them by name
def draw(seed: int, n: int) -> dict:
    rng = np.random.default_rng(seed)
    return {"seed": seed, "x": rng.normal(size=n), "k": int(rng.integers(1000))}


def slow_first(seed: int) -> int:
    if seed == 0:
        time.sleep(1.0)  # finishes after the units behind it
    return 10 * seed


def fail_on_three(seed: int) -> int:
    if seed == 3:
        raise ValueError(f"unit {seed} failed")
    return seed


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for u, v in zip(a, b, strict=True):
        assert u["seed"] == v["seed"] and u["k"] == v["k"]
        assert np.array_equal(u["x"], v["x"])  # bit-identical


def test_local_backend_keeps_the_input_order_and_passes_args():
    out = map_seeds(draw, [5, 1, 3], args=(4,), progress=False)
    assert [o["seed"] for o in out] == [5, 1, 3]
    assert np.array_equal(out[0]["x"], np.random.default_rng(5).normal(size=4))
    assert map_seeds(draw, [], args=(4,), progress=False) == []


def _nested():
    def inner(seed):
        return seed

    return inner


CALLS = []


def logged(seed: int) -> int:
    CALLS.append(seed)
    return seed


def test_imap_local_is_lazy():
    CALLS.clear()
    it = imap_seeds(logged, range(5), progress=False)
    assert CALLS == []  # arguments are checked now, the work waits for next()
    assert [next(it), next(it)] == [0, 1] and CALLS == [0, 1]
    assert list(it) == [2, 3, 4]


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"backend": "dask"}, ValueError, "unknown backend 'dask'; expected one of local, ray"),
        ({"fn": lambda s: s}, TypeError, "top-level"),
        ({"fn": _nested()}, TypeError, "top-level"),
        ({"fn": functools.partial(draw, n=2), "args": ()}, TypeError, "top-level function, got partial"),
        ({"args": [3]}, TypeError, "args must be a tuple"),
        ({"chunksize": 0}, ValueError, "chunksize must be an int >= 1"),
        ({"max_in_flight": 1.5}, ValueError, "max_in_flight must be an int >= 1"),
        ({"address": "auto"}, ValueError, "apply to the 'ray' backend only"),
        ({"num_cpus": 2}, ValueError, "apply to the 'ray' backend only"),
    ],
)
def test_bad_inputs_raise(kwargs, error, match):
    call = {"fn": draw, "units": [1, 2], "args": (2,), "progress": False, **kwargs}
    with pytest.raises(error, match=match):
        map_seeds(**call)


def test_ray_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(ImportError, match=r"Ray is not installed .*pip install kin-envs\[distributed\]"):
        map_seeds(draw, [1], "ray", args=(2,), progress=False)
    with pytest.raises(ImportError, match="pip install"):  # at the call, not at the first next()
        imap_seeds(draw, [1], "ray", args=(2,), progress=False)


def test_cached_builds_once_per_key():
    calls = []
    key = ("test_distributed", object())
    for _ in range(3):
        assert cached(key, lambda: calls.append(1) or "built") == "built"
    assert calls == [1]


def test_import_kin_envs_does_not_import_distributed_or_ray():
    code = "import sys, kin_envs; print('kin_envs.distributed' in sys.modules, 'ray' in sys.modules)"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["False", "False"]


# --------------------------------------------------------------------------- with Ray


@pytest.mark.distributed
def test_a_ray_started_for_the_call_matches_local_and_is_shut_down():
    ray = pytest.importorskip("ray", reason=RAY_REASON)
    # runs before the module's shared session below (file order), so map_seeds starts its own Ray
    assert not ray.is_initialized(), "a Ray session leaked from another test"
    with pytest.raises(ValueError, match="num_cpus applies to a local Ray only"):
        with ray_session(address="auto", num_cpus=2):
            pass
    out = map_seeds(draw, range(6), "ray", args=(3,), num_cpus=2, progress=False)
    assert not ray.is_initialized()
    assert_same(out, map_seeds(draw, range(6), args=(3,), progress=False))


@pytest.mark.distributed
def test_an_address_where_nothing_listens_fails_fast():
    ray = pytest.importorskip("ray", reason=RAY_REASON)
    assert not ray.is_initialized(), "a Ray session leaked from another test"
    with socket.socket() as s:  # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(ConnectionError, match=f"cannot join the Ray cluster at '127.0.0.1:{port}'"):
        map_seeds(draw, [1], "ray", args=(2,), address=f"127.0.0.1:{port}", progress=False)
    assert time.perf_counter() - t0 < 30  # ray.init alone would wait for minutes
    assert not ray.is_initialized()


@pytest.fixture(scope="module")
def ray_local():
    ray = pytest.importorskip("ray", reason=RAY_REASON)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.mark.distributed
@pytest.mark.parametrize("chunksize", [1, 4])
def test_ray_matches_local(ray_local, chunksize):
    units = [17, 3, 1_000_000, 0, 42, 8, 9, 10, 11, 12, 13]  # out of order: results keep it
    local = map_seeds(draw, units, args=(5,), progress=False)
    remote = map_seeds(draw, units, "ray", args=(5,), chunksize=chunksize, max_in_flight=3, progress=False)
    assert_same(local, remote)
    assert ray_local.is_initialized()  # the caller's session is used and left running


@pytest.mark.distributed
def test_ray_unit_error_raises_the_original_exception_type(ray_local):
    with pytest.raises(ValueError, match="unit 3 failed"):
        map_seeds(fail_on_three, range(8), "ray", progress=False)
    # the session still works after a failed sweep
    assert map_seeds(fail_on_three, [1, 2], "ray", progress=False) == [1, 2]


@pytest.mark.distributed
@pytest.mark.parametrize("chunksize", [1, 2])
def test_imap_ray_keeps_the_order_behind_a_slow_unit_and_can_stop_early(ray_local, chunksize):
    it = imap_seeds(slow_first, range(12), "ray", chunksize=chunksize, max_in_flight=3, progress=False)
    assert list(it) == [10 * s for s in range(12)]
    it = imap_seeds(slow_first, range(1, 50), "ray", progress=False)
    assert [next(it), next(it)] == [10, 20]
    it.close()  # abandoned: the queued tasks are cancelled, the session goes on
    assert map_seeds(slow_first, [3], "ray", progress=False) == [30]
