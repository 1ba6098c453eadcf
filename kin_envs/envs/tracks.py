"""The envs' tracker path: feed a :class:`detectors.KinTracker` with a frame's detections (batched over
observers), and read its tracks back as fixed-shape info or as detection rows (``obs_tracks``)."""

from __future__ import annotations

import numba
import numpy as np

from kin_envs.core.world import Scan

__all__ = [
    "PermissiveFeed", "VectorTracker", "auto_kin_model", "housing_beams", "make_feeder", "track_info",
    "track_rows", "track_update",
]


def track_update(tracker, scan: Scan, dets, odom_delta: np.ndarray, dt: float, feed=None) -> None:
    """Advance ``tracker`` (one observer per scan row) by one frame: the detections ``(row, cols)`` of
    :func:`kin_envs.envs.common.detect_rows` (all accepted: the detector's operating point), their
    segments' scan points, and each observer's odometry increment ``odom_delta`` (rows, 3); or, with
    ``tracker={"feed": "permissive"}``, the candidates ``feed`` of :meth:`PermissiveFeed.detect`."""
    delta = np.asarray(odom_delta, np.float64).reshape(-1, 3)
    if feed is not None:
        _feed_candidates(tracker, scan, feed, None, delta, dt)
        return
    row, cols = dets if dets is not None else (np.zeros(0, np.int64), None)
    _feed(tracker, scan, row, cols, row, delta, dt)


class _Given:
    """A detector stand-in whose trusted table call returns a result already computed (so that
    :func:`kin_envs.envs.common.detect_rows` builds the shipped detections from it, unchanged)."""

    def __init__(self, table) -> None:
        self.table = table

    def _detect_table_trusted(self, ranges, angles):
        return self.table


def _is_permissive(feed: str | None, detector) -> bool:
    """Whether ``tracker["feed"]`` gives the tracker ``detector``'s permissive candidates: ``"permissive"``,
    or ``"auto"`` where they cost no second detector call (:meth:`PermissiveFeed.one_call_for`)."""
    return feed == "permissive" or (feed == "auto" and PermissiveFeed.one_call_for(detector))


def auto_kin_model(feed: str | None, detector) -> str:
    """``tracker={"kin_model": "auto"}``: the shipped track classifier fitted on what the tracker gets:
    ``"geometric"`` for the geometric detector's permissive candidates, ``"learned"`` otherwise."""
    geometric = _is_permissive(feed, detector) and PermissiveFeed.one_call_for(detector)
    return "geometric" if geometric else "learned"


def make_feeder(feed: str | None, detector, range_noise: float):
    """The env's :class:`PermissiveFeed` for ``tracker["feed"]`` (``"permissive"``, or ``"auto"`` where it
    costs no second detector call), or ``None`` (the accepted detections)."""
    return PermissiveFeed(detector, range_noise) if _is_permissive(feed, detector) else None


