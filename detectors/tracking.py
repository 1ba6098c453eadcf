"""Multi-frame kin tracking: per-frame candidates + odometry -> tracks with a kin probability.

Simulator-free, like every detector: it takes what a real robot has — per-frame kin candidates (positions
and scores from any :class:`~detectors.base.KinDetector`, optionally the scan points of each candidate's
segment) and wheel-odometry increments — so it runs on recorded data as well as in the simulator.

**Frames.** Tracks live in the observer's *odometry frame*: the frame the robot's odometry integrates in
(its pose at the first frame is the origin). Each :meth:`KinTracker.update` gets the odometry increment
``(dx, dy, dtheta)`` since the previous frame, in the robot frame at the previous frame (x forward, y left,
CCW positive); candidates are given in the current robot frame (x forward, y left, m). Odometry drift
makes the odometry frame slide slowly against the world, which the constant-velocity model's process noise
absorbs.

**Per frame** (:meth:`KinTracker.update`):

1. *Predict* every track with a constant-velocity Kalman filter (state ``x, y, vx, vy``; white-noise
   acceleration ``process_accel``).
2. *Associate* candidates to tracks: Mahalanobis distance under the predicted innovation covariance,
   gated at ``gate_chi2`` (chi-square, 2 dof), solved jointly with the Hungarian method
   (:func:`scipy.optimize.linear_sum_assignment`).
3. *Update* matched tracks (Kalman update with an isotropic measurement noise
   ``meas_sigma + meas_sigma_rel * range``); unmatched candidates start tentative tracks; unmatched tracks
   that should have been seen (within ``max_range``) count a miss.
4. *Existence* probability: Bayes with a detection probability ``p_detect`` and a clutter ratio
   ``clutter_ratio`` (hit: ``p <- p / (p + (1 - p) * clutter_ratio)``; miss: ``p <- p (1 - P_D) /
   (1 - p P_D)``). A track is *confirmed* once its existence reaches ``confirm_existence`` and deleted when
   it falls below ``delete_existence``.
5. *Kin probability*, in log-odds, from three cues (each documented in :class:`TrackerParams`):

   a. **detector score**: the frame's candidate score ``s`` (higher = more kin-like, in (0, 1)) adds
      ``score_weight * (logit(s) - logit(score_prior))``. Frames of a static scene are strongly correlated
      (the same object seen from almost the same place gives the same evidence), so the weight is < 1 and
      the score part of the log-odds is clamped to ``±score_clamp``: repeating one ambiguous view cannot
      make a track certain.
   b. **accumulated outline**: the candidate's scan points, moved into the odometry frame (ego-motion
      compensated) and taken relative to the track's centre, accumulate (up to ``max_points``, newest
      kept) with their expected noise ``sigma_i = sqrt(shape_sigma**2 + (noise * d_i)**2)`` (``noise``: the
      frame's relative range noise, estimated from the scan itself by :func:`detectors.features.scan_noise`
      in :meth:`KinTracker.update_from_result`). A circle of the housing radius ``r`` is fitted to all of
      them (Gauss-Newton on the centre, radius fixed). As the observer moves and turns, the beams sample the
      outline far more densely than one scan does: a housing stays on its circle, a 7 cm prism does not.
      The cue is the Gaussian log-likelihood ratio of the residuals ``e_i`` between "on the circle"
      (``e_i ~ N(0, sigma_i^2)``) and "off it by a look-alike's typical deviation ``shape_delta``"
      (``N(0, sigma_i^2 + shape_delta^2)``), summed over the points, scaled down to at most
      ``shape_n_cap`` points' worth (neighbouring points are not independent) and clamped to
      ``±shape_clamp``. It replaces (is not added to) the previous frame's shape cue: the outline is one
      growing piece of evidence. With noise much larger than ``shape_delta`` it is honestly ~0.
   c. **motion**: static obstacles do not move in the odometry frame. A track whose filtered position has
      left the place where it was first seen by more than ``motion_dist`` (and by more than 3 standard
      deviations of the two positions' uncertainty) has *moved*: it gets ``motion_gain``, strong evidence
      for a kin (only pushed movable obstacles also move). Displacement from an anchor rather than the
      filtered speed, because a slowly wandering kin's speed estimate stays within its own noise for many
      frames, while its displacement grows. Conversely, a track seen for longer than ``static_time``
      without ever moving, while some other track of the same observer *has* moved (so the swarm around
      it is active), gets ``static_penalty``: a circle that stays put among moving kin is more likely a
      same-radius cylinder than a parked kin (set 0 where kin often park).

   ``kin_prob = sigmoid(prior + score part + shape part + motion part)``.

Tracks are plain arrays inside (the hot path); :meth:`KinTracker.tracks` builds :class:`Track` objects and
:meth:`KinTracker.track_arrays` fixed-shape padded arrays (for vector envs) on demand.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import linear_sum_assignment

from .base import DetectionResult, wrap_angle
from .features import scan_noise, segment_batch

__all__ = ["TrackerParams", "Track", "KinTracker", "TRACK_FIELDS", "fit_known_circle"]

#: Columns of :meth:`KinTracker.track_arrays`' ``tracks`` array.
TRACK_FIELDS = ("id", "x", "y", "vx", "vy", "existence", "kin_prob", "frames_seen", "confirmed", "age")


def _logit(p):
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


@dataclass(frozen=True)
class TrackerParams:
    """Parameters of :class:`KinTracker` (SI units; see the module docstring for how each enters).

    Attributes:
        r: radius of the kin's lidar housing, m (the outline cue's circle).
        process_accel: constant-velocity model's white acceleration noise, m/s^2.
        meas_sigma, meas_sigma_rel: candidate position noise ``meas_sigma + meas_sigma_rel * range``, m.
        init_speed_sigma: initial velocity uncertainty of a new track, m/s.
        gate_chi2: association gate on the squared Mahalanobis distance (9.21: 99 %, 2 dof).
        p_detect: probability that an existing object in range yields a candidate in a frame.
        clutter_ratio: how likely a hit is under "no object" relative to "object" (existence update).
        birth_existence: existence probability of a new track.
        confirm_existence, delete_existence: confirm / delete thresholds of the existence probability.
        max_range: m; a track beyond it is not expected to be seen (no miss counted).
        kin_prior: prior kin probability of a new track.
        score_prior: the score a candidate carries no evidence at (the detector's operating point).
        score_weight, score_clamp: weight of one frame's score log-odds, and the clamp of their sum.
        shape_delta: RMS deviation of a 7 cm look-alike's outline from the housing circle, m (a hexagon's
            is ~2 mm, a triangle's ~8 mm).
        shape_sigma: per-point noise floor, m; range_noise: relative range noise used when a frame gives
            none.
        shape_n_cap, shape_min_points, shape_clamp: the outline cue's point cap, minimum points, clamp.
        max_points: accumulated outline points kept per track (newest).
        motion_dist, motion_gain: the motion cue (m; log-odds once moved).
        static_time, static_penalty: a track seen this long (s) without moving, while another track has
            moved, gets this log-odds.
        kin_threshold: a confirmed track with ``kin_prob >= kin_threshold`` is reported as kin.
    """

    r: float = 0.035
    process_accel: float = 0.5
    meas_sigma: float = 0.01
    meas_sigma_rel: float = 0.01
    init_speed_sigma: float = 0.3
    gate_chi2: float = 9.21
    p_detect: float = 0.8
    clutter_ratio: float = 0.2
    birth_existence: float = 0.5
    confirm_existence: float = 0.8
    delete_existence: float = 0.1
    max_range: float = 5.0
    kin_prior: float = 0.5
    score_prior: float = 0.5
    score_weight: float = 0.4
    score_clamp: float = 4.0
    shape_delta: float = 0.002
    shape_sigma: float = 0.0005
    range_noise: float = 0.01
    shape_n_cap: int = 60
    shape_min_points: int = 8
    shape_clamp: float = 6.0
    max_points: int = 240
    motion_dist: float = 0.1
    motion_gain: float = 6.0
    static_time: float = 5.0
    static_penalty: float = -6.0
    kin_threshold: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"TrackerParams.{f.name} must be a finite number, got {v!r}")
        for name in ("r", "meas_sigma", "init_speed_sigma", "gate_chi2", "max_range", "shape_sigma",
                     "shape_delta"):  # fmt: skip
            if getattr(self, name) <= 0:
                raise ValueError(f"TrackerParams.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("p_detect", "birth_existence", "confirm_existence", "delete_existence", "kin_prior",
                     "score_prior", "kin_threshold"):  # fmt: skip
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"TrackerParams.{name} must be in (0, 1), got {getattr(self, name)!r}")
        if not self.delete_existence < self.birth_existence <= self.confirm_existence:
            raise ValueError("TrackerParams: need delete_existence < birth_existence <= confirm_existence")
        for name in ("shape_n_cap", "shape_min_points", "max_points"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(
                    f"TrackerParams.{name} must be a positive integer, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_dict(cls, d) -> TrackerParams:
        names = {f.name for f in fields(cls)}
        if not isinstance(d, dict) or set(d) - names:
            bad = sorted(set(d) - names) if isinstance(d, dict) else d
            raise ValueError(f"TrackerParams: unknown key(s) {bad}; expected a subset of {sorted(names)}")
        return cls(**d)


@dataclass(frozen=True, eq=False)
class Track:
    """One track, in the observer's odometry frame (m, m/s).

    Attributes:
        id: unique within the tracker (never reused).
        x, y: filtered position; vx, vy: filtered velocity.
        covariance: (4, 4) state covariance of ``x, y, vx, vy``.
        existence: probability that the object exists.
        kin_prob: probability that it is a kin.
        frames_seen: frames with an associated candidate.
        age: frames since the track started.
        confirmed: existence has reached ``confirm_existence``.
        points: (m, 2) accumulated outline points relative to the track's centre.
    """

    id: int
    x: float
    y: float
    vx: float
    vy: float
    covariance: np.ndarray
    existence: float
    kin_prob: float
    frames_seen: int
    age: int
    confirmed: bool
    points: np.ndarray = field(repr=False)

    @property
    def is_kin(self) -> bool:
        return self.confirmed and self.kin_prob >= 0.5


def fit_known_circle(points: np.ndarray, r: float, centre0=(0.0, 0.0), iterations: int = 8):
    """Least-squares centre of a circle of known radius ``r`` through ``points`` (m, 2).

    Minimises ``sum_i (|p_i - c| - r)^2`` over ``c`` by Gauss-Newton from ``centre0``.
    Returns ``(centre (2,), residuals (m,))``.
    """
    p = np.asarray(points, dtype=np.float64)
    c = np.asarray(centre0, dtype=np.float64).copy()
    for _ in range(iterations):
        d = p - c
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
        e = dist - r
        J = -d / dist[:, None]  # de/dc
        JtJ = J.T @ J
        if np.linalg.cond(JtJ) > 1e12:
            break
        step = np.linalg.solve(JtJ, -J.T @ e)
        c += step
        if np.hypot(*step) < 1e-9:
            break
    d = p - c
    return c, np.hypot(d[:, 0], d[:, 1]) - r


class KinTracker:
    """Tracks kin over frames from one observer's candidates and odometry (see the module docstring).

    Example::

        tracker = KinTracker()
        for ranges, odom_delta in frames:               # (n,) m; (dx, dy, dtheta) since the last frame
            result = detector.detect(ranges, angles)    # any KinDetector, ideally a permissive one
            tracker.update_from_result(result, ranges, angles, odom_delta, dt=0.1)
            kin = [t for t in tracker.tracks() if t.is_kin]
    """

    def __init__(self, params: TrackerParams | None = None) -> None:
        self.params = params or TrackerParams()
        self.reset()

    def reset(self) -> None:
        """Forget every track; the odometry frame restarts at the robot's current pose."""
        self.pose = np.zeros(3)  # the observer in its odometry frame
        self.time = 0.0
        self._next_id = 0
        self._n = 0
        cap = 16
        self._id = np.zeros(cap, np.int64)
        self._x = np.zeros((cap, 4))
        self._P = np.zeros((cap, 4, 4))
        self._exist = np.zeros(cap)
        self._lo_score = np.zeros(cap)
        self._lo_shape = np.zeros(cap)
        self._lo_motion = np.zeros(cap)
        self._seen = np.zeros(cap, np.int64)
        self._age = np.zeros(cap, np.int64)
        self._static_t = np.zeros(cap)
        self._moved = np.zeros(cap, bool)
        self._confirmed = np.zeros(cap, bool)
        self._anchor = np.zeros((cap, 2))  # where the track was first seen, odometry frame
        self._anchor_var = np.zeros(cap)
        self._points: list[np.ndarray] = [np.zeros((0, 3)) for _ in range(cap)]

    # -- the frame update --------------------------------------------------------------------------
    def update(
        self, xy, scores, odom_delta, dt: float, points: Sequence[np.ndarray] | None = None, noise=None
    ) -> None:
        """Advance one frame.

        Args:
            xy: (k, 2) candidate centres in the current robot frame (x forward, y left), m.
            scores: (k,) candidate scores in [0, 1] (higher = more kin-like).
            odom_delta: (3,) odometry increment since the previous frame, robot frame at the previous
                frame (dx, dy m; dtheta rad CCW).
            dt: s since the previous frame (> 0).
            points: optional k arrays (m_i, 2) of each candidate's scan points, robot frame, m.
            noise: the frame's relative range noise (0.01 = 1 % of the distance); default
                ``params.range_noise``.
        """
        pr = self.params
        noise = pr.range_noise if noise is None else float(noise)
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"KinTracker.update: noise must be a relative range noise >= 0, got {noise!r}")
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        delta = np.asarray(odom_delta, dtype=np.float64).reshape(-1)
        if delta.shape != (3,) or not np.all(np.isfinite(delta)):
            raise ValueError(
                f"KinTracker.update: odom_delta must be 3 finite numbers (dx, dy, dtheta), got {odom_delta!r}"
            )
        if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"KinTracker.update: dt must be a positive number of seconds, got {dt!r}")
        if scores.shape[0] != xy.shape[0] or not (np.all(np.isfinite(xy)) and np.all(np.isfinite(scores))):
            raise ValueError(
                f"KinTracker.update: xy (k, 2) and scores (k,) must be finite and of one length, got "
                f"{xy.shape} and {scores.shape}"
            )
        if points is not None and len(points) != xy.shape[0]:
            raise ValueError(f"KinTracker.update: points must hold one array per candidate ({xy.shape[0]})")
        # ego-motion: the observer's new pose in the odometry frame
        c, s = math.cos(self.pose[2]), math.sin(self.pose[2])
        self.pose = np.array(
            [self.pose[0] + c * delta[0] - s * delta[1], self.pose[1] + s * delta[0] + c * delta[1],
             float(wrap_angle(self.pose[2] + delta[2]))]
        )  # fmt: skip
        self.time += dt
        R = self._to_odom_rotation()
        z = xy @ R.T + self.pose[:2]  # candidates in the odometry frame
        rng = np.hypot(xy[:, 0], xy[:, 1])
        self._predict(dt)
        pairs = self._associate(z, rng)
        n_before = self._n
        hit = np.zeros(n_before, bool)
        for ti, ci in pairs:
            hit[ti] = True
            self._kalman_update(ti, z[ci], rng[ci])
            self._evidence(ti, scores[ci], None if points is None else points[ci], R, noise)
        matched = {ci for _, ci in pairs}
        for ci in range(xy.shape[0]):
            if ci not in matched:
                ti = self._birth(z[ci], rng[ci])
                self._evidence(ti, scores[ci], None if points is None else points[ci], R, noise)
        self._existence(hit, n_before)
        self._motion(dt)
        self._age[: self._n] += 1
        self._prune()

    def update_from_result(self, result: DetectionResult, ranges, angles, odom_delta, dt: float) -> None:
        """:meth:`update` from a detector's :class:`DetectionResult` on scan ``(ranges, angles)``: each
        detection's segment beams (``first_beam``..``last_beam``, wrapping) give its outline points."""
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = np.asarray(angles, dtype=np.float64)
        n = ranges.shape[0]
        dets = result.detections
        xy = np.array([[d.x, d.y] for d in dets]).reshape(-1, 2)
        scores = np.array([d.score for d in dets])
        pts = []
        for d in dets:
            idx = np.arange(d.first_beam, d.first_beam + ((d.last_beam - d.first_beam) % n) + 1) % n
            r = ranges[idx]
            ok = np.isfinite(r) & (r > 0)
            pts.append(np.stack([r[ok] * np.cos(angles[idx][ok]), r[ok] * np.sin(angles[idx][ok])], axis=1))
        noise, count = scan_noise(segment_batch(ranges[None], angles))
        self.update(xy, scores, odom_delta, dt, pts, noise=float(noise[0]) if count[0] >= 5 else None)

    # -- steps ----------------------------------------------------------------------------------------
    def _to_odom_rotation(self) -> np.ndarray:
        c, s = math.cos(self.pose[2]), math.sin(self.pose[2])
        return np.array([[c, -s], [s, c]])

    def _predict(self, dt: float) -> None:
        n = self._n
        if not n:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.params.process_accel**2
        Q1 = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = Q1
        Q[np.ix_([1, 3], [1, 3])] = Q1
        self._x[:n] = self._x[:n] @ F.T
        self._P[:n] = F @ self._P[:n] @ F.T + Q

    def _meas_var(self, rng: np.ndarray) -> np.ndarray:
        return (self.params.meas_sigma + self.params.meas_sigma_rel * rng) ** 2

    def _associate(self, z: np.ndarray, rng: np.ndarray) -> list[tuple[int, int]]:
        n, k = self._n, z.shape[0]
        if not n or not k:
            return []
        S = self._P[:n, None, :2, :2] + np.eye(2) * self._meas_var(rng)[None, :, None, None]  # (n, k, 2, 2)
        d = z[None, :, :] - self._x[:n, None, :2]
        det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
        m2 = (S[..., 1, 1] * d[..., 0] ** 2 - 2 * S[..., 0, 1] * d[..., 0] * d[..., 1]
              + S[..., 0, 0] * d[..., 1] ** 2) / det  # fmt: skip
        gated = m2 > self.params.gate_chi2
        cost = np.where(gated, 1e6, m2)
        rows, cols = linear_sum_assignment(cost)
        return [(int(t), int(c)) for t, c in zip(rows, cols, strict=True) if not gated[t, c]]

    def _kalman_update(self, ti: int, z: np.ndarray, rng: float) -> None:
        x, P = self._x[ti], self._P[ti]
        S = P[:2, :2] + np.eye(2) * self._meas_var(np.array(rng))
        K = P[:, :2] @ np.linalg.inv(S)
        x += K @ (z - x[:2])
        IKH = np.eye(4)
        IKH[:, :2] -= K
        self._P[ti] = IKH @ P @ IKH.T + K @ (np.eye(2) * self._meas_var(np.array(rng))) @ K.T  # Joseph form
        self._seen[ti] += 1

    def _grow(self) -> None:
        cap = self._id.shape[0] * 2
        for name in ("_id", "_x", "_P", "_exist", "_lo_score", "_lo_shape", "_lo_motion", "_seen", "_age",
                     "_static_t", "_moved", "_confirmed", "_anchor", "_anchor_var"):  # fmt: skip
            a = getattr(self, name)
            b = np.zeros((cap, *a.shape[1:]), a.dtype)
            b[: a.shape[0]] = a
            setattr(self, name, b)
        self._points += [np.zeros((0, 3)) for _ in range(cap - len(self._points))]

    def _birth(self, z: np.ndarray, rng: float) -> int:
        if self._n == self._id.shape[0]:
            self._grow()
        ti, pr = self._n, self.params
        self._n += 1
        self._id[ti] = self._next_id
        self._next_id += 1
        self._x[ti] = (z[0], z[1], 0.0, 0.0)
        self._P[ti] = np.diag(
            [*(2 * [self._meas_var(np.array(rng))]), pr.init_speed_sigma**2, pr.init_speed_sigma**2]
        )
        self._exist[ti] = pr.birth_existence
        self._lo_score[ti] = self._lo_shape[ti] = self._lo_motion[ti] = 0.0
        self._seen[ti] = 1
        self._age[ti] = 0
        self._static_t[ti] = 0.0
        self._moved[ti] = False
        self._confirmed[ti] = pr.birth_existence >= pr.confirm_existence
        self._points[ti] = np.zeros((0, 3))
        self._anchor[ti] = z
        self._anchor_var[ti] = self._meas_var(np.array(rng))
        return ti

    def _evidence(self, ti: int, score: float, pts, R: np.ndarray, noise: float) -> None:
        pr = self.params
        # (a) the detector's score: correlated frames -> weight < 1, clamped sum
        lo = self._lo_score[ti] + pr.score_weight * float(_logit(score) - _logit(pr.score_prior))
        self._lo_score[ti] = float(np.clip(lo, -pr.score_clamp, pr.score_clamp))
        # (b) the accumulated outline relative to the track centre (ego-motion compensated)
        if pts is not None and len(pts):
            pts = np.asarray(pts, np.float64)
            sig = np.sqrt(pr.shape_sigma**2 + (noise * np.hypot(pts[:, 0], pts[:, 1])) ** 2)
            rel = np.c_[pts @ R.T + self.pose[:2] - self._x[ti, :2], sig]
            acc = np.concatenate([self._points[ti], rel])[-pr.max_points :]
            self._points[ti] = acc
            if acc.shape[0] >= pr.shape_min_points:
                _, e = fit_known_circle(acc[:, :2], pr.r, centre0=self._fit_start(ti, acc[:, :2]))
                v0, v1 = acc[:, 2] ** 2, acc[:, 2] ** 2 + pr.shape_delta**2
                llr = 0.5 * np.log(v1 / v0) - 0.5 * e**2 * (1.0 / v0 - 1.0 / v1)
                llr = float(llr.sum()) * min(1.0, pr.shape_n_cap / acc.shape[0])
                self._lo_shape[ti] = float(np.clip(llr, -pr.shape_clamp, pr.shape_clamp))

    def _fit_start(self, ti: int, acc: np.ndarray) -> np.ndarray:
        cen = acc.mean(axis=0)
        away = cen + self._x[ti, :2] - self.pose[:2]  # from the observer towards the points
        norm = np.hypot(*away)
        return cen + (away / norm * self.params.r * 0.5 if norm > 0 else 0.0)

    def _existence(self, hit: np.ndarray, n_before: int) -> None:
        pr = self.params
        p = self._exist[:n_before]
        in_range = np.hypot(*(self._x[:n_before, :2] - self.pose[:2]).T) <= pr.max_range
        p_hit = p / (p + (1 - p) * pr.clutter_ratio)
        p_miss = p * (1 - pr.p_detect) / (1 - p * pr.p_detect)
        self._exist[:n_before] = np.where(hit, p_hit, np.where(in_range, p_miss, p))
        n = self._n
        self._confirmed[:n] |= self._exist[:n] >= pr.confirm_existence

    def _motion(self, dt: float) -> None:
        pr, n = self.params, self._n
        if not n:
            return
        disp = np.hypot(*(self._x[:n, :2] - self._anchor[:n]).T)
        var = self._anchor_var[:n] + 0.5 * (self._P[:n, 0, 0] + self._P[:n, 1, 1])
        moving = (disp > pr.motion_dist) & (disp > 3.0 * np.sqrt(var)) & (self._seen[:n] > 2)
        self._moved[:n] |= moving
        self._lo_motion[:n] = np.where(self._moved[:n], pr.motion_gain, 0.0)
        self._static_t[:n] += dt

    def _prune(self) -> None:
        n = self._n
        keep = np.flatnonzero(self._exist[:n] >= self.params.delete_existence)
        if keep.size == n:
            return
        for name in ("_id", "_x", "_P", "_exist", "_lo_score", "_lo_shape", "_lo_motion", "_seen", "_age",
                     "_static_t", "_moved", "_confirmed", "_anchor", "_anchor_var"):  # fmt: skip
            a = getattr(self, name)
            a[: keep.size] = a[keep]
        pts = [self._points[i] for i in keep]
        self._points[: keep.size] = pts
        self._n = int(keep.size)

    # -- outputs -----------------------------------------------------------------------------------------
    def kin_prob(self) -> np.ndarray:
        """(n_tracks,) kin probability of every current track."""
        pr, n = self.params, self._n
        active = bool(self._moved[:n].any())  # some track of this observer moved: the swarm is active
        static = np.where(
            active & ~self._moved[:n] & (self._static_t[:n] >= pr.static_time), pr.static_penalty, 0.0
        )
        lo = _logit(pr.kin_prior) + self._lo_score[:n] + self._lo_shape[:n] + self._lo_motion[:n] + static
        return 1.0 / (1.0 + np.exp(-lo))

    def __len__(self) -> int:
        return self._n

    def tracks(self) -> list[Track]:
        """The current tracks as :class:`Track` objects (built on demand)."""
        kp = self.kin_prob()
        return [
            Track(
                id=int(self._id[i]),
                x=float(self._x[i, 0]),
                y=float(self._x[i, 1]),
                vx=float(self._x[i, 2]),
                vy=float(self._x[i, 3]),
                covariance=self._P[i].copy(),
                existence=float(self._exist[i]),
                kin_prob=float(kp[i]),
                frames_seen=int(self._seen[i]),
                age=int(self._age[i]),
                confirmed=bool(self._confirmed[i]),
                points=self._points[i][:, :2].copy(),
            )  # fmt: skip
            for i in range(self._n)
        ]

    def in_robot_frame(self) -> np.ndarray:
        """(n_tracks, 2) track positions in the observer's current robot frame (x forward, y left), m."""
        R = self._to_odom_rotation()
        return (self._x[: self._n, :2] - self.pose[:2]) @ R

    def track_arrays(self, max_tracks: int) -> dict[str, np.ndarray]:
        """Fixed-shape view for vector envs: ``tracks`` (max_tracks, len(TRACK_FIELDS)) float32 padded with
        zeros (columns :data:`TRACK_FIELDS`, positions and velocities in the robot frame), ``mask``
        (max_tracks,) bool and ``count``. The most kin-like tracks come first when there are more."""
        n = self._n
        out = np.zeros((max_tracks, len(TRACK_FIELDS)), np.float32)
        mask = np.zeros(max_tracks, bool)
        if n:
            kp = self.kin_prob()
            order = np.argsort(-(kp + self._confirmed[:n]), kind="stable")[:max_tracks]
            R = self._to_odom_rotation()
            pos = self.in_robot_frame()[order]
            vel = self._x[order, 2:] @ R
            cols = np.stack(
                [self._id[order], pos[:, 0], pos[:, 1], vel[:, 0], vel[:, 1], self._exist[order], kp[order],
                 self._seen[order], self._confirmed[order], self._age[order]], axis=1,
            )  # fmt: skip
            out[: order.size] = cols
            mask[: order.size] = True
        return {"tracks": out, "mask": mask, "count": np.int64(min(n, max_tracks))}
