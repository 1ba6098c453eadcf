"""scripts/main_job.py (the README's ``make run``): a quick end-to-end run writes every step's outputs."""

from tests.scripts.helpers import load_script


def test_quick_main_job_writes_all_three_steps(tmp_path):
    results = load_script("main_job").main(["--quick", "--out", str(tmp_path)])
    assert set(results) >= {"reproduce_paper", "benchmark_detectors", "benchmark_tracking"}
    for step in ("reproduce_paper/reproduction.md", "benchmark_detectors/results.md",
                 "benchmark_tracking/results.md", "benchmark_tracking/f1_vs_frames.png"):  # fmt: skip
        assert (tmp_path / step).stat().st_size > 0, step


def test_full_flag_reaches_both_benchmarks(tmp_path, monkeypatch):
    """``main_job.py --full`` (the README's full-size run) passes ``--full`` to the detection and the
    sequence benchmarks, and the paper reproduction runs as usual (steps stubbed: no real run)."""
    mod = load_script("main_job")
    calls = {}

    class Step:
        def __init__(self, name):
            self.name = name

        def main(self, argv):
            calls[self.name] = argv
            return {}

    monkeypatch.setattr(mod, "_load", Step)
    mod.main(["--full", "--out", str(tmp_path), "-q"])
    assert "--full" in calls["benchmark_detectors"] and "--scenes" not in calls["benchmark_detectors"]
    assert "--full" in calls["benchmark_tracking"]
    assert "--full" not in calls["reproduce_paper"]
    # and the detection benchmark's own --full is its full size
    from kin_envs.detection.benchmark import SPLITS, _sizes

    assert [_sizes("full", SPLITS[s]) for s in ("paper", "swarm", "lookalike")] == [400, 300, 600]


def test_bad_options_refused_before_the_first_step(tmp_path, monkeypatch, capsys):
    """``--scenes 0`` used to fail in the detection benchmark, after the paper reproduction's minutes of
    work; an ``--out`` that is a file, at its ``mkdir`` with a traceback. Both are one-line errors now."""
    import pytest

    mod = load_script("main_job")

    def computing(name):
        raise AssertionError(f"{name} ran before the options were checked")

    monkeypatch.setattr(mod, "_load", computing)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for argv, message in ((["--scenes", "0", "--out", str(tmp_path)], "--scenes must be >= 1, got 0"),
                          (["--out", str(a_file)], "is a file, not a directory")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            mod.main([*argv, "-q"])
        assert e.value.code == 2 and message in capsys.readouterr().err
