"""Candidate windows inside segments too wide for a housing (issue 11, rounds 5-7).

The paper's segmentation (``d_th`` = 0.1 m) merges a kin touching a wall or another robot into one
segment wider than a housing; the learned detector's pre-gate drops that segment and the kin has no
candidate. :func:`candidate_windows` cuts housing-sized **windows** out of such segments, one per
*anchor* (a range minimum), as rows of a :class:`~detectors.features.SegmentBatch` that the feature
extractor and the network take like any segment. The dataset writer
(:func:`kin_envs.detection.dataset.scene_records` with ``windows=True``) and
``scripts/experiment_split_windows.py`` both call this one function.

A window from anchor beam ``j`` (range ``d_m``) holds the beams within ``depth * r`` of ``d_m``, at
most ``w`` beams either side, ``w`` = half a housing's beam span at ``d_m`` (+1): a housing touching a
wall is exactly its own beams. Anchors (:class:`WindowConfig`):

* every **local range minimum** (``anchor="local"``) or every beam that is the minimum over the ``w``
  beams either side (``anchor="span"``; a beam more than ``depth * r`` nearer counts as another object
  in front). Round 5 used every local minimum: with range noise a wall has one every few beams (43
  windows per swarm scan at 1 % noise);
* round 6 adds a **bulge test** (on when ``sag`` or ``sag_noise`` > 0; the default): the anchor's point
  must lie at least ``max(sag * r, sag_noise * sigma * d_m)`` in front of the chord between the beams
  just outside the window (``sigma``: the scan's relative noise estimate,
  :func:`detectors.features.scan_noise`). A housing in front of a wall bulges by up to ``2 r``, a flat
  or oblique wall by its noise only. A chord end past the segment's end is the beam beyond the jump
  when that is farther (the window stands out of the background), else (an occluder's edge, or no
  beam) the window's own end beam; an anchor that is itself a chord end is scored by the other side's
  rise. An anchor on its segment's end beam beside a jump behind it is an object's end, never a
  housing's nearest point (whose neighbours on both sides hit the housing), and is dropped where a
  housing returns >= 3 beams (``d_m`` below ~1.3 m). Known leak: a wall's own range minimum within
  a housing's span of a jump behind it still passes (the far point beyond the jump makes the chord).

On 30 swarm scenes (training seeds 610,000+) round 6 cuts 7.1 / 6.2 / 4.8 windows per scan at 0 /
0.5 / 1 % noise against round 5's 10.4 / 36.7 / 42.5, and keeps a kin window for 23 / 24 / 22 of the
26 / 26 / 29 merged kin at 0.3-1 m in too-wide segments (round 5: 24 / 24 / 25); README, "Issue 11,
round 6".

Pure numpy over all windows at once (loops over beam offsets, at most a housing's span, never over
beams); only the segments given are searched. :func:`_cut_windows` is the same function compiled, which
the learned detector's driver runs on the segments its pre-gate drops (round 7,
``LearnedKinDetector(windows=...)``; :func:`cut_windows` calls it from Python; tested equal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from . import _kernels as _k
from .features import FeatureConfig, SegmentBatch, config_from_dict, scan_noise

__all__ = ["ANCHORS", "WindowConfig", "Windows", "candidate_windows", "cut_windows", "wide_segments"]

ANCHORS = ("local", "span")
#: the learned detector's pre-gate constants (``detectors.learned.PRE_GATE_SLACK`` / ``_MARGIN``;
#: not imported: ``detectors.learned`` loads its compiled driver, the dataset writer need not; a test ties
#: them)
PRE_GATE_SLACK = 0.8
PRE_GATE_MARGIN = 2


@dataclass(frozen=True)
class WindowConfig:
    """How windows are cut (see the module docstring).

    Attributes:
        anchor: ``"local"`` (every local range minimum: the default, and round 5's anchors) or
            ``"span"`` (the minimum over a housing's beam span either side; tried in round 6, not kept).
        depth: a window holds the beams within ``depth * r`` of its anchor's range.
        sag: least bulge of the anchor in front of the window's outer chord, in housing radii (the
            bulge test, with either anchor; ``sag = sag_noise = 0`` turns it off: round 5's windows).
        sag_noise: ... and at least this many times the scan's noise (``sigma * d_m``).
    """

    anchor: str = "local"
    depth: float = 1.0
    sag: float = 0.3
    sag_noise: float = 3.0

    def __post_init__(self) -> None:
        if self.anchor not in ANCHORS:
            raise ValueError(f"WindowConfig.anchor must be one of {ANCHORS}, got {self.anchor!r}")
        for name in ("depth", "sag", "sag_noise"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ValueError(f"WindowConfig.{name} must be a finite number >= 0, got {v!r}")
        if self.depth <= 0:
            raise ValueError(f"WindowConfig.depth must be > 0, got {self.depth!r}")

    @classmethod
    def from_dict(cls, d) -> WindowConfig:
        """From a JSON object; unknown keys raise (a ``ValueError`` naming them)."""
        return config_from_dict(cls, d)

    def to_dict(self) -> dict:
        return {"anchor": self.anchor, "depth": self.depth, "sag": self.sag, "sag_noise": self.sag_noise}


@dataclass(frozen=True, eq=False)
class Windows:
    """Output of :func:`candidate_windows`.

    Attributes:
        batch: the windows as a :class:`SegmentBatch` (same ``ranges`` / ``angles`` as the searched
            batch; ``prev_beam`` / ``next_beam`` are the beams just outside each window).
        parent: ``(W,)`` index of the segment each window was cut from.
        anchor: ``(W,)`` the anchor beam.
        sag: ``(W,)`` the anchor's bulge in front of the outer chord, m (NaN when undefined).
    """

    batch: SegmentBatch
    parent: np.ndarray
    anchor: np.ndarray
    sag: np.ndarray

    @property
    def n_windows(self) -> int:
        return int(self.parent.shape[0])


def wide_segments(batch: SegmentBatch, step: float, r: float) -> np.ndarray:
    """Indices of the segments the learned detector's pre-gate drops (more beams than a housing of
    radius ``r`` can return at the segment's range, :func:`detectors._kernels.housing_max_beams`)."""
    out = np.empty(batch.n_segments)
    _k.housing_max_beams(batch.ranges, batch.scan, batch.first, batch.count, float(step), float(r),
                         PRE_GATE_SLACK, float(PRE_GATE_MARGIN), out)  # fmt: skip
    return np.flatnonzero(batch.count > out)


def _empty(batch: SegmentBatch) -> Windows:
    z = np.zeros(0, np.int64)
    b = SegmentBatch(ranges=batch.ranges, angles=batch.angles, circular=batch.circular, scan=z,
                     first=z.copy(), count=z.copy(), prev_beam=z.copy(), next_beam=z.copy(),
                     prev_nearer=np.zeros(0, bool), next_nearer=np.zeros(0, bool))  # fmt: skip
    return Windows(b, z.copy(), z.copy(), np.zeros(0))


def candidate_windows(
    batch: SegmentBatch,
    segments,
    step: float,
    r: float,
    config: WindowConfig | None = None,
    feature_config: FeatureConfig | None = None,
) -> Windows:
    """Candidate windows inside the segments ``segments`` (indices into ``batch``, e.g.
    :func:`wide_segments`) of a scan batch with beams ``step`` rad apart, for housings of radius
    ``r`` m (module docstring). ``feature_config`` supplies ``d_th`` / ``d_max`` for the noise
    estimate of ``anchor="span"``. Windows come in segment order, each segment's by anchor beam."""
    c = config or WindowConfig()
    seg = np.asarray(segments, dtype=np.int64)
    if seg.size == 0:
        return _empty(batch)
    n = batch.ranges.shape[1]
    cnt = batch.count[seg].astype(np.int64)
    start = np.zeros(seg.size, np.int64)
    np.cumsum(cnt[:-1], out=start[1:])
    owner = np.repeat(np.arange(seg.size), cnt)  # flat beam -> position in ``seg``
    pos = np.arange(owner.size) - start[owner]  # position inside its segment
    beam = (batch.first[seg][owner] + pos) % n
    row = batch.scan[seg][owner]
    d = batch.ranges[row, beam]
    c_of = cnt[owner]
    w = np.floor(np.arcsin(np.minimum(r / (d + r), 1.0)) / step).astype(np.int64) + 1

    def at(k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(inside, d)`` of the beam ``k`` positions on (negative: back) from every flat beam."""
        p = pos + k
        inside = (p >= 0) & (p < c_of)
        return inside, d[np.where(inside, np.arange(owner.size) + k, 0)]

    span = c.anchor == "span"
    tol = c.depth * r
    reach = int(w.max()) if span else 1
    is_min = np.ones(owner.size, bool)
    for k in range(1, reach + 1):  # left ties allowed, right strict: the last beam of a flat bottom
        # "span": a beam more than depth * r nearer is another object in front (a kin behind a box's
        # edge), not a lower point of this one
        ins, dl = at(-k)
        is_min &= ~(ins & (dl < d) & ((k <= w) & (d - dl <= tol) if span else True))
        ins, dr = at(k)
        is_min &= ~(ins & (dr <= d) & ((k <= w) & (d - dr <= tol) if span else True))
    # extents: contiguous beams within depth * r of d_m ("span": either way), at most w either side
    left = np.zeros(owner.size, np.int64)
    right = np.zeros(owner.size, np.int64)
    go_l = np.ones(owner.size, bool)
    go_r = np.ones(owner.size, bool)
    for k in range(1, int(w.max()) + 1):
        ins, dl = at(-k)
        go_l &= ins & (k <= w) & (dl - d <= tol) & ((d - dl <= tol) if span else True)
        left += go_l
        ins, dr = at(k)
        go_r &= ins & (k <= w) & (dr - d <= tol) & ((d - dr <= tol) if span else True)
        right += go_r
    a0, a1 = pos - left, pos + right
    size = a1 - a0 + 1
    keep = is_min & (size >= 2) & ~((a0 == 0) & (a1 == c_of - 1))
    j = np.flatnonzero(keep)  # flat index of each window's anchor
    if j.size == 0:
        return _empty(batch)
    s = seg[owner[j]]
    f0, f1 = j - left[j], j + right[j]  # flat indices of the window's end beams
    at_start, at_end = a0[j] == 0, a1[j] == c_of[j] - 1
    first = beam[f0]
    prev = np.where(at_start, batch.prev_beam[s], beam[np.maximum(f0 - 1, 0)])
    nxt = np.where(at_end, batch.next_beam[s], beam[np.minimum(f1 + 1, owner.size - 1)])
    pn = np.where(at_start, batch.prev_nearer[s], d[np.maximum(f0 - 1, 0)] < d[f0])
    nn = np.where(at_end, batch.next_nearer[s], d[np.minimum(f1 + 1, owner.size - 1)] < d[f1])
    # the anchor's bulge in front of the chord between the beams just outside the window
    # the chord's ends: the beam just outside the window (past a segment's end too: a jump behind
    # it) unless it is nearer than the anchor (an occluder's edge) or missing; then the window's own
    # end beam. An anchor that is itself a chord end (occluded there) gets the other side's rise.
    ang = batch.angles
    rows_j = batch.scan[s]
    dj = d[j]
    lo_b = np.where(pn | (prev < 0) | (batch.ranges[rows_j, np.maximum(prev, 0)] < dj), beam[f0], prev)
    hi_b = np.where(nn | (nxt < 0) | (batch.ranges[rows_j, np.maximum(nxt, 0)] < dj), beam[f1], nxt)
    dl, dh = batch.ranges[rows_j, lo_b], batch.ranges[rows_j, hi_b]
    lx, ly = dl * np.cos(ang[lo_b]), dl * np.sin(ang[lo_b])
    hx, hy = dh * np.cos(ang[hi_b]), dh * np.sin(ang[hi_b])
    mx, my = d[j] * np.cos(ang[beam[j]]), d[j] * np.sin(ang[beam[j]])
    ex, ey = hx - lx, hy - ly
    length = np.hypot(ex, ey)
    side_m = ex * (my - ly) - ey * (mx - lx)
    side_o = ex * (0.0 - ly) - ey * (0.0 - lx)  # the observer's side of the chord
    with np.errstate(invalid="ignore", divide="ignore"):
        sag = np.where(length > 0, side_m * np.sign(side_o) / length, np.nan)
    sag = np.where(lo_b == beam[j], dh - dj, np.where(hi_b == beam[j], dl - dj, sag))
    ok = np.ones(j.size, bool)
    if c.sag > 0 or c.sag_noise > 0:
        fc = feature_config or FeatureConfig()
        sigma = scan_noise(batch, fc)[0][row[j]]
        ok = np.nan_to_num(sag, nan=-1.0) >= np.maximum(c.sag * r, c.sag_noise * sigma * dj)
        # a housing's nearest point has housing beams on both sides: an anchor on its segment's end
        # beam beside a jump behind it is an object's end (an oblique wall's), unless the housing
        # returns fewer than 3 beams at that range (then its 2-3 beams may show the minimum anywhere)
        end = ((pos[j] == 0) & ~pn & (prev >= 0)) | ((pos[j] == c_of[j] - 1) & ~nn & (nxt >= 0))
        expected = 2 * np.arcsin(np.minimum(r / (dj + r), 1.0)) / step
        ok &= ~(end & (expected >= 3.0))
    sel = np.flatnonzero(ok)
    wb = SegmentBatch(
        ranges=batch.ranges, angles=batch.angles, circular=batch.circular,
        scan=batch.scan[s][sel].astype(np.int64), first=first[sel].astype(np.int64),
        count=size[j][sel].astype(np.int64), prev_beam=prev[sel].astype(np.int64),
        next_beam=nxt[sel].astype(np.int64), prev_nearer=pn[sel].astype(bool),
        next_nearer=nn[sel].astype(bool),
    )  # fmt: skip
    return Windows(wb, s[sel], beam[j][sel].astype(np.int64), sag[sel])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _cut_windows(d, scan, first, count, prev, nxt, p_near, n_near, wide, sigma, cos_a, sin_a, step, r, span,
                 depth, sag_r, sag_noise, o_scan, o_first, o_count, o_prev, o_next, o_pn, o_nn, offset,
                 o_parent, o_anchor, o_sag):  # fmt: skip
    """:func:`candidate_windows` compiled, one segment of ``wide`` at a time (the learned detector's
    driver calls it on the segments its pre-gate drops): the same tests with the same expressions,
    written to ``o_*[offset + k]`` (the window's segment columns) and ``o_parent / o_anchor /
    o_sag[k]``; returns how many. ``d`` (B, n): the pre-processed ranges; ``sigma`` (B,): each scan's
    noise estimate (:func:`detectors.features.scan_noise`); ``cos_a`` / ``sin_a``: the beams'; ``span``:
    ``anchor == "span"``. The output arrays need room for half the beams of the wide segments (anchors
    are never adjacent: a local minimum's right neighbour is strictly farther)."""
    n = d.shape[1]
    tol = depth * r
    bulge = sag_r > 0.0 or sag_noise > 0.0
    k_out = 0
    for q in range(wide.shape[0]):
        i = wide[q]
        b = scan[i]
        f = first[i]
        c = count[i]
        row = d[b]
        for pos in range(c):
            bj = f + pos if f + pos < n else f + pos - n
            dj = row[bj]
            # a local minimum first (cheap; most beams are not one), then the housing's span
            # ("span": a beam more than depth * r nearer is another object in front, not a lower point)
            if pos > 0:
                dl = row[bj - 1 if bj > 0 else n - 1]
                if dl < dj and (not span or dj - dl <= tol):
                    continue
            if pos + 1 < c:
                dr = row[bj + 1 if bj + 1 < n else 0]
                if dr <= dj and (not span or dj - dr <= tol):
                    continue
            half = math.asin(min(r / (dj + r), 1.0)) / step  # half a housing's beam span at dj
            w = int(math.floor(half)) + 1
            is_min = True
            if span:
                for k in range(2, w + 1):
                    if pos - k >= 0:
                        dl = row[(f + pos - k) % n]
                        if dl < dj and dj - dl <= tol:
                            is_min = False
                            break
                    if pos + k < c:
                        dr = row[(f + pos + k) % n]
                        if dr <= dj and dj - dr <= tol:
                            is_min = False
                            break
            if not is_min:
                continue
            left = 0
            for k in range(1, w + 1):
                if pos - k < 0:
                    break
                dl = row[(f + pos - k) % n]
                if not (dl - dj <= tol and (not span or dj - dl <= tol)):
                    break
                left += 1
            right = 0
            for k in range(1, w + 1):
                if pos + k >= c:
                    break
                dr = row[(f + pos + k) % n]
                if not (dr - dj <= tol and (not span or dj - dr <= tol)):
                    break
                right += 1
            a0 = pos - left
            a1 = pos + right
            size = a1 - a0 + 1
            if size < 2 or (a0 == 0 and a1 == c - 1):
                continue
            b0 = (f + a0) % n
            b1 = (f + a1) % n
            if a0 == 0:
                wp = prev[i]
                pn = p_near[i]
            else:
                wp = (f + a0 - 1) % n
                pn = row[wp] < row[b0]
            if a1 == c - 1:
                wn = nxt[i]
                nn = n_near[i]
            else:
                wn = (f + a1 + 1) % n
                nn = row[wn] < row[b1]
            # the anchor's bulge in front of the chord between the beams just outside the window
            lo_b = b0 if (pn or wp < 0 or row[max(wp, 0)] < dj) else wp
            hi_b = b1 if (nn or wn < 0 or row[max(wn, 0)] < dj) else wn
            dlo = row[lo_b]
            dhi = row[hi_b]
            lx = dlo * cos_a[lo_b]
            ly = dlo * sin_a[lo_b]
            hx = dhi * cos_a[hi_b]
            hy = dhi * sin_a[hi_b]
            mx = dj * cos_a[bj]
            my = dj * sin_a[bj]
            ex = hx - lx
            ey = hy - ly
            length = math.hypot(ex, ey)
            side_m = ex * (my - ly) - ey * (mx - lx)
            side_o = ex * (0.0 - ly) - ey * (0.0 - lx)
            sg = np.nan
            if length > 0:
                sg = side_m * np.sign(side_o) / length
            if lo_b == bj:
                sg = dhi - dj
            elif hi_b == bj:
                sg = dlo - dj
            if bulge:
                v = sg if sg == sg else -1.0
                if not v >= max(sag_r * r, sag_noise * sigma[b] * dj):
                    continue
                end = (pos == 0 and not pn and wp >= 0) or (pos == c - 1 and not nn and wn >= 0)
                if end and 2 * half >= 3.0:  # (2 * (a / step) == 2 * a / step exactly: a doubling)
                    continue
            o = offset + k_out
            o_scan[o] = b
            o_first[o] = b0
            o_count[o] = size
            o_prev[o] = wp
            o_next[o] = wn
            o_pn[o] = pn
            o_nn[o] = nn
            o_parent[k_out] = i
            o_anchor[k_out] = bj
            o_sag[k_out] = sg
            k_out += 1
    return k_out


def cut_windows(batch: SegmentBatch, segments, step: float, r: float, config: WindowConfig | None = None,
                sigma: np.ndarray | None = None) -> Windows:
    """:func:`candidate_windows` through the compiled kernel the learned detector runs
    (:func:`_cut_windows`; the same windows, tested against it). ``sigma``: each scan's noise estimate
    (default: :func:`detectors.features.scan_noise` with the default feature config)."""
    c = config or WindowConfig()
    seg = np.ascontiguousarray(segments, dtype=np.int64)
    if sigma is None:
        sigma = scan_noise(batch, FeatureConfig())[0]
    ang = np.ascontiguousarray(batch.angles, dtype=np.float64)
    room = int(batch.count[seg].sum()) // 2 + 1
    cols = [np.empty(room, np.int64) for _ in range(5)] + [np.empty(room, bool) for _ in range(2)]
    parent, anchor, sag = np.empty(room, np.int64), np.empty(room, np.int64), np.empty(room)
    k = _cut_windows(np.ascontiguousarray(batch.ranges, dtype=np.float64), batch.scan, batch.first,
                     batch.count, batch.prev_beam, batch.next_beam, batch.prev_nearer, batch.next_nearer, seg,
                     np.ascontiguousarray(sigma, dtype=np.float64), np.cos(ang), np.sin(ang), float(step),
                     float(r), c.anchor == "span", float(c.depth), float(c.sag), float(c.sag_noise), *cols, 0,
                     parent, anchor, sag)  # fmt: skip
    wb = SegmentBatch(ranges=batch.ranges, angles=batch.angles, circular=batch.circular, scan=cols[0][:k],
                      first=cols[1][:k], count=cols[2][:k], prev_beam=cols[3][:k], next_beam=cols[4][:k],
                      prev_nearer=cols[5][:k], next_nearer=cols[6][:k])  # fmt: skip
    return Windows(wb, parent[:k], anchor[:k], sag[:k])
