"""scripts/main_job.py (the README's ``make run``): a quick end-to-end run writes every step's outputs."""

from tests.scripts.helpers import load_script


def test_quick_main_job_writes_all_three_steps(tmp_path):
    results = load_script("main_job").main(["--quick", "--out", str(tmp_path)])
    assert set(results) >= {"reproduce_paper", "benchmark_detectors", "benchmark_tracking"}
    for step in ("reproduce_paper/reproduction.md", "benchmark_detectors/results.md",
                 "benchmark_tracking/results.md", "benchmark_tracking/f1_vs_frames.png"):  # fmt: skip
        assert (tmp_path / step).stat().st_size > 0, step
