"""scripts/experiment_split_windows.py: candidate windows inside segments too wide for the pre-gate."""

import json
import math

import numpy as np
import pytest

from tests.scripts.helpers import load_script


def _housing_at_wall(offset, n=360, centre=0.965, r=0.035, wall=1.0, half=20):
    """One scan: a housing whose far side touches a wall perpendicular to the beams near 0 (one merged
    segment, beams -half..half), its centre ``offset`` beams off beam 0 → ``(ranges, housing beams)``."""
    th = (np.arange(-half, half + 1) + offset) * (2 * math.pi / n)
    d = wall / np.cos(th)
    s = centre * np.sin(th)
    hit = np.abs(s) < r
    d[hit] = centre * np.cos(th[hit]) - np.sqrt(r * r - s[hit] ** 2)
    ranges = np.full((1, n), np.inf)
    ranges[0, np.arange(-half, half + 1) % n] = d
    return ranges, set(((np.flatnonzero(hit) - half) % n).tolist())


@pytest.mark.parametrize("offset", [0.0, 0.4])  # housing centred on a beam / between two beams
def test_window_is_the_housing(offset):
    mod = load_script("experiment_split_windows")
    n, half = 360, 20
    ranges, housing = _housing_at_wall(offset, n, half=half)
    seg = dict(scan=[0], first=[n - half], count=[2 * half + 1], prev_beam=[-1], next_beam=[-1],
               prev_nearer=[False], next_nearer=[False])  # fmt: skip
    rows = mod.window_rows(ranges, 2 * math.pi / n, 0.035, 1.0, *(np.array(v) for v in seg.values()))
    assert len(rows) == 1  # the wall's ranges grow away from beam 0: its only minimum is the housing's
    b, first, count, prev, nxt, pn, nn = rows[0]
    assert b == 0 and count >= 4 and {(first + k) % n for k in range(count)} == housing
    # the window's neighbours are the wall beams beside it, farther than its ends
    assert prev == (first - 1) % n and nxt == (first + count) % n and not pn and not nn


def test_runs_and_counts(tmp_path):
    pytest.importorskip("torch")
    mod = load_script("experiment_split_windows")
    res = mod.main(["--scenes", "1", "--noise", "0.01", "--window-threshold", "0.995", "--out", str(tmp_path),
                    "--no-progress", "-q"])  # fmt: skip
    for name in ("shipped", "windows >= 0.995"):
        for r in res[name]["1 %"].values():
            assert r["found"] + r["missed"] == r["counted_kin"]
            assert sum(r["fp_kinds"].values()) == r["fp"]
    c = res["windows >= 0.995"]["counts"]
    assert c["windows"] > 0 and c["wide"] > 0 and c["accepted"] <= c["windows"]
    assert json.loads((tmp_path / "results.json").read_text()) == res
    assert (tmp_path / "run.json").is_file() and (tmp_path / "results.md").is_file()


def test_refuses_benchmark_seeds(tmp_path, capsys):
    mod = load_script("experiment_split_windows")
    with pytest.raises(SystemExit):
        mod.main(["--first-seed", "2010000000", "--out", str(tmp_path)])
    assert "reserved" in capsys.readouterr().err
