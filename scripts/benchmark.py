"""Speed benchmarks, reported as ratios against baselines measured in the same run.

Sections (``--sections``, comma separated; default all available):

* ``lidar``: scans/s of the vectorised raycaster (one scan = one robot's 360 beams) for
  N = 1, 8, 64, 256 robots with 50 obstacles in a 10 x 10 m arena, against a naive loop of pymunk
  ``segment_query_first`` per beam on the same world; and physics steps/s.
* ``lidar_scaling``: robot-scans/s for ``--scaling-robots`` (1, 16, 64, 256) robots x
  ``--scaling-obstacles`` (10, 100, 1,000) obstacles at one density of objects (the arena's side is
  ``sqrt((robots + obstacles) / 0.7)`` m, at least 5 m): the grid broad phase (forced on), the
  brute-force kernel (``WorldConfig(lidar_grid=False)``) and the naive pymunk loop on the same world,
  which of the two kernels the default picks, and the world's build time. Targets are computed on
  the default's choice. Compile / cache-load time of the kernels is reported on its own.
* ``detector``: scans/s of the geometric and learned detectors batched on one core (all 64 scans of
  a dense arena per call), array path vs objects vs the previous implementation, warm; start-up
  (incl. numba compilation) on its own line.
* ``envs``: env steps/s for KinSeek-v2 and aggregation_v2 (16, 64, 256 robots) with the detector off,
  geometric and learned, as a user gets them (no thread settings), and the ratio to detector off.
* ``memory``: RSS of a 256-robot swarm with the learned detector over ``--memory-steps`` steps.
* ``vecenv``: env-steps/s of ``KinSeek-v2``'s native vector env (``gym.make_vec``, K sub-envs,
  ``--vec-envs``) against Gymnasium's ``SyncVectorEnv`` over K envs, same run, per detector
  (``--vec-detectors``) and range noise (``--vec-noise``: 0, KinSeek's default, and 1 %).
* ``ros``: recording an 8-robot World run to a bag (steps/s, against the same run unrecorded) and
  reading its scans back (scans/s, against running the geometric detector on them), per bag format
  (needs the ``ros`` extra).

Writes ``benchmark.json`` and ``benchmark.md`` (plus the command and config) to ``--out``.
Never assert wall-clock times in tests; this script is where speed targets are checked.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import math
import os
import platform
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kin_envs import World, scenes
from kin_envs.cli import add_logging_args, setup_logging, write_run_info
from kin_envs.core.world import LIDAR_QUERY_FILTER

#: The clock of :func:`rate`: wall time (``--clock wall``, default, what a user sees) or this process's
#: CPU time (``--clock cpu``: on a shared machine, time spent waiting for a core is not counted).
CLOCK: dict[str, Callable[[], float]] = {"now": time.perf_counter}


def rate(fn: Callable[[], object], min_time: float) -> float:
    """Calls per second of ``fn`` (best of 3 timed runs of at least ``min_time`` / 3 s each)."""
    fn()  # warm-up (numba JIT, caches)
    best = 0.0
    now = CLOCK["now"]
    for _ in range(3):
        n, t0 = 0, now()
        while True:
            fn()
            n += 1
            dt = now() - t0
            if dt >= min_time / 3:
                break
        best = max(best, n / dt)
    return best


def rate_batched(fn: Callable[[], object], min_time: float, batch_time: float = 2e-3) -> float:
    """:func:`rate` with the clock read once per batch of calls (~``batch_time`` s each) instead of after
    every call: reading the CPU clock (``--clock cpu``) is a system call on these VMs, ~1.4 us, which the
    per-call loop counted as part of a ~11 us one-robot scan (wall clock ~0.2 us). Slow calls (the naive
    loop) get batches of one, as :func:`rate`."""
    fn()  # warm-up (numba JIT, caches)
    t0 = time.perf_counter()
    fn()
    batch = max(1, min(1000, int(batch_time / max(time.perf_counter() - t0, 1e-7))))
    if batch == 1:
        return rate(fn, min_time)

    def calls() -> None:
        for _ in range(batch):
            fn()

    return rate(calls, min_time) * batch


def interleaved_samples(
    fns: dict[str, Callable[[], object]], min_time: float, rounds: int = 9
) -> dict[str, list[float]]:
    """Calls per second of each of ``fns`` in each of ``rounds`` round-robin blocks of at least
    ``min_time / rounds`` s each (one list per function, in round order). A change in the machine's speed
    during the run (other jobs, clock) then hits every function alike, so their ratios hold: timing them one
    after the other, minutes apart, moved the envs' detector-on / off ratios by 10-30 points between runs."""
    for fn in fns.values():
        fn()  # warm-up (numba JIT, caches)
    now = CLOCK["now"]
    samples: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            n, t0 = 0, now()
            while True:
                fn()
                n += 1
                dt = now() - t0
                if dt >= min_time / rounds:
                    break
            samples[k].append(n / dt)
    return samples


