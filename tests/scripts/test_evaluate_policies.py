"""scripts/evaluate_policies.py statistics on hand-made data: intervals never leave the quantity's range."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from tests.scripts.helpers import load_script

ev = load_script("evaluate_policies")


def _t_interval(x):
    """The Student t interval the script used before (for comparison)."""
    x = np.asarray(x, float)
    half = stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
    return x.mean() - half, x.mean() + half


def test_proportion_interval_is_wilson_within_0_1():
    lo, hi = ev.proportion_ci(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    assert ev.proportion_ci(0, 5)[0] == 0.0 and ev.proportion_ci(5, 5)[1] == 1.0
    assert all(np.isnan(ev.proportion_ci(0, 0)))


@pytest.mark.parametrize(
    ("x", "low", "high"),
    [
        ([0] * 18 + [20, 16], 0.0, np.inf),  # collision counts: mostly 0, a few large
        ([1.0] * 19 + [0.2], 0.0, 1.0),  # largest-cluster fractions, one bad episode
        ([0.05] * 9 + [0.9], 0.0, np.inf),  # distances, one outlier
    ],
)
def test_mean_interval_stays_in_range_where_t_does_not(x, low, high):
    t_lo, t_hi = _t_interval(x)
    assert t_lo < low or t_hi > high  # the old interval left the range on this data
    m, lo, hi = ev.mean_ci(x)
    assert m == pytest.approx(np.mean(x))
    assert low <= min(x) <= lo <= m <= hi <= max(x) <= high
    assert ev.mean_ci(x) == (m, lo, hi)  # seeded: the same table on every run


def test_mean_interval_edge_cases():
    assert ev.mean_ci([3.0, 3.0, 3.0]) == (3.0, 3.0, 3.0)
    m, lo, hi = ev.mean_ci([2.0])
    assert m == 2.0 and np.isnan(lo) and np.isnan(hi)
    assert all(np.isnan(ev.mean_ci([])))
    m, lo, hi = ev.mean_ci([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert 1.0 <= lo < 3.5 < hi <= 6.0


def test_cluster_metrics_connected_components():
    # two pairs 0.3 m apart, far from each other; link radius 0.5: largest cluster 2 of 4
    xy = np.array([[0, 0], [0.3, 0], [3, 3], [3.3, 3]])
    nearest, frac = ev.cluster_metrics(xy, 0.5)
    assert nearest == pytest.approx(0.3) and frac == 0.5
    assert ev.cluster_metrics(xy, 5.0)[1] == 1.0
    # a chain links transitively: the ends are 1.2 m apart, every neighbour 0.4 m; plus a loner
    chain = np.array([[0, 0], [0.4, 0], [0.8, 0], [1.2, 0], [5, 5]])
    assert ev.cluster_metrics(chain, 0.5)[1] == pytest.approx(0.8)
    assert ev.cluster_metrics(chain, 0.3)[1] == pytest.approx(0.2)
