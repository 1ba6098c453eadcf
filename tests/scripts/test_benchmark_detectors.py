"""scripts/benchmark_detectors.py end to end on a tiny size."""

import json

import pytest

from tests.scripts.helpers import load_script


def test_tiny_run_writes_tables_plots_and_run_record(tmp_path):
    mod = load_script("benchmark_detectors")
    res = mod.main(
        ["--detectors", "geometric", "--splits", "paper", "lookalike", "--scenes", "2",
         "--noise", "0", "0.01", "--resamples", "20", "--out", str(tmp_path), "--quiet"]
    )  # fmt: skip
    assert {r["split"] for r in res.rows} == {"paper", "lookalike"}
    assert {r["noise"] for r in res.rows} == {0.0, 0.01}
    md = (tmp_path / "results.md").read_text()
    assert "## paper: 2 scenes" in md and "| geometric | all |" in md
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["config"]["benchmark_version"] == res.config["benchmark_version"]
    assert len(saved["rows"]) == len(res.rows)
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["args"]["scenes"] == 2 and "benchmark_detectors.py" in run["command"]
    for split in ("paper", "lookalike"):
        png = (tmp_path / f"pr_{split}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob("*.tmp*"))  # atomic writes leave no temporaries


def test_bad_arguments_exit(tmp_path):
    mod = load_script("benchmark_detectors")
    with pytest.raises(SystemExit):
        mod.main(["--detectors", "nonsense", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        mod.main(["--scenes", "0", "--out", str(tmp_path)])


def test_runs_on_the_core_install(tmp_path, monkeypatch, caplog):
    # the core install has no tqdm (the benchmark's progress bars) and no matplotlib (its PR plots): the
    # tables and a warning instead of a traceback after the paper reproduction in `make run`
    import sys

    for name in ("tqdm", "matplotlib", "torch"):  # import -> ImportError, find_spec -> None
        monkeypatch.setitem(sys.modules, name, None)
    mod = load_script("benchmark_detectors")
    mod.main(["--detectors", "geometric", "learned", "--splits", "paper", "--scenes", "2", "--noise", "0",
              "--resamples", "0", "--out", str(tmp_path)])  # fmt: skip
    assert "no PR plots: matplotlib is not installed" in caplog.text
    assert (tmp_path / "results.md").stat().st_size > 0 and not list(tmp_path.glob("*.png"))
