"""The look-alike oracle: its ray casting against the simulator's lidar, its LLR, its best F1."""

import math

import numpy as np
import pytest

from kin_envs import World
from kin_envs.core.lidar import HitKind
from kin_envs.detection.oracle import (
    HOUSING_RADIUS,
    _box,
    _polygon,
    best_f1,
    best_f1_grouped,
    circle_ranges,
    object_llr,
    object_llr_swarm,
    polygon_ranges,
    scan_objects_llr,
)
from kin_envs.scenes import Arena, Box, Cylinder, Prism, Robot, Scene, Wall


def _observer_xy(x, y, th):
    c, s = math.cos(th), math.sin(th)
    return c * x + s * y, -s * x + c * y


def test_ray_casting_matches_the_simulators_lidar():
    """Predicted ranges at the true pose equal the noise-free scan of random prisms, boxes and
    cylinders (the simulator's lidar is the independent reference)."""
    rng = np.random.default_rng(3)
    for _ in range(12):
        th0 = float(rng.uniform(-np.pi, np.pi))
        d, b = float(rng.uniform(0.3, 1.5)), float(rng.uniform(-np.pi, np.pi))
        x, y, rot = d * math.cos(b), d * math.sin(b), float(rng.uniform(0, 2 * np.pi))
        sides = int(rng.integers(3, 7))
        kind = int(rng.integers(3))
        obst = (Prism(x, y, sides=sides, width=0.07, theta=rot), Box(x, y, width=0.07, depth=0.07, theta=rot),
                Cylinder(x, y, radius=0.045))[kind]  # fmt: skip
        scene = Scene(robots=(Robot(0.0, 0.0, th0),), obstacles=(obst,), arena=Arena(8, 8, walls=False))
        scan = World(scene, seed=0).scan(noise=False)
        beams = np.flatnonzero((scan.hit_index[0] == 0) & (scan.hit_kind[0] != HitKind.NONE))
        assert beams.size >= 2
        lx, ly = _observer_xy(x, y, th0)
        a = scan.angles[beams]
        if kind == 2:
            pred, hit, _ = circle_ranges(a, lx, ly, 0.045)
        else:
            verts = np.array(obst.footprint()[1]) @ np.array([[math.cos(th0), -math.sin(th0)],
                                                              [math.sin(th0), math.cos(th0)]])  # fmt: skip
            pred, hit, _ = polygon_ranges(a, verts)
        assert hit.all()
        np.testing.assert_allclose(pred, scan.true_ranges[0, beams], atol=1e-6)
        miss = np.setdiff1d(np.arange(scan.ranges.shape[1]), beams)
        if kind == 2:
            assert not circle_ranges(scan.angles[miss], lx, ly, 0.045)[1].any()
        else:
            assert not polygon_ranges(scan.angles[miss], verts)[1].any()


def test_llr_separates_shapes_at_low_noise_and_not_at_one_percent():
    """Up close and nearly noise-free the kin is far more likely a circle and a triangle a
    look-alike; at 1 % noise a kin and a hexagon at 0.8 m are nearly indistinguishable."""
    rng = np.random.default_rng(0)
    res = []
    for obst in (None, Prism(0.5, 0.05, sides=3, width=0.07, theta=0.4), Prism(0.8, 0.0, sides=6, theta=0.2)):
        robots = (Robot(0.0, 0.0, 0.0),) + ((Robot(0.5, 0.05, 0.0),) if obst is None else ())
        obstacles = () if obst is None else (obst,)
        scene = Scene(robots=robots, obstacles=obstacles, arena=Arena(8, 8, walls=False))
        scan = World(scene, seed=0).scan(robots=[0], noise=False)
        kind = HitKind.ROBOT if obst is None else HitKind.PRISM
        b = np.flatnonzero(scan.hit_kind[0] == kind)
        r = scan.true_ranges[0, b]
        low = object_llr(scan.angles[b], r + rng.normal(0, 0.0005 * r), 0.0005, n_starts=2)[0]
        one = object_llr(scan.angles[b], r + rng.normal(0, 0.01 * r), 0.01, n_starts=2)[0]
        res.append((low, one))
    assert res[0][0] > 5 and res[1][0] < -5  # kin vs triangle at 0.05 % noise
    assert abs(res[2][1]) < 3  # hexagon at 0.8 m, 1 % noise: no evidence either way
    with pytest.raises(ValueError, match="2 beams"):
        object_llr([0.1], [1.0], 0.01)
    with pytest.raises(ValueError, match="noise"):
        object_llr([0.1, 0.11], [1.0, 1.0], -1)


def test_scan_objects_llr_lists_the_candidates():
    scene = Scene(
        robots=(Robot(0.0, 0.0, 0.0), Robot(0.6, 0.3, 1.0)),
        obstacles=(Prism(0.6, -0.3, sides=5), Cylinder(0.4, 0.5, radius=HOUSING_RADIUS),
                   Cylinder(-0.6, 0.0, radius=0.05), Box(0.0, -0.7, width=0.07, depth=0.07)),
        arena=Arena(8, 8, walls=False),
    )  # fmt: skip
    scan = World(scene, seed=0).scan(robots=[0], noise=False)
    objs = scan_objects_llr(scan, scene, 0, 0.005, (0.3, 1.0), n_starts=1)
    labels = sorted(o.label for o in objs)
    assert labels == ["7 cm box", "7 cm prism 5", "kin", "other cylinder"]  # same radius left out
    kin = next(o for o in objs if o.kin)
    assert kin.distance == pytest.approx(math.hypot(0.6, 0.3)) and kin.n_beams >= 2


