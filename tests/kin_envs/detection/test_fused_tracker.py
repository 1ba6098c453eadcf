"""The fused frame update of detectors.KinTracker (one compiled call per frame) against the staged tracker
it replaced (tests/detectors/reference_tracking.py), on the sequence benchmark's training episodes: every
state array, pose, odometer and output bitwise equal, frame after frame."""

from dataclasses import replace

import numpy as np
import pytest

from detectors.features import scan_noise, segment_batch
from detectors.geometric import GeometricKinDetector
from detectors.tracking import KinTracker
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


@pytest.mark.parametrize("split, n_robots", [("swarm", 8), ("lookalike", None)])
def test_fused_update_is_bitwise_the_staged_one_on_sequence_episodes(split, n_robots):
    spec = training_split(split, 7)
    run = replace(spec.run, frames=25)
    if n_robots:
        spec = replace(spec, scenes=replace(spec.scenes, n_robots=(n_robots, n_robots)))
    spec = replace(spec, run=run)
    ep = episode(spec, spec.first_seed, 0.01)
    det = GeometricKinDetector(reports=False)
    perm = permissive(det)
    n = len(ep.observers)
    fused, staged = KinTracker(n_observers=n), StagedKinTracker(n_observers=n)
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
        _assert_same(fused, staged)
        n_tracks = max(n_tracks, len(fused))
    assert n_tracks >= 5  # the episode gave the tracker something to do
    assert any(t.moved for o in range(n) for t in fused.tracks(o)) or split == "lookalike"
