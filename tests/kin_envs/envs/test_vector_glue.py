"""The native vector env's compiled detection glue (``kin_envs.envs._vector_glue.match_pad_worlds``)
against its numpy reference: ``detect_rows`` with ``robot_world`` (the general path), the vector env's
conversion of ``kin_index`` to each world's own robot index, then ``pad_rows``; bit for bit, on
randomised tables (overlapping worlds, ties and NaN ranges, centres on and off the robots, one to
three robots a world, more detections than slots)."""

from __future__ import annotations

import numpy as np
import pytest

from kin_envs.envs._vector_glue import match_pad_worlds
from kin_envs.envs.common import KIN_MATCH_TOLERANCE, detect_rows
from kin_envs.envs.info import DETECTION_FIELDS, pad_rows


class _Table:
    """A detector whose trusted table is given (what ``detection_arrays`` reads first)."""

    def __init__(self, owner, tab):
        self.owner, self.tab = owner, tab

    def _detect_table_trusted(self, ranges, angles):
        return self.owner, self.tab


def _reference(owner, tab, poses, n, slots):
    k = poses.shape[0] // n
    ranges, angles = np.zeros((k, 8)), np.linspace(-np.pi, np.pi, 8, endpoint=False)
    observers = np.arange(k) * n
    row, cols = detect_rows(_Table(owner, tab), ranges, angles, observers, poses,
                            robot_world=np.repeat(np.arange(k), n), trusted=True)  # fmt: skip
    ki = cols["kin_index"]
    cols["kin_index"] = np.where(ki >= 0, ki - row * n, -1)  # KinVectorEnv._sense's conversion
    return (row, cols), pad_rows(row, cols, k, slots)


def _random_case(rng, k, n, per_row):
    # worlds on top of each other (the same few square metres): another world's robot is often the
    # nearest one, which a detection must never match
    poses = np.column_stack([rng.uniform(0, 3, k * n), rng.uniform(0, 3, k * n), rng.uniform(-4, 4, k * n)])
    counts = rng.integers(0, per_row + 1, k)
    owner = np.repeat(np.arange(k), counts)
    d = owner.size
    tab = np.empty((d, 8))
    obs = owner * n
    # half the detections on a robot of any world (within the tolerance or just beyond), the rest anywhere
    target = rng.integers(0, k * n, d)
    own = rng.random(d) < 0.6  # most on a robot of the observer's own world (the observer included)
    target[own] = obs[own] + rng.integers(0, n, int(own.sum()))
    c, s = np.cos(poses[obs, 2]), np.sin(poses[obs, 2])
    dx = poses[target, 0] - poses[obs, 0] + rng.normal(0, KIN_MATCH_TOLERANCE * 0.8, d)
    dy = poses[target, 1] - poses[obs, 1] + rng.normal(0, KIN_MATCH_TOLERANCE * 0.8, d)
    x, y = c * dx + s * dy, c * dy - s * dx
    far = rng.random(d) < 0.5
    x[far], y[far] = rng.uniform(-3, 3, (2, int(far.sum())))
    tab[:, 2], tab[:, 3] = x, y
    tab[:, 0] = np.round(np.hypot(x, y), 1)  # rounded: ties within a row
    tab[rng.random(d) < 0.05, 0] = np.nan
    tab[:, 1] = np.arctan2(y, x)
    tab[:, 4] = rng.random(d)
    tab[:, 5] = rng.integers(0, 360, d)
    tab[:, 6] = rng.integers(0, 360, d)
    tab[:, 7] = rng.integers(1, 30, d)
    return owner, tab, poses


def _assert_equal(got, want):
    (row_g, flat_g), (pad_g, count_g) = got
    (row_w, flat_w), (pad_w, count_w) = want
    assert np.array_equal(row_g, row_w) and row_g.dtype == row_w.dtype
    assert np.array_equal(count_g, count_w) and count_g.dtype == count_w.dtype
    assert tuple(flat_g) == tuple(flat_w) == tuple(pad_g) == tuple(pad_w) == DETECTION_FIELDS
    for f in DETECTION_FIELDS:
        for a, b in ((flat_g[f], flat_w[f]), (pad_g[f], pad_w[f])):
            assert a.dtype == b.dtype and a.shape == b.shape, f
            assert a.tobytes() == b.tobytes(), f  # bit for bit (NaN ranges, signed zeros)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_matches_the_numpy_path_bit_for_bit(n):
    rng = np.random.default_rng(n)
    matched = 0
    for _ in range(60):
        k = int(rng.integers(1, 12))
        owner, tab, poses = _random_case(rng, k, n, per_row=int(rng.integers(0, 9)))
        slots = int(rng.integers(1, 6))
        got = match_pad_worlds(owner, tab, poses, n, slots)
        want = _reference(owner, tab, poses, n, slots)
        _assert_equal(got, want)
        matched += int((want[0][1]["kin_index"] >= 0).sum())
    if n > 1:
        assert matched > 30  # the match itself was exercised, not only the misses


def test_non_finite_centres_and_poses():
    rng = np.random.default_rng(7)
    owner, tab, poses = _random_case(rng, 6, 2, per_row=6)
    tab[::3, 2] = np.nan
    tab[1::5, 3] = np.inf
    poses[3, 0] = np.nan  # a robot (not an observer) somewhere off the map
    _assert_equal(match_pad_worlds(owner, tab, poses, 2, 4), _reference(owner, tab, poses, 2, 4))


def test_no_detections_and_rows_out_of_order():
    poses = np.random.default_rng(0).uniform(0, 3, (8, 3))
    empty_o, empty_t = np.zeros(0, np.int64), np.zeros((0, 8))
    _assert_equal(match_pad_worlds(empty_o, empty_t, poses, 2, 3), _reference(empty_o, empty_t, poses, 2, 3))
    # a detector that gives rows out of order: None, the caller takes the general path
    tab = np.ones((2, 8))
    assert match_pad_worlds(np.array([1, 0]), tab, poses, 2, 3) is None
    with pytest.raises(ValueError, match="scan rows"):
        match_pad_worlds(np.array([0, 4]), tab, poses, 2, 3)
