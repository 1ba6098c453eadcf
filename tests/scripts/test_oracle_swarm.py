"""scripts/oracle_swarm.py: argument checks and its grouping helpers (the oracle itself is tested in
tests/kin_envs/detection/test_oracle.py; a run costs minutes of least-squares fits)."""

import pytest

from tests.scripts.helpers import load_script


def test_refuses_benchmark_seeds_and_bad_bins(tmp_path, capsys):
    from kin_envs.detection.benchmark import BENCHMARK_SEEDS

    mod = load_script("oracle_swarm")
    with pytest.raises(SystemExit):
        mod.main(["--first-seed", str(BENCHMARK_SEEDS.start), "--out", str(tmp_path / "o")])
    assert "reserved" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mod.main(["--bins", "1", "0.5", "--out", str(tmp_path / "o")])
    assert "--bins" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mod.main(["--scenes", "0", "--out", str(tmp_path / "o")])
    assert "--scenes" in capsys.readouterr().err


def test_groups():
    mod = load_script("oracle_swarm")
    assert [mod.beam_group(n) for n in (1, 2, 3, 4, 5, 9, 10, 300)] == ["1", "2", "3", "4", "5-9", "5-9",
                                                                        ">=10", ">=10"]  # fmt: skip
    assert mod.kind_group("7 cm prism 5") == "7 cm prism/box" and mod.kind_group("prism") == "other prism"
    assert mod.kind_group("kin") == "kin" and mod.kind_group("boundary") == "boundary"
