"""scripts/benchmark.py runs end to end on tiny budgets (speed targets are checked by running it)."""

import json

import pytest

from tests.scripts.helpers import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("benchmark")


def test_lidar_and_detector_sections(bench, tmp_path):
    res = bench.main(
        ["--sections", "lidar,detector", "--min-time", "0.03", "--robots", "1", "4", "--out", str(tmp_path)]
    )
    assert [r["robots"] for r in res["lidar"]] == [1, 4]
    for r in res["lidar"]:
        assert r["scans_per_s"] > 0 and r["naive_scans_per_s"] > 0
        assert r["ratio"] == pytest.approx(r["scans_per_s"] / r["naive_scans_per_s"])
    geo = res["detector"][0]
    assert geo["detector"] == "geometric" and geo["scans"] == 64
    for k in ("arrays", "objects", "objects_reports", "old", "single_scan", "startup_s"):
        assert geo[k] > 0, k
    saved = json.loads((tmp_path / "benchmark.json").read_text())
    assert saved["config"]["robots"] == [1, 4]
    md = (tmp_path / "benchmark.md").read_text()
    assert "| robots |" in md and "previous implementation" in md and "Start-up" in md
    assert saved["config"]["clock"] == "wall" and "wall clock" in md
    if len(res["detector"]) > 1:  # with torch: the learned variants, the default first
        names = [r["detector"] for r in res["detector"]]
        assert names[1] == "learned (default)" and "learned (default, no pre-gate)" in names
        assert all(r["arrays"] > 0 and r["single_scan"] > 0 for r in res["detector"])
    # the KinSeek-scan rows (public API and the env's trusted entry), for every detector
    assert all(r["kinseek_scan"] > 0 and r["kinseek_env"] > 0 for r in res["detector"])
    assert "KinSeek scan calls/s" in (tmp_path / "benchmark.md").read_text()


def test_cpu_clock(bench, tmp_path):
    argv = ["--sections", "detector", "--min-time", "0.03", "--clock", "cpu"]
    res = bench.main([*argv, "--out", str(tmp_path)])
    assert res["config"]["clock"] == "cpu" and res["detector"][0]["arrays"] > 0
    assert "cpu clock" in (tmp_path / "benchmark.md").read_text()


def test_rates_interleaved_alternates_the_functions(bench):
    calls = []
    fns = {k: (lambda k=k: calls.append(k)) for k in ("off", "on")}
    rates = bench.rates_interleaved(fns, min_time=0.006, rounds=3)
    assert set(rates) == {"off", "on"} and all(r > 0 for r in rates.values())
    # one warm-up call each, then three blocks of each in turn: off, on, off, on, off, on
    blocks = [k for i, k in enumerate(calls[2:]) if i == 0 or calls[2:][i - 1] != k]
    assert calls[:2] == ["off", "on"] and blocks == ["off", "on"] * 3


def test_rate_batched_reads_the_clock_once_per_batch(bench, monkeypatch):
    """A fast call is timed in batches (the clock, a system call for CPU time, is not counted as its cost):
    with a clock that advances only when read, a per-call loop reports far fewer calls per second than
    there are; the batched one reads it once per batch and reports the calls made. A slow call is timed as
    rate times it."""
    reads, calls = [], []

    def clock():  # 1 ms per read, nothing for the calls themselves
        reads.append(1)
        return len(reads) * 1e-3

    monkeypatch.setitem(bench.CLOCK, "now", clock)
    fast = bench.rate_batched(lambda: calls.append(1), min_time=0.3)
    per_batch = (len(calls) - 2) / (len(reads) - 3)  # after the two warm-up calls; 3 runs of rate
    assert per_batch > 50 and fast > 20 * bench.rate(lambda: None, min_time=0.3)
    monkeypatch.setitem(bench.CLOCK, "now", bench.time.perf_counter)
    slow = bench.rate_batched(lambda: bench.time.sleep(0.003), min_time=0.03)
    assert 100 < slow < 334  # batches of one: ~1/3 ms^-1 less the loop's overhead


