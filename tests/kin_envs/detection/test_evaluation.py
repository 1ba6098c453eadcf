"""Evaluation harness on hand-built cases with known answers."""

import math

import numpy as np
import pytest

from detectors import GeometricKinDetector
from detectors.base import Detection, DetectionResult, KinDetector
from kin_envs import World, scenes
from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.core.scenes import Arena, Cylinder, Prism, Robot, Scene
from kin_envs.detection.evaluation import (
    DEFAULT_GATE,
    describe_hits,
    evaluate,
    kin_truth,
    match_detections,
    segment_beams,
)


class ScriptedDetector(KinDetector):
    """Returns the given detections for successive scans (ignores the ranges)."""

    def __init__(self, *per_scan):
        self.per_scan = [list(d) for d in per_scan]

    def detect(self, ranges, angles):
        return DetectionResult(self.per_scan.pop(0), [])


def det(x, y, first=0, last=0):
    return Detection(math.hypot(x, y), math.atan2(y, x), x, y, 0.0, first, last, (last - first) % 360 + 1)


def scene_of(robots, obstacles=(), lidar=None):
    return Scene(
        robots=tuple(robots), obstacles=tuple(obstacles), arena=Arena(6, 6), lidar=lidar or LidarSpec()
    )


def scanned(scene, robots=(0,), seed=0):
    return World(scene, seed=seed).scan(robots=list(robots)), scene


def beams_on(scan, kind, row=0):
    """First and last beam (scan order, may wrap across the seam) of the one object of ``kind``."""
    b = np.flatnonzero(scan.hit_kind[row] == kind)
    gaps = np.flatnonzero(np.diff(b) != 1)
    assert b.size and gaps.size <= 1, "expected one contiguous object"
    if gaps.size:  # wraps: e.g. 358, 359, 0, 1, 2
        return int(b[gaps[0] + 1]), int(b[gaps[0]])
    return int(b[0]), int(b[-1])


# --------------------------------------------------------------------------- ground truth


def test_kin_truth_in_observer_frame():
    # observer at (1, 1) facing +y; kin at (1, 2) is 1 m straight ahead, kin at (0, 1) 1 m to its left
    scene = scene_of([Robot(1, 1, math.pi / 2), Robot(1, 2, 0.0), Robot(0, 1, 0.0)])
    scan, _ = scanned(scene)
    truth = kin_truth(scan, 0, scene)
    assert [k.robot for k in truth] == [1, 2]
    a, b = truth
    assert (a.x, a.y, a.range, a.bearing) == pytest.approx((1.0, 0.0, 1.0, 0.0), abs=1e-9)
    assert (b.x, b.y, b.bearing) == pytest.approx((0.0, 1.0, math.pi / 2), abs=1e-9)
    assert a.n_beams == scan.visible_robots(0)[1] > 3
    # the same from a scan of every robot (positions from scan.poses), row 0 = the observer
    full, _ = scanned(scene, robots=(0, 1, 2))
    assert kin_truth(full, 0, scene) == truth


def test_hidden_or_out_of_range_kin_is_not_ground_truth_and_not_missed():
    # kin 1 hidden behind a big cylinder, kin 2 beyond the lidar's range
    lidar = LidarSpec(range_max=2.0)
    scene = scene_of([Robot(0, 0, 0), Robot(2.0, 0, 0), Robot(0, 2.5, 0)], [Cylinder(1.0, 0, 0.2)], lidar)
    pair = scanned(scene)
    assert kin_truth(*pair[:1], 0, scene) == ()
    ev = evaluate(ScriptedDetector([]), [pair])
    m = ev.metrics()
    assert (m.n_kin, m.tp, m.fp, m.fn) == (0, 0, 0, 0)
    assert math.isnan(m.recall) and math.isnan(m.precision) and math.isnan(m.f1)


def test_describe_hits_majority_mixed_nothing_and_seam():
    scene = scene_of([Robot(0, 0, 0)], [Prism(1.0, 0.0, sides=6, width=0.07), Cylinder(0.0, 1.0, 0.05)])
    scan, _ = scanned(scene)
    on_prism = np.flatnonzero(scan.hit_kind[0] == HitKind.PRISM)
    assert 0 in on_prism and 359 in on_prism  # straight ahead: straddles the seam
    first, last = 360 - int((on_prism > 180).sum()), int(on_prism[on_prism < 180].max())
    beams = segment_beams(first, last, 360)
    assert sorted(beams.tolist()) == sorted(on_prism.tolist())
    src = describe_hits(scan, 0, beams, scene)
    assert (src.kind, src.label, src.index, src.sides) == ("prism", "prism 6 sides", 0, 6)
    cyl = np.flatnonzero(scan.hit_kind[0] == HitKind.CYLINDER)
    assert describe_hits(scan, 0, np.concatenate([on_prism[:3], cyl[:3]]), scene).kind == "mixed"
    assert describe_hits(scan, 0, np.concatenate([on_prism[:3], cyl[:2]]), scene).kind == "prism"
    assert describe_hits(scan, 0, [180], scene).kind == "boundary"
    assert describe_hits(scan, 0, [], scene).kind == "nothing"
    with pytest.raises(ValueError, match="beam indices"):
        segment_beams(0, 360, 360)


