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
    "argv", [["--frames", "1"], ["--noise", "0"], ["--still", "0"], ["--swarm-episodes", "-1"]]
)
def test_bad_arguments_exit(argv, tmp_path):
    mod = load_script("track_shape_oracle")
    with pytest.raises(SystemExit):
        mod.main([*argv, "--out", str(tmp_path / "o")])
