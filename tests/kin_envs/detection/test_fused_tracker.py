"""The fused frame update of detectors.KinTracker (one compiled call per frame) against the staged tracker
it replaced (tests/detectors/reference_tracking.py), on the sequence benchmark's training episodes: every
state array, pose, odometer and output bitwise equal, frame after frame."""

from dataclasses import replace

import numpy as np
import pytest

from detectors.features import scan_noise, segment_batch
from detectors.geometric import GeometricKinDetector
from detectors.tracking import KinTracker, TrackerParams
from kin_envs.detection.benchmark import permissive
from kin_envs.detection.sequences import _candidates, episode, training_split
from tests.detectors.reference_tracking import StagedKinTracker


def _assert_same(a: KinTracker, b: KinTracker) -> None:
    for name in KinTracker._FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y), name
    for name in ("poses", "odometer"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (a._next_id, a.time) == (b._next_id, b.time)
    ta, tb = a.track_arrays(16), b.track_arrays(16)
    assert all(np.array_equal(ta[k], tb[k]) for k in ta)


#: the per-frame residuals: one Gauss-Newton step from the candidate's own centre (the default), and fits of 6
#: steps from behind the points (the default before session 14), with the outline's points kept
_FITS = {"centre": TrackerParams(), "fits6": TrackerParams(frame_fit_iterations=6, frame_fit_warm_start=0,
                                                           keep_points=1)}


@pytest.mark.parametrize("fits", sorted(_FITS))
@pytest.mark.parametrize("split, n_robots", [("swarm", 8), ("lookalike", None)])
def test_fused_update_is_bitwise_the_staged_one_on_sequence_episodes(split, n_robots, fits):
    spec = training_split(split, 7)
    run = replace(spec.run, frames=25)
    if n_robots:
        spec = replace(spec, scenes=replace(spec.scenes, n_robots=(n_robots, n_robots)))
    spec = replace(spec, run=run)
    ep = episode(spec, spec.first_seed, 0.01)
    det = GeometricKinDetector(reports=False)
    perm = permissive(det)
    n = len(ep.observers)
    pr = _FITS[fits]
    fused, staged = KinTracker(pr, n_observers=n), StagedKinTracker(pr, n_observers=n)
    # the per-frame fits started at the candidate's centre, 2 steps: only their residual sums differ
    warm = KinTracker(replace(pr, frame_fit_iterations=2, frame_fit_warm_start=1), n_observers=n)
    n_tracks = 0
    for frame in range(run.frames):
        if frame:
            ep.step(frame)
        delta = ep.world.odometry_delta[ep.observers] if frame else np.zeros((n, 3))
        scan = ep.scan()
        ob, xy, sc, pts, own, acc = _candidates(perm.detect_batch(scan.ranges, scan.angles), scan,
                                                det.detect_batch(scan.ranges, scan.angles))  # fmt: skip
        noise, count = scan_noise(segment_batch(scan.ranges, scan.angles))
        noise = np.where(count >= 5, noise, 0.01)
        # alternate the optional inputs: decisions given or not, noise given or the default
        kw = {"noise": noise if frame % 2 else None, "accepted": acc if frame % 3 else None}
        fused.update_batch(ob, xy, sc, delta, 0.1, pts, own, **kw)
        staged.update_batch(ob, xy, sc, delta, 0.1, pts, own, **kw)
        warm.update_batch(ob, xy, sc, delta, 0.1, pts, own, **kw)
        for name in KinTracker._FIELDS:
            if name != "_res_chi2":
                assert np.array_equal(getattr(warm, name), getattr(fused, name)), name
        _assert_same(fused, staged)
        n_tracks = max(n_tracks, len(fused))
    assert n_tracks >= 5  # the episode gave the tracker something to do
    live = np.flatnonzero(fused._alive & (fused._res_dof > 0))
    rel = np.abs(warm._res_chi2[live] / fused._res_chi2[live] - 1)
    assert not np.array_equal(warm._res_chi2, fused._res_chi2)
    if fits == "fits6":  # 2 steps from the detector's own fit reach the 6 steps' fit
        assert np.median(rel) < 1e-3
    else:  # 1 step against 2 from the geometric detector's own fit of (nearly) the same points
        assert np.median(rel) < 0.2
    with pytest.raises(ValueError, match="frame_fit_warm_start must be 0 or 1"):
        TrackerParams(frame_fit_warm_start=2)
    with pytest.raises(ValueError, match="frame_fit_iterations must be an integer >= 0"):
        TrackerParams(frame_fit_iterations=-1)
    with pytest.raises(ValueError, match="frame_fit_iterations 0 .* needs frame_fit_warm_start 1"):
        TrackerParams(frame_fit_iterations=0, frame_fit_warm_start=0)
    with pytest.raises(ValueError, match="keep_points must be 0 or 1"):
        TrackerParams(keep_points=2)
    assert any(t.moved for o in range(n) for t in fused.tracks(o)) or split == "lookalike"


def test_tracking_cost_reports_wall_and_cpu_clock_and_the_shipped_detector():
    """tracking_cost: the tracker against the permissive detector feeding it, by the wall and the CPU clock,
    and against the shipped detector's own batched call; the benchmark script's report shows them."""
    from kin_envs.detection.sequences import tracking_cost
    from tests.scripts.helpers import load_script

    alt = TrackerParams(frame_fit_iterations=2, frame_fit_warm_start=1)
    c = tracking_cost(GeometricKinDetector(reports=False), n_robots=4, frames=4, skip=1, repeats=1,
                      alt_params=alt)
    for key in ("detector", "tracker", "outputs", "shipped"):
        assert c[f"{key}_per_frame"] > 0 and c[f"{key}_cpu_per_frame"] > 0, key
    assert c["ratio_cpu"] == pytest.approx(c["tracker_cpu_per_frame"] / c["detector_cpu_per_frame"])
    assert c["ratio_shipped_cpu"] == pytest.approx(c["tracker_cpu_per_frame"] / c["shipped_cpu_per_frame"])
    assert c["n_robots"] == 4 and c["frames"] == 3 and c["candidates_per_frame"] > 0
    text = load_script("benchmark_tracking").report([], c)
    assert "Tracking cost at 4 observers" in text and "CPU clock" in text and "detect_arrays" in text
    assert c["alt_cpu_per_frame"] > 0 and "frame_fit_warm_start=1" in text
