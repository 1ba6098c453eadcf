"""The envs' tracker path: feed a :class:`detectors.KinTracker` with a frame's detections (batched over
observers), and read its tracks back as fixed-shape info or as detection rows (``obs_tracks``)."""

from __future__ import annotations

import numpy as np

from kin_envs.core.world import Scan

__all__ = ["VectorTracker", "track_info", "track_rows", "track_update"]


def track_update(tracker, scan: Scan, dets, odom_delta: np.ndarray, dt: float) -> None:
    """Advance ``tracker`` (one observer per scan row) by one frame: the detections ``(row, cols)`` of
    :func:`kin_envs.envs.common.detect_rows` (all accepted: the detector's operating point), their
    segments' scan points, and each observer's odometry increment ``odom_delta`` (rows, 3)."""
    row, cols = dets if dets is not None else (np.zeros(0, np.int64), None)
    _feed(tracker, scan, row, cols, row, np.asarray(odom_delta, np.float64).reshape(-1, 3), dt)


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


class VectorTracker:
    """One :class:`detectors.KinTracker` over the K sub-envs of a native vector env (observer ``i`` = sub-env
    ``i``'s learner): one :meth:`update` per step for all stepped sub-envs, and a sub-env that resets runs its
    first frame on its own one-observer tracker, which :meth:`adopt` copies in (``KinTracker.adopt``).

    Track ids are each sub-env's own (from 0 after its reset, as its own tracker numbers them), so that the
    tracks are those of K separate envs with the same seeds: the shared tracker's ids are mapped back per
    observer (both increase in birth order, so the slots' id tie-break keeps its order)."""

    def __init__(self, tracker) -> None:
        self.tracker = tracker
        self.params = tracker.params
        k = tracker.n_observers
        self._next_local = np.zeros(k, np.int64)  # each observer's next own id
        self._gid = np.zeros(0, np.int64)  # shared ids (increasing) -> own ids
        self._lid = np.zeros(0, np.int64)

    def _record(self, obs: np.ndarray, gid: np.ndarray, lid: np.ndarray) -> None:
        self._gid, self._lid = np.r_[self._gid, gid], np.r_[self._lid, lid]
        if self._gid.size > 4 * max(int(self.tracker._alive.sum()), 64):  # forget dead tracks' ids
            keep = np.isin(self._gid, self.tracker._id[self.tracker._alive])
            self._gid, self._lid = self._gid[keep], self._lid[keep]

    def adopt(self, observer: int, own) -> None:
        """Sub-env ``observer`` has reset and run its first frame on ``own`` (its one-observer tracker)."""
        first = self.tracker._next_id
        lid = self.tracker.adopt(observer, own)
        self._next_local[observer] = own._next_id
        self._record(np.full(lid.size, observer), first + np.arange(lid.size), lid)

    def update(self, scan: Scan, dets, observers: np.ndarray, odom_delta: np.ndarray, dt: float) -> None:
        """One frame of the sub-envs ``observers`` (scan row ``r`` and detection row ``r`` are sub-env
        ``observers[r]``'s; every other observer gets no candidate and a zero odometry increment: it is
        about to be replaced by :meth:`adopt`)."""
        tr = self.tracker
        observers = np.asarray(observers, np.int64)
        delta = np.zeros((tr.n_observers, 3))
        delta[observers] = odom_delta
        row, cols = dets if dets is not None else (np.zeros(0, np.int64), None)
        first = tr._next_id
        _feed(tr, scan, row, cols, observers[row], delta, dt)
        if tr._next_id > first:  # births: own ids per observer, in birth (= shared id) order
            rows = np.flatnonzero(tr._alive & (tr._id >= first))
            rows = rows[np.argsort(tr._id[rows], kind="stable")]
            o = tr._obs[rows]
            order = np.argsort(o, kind="stable")
            o_s = o[order]
            start = np.searchsorted(o_s, o_s)  # first index of each observer's group
            lid = np.empty(rows.size, np.int64)
            lid[order] = self._next_local[o_s] + np.arange(rows.size) - start
            np.add.at(self._next_local, o, 1)
            self._record(o, tr._id[rows], lid)

    def track_arrays(self, max_tracks: int) -> dict[str, np.ndarray]:
        """:meth:`detectors.KinTracker.track_arrays` with each sub-env's own track ids."""
        a = self.tracker.track_arrays(max_tracks)
        m = a["mask"]
        if m.any():
            g = a["tracks"][..., 0][m].astype(np.int64)
            a["tracks"][..., 0][m] = self._lid[np.searchsorted(self._gid, g)]
        return a


def _feed(tracker, scan: Scan, row, cols, obs, delta, dt) -> None:
    from detectors.tracking import segment_points

    xy, pts, own, scores = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0)
    if row.size:
        xy = np.c_[cols["x"], cols["y"]]
        pts, own = segment_points(scan.ranges, scan.angles, row, cols["first_beam"], cols["last_beam"],
                                  scan.range_max)  # fmt: skip
        scores = cols["score"]
    tracker.update_batch(np.asarray(obs, np.int64), xy, scores, delta, dt, pts, own,
                         accepted=np.ones(row.size, bool))  # fmt: skip