def rates_interleaved(
    fns: dict[str, Callable[[], object]], min_time: float, rounds: int = 9
) -> dict[str, float]:
    """The median block's calls per second of each of ``fns`` (:func:`interleaved_samples`)."""
    return {k: float(np.median(v)) for k, v in interleaved_samples(fns, min_time, rounds).items()}


def paired_ratio(num: list[float], den: list[float], confidence: float = 0.95) -> tuple[float, float, float]:
    """The median over rounds of ``num[i] / den[i]`` (two functions' rates timed in the same round of
    :func:`interleaved_samples`, seconds apart) and its percentile-bootstrap interval (scipy), as
    ``(median, low, high)``. Pairing by round cancels the machine's slow phases that outlast a round,
    which the ratio of the two medians (:func:`rates_interleaved`) does not; the percentile interval of a
    median stays inside the observed ratios."""
    from scipy import stats

    r = np.asarray(num, dtype=float) / np.asarray(den, dtype=float)
    med = float(np.median(r))
    if r.size < 3 or np.ptp(r) == 0:
        return med, med, med
    with warnings.catch_warnings():  # (scipy >= 1.15 renames random_state; the base install allows 1.10)
        warnings.simplefilter("ignore")
        res = stats.bootstrap((r,), np.median, confidence_level=confidence, n_resamples=2000,
                              method="percentile", random_state=np.random.default_rng(0))  # fmt: skip
    return med, float(res.confidence_interval.low), float(res.confidence_interval.high)


def naive_scan(world: World, robot: int) -> np.ndarray:
    """The baseline: one pymunk ``segment_query_first`` per beam, in a Python loop."""
    import pymunk

    spec = world.scene.lidar
    x, y, th = world.poses[robot]
    flt = pymunk.ShapeFilter(
        group=robot + 1, categories=LIDAR_QUERY_FILTER.categories, mask=LIDAR_QUERY_FILTER.mask
    )
    out = np.full(spec.n_beams, spec.range_max)
    for i, a in enumerate(spec.angles):
        end = (x + spec.range_max * math.cos(th + a), y + spec.range_max * math.sin(th + a))
        info = world.space.segment_query_first((x, y), end, 0.0, flt)
        if info is not None:
            out[i] = info.alpha * spec.range_max
    return out


def bench_lidar(min_time: float, robots=(1, 8, 64, 256)) -> list[dict]:
    rows = []
    for n in robots:
        scene = scenes.random_arena(n, 50, seed=0, size=10.0)
        world = World(scene, seed=0)
        fast = rate_batched(world.scan, min_time) * n
        k = min(n, 4)  # the naive loop is slow: time a few robots' scans
        naive = rate(lambda w=world, k=k: [naive_scan(w, i) for i in range(k)], min_time) * k
        cmd = np.tile([0.2, 0.5], (n, 1))
        steps = rate(lambda w=world, c=cmd: w.step(commands=c), min_time)
        rows.append(
            {
                "robots": n,
                "scans_per_s": fast,
                "naive_scans_per_s": naive,
                "ratio": fast / naive,
                "physics_steps_per_s": steps,
            }
        )
        print(
            f"  lidar N={n:4d}: {fast:10.0f} scans/s  naive {naive:7.0f}  x{fast / naive:6.1f}  "
            f"world.step {steps:8.1f}/s",
            flush=True,
        )
    return rows


#: objects (robots + obstacles) per m^2 of the scaling section's arenas
SCALING_DENSITY = 0.7


def scaling_arena_side(n_robots: int, n_obstacles: int) -> float:
    """Side of the square arena holding ``n_robots + n_obstacles`` objects at ``SCALING_DENSITY``, m."""
    return max(5.0, math.sqrt((n_robots + n_obstacles) / SCALING_DENSITY))


