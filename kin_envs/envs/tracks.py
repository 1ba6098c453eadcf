"""The envs' tracker path: feed a :class:`detectors.KinTracker` with a frame's detections (batched over
observers), and read its tracks back as fixed-shape info or as detection rows (``obs_tracks``)."""

from __future__ import annotations

import numpy as np

from kin_envs.core.world import Scan

__all__ = ["track_info", "track_rows", "track_update"]


def track_update(tracker, scan: Scan, dets, odom_delta: np.ndarray, dt: float) -> None:
    """Advance ``tracker`` (one observer per scan row) by one frame: the detections ``(row, cols)`` of
    :func:`kin_envs.envs.common.detect_rows` (all accepted: the detector's operating point), their
    segments' scan points, and each observer's odometry increment ``odom_delta`` (rows, 3)."""
    from detectors.tracking import segment_points

    row, cols = dets if dets is not None else (np.zeros(0, np.int64), None)
    xy, pts, own, scores = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0)
    if row.size:
        xy = np.c_[cols["x"], cols["y"]]
        pts, own = segment_points(scan.ranges, scan.angles, row, cols["first_beam"], cols["last_beam"],
                                  scan.range_max)  # fmt: skip
        scores = cols["score"]
    delta = np.asarray(odom_delta, np.float64).reshape(-1, 3)
    tracker.update_batch(np.asarray(row, np.int64), xy, scores, delta, dt, pts, own,
                         accepted=np.ones(row.size, bool))  # fmt: skip


def track_info(tracker, max_tracks: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``({field: (n_observers, max_tracks) float64}, count (n_observers,))``: every observer's tracks in
    padded slots (:data:`detectors.tracking.TRACK_FIELDS`, robot frame; empty slots 0)."""
    from detectors.tracking import TRACK_FIELDS

    a = tracker.track_arrays(max_tracks)
    cols = {name: a["tracks"][:, :, j].astype(np.float64) for j, name in enumerate(TRACK_FIELDS)}
    return cols, a["count"]


def track_rows(tracker, max_tracks: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The confirmed kin tracks of every observer as detection rows ``(row, cols)`` (the layout of
    :func:`kin_envs.envs.common.detect_rows`: sorted by observer, then nearest first), for ``obs_tracks``."""
    a = tracker.track_arrays(max_tracks)
    o, s = np.nonzero(a["mask"])
    t = a["tracks"][o, s]
    kin = (t[:, 8] > 0) & (t[:, 6] >= tracker.params.kin_threshold)
    o, t = o[kin], t[kin]
    rng = np.hypot(t[:, 1], t[:, 2])
    order = np.lexsort((rng, o))
    o, t, rng = o[order], t[order], rng[order]
    m = t.shape[0]
    cols = {"range": rng.astype(np.float64), "bearing": np.arctan2(t[:, 2], t[:, 1]).astype(np.float64),
            "x": t[:, 1].astype(np.float64), "y": t[:, 2].astype(np.float64),
            "score": t[:, 6].astype(np.float64), "first_beam": np.full(m, -1, np.int64),
            "last_beam": np.full(m, -1, np.int64), "n_beams": np.zeros(m, np.int64),
            "kin_index": np.full(m, -1, np.int64)}  # fmt: skip
    return o.astype(np.int64), cols