def test_paired_ratio_is_the_median_of_the_rounds_ratios(bench):
    # a slow phase in round 3 hits both functions: the paired ratio stays 0.5, the ratio of medians does not
    on, off = [50.0, 52.0, 20.0, 49.0, 51.0], [100.0, 104.0, 40.0, 98.0, 102.0]
    med, lo, hi = bench.paired_ratio(on, off)
    assert med == lo == hi == 0.5
    on = [50.0, 55.0, 20.0, 49.0, 60.0, 45.0, 51.0]
    off = [100.0, 100.0, 50.0, 100.0, 100.0, 100.0, 100.0]
    med, lo, hi = bench.paired_ratio(on, off)
    ratios = [a / b for a, b in zip(on, off, strict=True)]
    assert med == sorted(ratios)[3] and min(ratios) <= lo <= med <= hi <= max(ratios) and lo < hi


def test_env_and_memory_sections(bench, tmp_path):
    pytest.importorskip("torch")
    argv = ["--sections", "envs,memory", "--min-time", "0.03", "--env-robots", "4", "--memory-steps", "4"]
    res = bench.main([*argv, "--memory-robots", "4", "--out", str(tmp_path)])
    rows = {(r["env"], r["robots"], r["detector"]): r for r in res["envs"]}
    assert set(rows) == {
        (e, n, d)
        for e, n in (("KinSeek-v2", 1), ("aggregation_v2", 4))
        for d in ("None", "geometric", "learned")
    }
    assert all(r["steps_per_s"] > 0 for r in rows.values())
    assert rows[("aggregation_v2", 4, "None")]["of_detector_off"] == 1.0
    assert rows[("aggregation_v2", 4, "None")]["of_detector_off_paired_ci"] == [1.0, 1.0]
    for r in rows.values():
        lo, hi = r["of_detector_off_paired_ci"]
        assert 0 < lo <= r["of_detector_off_paired"] <= hi
    (mem,) = res["memory"]
    assert mem["steps"] == 4 and mem["peak_rss_mb"] > 0 and mem["rss_end_mb"] > 0
    # growth is the second half's (half-time to end), settling the first half's (warm to half-time)
    assert mem["growth_mb"] == mem["rss_end_mb"] - mem["rss_half_mb"]
    assert mem["settle_mb"] == mem["rss_half_mb"] - mem["rss_warm_mb"]
    assert "growth, second half" in (tmp_path / "benchmark.md").read_text()
    assert "of detector off" in (tmp_path / "benchmark.md").read_text()


