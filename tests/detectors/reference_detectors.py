"""Reference copies of the detectors' batch paths as they were before the array-first rewrite.

The tests compare the array-first ``detect_arrays`` / ``detect_batch`` against these (per-scan
numpy segmentation, numpy / plain-Python Levenberg-Marquardt, torch forward pass). Not part of the
package: kept here only as an independent implementation of the same outputs.
"""

from __future__ import annotations

import numpy as np

from detectors.base import (
    Detection,
    DetectionResult,
    KinDetector,
    SegmentReport,
    validate_batch,
    validate_scan,
    wrap_angle,
)
from detectors.geometric import (
    _LM_XTOL,
    _VECTORISE_MIN_SEGMENTS,
    GeometricParams,
    _diameter_reason,
    _diameters,
    _lm_scalar,
    _runs,
    _segments_from_runs,
    _shape_decision,
    _sweep_sign,
    fit_circles,
    is_circular_sweep,
    position_kin,
    preprocess,
)


class ReferenceGeometricKinDetector(KinDetector):
    """The paper's detector: pre-process, segment, diameter filter, shape filter.

    ``detect`` returns the accepted kins plus one :class:`SegmentReport` per
    segment with the stage that rejected it (``"diameter"``,
    ``"too_few_points"``, ``"shape"``) or ``"accepted"``, and the stage numbers
    (``d_cest``, ``omega_min``, ``omega_max``, ``F``, ``r_c``, ``theta_c``).
    ``detect_batch`` runs one circle fit for all scans.

    Args:
        params: detector parameters (paper defaults).
        reports: build the per-segment reports. Cluttered scans have ~100
            segments (mostly 1-2 beam fragments), and building their Python
            report objects costs more than the detection itself; pass False
            when only ``detections`` are needed (``reports`` is then empty).

    Segmentation and the diameter filter run vectorised over all segments
    of a scan; the same stages are available one segment at a time as
    :func:`segment`, :func:`filter_by_diameter` and :func:`filter_by_shape`.
    """

    def __init__(self, params: GeometricParams | None = None, *, reports: bool = True) -> None:
        self.params = GeometricParams() if params is None else params
        self.reports = bool(reports)
        self._angles_key: np.ndarray | None = None
        self._circular = True
        self._sweep = -1.0

    def _check(self, ranges, angles) -> tuple[np.ndarray, np.ndarray]:
        # Validating the sweep costs as much as detecting in a small scan, so
        # the last beam layout seen is remembered; ranges are always checked.
        a = np.asarray(angles, dtype=np.float64)
        key = self._angles_key
        if key is not None and key.shape == a.shape and np.array_equal(key, a):
            r = np.asarray(ranges, dtype=np.float64)
            if r.shape != a.shape or (r < 0.0).any():
                validate_scan(r, a)  # raises with the full message
            return r, a
        r, a = validate_scan(ranges, a)
        self._circular = is_circular_sweep(a)
        self._sweep = _sweep_sign(a)
        self._angles_key = a.copy()
        return r, a

    def _stages_1_to_3(self, r: np.ndarray, a: np.ndarray):
        p = self.params
        d = preprocess(r, p.d_max, p.noise_filter, self._circular, p.d_th)
        runs = _runs(d, p.d_th, p.d_max, self._circular)
        if runs.first.shape[0] == 0:
            return d, a, runs, None, np.zeros(0, dtype=bool)
        diam = _diameters(d, a, runs, p.r, p.occlusion_unbounded, self._sweep)
        cand = diam.passed & (runs.length >= p.min_points)
        return d, a, runs, diam, cand

    def _fit(self, staged) -> list[tuple[float, float, float]]:
        """(r_c, theta_c, sum |e_i|) for every candidate of every staged scan, in order."""
        p = self.params
        n_cand = sum(int(c.sum()) for *_, c in staged)
        if n_cand == 0:
            return []
        if n_cand < _VECTORISE_MIN_SEGMENTS:
            fits = []
            for d, a, runs, diam, cand in staged:
                for k in np.flatnonzero(cand).tolist():
                    b = runs.beams[runs.offsets[k] : runs.offsets[k] + runs.length[k]]
                    rc, tc, _, _, sabs = _lm_scalar(
                        d[b].tolist(),
                        a[b].tolist(),
                        p.r,
                        float(diam.d_cest[k]),  # eq. 7 is eq. 2
                        float(a[diam.min_beam[k]]),
                        p.lm_max_iter,
                        _LM_XTOL,
                    )
                    fits.append((rc, tc, sabs))
            return fits
        ri, ti, counts, rc0, tc0 = [], [], [], [], []
        for d, a, runs, diam, cand in staged:
            if not cand.any():
                continue
            b = runs.beams[cand[runs.seg_id]]
            ri.append(d[b])
            ti.append(a[b])
            counts.append(runs.length[cand])
            rc0.append(diam.d_cest[cand])
            tc0.append(a[diam.min_beam[cand]])
        counts = np.concatenate(counts)
        rc, tc, e, _, _ = fit_circles(
            np.concatenate(ri),
            np.concatenate(ti),
            counts,
            p.r,
            np.concatenate(rc0),
            np.concatenate(tc0),
            max_iter=p.lm_max_iter,
        )
        sums = np.add.reduceat(np.abs(e), np.cumsum(counts) - counts)
        return list(zip(rc.tolist(), tc.tolist(), sums.tolist(), strict=True))

    def _results(self, staged, fits) -> list[DetectionResult]:
        p = self.params
        diameter = 2.0 * p.r
        out = []
        j = 0
        for _, _, runs, diam, cand in staged:
            detections: list[Detection] = []
            reports: list[SegmentReport] = []
            if diam is None:
                out.append(DetectionResult(detections, reports))
                continue
            first, last, length = runs.first.tolist(), runs.last.tolist(), runs.length.tolist()
            segs = _segments_from_runs(runs) if self.reports else None
            cols = (diam.d_cest.tolist(), diam.omega_min.tolist(), diam.omega_max.tolist())
            passed, too_wide = diam.passed.tolist(), diam.too_wide.tolist()
            for k, is_cand in enumerate(cand.tolist()):
                if is_cand:
                    r_c, t_c, sabs = fits[j]
                    j += 1
                    F = sabs if p.shape_metric == "sum" else sabs / length[k]
                    ok, reason = _shape_decision(F, p.F_threshold, p.shape_metric)
                    if ok:
                        pos = position_kin(r_c, t_c)
                        detections.append(
                            Detection(pos.range, pos.bearing, pos.x, pos.y, F, first[k], last[k], length[k])
                        )
                    if segs is not None:
                        m = {
                            "d_cest": cols[0][k],
                            "omega_min": cols[1][k],
                            "omega_max": cols[2][k],
                            "F": F,
                            "r_c": r_c,
                            "theta_c": wrap_angle(t_c),
                        }
                        reports.append(SegmentReport(segs[k], "accepted" if ok else "shape", reason, m))
                elif segs is not None:
                    m = {"d_cest": cols[0][k], "omega_min": cols[1][k], "omega_max": cols[2][k]}
                    if passed[k]:
                        stage = "too_few_points"
                        reason = f"{length[k]} beams < min_points={p.min_points} for the circle fit"
                    else:
                        stage = "diameter"
                        reason = _diameter_reason(
                            False, too_wide[k], m["omega_min"], m["omega_max"], diameter
                        )
                    reports.append(SegmentReport(segs[k], stage, reason, m))
            out.append(DetectionResult(detections, reports))
        return out

    def detect(self, ranges, angles) -> DetectionResult:
        """Detect kins in one scan (``ranges`` (n,) m, ``angles`` (n,) rad)."""
        r, a = self._check(ranges, angles)
        staged = [self._stages_1_to_3(r, a)]
        return self._results(staged, self._fit(staged))[0]

    def detect_batch(self, ranges, angles) -> list[DetectionResult]:
        """Detect kins in ``B`` scans (``ranges`` (B, n) m, shared ``angles`` (n,) rad).

        Same results as calling :meth:`detect` per row, but the circle fits of
        all scans run together (vectorised when there are many).
        """
        rb, a = validate_batch(ranges, angles)
        staged = []
        for row in rb:
            r, a = self._check(row, a)
            staged.append(self._stages_1_to_3(r, a))
        return self._results(staged, self._fit(staged))