# --------------------------------------------------------------------------- matching


def test_true_kin_within_gate_is_tp_and_outside_is_fp_plus_fn():
    scene = scene_of([Robot(0, 0, 0), Robot(1.0, 0, math.pi)])
    pair = scanned(scene)
    ev = evaluate(ScriptedDetector([det(1.02, 0.0)]), [pair])
    m = ev.metrics()
    assert (m.n_kin, m.tp, m.fp, m.fn) == (1, 1, 0, 0)
    assert (m.precision, m.recall, m.f1) == (1.0, 1.0, 1.0)
    assert m.error_mean == pytest.approx(0.02) and m.error_p95 == pytest.approx(0.02)
    assert ev.kin[0].detected and ev.detections[0].kin == 1 and ev.detections[0].source.kind == "kin"
    # 0.15 m off: outside the default 0.1 m gate -> a false positive on the kin, and the kin missed
    first, last = beams_on(pair[0], HitKind.ROBOT)
    ev = evaluate(ScriptedDetector([det(1.15, 0.0, first, last)]), [pair])
    m = ev.metrics()
    assert (m.tp, m.fp, m.fn, m.precision, m.recall, m.f1) == (0, 1, 1, 0.0, 0.0, 0.0)
    assert ev.false_positives() == {"kin (outside gate)": 1}
    # ... but inside a 0.2 m gate
    assert evaluate(ScriptedDetector([det(1.15, 0.0)]), [pair], gate=0.2).metrics().tp == 1


def test_detection_on_a_prism_is_a_false_positive_attributed_to_the_prism():
    scene = scene_of([Robot(0, 0, 0)], [Prism(0.8, -0.3, sides=6, width=0.07, theta=0.3)])
    pair = scanned(scene)
    first, last = beams_on(pair[0], HitKind.PRISM)
    ev = evaluate(ScriptedDetector([det(0.8, -0.3, first, last)]), [pair])
    m = ev.metrics()
    assert (m.n_kin, m.tp, m.fp, m.fn, m.same_radius) == (0, 0, 1, 0, 0)
    assert m.precision == 0.0 and math.isnan(m.recall)
    assert ev.false_positives() == {"prism 6 sides": 1}
    src = ev.detections[0].source
    assert (src.kind, src.index, src.sides, src.size) == ("prism", 0, 6, 0.07)


def test_same_radius_cylinder_option():
    scene = scene_of(
        [Robot(0, 0, 0), Robot(1.0, 0, 0)], [Cylinder(1.0, 0.5, 0.035), Cylinder(0.0, 1.0, 0.05)]
    )
    pair = scanned(scene)
    cyl = np.flatnonzero(pair[0].hit_kind[0] == HitKind.CYLINDER)
    same = [b for b in cyl.tolist() if pair[0].hit_index[0, b] == 0]
    other = [b for b in cyl.tolist() if pair[0].hit_index[0, b] == 1]
    dets = [det(1.0, 0.0), det(1.0, 0.5, same[0], same[-1]), det(0.0, 1.0, other[0], other[-1])]
    counted = evaluate(ScriptedDetector(dets), [pair])
    m = counted.metrics()
    assert (m.tp, m.fp, m.same_radius) == (1, 2, 1)
    assert m.precision == pytest.approx(1 / 3)
    assert counted.false_positives() == {"cylinder r=3.5 cm (kin radius)": 1, "cylinder r=5 cm": 1}
    apart = evaluate(ScriptedDetector(dets), [pair], same_radius_separate=True)
    m = apart.metrics()
    assert (m.tp, m.fp, m.same_radius) == (1, 1, 1)
    assert m.precision == pytest.approx(1 / 2)
    assert apart.false_positives() == {"cylinder r=5 cm": 1}
    assert apart.metrics(same_radius_separate=False).fp == 2  # per-call override


def test_hungarian_matching_with_crossing_kin_and_detections():
    # d0 is nearer kin A, but giving A to d0 (greedy) would leave d1 without a kin in the gate
    kin = [(0.0, 0.0), (0.0, 0.15)]
    dets = [(0.0, 0.07), (0.0, -0.02)]
    got = sorted(match_detections(dets, kin, gate=0.1))
    assert [(i, j) for i, j, _ in got] == [(0, 1), (1, 0)]
    assert [e for *_, e in got] == pytest.approx([0.08, 0.02])
    assert match_detections([], kin) == [] and match_detections(dets, []) == []
    # the same in a world: kin A at (1, 0), B at (1, 0.2), gate 0.15
    scene = scene_of([Robot(0, 0, 0), Robot(1.0, 0.0, 0), Robot(1.0, 0.2, 0)])
    pair = scanned(scene)
    ev = evaluate(ScriptedDetector([det(1.0, 0.09), det(1.0, -0.05)]), [pair], gate=0.15)
    m = ev.metrics()
    assert (m.n_kin, m.tp, m.fp, m.fn) == (2, 2, 0, 0)
    assert [d.kin for d in ev.detections] == [2, 1]
    assert m.error_mean == pytest.approx((0.11 + 0.05) / 2)