def bench_lidar_scaling(
    min_time: float, robots=(1, 16, 64, 256), obstacles=(10, 100, 1000)
) -> tuple[list[dict], dict]:
    """Robot-scans/s of the grid kernel, the brute-force kernel and the naive pymunk loop."""
    from tqdm import tqdm

    from kin_envs.core.world import WorldConfig

    brute_cfg, grid_cfg = WorldConfig(lidar_grid=False), WorldConfig(lidar_grid=True)
    # first calls compile the kernels (or load numba's cache): timed apart from the rates
    t0 = time.perf_counter()
    World(scenes.random_arena(2, 3, seed=0, size=5.0), seed=0, config=grid_cfg).scan()
    t1 = time.perf_counter()
    World(scenes.random_arena(2, 3, seed=0, size=5.0), seed=0, config=brute_cfg).scan()
    startup = {"grid_first_scan_s": t1 - t0, "brute_force_first_scan_s": time.perf_counter() - t1}
    print(f"  first scan (compile or cache load): grid {startup['grid_first_scan_s']:.2f} s, "
          f"brute force {startup['brute_force_first_scan_s']:.2f} s", flush=True)  # fmt: skip
    rows = []
    for n_obs in obstacles:
        for n in tqdm(robots, desc=f"lidar scaling, {n_obs} obstacles", leave=False):
            side = scaling_arena_side(n, n_obs)
            scene = scenes.random_arena(n, n_obs, seed=0, size=side)
            t = time.perf_counter()
            world = World(scene, seed=0, config=grid_cfg)
            build = time.perf_counter() - t
            brute = World(scene, seed=0, config=brute_cfg)
            uses_grid = World(scene, seed=0)._lidar_grid is not None  # the default's choice
            grid_rate = rate_batched(world.scan, min_time) * n
            brute_rate = rate_batched(brute.scan, min_time) * n
            k = min(n, 2)  # the naive loop is slow: time a few robots' scans
            naive = rate(lambda w=world, k=k: [naive_scan(w, i) for i in range(k)], min_time / 2) * k
            g = world._lidar_grid
            rows.append(
                {
                    "robots": n,
                    "obstacles": n_obs,
                    "arena_m": side,
                    "cell_m": g.cell_size,
                    "grid_scans_per_s": grid_rate,
                    "brute_force_scans_per_s": brute_rate,
                    "naive_scans_per_s": naive,
                    "grid_vs_brute_force": grid_rate / brute_rate,
                    "grid_vs_naive": grid_rate / naive,
                    "default": "grid" if uses_grid else "brute force",
                    "default_scans_per_s": grid_rate if uses_grid else brute_rate,
                    "default_vs_naive": (grid_rate if uses_grid else brute_rate) / naive,
                    "world_build_s": build,
                }
            )
            print(
                f"  {n:4d} robots {n_obs:5d} obstacles {side:5.1f} m: grid {grid_rate:9.0f} scans/s, "
                f"brute force {brute_rate:9.0f} (x{grid_rate / brute_rate:.2f}), naive {naive:6.0f} "
                f"(grid x{grid_rate / naive:.0f}), build {build:.2f} s, default: {rows[-1]['default']} "
                f"(x{rows[-1]['default_vs_naive']:.0f} the naive loop)",
                flush=True,
            )
    return rows, startup


def scaling_targets(rows: list[dict]) -> dict:
    """The issue's lidar targets on the default kernel choice (only the pairs that were measured)."""
    cost = {(r["robots"], r["obstacles"]): 1.0 / r["default_scans_per_s"] for r in rows}
    out: dict = {}
    if (64, 1000) in cost and (64, 100) in cost:
        out["cost_1000_vs_100_obstacles_64_robots"] = cost[64, 1000] / cost[64, 100]  # target <= 2
    for n_obs in sorted({o for _, o in cost}):
        if (256, n_obs) in cost and (64, n_obs) in cost:
            out[f"cost_256_vs_64_robots_{n_obs}_obstacles"] = cost[256, n_obs] / cost[64, n_obs]  # <= 1.5
    out["min_default_vs_naive"] = (
        min(r["default_scans_per_s"] / r["naive_scans_per_s"] for r in rows) if rows else None
    )  # >= 100
    return out
def _importable(module: str) -> bool:
    """Whether ``module`` can be imported (without importing it)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _reference_detectors():
    """The pre-array-first implementations (tests/detectors/reference_detectors.py), or None
    outside a clone."""
    root = Path(__file__).resolve().parents[1]
    if not (root / "tests" / "detectors" / "reference_detectors.py").is_file():
        return None
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    from tests.detectors import reference_detectors

    return reference_detectors


def dense_arena_scans(n_robots: int = 64, n_obstacles: int = 50, noise: float = 0.01):
    """Every robot's scan in a dense random arena (10 x 10 m), 1 % range noise: ``(ranges, angles)``."""
    from kin_envs.core.lidar import LidarSpec

    scene = scenes.random_arena(n_robots, n_obstacles, seed=1).replace(lidar=LidarSpec(noise_sigma=noise))
    scan = World(scene, seed=0).scan()
    return np.ascontiguousarray(scan.ranges, dtype=np.float64), scan.angles


def kin_seek_scans(n: int = 32, noise: float = 0.01):
    """``n`` learner scans of ``KinSeek-v2`` episodes (seeds 0..n-1, 1 % noise) as the env's lidar gives
    them (float32 ``(1, n_beams)`` rows, the lidar's ``angles`` array): what a single-agent env's
    detector sees each step (~30-40 segments, against ~100 in the dense arena)."""
    import gymnasium as gym

    env = gym.make("kin_envs/KinSeek-v2", detector=None, noise_sigma=noise)
    rows = []
    for seed in range(n):
        env.reset(seed=seed)
        rows.append(env.unwrapped._last_scan.ranges[:1].copy())
    angles = env.unwrapped._last_scan.angles
    env.close()
    return rows, angles


