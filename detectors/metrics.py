"""Detection metrics for 2D-lidar detectors, as DROW / DR-SPAAM report them (numpy / scipy only).

Works on any labelled scans, simulated or recorded: the inputs are detections (centre, score,
frame) and ground-truth centres (frame, optional "don't care" flag), nothing from the simulator.

**Matching** (:func:`match`): in each frame (one scan) detections are assigned one-to-one to
ground-truth objects by the Hungarian algorithm; a pair is allowed only when the centres are at most
``gate`` apart (DROW's association radius). The assignment maximises, in this order, the number of
matches to counted objects (true positives), then the number of detections kept from being false
positives by a match to a "don't care" object (which is neither required nor a false positive, like
DROW's ignore regions), and then minimises the summed centre distance.

**Precision-recall curve** (:func:`pr_curve`), after DROW's ``prec_rec_2d`` (also used by
DR-SPAAM): detections are accepted in order of decreasing score and, at every threshold, the
accepted detections of each frame are matched anew; precision = TP / (TP + FP), recall = TP / number
of counted objects. Two deliberate differences from the DROW code: tied scores form one point (the
curve does not depend on the order of equal scores), and the curve starts at recall 0 with the
precision of its first point, so that a detector that ranks every true positive first gets AP = 1
(DROW's ``auc`` starts at the first detection's recall and so loses up to 1 / n_objects).

**Average precision** (:func:`average_precision`): the area under that curve by the trapezoidal
rule, as DROW / DR-SPAAM compute it (``sklearn.metrics.auc(rec, prec)``). Recall the detector
never reaches adds nothing, so AP <= the highest recall.

Detections outside an evaluated region (a distance bin, say) can be flagged ``det_ignore``: they
count as true positives when they match a counted object and are otherwise left out, so a detection
of a kin just across a bin edge is not a false positive of the other bin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = [
    "Matching",
    "PRCurve",
    "average_precision",
    "frame_increments",
    "increments",
    "match",
    "pr_curve",
    "pr_from_increments",
    "prf1",
]


def _check_gate(gate) -> float:
    if (
        isinstance(gate, bool)
        or not isinstance(gate, int | float | np.floating)
        or not (math.isfinite(gate) and gate > 0)
    ):
        raise ValueError(f"gate must be a finite distance > 0 m, got {gate!r}")
    return float(gate)


def _xy(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.size == 0:
        return a.reshape(0, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"{what} must be an (n, 2) array of x, y centres, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{what} must be finite, got a non-finite centre")
    return a


def _mask(v, n: int, what: str) -> np.ndarray:
    if v is None:
        return np.zeros(n, bool)
    m = np.asarray(v, dtype=bool).reshape(-1)
    if m.shape[0] != n:
        raise ValueError(f"{what} must have one flag per entry ({n}), got {m.shape[0]}")
    return m


@dataclass(frozen=True)
class Matching:
    """Result of :func:`match` for one frame.

    Attributes:
        gt: ``(D,)`` index of the ground-truth object each detection is matched to, -1 if none.
        distance: ``(D,)`` centre distance to it, m (NaN if unmatched).
        tp: ``(D,)`` matched to a counted object.
        ignored: ``(D,)`` neither a true nor a false positive (matched to a "don't care" object, or
            an unmatched ``det_ignore`` detection).
        fp: ``(D,)`` false positive: not ``tp`` and not ``ignored``.
    """

    gt: np.ndarray
    distance: np.ndarray
    tp: np.ndarray
    ignored: np.ndarray

    @property
    def fp(self) -> np.ndarray:
        return ~(self.tp | self.ignored)


def match(det_xy, gt_xy, gate: float = 0.1, gt_ignore=None, det_ignore=None) -> Matching:
    """One-to-one matching of one frame's detections to its ground truth (see the module docstring).

    Args:
        det_xy: ``(D, 2)`` detection centres, m.
        gt_xy: ``(G, 2)`` ground-truth centres, m.
        gate: largest allowed centre distance, m.
        gt_ignore: ``(G,)`` "don't care" objects (not required; a detection on one is ignored).
        det_ignore: ``(D,)`` detections outside the evaluated region (ignored unless matched to a
            counted object).
    """
    gate = _check_gate(gate)
    d, g = _xy(det_xy, "det_xy"), _xy(gt_xy, "gt_xy")
    nd, ng = d.shape[0], g.shape[0]
    gi, di = _mask(gt_ignore, ng, "gt_ignore"), _mask(det_ignore, nd, "det_ignore")
    gt = np.full(nd, -1, np.int64)
    dist_out = np.full(nd, np.nan)
    if nd and ng:
        dist = np.hypot(d[:, None, 0] - g[None, :, 0], d[:, None, 1] - g[None, :, 1])
        ok = dist <= gate
        if ok.any():
            k = nd + ng + 1
            # lexicographic objective in one cost: a match to a counted object (2k) outweighs
            # every other term together; then each matched detection that would otherwise be a
            # false positive (1); then the distances (together < 1/4)
            value = np.where(gi[None, :], 0.0, 2.0 * k) + np.where(di[:, None], 0.0, 1.0)
            cost = np.where(ok, -value + dist / (gate * 4.0 * k), 0.0)
            rows, cols = linear_sum_assignment(cost)
            keep = ok[rows, cols]
            gt[rows[keep]] = cols[keep]
            dist_out[rows[keep]] = dist[rows[keep], cols[keep]]
    matched = gt >= 0
    tp = matched & ~gi[np.maximum(gt, 0)] if ng else np.zeros(nd, bool)
    ignored = (matched & ~tp) | (~matched & di)
    return Matching(gt, dist_out, tp, ignored)


def frame_increments(scores, det_xy, gt_xy, gate: float = 0.1, gt_ignore=None, det_ignore=None):
    """Per detection of one frame, how TP and FP change when it is accepted.

    Detections are accepted in order of decreasing score (stable for ties) and the frame is
    re-matched (:func:`match`) after each; returns ``(dtp, dfp)``, ``(D,)`` int arrays in the input
    order, so that TP (FP) at threshold ``t`` is the sum of ``dtp`` (``dfp``) over detections with
    score >= ``t``. Detections that cannot match anything (no object within ``gate``) are handled
    without re-matching.
    """
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    d, g = _xy(det_xy, "det_xy"), _xy(gt_xy, "gt_xy")
    nd, ng = d.shape[0], g.shape[0]
    if s.shape[0] != nd:
        raise ValueError(f"scores must have one entry per detection ({nd}), got {s.shape[0]}")
    gi, di = _mask(gt_ignore, ng, "gt_ignore"), _mask(det_ignore, nd, "det_ignore")
    dtp = np.zeros(nd, np.int64)
    dfp = (~di).astype(np.int64)  # a detection that can match nothing
    if nd == 0 or ng == 0:
        return dtp, dfp
    near = np.hypot(d[:, None, 0] - g[None, :, 0], d[:, None, 1] - g[None, :, 1]) <= gate
    n_near = near.sum(axis=1)
    cand = np.flatnonzero(n_near > 0)
    if cand.size == 0:
        return dtp, dfp
    order = cand[np.argsort(-s[cand], kind="stable")]
    if n_near.max() == 1:
        # every candidate is near one object only: the frame splits into one group per object,
        # whose object is matched (to a non-ignored detection if it has one) once it has a candidate
        owner = near.argmax(axis=1)
        has_any = np.zeros(ng, bool)
        has_real = np.zeros(ng, bool)
        for j in order.tolist():
            o = owner[j]
            t = int(not has_any[o] and not gi[o])  # first candidate of a counted object
            if di[j]:
                f = 0
            else:
                # a non-ignored detection is a false positive unless it takes the match, which it
                # does only if the group had no non-ignored detection yet (it may displace an
                # ignored one; the displaced one then costs nothing)
                f = 0 if not has_real[o] else 1
                has_real[o] = True
            has_any[o] = True
            dtp[j], dfp[j] = t, f
        return dtp, dfp
    prev_tp = prev_fp = 0
    for k in range(1, order.size + 1):
        idx = order[:k]
        m = match(d[idx], g, gate, gi, di[idx])
        tp, fp = int(m.tp.sum()), int(m.fp.sum())
        dtp[order[k - 1]], dfp[order[k - 1]] = tp - prev_tp, fp - prev_fp
        prev_tp, prev_fp = tp, fp
    return dtp, dfp


@dataclass(frozen=True)
class PRCurve:
    """A precision-recall curve over the detection score, one point per distinct score.

    Attributes:
        thresholds: ``(K,)`` scores, descending; point ``k`` accepts detections with score >= it.
        tp, fp: ``(K,)`` true / false positives at each threshold.
        n_gt: counted ground-truth objects.
        precision, recall: ``(K,)``; recall is NaN everywhere when ``n_gt == 0``.
    """

    thresholds: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    n_gt: float

    @property
    def precision(self) -> np.ndarray:
        n = self.tp + self.fp
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, self.tp / np.where(n > 0, n, 1), np.nan)

    @property
    def recall(self) -> np.ndarray:
        if self.n_gt <= 0:
            return np.full(self.tp.shape, np.nan)
        return self.tp / self.n_gt

    @property
    def ap(self) -> float:
        """Average precision (:func:`average_precision`)."""
        if self.n_gt <= 0:
            return math.nan
        return average_precision(self.recall, self.precision)

    @property
    def peak_f1(self) -> float:
        """Best F1 along the curve (DROW's ``peakf1``)."""
        if self.n_gt <= 0:
            return math.nan
        if self.tp.size == 0:
            return 0.0
        return float(np.max(2 * self.tp / (self.tp + self.fp + self.n_gt)))


def average_precision(recall, precision) -> float:
    """Area under a precision-recall curve by the trapezoidal rule, from recall 0.

    ``recall`` must be non-decreasing (a curve in order of decreasing threshold); points with NaN
    precision (nothing accepted yet) are dropped, and the curve is extended to recall 0 at the
    precision of its first point. An empty curve has AP 0.
    """
    r = np.asarray(recall, dtype=np.float64).reshape(-1)
    p = np.asarray(precision, dtype=np.float64).reshape(-1)
    if r.shape != p.shape:
        raise ValueError(f"recall and precision must have the same length, got {r.shape} and {p.shape}")
    keep = np.isfinite(p) & np.isfinite(r)
    r, p = r[keep], p[keep]
    if r.size == 0:
        return 0.0
    if np.any(np.diff(r) < -1e-12):
        raise ValueError("recall must be non-decreasing (points in order of decreasing threshold)")
    r = np.concatenate(([0.0], r))
    p = np.concatenate(([p[0]], p))
    return float(np.sum(np.diff(r) * 0.5 * (p[1:] + p[:-1])))


def pr_from_increments(scores, dtp, dfp, n_gt, weights=None) -> PRCurve:
    """The PR curve from per-detection increments (:func:`frame_increments`) of any frames.

    ``weights`` (per detection, default 1) repeat detections, e.g. the frames of a bootstrap
    resample; ``n_gt`` is then the weighted count of counted objects.
    """
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    a, b = np.asarray(dtp, dtype=np.float64).reshape(-1), np.asarray(dfp, dtype=np.float64).reshape(-1)
    if not (s.shape == a.shape == b.shape):
        raise ValueError(f"scores, dtp and dfp must have one entry each, got {s.shape}, {a.shape}, {b.shape}")
    if np.isnan(s).any():
        raise ValueError("scores must not be NaN")
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != s.shape:
            raise ValueError(f"weights must have one entry per detection, got {w.shape}")
        a, b = a * w, b * w
    order = np.argsort(-s, kind="stable")
    s, a, b = s[order], a[order], b[order]
    tp, fp = np.cumsum(a), np.cumsum(b)
    last = np.ones(s.shape[0], bool)  # the last detection of each run of equal scores
    last[:-1] = s[1:] != s[:-1]
    return PRCurve(s[last], tp[last], fp[last], float(n_gt))


def increments(
    scores, det_frame, det_xy, gt_frame, gt_xy, gate: float = 0.1, gt_ignore=None, det_ignore=None
):
    """:func:`frame_increments` of every frame at once: ``(dtp, dfp)`` per detection, input order.

    Arguments as :func:`pr_curve`. Only frames with a detection within ``gate`` of an object are
    re-matched; every other detection adds one false positive (none if ``det_ignore``).
    """
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    df = np.asarray(det_frame).reshape(-1)
    gf = np.asarray(gt_frame).reshape(-1)
    d, g = _xy(det_xy, "det_xy"), _xy(gt_xy, "gt_xy")
    if not (s.shape[0] == df.shape[0] == d.shape[0]):
        raise ValueError("scores, det_frame and det_xy must have one entry per detection")
    if gf.shape[0] != g.shape[0]:
        raise ValueError("gt_frame and gt_xy must have one entry per ground-truth object")
    gi, di = _mask(gt_ignore, g.shape[0], "gt_ignore"), _mask(det_ignore, d.shape[0], "det_ignore")
    dtp = np.zeros(s.shape[0], np.int64)
    dfp = (~di).astype(np.int64)
    if s.shape[0] == 0 or g.shape[0] == 0:
        return dtp, dfp
    # every (detection, object) pair of the same frame within the gate, without a per-frame loop
    go = np.argsort(gf, kind="stable")
    gfs = gf[go]
    lo, hi = np.searchsorted(gfs, df, "left"), np.searchsorted(gfs, df, "right")
    n_pairs = hi - lo
    pd = np.repeat(np.arange(df.shape[0]), n_pairs)
    pg = go[np.repeat(lo - np.cumsum(n_pairs) + n_pairs, n_pairs) + np.arange(int(n_pairs.sum()))]
    near = np.hypot(*(d[pd] - g[pg]).T) <= gate
    pd, pg = pd[near], pg[near]
    if pd.size == 0:
        return dtp, dfp
    n_near = np.bincount(pd, minlength=df.shape[0])
    # frames where a candidate is near two or more objects: re-match (Hungarian) frame by frame
    hard = np.isin(df, np.unique(df[n_near > 1]))
    for f in np.unique(df[hard]).tolist():
        dm, gm = np.flatnonzero(df == f), np.flatnonzero(gf == f)
        dtp[dm], dfp[dm] = frame_increments(s[dm], d[dm], g[gm], gate, gi[gm], di[dm])
    # elsewhere every candidate belongs to one object: per object, in order of decreasing score
    # (ties by input order), the first candidate takes it (a true positive if it is counted) and
    # each non-ignored candidate after the group's first non-ignored one is a false positive
    easy = ~hard[pd]
    cd, cg = pd[easy], pg[easy]
    if cd.size:
        order = np.lexsort((cd, -s[cd], cg))
        cd, cg = cd[order], cg[order]
        first = np.ones(cd.size, bool)
        first[1:] = cg[1:] != cg[:-1]
        dtp[cd] = (first & ~gi[cg]).astype(np.int64)
        real = (~di[cd]).astype(np.int64)
        group = np.cumsum(first) - 1
        start = np.flatnonzero(first)
        real_before = np.cumsum(real) - real - (np.cumsum(real) - real)[start][group]
        dfp[cd] = real * (real_before > 0)
    return dtp, dfp


def pr_curve(
    scores, det_frame, det_xy, gt_frame, gt_xy, gate: float = 0.1, gt_ignore=None, det_ignore=None
) -> PRCurve:
    """The precision-recall curve of scored detections over many frames (see the module docstring).

    Args:
        scores: ``(D,)`` detection scores, higher = more confident.
        det_frame: ``(D,)`` frame (scan) id of each detection.
        det_xy: ``(D, 2)`` detection centres, m.
        gt_frame: ``(G,)`` frame id of each ground-truth object.
        gt_xy: ``(G, 2)`` ground-truth centres, m.
        gate: association radius, m.
        gt_ignore: ``(G,)`` "don't care" objects.
        det_ignore: ``(D,)`` detections outside the evaluated region.
    """
    dtp, dfp = increments(scores, det_frame, det_xy, gt_frame, gt_xy, gate, gt_ignore, det_ignore)
    n_gt = int((~_mask(gt_ignore, np.asarray(gt_frame).reshape(-1).shape[0], "gt_ignore")).sum())
    return pr_from_increments(scores, dtp, dfp, n_gt)


def prf1(tp, fp, fn) -> tuple[float, float, float]:
    """Precision, recall, F1 from counts (NaN when undefined; F1 = 2 TP / (2 TP + FP + FN))."""
    tp, fp, fn = float(tp), float(fp), float(fn)
    p = tp / (tp + fp) if tp + fp > 0 else math.nan
    r = tp / (tp + fn) if tp + fn > 0 else math.nan
    f = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn > 0 else math.nan
    return p, r, f