# --------------------------------------------------------------------------- binning


def test_binning_by_distance_beams_and_noise():
    near = scene_of([Robot(0, 0, 0), Robot(0.5, 0, 0)])
    far = scene_of(
        [Robot(0, 0, 0), Robot(1.5, 0, 0)],
        [Prism(0.0, 1.2, sides=3, width=0.07)],
        LidarSpec(noise_sigma=0.01),
    )
    p_far = scanned(far)
    first, last = beams_on(p_far[0], HitKind.PRISM)
    detector = ScriptedDetector([det(0.5, 0.0)], [det(0.0, 1.2, first, last)])
    ev = evaluate(detector, [scanned(near), p_far])
    (lo0, hi0, b0), (lo1, hi1, b1) = ev.by_distance([0.0, 1.0, 2.0])
    assert (lo0, hi0, lo1, hi1) == (0.0, 1.0, 1.0, 2.0)
    assert (b0.n_kin, b0.tp, b0.fp, b0.fn) == (1, 1, 0, 0)
    assert (b1.n_kin, b1.tp, b1.fp, b1.fn) == (1, 0, 1, 1)  # the FP is binned by its own range (1.2 m)
    # values outside the edges are dropped; the last edge is inclusive
    ((_, _, only),) = ev.by_distance([0.4, 0.5])
    assert (only.n_kin, only.tp, only.fp) == (1, 1, 0)
    assert ev.by_distance([1.6, 3.0])[0][2].n_kin == 0
    # beams on target: the near kin has more valid beams than the far one
    n_near, n_far = (k.truth.n_beams for k in ev.kin)
    assert n_near > n_far >= 3
    (_, _, few), (_, _, many) = ev.by_beams([1, n_near, 361])
    assert (few.n_kin, few.fn, many.n_kin, many.tp) == (1, 1, 1, 1)
    noise = ev.by_noise()
    assert list(noise) == [0.0, 0.01]
    assert (noise[0.0].tp, noise[0.0].fp, noise[0.01].fn, noise[0.01].fp) == (1, 0, 1, 1)
    assert ev.select(scans=[1]).metrics().n_kin == 1
    with pytest.raises(ValueError, match="bin edges"):
        ev.by_distance([1.0, 1.0])


# --------------------------------------------------------------------------- real detector, bad input


def test_geometric_detector_on_scenario_II():
    scene = scenes.paper_scenario(2, distance=0.5)
    ev = evaluate(GeometricKinDetector(reports=False), [scanned(scene)], name="geometric")
    m = ev.metrics()
    assert (m.n_kin, m.tp, m.fp, m.fn, m.same_radius) == (1, 1, 1, 0, 1)
    assert m.error_mean < 1e-4
    assert ev.false_positives() == {"cylinder r=3.5 cm (kin radius)": 1}
    assert ev.n_scans == 1 and ev.seconds > 0 and ev.detector == "geometric"
    assert evaluate(GeometricKinDetector(), [scanned(scene)], same_radius_separate=True).metrics().fp == 0


@pytest.mark.parametrize("gate", [0, -0.1, float("nan"), float("inf"), True, "0.1"])
def test_bad_gate_raises(gate):
    pair = scanned(scene_of([Robot(0, 0, 0)]))
    with pytest.raises(ValueError, match="gate must be a finite distance > 0 m"):
        evaluate(ScriptedDetector([]), [pair], gate=gate)
    with pytest.raises(ValueError, match="gate"):
        match_detections([(0, 0)], [(0, 0)], gate=gate)


def test_bad_inputs_raise():
    pair = scanned(scene_of([Robot(0, 0, 0), Robot(1, 0, 0)]))
    with pytest.raises(ValueError, match=r"pairs\[0\] must be a \(scan, scene\) pair"):
        evaluate(ScriptedDetector([]), [pair[0]])
    with pytest.raises(ValueError, match="expected a kin_envs Scene"):
        evaluate(ScriptedDetector([]), [(pair[0], "scene")])
    with pytest.raises(ValueError, match="wrong scene"):
        full, _ = scanned(pair[1], robots=(0, 1))
        evaluate(ScriptedDetector([], []), [(full, scene_of([Robot(0, 0, 0)]))])
    with pytest.raises(ValueError, match="no detect_batch"):
        evaluate(object(), [pair])
    with pytest.raises(ValueError, match="batch_size"):
        evaluate(ScriptedDetector([]), [pair], batch_size=0)
    assert DEFAULT_GATE == 0.1