def test_vecenv_section(bench, tmp_path, monkeypatch):
    import gymnasium as gym

    counts, make_vec = [], gym.make_vec

    noises = []

    def counting_make_vec(*args, **kwargs):
        noises.append(kwargs["noise_sigma"])
        env, calls = make_vec(*args, **kwargs), [kwargs["vectorization_mode"], 0]
        step = env.step

        def counted(a):
            calls[1] += 1
            return step(a)

        env.step = counted
        counts.append(calls)
        return env

    monkeypatch.setattr(gym, "make_vec", counting_make_vec)
    res = bench.main(["--sections", "vecenv", "--min-time", "0.03", "--vec-envs", "2", "--vec-steps", "30",
                      "--vec-detectors", "none", "geometric", "--vec-noise", "0", "0.005",
                      "--out", str(tmp_path)])
    assert noises == [0.0] * 4 + [0.005] * 4  # the same range noise in both vectorisations, every detector
    # both envs step the same window (in steps, chunk by chunk, so resets count alike), plus one warm-up
    assert counts == [["vector_entry_point", 31], ["sync", 31]] * 4
    assert [(r["noise"], r["detector"]) for r in res["vecenv"]] == [
        (0.0, "none"), (0.0, "geometric"), (0.005, "none"), (0.005, "geometric")]
    for r in res["vecenv"]:
        assert r["num_envs"] == 2 and r["native_env_steps_per_s"] > 0 and r["sync_env_steps_per_s"] > 0
        assert r["ratio"] == pytest.approx(r["native_env_steps_per_s"] / r["sync_env_steps_per_s"])
    assert "| KinSeek-v2 | 2 | geometric | 0.5% |" in (tmp_path / "benchmark.md").read_text()
    with pytest.raises(SystemExit):
        bench.main(["--sections", "vecenv", "--vec-envs", "0", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        bench.main(["--sections", "vecenv", "--vec-steps", "0", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        bench.main(["--sections", "vecenv", "--vec-noise", "-0.01", "--out", str(tmp_path)])


def test_naive_baseline_matches_the_world_scan(bench):
    import numpy as np

    from kin_envs import World, scenes

    world = World(scenes.random_arena(3, 10, seed=2, size=5.0))
    np.testing.assert_allclose(bench.naive_scan(world, 1), world.scan().ranges[1], atol=1e-5)


def test_bad_arguments(bench, tmp_path, capsys):
    with pytest.raises(SystemExit):
        bench.main(["--sections", "gpu", "--out", str(tmp_path)])
    # each refused option is named with its value
    for argv, message in ((["--min-time", "0"], "--min-time must be > 0 s, got 0.0"),
                          (["--min-time", "nan"], "--min-time must be > 0 s, got nan"),
                          (["--robots", "8", "0"], "--robots must be >= 1, got [8, 0]"),
                          (["--env-robots", "1"], "--env-robots must be >= 2, got [1]"),
                          (["--scaling-obstacles", "-5"], "must be >= 0, got [-5]")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            bench.main([*argv, "--out", str(tmp_path)])
        assert e.value.code == 2 and message in capsys.readouterr().err


def test_lidar_scaling_section(bench, tmp_path):
    res = bench.main(
        [
            "--sections", "lidar_scaling", "--min-time", "0.03", "--scaling-robots", "1", "3",
            "--scaling-obstacles", "0", "5", "--out", str(tmp_path),
        ]
    )  # fmt: skip
    rows = res["lidar_scaling"]
    assert [(r["robots"], r["obstacles"]) for r in rows] == [(1, 0), (3, 0), (1, 5), (3, 5)]
    for r in rows:
        assert r["arena_m"] == bench.scaling_arena_side(r["robots"], r["obstacles"]) == 5.0
        assert min(r["grid_scans_per_s"], r["brute_force_scans_per_s"], r["naive_scans_per_s"]) > 0
        assert r["grid_vs_brute_force"] == pytest.approx(r["grid_scans_per_s"] / r["brute_force_scans_per_s"])
        assert r["default"] == "brute force" and r["default_scans_per_s"] == r["brute_force_scans_per_s"]
        assert r["default_vs_naive"] == pytest.approx(r["brute_force_scans_per_s"] / r["naive_scans_per_s"])
    assert res["lidar_scaling_targets"]["min_default_vs_naive"] == pytest.approx(
        min(r["brute_force_scans_per_s"] / r["naive_scans_per_s"] for r in rows)
    )
    assert set(res["lidar_scaling_startup"]) == {"grid_first_scan_s", "brute_force_first_scan_s"}
    assert "| grid / brute force | default | default / naive |" in (tmp_path / "benchmark.md").read_text()
    assert bench.scaling_arena_side(64, 1000) == pytest.approx((1064 / 0.7) ** 0.5)
    with pytest.raises(SystemExit):
        bench.main(["--scaling-robots", "0", "--out", str(tmp_path)])


def test_ros_section(bench, tmp_path):
    pytest.importorskip("rosbags")
    res = bench.bench_ros(0.01, steps=3)
    assert [r["storage"] for r in res] == ["mcap", "sqlite3", "ros1"]
    for r in res:
        assert r["record_steps_per_s"] > 0 and r["read_scans_per_s"] > 0 and r["detect_scans_per_s"] > 0
    assert "| bag | record steps/s" in bench.to_markdown({"ros": res})