# --------------------------------------------------------------------------- learned


def reference_segment_batch(ranges, angles, config, circular):
    """The old ``detectors.features.segment_batch``: per-scan numpy segmentation, Segment objects."""
    import itertools
    import operator

    from detectors.features import SegmentBatch
    from detectors.geometric import segment

    fields = operator.attrgetter(
        "first_beam", "last_beam", "prev_beam", "next_beam", "prev_nearer", "next_nearer", "beams"
    )
    c = config
    a = np.asarray(angles, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    circ = bool(circular)
    d = np.empty_like(r)
    segs = []
    for b in range(r.shape[0]):
        d[b] = preprocess(r[b], c.d_max, False, circ)
        segs.append(segment(d[b], d_th=c.d_th, d_max=c.d_max, circular=circ))
    scan = np.repeat(np.arange(len(segs), dtype=np.int64), [len(ss) for ss in segs])
    cols = list(zip(*map(fields, itertools.chain.from_iterable(segs)), strict=True))
    if not cols:
        cols = [()] * 7
    first, last, prev, nxt, p_near, n_near, _ = cols
    n = a.shape[0]
    first = np.array(first, dtype=np.int64)
    return SegmentBatch(
        ranges=d,
        angles=a,
        circular=circ,
        scan=scan,
        first=first,
        count=(np.array(last, dtype=np.int64) - first) % n + 1,
        prev_beam=np.array([-1 if v is None else v for v in prev], dtype=np.int64),
        next_beam=np.array([-1 if v is None else v for v in nxt], dtype=np.int64),
        prev_nearer=np.array(p_near, dtype=bool),
        next_nearer=np.array(n_near, dtype=bool),
    )


def reference_learned_predict(det, ranges, angles):
    """The old ``LearnedKinDetector._predict``: ``(batch, p_kin, centres, thresholds)`` with the torch
    forward pass in 4096-row chunks and the vectorised circle fit for ``positioning="fit"``."""
    import torch

    from detectors.features import local_to_observer, segment_features

    rb, a = validate_batch(ranges, angles)
    batch = reference_segment_batch(rb, a, det.feature_config, is_circular_sweep(a))
    feats = segment_features(batch, det.feature_config)
    if batch.n_segments == 0:
        return batch, np.zeros(0), np.zeros((0, 2)), np.zeros(0)
    prev = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.inference_mode():
            x = torch.from_numpy(feats.x)
            out = torch.cat([det.model(c) for c in x.split(4096)]).numpy().astype(np.float64)
    finally:
        torch.set_num_threads(prev)
    p = 1.0 / (1.0 + np.exp(-out[:, 0]))
    thr = det.segment_thresholds(feats)
    if det.positioning == "regression":
        nrm = det.checkpoint["normalisation"]
        uv = np.asarray(nrm["t_mean"]) + np.asarray(nrm["t_std"]) * out[:, 1:3]
        return batch, p, local_to_observer(feats.frames, uv), thr
    r = det.feature_config.r
    n = batch.angles.shape[0]
    centres = np.full((batch.n_segments, 2), np.nan)
    idx = np.flatnonzero(p >= thr)
    if idx.size:
        cnt = batch.count[idx]
        beams = np.concatenate([(batch.first[i] + np.arange(c)) % n for i, c in zip(idx, cnt, strict=True)])
        rows = np.repeat(batch.scan[idx], cnt)
        mb = feats.min_beam[idx]
        d_min = batch.ranges[batch.scan[idx], mb]
        rc, tc, _, _, _ = fit_circles(
            batch.ranges[rows, beams], batch.angles[beams], cnt, r, d_min + r, batch.angles[mb]
        )
        one = cnt < 2
        rc[one], tc[one] = d_min[one] + r, batch.angles[mb[one]]
        for k, i in enumerate(idx.tolist()):
            pos = position_kin(float(rc[k]), float(tc[k]))
            centres[i] = pos.x, pos.y
    return batch, p, centres, thr
