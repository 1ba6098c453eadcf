"""scripts/track_shape_oracle.py: its tables on hand-made samples; bad arguments exit (the episode run
itself is covered by tests/kin_envs/detection/test_shape_oracle.py)."""

import pytest

from tests.scripts.helpers import load_script


def test_tables_rank_the_statistics_per_split_and_frames():
    mod = load_script("track_shape_oracle")
    rows = [{"split": "lookalike", "frames": 10, "kin": k, "llr": v, "track_prob": 0.5, "mean_logit": -v}
            for k, v in [(True, 3.0), (True, 2.0), (False, -1.0), (False, -4.0)]]  # fmt: skip
    lines = mod.tables(rows, frames=(10,))
    assert len(lines) == 2 + 3
    assert lines[2].startswith("| lookalike | 10 | 2 / 2 | oracle shape LLR | 1.00 |")
    assert "| track classifier | 0.50 |" in lines[3] and "| mean score logit | 0.00 |" in lines[4]


@pytest.mark.parametrize(
    "argv",
    [["--frames", "1"], ["--noise", "0"], ["--still", "0"], ["--swarm-episodes", "-1"],
     ["--noise", "0.01", "0.005"], ["--ceiling", "--noise", "0.1"], ["--compare", "results.json"],
     ["--ceiling", "--compare", "missing.json"], ["--ceiling", "--full"], ["--full", "--benchmark-seeds"]],
)
def test_bad_arguments_exit(argv, tmp_path):
    mod = load_script("track_shape_oracle")
    with pytest.raises(SystemExit):
        mod.main([*argv, "--out", str(tmp_path / "o")])


def test_ceiling_tables_put_the_benchmark_beside_the_ceiling():
    mod = load_script("track_shape_oracle")
    c = {"f1": 0.9, "f1_ci": (0.8, 0.95), "precision": 0.95, "recall": 0.85, "f1_no_shape": 0.8,
         "moving_kin_rows": 10, "still_kin_rows": 5, "lookalike_rows": 7,
         "rejected": {"prism5": (0.5, 4), "prism3": (1.0, 4)},
         "by_distance": {1: {"f1": 0.95}, 2: {"f1": 0.85}}, "same_radius_rejected": (0.25, 4)}  # fmt: skip
    cell = {"tp": 8, "fp": 1, "fn": 1}
    bench = [{"split": "swarm", "noise": 0.01, "by_age_distance": {"tracker": {"3,1": cell, "3,2": cell},
                                                                   "single": {"3,1": cell}},
              "lookalikes_rejected": {"tracker": {"prism": (0.9, 10), "box": (1.0, 3)}},
              "same_radius_rejected": {"tracker": (0.5, 8)}}]  # fmt: skip
    lines = mod.ceiling_tables({("swarm", 0.01): c}, bench)
    assert len(lines) == 3
    assert lines[2].startswith("| swarm | 1 % | **0.90** [0.80, 0.95] (0.95 / 0.85) | 0.95 | 0.85 | 0.80 | "
                               "10 / 5 | 7 | 75 % of 8 | 25 % of 4 |")
    assert lines[2].endswith("| 0.89 (0.89 / 0.89) | 0.89 | 90 % / 50 % of 8 |")
    assert mod.ceiling_tables({("lookalike", 0.0): c})[2].endswith("| – | – | – |")


def test_ceiling_run_writes_its_table(tmp_path):
    """One short training lookalike episode end to end: the table, the rows and the run record."""
    import json

    mod = load_script("track_shape_oracle")
    out = mod.main(["--ceiling", "--swarm-episodes", "0", "--lookalike-episodes", "1", "--first-seed", "90",
                    "--noise", "0", "0.01", "--out", str(tmp_path / "o"), "--quiet"])  # fmt: skip
    assert set(out["ceiling"]) == {"lookalike 0", "lookalike 0.01"}
    assert all(0 <= c["f1"] <= 1 and c["f1_no_shape"] <= c["f1"] + 1e-12 for c in out["ceiling"].values())
    saved = json.loads((tmp_path / "o" / "ceiling.json").read_text())
    assert set(saved["records"]) == {"lookalike 0", "lookalike 0.01"}
    assert (tmp_path / "o" / "ceiling.md").read_text().count("| lookalike |") == 2
    assert json.loads((tmp_path / "o" / "run.json").read_text())["args"]["ceiling"] is True