class PermissiveFeed:
    """``tracker={"feed": "permissive"}``: each step's detector call gives both the shipped detections
    (``info["kin_detections"]``, bitwise those of the detector alone) and the tracker's input as the
    sequence benchmark (:mod:`kin_envs.detection.sequences`) gives it, which the track classifier is fitted
    on: every candidate of the detector at its permissive operating point
    (:func:`kin_envs.detection.benchmark.permissive`) with its score, whether the detector accepts it at
    its operating point, and each scan's own noise estimate (:func:`detectors.features.scan_noise`).

    The shipped geometric detector takes **one call**: its batched arrays keep every segment's circle fit
    (independent of ``F_threshold``), so the permissive candidates are the segments that reached the fit
    (``F`` < the permissive threshold), scored as the permissive detector scores them. Any other detector
    runs twice (its own call and its permissive one's; the learned detector's permissive run scores every
    segment with the network, without the cascade)."""

    def __init__(self, detector, range_noise: float) -> None:
        from kin_envs.detection.benchmark import PERMISSIVE_F_THRESHOLD, permissive

        self.detector = detector
        self.range_noise = float(range_noise)
        self.one_call = self.one_call_for(detector)
        self._f_perm = float(PERMISSIVE_F_THRESHOLD)
        # the scan noise read from the detector's own preprocessed rows: the same rows scan_noise_of makes
        # (the same d_max, no spike filter)
        from detectors.features import FeatureConfig

        dp = getattr(detector, "params", None)
        self._noise_on_d = self.one_call and not dp.noise_filter and float(dp.d_max) == FeatureConfig().d_max
        self.permissive = None if self.one_call else permissive(detector)

    @staticmethod
    def one_call_for(detector) -> bool:
        """Whether ``detector``'s own batched call also gives its permissive candidates (the shipped
        geometric detector, whose arrays keep every segment's circle fit): no second detector call."""
        from detectors.geometric import GeometricKinDetector
        from kin_envs.detection.benchmark import PERMISSIVE_F_THRESHOLD

        return type(detector) is GeometricKinDetector and detector.params.F_threshold < PERMISSIVE_F_THRESHOLD

    def detect_padded(self, ranges, angles, observers, poses, slots: int, hits=None,
                      range_max: float = np.inf):
        """``(dets, padded, feed)``: :meth:`detect` (one world) and the shipped detections' padded info
        columns ``padded`` = ``pad_rows(*dets, len(ranges), slots)`` (:func:`kin_envs.envs.info.pad_rows`),
        the same values; for the shipped geometric detector matched and padded in one compiled call with
        the flat rows (:func:`kin_envs.envs.common.detect_rows_padded`; ``hits``: the scan's ``(hit_kind,
        hit_index)``, as it takes them)."""
        if self.one_call:
            return self._detect(ranges, angles, observers, poses, None, slots, hits)
        from kin_envs.envs.info import pad_rows

        dets, feed = self._detect(ranges, angles, observers, poses, None)
        return dets, pad_rows(*dets, ranges.shape[0], slots), feed

    def detect(self, ranges, angles, observers, poses, robot_world=None, range_max: float = np.inf):
        """``(dets, feed)``: the shipped detections ``(row, cols)`` of
        :func:`kin_envs.envs.common.detect_rows` (trusted: the env's own scans) and the tracker's
        candidates ``(row, x, y, scores, accepted, first_beam, last_beam, noise)`` (rows of ``ranges``; their
        points are the segments' beams, computed in the tracker's update: :func:`_feed_candidates`).
        ``range_max`` is not read here (the update takes the scan's)."""
        return self._detect(ranges, angles, observers, poses, robot_world)

    def _detect(self, ranges, angles, observers, poses, robot_world, slots=None, hits=None):
        """:meth:`detect`'s ``(dets, feed)``; with ``slots`` (the one-call detector, one world)
        :meth:`detect_padded`'s ``(dets, padded, feed)``."""
        from detectors.features import scan_noise_of
        from kin_envs.envs.common import detect_rows

        n = angles.shape[0]
        if self.one_call:
            # the shipped detections' table and the segments whose fit reached F < the permissive threshold
            # (stage ACCEPTED or SHAPE), from one compiled call: the values of _detect_arrays_trusted's
            # segment arrays at those segments (the accepted ones its detections)
            fused = self.detector._detect_table_feed_trusted(ranges, angles, self._f_perm)
            table, (row, first, count, f, rc, bearing, accepted), d = fused
            if slots is None:
                dets = detect_rows(_Given(table), ranges, angles, observers, poses, robot_world, trusted=True)
            else:
                from kin_envs.envs.common import detect_rows_padded

                dets, padded = detect_rows_padded(_Given(table), ranges, angles, observers, poses, slots,
                                                  trusted=True, hits=hits)  # fmt: skip
            last = (first + count - 1) % n
            x, y = rc * np.cos(bearing), rc * np.sin(bearing)
            scores = self._f_perm / (self._f_perm + f)  # the permissive detector's score
        else:
            dets = detect_rows(self.detector, ranges, angles, observers, poses, robot_world, trusted=True)
            p = self.permissive
            fast = getattr(p, "_detect_arrays_trusted", None) or p.detect_arrays
            c = fast(ranges, angles)
            get = c.__getitem__ if isinstance(c, dict) else lambda k: getattr(c, k)
            c_ = np.ascontiguousarray  # (the tracker's trusted entry takes them as they are)
            row = c_(get("scan"), np.int64)
            first, last = c_(get("first_beam"), np.int64), c_(get("last_beam"), np.int64)
            x, y = c_(get("x"), np.float64), c_(get("y"), np.float64)
            scores = c_(get("score"), np.float64)
            # accepted: the shipped detector has the same segment (scan row, first and last beam)
            d_row, d_cols = dets
            key = lambda r, a, z: (r * n + a) * n + z  # noqa: E731
            accepted = np.isin(key(row, first, last), key(d_row, d_cols["first_beam"], d_cols["last_beam"]))
        if self.one_call and self._noise_on_d:
            from detectors.features import _scan_noise_of_d

            est, count = _scan_noise_of_d(d, self.detector._circular)  # (its _check_batch: these angles)
        else:
            est, count = scan_noise_of(ranges, angles)  # (the segmentation is not needed for it)
        est = np.where(count >= 5, est, np.nan)
        noise = np.where(np.isnan(est), self.range_noise, est)
        feed = (row, x, y, scores, accepted, first, last, noise)
        return (dets, feed) if slots is None else (dets, padded, feed)