def bench_detector(min_time: float) -> list[dict]:
    """Batched detection on one core: every scan of the dense 64-robot arena in one call.

    Rows: each detector's array path (``detect_arrays``), its objects (``detect_batch`` without
    and with per-segment reports) and the previous implementation (same run), plus a single scan
    per call (what a single-agent env does). Start-up (construction + first call: numba compiles
    on the first run after an install, later runs load its cache) is timed apart.
    """
    from detectors import GeometricKinDetector
    from kin_envs.envs.common import detection_arrays

    ref = _reference_detectors()
    ranges, angles = dense_arena_scans()
    seek_rows, seek_angles = kin_seek_scans()
    n = ranges.shape[0]
    variants: dict[str, Callable[[], object]] = {"geometric": GeometricKinDetector}
    has_torch = _importable("torch")
    try:
        from detectors.learned import LearnedKinDetector

        # the default (inference="auto": the compiled network inside the fused driver; pre-gate and
        # cascade on), then each inference path alone (BLAS and torch where their packages are
        # installed: the base install runs the learned detector without them), the pre-gate off and
        # the cascade off
        variants["learned (default)"] = LearnedKinDetector
        if _importable("threadpoolctl"):
            variants["learned (blas)"] = lambda: LearnedKinDetector(inference="blas")
        variants["learned (numba)"] = lambda: LearnedKinDetector(inference="numba")
        if has_torch:
            variants["learned (torch, 1 thread)"] = lambda: LearnedKinDetector(inference="torch")
        variants["learned (default, no pre-gate)"] = lambda: LearnedKinDetector(pre_gate=False)
        variants["learned (default, no cascade)"] = lambda: LearnedKinDetector(cascade=False)
    except ImportError as e:
        print(f"  learned detector skipped ({e})")
    rows = []
    for name, make in variants.items():
        t0 = time.perf_counter()
        det = make()
        det.detect_arrays(ranges[:1], angles)
        startup = time.perf_counter() - t0
        row = {"detector": name, "scans": n, "startup_s": startup}
        row["arrays"] = rate(lambda d=det: d.detect_arrays(ranges, angles), min_time) * n
        det.reports = False
        row["objects"] = rate(lambda d=det: d.detect_batch(ranges, angles), min_time) * n
        det.reports = True  # reports are built on first access: read them all
        row["objects_reports"] = (
            rate(lambda d=det: [r.reports for r in d.detect_batch(ranges, angles)], min_time) * n
        )
        row["single_scan"] = rate(lambda d=det: d.detect_arrays(ranges[:1], angles), min_time)
        # a KinSeek learner scan per call, through the public API and through the env's own entry
        # (kin_envs.envs.common.detection_arrays, trusted: no per-call input checks)
        n_seek = len(seek_rows)
        row["kinseek_scan"] = n_seek * rate(
            lambda d=det: [d.detect_arrays(r, seek_angles) for r in seek_rows], min_time
        )
        row["kinseek_env"] = n_seek * rate(
            lambda d=det: [detection_arrays(d, r, seek_angles, trusted=True) for r in seek_rows], min_time
        )
        row["old"] = math.nan
        if ref is not None and name == "geometric":
            old = ref.ReferenceGeometricKinDetector(reports=False)
            row["old"] = rate(lambda d=old: d.detect_batch(ranges, angles), min_time) * n
        elif ref is not None and has_torch and name in ("learned (default)", "learned (torch, 1 thread)"):
            row["old"] = rate(lambda d=det: ref.reference_learned_predict(d, ranges, angles), min_time) * n
        row["speed_up"] = row["arrays"] / row["old"]
        rows.append(row)
        print(
            f"  {name:30s} {row['arrays']:9.0f} scans/s arrays, {row['objects']:9.0f} objects, "
            f"{row['objects_reports']:8.0f} with reports, old {row['old']:7.0f} (x{row['speed_up']:.1f}); "
            f"single scan {row['single_scan']:7.0f}/s; KinSeek scan {row['kinseek_scan']:7.0f}/s "
            f"(env entry {row['kinseek_env']:7.0f}/s); start-up {startup:.2f} s",
            flush=True,
        )
    return rows


def _agg_step(n: int, detector) -> Callable[[], None]:
    from kin_envs import aggregation_v2

    penv = aggregation_v2.parallel_env(n_robots=n, detector=detector, noise_sigma=0.01)
    penv.reset(seed=0)
    acts = {a: penv.action_space(a).sample() for a in penv.agents}

    def step_agg(penv=penv, acts=acts):
        _, _, _, trunc, _ = penv.step(acts)
        if any(trunc.values()):
            penv.reset()

    return step_agg


def _seek_step(detector) -> Callable[[], None]:
    import gymnasium as gym

    env = gym.make("kin_envs/KinSeek-v2", detector=detector, noise_sigma=0.01)
    env.reset(seed=0)

    def step_seek(env=env):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()

    return step_seek