def test_best_f1_hand_made():
    r = best_f1([0.9, 0.8, 0.7, 0.1], [True, False, True, False])
    assert r["f1"] == pytest.approx(0.8) and r["threshold"] == 0.7  # 2 TP, 1 FP
    r = best_f1([1.0, 1.0, 0.0], [True, False, True])  # a tie is accepted together
    assert r["f1"] == pytest.approx(max(2 * 1 / 4, 2 * 2 / 5))
    with pytest.raises(ValueError):
        best_f1([0.1], [False])


def test_swarm_shapes_of_any_size_match_the_simulators_lidar():
    """The swarm oracle's free-size shapes (``_polygon`` with any circumradius, ``_box`` with any
    sides, the same parametrisation its fits use) at the true pose give the noise-free scan of random
    prisms and boxes of the swarm generator's sizes."""
    rng = np.random.default_rng(11)
    for k in range(10):
        th0 = float(rng.uniform(-np.pi, np.pi))
        d, b = float(rng.uniform(0.5, 2.0)), float(rng.uniform(-np.pi, np.pi))
        x, y, rot = d * math.cos(b), d * math.sin(b), float(rng.uniform(-np.pi, np.pi))
        lx, ly = _observer_xy(x, y, th0)
        if k % 2:
            w, dep = (float(v) for v in rng.uniform(0.05, 0.4, size=2))
            obst = Box(x, y, width=w, depth=dep, theta=rot)
            verts = _box(lx, ly, rot - th0, w, dep)
        else:
            sides, width = int(rng.integers(3, 7)), float(rng.uniform(0.05, 0.3))
            obst = Prism(x, y, sides=sides, width=width, theta=rot)
            verts = _polygon(sides, width / 2, lx, ly, rot - th0)
        scene = Scene(robots=(Robot(0.0, 0.0, th0),), obstacles=(obst,), arena=Arena(8, 8, walls=False))
        scan = World(scene, seed=0).scan(noise=False)
        beams = np.flatnonzero((scan.hit_index[0] == 0) & (scan.hit_kind[0] != HitKind.NONE))
        pred, hit, _ = polygon_ranges(scan.angles[beams], verts)
        assert hit.all()
        np.testing.assert_allclose(pred, scan.true_ranges[0, beams], atol=1e-6)


def test_swarm_llr_rejects_large_objects_and_prefers_the_circle_for_kin():
    rng = np.random.default_rng(2)
    scene = Scene(
        robots=(Robot(0.0, 0.0, 0.0), Robot(0.5, 0.05, 0.0)),
        obstacles=(Wall(-0.8, -0.5, -0.8, 0.5), Prism(0.1, -0.7, sides=4, width=0.07, theta=0.3),
                   Cylinder(0.0, 0.7, radius=HOUSING_RADIUS), Box(-0.3, 0.9, width=0.3, depth=0.2)),
        arena=Arena(8, 8, walls=False),
    )  # fmt: skip
    scan = World(scene, seed=0).scan(robots=[0], noise=False)
    sigma = 0.0005
    noisy = scan.true_ranges[0] * (1 + rng.normal(0, sigma, scan.true_ranges.shape[1]))
    scan.ranges[0] = np.where(scan.ranges[0] < scan.range_max, noisy, scan.ranges[0])
    objs = scan_objects_llr(scan, scene, 0, sigma, (0.3, 1.5), n_starts=1, split="swarm")
    objs = {o.label: o for o in objs}
    assert set(objs) == {"kin", "wall", "7 cm prism 4", "box"}  # the same-radius cylinder left out
    assert objs["wall"].llr == -math.inf and objs["box"].llr == -math.inf  # wider than any housing
    assert objs["kin"].llr > 5 and objs["7 cm prism 4"].llr < -5  # nearly noise-free: shapes tell
    assert objs["kin"].distance == pytest.approx(math.hypot(0.5, 0.05))
    assert objs["wall"].distance == pytest.approx(0.8 - 0.05 / 2, abs=0.002)  # its nearest point
    # two beams carry no shape evidence: a line fits them exactly, so the LLR is never positive
    llr2, llr2_all = object_llr_swarm([0.0, 0.017], [1.0, 1.001], 0.01)
    assert llr2 <= 0 and llr2_all <= 0
    with pytest.raises(ValueError, match="split"):
        scan_objects_llr(scan, scene, 0, sigma, (0.3, 1.5), split="paper")
    with pytest.raises(ValueError, match="2 beams"):
        object_llr_swarm([0.1], [1.0], 0.01)


def test_best_f1_grouped_hand_made():
    """Group a separates at 1 vs 0.5; group b's objects all score 0 and are mostly kin: one threshold
    per group accepts a's kin and all of b (F1 10/11), a common one at best everything (10/13)."""
    scores = [1.0, 1.0, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0]
    kin = [True, True, False, False, True, True, True, False]
    groups = ["a"] * 4 + ["b"] * 4
    assert best_f1(scores, kin)["f1"] == pytest.approx(10 / 13)
    r = best_f1_grouped(scores, kin, groups)
    assert r["f1"] == pytest.approx(10 / 11) and r["thresholds"] == {"a": 1.0, "b": 0.0}
    assert r["precision"] == pytest.approx(5 / 6) and r["recall"] == 1.0
    with pytest.raises(ValueError):
        best_f1_grouped([0.1], [True], [0, 1])
