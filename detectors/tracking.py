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
5. *Kin probability*, in log-odds, from these cues (each documented in :class:`TrackerParams`; which
   are on by default, and why: the README):

   a. **detector score**: each frame adds the evidence ``score_weight * (logit(s) - logit(score_prior))``
      of its candidate score ``s`` (higher = more kin-like, in (0, 1); logit clipped to ±6), plus, when
      the caller passes the detector's own decisions at its operating point (``accepted``),
      ``accept_llr`` / ``reject_llr``. The cue is the *mean* evidence per frame times ``score_gain``
      (shrunk towards 0 by ``score_n0`` pseudo-frames), clamped to ``±score_clamp``: frames of one object
      are strongly correlated (the same object seen from almost the same place gives the same score), so
      the evidence is how consistently the detector calls it kin, not how often it has been seen; the
      mean still averages out the per-frame score noise as the beam pattern slides over the object.
   r. **per-frame residual** (off by default, ``resid_clamp = 0``): each frame's points of the candidate
      (one pose: no odometry drift, valid while the object moves) are compared with a circle of the housing
      radius fitted by one Gauss-Newton step from the candidate's own centre (by default:
      ``frame_fit_iterations``); the Gaussian log-likelihood ratio of the noise-normalised residuals, "on
      the circle" (``N(0, sigma_i^2)``) vs "off it by ``shape_delta``", with the fit's 2 degrees of freedom
      taken out, is summed over the track's frames (clamped to ``±resid_clamp``). For a circle it is pure
      noise; for a look-alike a systematic term accumulates (the noise of the sum grows as ``sqrt(N)``, the
      systematic part as ``N``). Its information per point is ~``(shape_delta / sigma)^4``: decisive at
      millimetre noise, ~0 at 1 % range noise beyond 0.3 m (measured on the sequence benchmark's
      training episodes, where it did not help), hence off.
   b. **accumulated outline** (off by default, ``shape_clamp = 0``: blurred by heading drift beyond
      ~1 m, no help on the training episodes, and its refit is the tracker's costliest step): the
      candidate's scan points, moved into the odometry frame (ego-motion compensated), accumulate
      (up to ``max_points``, newest kept) with their expected noise
      ``sigma_i = sqrt(shape_sigma**2 + (noise * d_i)**2)`` (``noise``: the frame's relative range noise,
      estimated from the scan itself by :func:`detectors.features.scan_noise` in
      :meth:`KinTracker.update_from_result`). A circle of the housing radius ``r`` is fitted to all of
      them (Gauss-Newton on the centre, radius fixed, warm-started at the last fit). As the observer
      moves and turns, the beams sample the outline far more densely than one scan does: a housing stays
      on its circle, a 7 cm prism does not. The cue is the Gaussian log-likelihood ratio of the residuals
      ``e_i`` between "on the circle" (``e_i ~ N(0, sigma_i^2)``, ``sigma_i`` grown by the odometry's
      random-walk error since the point was seen, ``odom_heading_rate``) and "off it by a look-alike's typical
      deviation ``shape_delta``" (``N(0, sigma_i^2 + shape_delta^2)``), summed over the points, scaled
      down to at most ``shape_n_cap`` points' worth (neighbouring points are not independent) and clamped
      to ``±shape_clamp``. It replaces (is not added to) the previous frame's shape cue: the outline is
      one growing piece of evidence. With noise much larger than ``shape_delta`` it is honestly ~0. Points
      of a track with a significant velocity (beyond 2 standard deviations) are carried along it to the
      current time, and their variance grows with that velocity's uncertainty times their age, so a moving
      object's smeared history weighs little; other tracks are tested as static objects. Once a track has
      moved (cue c) its outline is no evidence at all: the shape cue is set to 0.
   c. **motion**: static obstacles do not move in the odometry frame. A track whose filtered position has
      left the place where it was first seen by more than ``motion_dist`` (and by more than 3 standard
      deviations of the two positions' uncertainty plus the odometry drift since, which slides static
      objects through the odometry frame) has *moved*: it gets ``motion_gain``, strong evidence
      for a kin (only pushed movable obstacles also move). Displacement from an anchor rather than the
      filtered speed, because a slowly wandering kin's speed estimate stays within its own noise for many
      frames, while its displacement grows. Conversely, a track seen for longer than ``static_time``
      without ever moving, while some other track of the same observer *has* moved (so the swarm around
      it is active), gets ``static_penalty``: a circle that stays put among moving kin is more likely a
      same-radius cylinder than a parked kin. Off by default (``static_penalty = 0``): a parked kin and a
      same-radius cylinder are indistinguishable, and in the swarm episodes parked kin far outnumber
      same-radius cylinders; set it (e.g. -4) where same-radius cylinders are the bigger risk.

   ``kin_prob = sigmoid(prior + score part + residual part + shape part + motion part)`` — the
   *hand-tuned fusion*, ``KinTracker(kin_model="hand")``.

6. *The kin decision* by default (``kin_model="learned"``) is a **learned track-level classifier**
   (:class:`TrackKinModel`, shipped as ``checkpoints/tracker_kin_default.json``): a small network (one
   tanh layer of 8 units) over per-track features (:data:`TRACK_FEATURES`: the detector's score log-odds
   averaged, spread, maximum and last; the detector's own decisions; frames seen, beams, range; the motion
   statistic in the odometry frame; existence; the share of the observer's tracks that moved; the
   per-frame residuals' summed chi-square, cue r's statistic), fitted on training-seed
   sequence episodes (``scripts/fit_track_classifier.py``). A track seen in fewer than its ``min_frames``
   frames takes the detector's own decision of its last frame instead, so that a young track is never
   worse than the single scan. The cues above still run (their state feeds the features); only their
   hand-set weights are replaced. It is fitted on candidates *with* their scan points (``points`` /
   ``owner``: the beams and the per-frame residuals are among its inputs); a caller without points
   should use ``kin_model="hand"``. The shipped model answers "a kin in view here, this frame" (its
   labels are the per-frame benchmark's) and gives a track not updated this frame probability 0
   (``TrackKinModel.hit_only``).

Tracks are plain arrays inside (the hot path); :meth:`KinTracker.tracks` builds :class:`Track` objects and
:meth:`KinTracker.track_arrays` fixed-shape padded arrays (for vector envs) on demand.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

from .base import DetectionResult
from .features import scan_noise, segment_batch

__all__ = ["TrackerParams", "Track", "KinTracker", "TRACK_FIELDS", "TRACK_FEATURES", "TrackKinModel",
           "DEFAULT_KIN_MODEL", "fit_known_circle", "segment_points"]

#: Columns of :meth:`KinTracker.track_arrays`' ``tracks`` array.
TRACK_FIELDS = ("id", "x", "y", "vx", "vy", "existence", "kin_prob", "frames_seen", "confirmed", "age")

#: Inputs of the track-level kin classifier (:class:`TrackKinModel`), one row per track
#: (:meth:`KinTracker.track_features`): the detector's score logits (clipped to ±6) averaged over the
#: track's frames, their standard deviation, maximum and the last one, and the last one if the track was
#: updated this frame (else -6); the share of frames the detector accepted at its operating point, whether
#: it accepted the last one (0.5 when not given) and that flag if updated this frame (else 0); whether the
#: track was updated this frame; log of the frames seen; log of the last candidate's beams; its range (m); the
#: motion statistic (displacement from where first seen over its standard deviation with the odometry
#: drift since, clipped to 10) and the motion cue's flag; the existence probability; the filtered speed
#: over its standard deviation (clipped to 10); and the scene around it: the share of the observer's
#: confirmed tracks that have moved and log(1 + their number) — in a swarm many tracks move and a kin is
#: the likely object, among static look-alikes few do; and the per-frame residuals (each frame's points
#: against a circle of the housing radius fitted from the candidate's centre, one pose so no odometry drift,
#: noise-normalised chi-square summed over the track's frames, as its excess over the degrees of freedom
#: in standard deviations, clipped to ±10).
TRACK_FEATURES = ("mean_logit", "std_logit", "max_logit", "last_logit", "hit_logit", "accept_rate",
                  "last_accepted", "hit_accepted", "hit", "log_frames", "log_beams", "range", "motion_z",
                  "moved", "existence", "speed_z", "moved_share", "log_moved", "resid_z")  # fmt: skip

_I_LOG_FRAMES, _I_HIT_ACC = TRACK_FEATURES.index("log_frames"), TRACK_FEATURES.index("hit_accepted")
_I_HIT = TRACK_FEATURES.index("hit")

#: The shipped track-level kin classifier (``scripts/fit_track_classifier.py --ship`` writes it).
DEFAULT_KIN_MODEL = Path(__file__).resolve().parent / "checkpoints" / "tracker_kin_default.json"
#: the track classifier fitted on the geometric detector's permissive candidates (``kin_model="geometric"``;
#: ``scripts/fit_track_classifier.py --detector geometric --ship``): held-out training seeds at 1 % noise,
#: target-window F1 swarm 0.714 / lookalike 0.692 with that feed, against 0.667 / 0.518 with the default model
GEOMETRIC_KIN_MODEL = Path(__file__).resolve().parent / "checkpoints" / "tracker_kin_geometric.json"


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
        score_weight: weight of one frame's score log-odds (relative to ``score_prior``'s).
        accept_llr, reject_llr: with the detector's own decisions at its operating point (``accepted`` in
            :meth:`KinTracker.update_batch`), the evidence a frame adds for an accepted / rejected
            candidate (on top of the score's).
        score_per_metre: how much the score bar ``logit(score_prior)`` (the bar at 1 m) falls per metre
            of range, log-odds/m: a detector's scores fall with range (fewer beams), kin's and
            look-alikes' alike.
        score_gain, score_n0, score_clamp: the score cue is ``score_gain`` times the mean evidence per
            frame (``score_n0`` pseudo-frames of zero evidence in the mean), clamped to ``±score_clamp``.
        resid_clamp: clamp of the per-frame residual cue's sum in the hand-tuned fusion (0: off; the
            per-frame residuals are summed anyway: the track classifier reads their chi-square, ``resid_z``).
        shape_delta: RMS deviation of a 7 cm look-alike's outline from the housing circle, m (a hexagon's
            is ~2 mm, a triangle's ~8 mm).
        shape_sigma: per-point noise floor, m; range_noise: relative range noise used when a frame gives
            none.
        shape_n_cap, shape_min_points, shape_clamp: the outline cue's point cap, minimum points, clamp
            (0: off, and its refit skipped).
        odom_heading_rate, odom_position_rate: the odometry's random-walk heading (rad/sqrt(m)) and position
            (m/sqrt(m)) error per metre of wheel travel; a point seen ``L`` m of travel ago has drifted by
            ``sqrt(L) * (odom_heading_rate * range + odom_position_rate)``. Defaults match
            ``kin_envs``' default odometry model (noise_k = 0.005 m^1/2, wheel base 0.16 m).
        wheel_base: m, turns the odometry's dtheta into wheel travel for the odometer.
        max_points: accumulated outline points kept per track (newest), when kept: for the outline cue
            (``shape_clamp > 0``) or with ``keep_points`` 1; otherwise none (:attr:`Track.points` empty:
            writing every candidate's points into a ring per track was ~5 % of a 64-observer frame).
        keep_points: 1 keeps the outline points (:attr:`Track.points`) with the outline cue off too.
        motion_dist, motion_gain: the motion cue (m; log-odds once moved).
        static_time, static_penalty: a track seen this long (s) without moving, while another track has
            moved, gets this log-odds (0: off).

    The defaults were tuned (:func:`kin_envs.detection.sequences.tune_tracker`,
    ``scripts/tune_tracker.py``) on training-seed sequence episodes (swarm and lookalike, 1 % noise) for
    the shipped learned and the geometric detector jointly; re-run it for another detector or checkpoint.
        kin_threshold: a confirmed track with ``kin_prob >= kin_threshold`` is reported as kin.
        min_score: candidates scoring below this are dropped before association: a permissive detector
            scores every segment, and those of walls slide along the wall as the observer moves, which
            would read as motion.
        birth_min_score: an unmatched candidate starts a track only if it scores at least this (0: every
            one does); a candidate below it still updates a track it is associated with (unlike
            ``min_score``, which drops it before association). For the learned detector's permissive feed
            0.6 cuts the live tracks at 64 observers by ~1/3 (its 0.1-0.6 candidates, mostly walls and
            clutter, started them; every stage scales with the tracks), within 0.02 of no floor on every
            held-out figure with the shipped classifier. Off by default: scores are the detector's own
            scale, and the geometric detector's accepted detections of kin score below 0.6 about 40 % of
            the time (an env's default feed), where a floor would keep them from ever starting a track.
        frame_residuals: 1 computes the per-frame residuals (cue r, the classifier's ``resid_z``) every
            frame; 0 skips them (``resid_z`` reads 0: for a kin model fitted with them off, which does not
            read it; the residual cue, ``resid_clamp``, needs them).
        frame_fit_iterations, frame_fit_warm_start: the per-frame residuals (the classifier's ``resid_z``):
            each candidate's points against a circle of radius ``r`` fitted by ``frame_fit_iterations``
            Gauss-Newton steps (0: none) from where ``frame_fit_warm_start`` says: 1 (default) the
            candidate's own centre (the geometric detector's is its circle fit of the same points, the
            learned detector's its positioning), in the robot frame, one pass over the points per step and
            one for the residuals; 0 from 0.7 ``r`` behind the points' middle, in the odometry frame
            (vectorised lanes: the rounds before issue 12's session 14 ran 6 such steps). Default 1 step
            from the centre: on held-out training seeds, refitted, within ±0.02 of the 6-step fits on
            every figure (F1, same-radius and prism rejection, two training sets) at ~1/3 of their cost; 0
            steps cost less again but moved same-radius rejection by up to 0.06 (README, "Multi-frame kin
            tracking", session 14). Refit the classifier for another setting.
    """

    r: float = 0.035
    process_accel: float = 0.25
    meas_sigma: float = 0.01
    meas_sigma_rel: float = 0.01
    init_speed_sigma: float = 0.3
    gate_chi2: float = 9.21
    p_detect: float = 0.6
    clutter_ratio: float = 0.4
    birth_existence: float = 0.8
    confirm_existence: float = 0.8
    delete_existence: float = 0.1
    max_range: float = 5.0
    kin_prior: float = 0.5
    score_prior: float = 0.93
    score_weight: float = 0.5
    score_clamp: float = 4.0
    accept_llr: float = 1.0
    reject_llr: float = -1.0
    score_gain: float = 8.0
    score_per_metre: float = 0.0
    score_n0: float = 0.0
    shape_delta: float = 0.002
    shape_sigma: float = 0.0005
    range_noise: float = 0.01
    shape_n_cap: int = 60
    shape_min_points: int = 8
    shape_clamp: float = 0.0
    resid_clamp: float = 0.0
    odom_heading_rate: float = 0.045
    odom_position_rate: float = 0.005
    wheel_base: float = 0.16
    max_points: int = 120
    motion_dist: float = 0.1
    motion_gain: float = 6.0
    static_time: float = 3.0
    static_penalty: float = 0.0
    kin_threshold: float = 0.5
    min_score: float = 0.1
    birth_min_score: float = 0.0
    frame_residuals: int = 1
    frame_fit_iterations: int = 1
    frame_fit_warm_start: int = 1
    keep_points: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"TrackerParams.{f.name} must be a finite number, got {v!r}")
        for name in ("r", "meas_sigma", "init_speed_sigma", "gate_chi2", "max_range", "shape_sigma",
                     "shape_delta", "wheel_base"):  # fmt: skip
            if getattr(self, name) <= 0:
                raise ValueError(f"TrackerParams.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("odom_heading_rate", "odom_position_rate"):  # 0: exact odometry
            if getattr(self, name) < 0:
                raise ValueError(f"TrackerParams.{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("min_score", "birth_min_score"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"TrackerParams.{name} must be in [0, 1), got {getattr(self, name)!r}")
        for name in ("p_detect", "birth_existence", "confirm_existence", "delete_existence", "kin_prior",
                     "score_prior", "kin_threshold"):  # fmt: skip
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"TrackerParams.{name} must be in (0, 1), got {getattr(self, name)!r}")
        if not self.delete_existence < self.birth_existence <= self.confirm_existence:
            raise ValueError("TrackerParams: need delete_existence < birth_existence <= confirm_existence")
        if self.frame_fit_warm_start not in (0, 1):
            raise ValueError(
                f"TrackerParams.frame_fit_warm_start must be 0 or 1, got {self.frame_fit_warm_start!r}"
            )
        for name in ("shape_n_cap", "shape_min_points", "max_points"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(
                    f"TrackerParams.{name} must be a positive integer, got {getattr(self, name)!r}"
                )
        if int(self.frame_fit_iterations) != self.frame_fit_iterations or self.frame_fit_iterations < 0:
            v = self.frame_fit_iterations
            raise ValueError(f"TrackerParams.frame_fit_iterations must be an integer >= 0, got {v!r}")
        if self.frame_fit_iterations == 0 and self.frame_fit_warm_start != 1:
            raise ValueError("TrackerParams: frame_fit_iterations 0 (no fit) needs frame_fit_warm_start 1 "
                             "(the residuals at the candidate's own centre), got "
                             f"{self.frame_fit_warm_start!r}")  # fmt: skip
        if self.frame_residuals not in (0, 1):
            raise ValueError(f"TrackerParams.frame_residuals must be 0 or 1, got {self.frame_residuals!r}")
        if self.frame_residuals == 0 and self.resid_clamp != 0:
            raise ValueError("TrackerParams: resid_clamp (the per-frame residual cue) needs frame_residuals "
                             f"1, got resid_clamp {self.resid_clamp!r} with frame_residuals 0")  # fmt: skip
        if self.keep_points not in (0, 1):
            raise ValueError(f"TrackerParams.keep_points must be 0 or 1, got {self.keep_points!r}")

    @classmethod
    def from_dict(cls, d) -> TrackerParams:
        names = {f.name for f in fields(cls)}
        if not isinstance(d, dict) or set(d) - names:
            bad = sorted(set(d) - names) if isinstance(d, dict) else d
            raise ValueError(f"TrackerParams: unknown key(s) {bad}; expected a subset of {sorted(names)}")
        return cls(**d)


@numba.njit(cache=True, nogil=True)
def _dense_layer(h, W, b):
    """``h @ W + b``, one row at a time on one thread."""
    n, k = h.shape
    m = W.shape[1]
    out = np.empty((n, m))
    if m < 4:  # the output layer: across rows instead (one row's chain of k dependent sums was ~8 us a frame)
        for j in range(m):
            for r in range(n):
                out[r, j] = b[j]
            for i in range(k):  # each sum in the same order as below: the same bits
                w = W[i, j]
                for r in range(n):
                    out[r, j] += h[r, i] * w
        return out
    for r in range(n):
        for j in range(m):
            out[r, j] = b[j]
        for i in range(k):  # the units in the inner loop: contiguous rows of W, vectorised
            v = h[r, i]
            for j in range(m):
                out[r, j] += v * W[i, j]
    return out


# exp, tanh and the logistic on arrays, compiled and vectorised (numba's math.exp / math.tanh are scalar libm
# calls: ~4x numpy's SIMD ones); the track classifier (TrackKinModel) and the tracker's compiled kin decision
# both call these, so that the two give the same bits. exp: round x / ln 2 to an integer k with the 1.5 * 2^52
# trick (k in the low mantissa bits), r = x - k ln 2 in two parts (|r| <= ln 2 / 2), e^r by its Taylor series
# to r^13 (truncation < 1e-17 relative), times 2^k built from k's bits: within 1 ulp of numpy's (tested)
_LOG2E, _LN2_HI, _LN2_LO = 1.4426950408889634, 6.93147180369123816490e-01, 1.90821492927058770002e-10
_MAGIC, _MAGIC_BITS = 6755399441055744.0, 0x4338000000000000


@intrinsic
def _bits_of(typingctx, x):
    """A float64's bits as an int64 (an LLVM bitcast: no memory, vectorises)."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], context.get_value_type(types.int64))

    return types.int64(types.float64), codegen


@intrinsic
def _float_of(typingctx, i):
    """The float64 of an int64's bits (an LLVM bitcast)."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@numba.njit(cache=True, nogil=True, inline="always")
def _exp1(y):
    """``e^y`` for ``|y| <= 700`` (no check: callers clip), inlined into their vectorised loops."""
    si = y * _LOG2E + _MAGIC
    kf = si - _MAGIC
    r = (y - kf * _LN2_HI) - kf * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    return p * _float_of((_bits_of(si) - _MAGIC_BITS + 1023) << 52)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _exp_into(x, out, lo, hi):
    """``out[i] = exp(clip(x[i], lo, hi))`` on 1-D arrays, ``-700 <= lo <= hi <= 700``."""
    for i in range(x.shape[0]):
        out[i] = _exp1(min(max(x[i], lo), hi))


@numba.njit(cache=True, nogil=True, error_model="numpy")  # no zero-division checks: they stop vectorising
def _tanh_inplace(a):
    """``a[i] = tanh(a[i])`` on a 1-D contiguous array: ``1 - 2 / (e^2x + 1)`` with :func:`_exp1`
    (|x| clipped to 20, where tanh is 1 in float64); absolute error ~3e-16 (tested against numpy's)."""
    for i in range(a.shape[0]):
        e = _exp1(min(max(2.0 * a[i], -40.0), 40.0))
        a[i] = 1.0 - 2.0 / (e + 1.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sigmoid(z):
    """``1 / (1 + e^-z)`` of a 1-D array (``z`` clipped to ±700: below ~1e-304 the value is ~0 anyway)."""
    out = np.empty(z.shape[0])
    for i in range(z.shape[0]):
        out[i] = 1.0 / (1.0 + _exp1(min(max(-z[i], -700.0), 700.0)))
    return out


def _tanh(h: np.ndarray) -> np.ndarray:
    """:func:`_tanh_inplace` of a copy of ``h`` (any shape)."""
    out = np.array(h, np.float64, order="C", copy=True)
    _tanh_inplace(out.reshape(-1))
    return out


class TrackKinModel:
    """Track-level kin classifier: a small network over :data:`TRACK_FEATURES` (standardised), ``tanh``
    hidden layers (none: logistic regression), one output logit (numpy arrays; the layers' sums, ``tanh``
    and the logistic are compiled, the tracker's compiled kin decision calls the same functions).

    Fitted with :meth:`fit` (scipy L-BFGS, deterministic) on training-seed sequence episodes
    (:func:`kin_envs.detection.sequences.track_samples`); the output is shifted by ``-logit(threshold)``
    so that ``kin_prob >= 0.5`` is the operating point chosen on those episodes.

    Args:
        mean, scale: (F,) standardisation of the features.
        layers: ``[(W (in, out), b (out,)), ...]``, the last with ``out = 1``.
        features: the feature names, must be :data:`TRACK_FEATURES`.
        info: free-form metadata (what it was fitted on), kept in the JSON.
        min_frames: a track seen in fewer frames takes the detector's own decision of its last frame
            instead (kin probability 0.75 if updated this frame by a candidate the detector accepted at its
            operating point, else 0.25): a young track's features say little more than that one frame.
        hit_only: a track not updated this frame gets kin probability 0. The model is fitted to say
            "a kin in view here, this frame" (the per-frame benchmark's question); a track that coasts
            had no candidate at all from a permissive detector, so the object is hidden or gone. Off:
            coasting tracks keep the model's probability (e.g. to keep following an occluded kin).
    """

    def __init__(self, mean, scale, layers, features=TRACK_FEATURES, info=None, min_frames: int = 0,
                 hit_only: bool = False) -> None:  # fmt: skip
        if tuple(features) != TRACK_FEATURES:
            raise ValueError(f"TrackKinModel: features {list(features)} are not this tracker's "
                             f"{list(TRACK_FEATURES)}; re-fit (scripts/fit_track_classifier.py)")  # fmt: skip
        F = len(TRACK_FEATURES)
        self.mean = np.asarray(mean, np.float64).reshape(-1)
        self.scale = np.asarray(scale, np.float64).reshape(-1)
        self.layers = [(np.asarray(W, np.float64), np.asarray(b, np.float64).reshape(-1)) for W, b in layers]
        if self.mean.shape != (F,) or self.scale.shape != (F,) or not np.all(self.scale > 0):
            raise ValueError(f"TrackKinModel: mean and scale must be ({F},), scale > 0")
        n_in = F
        for W, b in self.layers:
            if W.ndim != 2 or W.shape[0] != n_in or b.shape != (W.shape[1],):
                raise ValueError(f"TrackKinModel: layer shapes {W.shape}, {b.shape} do not chain from {n_in}")
            n_in = W.shape[1]
        if not self.layers or n_in != 1:
            raise ValueError("TrackKinModel: need at least one layer, the last with one output")
        if not all(np.all(np.isfinite(a)) for W, b in self.layers for a in (W, b)) or not np.all(
            np.isfinite(self.mean)
        ):
            raise ValueError("TrackKinModel: non-finite weights")
        if isinstance(min_frames, bool) or int(min_frames) != min_frames or min_frames < 0:
            raise ValueError(f"TrackKinModel: min_frames must be an integer >= 0, got {min_frames!r}")
        self.min_frames = int(min_frames)
        if not isinstance(hit_only, bool | np.bool_):
            raise ValueError(f"TrackKinModel: hit_only must be a bool, got {hit_only!r}")
        self.hit_only = bool(hit_only)
        self.info = dict(info or {})

    def logit(self, X: np.ndarray) -> np.ndarray:
        """(n,) kin log-odds of the feature rows ``X`` (n, F)."""
        h = (np.asarray(X, np.float64).reshape(-1, len(TRACK_FEATURES)) - self.mean) / self.scale
        for i, (W, b) in enumerate(self.layers):
            # compiled, not ``h @ W``: OpenBLAS threads a (n, 19) x (19, 8) product, and on a busy 2-core
            # machine that cost ~7x a single-threaded loop (measured at 64 observers)
            h = _dense_layer(np.ascontiguousarray(h), W, b)
            if i < len(self.layers) - 1:
                h = _tanh(h)  # compiled and vectorised, the tracker's kin decision's tanh (the same bits)
        return h[:, 0]

    def kin_prob(self, X: np.ndarray) -> np.ndarray:
        """(n,) kin probability of the feature rows ``X`` (n, F), young tracks by the detector's decision."""
        X = np.asarray(X, np.float64).reshape(-1, len(TRACK_FEATURES))
        p = _sigmoid(np.ascontiguousarray(self.logit(X)))
        if self.min_frames > 0:
            young = X[:, _I_LOG_FRAMES] < math.log(self.min_frames) - 1e-9
            p = np.where(young, np.where(X[:, _I_HIT_ACC] > 0.75, 0.75, 0.25), p)
        if self.hit_only:
            p = np.where(X[:, _I_HIT] > 0.5, p, 0.0)
        return p

    def to_dict(self) -> dict:
        return {"features": list(TRACK_FEATURES), "mean": self.mean.tolist(), "scale": self.scale.tolist(),
                "layers": [[W.tolist(), b.tolist()] for W, b in self.layers], "min_frames": self.min_frames,
                "hit_only": self.hit_only, "info": self.info}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict) -> TrackKinModel:
        keys = {"features", "mean", "scale", "layers", "info", "min_frames", "hit_only"}
        if not isinstance(d, dict) or set(d) - keys or not {"mean", "scale", "layers"} <= set(d):
            raise ValueError(f"TrackKinModel: expected a dict with keys {sorted(keys)}, got "
                             f"{sorted(d) if isinstance(d, dict) else type(d).__name__}")  # fmt: skip
        return cls(d["mean"], d["scale"], d["layers"], d.get("features", TRACK_FEATURES), d.get("info"),
                   d.get("min_frames", 0), d.get("hit_only", False))

    @classmethod
    def load(cls, path=None) -> TrackKinModel:
        """Load a model JSON (default: the shipped :data:`DEFAULT_KIN_MODEL`)."""
        path = Path(DEFAULT_KIN_MODEL if path is None else path)
        try:
            d = json.loads(path.read_text())
            return cls.from_dict(d)
        except (OSError, ValueError, TypeError) as e:
            raise ValueError(f"TrackKinModel: cannot load {path}: {e}") from e

    @classmethod
    def fit(cls, X, y, weight=None, hidden: Sequence[int] = (), l2: float = 1e-3, seed: int = 0,
            max_iter: int = 500, info=None, min_frames: int = 0,
            hit_only: bool = False) -> TrackKinModel:  # fmt: skip
        """Fit on feature rows ``X`` (n, F) and labels ``y`` (n,) in {0, 1}: weighted cross-entropy plus
        ``l2`` times the squared weights, minimised by scipy's L-BFGS from a seeded initialisation
        (deterministic for a given input)."""
        from scipy.optimize import minimize

        X = np.asarray(X, np.float64).reshape(-1, len(TRACK_FEATURES))
        y = np.asarray(y, np.float64).reshape(-1)
        w = np.ones(y.shape[0]) if weight is None else np.asarray(weight, np.float64).reshape(-1)
        if y.shape[0] != X.shape[0] or w.shape != y.shape or not np.all(np.isfinite(X)) or X.shape[0] < 2:
            raise ValueError(f"TrackKinModel.fit: X (n, {len(TRACK_FEATURES)}), y (n,) and weight (n,) must "
                             f"be finite and of one length, got {X.shape}, {y.shape}, {w.shape}")  # fmt: skip
        w = w / w.sum()
        mean, scale = X.mean(0), X.std(0)
        scale = np.where(scale > 1e-9, scale, 1.0)
        Z = (X - mean) / scale
        sizes = [Z.shape[1], *[int(h) for h in hidden], 1]
        rng = np.random.default_rng(seed)
        shapes = [(sizes[i], sizes[i + 1]) for i in range(len(sizes) - 1)]
        theta0 = np.concatenate(
            [np.r_[rng.normal(0, 1 / math.sqrt(a), a * b), np.zeros(b)] for a, b in shapes]
        )

        def unpack(theta):
            out, i = [], 0
            for a, b in shapes:
                out.append((theta[i : i + a * b].reshape(a, b), theta[i + a * b : i + a * b + b]))
                i += a * b + b
            return out

        def loss(theta):
            layers = unpack(theta)
            hs = [Z]
            for i, (W, b) in enumerate(layers):
                h = hs[-1] @ W + b
                hs.append(np.tanh(h) if i < len(layers) - 1 else h)
            z = hs[-1][:, 0]
            # cross-entropy with logits, stable: log(1 + e^z) - y z
            f = np.sum(w * (np.logaddexp(0.0, z) - y * z))
            g = (w * (1.0 / (1.0 + np.exp(-z)) - y))[:, None]
            grads = []
            for i in range(len(layers) - 1, -1, -1):
                W, b = layers[i]
                grads.append((hs[i].T @ g + 2 * l2 * W, g.sum(0)))
                if i:
                    g = (g @ W.T) * (1 - hs[i] ** 2)
            f += l2 * sum(float(np.sum(W * W)) for W, _ in layers)
            return f, np.concatenate([np.r_[gW.ravel(), gb] for gW, gb in reversed(grads)])

        res = minimize(loss, theta0, jac=True, method="L-BFGS-B", options={"maxiter": int(max_iter)})
        layers = unpack(res.x)
        # an input constant over the rows (e.g. resid_z with TrackerParams.frame_residuals 0) carries nothing:
        # its first-layer weights exactly 0, so that the tracker's compiled decision skips it
        layers[0][0][np.std(X, axis=0) <= 1e-9] = 0.0
        return cls(mean, scale, layers, min_frames=min_frames, hit_only=hit_only,
                   info={**(info or {}), "loss": float(res.fun), "hidden": [int(h) for h in hidden],
                         "l2": l2})  # fmt: skip

    def shifted(self, threshold: float) -> TrackKinModel:
        """The same model with its output moved so that ``kin_prob >= 0.5`` means ``p >= threshold``."""
        if not 0 < threshold < 1:
            raise ValueError(f"TrackKinModel.shifted: threshold must be in (0, 1), got {threshold!r}")
        layers = [(W.copy(), b.copy()) for W, b in self.layers]
        layers[-1][1][0] -= math.log(threshold / (1 - threshold))
        return TrackKinModel(self.mean, self.scale, layers, info={**self.info, "threshold": float(threshold)},
                             min_frames=self.min_frames, hit_only=self.hit_only)  # fmt: skip

    def with_min_frames(self, min_frames: int) -> TrackKinModel:
        """The same model with another ``min_frames``."""
        return TrackKinModel(self.mean, self.scale, self.layers, info=self.info, min_frames=min_frames,
                             hit_only=self.hit_only)

    def with_hit_only(self, hit_only: bool) -> TrackKinModel:
        """The same model with another ``hit_only`` (e.g. ``False`` for a tracker fed only the detector's
        accepted detections, where a coasting track is often a kin the detector missed this frame)."""
        return TrackKinModel(self.mean, self.scale, self.layers, info=self.info, min_frames=self.min_frames,
                             hit_only=hit_only)


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
        moved: the motion cue has fired (the track left where it was first seen).
        points: (m, 2) accumulated outline points (odometry frame) relative to the track's centre.
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
    moved: bool
    points: np.ndarray = field(repr=False)

    @property
    def is_kin(self) -> bool:
        return self.confirmed and self.kin_prob >= 0.5


def fit_known_circle(points: np.ndarray, r: float, centre0=(0.0, 0.0), iterations: int = 8, weights=None):
    """Least-squares centre of a circle of known radius ``r`` through ``points`` (m, 2).

    Minimises ``sum_i w_i (|p_i - c| - r)^2`` over ``c`` (``weights`` default 1) by Gauss-Newton from
    ``centre0``. Returns ``(centre (2,), residuals (m,))``.
    """
    p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    w = np.ones(p.shape[0]) if weights is None else np.ascontiguousarray(weights, dtype=np.float64)
    c = np.array(centre0, dtype=np.float64)
    e = np.empty(p.shape[0])
    _fit_known_circle(p, w, float(r), c, int(iterations), e)
    return c, e


@numba.njit(cache=True, nogil=True)
def _fit_known_circle(p, w, r, c, iterations, e):
    """Weighted Gauss-Newton on the centre ``c`` (in place, 2x2 normal equations solved in closed form);
    writes the residuals ``|p_i - c| - r`` into ``e``."""
    _fit_span(p, 0, p.shape[0], w, r, c, iterations, e)


@numba.njit(cache=True, nogil=True)
def _fit_span(p, a, m, w, r, c, iterations, e):
    """:func:`_fit_known_circle` on the points ``p[a:a + m]`` (weights ``w[:m]``, residuals into ``e[:m]``),
    by index rather than by slices (a slice passed on costs reference counting, ~100 ns per fit)."""
    for _ in range(iterations):
        a00 = a01 = a11 = g0 = g1 = 0.0
        for i in range(m):
            dx, dy = p[a + i, 0] - c[0], p[a + i, 1] - c[1]
            d = max(math.sqrt(dx * dx + dy * dy), 1e-12)
            jx, jy = -dx / d, -dy / d  # d e_i / d c
            ei = d - r
            a00 += w[i] * jx * jx
            a01 += w[i] * jx * jy
            a11 += w[i] * jy * jy
            g0 += w[i] * jx * ei
            g1 += w[i] * jy * ei
        det = a00 * a11 - a01 * a01
        if det <= 1e-12 * (a00 + a11) ** 2:  # points on a line through c: no unique step
            break
        s0 = -(a11 * g0 - a01 * g1) / det
        s1 = -(a00 * g1 - a01 * g0) / det
        c[0] += s0
        c[1] += s1
        if s0 * s0 + s1 * s1 < 1e-18:
            break
    for i in range(m):
        e[i] = math.sqrt((p[a + i, 0] - c[0]) ** 2 + (p[a + i, 1] - c[1]) ** 2) - r


def segment_points(ranges, angles, rows, first, last, range_max: float = math.inf):
    """The scan points of segments, for the tracker's outline cue (vectorised over all segments).

    Args:
        ranges: ``(B, n)`` scans, m; angles: ``(n,)`` beam angles, rad (robot frame, CCW positive).
        rows, first, last: ``(k,)`` scan row and first / last beam of each segment (wrapping at the
            seam: ``first > last`` is allowed).
        range_max: readings at or above it are no return (as are 0.0, NaN and inf).

    Returns ``(points (P, 2) x forward / y left, owner (P,))``: each valid beam's point and its segment.
    """
    angles = np.ascontiguousarray(angles, dtype=np.float64).reshape(-1)
    ranges = np.asarray(ranges)  # float32 scans stay float32 (widened per reading, exactly: no copy)
    ranges = np.ascontiguousarray(ranges, None if ranges.dtype in (np.float32, np.float64) else np.float64)
    ranges = ranges.reshape(-1, angles.shape[0])
    first = np.ascontiguousarray(first, dtype=np.int64).reshape(-1)
    last = np.ascontiguousarray(last, dtype=np.int64).reshape(-1)
    rows = np.ascontiguousarray(rows, dtype=np.int64).reshape(-1)
    if not rows.shape == first.shape == last.shape:
        raise ValueError(f"segment_points: rows, first and last must be of one length, got {rows.shape}, "
                         f"{first.shape} and {last.shape}")  # fmt: skip
    n = angles.shape[0]
    if first.size and (rows.min() < 0 or rows.max() >= ranges.shape[0] or min(first.min(), last.min()) < 0
                       or max(first.max(), last.max()) >= n):  # fmt: skip
        raise ValueError(f"segment_points: rows must be in [0, {ranges.shape[0]}) and beams in [0, {n})")
    return _segment_points_kernel(ranges, angles, rows, first, last, float(range_max))


@numba.njit(cache=True, nogil=True)
def _segment_points_kernel(ranges, angles, rows, first, last, range_max):
    """:func:`segment_points`' loops: each segment's beams in order (wrapping), valid readings only."""
    n = angles.shape[0]
    total = 0
    for j in range(first.shape[0]):
        total += (last[j] - first[j]) % n + 1
    pts, owner = np.empty((total, 2)), np.empty(total, np.int64)
    pre = 2 * total >= n  # many points: cos / sin once per beam rather than per point (the same values)
    ca, sa = np.empty(n if pre else 0), np.empty(n if pre else 0)
    for q in range(ca.shape[0]):
        ca[q], sa[q] = math.cos(angles[q]), math.sin(angles[q])
    m = 0
    for j in range(first.shape[0]):
        for q in range((last[j] - first[j]) % n + 1):
            beam = (first[j] + q) % n
            r = float(ranges[rows[j], beam])
            if np.isfinite(r) and r > 0 and r < range_max:
                pts[m, 0] = r * (ca[beam] if pre else math.cos(angles[beam]))
                pts[m, 1] = r * (sa[beam] if pre else math.sin(angles[beam]))
                owner[m] = j
                m += 1
    return pts[:m], owner[:m]


#: the per-track scalar columns, packed by type: one (len, capacity) array each (``KinTracker._F``, ``_I``,
#: ``_B``; the names are read-only properties of row views), so that the frame's compiled call takes 3
#: state arrays instead of 31 (each argument of a compiled call costs its dispatch ~55 ns)
_F_COLS = ("_exist", "_lo_score", "_lo_shape", "_lo_motion", "_static_t", "_anchor_var", "_anchor_odo",
           "_anchor_rng", "_lo_resid", "_res_chi2", "_res_dof", "_score_sum", "_n_scored", "_f_lgsum",
           "_f_lgsq", "_f_lgmax", "_f_lglast", "_f_accsum", "_f_acclast", "_f_beams", "_f_rng")  # fmt: skip
_I_COLS = ("_id", "_obs", "_seen", "_age", "_npts", "_head")
_B_COLS = ("_alive", "_moved", "_confirmed", "_hit")
#: the other per-track arrays (capacity first), kept apart
_ARRAYS = ("_x", "_P", "_anchor", "_fit_c", "_pts", "_pts_aux")


@numba.njit(cache=True, nogil=True)
def _f_cols(F, n):
    """:data:`_F_COLS`' row views of ``F``, in that order, their first ``n`` rows."""
    return (F[0][:n], F[1][:n], F[2][:n], F[3][:n], F[4][:n], F[5][:n], F[6][:n], F[7][:n], F[8][:n],
            F[9][:n], F[10][:n], F[11][:n], F[12][:n], F[13][:n], F[14][:n], F[15][:n], F[16][:n],
            F[17][:n], F[18][:n], F[19][:n], F[20][:n])  # fmt: skip


def _column(pack: str, i: int, name: str) -> property:
    return property(lambda self: getattr(self, pack)[i], doc=f"``{name}``: row {i} of ``{pack}`` (a view)")


class KinTracker:
    """Kin tracks of ``n_observers`` robots at once, from their candidates and odometry (module docstring).

    ``kin_model``: the kin decision: ``"learned"`` (default: the shipped :class:`TrackKinModel`, fitted on
    the learned detector's permissive candidates), ``"geometric"`` (the shipped one fitted on the geometric
    detector's, :data:`GEOMETRIC_KIN_MODEL`), ``"hand"`` (the hand-tuned fusion of the cues,
    :class:`TrackerParams`), a model JSON path or a :class:`TrackKinModel`.

    Batch-first: every observer's tracks live in one set of preallocated arrays (a row per track slot, its
    observer in ``obs``), and one :meth:`update_batch` call advances all observers by one frame in one
    compiled call (:func:`_update_kernel`; the staged steps it replaced are kept as the test reference,
    ``tests/detectors/reference_tracking.py``, and it reproduces them bitwise); the Hungarian solver runs
    only for the ambiguous gates. :meth:`track_arrays` computes the kin decision and the padded slots in
    compiled loops too, once per frame — inside the update's call when the frame before's were read, as an
    env reads them every step. :meth:`update` is the one-observer form.

    Example::

        tracker = KinTracker()
        for ranges, odom_delta in frames:               # (n,) m; (dx, dy, dtheta) since the last frame
            result = detector.detect(ranges, angles)    # any KinDetector, ideally a permissive one
            tracker.update_from_result(result, ranges, angles, odom_delta, dt=0.1)
            kin = [t for t in tracker.tracks() if t.is_kin]
    """

    _FIELDS = ("_id", "_obs", "_x", "_P", "_exist", "_lo_score", "_lo_shape", "_lo_motion", "_seen", "_age",
               "_static_t", "_moved", "_confirmed", "_anchor", "_anchor_var", "_alive", "_pts", "_pts_aux",
               "_npts", "_head", "_fit_c", "_anchor_odo", "_anchor_rng", "_lo_resid", "_res_chi2", "_res_dof",
               "_score_sum", "_n_scored", "_f_lgsum", "_f_lgsq", "_f_lgmax", "_f_lglast", "_f_accsum",
               "_f_acclast", "_f_beams", "_f_rng", "_hit")  # fmt: skip

    def __init__(
        self, params: TrackerParams | None = None, n_observers: int = 1, kin_model="learned"
    ) -> None:
        if isinstance(n_observers, bool) or not isinstance(n_observers, int | np.integer) or n_observers < 1:
            raise ValueError(f"KinTracker: n_observers must be a positive integer, got {n_observers!r}")
        self.params = params or TrackerParams()
        if not isinstance(self.params, TrackerParams):
            raise TypeError(f"KinTracker: params must be a TrackerParams, got {type(self.params).__name__}")
        #: the track-level kin classifier, or None for the hand-tuned fusion of the cues
        self.kin_model = _kin_model(kin_model)
        self.n_observers = int(n_observers)
        self.reset()

    def reset(self) -> None:
        """Forget every track; each observer's odometry frame restarts at its current pose."""
        self.poses = np.zeros((self.n_observers, 3))  # each observer in its own odometry frame
        self.time = 0.0
        self._next_id = 0
        pr = self.params
        # the outline's points are kept (a ring per track) only where read: its cue, or Track.points asked for
        cap, m = 8 * self.n_observers, int(pr.max_points) if pr.shape_clamp > 0 or pr.keep_points else 0
        # the per-track scalars, packed by type (:data:`_F_COLS`, ...): the track's existence, cue log-odds
        # (score, outline, motion, per-frame residual), time static; where it was first seen (variance,
        # the observer's odometer and the range then); the per-frame fits' summed chi-square and dof; the
        # score cue's sum and count; the track-level classifier's per-frame inputs (TrackKinModel: clipped
        # score logits summed, squared, max and last; accepted frames and the last flag; the last
        # candidate's beams and range); id, observer, frames seen, age, the outline ring's count and head;
        # alive, moved, confirmed and updated this frame (hit)
        self._F = np.zeros((len(_F_COLS), cap))
        self._I = np.zeros((len(_I_COLS), cap), np.int64)
        self._B = np.zeros((len(_B_COLS), cap), np.bool_)
        self._x = np.zeros((cap, 4))
        self._P = np.zeros((cap, 4, 4))
        self._anchor = np.zeros((cap, 2))  # where the track was first seen, odometry frame
        # outline points, a ring: odometry-frame x, y
        self._pts = np.zeros((cap, m, 2))
        # sensor sigma, range when seen, the observer's odometer and the time then: read only by the outline
        # refit, so kept only when it is on (shape_clamp > 0); apart from x, y, whose ring is 3x smaller
        self._pts_aux = np.zeros((cap, m if self.params.shape_clamp > 0 else 0, 4))
        self.odometer = np.zeros(self.n_observers)  # wheel travel so far, m (ages ego-motion errors)
        self._fit_c = np.zeros((cap, 2))  # the outline fit's centre, odometry frame (warm start)
        self._prm_of = None  # the params _prm was built from
        self._frame = 0  # frames since reset (keys the per-frame cache of the kin decision)
        self._kp_cache = (None, None)
        self._pending = None  # the decision's compiled part from the last update
        self._slots_max = -1  # max_tracks of the last track_arrays call (the update fills its slots then)
        self._slots_block = False  # that read was the envs' info block (_track_block)
        self._slots_frame = -1  # the frame of that read (the first read of a frame sets both)
        self._pending_slots = None  # those slots, filled in this frame's update call
        self._model_args = None  # (model, its arguments of _update_kernel), built once per model object

    @property
    def pose(self) -> np.ndarray:
        """Observer 0's pose in its odometry frame (the one-observer form)."""
        return self.poses[0]

    # -- the frame update --------------------------------------------------------------------------
    def update(
        self, xy, scores, odom_delta, dt: float, points: Sequence[np.ndarray] | None = None, noise=None
    ) -> None:
        """Advance one frame of a one-observer tracker.

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
        if self.n_observers != 1:
            raise ValueError(f"KinTracker.update is the one-observer form; this tracker has "
                             f"{self.n_observers} observers: use update_batch")  # fmt: skip
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        pts = owner = None
        if points is not None:
            if len(points) != xy.shape[0]:
                raise ValueError(
                    f"KinTracker.update: points must hold one array per candidate ({xy.shape[0]})"
                )
            arrs = [np.asarray(p, np.float64).reshape(-1, 2) for p in points]
            pts = np.concatenate(arrs) if arrs else np.zeros((0, 2))
            owner = np.repeat(np.arange(len(arrs)), [a.shape[0] for a in arrs])
        delta = np.asarray(odom_delta, np.float64).reshape(1, -1)
        obs = np.zeros(xy.shape[0], np.int64)
        self.update_batch(obs, xy, scores, delta, dt, pts, owner, None if noise is None else [noise])

    def update_batch(
        self, obs, xy, scores, odom_delta, dt: float, points=None, owner=None, noise=None, accepted=None
    ) -> None:
        """Advance every observer by one frame.

        Args:
            obs: (k,) observer of each candidate, in [0, n_observers).
            xy: (k, 2) candidate centres in their observer's current robot frame (x forward, y left), m.
            scores: (k,) candidate scores in [0, 1] (higher = more kin-like).
            odom_delta: (n_observers, 3) each observer's odometry increment since the previous frame.
            dt: s since the previous frame (> 0).
            points: optional (P, 2) scan points of the candidates, their observer's robot frame, m ...
            owner: ... (P,) and the candidate each point belongs to.
            noise: optional (n_observers,) relative range noise of each observer's scan.
            accepted: optional (k,) bool: the detector accepted the candidate at its operating point
                (then the score cue uses ``accept_llr`` / ``reject_llr``, see :class:`TrackerParams`).

        The whole frame (input checks on the values, ``min_score``, ego-motion, association, filter,
        births, cues, the classifier's running inputs, existence, confirm / delete) is one compiled call
        (:func:`_update_kernel`); a bad input raises before any state changes.
        """
        N = self.n_observers
        obs = np.asarray(obs).reshape(-1)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        delta = np.asarray(odom_delta, dtype=np.float64)
        k = xy.shape[0]
        if delta.shape != (N, 3):
            raise ValueError(
                f"KinTracker: odom_delta must be ({N}, 3) finite numbers (dx, dy, dtheta per observer), "
                f"got {np.shape(odom_delta)} {odom_delta!r}"
            )
        if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"KinTracker: dt must be a positive number of seconds, got {dt!r}")
        if scores.shape[0] != k or obs.shape[0] != k:
            raise ValueError(
                f"KinTracker: obs (k,), xy (k, 2) and scores (k,) must be finite and of one length, got "
                f"{obs.shape}, {xy.shape} and {scores.shape}"
            )
        if k and not np.issubdtype(obs.dtype, np.integer):
            raise ValueError(f"KinTracker: obs must be observer indices in [0, {N}), got {obs!r}")
        if self._prm_of is not self.params:  # the kernel's parameters, built once per params object
            self._prm, self._prm_of = _param_array(self.params), self.params
            self._noise0 = np.full(N, float(self.params.range_noise))
        noise = self._noise0 if noise is None else np.asarray(noise, np.float64).reshape(-1)
        if noise.shape != (N,):
            raise ValueError(f"KinTracker: noise must be {N} relative range noises >= 0, got {noise!r}")
        if accepted is None:
            accepted = _NO_FLAGS
        else:
            accepted = np.asarray(accepted, dtype=np.bool_).reshape(-1)
            if accepted.shape[0] != k:
                raise ValueError(
                    f"KinTracker: accepted must have one flag per candidate ({k}), got {accepted.shape}"
                )
        if points is None:
            pts, own = _NO_POINTS, _NO_OWNER
        else:
            pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
            own = np.asarray(owner).reshape(-1).astype(np.int64, copy=False)
            if own.shape[0] != pts.shape[0]:
                raise ValueError(
                    f"KinTracker: owner must give each of the {pts.shape[0]} points a candidate in [0, {k})"
                )
        # room for every kept candidate to start a track
        ms = self.params.min_score
        kept = k if ms <= 0 or not k else int(np.count_nonzero(scores >= ms))
        n_alive = int(np.count_nonzero(self._alive))  # (a bool array's sum casts: ~5x slower)
        if n_alive + kept > self._alive.shape[0]:
            self._grow(n_alive + kept)
        poses = self.poses.copy()  # a new array per frame: earlier views of ``poses`` keep their values
        dec, model_args, slots = self._decision_args()
        c_ = np.ascontiguousarray
        args = (c_(obs, np.int64), c_(xy), c_(scores), c_(accepted), c_(delta), float(dt), pts, c_(own),
                points is not None, c_(noise), poses, self.odometer, self.time + dt, self._next_id, self._prm,
                self._F, self._I, self._B, self._x, self._P, self._anchor, self._fit_c, self._pts,
                self._pts_aux, dec, model_args, slots, self._slots_block)  # fmt: skip
        res = _update_kernel(*args)
        if res[0] == _BAD_SORT:  # points not grouped by candidate (segment_points gives them sorted)
            order = np.argsort(own, kind="stable")
            args = (*args[:6], np.ascontiguousarray(pts[order]), own[order], *args[8:])
            res = _update_kernel(*args)
        if res[0]:
            raise ValueError(_update_error(res[0], N, k, delta, xy, scores, obs, noise, pts))
        self._updated(poses, dt, dec, slots, res)

    def _decision_args(self) -> tuple[bool, tuple, int]:
        """``(dec, model arguments, slots)`` of :func:`_update_kernel`: the kin decision runs in the update's
        call when the last frame's outputs were read (as an env does every step), and then the padded slots
        too (as many as that read asked for; a network of more than one hidden layer only up to its first
        layer: track_arrays finishes it and fills the slots). The model's arguments are built once per model
        object."""
        m = self.kin_model
        dec = (self._kp_cache[0] is not None and self._kp_cache[0][0] == self._frame and m is not None
               and TRACK_FEATURES == _KERNEL_FEATURES)  # fmt: skip
        if not dec:
            return False, _NO_MODEL, -1
        cached = self._model_args
        if cached is None or cached[0] is not m:
            W, b, W2, b2, tail = _layers(m)
            cached = self._model_args = (m, _model_array(m.mean, m.scale, W, b, W2, b2, tail, _log_min(m),
                                                         m.hit_only), tail)  # fmt: skip
        return True, cached[1], self._slots_max if cached[2] else -1

    def _updated(self, poses, dt, dec, slots, res) -> None:
        """The frame's bookkeeping after :func:`_update_kernel` returned ``res`` (status 0)."""
        _, next_id, rows, kp, sel, h, so = res
        self.poses = poses
        self.time += dt
        self._next_id = int(next_id)
        self._frame += 1
        # the decision (or its first layer) and the slots, for track_arrays of this frame (this model, params)
        self._pending = ((self._frame, self.kin_model, self.params), (rows, kp, sel, h)) if dec else None
        self._pending_slots = (self._frame, slots, self._slots_block, so) if slots >= 0 else None

    def _update_segments_trusted(self, obs, rows, x, y, scores, accepted, odom_delta, dt: float, ranges,
                                 angles, first, last, range_max: float, noise=None) -> None:
        """:meth:`update_batch` for the envs, on their own arrays (trusted: the shapes and dtypes below, scan
        rows and beams in range; the values are still checked, as :meth:`update_batch` checks them): the
        candidates' points are each segment's beams ``first..last`` of scan row ``rows`` (wrapping), as
        :func:`segment_points` gives them, computed in the update's compiled call (no ``(P, 2)`` array
        between calls), and ``xy`` is ``x, y``. The same state and outputs as ``update_batch(obs, c_[x, y],
        scores, odom_delta, dt, *segment_points(ranges, angles, rows, first, last, range_max), noise,
        accepted)`` (``tests/detectors/test_tracking.py``).

        ``obs``, ``rows``, ``first``, ``last``: (k,) int64; ``x``, ``y``, ``scores``: (k,) float64;
        ``accepted``: (k,) bool, or ``None`` for all accepted (the detector's operating point); ``odom_delta``
        (n_observers, 3) float64; ``ranges`` (B, n) float32 / float64 and ``angles`` (n,) float64, C order;
        ``noise``: (n_observers,) float64 or ``None`` (``params.range_noise``)."""
        if self._prm_of is not self.params:
            self._prm, self._prm_of = _param_array(self.params), self.params
            self._noise0 = np.full(self.n_observers, float(self.params.range_noise))
        noise = self._noise0 if noise is None else noise
        poses = self.poses.copy()
        dec, model_args, slots = self._decision_args()
        all_acc = accepted is None
        acc = _NO_FLAGS if all_acc else accepted
        block, dt, range_max = self._slots_block, float(dt), float(range_max)
        while True:  # (reads the state arrays anew: _grow replaces them)
            res = _update_segments_kernel(
                obs, rows, x, y, scores, acc, all_acc, odom_delta, dt, ranges, angles, first, last, range_max,
                noise, poses, self.odometer, self.time + dt, self._next_id, self._prm, self._F, self._I,
                self._B, self._x, self._P, self._anchor, self._fit_c, self._pts, self._pts_aux, dec,
                model_args, slots, block,
            )  # fmt: skip
            if res[0] != _NEED_ROOM:
                break
            self._grow(int(res[1]))  # more rows than the arrays have: grown as update_batch grows them
        if res[0]:  # a bad value: the public path raises its error (no state has changed)
            pts, own = segment_points(ranges, angles, rows, first, last, range_max)
            acc = np.ones(obs.shape[0], np.bool_) if all_acc else accepted
            self.update_batch(obs, np.c_[x, y], scores, odom_delta, dt, pts, own, noise, acc)
            raise AssertionError("KinTracker: the trusted update failed where update_batch did not")
        self._updated(poses, dt, dec, slots, res)

    def update_from_result(self, result: DetectionResult, ranges, angles, odom_delta, dt: float) -> None:
        """:meth:`update` from a detector's :class:`DetectionResult` on scan ``(ranges, angles)``: each
        detection's segment beams (``first_beam``..``last_beam``, wrapping) give its outline points, and the
        scan's own noise estimate (:func:`detectors.features.scan_noise`) the outline cue's noise."""
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = np.asarray(angles, dtype=np.float64)
        dets = result.detections
        xy = np.array([[d.x, d.y] for d in dets]).reshape(-1, 2)
        scores = np.array([d.score for d in dets])
        pts, owner = segment_points(ranges, angles, np.zeros(len(dets), np.int64),
                                    [d.first_beam for d in dets], [d.last_beam for d in dets])  # fmt: skip
        noise, count = scan_noise(segment_batch(ranges[None], angles))
        delta = np.asarray(odom_delta, np.float64).reshape(1, -1)
        self.update_batch(np.zeros(len(dets), np.int64), xy, scores, delta, dt, pts, owner,
                          None if count[0] < 5 else [float(noise[0])])  # fmt: skip

    def adopt(self, observer: int, other: KinTracker) -> np.ndarray:
        """Replace observer ``observer``'s tracks and odometry frame by those of the one-observer tracker
        ``other`` (same params; e.g. a vector env's sub-env that has just reset and run its first frame):
        its tracks are copied bitwise into free rows, so the next :meth:`update_batch` advances them exactly
        as ``other.update_batch`` would. The copies get new ids of this tracker (increasing in ``other``'s
        id order); returns ``other``'s ids of the adopted tracks in that order. ``other.time`` is not
        copied (read only by the outline cue, ``shape_clamp > 0``)."""
        if isinstance(observer, bool) or not isinstance(observer, int | np.integer) or not (
            0 <= observer < self.n_observers
        ):
            raise ValueError(
                f"KinTracker.adopt: observer must be in [0, {self.n_observers}), got {observer!r}"
            )
        if not isinstance(other, KinTracker) or other.n_observers != 1 or other.params != self.params:
            raise ValueError("KinTracker.adopt: other must be a one-observer KinTracker with the same params")
        self._alive[self._alive & (self._obs == observer)] = False
        src = np.flatnonzero(other._alive)
        src = src[np.argsort(other._id[src], kind="stable")]
        n_alive = int(np.count_nonzero(self._alive))
        if n_alive + src.size > self._alive.shape[0]:
            self._grow(n_alive + src.size)
        dst = np.flatnonzero(~self._alive)[: src.size]
        for name in self._FIELDS:
            getattr(self, name)[dst] = getattr(other, name)[src]
        self._obs[dst] = observer
        self._id[dst] = self._next_id + np.arange(src.size)
        self._next_id += int(src.size)
        self.poses[observer] = other.poses[0]
        self.odometer[observer] = other.odometer[0]
        self._kp_cache = (None, None)
        self._pending = None  # the decision's compiled part from the last update
        self._pending_slots = None
        return other._id[src].copy()

    # -- steps ----------------------------------------------------------------------------------------
    def _grow(self, need: int) -> None:
        cap0 = cap = self._alive.shape[0]
        while cap < need:
            cap *= 2
        for name in ("_F", "_I", "_B"):
            a = getattr(self, name)
            b = np.zeros((a.shape[0], cap), a.dtype)
            b[:, :cap0] = a
            setattr(self, name, b)
        for name in _ARRAYS:
            a = getattr(self, name)
            b = np.zeros((cap, *a.shape[1:]), a.dtype)
            b[:cap0] = a
            setattr(self, name, b)

    # -- outputs -----------------------------------------------------------------------------------------
    def _rows(self, observer: int | None) -> np.ndarray:
        rows = np.flatnonzero(self._alive)
        if observer is not None:
            if not 0 <= int(observer) < self.n_observers:
                raise ValueError(f"KinTracker: observer must be in [0, {self.n_observers}), got {observer!r}")
            rows = rows[self._obs[rows] == int(observer)]
        return rows[np.argsort(self._id[rows], kind="stable")]

    def _kin_prob(self, rows: np.ndarray) -> np.ndarray:
        pr = self.params
        if self.kin_model is not None:
            return self.kin_model.kin_prob(self._features_fast(rows))
        # some track of the same observer moved: the swarm around it is active
        active = np.bincount(self._obs[rows][self._moved[rows]], minlength=self.n_observers) > 0
        idle = active[self._obs[rows]] & ~self._moved[rows] & (self._static_t[rows] >= pr.static_time)
        lo = (_logit(pr.kin_prior) + self._lo_score[rows] + self._lo_resid[rows] + self._lo_shape[rows]
              + self._lo_motion[rows] + np.where(idle, pr.static_penalty, 0.0))  # fmt: skip
        return 1.0 / (1.0 + np.exp(-lo))

    def _features_fast(self, rows: np.ndarray) -> np.ndarray:
        """:meth:`_features` in one compiled loop (:func:`_features_kernel`, bitwise the same, tested) while
        :data:`TRACK_FEATURES` are the columns it computes; else :meth:`_features` itself."""
        if TRACK_FEATURES != _KERNEL_FEATURES:
            return self._features(rows)
        pr = self.params
        return _features_kernel(
            np.ascontiguousarray(rows, np.int64), self.n_observers, self._alive, self._confirmed, self._obs,
            self._seen, self._x, self._P, self._anchor, self._anchor_var, self._anchor_odo, self._anchor_rng,
            self.odometer, self._hit, self._f_lgsum, self._f_lgsq, self._f_lgmax, self._f_lglast,
            self._f_accsum, self._f_acclast, self._f_beams, self._f_rng, self._moved, self._exist,
            self._res_chi2, self._res_dof, pr.odom_heading_rate**2, pr.odom_position_rate**2,
        )  # fmt: skip

    def _decide(self) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, kin probability)`` of every live track (ascending rows): :meth:`_kin_prob`'s values, for
        the learned model in one compiled pass (:func:`_decide_kernel`: the classifier's inputs and its
        layers only for the tracks it decides — updated this frame (``hit_only``) and seen in
        ``min_frames`` frames or more —, the others' probability directly; a network of more than one
        hidden layer finishes here, on those rows only), with the compiled ``tanh`` and logistic that
        :class:`TrackKinModel` uses too: the same values bit for bit (tested)."""
        m = self.kin_model
        if m is None or TRACK_FEATURES != _KERNEL_FEATURES:
            rows = np.flatnonzero(self._alive)
            return rows, self._kin_prob(rows) if rows.size else np.zeros(0)
        pend, self._pending = self._pending, None
        if pend is not None and pend[0][0] == self._frame and pend[0][1] is m and pend[0][2] is self.params:
            rows, kp, sel, h = pend[1]  # computed in this frame's update call
        else:
            pr = self.params
            rows, kp, sel, h = _decide_packed(
                self.n_observers, self._F, self._I, self._B, self._x, self._P, self._anchor, self.odometer,
                pr.odom_heading_rate**2, pr.odom_position_rate**2, m.mean, m.scale, *_layers(m), _log_min(m),
                m.hit_only,
            )  # fmt: skip
        if sel.size:  # a network of more than one hidden layer: its later layers here
            for W, b in m.layers[1:]:  # TrackKinModel.logit's later layers
                h = _dense_layer(_tanh(h), W, b)
            kp[sel] = _sigmoid(np.ascontiguousarray(h[:, 0]))
        return rows, kp

    def _features(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), F) :data:`TRACK_FEATURES` of the track rows ``rows``."""
        pr = self.params
        n = np.maximum(self._seen[rows], 1).astype(np.float64)
        o = self._obs[rows]
        dx, dy = (self._x[rows, :2] - self._anchor[rows]).T
        disp = np.sqrt(dx * dx + dy * dy)  # not hypot: the kernels' square root (libm's hypot ~15 ns)
        aged = self.odometer[o] - self._anchor_odo[rows]
        drift = aged * (pr.odom_heading_rate**2 * self._anchor_rng[rows] ** 2 + pr.odom_position_rate**2)
        var = self._anchor_var[rows] + 0.5 * (self._P[rows, 0, 0] + self._P[rows, 1, 1]) + drift
        speed = np.sqrt(self._x[rows, 2] * self._x[rows, 2] + self._x[rows, 3] * self._x[rows, 3])
        speed_sd = np.sqrt(np.maximum(0.5 * (self._P[rows, 2, 2] + self._P[rows, 3, 3]), 1e-12))
        hit = self._hit[rows]
        mean = self._f_lgsum[rows] / n
        dof = self._res_dof[rows]
        live = np.flatnonzero(self._alive & self._confirmed)  # the scene: the observer's confirmed tracks
        n_conf = np.bincount(self._obs[live], minlength=self.n_observers)[o].astype(np.float64)
        n_moved = np.bincount(self._obs[live][self._moved[live]], minlength=self.n_observers)[o]
        return np.stack([
            mean, np.sqrt(np.maximum(self._f_lgsq[rows] / n - mean * mean, 0.0)), self._f_lgmax[rows],
            self._f_lglast[rows], np.where(hit, self._f_lglast[rows], -6.0), self._f_accsum[rows] / n,
            self._f_acclast[rows], np.where(hit, self._f_acclast[rows], 0.0), hit.astype(np.float64),
            np.log(n),
            np.log1p(self._f_beams[rows]), self._f_rng[rows], np.minimum(disp / np.sqrt(var), 10.0),
            self._moved[rows].astype(np.float64), self._exist[rows], np.minimum(speed / speed_sd, 10.0),
            n_moved / np.maximum(n_conf, 1.0), np.log1p(n_moved),
            np.clip((self._res_chi2[rows] - dof) / np.sqrt(2.0 * np.maximum(dof, 1.0)), -10.0, 10.0),
        ], axis=1)  # fmt: skip

    def track_features(self, observer: int = 0) -> dict[str, np.ndarray]:
        """The track classifier's inputs of ``observer``'s tracks, in track-id order: ``id`` (n,), ``xy``
        (n, 2) in its current robot frame, ``confirmed`` (n,) and ``features`` (n, F)
        (:data:`TRACK_FEATURES`)."""
        rows = self._rows(observer)
        return {"id": self._id[rows].copy(), "xy": self.in_robot_frame(observer),
                "confirmed": self._confirmed[rows].copy(), "features": self._features(rows)}

    def kin_prob(self, observer: int | None = 0) -> np.ndarray:
        """Kin probability of ``observer``'s tracks (all observers' for ``None``), in track-id order."""
        return self._kin_prob(self._rows(observer))

    def __len__(self) -> int:
        return int(np.count_nonzero(self._alive))

    def tracks(self, observer: int | None = 0) -> list[Track]:
        """``observer``'s tracks (all for ``None``) as :class:`Track` objects, id order, built on demand."""
        rows = self._rows(observer)
        kp = self._kin_prob(rows)
        out = []
        for i, p in zip(rows.tolist(), kp.tolist(), strict=True):
            m = int(self._npts[i])
            out.append(Track(
                id=int(self._id[i]), x=float(self._x[i, 0]), y=float(self._x[i, 1]), vx=float(self._x[i, 2]),
                vy=float(self._x[i, 3]), covariance=self._P[i].copy(), existence=float(self._exist[i]),
                kin_prob=p, frames_seen=int(self._seen[i]), age=int(self._age[i]),
                confirmed=bool(self._confirmed[i]), moved=bool(self._moved[i]),
                points=self._pts[i, :m, :2] - self._x[i, :2],
            ))  # fmt: skip
        return out

    def in_robot_frame(self, observer: int = 0) -> np.ndarray:
        """(n_tracks, 2) ``observer``'s track positions in its current robot frame (x forward, y left), m."""
        rows = self._rows(observer)
        pose = self.poses[observer]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return (self._x[rows, :2] - pose[:2]) @ np.array([[c, -s], [s, c]])

    def track_arrays(self, max_tracks: int) -> dict[str, np.ndarray]:
        """Fixed-shape view for vector envs: ``tracks`` (n_observers, max_tracks, len(TRACK_FIELDS)) float32,
        zero-padded (columns :data:`TRACK_FIELDS`; positions and velocities in each observer's current robot
        frame), ``mask`` (n_observers, max_tracks) bool and ``count`` (n_observers,). Per observer, confirmed
        tracks come first, then by kin probability, when there are more than ``max_tracks``."""
        _check_max_tracks(max_tracks)
        out, mask, count, _ = self._read_slots(int(max_tracks), False)
        return {"tracks": out, "mask": mask, "count": count}

    def _track_block(self, max_tracks: int) -> tuple[np.ndarray, np.ndarray]:
        """The envs' info (:func:`kin_envs.envs.tracks.track_info`): ``(block, count)``, ``block`` (fields,
        n_observers, max_tracks) float64 the values of ``track_arrays(max_tracks)["tracks"].transpose(2, 0,
        1).astype(float64)`` (``count`` its count) bit for bit, with the same effect on the tracker; each
        field a C-contiguous row. Filled in the update's compiled call when the frame before was read so."""
        _check_max_tracks(max_tracks)
        _, _, count, block = self._read_slots(int(max_tracks), True)
        return block, count

    def _read_slots(self, max_tracks: int, block: bool) -> tuple:
        """:func:`_slots_kernel`'s ``(tracks, mask, count, blk)`` of this frame (``block``: the info's)."""
        # the kin decision of this frame's tracks, once per frame (an env reads it for the info and again for
        # the observation's track channel)
        key, cached = self._kp_cache
        fresh = (key is None or key[0] != self._frame or key[1] is not self.kin_model
                 or key[2] is not self.params)  # fmt: skip
        ps, self._pending_slots = self._pending_slots, None
        if self._slots_frame != self._frame:  # the next update fills the slots the first read asked for
            self._slots_max, self._slots_block, self._slots_frame = max_tracks, block, self._frame
        if fresh:
            pend = self._pending
            cached = self._decide()
            self._kp_cache = ((self._frame, self.kin_model, self.params), cached)
            # the slots the update's call filled: the first read of this frame, as many slots in the same
            # form, the decision that call made (each later read builds its own arrays: a caller may write
            # into them)
            if ps is not None and ps[0] == self._frame and ps[1] == max_tracks and ps[2] == block \
                    and pend is not None and pend[0][1] is self.kin_model and pend[0][2] is self.params:
                return ps[3]
        rows, kp = cached
        return _slots_kernel(rows, kp, self.n_observers, max_tracks, self._obs, self._id, self._confirmed,
                             self._x, self.poses, self._exist, self._seen, self._age, block)  # fmt: skip

for _pack, _cols in (("_F", _F_COLS), ("_I", _I_COLS), ("_B", _B_COLS)):
    for _i, _name in enumerate(_cols):
        setattr(KinTracker, _name, _column(_pack, _i, _name))
assert set(KinTracker._FIELDS) == {*_F_COLS, *_I_COLS, *_B_COLS, *_ARRAYS}


def _check_max_tracks(max_tracks) -> None:
    if isinstance(max_tracks, bool) or not isinstance(max_tracks, int | np.integer) or max_tracks < 0:
        raise ValueError(f"KinTracker.track_arrays: max_tracks must be an int >= 0, got {max_tracks!r}")


def _log_min(m: TrackKinModel) -> float:
    """The model's ``min_frames`` as :func:`_decide_kernel` compares it (to ``log(frames)``)."""
    return math.log(m.min_frames) - 1e-9 if m.min_frames > 0 else -math.inf


_NO_W, _NO_B = np.zeros((0, 0)), np.zeros(0)


def _model_array(mean, scale, W, b, W2, b2, tail, log_min, hit_only) -> np.ndarray:
    """:func:`_decide_kernel`'s model arguments as one float64 array (:func:`_model_views` reads them back,
    the same values: one argument of :func:`_update_kernel` instead of nine)."""
    arrs = [np.asarray(a, np.float64) for a in (mean, scale, W, b, W2, b2)]
    head = [float(arrs[0].size), float(arrs[1].size), *map(float, arrs[2].shape), float(arrs[3].size),
            *map(float, arrs[4].shape), float(arrs[5].size), float(tail), float(log_min),
            float(bool(hit_only))]  # fmt: skip
    return np.concatenate([np.array(head), *(a.ravel() for a in arrs)])


#: :func:`_update_kernel`'s model argument when the decision does not run in it
_NO_MODEL = _model_array(_NO_B, _NO_B, _NO_W, _NO_B, _NO_W, _NO_B, 0, 0.0, False)


@numba.njit(cache=True, nogil=True)
def _model_views(model):
    """:func:`_model_array`'s ``(mean, scale, W, b, W2, b2, tail, log_min, hit_only)``, views of ``model``."""
    n_mean, n_scale, w0, w1, n_b = int(model[0]), int(model[1]), int(model[2]), int(model[3]), int(model[4])
    v0, v1, n_b2 = int(model[5]), int(model[6]), int(model[7])
    tail, log_min, hit_only = int(model[8]), model[9], model[10] != 0.0
    o = 11
    mean = model[o : o + n_mean]
    o += n_mean
    scale = model[o : o + n_scale]
    o += n_scale
    W = model[o : o + w0 * w1].reshape(w0, w1)
    o += w0 * w1
    b = model[o : o + n_b]
    o += n_b
    W2 = model[o : o + v0 * v1].reshape(v0, v1)
    o += v0 * v1
    b2 = model[o : o + n_b2]
    return mean, scale, W, b, W2, b2, tail, log_min, hit_only


def _layers(m: TrackKinModel) -> tuple:
    """``(W, b, W2, b2, tail)`` of :func:`_decide_kernel`: the first layer, the output layer when the
    network has one hidden layer, and how much of it the kernel finishes (``tail``)."""
    W, b = m.layers[0]
    if len(m.layers) == 1:
        return W, b, _NO_W, _NO_B, 1
    if len(m.layers) == 2:
        return W, b, *m.layers[1], 2
    return W, b, _NO_W, _NO_B, 0


def _kin_model(kin_model) -> TrackKinModel | None:
    if isinstance(kin_model, TrackKinModel):
        return kin_model
    if isinstance(kin_model, str) and kin_model == "hand":
        return None
    if isinstance(kin_model, str) and kin_model == "learned":
        return _shipped_kin_model()
    if isinstance(kin_model, str) and kin_model == "geometric":
        return _shipped_kin_model(GEOMETRIC_KIN_MODEL)
    expected = "'hand', 'learned', 'geometric', a model JSON path or a TrackKinModel"
    if isinstance(kin_model, str | Path):
        if not Path(kin_model).is_file():  # a misspelt name reads as a path: say what else it could be
            raise ValueError(f"KinTracker: kin_model must be {expected}, got {str(kin_model)!r} "
                             "(no such file)")  # fmt: skip
        return TrackKinModel.load(kin_model)
    raise TypeError(f"KinTracker: kin_model must be {expected}, got {kin_model!r}")


_SHIPPED_MODELS: dict = {}


def _shipped_kin_model(path: Path = DEFAULT_KIN_MODEL) -> TrackKinModel:
    """A shipped track classifier, loaded once per process (every env's tracker shares it; never mutated)."""
    if path not in _SHIPPED_MODELS:
        _SHIPPED_MODELS[path] = TrackKinModel.load(path)
    return _SHIPPED_MODELS[path]


@numba.njit(cache=True, nogil=True)
def _find(parent, i):
    """Union-find root of ``i`` (with path halving)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True, nogil=True)
def _hungarian(cost):
    """Minimum-cost assignment of the rows of ``cost`` (n, m), n <= m, to distinct columns (shortest
    augmenting paths with potentials, O(n^2 m)); returns each row's column."""
    n, m = cost.shape
    inf = 1e300
    u = np.zeros(n + 1)
    v = np.zeros(m + 1)
    p = np.zeros(m + 1, np.int64)
    way = np.zeros(m + 1, np.int64)
    minv = np.empty(m + 1)
    used = np.empty(m + 1, np.bool_)
    for i in range(1, n + 1):
        p[0] = i
        j0 = 0
        minv[:] = inf
        used[:] = False
        while True:
            used[j0] = True
            i0 = p[j0]
            delta = inf
            j1 = 0
            for j in range(1, m + 1):
                if not used[j]:
                    cur = cost[i0 - 1, j - 1] - u[i0] - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta = minv[j]
                        j1 = j
            for j in range(m + 1):
                if used[j]:
                    u[p[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if p[j0] == 0:
                break
        while True:
            j1 = way[j0]
            p[j0] = p[j1]
            j0 = j1
            if j0 == 0:
                break
    ans = np.full(n, -1, np.int64)
    for j in range(1, m + 1):
        if p[j] != 0:
            ans[p[j] - 1] = j - 1
    return ans


@numba.njit(cache=True, nogil=True)
def _gate_pairs(n_obs, t_cnt, c_cnt, c_ord, z, rng, meas_sigma, meas_sigma_rel, gate, gate_b, lam_max, xs, kx,
                ky, lam_s, g00, g01, g10, g11, pt, pc, pm, deg_t, deg_c):  # fmt: skip
    """:func:`_frame_kernel`'s gated pairs (track ``pt``, candidate ``pc``, squared Mahalanobis distance
    ``pm``), grouped by observer, and each track's and candidate's number of them; returns how many, or -1
    when they do not fit the buffers. Each observer's tracks ``xs[t_cnt[o]:t_cnt[o + 1]]`` are sorted by
    ``x`` (``kx``), with their ``y``, bound and position covariance in the same order."""
    n_g = 0
    mv_a, w_a = np.empty(c_ord.shape[0]), np.empty(c_ord.shape[0])
    near = np.empty(xs.shape[0], np.int64)
    for o in range(n_obs):
        lo, hi = t_cnt[o], t_cnt[o + 1]
        if lo == hi:
            continue
        a0, a1 = c_cnt[o], c_cnt[o + 1]
        for a in range(a0, a1):  # the reach of each candidate's gate first (its square roots vectorised)
            c = c_ord[a]
            mv_a[a - a0] = (meas_sigma + meas_sigma_rel * rng[c]) ** 2
            w_a[a - a0] = math.sqrt(gate_b * (lam_max[o] + mv_a[a - a0])) * (1.0 + 1e-9)
        for a in range(a0, a1):
            c = c_ord[a]
            mv, w = mv_a[a - a0], w_a[a - a0]
            zx, zy = z[c, 0], z[c, 1]
            # the walk: from the first track with zx - x <= w to the first with zx - x < -w (zx - x falls
            # along the order, so each is a count of the tracks before it: for the usual tens of tracks of an
            # observer counted without a branch, vectorised; the halving's steps were mispredicted)
            if hi - lo <= 64:
                l = e = lo
                for b in range(lo, hi):
                    dx = zx - kx[b]
                    l += dx > w
                    e += dx >= -w
            else:
                l, h_ = lo, hi
                while l < h_:
                    mid = (l + h_) >> 1
                    right = zx - kx[mid] > w
                    l = mid + 1 if right else l
                    h_ = h_ if right else mid
                e, h_ = l, hi
                while e < h_:
                    mid = (e + h_) >> 1
                    left = zx - kx[mid] < -w
                    e = e if left else mid + 1
                    h_ = mid if left else h_
            # the bound's test over the walk without a branch (the tracks that pass, compacted in order: a
            # track per branch was mispredicted often, ~1/6 of a learned frame went to this loop)
            nb = 0
            for b in range(l, e):
                d0, d1 = zx - kx[b], zy - ky[b]
                near[nb] = b
                nb += d0 * d0 + d1 * d1 <= gate_b * (lam_s[b] + mv)
            for q in range(nb):
                b = near[q]
                d0, d1 = zx - kx[b], zy - ky[b]
                a00, a01, a10, a11 = g00[b] + mv, g01[b], g10[b], g11[b] + mv
                det = a00 * a11 - a01 * a10
                m2 = (a11 * d0 * d0 - 2 * a01 * d0 * d1 + a00 * d1 * d1) / det
                if m2 <= gate:
                    if n_g == pt.shape[0]:
                        return -1
                    t = xs[b]
                    pt[n_g] = t
                    pc[n_g] = c
                    pm[n_g] = m2
                    deg_t[t] += 1
                    deg_c[c] += 1
                    n_g += 1
    return n_g


@numba.njit(cache=True, nogil=True)
def _kalman_update(xt, Pt, zx, zy, mv):
    """One track's Kalman update (state ``xt`` (4,), covariance ``Pt`` (4, 4), in place) with a position
    ``zx, zy`` measured with isotropic variance ``mv``, in the standard form ``P - K H P`` written symmetric
    (its upper triangle, mirrored): ~1/3 of the Joseph form's operations (which the rounds before session 14
    used; P is a well-conditioned 4 x 4 here, and the filter is tested against filterpy's Joseph form)."""
    p00, p01, p11 = Pt[0, 0], Pt[0, 1], Pt[1, 1]
    s00, s11 = p00 + mv, p11 + mv
    det = s00 * s11 - p01 * p01
    i00, i01, i11 = s11 / det, -p01 / det, s00 / det
    # K = P H^T S^-1 (4 x 2) from P's first two columns (rows, P being symmetric)
    h00, h01, h02, h03 = Pt[0, 0], Pt[0, 1], Pt[0, 2], Pt[0, 3]
    h10, h11, h12, h13 = Pt[1, 0], Pt[1, 1], Pt[1, 2], Pt[1, 3]
    k00, k01 = h00 * i00 + h10 * i01, h00 * i01 + h10 * i11
    k10, k11 = h01 * i00 + h11 * i01, h01 * i01 + h11 * i11
    k20, k21 = h02 * i00 + h12 * i01, h02 * i01 + h12 * i11
    k30, k31 = h03 * i00 + h13 * i01, h03 * i01 + h13 * i11
    d0, d1 = zx - xt[0], zy - xt[1]
    xt[0] += k00 * d0 + k01 * d1
    xt[1] += k10 * d0 + k11 * d1
    xt[2] += k20 * d0 + k21 * d1
    xt[3] += k30 * d0 + k31 * d1
    # P - K (H P): H P is P's first two rows
    a00 = Pt[0, 0] - (k00 * h00 + k01 * h10)
    a01 = Pt[0, 1] - (k00 * h01 + k01 * h11)
    a02 = Pt[0, 2] - (k00 * h02 + k01 * h12)
    a03 = Pt[0, 3] - (k00 * h03 + k01 * h13)
    a11 = Pt[1, 1] - (k10 * h01 + k11 * h11)
    a12 = Pt[1, 2] - (k10 * h02 + k11 * h12)
    a13 = Pt[1, 3] - (k10 * h03 + k11 * h13)
    a22 = Pt[2, 2] - (k20 * h02 + k21 * h12)
    a23 = Pt[2, 3] - (k20 * h03 + k21 * h13)
    a33 = Pt[3, 3] - (k30 * h03 + k31 * h13)
    Pt[0, 0], Pt[0, 1], Pt[0, 2], Pt[0, 3] = a00, a01, a02, a03
    Pt[1, 0], Pt[1, 1], Pt[1, 2], Pt[1, 3] = a01, a11, a12, a13
    Pt[2, 0], Pt[2, 1], Pt[2, 2], Pt[2, 3] = a02, a12, a22, a23
    Pt[3, 0], Pt[3, 1], Pt[3, 2], Pt[3, 3] = a03, a13, a23, a33


@numba.njit(cache=True, nogil=True)
def _frame_kernel(z, obs, rng, dt, n_obs, alive, tobs, tid, next_id, x, P, poses, exist, lo_score, lo_shape,
                  lo_motion, lo_resid, res_chi2, res_dof, score_sum, n_scored, seen, age, static_t, moved,
                  confirmed, npts, head, fit_c, anchor, anchor_var, anchor_odo, anchor_rng, odometer, q,
                  meas_sigma, meas_sigma_rel, speed_var, gate, birth_exist, confirm_exist, r, scores,
                  birth_floor):  # fmt: skip
    """One frame's predict (constant velocity), Mahalanobis gating, assignment (a pair alone in both its
    gates is forced; the rest per observer by :func:`_hungarian`), Kalman update (:func:`_kalman_update`), and
    births (of the unmatched candidates scoring ``>= birth_floor``)."""
    cap = alive.shape[0]
    k = z.shape[0]
    # predict
    q11, q12, q22 = q * dt**4 / 4, q * dt**3 / 2, q * dt * dt
    for t in range(cap):
        if not alive[t]:
            continue
        x[t, 0] += dt * x[t, 2]
        x[t, 1] += dt * x[t, 3]
        # P <- F P F^T + Q with F = [[I, dt I], [0, I]]
        Pt = P[t]  # P F^T: columns 0, 1 += dt * columns 2, 3; then F (P F^T): rows likewise
        for i in range(4):
            Pt[i, 0] += dt * Pt[i, 2]
            Pt[i, 1] += dt * Pt[i, 3]
        for j in range(4):
            Pt[0, j] += dt * Pt[2, j]
            Pt[1, j] += dt * Pt[3, j]
        Pt[0, 0] += q11
        Pt[1, 1] += q11
        Pt[0, 2] += q12
        Pt[2, 0] += q12
        Pt[1, 3] += q12
        Pt[3, 1] += q12
        Pt[2, 2] += q22
        Pt[3, 3] += q22
    # group tracks and candidates by observer (stable counting sort)
    t_cnt = np.zeros(n_obs + 1, np.int64)
    c_cnt = np.zeros(n_obs + 1, np.int64)
    for t in range(cap):
        if alive[t]:
            t_cnt[tobs[t] + 1] += 1
    for c in range(k):
        c_cnt[obs[c] + 1] += 1
    for o in range(n_obs):
        t_cnt[o + 1] += t_cnt[o]
        c_cnt[o + 1] += c_cnt[o]
    t_ord = np.empty(t_cnt[n_obs], np.int64)
    c_ord = np.empty(k, np.int64)
    fill = t_cnt[:-1].copy()
    for t in range(cap):
        if alive[t]:
            t_ord[fill[tobs[t]]] = t
            fill[tobs[t]] += 1
    fill = c_cnt[:-1].copy()
    for c in range(k):
        c_ord[fill[obs[c]]] = c
        fill[obs[c]] += 1
    # gating: squared Mahalanobis distance under the innovation covariance
    deg_t = np.zeros(cap, np.int64)
    deg_c = np.zeros(k, np.int64)
    # a cheap bound first: m2 >= |d|^2 / lambda_max(S) with S = P_xy + mv I, so a pair whose |d|^2 exceeds
    # gate * lambda_max(S) (with a margin far above rounding) is outside the gate, and only the others need
    # the exact test (in a swarm most pairs of an observer are metres apart); the gated pairs are the same
    lam = np.empty(cap)
    for b in range(t_cnt[n_obs]):
        t = t_ord[b]
        h, off = 0.5 * (P[t, 0, 0] - P[t, 1, 1]), max(abs(P[t, 0, 1]), abs(P[t, 1, 0]))
        lam[t] = 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + math.sqrt(h * h + off * off)
    gate_b = gate * (1.0 + 1e-6)
    # and before the bound, each observer's tracks in ascending x: a candidate visits only those whose x is
    # within w = sqrt(gate_b (max lambda + mv)) (1 + 1e-9) of its own (a binary search, then a walk). Any
    # other track has |dx| > w, so |d|^2 exceeds every track's bound even after rounding: the bound would
    # have rejected it. The gated pairs are the same; only their order changes, which no result depends
    # on (each track takes at most one candidate; components and the Hungarian see sorted rows and columns)
    nt_all = t_cnt[n_obs]
    xs = t_ord.copy()
    kx = np.empty(nt_all)  # the sort key beside the rows: the sort and the search read contiguous keys
    lam_max = np.zeros(n_obs)
    gx = np.empty(64)
    for o in range(n_obs):
        lo, hi = t_cnt[o], t_cnt[o + 1]
        for q in range(lo, hi):
            lam_max[o] = max(lam_max[o], lam[t_ord[q]])
        if hi - lo <= 64:
            # stable sort by x as ranks, counted branch-free (the usual tens of tracks of an observer: an
            # insertion sort's comparisons were mispredicted about every other time): x below, or equal and
            # earlier in row order
            ng = hi - lo
            for q in range(ng):
                gx[q] = x[t_ord[lo + q], 0]
            for q in range(ng):
                xq = gx[q]
                rk = 0
                for q2 in range(ng):
                    rk += (gx[q2] < xq) | ((gx[q2] == xq) & (q2 < q))
                xs[lo + rk] = t_ord[lo + q]
                kx[lo + rk] = xq
            continue
        for q in range(lo, hi):  # insertion sort by x
            t = xs[q]
            xt = x[t, 0]
            p = q - 1
            while p >= lo and kx[p] > xt:
                xs[p + 1] = xs[p]
                kx[p + 1] = kx[p]
                p -= 1
            xs[p + 1] = t
            kx[p + 1] = xt
    # what the walk reads of each track, in the sorted order (contiguous: the walk streams through it)
    ky, lam_s = np.empty(nt_all), np.empty(nt_all)
    g00, g01, g10, g11 = np.empty(nt_all), np.empty(nt_all), np.empty(nt_all), np.empty(nt_all)
    for b in range(nt_all):
        t = xs[b]
        ky[b], lam_s[b] = x[t, 1], lam[t]
        g00[b], g01[b], g10[b], g11[b] = P[t, 0, 0], P[t, 0, 1], P[t, 1, 0], P[t, 1, 1]
    # gated pairs: about one per candidate; the buffers doubled (and the gating rerun) when a frame has more
    # (grown outside the gating loop: arrays rebound inside a loop cost a reference count per iteration)
    n_pairs = k + 16
    while True:
        pt = np.empty(n_pairs, np.int64)
        pc = np.empty(n_pairs, np.int64)
        pm = np.empty(n_pairs)
        n_g = _gate_pairs(n_obs, t_cnt, c_cnt, c_ord, z, rng, meas_sigma, meas_sigma_rel, gate, gate_b,
                          lam_max, xs, kx, ky, lam_s, g00, g01, g10, g11, pt, pc, pm, deg_t, deg_c)
        if n_g >= 0:
            break
        n_pairs *= 2
        deg_t[:] = 0
        deg_c[:] = 0
    ti = np.empty(min(n_g, k), np.int64)
    ci = np.empty(min(n_g, k), np.int64)
    n_m = 0
    # forced pairs; the rest of each observer's gated pairs (grouped by observer already) by the Hungarian
    t_loc = np.full(cap, -1, np.int64)
    c_loc = np.full(k, -1, np.int64)
    t_q = np.full(cap, -1, np.int64)
    c_q = np.full(k, -1, np.int64)
    a = 0
    while a < n_g:
        o = tobs[pt[a]]
        b = a
        while b < n_g and tobs[pt[b]] == o:
            b += 1
        nt = nc = 0
        for g in range(a, b):
            t, c = pt[g], pc[g]
            if deg_t[t] == 1 and deg_c[c] == 1:
                ti[n_m] = t
                ci[n_m] = c
                n_m += 1
            else:
                if t_loc[t] < 0:
                    t_loc[t] = nt
                    nt += 1
                if c_loc[c] < 0:
                    c_loc[c] = nc
                    nc += 1
        if nt:
            ut = np.empty(nt, np.int64)
            uc = np.empty(nc, np.int64)
            for g in range(a, b):
                if t_loc[pt[g]] >= 0:
                    ut[t_loc[pt[g]]] = pt[g]
                if c_loc[pc[g]] >= 0:
                    uc[c_loc[pc[g]]] = pc[g]
            # connected components of the ambiguous gates (tracks and candidates as nodes): the optimal
            # assignment (most pairs, then least cost) decomposes over them, so each is solved on its own
            # (in a swarm one observer's gates form many small clusters, not one big matrix)
            nn = nt + nc
            parent = np.arange(nn)
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    u, v = _find(parent, t_loc[pt[g]]), _find(parent, nt + c_loc[pc[g]])
                    if u != v:
                        parent[u] = v
            comp = np.empty(nn, np.int64)
            cid = np.full(nn, -1, np.int64)
            n_comp = 0
            for i in range(nn):
                root = _find(parent, i)
                if cid[root] < 0:
                    cid[root] = n_comp
                    n_comp += 1
                comp[i] = cid[root]
            # pairs bucketed by component (counting sort)
            p_cnt = np.zeros(n_comp + 1, np.int64)
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    p_cnt[comp[t_loc[pt[g]]] + 1] += 1
            for q in range(n_comp):
                p_cnt[q + 1] += p_cnt[q]
            p_ord = np.empty(p_cnt[n_comp], np.int64)
            fill = p_cnt[:-1].copy()
            for g in range(a, b):
                if not (deg_t[pt[g]] == 1 and deg_c[pc[g]] == 1):
                    q = comp[t_loc[pt[g]]]
                    p_ord[fill[q]] = g
                    fill[q] += 1
            for q in range(n_comp):
                # the component's tracks and candidates in ascending order (as np.unique in the reference)
                mt = mc = 0
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    if t_q[pt[g]] < 0:
                        t_q[pt[g]] = 0
                        mt += 1
                    if c_q[pc[g]] < 0:
                        c_q[pc[g]] = 0
                        mc += 1
                qt = np.empty(mt, np.int64)
                qc = np.empty(mc, np.int64)
                it = ic = 0
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    if t_q[pt[g]] == 0:
                        t_q[pt[g]] = 1
                        qt[it] = pt[g]
                        it += 1
                    if c_q[pc[g]] == 0:
                        c_q[pc[g]] = 1
                        qc[ic] = pc[g]
                        ic += 1
                qt.sort()
                qc.sort()
                for i in range(mt):
                    t_q[qt[i]] = i
                for i in range(mc):
                    c_q[qc[i]] = i
                cost = np.full((mt, mc), 1e6)
                for z_ in range(p_cnt[q], p_cnt[q + 1]):
                    g = p_ord[z_]
                    cost[t_q[pt[g]], c_q[pc[g]]] = pm[g]
                if mt <= mc:
                    col = _hungarian(cost)
                    for i in range(mt):
                        if col[i] >= 0 and cost[i, col[i]] < 1e6:
                            ti[n_m] = qt[i]
                            ci[n_m] = qc[col[i]]
                            n_m += 1
                else:
                    row = _hungarian(cost.T.copy())
                    for j in range(mc):
                        if row[j] >= 0 and cost[row[j], j] < 1e6:
                            ti[n_m] = qt[row[j]]
                            ci[n_m] = qc[j]
                            n_m += 1
                for i in range(mt):
                    t_q[qt[i]] = -1
                for i in range(mc):
                    c_q[qc[i]] = -1
            ut_s, uc_s = ut, uc
            for i in range(nt):
                t_loc[ut_s[i]] = -1
            for i in range(nc):
                c_loc[uc_s[i]] = -1
        a = b
    ti, ci = ti[:n_m], ci[:n_m]
    # Kalman update, position measured with isotropic noise
    taken = np.zeros(k, np.bool_)
    for j in range(n_m):
        t, c = ti[j], ci[j]
        taken[c] = True
        _kalman_update(x[t], P[t], z[c, 0], z[c, 1], (meas_sigma + meas_sigma_rel * rng[c]) ** 2)
        seen[t] += 1
    # births: unmatched candidates scoring >= birth_floor, in index order, take the first free rows
    born = np.empty(k - n_m, np.int64)
    n_b = 0
    for c in range(k):
        if not taken[c] and (birth_floor <= 0.0 or scores[c] >= birth_floor):  # (0: any score, even < 0)
            born[n_b] = c
            n_b += 1
    born = born[:n_b]
    tb = np.empty(n_b, np.int64)
    t = 0
    for j in range(n_b):
        while alive[t]:
            t += 1
        c = born[j]
        tb[j] = t
        alive[t] = True
        tid[t] = next_id
        next_id += 1
        o = obs[c]
        tobs[t] = o
        mv = (meas_sigma + meas_sigma_rel * rng[c]) ** 2
        x[t, 0], x[t, 1], x[t, 2], x[t, 3] = z[c, 0], z[c, 1], 0.0, 0.0
        P[t] = 0.0
        P[t, 0, 0] = P[t, 1, 1] = mv
        P[t, 2, 2] = P[t, 3, 3] = speed_var
        exist[t] = birth_exist
        lo_score[t] = lo_shape[t] = lo_motion[t] = 0.0
        lo_resid[t] = res_chi2[t] = res_dof[t] = 0.0
        score_sum[t] = n_scored[t] = 0.0
        seen[t] = 1
        age[t] = 0
        static_t[t] = 0.0
        moved[t] = False
        confirmed[t] = birth_exist >= confirm_exist
        npts[t] = head[t] = 0
        # the housing's centre is r behind the visible arc's middle, seen from the observer
        ax, ay = z[c, 0] - poses[o, 0], z[c, 1] - poses[o, 1]
        an = max(math.sqrt(ax * ax + ay * ay), 1e-9)
        fit_c[t, 0] = z[c, 0] + ax / an * r * 0.5
        fit_c[t, 1] = z[c, 1] + ay / an * r * 0.5
        anchor[t, 0], anchor[t, 1] = z[c, 0], z[c, 1]
        anchor_var[t] = mv
        anchor_odo[t] = odometer[o]
        anchor_rng[t] = rng[c]
    return ti, ci, tb, born, next_id


@numba.njit(cache=True, nogil=True)
def _finish_kernel(pre, hit, dt, alive, tobs, x, P, poses, exist, confirmed, moved, lo_motion, static_t, age,
                   seen, anchor, anchor_var, anchor_odo, anchor_rng, odometer, p_detect, clutter, max_range,
                   confirm_exist, delete_exist, motion_dist, motion_gain, head_rate2, pos_rate2):  # fmt: skip
    """Existence (Bayes: hit, or a miss when in range), confirm; the motion cue; age; delete.

    The distances are ``math.hypot``s (libm's, ~15 ns each), taken only where a comparison needs them: a
    squared distance clear of the threshold's square by a relative 1e-9 (far above the rounding of
    either) decides it alone, and a track that has moved (the flag stays) or was seen in 2 frames or fewer
    needs no displacement. The same decisions as computing every distance."""
    r_in, r_out = max_range * max_range * (1.0 - 1e-9), max_range * max_range * (1.0 + 1e-9)
    for t in range(alive.shape[0]):
        if pre[t]:
            p = exist[t]
            if hit[t]:
                exist[t] = p / (p + (1 - p) * clutter)
            else:
                o = tobs[t]
                dx, dy = x[t, 0] - poses[o, 0], x[t, 1] - poses[o, 1]
                d2 = dx * dx + dy * dy
                if d2 <= r_in or (d2 < r_out and math.hypot(dx, dy) <= max_range):
                    exist[t] = p * (1 - p_detect) / (1 - p * p_detect)
    for t in range(alive.shape[0]):
        if not alive[t]:
            continue
        if exist[t] >= confirm_exist:
            confirmed[t] = True
        # motion: displaced from where first seen beyond 3 sigma, sigma including the odometry drift since
        if not moved[t] and seen[t] > 2:
            dx, dy = x[t, 0] - anchor[t, 0], x[t, 1] - anchor[t, 1]
            aged = odometer[tobs[t]] - anchor_odo[t]
            drift = aged * (head_rate2 * anchor_rng[t] ** 2 + pos_rate2)
            var = anchor_var[t] + 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + drift
            s3 = 3.0 * math.sqrt(var)
            thr = max(motion_dist, s3)
            if dx * dx + dy * dy >= thr * thr * (1.0 - 1e-9):
                disp = math.hypot(dx, dy)
                if disp > motion_dist and disp > s3:
                    moved[t] = True
        lo_motion[t] = motion_gain if moved[t] else 0.0
        static_t[t] += dt
        age[t] += 1
        alive[t] = exist[t] >= delete_exist


@numba.njit(cache=True, nogil=True)
def _score_logits(scores):
    """The candidates' score log-odds, clipped (the score cue's and the classifier's per-frame input)."""
    lgs = np.empty(scores.shape[0])
    for j in range(scores.shape[0]):
        p = min(max(scores[j], 1e-6), 1 - 1e-6)
        lgs[j] = min(max(math.log(p / (1 - p)), -6.0), 6.0)
    return lgs


@numba.njit(cache=True, nogil=True)
def _feature_kernel(tracks, n_matched, lgs, accepted, rng, beams, lgsum, lgsq, lgmax, lglast, accsum,
                    acclast, f_beams, f_rng, hit):  # fmt: skip
    """The track classifier's running inputs of the updated tracks (``tracks[j]`` got candidate ``j``, of
    clipped score log-odds ``lgs[j]``, :func:`_score_logits`; rows from ``n_matched`` on were born this
    frame and start afresh); ``hit`` marks them."""
    hit[:] = False
    for j in range(tracks.shape[0]):
        t = tracks[j]
        lg = lgs[j]
        a = (1.0 if accepted[j] else 0.0) if accepted.shape[0] else 0.5  # 0.5: decisions not given
        if j >= n_matched:
            lgsum[t] = lgsq[t] = accsum[t] = 0.0
            lgmax[t] = -6.0
        lgsum[t] += lg
        lgsq[t] += lg * lg
        lgmax[t] = max(lgmax[t], lg)
        lglast[t] = lg
        accsum[t] += a
        acclast[t] = a
        f_beams[t] = beams[j]
        f_rng[t] = rng[j]
        hit[t] = True


@numba.njit(cache=True, nogil=True)
def _score_kernel(ti, lgs, accepted, rng, score_sum, n_scored, lo_score, bar1, per_metre, weight, acc_llr,
                  rej_llr, n0, gain, clamp):  # fmt: skip
    """The score cue of the updated tracks ``ti`` (candidate ``j`` of this frame for ``ti[j]``, its clipped
    score log-odds ``lgs[j]``, :func:`_score_logits`)."""
    for j in range(ti.shape[0]):
        t = ti[j]
        lg = lgs[j]
        step = weight * (lg - (bar1 - per_metre * (rng[j] - 1.0)))
        if accepted.shape[0]:
            step += acc_llr if accepted[j] else rej_llr
        score_sum[t] += step
        n_scored[t] += 1
        lo_score[t] = min(max(gain * score_sum[t] / (n_scored[t] + n0), -clamp), clamp)


@numba.njit(cache=True, nogil=True)
def _points_check(pts, owner, k):
    """0: fine; 1: an owner outside [0, k); 2: a non-finite point; 3: fine but not sorted by owner."""
    return _points_scan_seq(pts, owner, k, np.empty(k + 1, np.int64))


@numba.njit(cache=True, nogil=True)
def _points_scan(pts, owner, k, cstart):
    """:func:`_points_scan_seq` (the same status and ``cstart``) without a branch per point: the checks
    as branch-free counts (``v - v`` is 0 for a finite ``v``, NaN otherwise), and ``cstart`` without a
    branch per point either (for owners sorted in ``[0, k)``, the number of points owned by an earlier
    candidate is the first point owned by ``c`` or a later one). A frame of the learned feed has ~6,000
    candidates of ~2 points: the sequential scan's "next candidate?" branch was mispredicted at about every
    other point. A bad input takes the sequential scan (its first bad point decides)."""
    n = pts.shape[0]
    n_nonfinite = n_bad = n_desc = 0
    for i in range(n):
        v = (pts[i, 0] - pts[i, 0]) + (pts[i, 1] - pts[i, 1])  # NaN unless both are finite
        n_nonfinite += v != v
        o = owner[i]
        n_bad += (o < 0) | (o >= k)
    if n_nonfinite or n_bad:
        return _points_scan_seq(pts, owner, k, cstart)
    for i in range(1, n):
        n_desc += owner[i] < owner[i - 1]
    if n_desc:
        return 3
    # each candidate's first point, stored from the last point back (the first one's index stays; stores
    # only: counting ``cstart[owner[i] + 1] += 1`` chained each point on the store before it, ~6 cycles a
    # point), then the first point owned by ``c`` or a later one from the back (candidates without points)
    cstart[:] = n
    for i in range(n - 1, -1, -1):
        cstart[owner[i]] = i
    run = n  # (in a register: read back from memory, each step waited on the store before it)
    for c in range(k - 1, -1, -1):
        run = min(cstart[c], run)
        cstart[c] = run
    return 0


@numba.njit(cache=True, nogil=True)
def _points_scan_seq(pts, owner, k, cstart):
    """:func:`_points_check`'s status, and in the same pass (when sorted) each candidate's points:
    ``cstart[c]`` the first point owned by ``c`` or a later candidate (so ``c``'s are
    ``cstart[c]:cstart[c + 1]``)."""
    status = 0
    c = 0
    for i in range(pts.shape[0]):
        o = owner[i]
        if o < 0 or o >= k:
            return 1
        if not (np.isfinite(pts[i, 0]) and np.isfinite(pts[i, 1])):
            return 2
        if i and o < owner[i - 1]:
            status = 3
        while c <= o:
            cstart[c] = i
            c += 1
    while c <= k:
        cstart[c] = pts.shape[0]
        c += 1
    return status


@numba.njit(cache=True, nogil=True)
def _points_prep(pts, owner, obs, noise, cos, sin, poses, sigma2):
    """Each candidate point in its observer's odometry frame, its expected noise and its range."""
    n = pts.shape[0]
    odom, sig, dist = np.empty((n, 2)), np.empty(n), np.empty(n)
    # each point's observer's values gathered first, so that the arithmetic (two square roots per point)
    # runs as one vector pass over contiguous columns
    g = np.empty((5, n))
    for i in range(n):
        o = obs[owner[i]]
        g[0, i], g[1, i], g[2, i], g[3, i], g[4, i] = noise[o], cos[o], sin[o], poses[o, 0], poses[o, 1]
    px, py = np.empty(n), np.empty(n)
    for i in range(n):
        px[i], py[i] = pts[i, 0], pts[i, 1]
    ox, oy = np.empty(n), np.empty(n)
    for i in range(n):
        d = math.sqrt(px[i] * px[i] + py[i] * py[i])
        dist[i] = d
        sig[i] = math.sqrt(sigma2 + (g[0, i] * d) ** 2)
        ox[i] = g[1, i] * px[i] - g[2, i] * py[i] + g[3, i]
        oy[i] = g[2, i] * px[i] + g[1, i] * py[i] + g[4, i]
    for i in range(n):
        odom[i, 0], odom[i, 1] = ox[i], oy[i]
    return odom, sig, dist


# fits side by side: LLVM vectorises the lane loop 8 wide, unrolled twice, so it takes the vector path from 16
# lanes on (8 lanes ran it scalar: 4-5x slower per fit)
_LANES = 16


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lanes_normal(px, py, w, cx, cy, mm, L, r, a00, a01, a11, g0, g1):
    """One Gauss-Newton step's normal equations of ``L`` fits at once (lane ``l``: points ``px[:mm, l]``,
    ``py``, weights ``w``, centre ``cx[l], cy[l]``), each lane's sums in :func:`_fit_span`'s order."""
    for l in range(L):
        a00[l] = a01[l] = a11[l] = g0[l] = g1[l] = 0.0
    for i in range(mm):
        for l in range(L):  # the lanes innermost: vectorised (a vector of fits)
            dx, dy = px[i, l] - cx[l], py[i, l] - cy[l]
            d = max(math.sqrt(dx * dx + dy * dy), 1e-12)
            jx, jy = -dx / d, -dy / d
            ei = d - r
            wi = w[i, l]
            a00[l] += wi * jx * jx
            a01[l] += wi * jx * jy
            a11[l] += wi * jy * jy
            g0[l] += wi * jx * ei
            g1[l] += wi * jy * ei


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lanes_start(v0, w, mm, mx, my, mf, ox, oy, r, cx, cy, L):
    """The fits' weights ``1 / sig^2`` and starts: ``0.7 r`` behind the points' mean (sums ``mx, my`` of
    ``mf`` points) as seen from the observer at ``ox, oy`` (each lane's operations in the scalar order)."""
    for i in range(mm):
        for l in range(L):
            w[i, l] = 1.0 / v0[i, l]
    for l in range(L):
        ax, ay = mx[l] / mf[l], my[l] / mf[l]
        ux, uy = ax - ox[l], ay - oy[l]
        un = max(math.sqrt(ux * ux + uy * uy), 1e-9)
        cx[l] = ax + ux / un * r * 0.7
        cy[l] = ay + uy / un * r * 0.7


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lanes_step(a00, a01, a11, g0, g1, cx, cy, go, L):
    """One Gauss-Newton step of every lane still going (:func:`_fit_span`'s step and its two stopping
    rules), branch-free so that it runs across the lanes as vectors: a lane that stops keeps its centre
    (the step is computed and discarded), the others move by exactly :func:`_fit_span`'s step."""
    for l in range(L):
        det = a00[l] * a11[l] - a01[l] * a01[l]
        s0 = -(a11[l] * g0[l] - a01[l] * g1[l]) / det
        s1 = -(a00[l] * g1[l] - a01[l] * g0[l]) / det
        ok = go[l] and not det <= 1e-12 * (a00[l] + a11[l]) ** 2
        cx[l] = cx[l] + s0 if ok else cx[l]
        cy[l] = cy[l] + s1 if ok else cy[l]
        go[l] = ok and not s0 * s0 + s1 * s1 < 1e-18


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lanes_chi2(px, py, v0, cx, cy, mm, L, r, e, chi2):
    """The fits' residuals ``e = |p - c| - r`` and their noise-normalised chi-square (padding: ``v0 = inf``
    adds exactly 0), each lane's sum in the points' order."""
    for l in range(L):
        chi2[l] = 0.0
    for i in range(mm):
        for l in range(L):
            ep = math.sqrt((px[i, l] - cx[l]) ** 2 + (py[i, l] - cy[l]) ** 2) - r
            e[i, l] = ep
            chi2[l] += ep * ep / v0[i, l]


@numba.njit(cache=True, nogil=True, error_model="numpy")  # no zero-division checks: they stop vectorising
def _frame_fits_kernel(ti, ci, pts, sig, cstart, tobs, poses, z, r, iterations, warm, delta2, resid_clamp,
                       lo_resid, res_chi2, res_dof):  # fmt: skip
    """The per-frame known-radius circle fits of the updated tracks ``ti`` (candidate ``ci[j]``'s points
    ``pts[cstart[c]:cstart[c + 1]]``, odometry frame, noise ``sig``; 3 points or more; one pose, so no
    odometry drift: valid while the object moves) and each track's residual sums: the noise-normalised
    chi-square and its dof, and (when the hand-tuned cue is on) the Gaussian LLR "on the circle" vs "off it
    by delta", the fit's 2 dof taken out of the log term. Each fit is :func:`_fit_span` with weights
    ``1 / sig^2``, ``iterations`` Gauss-Newton steps from ``0.7 r`` behind the points' mean as seen from
    the observer, or (``warm``) from the candidate's own centre ``z[c]`` (the geometric detector's is its
    circle fit of the same points).

    Sixteen fits run side by side, one per vector lane (the point index outer, the lane inner, so the
    compiler vectorises the square roots and divisions across fits), grouped by point count so that
    lanes are padded little; a padded point has weight 0 and adds exactly +0.0 or -0.0 to a sum that
    starts at +0.0, and each lane stops on its own rule, so every fit's centre and residuals are the same
    bits as :func:`_fit_span`'s (tested against one fit at a time). No division here can be by zero (the
    distances are >= 1e-12, the step's determinant is tested first), so numpy's error model changes
    nothing but the code."""
    n = ti.shape[0]
    m_max = nf = 0
    for j in range(n):
        m = cstart[ci[j] + 1] - cstart[ci[j]]
        if m >= 3:
            nf += 1
            m_max = max(m_max, m)
    if nf == 0:
        return
    L = min(_LANES, nf)  # known at run time only: a constant trip count gets unrolled, not vectorised
    # the fits in ascending point count (counting sort): a group of L has similar lengths
    cnt = np.zeros(m_max + 2, np.int64)
    for j in range(n):
        m = cstart[ci[j] + 1] - cstart[ci[j]]
        if m >= 3:
            cnt[m + 1] += 1
    for m in range(m_max + 1):
        cnt[m + 1] += cnt[m]
    jobs = np.empty(nf, np.int64)
    for j in range(n):
        m = cstart[ci[j] + 1] - cstart[ci[j]]
        if m >= 3:
            jobs[cnt[m]] = j
            cnt[m] += 1
    px, py, w = np.zeros((m_max, L)), np.zeros((m_max, L)), np.zeros((m_max, L))
    v0, e = np.zeros((m_max, L)), np.zeros((m_max, L))
    cx, cy, go = np.zeros(L), np.zeros(L), np.zeros(L, np.bool_)
    mx, my, mfl, ox, oy = np.zeros(L), np.zeros(L), np.ones(L), np.zeros(L), np.zeros(L)
    a00, a01, a11, g0, g1, chi2 = np.empty(L), np.empty(L), np.empty(L), np.empty(L), np.empty(L), np.empty(L)
    for g in range(0, nf, L):
        nl = min(L, nf - g)
        mm = cstart[ci[jobs[g + nl - 1]] + 1] - cstart[ci[jobs[g + nl - 1]]]  # the group's longest
        for l in range(L):
            mx[l] = my[l] = 0.0
            if l >= nl:  # an empty lane: weight 0, never stepped
                for i in range(mm):
                    px[i, l] = py[i, l] = 0.0
                    v0[i, l] = np.inf
                go[l] = False
                continue
            j = jobs[g + l]
            a, b = cstart[ci[j]], cstart[ci[j] + 1]
            sx = sy = 0.0  # in registers (a sum through mx[l] waits on its own store every point)
            for p in range(a, b):  # the points' sums in their order (the start is their mean)
                sx += pts[p, 0]
                sy += pts[p, 1]
                px[p - a, l] = pts[p, 0]
                py[p - a, l] = pts[p, 1]
                v0[p - a, l] = sig[p] * sig[p]
            mx[l], my[l] = sx, sy
            for i in range(b - a, mm):  # padding: weight 1 / inf = 0, adds exactly 0 to every sum
                px[i, l] = py[i, l] = 0.0
                v0[i, l] = np.inf
            o = tobs[ti[j]]
            mfl[l], ox[l], oy[l] = b - a, poses[o, 0], poses[o, 1]
            go[l] = True
        _lanes_start(v0, w, mm, mx, my, mfl, ox, oy, r, cx, cy, L)
        if warm:
            for l in range(nl):
                c = ci[jobs[g + l]]
                cx[l], cy[l] = z[c, 0], z[c, 1]
        for _ in range(iterations):  # _fit_span's steps, lane by lane
            active = False
            for l in range(L):
                active |= go[l]
            if not active:
                break
            _lanes_normal(px, py, w, cx, cy, mm, L, r, a00, a01, a11, g0, g1)
            _lanes_step(a00, a01, a11, g0, g1, cx, cy, go, L)
        _lanes_chi2(px, py, v0, cx, cy, mm, L, r, e, chi2)
        for l in range(nl):  # the track's sums
            j = jobs[g + l]
            t, c = ti[j], ci[j]
            mf = cstart[c + 1] - cstart[c]
            res_chi2[t] += chi2[l]
            res_dof[t] += mf - 2
            if resid_clamp > 0.0:  # the hand-tuned cue's LLR (its logs) only when it is on
                llr = 0.0
                for i in range(mf):
                    vi = v0[i, l]
                    v1 = vi + delta2
                    ee = e[i, l] * e[i, l]
                    llr += 0.5 * math.log(v1 / vi) * (mf - 2) / mf - 0.5 * ee * (1.0 / vi - 1.0 / v1)
                lo_resid[t] = min(max(lo_resid[t] + llr, -resid_clamp), resid_clamp)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _centre_resid_kernel(ti, ci, pts, lo, hi, xy, obs, noise, sigma2, r, delta2, resid_clamp, lo_resid,
                         res_chi2, res_dof, iterations=0):  # fmt: skip
    """The per-frame residual sums from the candidate's centre (``frame_fit_warm_start`` 1, the default):
    each updated track's candidate points (``pts[lo[c]:hi[c]]``, 3 or more; robot frame) against a circle
    of the housing radius at the candidate's own centre ``xy[c]`` (robot frame too: distances do not depend
    on the frame, so the points need no transform). Each point's variance is ``sigma2 + (noise * range)^2``;
    the sums are :func:`_frame_fits_kernel`'s: the noise-normalised chi-square, its dof (points - 2, as after
    a fit: the detector placed the centre on these points) and, when the hand-tuned cue is on, its LLR; after
    ``iterations`` Gauss-Newton steps of the centre (:func:`_fit_span`'s, weights ``1 / variance``; the
    default 1) from the candidate's centre, in the robot frame. Divisions: each point's weight once, one
    reciprocal of the distance per step (the residuals reuse the weights: ``e^2 w``)."""
    m_max = 0
    for j in range(ti.shape[0]):
        m_max = max(m_max, hi[ci[j]] - lo[ci[j]])
    wbuf = np.empty(m_max)
    for j in range(ti.shape[0]):
        c = ci[j]
        a, b = lo[c], hi[c]
        mf = b - a
        if mf < 3:
            continue
        t = ti[j]
        cx, cy = xy[c, 0], xy[c, 1]
        n2 = noise[obs[c]] * noise[obs[c]]
        for p in range(a, b):  # each point's weight, 1 / variance, once (the divider bounds this kernel)
            px, py = pts[p, 0], pts[p, 1]
            wbuf[p - a] = 1.0 / (sigma2 + n2 * (px * px + py * py))
        for _ in range(iterations):
            a00 = a01 = a11 = g0 = g1 = 0.0
            for p in range(a, b):
                px, py = pts[p, 0], pts[p, 1]
                w = wbuf[p - a]
                dx, dy = px - cx, py - cy
                d = max(math.sqrt(dx * dx + dy * dy), 1e-12)
                inv = 1.0 / d
                jx, jy = -dx * inv, -dy * inv
                ei = d - r
                a00 += w * jx * jx
                a01 += w * jx * jy
                a11 += w * jy * jy
                g0 += w * jx * ei
                g1 += w * jy * ei
            det = a00 * a11 - a01 * a01
            if det <= 1e-12 * (a00 + a11) ** 2:  # points on a line through c: no unique step
                break
            s0 = -(a11 * g0 - a01 * g1) / det
            s1 = -(a00 * g1 - a01 * g0) / det
            cx += s0
            cy += s1
            if s0 * s0 + s1 * s1 < 1e-18:
                break
        chi2 = llr = 0.0
        for p in range(a, b):
            px, py = pts[p, 0], pts[p, 1]
            e = math.sqrt((px - cx) * (px - cx) + (py - cy) * (py - cy)) - r
            chi2 += e * e * wbuf[p - a]
            if resid_clamp > 0.0:
                v0 = sigma2 + n2 * (px * px + py * py)
                v1 = v0 + delta2
                llr += 0.5 * math.log(v1 / v0) * (mf - 2) / mf - 0.5 * e * e * (1.0 / v0 - 1.0 / v1)
        res_chi2[t] += chi2
        res_dof[t] += mf - 2
        if resid_clamp > 0.0:
            lo_resid[t] = min(max(lo_resid[t] + llr, -resid_clamp), resid_clamp)


@numba.njit(cache=True, nogil=True)
def _outline_kernel(ti, ci, pts, sig, dist, cstart, obs, odometer, moved, buf, aux, npts, head, fit_c,
                    lo_shape, x, P, now, r, delta2, n_cap, min_points, clamp, head_rate2,
                    pos_rate2):  # fmt: skip
    """Append each updated track's candidate points (odometry frame) to its ring buffer, then refit its
    outline (warm-started at the last fit's centre) and set its shape cue. A track that has moved keeps
    its last shape cue: its points no longer share one frame, and the motion cue has decided it anyway.
    (The per-frame fits are :func:`_frame_fits_kernel`'s.)"""
    m_max = buf.shape[1]
    e, var, wgt, pp = np.empty(m_max), np.empty(m_max), np.empty(m_max), np.empty((m_max, 2))
    for j in range(ti.shape[0]):
        t, c = ti[j], ci[j]
        a, b = cstart[c], cstart[c + 1]
        if moved[t]:  # a moving object's points share no frame: its outline is no evidence
            lo_shape[t] = 0.0
            continue
        if b == a or m_max == 0:  # max_points 0: no outline kept (nor its cue: shape_clamp is 0 then)
            continue
        h, odo_t = head[t], odometer[obs[t]]
        for p in range(a, b):
            buf[t, h, 0] = pts[p, 0]
            buf[t, h, 1] = pts[p, 1]
            if aux.shape[1]:
                aux[t, h, 0] = sig[p]
                aux[t, h, 1] = dist[p]
                aux[t, h, 2] = odo_t
                aux[t, h, 3] = now
            h += 1
            if h == m_max:  # the ring wraps (no integer division per point)
                h = 0
        head[t] = h
        npts[t] = min(npts[t] + (b - a), m_max)
        m = npts[t]
        if m < min_points or clamp <= 0.0:  # clamp 0: the cue is off, skip the (costly) refit
            continue
        acc, acx = buf[t, :m], aux[t, :m]
        odo = odometer[obs[t]]
        vx, vy = x[t, 2], x[t, 3]
        pv = 0.5 * (P[t, 2, 2] + P[t, 3, 3])
        if (vx * vx + vy * vy) < 4.0 * pv:  # no significant velocity: test the object as static
            vx = vy = pv = 0.0
        for i in range(m):
            # sensor noise, plus the ego-motion error accumulated since the point was seen (heading drift
            # moves it sideways in proportion to its range), plus how far the object may have gone since:
            # the point is moved along the track's velocity, with that velocity's uncertainty
            aged = odo - acx[i, 2]
            dt = now - acx[i, 3]
            pp[i, 0] = acc[i, 0] + vx * dt
            pp[i, 1] = acc[i, 1] + vy * dt
            var[i] = (
                acx[i, 0] * acx[i, 0] + aged * (head_rate2 * acx[i, 1] * acx[i, 1] + pos_rate2) + pv * dt * dt
            )
            wgt[i] = 1.0 / var[i]
        cen = fit_c[t]
        _fit_known_circle(pp[:m], wgt[:m], r, cen, 4, e[:m])
        llr = 0.0
        for i in range(m):
            v0 = var[i]
            v1 = v0 + delta2
            llr += 0.5 * math.log(v1 / v0) - 0.5 * e[i] * e[i] * (1.0 / v0 - 1.0 / v1)
        llr *= min(1.0, n_cap / m)
        lo_shape[t] = min(max(llr, -clamp), clamp)


# -- the fused frame update ---------------------------------------------------------------------------------

_NO_FLAGS = np.zeros(0, np.bool_)
_NO_POINTS = np.zeros((0, 2))
_NO_OWNER = np.zeros(0, np.int64)
# _update_kernel's status codes (0: done)
_BAD_DELTA, _BAD_VALUES, _BAD_OBS, _BAD_NOISE, _BAD_OWNER, _BAD_POINTS, _BAD_SORT = range(1, 8)


def _param_array(pr: TrackerParams) -> np.ndarray:
    """:class:`TrackerParams` as :func:`_update_kernel` reads them (derived values as the staged steps
    computed them, so that the fused update is bitwise the staged one)."""
    return np.array([
        pr.process_accel**2, pr.meas_sigma, pr.meas_sigma_rel, pr.init_speed_sigma**2, pr.gate_chi2,
        pr.birth_existence, pr.confirm_existence, pr.r, float(_logit(pr.score_prior)), pr.score_per_metre,
        pr.score_weight, pr.accept_llr, pr.reject_llr, pr.score_n0, pr.score_gain, pr.score_clamp,
        pr.shape_sigma**2, pr.shape_delta**2, float(pr.shape_n_cap), float(int(pr.shape_min_points)),
        pr.shape_clamp, pr.odom_heading_rate**2, pr.odom_position_rate**2, pr.resid_clamp, pr.p_detect,
        pr.clutter_ratio, pr.max_range, pr.delete_existence, pr.motion_dist, pr.motion_gain, pr.min_score,
        0.5 * pr.wheel_base, float(int(pr.frame_fit_iterations)), float(pr.frame_fit_warm_start),
        pr.birth_min_score, float(pr.frame_residuals),
    ], np.float64)  # fmt: skip


def _update_error(status, N, k, delta, xy, scores, obs, noise, pts) -> str:
    """The message of a bad input :func:`_update_kernel` found (its status code)."""
    if status == _BAD_DELTA:
        return (f"KinTracker: odom_delta must be ({N}, 3) finite numbers (dx, dy, dtheta per observer), "
                f"got {delta.shape} {delta!r}")  # fmt: skip
    if status == _BAD_VALUES:
        return (f"KinTracker: obs (k,), xy (k, 2) and scores (k,) must be finite and of one length, got "
                f"{obs.shape}, {xy.shape} and {scores.shape}")  # fmt: skip
    if status == _BAD_OBS:
        return f"KinTracker: obs must be observer indices in [0, {N}), got {obs!r}"
    if status == _BAD_NOISE:
        return f"KinTracker: noise must be {N} relative range noises >= 0, got {noise!r}"
    if status == _BAD_OWNER:
        return f"KinTracker: owner must give each of the {pts.shape[0]} points a candidate in [0, {k})"
    return "KinTracker: points must be finite"


@numba.njit(cache=True, nogil=True)
def _update_kernel(obs, xy, scores, accepted, delta, dt, pts, owner, has_points, noise, poses, odometer, now,
                   next_id, prm, F, I, B, x, P, anchor, fit_c, buf, aux, dec, model, slots,
                   block):  # fmt: skip
    """One frame of every observer (:meth:`KinTracker.update_batch`) on the packed state (:data:`_F_COLS`,
    :data:`_I_COLS`, :data:`_B_COLS`): :func:`_update_frame`, then (``dec``) the kin decision's compiled
    part (:func:`_decide_kernel`, the model's layers ``mean, scale, W, b, W2, b2, tail`` packed in ``model``:
    :func:`_model_array`) and (``slots`` >= 0)
    :meth:`KinTracker.track_arrays`' padded slots (:func:`_slots_kernel`, ``slots`` of them per observer;
    ``block``: as the envs' info block, :meth:`KinTracker._track_block`). Returns ``(status, next_id, rows,
    kp, sel, h, (tracks, mask, count, blk))`` (the decision's arrays empty unless ``dec``, the slots unless
    ``slots >= 0``)."""
    # the frame's steps see the rows below n only: the rows from the last live one up are free, and births
    # (one per candidate at most) take the first free rows, so every row this frame reads or writes is below
    # n (a swarm's arrays have about twice its tracks: their loops over every row would mostly skip)
    cap = B.shape[1]
    top = cap
    while top > 0 and not B[0, top - 1]:
        top -= 1
    n = min(cap, top + xy.shape[0])
    (exist, lo_score, lo_shape, lo_motion, static_t, anchor_var, anchor_odo, anchor_rng, lo_resid, res_chi2,
     res_dof, score_sum, n_scored, f_lgsum, f_lgsq, f_lgmax, f_lglast, f_accsum, f_acclast, f_beams,
     f_rng) = _f_cols(F, n)  # fmt: skip
    tid, tobs, seen, age, npts, head = I[0][:n], I[1][:n], I[2][:n], I[3][:n], I[4][:n], I[5][:n]
    alive, moved, confirmed, hit = B[0][:n], B[1][:n], B[2][:n], B[3][:n]
    x, P, anchor, fit_c, buf, aux = x[:n], P[:n], anchor[:n], fit_c[:n], buf[:n], aux[:n]
    status, next_id = _update_frame(
        obs, xy, scores, accepted, delta, dt, pts, owner, has_points, noise, poses, odometer, now, next_id,
        prm, alive, tobs, tid, x, P, exist, lo_score, lo_shape, lo_motion, lo_resid, res_chi2, res_dof,
        score_sum, n_scored, seen, age, static_t, moved, confirmed, npts, head, fit_c, anchor, anchor_var,
        anchor_odo, anchor_rng, buf, aux, f_lgsum, f_lgsq, f_lgmax, f_lglast, f_accsum, f_acclast, f_beams,
        f_rng, hit,
    )  # fmt: skip
    if not status:
        B[3][n:] = False  # "updated this frame" is cleared on every row (a row adopt() freed may hold it)
    if status or not dec:
        return _no_decision(status, next_id)
    mean, scale, W, b, W2, b2, tail, log_min, hit_only = _model_views(model)
    rows, kp, sel, h = _decide_kernel(
        poses.shape[0], alive, confirmed, tobs, seen, x, P, anchor, anchor_var, anchor_odo, anchor_rng,
        odometer, hit, f_lgsum, f_lgsq, f_lgmax, f_lglast, f_accsum, f_acclast, f_beams, f_rng, moved, exist,
        res_chi2, res_dof, prm[21], prm[22], mean, scale, W, b, W2, b2, tail, log_min, hit_only,
    )  # fmt: skip
    if slots < 0:
        return status, next_id, rows, kp, sel, h, _no_slots()
    # track_arrays' slots while this frame's rows are in cache (_slots_kernel on the rows below n: every live
    # row is; ``poses`` already the new poses)
    so = _slots_kernel(rows, kp, poses.shape[0], slots, tobs, tid, confirmed, x, poses, exist, seen, age,
                       block)
    return status, next_id, rows, kp, sel, h, so


_NEED_ROOM = 8  # _update_segments_kernel: the state's arrays need more rows (``next_id``: how many)


@numba.njit(cache=True, nogil=True)
def _no_slots():
    """:func:`_slots_kernel`'s outputs when it does not run: ``(tracks, mask, count, blk)``, all empty."""
    return (np.zeros((0, 0, 10), np.float32), np.zeros((0, 0), np.bool_), np.zeros(0, np.int64),
            np.zeros((0, 0, 0)))


@numba.njit(cache=True, nogil=True)
def _no_decision(status, next_id):
    """:func:`_update_kernel`'s outputs when no decision ran (``status``, ``next_id`` as given)."""
    return (status, next_id, np.empty(0, np.int64), np.zeros(0), np.empty(0, np.int64), np.empty((0, 0)),
            _no_slots())


@numba.njit(cache=True, nogil=True)
def _update_segments_kernel(obs, rows, x, y, scores, accepted, all_accepted, delta, dt, ranges, angles,
                            first, last, range_max, noise, poses, odometer, now, next_id, prm, F, I, B, xs, P,
                            anchor, fit_c, buf, aux, dec, model, slots, block):  # fmt: skip
    """:meth:`KinTracker._update_segments_trusted`: the candidates' ``xy`` and points (as ``np.c_[x, y]``
    and :func:`_segment_points_kernel` give them), the room check of :meth:`KinTracker.update_batch`
    (``_NEED_ROOM`` and the rows needed, before any state changes), then :func:`_update_kernel`."""
    k = x.shape[0]
    min_score = prm[30]
    kept = k
    if min_score > 0.0 and k:
        kept = 0
        for c in range(k):
            kept += scores[c] >= min_score
    n_alive = 0
    for t in range(B.shape[1]):
        n_alive += B[0, t]
    if n_alive + kept > B.shape[1]:
        return _no_decision(_NEED_ROOM, n_alive + kept)
    xy = np.empty((k, 2))
    for c in range(k):
        xy[c, 0], xy[c, 1] = x[c], y[c]
    if all_accepted:
        accepted = np.ones(k, np.bool_)
    pts, owner = _segment_points_kernel(ranges, angles, rows, first, last, range_max)
    return _update_kernel(obs, xy, scores, accepted, delta, dt, pts, owner, True, noise, poses, odometer, now,
                          next_id, prm, F, I, B, xs, P, anchor, fit_c, buf, aux, dec, model, slots,
                          block)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _update_frame(obs, xy, scores, accepted, delta, dt, pts, owner, has_points, noise, poses, odometer, now,
                  next_id, prm, alive, tobs, tid, x, P, exist, lo_score, lo_shape, lo_motion, lo_resid,
                  res_chi2, res_dof, score_sum, n_scored, seen, age, static_t, moved, confirmed, npts, head,
                  fit_c, anchor, anchor_var, anchor_odo, anchor_rng, buf, aux, f_lgsum, f_lgsq, f_lgmax,
                  f_lglast, f_accsum, f_acclast, f_beams, f_rng, hit):  # fmt: skip
    """One frame of every observer (:meth:`KinTracker.update_batch`) in one call: checks the inputs'
    values (a status code and no state change if one is bad), drops candidates below ``min_score``,
    moves each observer by its odometry, then runs the frame's steps in the staged order — association,
    filter and births (:func:`_frame_kernel`), the score cue, the per-frame fits and outline
    (:func:`_outline_kernel`), the classifier's running inputs, existence / motion / confirm / delete.
    ``poses`` is updated in place (the caller passes a fresh copy). Returns ``(status, next_id)``."""
    k, N = xy.shape[0], poses.shape[0]
    # -- the inputs' values, before any state changes
    for o in range(N):
        if not (np.isfinite(delta[o, 0]) and np.isfinite(delta[o, 1]) and np.isfinite(delta[o, 2])):
            return _BAD_DELTA, next_id
    n_nonfinite = n_bad = 0  # counted branch-free first (vectorised), then which one
    for c in range(k):
        v = (xy[c, 0] - xy[c, 0]) + (xy[c, 1] - xy[c, 1]) + (scores[c] - scores[c])  # NaN unless finite
        n_nonfinite += v != v
        n_bad += (obs[c] < 0) | (obs[c] >= N)
    if n_nonfinite:
        for c in range(k):
            if not (np.isfinite(xy[c, 0]) and np.isfinite(xy[c, 1]) and np.isfinite(scores[c])):
                return _BAD_VALUES, next_id
    if n_bad:
        return _BAD_OBS, next_id
    for o in range(N):
        if not (np.isfinite(noise[o]) and noise[o] >= 0):
            return _BAD_NOISE, next_id
    cstart = np.empty(k + 1, np.int64)  # owner sorted: candidate c's points are cstart[c]:cstart[c + 1]
    if has_points:
        status = _points_scan(pts, owner, k, cstart)
        if status == 1:
            return _BAD_OWNER, next_id
        if status == 2:
            return _BAD_POINTS, next_id
        if status == 3:
            return _BAD_SORT, next_id
    # -- candidates below min_score are dropped (the rest renumbered). Their points stay where they are: kept
    # candidate j's are pts[lo[j]:hi[j]] (copying the kept points was ~10 % of a learned frame, which drops
    # ~5 of 6 candidates); only the fits from behind the points and the outline ring, which read each
    # point's owner, get them copied in order (and cstart renumbered)
    min_score = prm[30]
    gn = prm[32] > 0.0 and prm[33] <= 0.0  # fits from behind the points: in the odometry frame, owners read
    copy_pts = has_points and ((gn and prm[35] > 0.0) or buf.shape[1] > 0)
    kept = np.empty(k, np.int64)
    kk = 0
    for c in range(k):  # the kept candidates' indices, compacted without a branch
        kept[kk] = c
        kk += (min_score <= 0.0) | (scores[c] >= min_score)
    if kk < k:
        ob2, xy2, sc2 = np.empty(kk, np.int64), np.empty((kk, 2)), np.empty(kk)
        acc2 = np.empty(kk if accepted.shape[0] else 0, np.bool_)
        for j in range(kk):
            c = kept[j]
            ob2[j], xy2[j, 0], xy2[j, 1], sc2[j] = obs[c], xy[c, 0], xy[c, 1], scores[c]
        if accepted.shape[0]:
            for j in range(kk):
                acc2[j] = accepted[kept[j]]
        obs, xy, scores, accepted = ob2, xy2, sc2, acc2
        if copy_pts:  # the kept candidates' point ranges, copied in order
            m = 0
            for j in range(kk):
                m += cstart[kept[j] + 1] - cstart[kept[j]]
            pts2, own2, cs2 = np.empty((m, 2)), np.empty(m, np.int64), np.empty(kk + 1, np.int64)
            m = 0
            for j in range(kk):
                c = kept[j]
                cs2[j] = m
                for i in range(cstart[c], cstart[c + 1]):
                    pts2[m, 0], pts2[m, 1], own2[m] = pts[i, 0], pts[i, 1], j
                    m += 1
            cs2[kk] = m
            pts, owner, cstart = pts2, own2, cs2
            for j in range(kk):
                kept[j] = j
        k = kk
    lo, hi = np.empty(k if has_points else 0, np.int64), np.empty(k if has_points else 0, np.int64)
    if has_points:
        for j in range(k):
            lo[j], hi[j] = cstart[kept[j]], cstart[kept[j] + 1]
    # -- ego-motion: each observer's new pose in its odometry frame; the odometer (wheel travel)
    cos, sin = np.empty(N), np.empty(N)
    for o in range(N):
        c, s = math.cos(poses[o, 2]), math.sin(poses[o, 2])
        px = poses[o, 0] + c * delta[o, 0] - s * delta[o, 1]
        py = poses[o, 1] + s * delta[o, 0] + c * delta[o, 1]
        w = (poses[o, 2] + delta[o, 2] + math.pi) % (2.0 * math.pi) - math.pi  # wrap_angle
        if w <= -math.pi:
            w += 2.0 * math.pi
        poses[o, 0], poses[o, 1], poses[o, 2] = px, py, w
        odometer[o] += math.hypot(delta[o, 0], delta[o, 1]) + prm[31] * abs(delta[o, 2])
        cos[o], sin[o] = math.cos(w), math.sin(w)
    z, rng = np.empty((k, 2)), np.empty(k)  # candidates in their observer's odometry frame, and range
    for c in range(k):
        o = obs[c]
        z[c, 0] = cos[o] * xy[c, 0] - sin[o] * xy[c, 1] + poses[o, 0]
        z[c, 1] = sin[o] * xy[c, 0] + cos[o] * xy[c, 1] + poses[o, 1]
        rng[c] = math.sqrt(xy[c, 0] * xy[c, 0] + xy[c, 1] * xy[c, 1])  # (libm's hypot: ~15 ns a call)
    pre = alive.copy()  # the tracks before this frame's births (existence: hit or miss)
    ti, ci, tb, born, next_id = _frame_kernel(
        z, obs, rng, dt, N, alive, tobs, tid, next_id, x, P, poses, exist, lo_score, lo_shape, lo_motion,
        lo_resid, res_chi2, res_dof, score_sum, n_scored, seen, age, static_t, moved, confirmed, npts, head,
        fit_c, anchor, anchor_var, anchor_odo, anchor_rng, odometer, prm[0], prm[1], prm[2], prm[3], prm[4],
        prm[5], prm[6], prm[7], scores, prm[34],
    )  # fmt: skip
    n_m, n_t = ti.shape[0], ti.shape[0] + tb.shape[0]
    tracks, cands = np.empty(n_t, np.int64), np.empty(n_t, np.int64)
    tracks[:n_m] = ti
    tracks[n_m:] = tb
    cands[:n_m] = ci
    cands[n_m:] = born
    sc, rg = np.empty(n_t), np.empty(n_t)
    ac = np.empty(n_t if accepted.shape[0] else 0, np.bool_)
    for j in range(n_t):
        sc[j], rg[j] = scores[cands[j]], rng[cands[j]]
        if accepted.shape[0]:
            ac[j] = accepted[cands[j]]
    lgs = _score_logits(sc)  # once for both of its readers
    _score_kernel(tracks, lgs, ac, rg, score_sum, n_scored, lo_score, prm[8], prm[9], prm[10], prm[11],
                  prm[12], prm[13], prm[14], prm[15])  # fmt: skip
    bm = np.zeros(n_t)
    if has_points and n_t:
        # the per-frame residual sums (always: the track classifier reads them, resid_z): by default fitted
        # from the candidate's own centre in the robot frame (no transform); fits from behind the points
        # (frame_fit_warm_start 0) and the outline's ring need the points in the odometry frame
        if copy_pts:
            odom, sig, dist = _points_prep(pts, owner, obs, noise, cos, sin, poses, prm[16])
            if gn and prm[35] > 0.0:
                _frame_fits_kernel(tracks, cands, odom, sig, cstart, tobs, poses, z, prm[7], int(prm[32]),
                                   prm[33] > 0.0, prm[17], prm[23], lo_resid, res_chi2, res_dof)  # fmt: skip
            if buf.shape[1] > 0:
                _outline_kernel(tracks, cands, odom, sig, dist, cstart, tobs, odometer, moved, buf, aux, npts,
                                head, fit_c, lo_shape, x, P, now, prm[7], prm[17], prm[18], int(prm[19]),
                                prm[20], prm[21], prm[22])  # fmt: skip
        if not gn and prm[35] > 0.0:
            _centre_resid_kernel(tracks, cands, pts, lo, hi, xy, obs, noise, prm[16], prm[7], prm[17],
                                 prm[23], lo_resid, res_chi2, res_dof, int(prm[32]))  # fmt: skip
        for j in range(n_t):
            bm[j] = hi[cands[j]] - lo[cands[j]]
    _feature_kernel(tracks, n_m, lgs, ac, rg, bm, f_lgsum, f_lgsq, f_lgmax, f_lglast, f_accsum, f_acclast,
                    f_beams, f_rng, hit)  # fmt: skip
    hit_t = np.zeros(alive.shape[0], np.bool_)
    for j in range(n_m):
        hit_t[ti[j]] = True
    _finish_kernel(pre, hit_t, dt, alive, tobs, x, P, poses, exist, confirmed, moved, lo_motion, static_t,
                   age, seen, anchor, anchor_var, anchor_odo, anchor_rng, odometer, prm[24], prm[25],
                   prm[26], prm[6], prm[27], prm[28], prm[29], prm[21], prm[22])  # fmt: skip
    return 0, next_id


# -- the classifier's inputs and the fixed-shape outputs, compiled -------------------------------------------

#: the columns :func:`_features_kernel` computes (a copy: if :data:`TRACK_FEATURES` changes, the tracker
#: falls back to the numpy :meth:`KinTracker._features` until the kernel follows)
_KERNEL_FEATURES = ("mean_logit", "std_logit", "max_logit", "last_logit", "hit_logit", "accept_rate",
                    "last_accepted", "hit_accepted", "hit", "log_frames", "log_beams", "range", "motion_z",
                    "moved", "existence", "speed_z", "moved_share", "log_moved", "resid_z")  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _features_kernel(rows, n_obs, alive, confirmed, obs, seen, x, P, anchor, anchor_var, anchor_odo,
                     anchor_rng, odometer, hit, lgsum, lgsq, lgmax, lglast, accsum, acclast, beams, f_rng,
                     moved, exist, res_chi2, res_dof, head_rate2, pos_rate2):  # fmt: skip
    """:meth:`KinTracker._features` of the track rows ``rows`` (the same operations, one loop)."""
    n_conf = np.zeros(n_obs)  # the scene: each observer's confirmed tracks, and those that moved
    n_moved = np.zeros(n_obs, np.int64)
    for t in range(alive.shape[0]):
        if alive[t] and confirmed[t]:
            n_conf[obs[t]] += 1.0
            if moved[t]:
                n_moved[obs[t]] += 1
    X = np.empty((rows.shape[0], len(_KERNEL_FEATURES)))
    for i in range(rows.shape[0]):
        t = rows[i]
        o = obs[t]
        n = float(max(seen[t], 1))
        dx, dy = x[t, 0] - anchor[t, 0], x[t, 1] - anchor[t, 1]
        disp = math.sqrt(dx * dx + dy * dy)
        drift = (odometer[o] - anchor_odo[t]) * (head_rate2 * anchor_rng[t] ** 2 + pos_rate2)
        var = anchor_var[t] + 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + drift
        speed_sd = math.sqrt(max(0.5 * (P[t, 2, 2] + P[t, 3, 3]), 1e-12))
        mean = lgsum[t] / n
        dof = res_dof[t]
        X[i, 0] = mean
        X[i, 1] = math.sqrt(max(lgsq[t] / n - mean * mean, 0.0))
        X[i, 2] = lgmax[t]
        X[i, 3] = lglast[t]
        X[i, 4] = lglast[t] if hit[t] else -6.0
        X[i, 5] = accsum[t] / n
        X[i, 6] = acclast[t]
        X[i, 7] = acclast[t] if hit[t] else 0.0
        X[i, 8] = 1.0 if hit[t] else 0.0
        X[i, 9] = math.log(n)
        X[i, 10] = math.log1p(beams[t])
        X[i, 11] = f_rng[t]
        X[i, 12] = min(disp / math.sqrt(var), 10.0)
        X[i, 13] = 1.0 if moved[t] else 0.0
        X[i, 14] = exist[t]
        X[i, 15] = min(math.sqrt(x[t, 2] * x[t, 2] + x[t, 3] * x[t, 3]) / speed_sd, 10.0)
        X[i, 16] = n_moved[o] / max(n_conf[o], 1.0)
        X[i, 17] = math.log1p(n_moved[o])
        X[i, 18] = min(max((res_chi2[t] - dof) / math.sqrt(2.0 * max(dof, 1.0)), -10.0), 10.0)
    return X


@numba.njit(cache=True, nogil=True, error_model="numpy")  # every divisor > 0: no checks, loops vectorise
def _decide_kernel(n_obs, alive, confirmed, obs, seen, x, P, anchor, anchor_var, anchor_odo, anchor_rng,
                   odometer, hit, lgsum, lgsq, lgmax, lglast, accsum, acclast, beams, f_rng, moved, exist,
                   res_chi2, res_dof, head_rate2, pos_rate2, mean, scale, W, b, W2, b2, tail, log_min,
                   hit_only):  # fmt: skip
    """:meth:`KinTracker._decide`'s compiled part: every live track's row and kin probability where
    :meth:`TrackKinModel.kin_prob` does not need the network (0 for a track not updated this frame under
    ``hit_only``; the detector's decision, 0.75 / 0.25, for one seen in fewer frames than the model's
    ``min_frames``, ``log(frames) < log_min``), and for the others (``sel``, indices into the rows) the
    network's first layer ``standardised features @ W + b`` (:func:`_features_kernel`'s inputs and
    :func:`_dense_layer`'s sums, the same operations in the same order). ``tail``: how much of the network
    is finished here too — 1: ``W, b`` is the output (a logistic model), 2: ``tanh`` of the first layer
    then the output layer ``W2, b2`` (the shipped model), both with :func:`_sigmoid`: ``kp`` complete and
    ``sel`` empty; 0: ``sel`` and the first layer returned for :meth:`KinTracker._decide` to finish
    (deeper networks). The same operations as :meth:`TrackKinModel.kin_prob`: the same bits."""
    n_conf = np.zeros(n_obs)  # the scene: each observer's confirmed tracks, and those that moved
    n_moved = np.zeros(n_obs, np.int64)
    n = 0
    for t in range(alive.shape[0]):
        if alive[t]:
            n += 1
            if confirmed[t]:
                n_conf[obs[t]] += 1.0
                if moved[t]:
                    n_moved[obs[t]] += 1
    rows, kp, sel = np.empty(n, np.int64), np.zeros(n), np.empty(n, np.int64)
    F, U = mean.shape[0], W.shape[1]
    # the decided tracks' inputs, one column per track (feature-major): the first layer then runs down
    # contiguous columns, vectorised across tracks, instead of one track's eight sums at a time through
    # memory (a chain of dependent loads and stores per input: ~40 % of this kernel)
    xf = np.empty((F, n))
    # the per-observer scene features, and log(frames) / log1p(beams) of small integers, each computed once
    # (the same libm calls on the same values: the same bits)
    share, log_moved = np.empty(n_obs), np.empty(n_obs)
    for o in range(n_obs):
        share[o] = n_moved[o] / max(n_conf[o], 1.0)
        log_moved[o] = math.log1p(n_moved[o])
    log_n, log1p_b = np.full(64, np.nan), np.full(64, np.nan)
    # inputs whose first-layer weights are all 0 (a model fitted on fewer inputs) are neither computed nor
    # summed: the sums of the others are the same bits (a 0 weight adds +-0)
    use = np.zeros(F, np.bool_)
    for q in range(F):
        for j in range(U):
            use[q] |= W[q, j] != 0.0
    u_std, u_mot, u_spd, u_res = use[1], use[12], use[15], use[18]
    i = n_sel = 0
    for t in range(alive.shape[0]):
        if not alive[t]:
            continue
        rows[i] = t
        i += 1
        if hit_only and not hit[t]:
            continue  # kin probability 0
        nf = float(max(seen[t], 1))
        if seen[t] < 64:
            if log_n[seen[t]] != log_n[seen[t]]:
                log_n[seen[t]] = math.log(nf)
            lnf = log_n[seen[t]]
        else:
            lnf = math.log(nf)
        if lnf < log_min:  # young: the detector's own decision of the last frame
            kp[i - 1] = 0.75 if (acclast[t] if hit[t] else 0.0) > 0.75 else 0.25
            continue
        o = obs[t]
        mn = lgsum[t] / nf
        c = n_sel
        xf[0, c] = mn
        if u_std:
            xf[1, c] = math.sqrt(max(lgsq[t] / nf - mn * mn, 0.0))
        xf[2, c] = lgmax[t]
        xf[3, c] = lglast[t]
        xf[4, c] = lglast[t] if hit[t] else -6.0
        xf[5, c] = accsum[t] / nf
        xf[6, c] = acclast[t]
        xf[7, c] = acclast[t] if hit[t] else 0.0
        xf[8, c] = 1.0 if hit[t] else 0.0
        xf[9, c] = lnf
        bt = beams[t]
        if 0.0 <= bt < 64.0 and bt == int(bt):
            q = int(bt)
            if log1p_b[q] != log1p_b[q]:
                log1p_b[q] = math.log1p(bt)
            xf[10, c] = log1p_b[q]
        else:
            xf[10, c] = math.log1p(bt)
        xf[11, c] = f_rng[t]
        if u_mot:
            dx, dy = x[t, 0] - anchor[t, 0], x[t, 1] - anchor[t, 1]
            disp = math.sqrt(dx * dx + dy * dy)
            drift = (odometer[o] - anchor_odo[t]) * (head_rate2 * anchor_rng[t] ** 2 + pos_rate2)
            var = anchor_var[t] + 0.5 * (P[t, 0, 0] + P[t, 1, 1]) + drift
            xf[12, c] = min(disp / math.sqrt(var), 10.0)
        xf[13, c] = 1.0 if moved[t] else 0.0
        xf[14, c] = exist[t]
        if u_spd:
            speed_sd = math.sqrt(max(0.5 * (P[t, 2, 2] + P[t, 3, 3]), 1e-12))
            xf[15, c] = min(math.sqrt(x[t, 2] * x[t, 2] + x[t, 3] * x[t, 3]) / speed_sd, 10.0)
        xf[16, c] = share[o]
        xf[17, c] = log_moved[o]
        if u_res:
            dof = res_dof[t]
            xf[18, c] = min(max((res_chi2[t] - dof) / math.sqrt(2.0 * max(dof, 1.0)), -10.0), 10.0)
        sel[n_sel] = i - 1
        n_sel += 1
    # standardised inputs @ W + b, each sum in the inputs' order (as _dense_layer's): the same bits
    ht = np.empty((U, n_sel))
    for j in range(U):
        for c in range(n_sel):
            ht[j, c] = b[j]
    for q in range(F):
        if not use[q]:
            continue
        mq, sq = mean[q], scale[q]
        v = xf[q, :n_sel]
        for c in range(n_sel):
            v[c] = (v[c] - mq) / sq
        for j in range(U):
            w = W[q, j]
            hj = ht[j]
            for c in range(n_sel):
                hj[c] += v[c] * w
    if tail == 0:
        return rows, kp, sel[:n_sel], np.ascontiguousarray(ht.T)
    if tail == 2:  # tanh, then the output layer summed in the units' order (as _dense_layer's narrow path)
        _tanh_inplace(ht.reshape(U * n_sel))
        z = np.empty(n_sel)
        for c in range(n_sel):
            z[c] = b2[0]
        for j in range(U):
            w = W2[j, 0]
            hj = ht[j]
            for c in range(n_sel):
                z[c] += hj[c] * w
    else:
        z = ht[0].copy()
    p = _sigmoid(z)
    for c in range(n_sel):
        kp[sel[c]] = p[c]
    return rows, kp, sel[:0], np.empty((0, 0))


@numba.njit(cache=True, nogil=True)
def _decide_packed(n_obs, F, I, B, x, P, anchor, odometer, head_rate2, pos_rate2, mean, scale, W, b, W2, b2,
                   tail, log_min, hit_only):  # fmt: skip
    """:func:`_decide_kernel` on the packed state (:data:`_F_COLS`, ...)."""
    (exist, _, _, _, _, anchor_var, anchor_odo, anchor_rng, _, res_chi2, res_dof, _, _, lgsum, lgsq, lgmax,
     lglast, accsum, acclast, beams, f_rng) = _f_cols(F, F.shape[1])  # fmt: skip
    alive, moved, confirmed, hit = B[0], B[1], B[2], B[3]
    return _decide_kernel(n_obs, alive, confirmed, I[1], I[2], x, P, anchor, anchor_var, anchor_odo,
                          anchor_rng, odometer, hit, lgsum, lgsq, lgmax, lglast, accsum, acclast, beams,
                          f_rng, moved, exist, res_chi2, res_dof, head_rate2, pos_rate2, mean, scale, W, b,
                          W2, b2, tail, log_min, hit_only)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _slot_after(k1, id1, k2, id2):
    """Track (key ``k1``, id ``id1``) sorts after (``k2``, ``id2``): keys ascending, NaN last, then ids."""
    if k1 != k1:
        return k2 == k2 or id1 > id2
    if k2 != k2:
        return False
    return k1 > k2 or (k1 == k2 and id1 > id2)


_NAN_KEY = np.iinfo(np.int64).max


@numba.njit(cache=True, nogil=True)
def _slots_kernel(rows, kp, n_obs, max_tracks, tobs, tid, confirmed, x, poses, exist, seen, age, block):
    """:meth:`KinTracker.track_arrays`' padded slots: each observer's tracks ``rows`` (kin probability
    ``kp``) ordered confirmed first, then by kin probability, then by id, the first ``max_tracks`` in its
    current robot frame (columns :data:`TRACK_FIELDS`). Returns ``(tracks, mask, count, blk)``; with
    ``block`` the envs' info block instead of ``tracks`` and ``mask`` (those then empty): ``blk`` (fields,
    n_obs, max_tracks) float64, each value the float32 slot's (``tracks.transpose(2, 0, 1).astype(float64)``
    bit for bit: :meth:`KinTracker._track_block`)."""
    n = rows.shape[0]
    cnt = np.zeros(n_obs + 1, np.int64)  # group by observer (counting sort)
    for i in range(n):
        cnt[tobs[rows[i]] + 1] += 1
    for o in range(n_obs):
        cnt[o + 1] += cnt[o]
    order = np.empty(n, np.int64)
    fill = cnt[:-1].copy()
    for i in range(n):
        o = tobs[rows[i]]
        order[fill[o]] = i
        fill[o] += 1
    if block:
        out, mask = np.zeros((0, 0, 10), np.float32), np.zeros((0, 0), np.bool_)
        blk = np.empty((10, n_obs, max_tracks))  # (each slot written once: its values or the padding 0)
    else:
        out, mask = np.zeros((n_obs, max_tracks, 10), np.float32), np.zeros((n_obs, max_tracks), np.bool_)
        blk = np.zeros((0, 0, 0))
    count = np.zeros(n_obs, np.int64)
    key, ids = np.empty(n), np.empty(n, np.int64)
    for i in range(n):
        key[i] = -(kp[i] + (1.0 if confirmed[rows[i]] else 0.0))
        ids[i] = tid[rows[i]]
    # each key as an integer of the same order (a float's bits, its magnitude bits flipped when negative;
    # -0 as +0, NaN above all), so that (key, id) compares as two integers, without branches
    kb = (key + 0.0).view(np.int64)  # + 0.0: -0 -> +0 (they tie as floats)
    for i in range(n):
        b = kb[i]
        kb[i] = _NAN_KEY if key[i] != key[i] else (b ^ 0x7FFFFFFFFFFFFFFF if b < 0 else b)
    slot = np.empty(n, np.int64)
    gk, gi = np.empty(64, np.int64), np.empty(64, np.int64)
    for o in range(n_obs):
        # each track's slot: its rank by (key, id) among the observer's tracks — numpy's argsort by id, then
        # its stable sort by key (NaN keys last). Counted branch-free for the usual tens of tracks (an
        # insertion sort's comparisons were mispredicted about every other time); ranks are distinct (ids)
        a, e = cnt[o], cnt[o + 1]
        if e - a <= 64:
            ng = e - a
            for q in range(ng):  # the group's keys and ids side by side (the count runs down them)
                gk[q], gi[q] = kb[order[a + q]], ids[order[a + q]]
            for q in range(ng):
                ki, ii = gk[q], gi[q]
                r = 0
                for q2 in range(ng):
                    r += (gk[q2] < ki) | ((gk[q2] == ki) & (gi[q2] < ii))
                slot[a + r] = order[a + q]
        else:
            for q in range(a, e):
                slot[q] = order[q]
            for q in range(a + 1, e):  # insertion sort by (key, id)
                i = slot[q]
                p = q - 1
                while p >= a and _slot_after(key[slot[p]], ids[slot[p]], key[i], ids[i]):
                    slot[p + 1] = slot[p]
                    p -= 1
                slot[p + 1] = i
        g = slot[a:e]
        c, s = math.cos(poses[o, 2]), math.sin(poses[o, 2])
        m = min(g.shape[0], max_tracks)
        for r in range(m):
            i = g[r]
            t = rows[i]
            d0, d1 = x[t, 0] - poses[o, 0], x[t, 1] - poses[o, 1]
            v0, v1 = x[t, 2], x[t, 3]
            vals = (float(tid[t]), c * d0 + s * d1, -s * d0 + c * d1, c * v0 + s * v1, -s * v0 + c * v1,
                    exist[t], kp[i], float(seen[t]), 1.0 if confirmed[t] else 0.0, float(age[t]))
            if block:  # each value rounded to the float32 slot's, then widened (exact)
                for j in range(10):
                    blk[j, o, r] = np.float32(vals[j])
            else:
                for j in range(10):
                    out[o, r, j] = vals[j]
                mask[o, r] = True
        if block:
            for j in range(10):
                blk[j, o, m:] = 0.0
        count[o] = m
    return out, mask, count, blk