def bench_envs(min_time: float, robots=(16, 64, 256)) -> list[dict]:
    """Env steps/s with the detector off / geometric / learned, as a user gets them: no thread
    settings by the caller (torch left at its default), 1 % range noise. The detector settings of one env
    are timed interleaved (:func:`rates_interleaved`), so each ratio to detector-off is measured in the same
    stretch of time."""
    try:
        import gymnasium  # noqa: F401
    except ImportError as e:  # pragma: no cover - before the envs exist
        print(f"  envs: skipped ({e})")
        return []
    try:
        import detectors.learned  # noqa: F401

        dets = (None, "geometric", "learned")
    except ImportError:
        dets = (None, "geometric")
    rows = []
    for env_id, n in [("KinSeek-v2", 1)] + [("aggregation_v2", n) for n in robots]:
        steps = {str(d): (_seek_step(d) if env_id == "KinSeek-v2" else _agg_step(n, d)) for d in dets}
        samples = interleaved_samples(steps, min_time * len(dets))
        rates = {k: float(np.median(v)) for k, v in samples.items()}
        for d in dets:
            r = rates[str(d)]
            paired, lo, hi = paired_ratio(samples[str(d)], samples["None"])
            rows.append({"env": env_id, "robots": n, "detector": str(d), "steps_per_s": r,
                         "of_detector_off": r / rates["None"], "of_detector_off_paired": paired,
                         "of_detector_off_paired_ci": [lo, hi]})
            print(f"  {env_id} N={n:3d} detector={d!s:9s} {r:8.1f} steps/s ({r / rates['None']:.0%} of off; "
                  f"paired by round {paired:.0%} [{lo:.0%}, {hi:.0%}])", flush=True)
        del steps  # free the 256-robot worlds before the next size
    return rows


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def bench_memory(min_time: float, steps: int = 2000, n_robots: int = 256) -> list[dict]:
    """Resident memory over ``steps`` steps of a 256-robot swarm with the learned detector (1 %
    noise): RSS after 10 % of the steps (warm), at half-time and at the end, and the process's peak RSS.

    ``growth_mb`` is the second half's (end - half-time): the first half still settles (the allocator's
    pools fill, every truncation rebuilds the world), by ~+5-10 MB at 256 robots; a leak grows in both
    halves. ``settle_mb`` is the first half's (half-time - warm)."""
    import resource

    from kin_envs import aggregation_v2

    try:
        import detectors.learned  # noqa: F401
    except ImportError as e:
        print(f"  memory: skipped ({e})")
        return []
    penv = aggregation_v2.parallel_env(n_robots=n_robots, detector="learned", noise_sigma=0.01)
    penv.reset(seed=0)
    rng = np.random.default_rng(0)
    warm_at, half_at = max(1, steps // 10), max(1, steps // 2)
    rss_warm = rss_half = math.nan
    t0 = time.perf_counter()
    for t in range(1, steps + 1):
        acts = {a: rng.uniform(-1, 1, penv.action_space(a).shape).astype(np.float32) for a in penv.agents}
        _, _, _, trunc, _ = penv.step(acts)
        if any(trunc.values()):
            penv.reset()
        if t == warm_at:
            rss_warm = _rss_mb()
        if t == half_at:
            rss_half = _rss_mb()
    seconds = time.perf_counter() - t0
    row = {
        "robots": n_robots,
        "steps": steps,
        "rss_warm_mb": rss_warm,
        "rss_half_mb": rss_half,
        "rss_end_mb": _rss_mb(),
        # ru_maxrss is in KiB on Linux
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "steps_per_s": steps / seconds,
    }
    row["settle_mb"] = row["rss_half_mb"] - row["rss_warm_mb"]
    row["growth_mb"] = row["rss_end_mb"] - row["rss_half_mb"]
    print(
        f"  memory N={n_robots} learned, {steps} steps: RSS {rss_warm:.0f} MB after {warm_at} steps, "
        f"{rss_half:.0f} MB after {half_at} (settling {row['settle_mb']:+.1f} MB), "
        f"{row['rss_end_mb']:.0f} MB at the end (second half's growth {row['growth_mb']:+.1f} MB), "
        f"peak {row['peak_rss_mb']:.0f} MB",
        flush=True,
    )
    return [row]


def bench_vecenv(min_time: float, num_envs: int = 64, detectors=("none", "geometric"),
                 steps: int = 300, chunk: int = 25, noises=(0.0, 0.01)) -> list[dict]:
    """Native vector env vs SyncVectorEnv, K sub-envs each, constant random actions, at each relative range
    noise sigma of ``noises`` (0 = KinSeek's default; 1 % as in the ``envs`` section); env-steps/s = K x
    vector steps/s over ``steps`` vector steps each (300 = KinSeek's episode: every sub-env that runs to
    its time limit autoresets once inside the window, so resets are counted as a user pays them). The
    two are stepped round robin, ``chunk`` steps at a time: timed one after the other on a shared
    machine, their ratio moved by 2x between runs. (``min_time`` is unused: the window is in steps.)"""
    import gymnasium as gym

    import kin_envs  # noqa: F401  (registers the ids)

    now = CLOCK["now"]
    rows = []
    for noise, det in itertools.product(noises, detectors):
        envs, fns = {}, {}
        for mode in ("vector_entry_point", "sync"):
            env = gym.make_vec("kin_envs/KinSeek-v2", num_envs=num_envs, vectorization_mode=mode,
                               detector=None if det == "none" else det, noise_sigma=noise)
            env.reset(seed=0)
            env.action_space.seed(0)
            envs[mode] = env
            actions = env.action_space.sample()
            fns[mode] = lambda env=env, a=actions: env.step(a)
            fns[mode]()  # warm-up (numba JIT, caches)
        spent = dict.fromkeys(fns, 0.0)
        done = 0
        while done < steps:
            n = min(chunk, steps - done)
            for mode, fn in fns.items():
                t0 = now()
                for _ in range(n):
                    fn()
                spent[mode] += now() - t0
            done += n
        rates = {k: steps * num_envs / spent[k] for k in fns}
        for env in envs.values():
            env.close()
        row = {"env": "KinSeek-v2", "num_envs": num_envs, "detector": det, "noise": noise,
               "native_env_steps_per_s": rates["vector_entry_point"],
               "sync_env_steps_per_s": rates["sync"],
               "ratio": rates["vector_entry_point"] / rates["sync"]}
        rows.append(row)
        print(f"  KinSeek-v2 x{num_envs} detector={det:9s} noise={noise:g} "
              f"native {row['native_env_steps_per_s']:8.0f} "
              f"env-steps/s, SyncVectorEnv {row['sync_env_steps_per_s']:7.0f}: {row['ratio']:.1f}x",
              flush=True)
    return rows


def bench_ros(min_time: float, steps: int = 100) -> list[dict]:
    try:
        from detectors.ros import read_scans
        from kin_envs.ros import WorldRecorder
    except ImportError as e:  # pragma: no cover - without the extra
        print(f"  ros: skipped ({e})")
        return []
    import tempfile

    from detectors import GeometricKinDetector

    scene = scenes.random_arena(8, 20, seed=3)
    cmds = np.tile([0.1, 0.5], (8, 1))

    def run(rec=None, n=steps):
        world = World(scene, seed=0)
        t0 = time.perf_counter()
        for _ in range(n):
            world.step(commands=cmds)
            scan = world.scan()
            if rec is not None:
                rec.record(world, scan)
        return time.perf_counter() - t0

    det = GeometricKinDetector()
    base = steps / min(run() for _ in range(3))
    out = []
    with tempfile.TemporaryDirectory() as d:
        for storage, name in (("mcap", "m"), ("sqlite3", "s"), ("ros1", "r.bag")):
            path = Path(d) / name
            with WorldRecorder(Path(d) / ("warm" + name), storage=storage) as rec:
                run(rec, 5)  # warm-up: imports, serialiser compilation
            with WorldRecorder(path, storage=storage) as rec:
                rec_rate = steps / run(rec)
            t0 = time.perf_counter()
            it = read_scans(path, "/robot_0/scan")
            first = next(it)  # opening parses every connection's message definition
            t_open = time.perf_counter() - t0
            t0 = time.perf_counter()
            scans = [first, *it]
            read_rate = (len(scans) - 1) / (time.perf_counter() - t0)
            def detect_all(s=scans):
                return [det.detect(x.ranges, x.angles) for x in s]

            det_rate = len(scans) * rate(detect_all, min_time)
            print(
                f"  {storage:7s}: record {rec_rate:7.1f} steps/s (unrecorded {base:7.1f}), open "
                f"{t_open:.2f} s, read {read_rate:7.0f} scans/s (geometric detector {det_rate:7.0f} scans/s)"
            )
            out.append(
                {
                    "storage": storage,
                    "robots": 8,
                    "steps": steps,
                    "record_steps_per_s": rec_rate,
                    "unrecorded_steps_per_s": base,
                    "open_s": t_open,
                    "read_scans_per_s": read_rate,
                    "detect_scans_per_s": det_rate,
                }
            )
    return out


SECTIONS = {
    "lidar": bench_lidar,
    "lidar_scaling": bench_lidar_scaling,
    "detector": bench_detector,
    "envs": bench_envs,
    "memory": bench_memory,
    "ros": bench_ros,
    "vecenv": bench_vecenv,
}


def to_markdown(results: dict) -> str:
    lines = []
    if results.get("lidar"):
        lines += [
            "| robots | scans/s (vectorised) | scans/s (naive pymunk loop) | ratio | world.step/s |",
            "|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['robots']} | {r['scans_per_s']:,.0f} | {r['naive_scans_per_s']:,.0f} | "
            f"{r['ratio']:.0f}x | {r['physics_steps_per_s']:,.0f} |"
            for r in results["lidar"]
        ]
        lines.append("")
    if results.get("lidar_scaling"):
        lines += [
            "| robots | obstacles | arena (m) | grid scans/s | brute-force kernel | naive pymunk "
            "| grid / brute force | default | default / naive | world build (s) |",
            "|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|",
        ]
        lines += [
            f"| {r['robots']} | {r['obstacles']:,} | {r['arena_m']:.1f} | "
            f"{r['grid_scans_per_s']:,.0f} | {r['brute_force_scans_per_s']:,.0f} | "
            f"{r['naive_scans_per_s']:,.0f} | "
            f"{r['grid_vs_brute_force']:.2f}x | {r['default']} | "
            f"{r.get('default_vs_naive', r['default_scans_per_s'] / r['naive_scans_per_s']):,.0f}x | "
            f"{r['world_build_s']:.2f} |"
            for r in results["lidar_scaling"]
        ]
        lines.append("")
        for k, v in results.get("lidar_scaling_targets", {}).items():
            lines.append(f"- {k}: {v:.2f}")
        st = results.get("lidar_scaling_startup")
        if st:
            lines.append(
                f"- first scan (compile or cache load): grid {st['grid_first_scan_s']:.2f} s, "
                f"brute force {st['brute_force_first_scan_s']:.2f} s"
            )
        lines.append("")
    if results.get("detector"):
        n = results["detector"][0]["scans"]
        lines += [
            f"Detectors, {n} scans of a dense arena (64 robots, 50 obstacles, 1 % noise) per call, "
            f"one core, warm, {results.get('config', {}).get('clock', 'wall')} clock:",
            "",
            "| detector | scans/s detect_arrays | detect_batch (objects) | with reports | previous "
            "implementation | speed-up | single scan calls/s | KinSeek scan calls/s | KinSeek env entry |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['detector']} | {r['arrays']:,.0f} | {r['objects']:,.0f} | {r['objects_reports']:,.0f} | "
            + (f"{r['old']:,.0f} | {r['speed_up']:.1f}x" if math.isfinite(r["old"]) else "— | —")
            + f" | {r['single_scan']:,.0f} | {r.get('kinseek_scan', math.nan):,.0f} "
            f"| {r.get('kinseek_env', math.nan):,.0f} |"
            for r in results["detector"]
        ]
        lines += [
            "",
            "Single scan: one scan of the dense arena (~110 segments); KinSeek scan: a KinSeek-v2 learner "
            "scan (~30-40 segments) per call through `detect_arrays`, and through the env's own entry "
            "(`kin_envs.envs.common.detection_arrays(trusted=True)`, no per-call input checks).",
        ]
        lines += [
            "",
            "Start-up (construction + first call; numba compiles on the first run after an install): "
            + ", ".join(f"{r['detector']} {r['startup_s']:.2f} s" for r in results["detector"]),
            "",
        ]
    if results.get("envs"):
        lines += [
            "Env steps/s as a user gets them (no thread settings), 1 % noise, "
            f"{results.get('config', {}).get('clock', 'wall')} clock; an env's detector settings timed "
            "interleaved (median of 9 blocks each); \"of detector off\" is the ratio of the two medians, "
            "\"paired\" the median of the 9 rounds' own ratios with its 95 % percentile-bootstrap interval "
            "(scipy; a round's blocks run seconds apart, so the machine's slow phases cancel):",
            "",
            "| env | robots | detector | steps/s | of detector off | paired by round [95 % CI] |",
            "|---|---:|---|---:|---:|---:|",
        ]
        lines += [
            f"| {r['env']} | {r['robots']} | {r['detector']} | {r['steps_per_s']:,.1f} | "
            f"{r['of_detector_off']:.0%} | {r['of_detector_off_paired']:.0%} "
            f"[{r['of_detector_off_paired_ci'][0]:.0%}, {r['of_detector_off_paired_ci'][1]:.0%}] |"
            for r in results["envs"]
        ]
        lines.append("")
    if results.get("memory"):
        lines += [
            "| memory: robots, learned detector | steps | RSS warm (MB) | half-time (MB) | end (MB) | "
            "growth, second half (MB) | peak RSS (MB) |",
            "|---:|---:|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['robots']} | {r['steps']} | {r['rss_warm_mb']:.0f} | {r['rss_half_mb']:.0f} | "
            f"{r['rss_end_mb']:.0f} | {r['growth_mb']:+.1f} | {r['peak_rss_mb']:.0f} |"
            for r in results["memory"]
        ]
        lines.append("")
    if results.get("ros"):
        lines += [
            "| bag | record steps/s (8 robots) | unrecorded | open, s | read scans/s | geometric scans/s |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['storage']} | {r['record_steps_per_s']:,.1f} | {r['unrecorded_steps_per_s']:,.1f} | "
            f"{r['open_s']:.2f} | {r['read_scans_per_s']:,.0f} | {r['detect_scans_per_s']:,.0f} |"
            for r in results["ros"]
        ]
        lines.append("")
    if results.get("vecenv"):
        lines += [
            "| env | sub-envs | detector | range noise | native vector env, env-steps/s | SyncVectorEnv "
            "| ratio |",
            "|---|---:|---|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {r['env']} | {r['num_envs']} | {r['detector']} | {r.get('noise', 0.0):.1%} | "
            f"{r['native_env_steps_per_s']:,.0f} | "
            f"{r['sync_env_steps_per_s']:,.0f} | {r['ratio']:.1f}x |"
            for r in results["vecenv"]
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sections", default=",".join(SECTIONS), help="comma-separated: " + ", ".join(SECTIONS))
    p.add_argument("--min-time", type=float, default=1.5, help="seconds of timing per measurement")
    p.add_argument("--robots", type=int, nargs="+", default=[1, 8, 64, 256], help="lidar: robot counts")
    p.add_argument(
        "--scaling-robots", type=int, nargs="+", default=[1, 16, 64, 256], help="lidar_scaling: robot counts"
    )
    p.add_argument(
        "--scaling-obstacles",
        type=int,
        nargs="+",
        default=[10, 100, 1000],
        help="lidar_scaling: obstacle counts",
    )
    p.add_argument(
        "--env-robots", type=int, nargs="+", default=[16, 64, 256], help="envs: aggregation_v2 robot counts"
    )
    p.add_argument(
        "--memory-steps", type=int, default=2000, help="memory: steps of the 256-robot learned-detector swarm"
    )
    p.add_argument("--memory-robots", type=int, default=256, help="memory: robots in the swarm")
    p.add_argument("--vec-envs", type=int, default=64, help="vecenv: number of sub-envs K")
    p.add_argument("--vec-steps", type=int, default=300,
                   help="vecenv: vector steps timed per env (300 = one KinSeek episode, autoresets included)")
    p.add_argument("--vec-detectors", nargs="+", default=["none", "geometric"],
                   choices=["none", "geometric", "learned"], help="vecenv: detectors to time")
    p.add_argument("--vec-noise", type=float, nargs="+", default=[0.0, 0.01],
                   help="vecenv: relative range noise sigmas of the sub-envs (0 = KinSeek's default; "
                   "1 %% as in the envs section)")
    p.add_argument(
        "--clock", choices=["wall", "cpu"], default="wall",
        help="rates from wall time (default) or from this process's CPU time (a shared machine: time "
        "spent waiting for a core is not counted; every timed path here runs on one thread)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("outputs/benchmark"), help="output directory")
    add_logging_args(p)
    args = p.parse_args(argv)
    setup_logging(args)
    CLOCK["now"] = time.process_time if args.clock == "cpu" else time.perf_counter
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        p.error(f"unknown section(s) {unknown}; expected some of {sorted(SECTIONS)}")
    # each bad option named with its value (one message for four options named none of them)
    for bad, opt, want, got in (
        (not args.min_time > 0, "--min-time", "> 0 s", args.min_time),
        (min(args.robots) < 1, "--robots", ">= 1", args.robots),
        (min(args.env_robots) < 2, "--env-robots", ">= 2", args.env_robots),
        (args.memory_steps < 1, "--memory-steps", ">= 1", args.memory_steps),
        (min(args.scaling_robots) < 1, "--scaling-robots", ">= 1", args.scaling_robots),
        (min(args.scaling_obstacles) < 0, "--scaling-obstacles", ">= 0", args.scaling_obstacles),
    ):
        if bad:
            p.error(f"{opt} must be {want}, got {got}")
    if not 2 <= args.memory_robots <= 256:
        p.error(f"--memory-robots must be in 2..256, got {args.memory_robots}")
    if args.vec_envs < 1:
        p.error(f"--vec-envs must be >= 1, got {args.vec_envs}")
    if args.vec_steps < 1:
        p.error(f"--vec-steps must be >= 1, got {args.vec_steps}")
    for v in args.vec_noise:
        if not 0.0 <= v < 1.0:
            p.error(f"--vec-noise values must be in [0, 1), got {v}")
    from detectors.fileio import write_json, write_text
    from kin_envs.cli import check_output_dir

    try:  # before the timings: an unwritable --out must not cost a whole run
        check_output_dir(args.out)
    except ValueError as e:
        p.error(str(e))
    results: dict = {
        "config": {
            "command": " ".join([sys.executable, *sys.argv]),
            "sections": sections,
            "clock": args.clock,
            "min_time": args.min_time,
            "robots": args.robots,
            "scaling_robots": args.scaling_robots,
            "scaling_obstacles": args.scaling_obstacles,
            "scaling_density_per_m2": SCALING_DENSITY,
            "env_robots": args.env_robots,
            "memory_steps": args.memory_steps,
            "memory_robots": args.memory_robots,
            "vec_envs": args.vec_envs,
            "vec_steps": args.vec_steps,
            "vec_detectors": args.vec_detectors,
            "vec_noise": args.vec_noise,
            "python": platform.python_version(),
            "machine": platform.machine(),
        }
    }
    for s in sections:
        print(f"[{s}]", flush=True)
        if s == "lidar_scaling":
            rows, startup = bench_lidar_scaling(args.min_time, args.scaling_robots, args.scaling_obstacles)
            results[s] = rows
            results["lidar_scaling_startup"] = startup
            results["lidar_scaling_targets"] = scaling_targets(rows)
            continue
        if s == "lidar":
            results[s] = SECTIONS[s](args.min_time, robots=args.robots)
        elif s == "envs":
            results[s] = SECTIONS[s](args.min_time, robots=args.env_robots)
        elif s == "memory":
            results[s] = SECTIONS[s](args.min_time, steps=args.memory_steps, n_robots=args.memory_robots)
        elif s == "vecenv":
            results[s] = SECTIONS[s](args.min_time, args.vec_envs, args.vec_detectors, args.vec_steps,
                                      noises=tuple(args.vec_noise))
        else:
            results[s] = SECTIONS[s](args.min_time)
    md = to_markdown(results)
    write_text(args.out / "benchmark.md", md)
    write_json(args.out / "benchmark.json", results)
    write_run_info(args.out, args, config=results["config"], argv=argv, script=__file__)  # last
    print("\n" + md)
    print(f"wrote {args.out / 'benchmark.json'} and {args.out / 'benchmark.md'}")
    return results


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