def track_info(tracker, max_tracks: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``({field: (n_observers, max_tracks) float64}, count (n_observers,))``: every observer's tracks in
    padded slots (:data:`detectors.tracking.TRACK_FIELDS`, robot frame; empty slots 0)."""
    from detectors.tracking import TRACK_FIELDS

    own = getattr(tracker, "_track_block", None)
    if own is not None:  # a KinTracker (or VectorTracker): the block filled in the update's compiled call
        block, count = own(max_tracks)
        return dict(zip(TRACK_FIELDS, block, strict=True)), count
    a = tracker.track_arrays(max_tracks)  # (any other tracker)
    # one transposed copy (field-major, float64), each field a C-contiguous row of it: the values of a copy
    # per field (``tracks[:, :, j].astype(float64)``) at half its cost
    block = a["tracks"].transpose(2, 0, 1).astype(np.float64, order="C")
    return dict(zip(TRACK_FIELDS, block, strict=True)), a["count"]


def track_rows(tracker, max_tracks: int, angles=None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The confirmed kin tracks of every observer as detection rows ``(row, cols)`` (the layout of
    :func:`kin_envs.envs.common.detect_rows`: sorted by observer, then nearest first), for ``obs_tracks``.

    ``angles``: the scan's beam directions (robot frame, rad, evenly spaced): then ``first_beam`` /
    ``last_beam`` / ``n_beams`` are the beams the tracked housing (radius ``tracker.params.r``) would lie on,
    seen from the track's centre (every beam within ``asin(r / range)`` of its bearing, at least the nearest
    one), as an ``obs_detections="mask"`` channel needs them; without, -1 / -1 / 0."""
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
    if angles is not None and m:
        cols["first_beam"], cols["last_beam"], cols["n_beams"] = housing_beams(
            angles, cols["bearing"], rng, tracker.params.r)
    return o.astype(np.int64), cols


def housing_beams(angles, bearing, rng, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(first, last, count)`` beams (wrapping at the seam: ``first > last`` allowed) of evenly spaced
    ``angles`` (rad, either turning direction) that a circle of radius ``r`` (m) centred at ``bearing``
    (rad, same frame) and ``rng`` (m) covers: within ``asin(min(1, r / rng))`` of the bearing, or the
    nearest beam when none is."""
    angles = np.asarray(angles, np.float64).reshape(-1)
    n = angles.shape[0]
    steps = (np.diff(angles) + np.pi) % (2 * np.pi) - np.pi  # consecutive steps, wrapped to [-pi, pi)
    step = float(steps[0]) if n > 1 else 0.0
    if step == 0 or np.abs(steps - step).max() > 1e-9:
        raise ValueError(f"housing_beams: angles must be >= 2 evenly spaced beam directions, got {angles!r}")
    d = np.arctan2(np.sin(bearing - angles[0]), np.cos(bearing - angles[0])) / step  # centre, in beams
    half = np.arcsin(np.minimum(1.0, r / np.maximum(rng, r))) / abs(step)
    lo, hi = np.ceil(d - half), np.floor(d + half)
    none = lo > hi
    lo[none] = hi[none] = np.round(d[none])
    lo, hi = lo.astype(np.int64), hi.astype(np.int64)
    count = np.minimum(hi - lo + 1, n)
    return lo % n, (lo + count - 1) % n, count


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
        self._gid, self._lid = np.concatenate((self._gid, gid)), np.concatenate((self._lid, lid))
        alive = int(np.count_nonzero(self.tracker._alive))
        if self._gid.size > 4 * max(alive, 64):  # forget dead tracks' ids
            keep = np.isin(self._gid, self.tracker._id[self.tracker._alive])
            self._gid, self._lid = self._gid[keep], self._lid[keep]

    def adopt(self, observer: int, own) -> None:
        """Sub-env ``observer`` has reset and run its first frame on ``own`` (its one-observer tracker)."""
        first = self.tracker._next_id
        lid = self.tracker.adopt(observer, own)
        self._next_local[observer] = own._next_id
        self._record(np.full(lid.size, observer), first + np.arange(lid.size), lid)

    def update(self, scan: Scan, dets, observers: np.ndarray, odom_delta: np.ndarray, dt: float,
               feed=None) -> None:
        """One frame of the sub-envs ``observers`` (scan row ``r`` and detection row ``r`` are sub-env
        ``observers[r]``'s; every other observer gets no candidate and a zero odometry increment: it is
        about to be replaced by :meth:`adopt`)."""
        tr = self.tracker
        observers = np.asarray(observers, np.int64)
        delta = np.zeros((tr.n_observers, 3))
        delta[observers] = odom_delta
        first = tr._next_id
        if feed is not None:
            _feed_candidates(tr, scan, feed, observers, delta, dt)
        else:
            row, cols = dets if dets is not None else (np.zeros(0, np.int64), None)
            _feed(tr, scan, row, cols, observers[row], delta, dt)
        if tr._next_id > first:  # births: own ids per observer, in birth (= shared id) order
            self._record(*_births(tr._alive, tr._id, tr._obs, first, self._next_local))

    def _track_block(self, max_tracks: int) -> tuple[np.ndarray, np.ndarray]:
        """``KinTracker._track_block`` (:func:`track_info`'s block) with each sub-env's own track ids: the
        values of :meth:`track_arrays`' ``tracks`` transposed to float64, as :func:`track_info` made them."""
        block, count = self.tracker._track_block(max_tracks)
        if count.any():
            m = np.arange(block.shape[2]) < count[:, None]  # the filled slots (track_arrays' mask)
            ids = block[0]
            g = ids[m].astype(np.int64)
            ids[m] = self._lid[np.searchsorted(self._gid, g)].astype(np.float32)  # (as the float32 slots)
        return block, count

    def track_arrays(self, max_tracks: int) -> dict[str, np.ndarray]:
        """:meth:`detectors.KinTracker.track_arrays` with each sub-env's own track ids."""
        a = self.tracker.track_arrays(max_tracks)
        m = a["mask"]
        if m.any():
            g = a["tracks"][..., 0][m].astype(np.int64)
            a["tracks"][..., 0][m] = self._lid[np.searchsorted(self._gid, g)]
        return a


@numba.njit(cache=True, nogil=True)
def _births(alive, tid, tobs, first, next_local):
    """The tracks born this frame (alive, shared id >= ``first``) in shared id order: ``(observer, shared
    id, own id)``, each observer's own ids counted on from ``next_local`` (updated in place) in that order."""
    n = 0
    for t in range(alive.shape[0]):
        n += alive[t] and tid[t] >= first
    rows = np.empty(n, np.int64)
    n = 0
    for t in range(alive.shape[0]):
        if alive[t] and tid[t] >= first:
            rows[n] = t
            n += 1
    rows = rows[np.argsort(tid[rows])]  # (ids are distinct: any sort is the stable one)
    o, gid, lid = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    for j in range(n):
        t = rows[j]
        o[j], gid[j] = tobs[t], tid[t]
        lid[j] = next_local[o[j]]
        next_local[o[j]] += 1
    return o, gid, lid


def _feed_candidates(tracker, scan: Scan, feed, observers, delta, dt) -> None:
    """``feed`` (:meth:`PermissiveFeed.detect` on ``scan``) into ``tracker``; ``observers``: the observer of
    each scan row (``None``: row ``r`` is observer ``r``; the others get no candidate and the default
    noise)."""
    row, x, y, scores, accepted, first, last, noise = feed
    obs = row
    if observers is not None:
        full = np.full(tracker.n_observers, tracker.params.range_noise)
        full[observers] = noise
        obs, noise = observers[row], full
    _update(tracker, scan, obs, row, x, y, scores, accepted, first, last, delta, dt, noise)


def _feed(tracker, scan: Scan, row, cols, obs, delta, dt) -> None:
    if not row.size:
        row = obs = first = last = _NO_INT
        x = y = scores = _NO_FLOAT
    else:
        x, y, scores, first, last = cols["x"], cols["y"], cols["score"], cols["first_beam"], cols["last_beam"]
    _update(tracker, scan, obs, row, x, y, scores, None, first, last, delta, dt, None)


_NO_INT, _NO_FLOAT = np.zeros(0, np.int64), np.zeros(0)


def _update(tracker, scan: Scan, obs, row, x, y, scores, accepted, first, last, delta, dt, noise) -> None:
    """The tracker's frame on the env's own arrays (its trusted entry,
    ``KinTracker._update_segments_trusted``: the candidates' points computed in the update's compiled call
    from the scan's beams ``first..last`` of row ``row``): the state and outputs of ``update_batch(obs,
    c_[x, y], scores, delta, dt, *segment_points(scan.ranges, scan.angles, row, first, last,
    scan.range_max), noise, accepted)``, ``accepted=None`` all accepted (the operating point's
    detections). The candidates' arrays are passed as the env built them (C-contiguous int64 / float64 /
    bool: :func:`kin_envs.envs.common.detect_rows`, :meth:`PermissiveFeed.detect`; any other layout would
    still give the same values, in a kernel compiled for it); the scan's as the world gives them."""
    ranges, angles = scan.ranges, scan.angles
    if ranges.dtype != np.float32:
        ranges = np.ascontiguousarray(ranges, np.float64)
    elif not ranges.flags.c_contiguous:
        ranges = np.ascontiguousarray(ranges)
    if angles.dtype != np.float64 or not angles.flags.c_contiguous:
        angles = np.ascontiguousarray(angles, np.float64)
    tracker._update_segments_trusted(obs, row, x, y, scores, accepted, delta, dt, ranges, angles, first, last,
                                     float(scan.range_max), noise)  # fmt: skip
