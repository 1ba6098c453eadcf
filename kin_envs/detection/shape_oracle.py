"""An oracle bound on how well any shape cue can tell a *still* kin from a still look-alike over frames.

For every still object an observer sees (a parked or stuck kin, a 7 cm look-alike), once it has been in
view (>= 2 beams) for ``n`` frames, the beams that hit it in those frames are ego-motion compensated into
the observer's odometry frame (the odometry a tracker has, or the true poses for a drift-free bound) and
scored with the lidar's own noise model (Gaussian range noise of sigma = noise x range, along the beam)
under two hypotheses, each with its centre fitted (2 dof each, which also absorbs a translation drift):

* ``circle``: the kin's housing, a circle of the housing radius;
* ``lookalike``: the best of a family of look-alike outlines (7 cm prisms of 3-6 sides and a 7 x 7 cm box
  on an orientation grid, cylinders of 2.5-6 cm radius away from the housing's, and every non-wall
  obstacle of the episode at its true orientation, so a look-alike's own outline is always in the family).

The generalised log-likelihood ratio ``circle - lookalike`` per object is the statistic of the best test
that knows the association, the noise model and the family of look-alike shapes: its ROC (kin vs
look-alikes) bounds what any per-track shape cue can reach. ``shape_llr`` is the scoring core; the
episode-level collection is :func:`oracle_samples` (training seeds unless asked otherwise), and
``scripts/track_shape_oracle.py`` reports it next to the track classifier's ROC on the same objects.
Analysis code, not on any hot path: numpy, vectorised over hypotheses and points.
"""

from __future__ import annotations

import math

import numpy as np

from detectors.metrics import prf1

HOUSING_R = 0.035  # m (the scene's value is passed in where a world is at hand)


def _ray_polygon(o, u, verts):
    """Range along rays (o + t u) to convex polygons: ``o``, ``u`` (N, 2); ``verts`` (H, K, 2) (a vertex
    repeated pads fewer sides: a zero-length edge never hits). Returns (H, N) ranges, inf on a miss."""
    a = verts[:, :, None, :]  # (H, K, 1, 2)
    e = np.roll(verts, -1, axis=1)[:, :, None, :] - a
    d = a - o[None, None]  # (H, K, N, 2)
    den = u[None, None, :, 0] * e[..., 1] - u[None, None, :, 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]) / den
        s = (d[..., 0] * u[None, None, :, 1] - d[..., 1] * u[None, None, :, 0]) / den
    ok = (np.abs(den) > 1e-15) & (s >= 0) & (s <= 1) & (t > 0)
    return np.where(ok, t, np.inf).min(axis=1)


def _dist_polygon(p, verts):
    """Distance from points ``p`` (N, 2) to the outlines of polygons ``verts`` (H, K, 2): (H, N)."""
    a = verts[:, :, None, :]
    e = np.roll(verts, -1, axis=1)[:, :, None, :] - a
    ee = (e * e).sum(-1)
    w = p[None, None] - a
    s = np.clip((w * e).sum(-1) / np.maximum(ee, 1e-30), 0.0, 1.0)
    q = w - s[..., None] * e
    return np.sqrt((q * q).sum(-1)).min(axis=1)


def _ray_circle(o, u, c, r):
    """Range along rays to circles of radius ``r`` (H,) at ``c`` (H, 2): (H, N), inf on a miss."""
    d = o[None] - c[:, None, :]
    b = (d * u[None]).sum(-1)
    cc = (d * d).sum(-1) - r[:, None] ** 2
    disc = b * b - cc
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def _line_extent(o, u, shapes, centres):
    """Signed side distances of each hypothesis' outline from each ray's line: ``lo``, ``hi`` (H, N), the
    smallest and largest over the outline (normal n = (-u_y, u_x)); the line crosses it iff lo < 0 < hi."""
    kind, geom = shapes
    n = np.c_[-u[:, 1], u[:, 0]]
    if kind == "circle":
        s = ((centres[:, None, :] - o[None]) * n[None]).sum(-1)
        return s - geom[:, None], s + geom[:, None]
    v = geom + centres[:, None, :]  # (H, K, 2)
    s = ((v[:, :, None, :] - o[None, None]) * n[None, None]).sum(-1)  # (H, K, N)
    return s.min(1), s.max(1)


def _residuals(o, u, rng, sig, shapes, centres, no=None, nu=None, angle_sigma=5e-4):
    """Residuals (H, M) of the returns under each hypothesis placed at ``centres``: the noise-normalised
    range residuals of the beams that hit the object (a ray missing the outline: the point's distance to
    it), and the **silhouette** terms the beams' exact directions give: a hitting ray must cross the
    outline (its gap over ``angle_sigma``), a neighbouring ray that saw past the object must not (its
    penetration over ``angle_sigma``)."""
    kind, geom = shapes
    p = o + u * rng[:, None]
    if kind == "circle":
        t = _ray_circle(o, u, centres, geom)
        miss = np.abs(np.hypot(p[None, :, 0] - centres[:, None, 0], p[None, :, 1] - centres[:, None, 1])
                      - geom[:, None])  # fmt: skip
    else:
        v = geom + centres[:, None, :]
        t = _ray_polygon(o, u, v)
        miss = _dist_polygon(p, v)
    out = [np.where(np.isfinite(t), rng[None] - t, miss) / sig[None]]
    if angle_sigma > 0:
        lo, hi = _line_extent(o, u, shapes, centres)
        out.append(np.maximum(np.maximum(lo, -hi), 0.0) / angle_sigma)  # gap of a hitting ray
        if no is not None and len(no):
            lo, hi = _line_extent(no, nu, shapes, centres)
            out.append(np.maximum(np.minimum(-lo, hi), 0.0) / angle_sigma)  # penetration of a neighbour
    return np.concatenate(out, axis=1)


def _fit(o, u, rng, sig, shapes, c0, iterations=12, extra=()):
    """Centres (H, 2) maximising each hypothesis' likelihood (damped Gauss-Newton, numeric Jacobian, the
    best of the iterates kept) and its log-likelihood (H,) up to a constant shared by all hypotheses."""

    def res(c):
        return _residuals(o, u, rng, sig, shapes, c, *extra)

    c = np.array(c0, float)
    h = 1e-5
    best_c, best = c.copy(), -0.5 * (res(c) ** 2).sum(1)
    lam = 1e-3
    for _ in range(iterations):
        r0 = res(c)
        jx = (res(c + [h, 0.0]) - r0) / h
        jy = (res(c + [0.0, h]) - r0) / h
        a11, a12, a22 = (jx * jx).sum(1), (jx * jy).sum(1), (jy * jy).sum(1)
        g1, g2 = (jx * r0).sum(1), (jy * r0).sum(1)
        a11, a22 = a11 * (1 + lam) + 1e-9, a22 * (1 + lam) + 1e-9
        det = a11 * a22 - a12 * a12
        step = np.c_[(a22 * g1 - a12 * g2) / det, (a11 * g2 - a12 * g1) / det]
        step = np.clip(np.nan_to_num(step), -0.01, 0.01)  # at most 1 cm a step
        c = c - step
        ll = -0.5 * (res(c) ** 2).sum(1)
        better = ll > best
        best_c[better], best[better] = c[better], ll[better]
    return best_c, best


def _regular(sides, width, theta):
    a = theta + 2 * np.pi * np.arange(sides) / sides
    return np.c_[np.cos(a), np.sin(a)] * width / 2


def lookalike_family(extra_polygons=(), extra_radii=(), housing_radius: float = HOUSING_R,
                     step_deg: float = 5.0) -> tuple:
    """The look-alike outlines the oracle tests against: ``(polygons (H, 6, 2) centred at 0, radii (R,))``.
    7 cm prisms of 3-6 sides and a 7 x 7 cm box on a ``step_deg`` orientation grid over their symmetry,
    cylinders of 2.5-6 cm radius (2.5 mm steps, none within 5 mm of the housing), plus ``extra_*``."""
    polys = []
    for sides in (3, 4, 5, 6):
        for th in np.deg2rad(np.arange(0.0, 360.0 / sides, step_deg)):
            polys.append(_regular(sides, 0.07, th))
    box = np.array([[-0.035, -0.035], [0.035, -0.035], [0.035, 0.035], [-0.035, 0.035]])
    for th in np.deg2rad(np.arange(0.0, 90.0, step_deg)):
        c, s = math.cos(th), math.sin(th)
        polys.append(box @ np.array([[c, s], [-s, c]]))
    polys += [np.asarray(p, float) for p in extra_polygons]
    pad = np.stack([np.r_[p, np.repeat(p[-1:], 6 - len(p), axis=0)] if len(p) < 6 else p for p in polys
                    if len(p) <= 6])  # fmt: skip
    radii = [r for r in np.arange(0.025, 0.0601, 0.0025) if abs(r - housing_radius) > 0.005]
    radii += [float(r) for r in extra_radii if abs(r - housing_radius) > 1e-3]
    return pad, np.asarray(radii, float)


def _hyp_ll(o, u, rng, sig, extra, family, housing_radius):
    """Log-likelihoods of the circle (scalar) and of the best look-alike of ``family`` for one set of
    returns, each with its centre fitted; and the circle's centre."""
    p = o + u * rng[:, None]
    back = p - o
    back /= np.linalg.norm(back, axis=1, keepdims=True)
    start = (p + back * housing_radius).mean(0)  # the points' mean pushed away from the sensor
    cc, llc = _fit(o, u, rng, sig, ("circle", np.array([housing_radius])), start[None], extra=extra)
    polys, radii = family
    lls = []
    if len(polys):
        lls.append(_fit(o, u, rng, sig, ("polygon", polys), np.repeat(start[None], len(polys), 0),
                        extra=extra)[1])  # fmt: skip
    if len(radii):
        rs = np.asarray(radii, float)
        st = (p + back * rs.mean()).mean(0)
        lls.append(_fit(o, u, rng, sig, ("circle", rs), np.repeat(st[None], len(rs), 0), extra=extra)[1])
    return float(llc[0]), np.concatenate(lls), cc[0]


def shape_llr(origins, dirs, ranges, noise: float, family, housing_radius: float = HOUSING_R,
              min_sigma: float = 1e-4, neighbours=None, angle_sigma: float = 5e-4, frame=None) -> dict:
    """Generalised log-likelihood ratio "housing circle" vs "best look-alike of ``family``" of lidar
    returns: ``origins`` (N, 2) sensor positions, ``dirs`` (N, 2) unit beam directions, ``ranges`` (N,)
    measured ranges, all in one frame; range noise sigma = ``noise`` x range (at least ``min_sigma`` m).
    ``neighbours``: ``(origins, dirs)`` (or ``(origins, dirs, frame)``) of the beams next to the hitting
    ones that saw past the object (they must not cross it); ``angle_sigma`` (m): the tolerance of these
    silhouette terms (beam directions are exact in the simulator; 0 switches them off). Each hypothesis
    gets its centre fitted: one for all returns, or with ``frame`` (N,) frame ids one per frame (no
    odometry drift between frames; each look-alike outline keeps one orientation over all frames).
    Returns ``llr`` (> 0: more circle-like), the circle's and the best look-alike's log-likelihoods."""
    o = np.asarray(origins, float).reshape(-1, 2)
    u = np.asarray(dirs, float).reshape(-1, 2)
    rng = np.asarray(ranges, float).reshape(-1)
    if not (len(o) == len(u) == len(rng)) or len(rng) < 2:
        raise ValueError(f"shape_llr: need >= 2 returns with one origin and direction each, got "
                         f"{len(o)} origins, {len(u)} directions, {len(rng)} ranges")  # fmt: skip
    if not (np.all(np.isfinite(rng)) and np.all(rng > 0)):
        raise ValueError("shape_llr: ranges must be finite and positive (drop no-return beams first)")
    if not noise >= 0:
        raise ValueError(f"shape_llr: noise must be >= 0 (relative range noise), got {noise!r}")
    sig = np.maximum(noise * rng, min_sigma)
    fid = np.zeros(len(rng), np.int64) if frame is None else np.asarray(frame, np.int64).reshape(-1)
    if len(fid) != len(rng):
        raise ValueError(f"shape_llr: frame must give one id per return, got {len(fid)} for {len(rng)}")
    if neighbours is None:
        no, nu, nf = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64)
    else:
        no = np.asarray(neighbours[0], float).reshape(-1, 2)
        nu = np.asarray(neighbours[1], float).reshape(-1, 2)
        nf = (np.asarray(neighbours[2], np.int64).reshape(-1) if len(neighbours) > 2 and frame is not None
              else np.zeros(len(no), np.int64))  # fmt: skip
    llc, lla = 0.0, 0.0
    for f in np.unique(fid):
        m, mn = fid == f, nf == f
        c, a, _ = _hyp_ll(o[m], u[m], rng[m], sig[m], (no[mn], nu[mn], angle_sigma), family, housing_radius)
        llc, lla = llc + c, lla + a
    best = float(np.max(lla))
    return {"llr": llc - best, "ll_circle": llc, "ll_lookalike": best}


def _kin_sized(o, wall_type) -> bool:
    kind, geom = o.footprint()
    if isinstance(o, wall_type):
        return False
    if kind == "circle":
        return bool(geom[2] <= 0.065)
    return bool(np.ptp(geom, axis=0).max() < 0.13)


def _roc(pos, neg):
    """AUC, true-positive rate at 5 % false positives, false-positive rate at 95 % true positives."""
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    if not len(pos) or not len(neg):
        return {"auc": math.nan, "tpr_at_fpr05": math.nan, "fpr_at_tpr95": math.nan}
    allv = np.r_[pos, neg]
    order = np.argsort(allv, kind="mergesort")
    ranks = np.empty(len(allv))
    ranks[order] = np.arange(1, len(allv) + 1)
    for v in np.unique(allv):  # mid-ranks for ties
        m = allv == v
        ranks[m] = ranks[m].mean()
    auc = (ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg))
    thr_neg = np.quantile(neg, 0.95, method="higher")
    thr_pos = np.quantile(pos, 0.05, method="lower")
    return {"auc": float(auc), "tpr_at_fpr05": float((pos > thr_neg).mean()),
            "fpr_at_tpr95": float((neg >= thr_pos).mean())}  # fmt: skip


def roc_summary(pos, neg) -> dict:
    """ROC figures of a statistic (higher = kin): ``auc``, ``tpr_at_fpr05`` (kin kept when 95 % of the
    look-alikes are rejected) and ``fpr_at_tpr95`` (look-alikes kept when 95 % of the kin are kept)."""
    return _roc(pos, neg)


def _returns(ranges, valid, ang, pose, beams, own) -> tuple:
    """One frame's evidence on one object: ``(origins, directions, ranges)`` of its ``beams`` (a mask over
    one scan row) and ``(origins, directions)`` of the beams beside them that saw past it (no return, or a
    return 5 cm farther than its farthest; never one of ``own``, the object's beams): its silhouette. Beam
    directions ``ang`` and the sensor at ``pose`` in one common frame."""
    r = ranges[beams].astype(float)
    nb = (np.roll(beams, 1) | np.roll(beams, -1)) & ~own
    nb &= ~valid | (ranges > r.max() + 0.05)
    o = np.asarray(pose, float)[None, :2]
    return (np.repeat(o, len(r), 0), np.c_[np.cos(ang[beams]), np.sin(ang[beams])], r,
            np.repeat(o, int(nb.sum()), 0), np.c_[np.cos(ang[nb]), np.sin(ang[nb])])  # fmt: skip


def _episode_family(world, step_deg: float):
    """The look-alike family of one episode's world (the generic outlines plus its own non-wall obstacles
    at their true orientation), which obstacles are kin-sized and which are same-radius cylinders."""
    from ..core.scenes import Cylinder, Wall
    from . import sequences as S

    r_h = world.scene.robot.housing_radius
    obst = world.scene.obstacles
    extra_p, extra_r = [], []
    for ob in obst:
        kind, geom = ob.footprint()
        if isinstance(ob, Wall):
            continue
        if kind == "circle":
            extra_r.append(geom[2])
        elif len(geom) <= 6 and np.ptp(geom, axis=0).max() < 0.2:
            extra_p.append(geom - np.asarray(ob.center))
    family = lookalike_family(extra_p, extra_r, r_h, step_deg)
    # kin-sized objects only (walls and large obstacles are no look-alikes of a 7 cm housing)
    small = np.array([_kin_sized(o, Wall) for o in obst], bool).reshape(-1)
    same_r = np.array([isinstance(o, Cylinder) and abs(o.radius - r_h) <= S.SAME_RADIUS_TOL
                       for o in obst], bool).reshape(-1)  # fmt: skip
    return family, small, same_r


def oracle_samples(recorded, frames=(10, 20), distance=(0.3, 2.0), still: float = 0.02, true_poses=False,
                   kin_model="learned", step_deg: float = 10.0, angle_sigma: float = 5e-4,
                   per_frame: bool = False, progress: bool = False,
                   benchmark_seeds: bool = False) -> list[dict]:
    """Still objects of ``recorded``'s episodes (``sequences.RecordedEpisodes``, training seeds only) at
    the frame they have been in view (>= 2 beams) for each of ``frames``, at ``distance`` from the
    observer: their shape LLR (:func:`shape_llr` over the beams that hit them in those frames, ego-motion
    compensated with the observer's odometry, or its true poses if ``true_poses``) and the tracker's kin
    probability (``kin_model``) of the confirmed track nearest the object (0 if none within ``GATE``).
    A kin is still when it moved < ``still`` m since first in view; same-radius cylinders and walls are
    left out (a same-radius cylinder *is* the circle). The episodes are re-run from their seeds to get the
    per-beam ground truth (asserted identical to the recording). ``benchmark_seeds=True`` accepts the
    benchmark's reserved episodes: for reporting the bound once, never for choosing a cue."""
    from detectors.tracking import KinTracker

    from ..core.lidar import HitKind
    from . import sequences as S
    from .benchmark import GATE

    if not recorded.spec.training and not benchmark_seeds:
        raise ValueError(f"oracle_samples: split {recorded.spec.name!r} uses the benchmark's reserved "
                         "seeds; analyse training_split(...) episodes")  # fmt: skip
    frames = tuple(sorted(int(f) for f in frames))
    out = []
    seeds = list(recorded.spec.seeds(len(recorded.episodes)))
    it = zip(seeds, recorded.episodes, strict=True)
    if progress:
        from kin_envs.cli import progress as _bar

        it = _bar(list(it), desc=f"oracle {recorded.spec.name}", leave=False)
    for seed, (n_obs, _n_robots, _n_obst, _kinds, _parked, rec) in it:
        ep = S.episode(recorded.spec, seed, recorded.noise)
        w = ep.world
        r_h = w.scene.robot.housing_radius
        obst = w.scene.obstacles
        family, small, same_r = _episode_family(w, step_deg)
        tracker = KinTracker(n_observers=n_obs, kin_model=kin_model)
        odo = np.zeros((n_obs, 3))
        # per (observer, ("r"|"o", index)): list of (origins, dirs, ranges) per frame in view, first pos
        acc: dict = {}
        done: set = set()
        for frame, fr in enumerate(rec):
            if frame:
                ep.step(frame)
            scan = ep.scan()
            if not np.allclose(scan.poses, fr.poses[ep.observers]):
                raise RuntimeError("oracle_samples: the re-run episode differs from the recording")
            ob_, xy, sc, pts, own, accd = fr.cand
            noise_est = np.where(np.isnan(fr.noise_est), tracker.params.range_noise, fr.noise_est)
            tracker.update_batch(ob_, xy, sc, fr.delta, S._FRAME_S, pts, own, noise_est, accepted=accd)
            for row in range(n_obs):
                x, y, th = odo[row]
                dx, dy, dth = fr.delta[row]
                c, s = math.cos(th), math.sin(th)
                odo[row] = (x + c * dx - s * dy, y + s * dx + c * dy, th + dth)  # as the tracker composes
                pose = scan.poses[row] if true_poses else odo[row]
                valid = scan.ranges[row] < scan.range_max
                kind, index = scan.hit_kind[row], scan.hit_index[row]
                ang = scan.angles + pose[2]
                tfeat = None
                for key_kind, sel in (("r", kind == HitKind.ROBOT),
                                      ("o", (kind != HitKind.ROBOT) & (kind != HitKind.NONE) & (index >= 0))):
                    ids, counts = np.unique(index[valid & sel], return_counts=True)
                    for j, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
                        if cnt < 2 or (key_kind == "o" and (same_r[j] or not small[j])):
                            continue
                        key = (row, key_kind, j)
                        b = valid & sel & (index == j)
                        true_xy = w.poses[j, :2] if key_kind == "r" else np.asarray(obst[j].center)
                        a = acc.setdefault(key, {"o": [], "u": [], "r": [], "no": [], "nu": [], "f": [],
                                                 "nf": [], "start": true_xy.copy()})  # fmt: skip
                        got = _returns(scan.ranges[row], valid, ang, pose, b, sel & (index == j))
                        for name, v in zip(("o", "u", "r", "no", "nu"), got, strict=True):
                            a[name].append(v)
                        a["f"].append(np.full(len(got[2]), frame))
                        a["nf"].append(np.full(len(got[3]), frame))
                        n_in = len(a["r"])
                        if n_in not in frames or (key, n_in) in done:
                            continue
                        done.add((key, n_in))
                        x0, y0, th0 = scan.poses[row]
                        d = true_xy - (x0, y0)
                        loc = np.array([math.cos(th0) * d[0] + math.sin(th0) * d[1],
                                        -math.sin(th0) * d[0] + math.cos(th0) * d[1]])  # fmt: skip
                        dist = float(np.hypot(*loc))
                        moved = float(np.hypot(*(true_xy - a["start"])))
                        if not (distance[0] <= dist < distance[1]) or moved >= still:
                            continue
                        cat = [np.concatenate(a[k]) for k in ("o", "u", "r")]
                        nbr = [np.concatenate(a[k]) for k in ("no", "nu", "nf")]
                        fid = np.concatenate(a["f"]) if per_frame else None
                        res = shape_llr(*cat, recorded.noise, family, r_h, angle_sigma=angle_sigma,
                                        neighbours=nbr, frame=fid)  # fmt: skip
                        if tfeat is None:
                            tfeat = tracker.track_features(row)
                            tprob = tracker.kin_prob(row)
                        dd = np.hypot(*(tfeat["xy"] - loc).T)
                        okt = tfeat["confirmed"] & (dd <= GATE)
                        if okt.any():
                            i = int(np.argmin(np.where(okt, dd, np.inf)))
                            p, mean_logit = float(tprob[i]), float(tfeat["features"][i, 0])
                        else:
                            p, mean_logit = 0.0, -np.inf
                        label = ("kin" if key_kind == "r" else
                                 obst[j].kind + (f"{obst[j].sides}" if obst[j].kind == "prism" else ""))
                        out.append({"split": recorded.spec.name, "seed": seed, "observer": row,
                                    "frames": n_in,
                                    "object": label, "kin": key_kind == "r", "distance": dist,
                                    "points": int(sum(len(r) for r in a["r"])), "llr": res["llr"],
                                    "chi2_circle": -2.0 * res["ll_circle"],
                                    "chi2_lookalike": -2.0 * res["ll_lookalike"],
                                    "track_prob": p, "mean_logit": mean_logit})  # fmt: skip
    return out


# --------------------------------------------------------------------------- the per-frame F1 ceiling


def ceiling_records(spec, n_episodes: int | None = None, noise: float = 0.01, still: float = 0.02,
                    min_age: int = 10, distance=(0.3, 2.0), step_deg: float = 10.0,
                    angle_sigma: float = 5e-4, centre: str = "frame", progress: bool = False,
                    benchmark_seeds: bool = False) -> list[dict]:
    """What an oracle tracker would decide, frame by frame, on the sequence benchmark's target window.

    Re-runs the episodes of ``spec`` (a ``sequences.SequenceSpec``; the reduced count unless
    ``n_episodes``) and returns one row per observer, frame and object that the benchmark's per-frame
    F1 counts in its window: a kin with >= ``MIN_BEAMS`` beams, or a kin-sized non-wall obstacle (7 cm
    prisms, boxes, cylinders of other radii; same-radius cylinders are "don't care" there) with >= 2
    beams, in view (its current run of frames with >= 1 beam, as the benchmark counts it) for
    >= ``min_age`` frames, at ``distance`` (m) from the observer. Each row says whether the object is a
    kin, whether it is *still* (a kin that has not moved ``still`` m from where this observer first saw
    it; obstacles always) and its shape LLR (:func:`shape_llr`'s statistic with a centre per frame and
    true headings, summed over **every** frame so far in which it had >= 2 beams: the evidence a tracker
    that never loses it could have), and ``id`` (the robot's or the obstacle's index) to group them by
    object. :func:`f1_ceiling` turns the rows into the best per-frame F1. Rows
    with ``dont_care`` are same-radius cylinders at ``distance`` once every kin the observer has seen moved
    ``sequences.MOVED`` m (the benchmark's same-radius rejection frames; any age), for that figure only.

    The oracle is generous everywhere it can be: true association, true headings, the noise model, every
    outline of the episode in its family, a kin that moved is always found, anything larger than a
    housing and every wall always rejected. ``benchmark_seeds`` accepts the reserved episodes (for
    reporting the bound once, never for choosing anything)."""
    from ..core.lidar import HitKind
    from . import sequences as S
    from .benchmark import DISTANCE_EDGES, MIN_BEAMS

    if not (spec.training or benchmark_seeds):
        raise ValueError(f"ceiling_records: split {spec.name!r} uses the benchmark's reserved seeds; pass "
                         "benchmark_seeds=True to report the bound on them (never to choose)")  # fmt: skip
    if not (isinstance(min_age, int) and min_age >= 1):
        raise ValueError(f"ceiling_records: min_age must be an integer >= 1, got {min_age!r}")
    if not still > 0:
        raise ValueError(f"ceiling_records: still must be > 0 m, got {still!r}")
    if centre not in ("frame", "one"):
        raise ValueError(f"ceiling_records: centre must be 'frame' or 'one', got {centre!r}")
    n = spec.reduced_episodes if n_episodes is None else int(n_episodes)
    seeds = list(spec.seeds(n))
    it = seeds
    if progress:
        from kin_envs.cli import progress as _bar

        it = _bar(seeds, desc=f"ceiling {spec.name} noise {100 * noise:g} %", leave=False)
    lo, hi = float(distance[0]), float(distance[1])
    out = []
    for seed in it:
        ep = S.episode(spec, seed, noise)
        w = ep.world
        r_h = w.scene.robot.housing_radius
        family, small, same_r = _episode_family(w, step_deg)
        n_obs, n_rob, n_ob = len(ep.observers), w.n_robots, w.n_obstacles
        age = np.zeros((n_obs, n_rob + n_ob), np.int64)  # visibility ages (>= 1 valid beam)
        first = np.full((n_obs, n_rob, 2), np.nan)  # where each observer first saw each kin
        moved = np.zeros((n_obs, n_rob))  # the farthest it has been from there since
        start = w.poses[:, :2].copy()  # the benchmark's "moved" for same-radius rejection: from here
        seen_kin = [set() for _ in range(n_obs)]
        data: dict = {}  # (row, object) -> [(frame, o, u, r, no, nu)] frames with >= 2 beams
        want: dict = {}  # (row, object) -> [(frame, distance, age, kin, still)] rows in the window
        for frame in range(spec.run.frames):
            if frame:
                ep.step(frame)
            scan = ep.scan()
            for row in range(n_obs):
                kind, index = scan.hit_kind[row], scan.hit_index[row]
                valid = scan.ranges[row] < scan.range_max
                robot = valid & (kind == HitKind.ROBOT)
                other = valid & (kind != HitKind.ROBOT) & (kind != HitKind.NONE) & (index >= 0)
                obj = np.where(robot, index, np.where(other, n_rob + index, -1))  # one id space
                ids, counts = np.unique(obj[obj >= 0], return_counts=True)
                vis = np.zeros(n_rob + n_ob, bool)
                vis[ids] = True
                age[row] = np.where(vis, age[row] + 1, 0)
                x0, y0, th = scan.poses[row]
                seen = ids[ids < n_rob]
                new = seen[np.isnan(first[row, seen, 0])]
                first[row, new] = w.poses[new, :2]
                far = np.hypot(*(w.poses[seen, :2] - first[row, seen]).T)
                moved[row, seen] = np.maximum(moved[row, seen], far)
                ang = scan.angles + th
                for j, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
                    is_kin = j < n_rob
                    if cnt < (MIN_BEAMS if is_kin else 2) or (not is_kin and not small[j - n_rob]):
                        continue
                    is_still = not is_kin or moved[row, j] < still
                    if not is_still:
                        continue  # the oracle finds a kin that moved; its rows come below, no evidence needed
                    b = obj == j
                    got = _returns(scan.ranges[row], valid, ang, scan.poses[row], b, b)
                    data.setdefault((row, j), []).append((frame, *got))
                seen_kin[row].update(seen[counts[ids < n_rob] >= MIN_BEAMS].tolist())
                sk = np.fromiter(seen_kin[row], np.int64)
                gone = np.hypot(*(w.poses[sk, :2] - start[sk]).T)
                all_moved = len(sk) > 0 and bool(np.all(gone >= S.MOVED))
                # the window's rows: kin (>= MIN_BEAMS) and kin-sized look-alikes (>= 2 beams); same-radius
                # cylinders ("don't care" for F1) in view once every kin seen so far moved S.MOVED m
                for j, cnt in zip(ids.tolist(), counts.tolist(), strict=True):
                    is_kin = j < n_rob
                    sr = not is_kin and bool(same_r[j - n_rob])
                    if sr and not all_moved:
                        continue
                    if not sr and (age[row, j] < min_age or cnt < (MIN_BEAMS if is_kin else 2)):
                        continue
                    if not is_kin and not small[j - n_rob]:
                        continue
                    cxy = w.poses[j, :2] if is_kin else np.asarray(w.scene.obstacles[j - n_rob].center)
                    dist = float(np.hypot(cxy[0] - x0, cxy[1] - y0))
                    if not (lo <= dist < hi):
                        continue
                    is_still = not is_kin or bool(moved[row, j] < still)
                    want.setdefault((row, j), []).append((frame, dist, int(age[row, j]), is_kin, is_still))
        obst = w.scene.obstacles
        for (row, j), rows in want.items():
            frames_needed = {f for f, *_rest in rows if _rest[-1]}  # still rows need the evidence
            llr_at = {}
            if frames_needed and centre == "frame":
                last = max(frames_needed)
                llc, lla = 0.0, 0.0
                for f, o, u, r, no, nu in data.get((row, j), []):
                    if f > last:
                        break
                    sig = np.maximum(noise * r, 1e-4)
                    c, a, _ = _hyp_ll(o, u, r, sig, (no, nu, angle_sigma), family, r_h)
                    llc, lla = llc + c, lla + a
                    llr_at[f] = llc - float(np.max(lla))
            elif frames_needed:
                llr_at = _one_centre_llrs(data.get((row, j), []), max(frames_needed), noise, angle_sigma,
                                          family, r_h)  # fmt: skip
            sr = j >= n_rob and bool(same_r[j - n_rob])
            label = "kin" if j < n_rob else "same-radius" if sr else (obst[j - n_rob].kind + (
                f"{obst[j - n_rob].sides}" if obst[j - n_rob].kind == "prism" else ""))  # fmt: skip
            for f, dist, a, is_kin, is_still in rows:
                out.append({"split": spec.name, "seed": seed, "observer": row, "frame": f, "object": label,
                            "id": int(j) if j < n_rob else int(j - n_rob),  # robot / obstacle index
                            "kin": is_kin, "still": is_still, "distance": dist, "age": a, "dont_care": sr,
                            "distance_bin": _bin_of(dist, DISTANCE_EDGES),
                            # no evidence this frame (one beam): nothing to report
                            "llr": llr_at.get(f, -math.inf) if is_still else math.inf})  # fmt: skip
    return out


def _one_centre_llrs(frames, last: int, noise: float, angle_sigma: float, family, housing_radius: float,
                     iterations: int = 4) -> dict:
    """``{frame: LLR}`` with one centre per hypothesis over every frame so far (a still object seen from
    true poses): each frame refits all the returns and silhouettes so far, warm-started from the previous
    frame's centres (the first frame from the points, as :func:`_hyp_ll`, with its full iterations)."""
    polys, radii = family
    parts = [("circle", np.array([housing_radius]), housing_radius), ("polygon", polys, housing_radius),
             ("circle", np.asarray(radii, float), float(np.mean(radii)) if len(radii) else 0.0)]
    parts = [(kind, geom, rad) for kind, geom, rad in parts if len(geom)]  # the circle is always first
    out, acc, warm = {}, [[] for _ in range(5)], None
    for f, *arrays in frames:
        if f > last:
            break
        for a, x in zip(acc, arrays, strict=True):
            a.append(x)
        o, u, r, no, nu = (np.concatenate(a) for a in acc)
        sig = np.maximum(noise * r, 1e-4)
        it = iterations
        if warm is None:  # the points' mean pushed away from the sensor by each part's radius
            p = o + u * r[:, None]
            back = (p - o) / np.linalg.norm(p - o, axis=1, keepdims=True)
            warm = [np.repeat((p + back * rad).mean(0)[None], len(geom), 0) for _k, geom, rad in parts]
            it = 12
        fits = [_fit(o, u, r, sig, (kind, geom), c0, it, (no, nu, angle_sigma))
                for (kind, geom, _r), c0 in zip(parts, warm, strict=True)]  # fmt: skip
        warm = [c for c, _ll in fits]
        out[f] = float(fits[0][1][0]) - float(np.max(np.concatenate([ll for _c, ll in fits[1:]])))
    return out


def _bin_of(value: float, edges) -> int:
    return int(np.searchsorted(edges, value, side="right")) - 1


def f1_ceiling(records, by=("distance_bin",), iterations: int = 50, lookalike_age: int = 20) -> dict:
    """The best per-frame F1 on :func:`ceiling_records`' rows: a kin that moved is always found; a still
    kin or look-alike is reported when its shape LLR reaches a threshold, one per value of the ``by``
    fields (a prior of its own per context; ``()``: one threshold), chosen to maximise F1 over all rows
    (Dinkelbach: at the optimum F*, each context reports where (2 - F*) per kin kept outweighs F* per
    look-alike kept; ``dont_care`` rows left out). Returns ``f1``, ``precision``, ``recall``, the counts,
    the thresholds, ``by_distance`` (the same decisions' P / R / F1 per distance bin), ``rejected``
    (look-alikes in view >= ``lookalike_age`` frames not reported, by kind: ``(share, rows)``),
    ``same_radius_rejected`` (the ``dont_care`` rows not reported: ``(share, rows)``), ``f1_no_shape``
    (still objects all reported or all dropped per context: motion and context without shape evidence) and
    ``f1_ci``, a 95 % percentile bootstrap interval over episodes (rows' ``seed``) at the chosen
    thresholds (NaN with fewer than two episodes)."""
    all_rows = list(records)
    rows = [r for r in all_rows if not r.get("dont_care", False)]
    moving = sum(1 for r in rows if r["kin"] and not r["still"])
    groups: dict = {}
    for r in rows:
        if r["still"]:
            groups.setdefault(tuple(r[k] for k in by), []).append((r["llr"], r["kin"]))
    n_pos = moving + sum(1 for g in groups.values() for _v, k in g if k)
    prepared = {}
    for key, g in groups.items():  # per context: TP and FP when reporting every row above each cut
        v = np.array([x for x, _k in g], float)
        k = np.array([kk for _x, kk in g], bool)
        order = np.argsort(-v, kind="mergesort")
        v, k = v[order], k[order]
        cut = np.r_[np.flatnonzero(np.diff(v) != 0) + 1, len(v)]  # report the first `cut` rows (ties kept)
        prepared[key] = (np.r_[0, np.cumsum(k)[cut - 1]], np.r_[0, np.cumsum(~k)[cut - 1]],
                         np.r_[np.inf, v[cut - 1]])  # thresholds: report rows with llr >= thr  # fmt: skip

    def solve(options):
        f, best = 0.0, None
        for _ in range(iterations):
            pick = {}
            for key, (tp, fp, _t) in prepared.items():
                i = options(len(tp))
                pick[key] = int(i[np.argmax((2 - f) * tp[i] - f * fp[i])])
            tp_ = moving + sum(int(prepared[key][0][i]) for key, i in pick.items())
            fp_ = sum(int(prepared[key][1][i]) for key, i in pick.items())
            f_new = 2 * tp_ / (tp_ + fp_ + n_pos) if n_pos else math.nan
            if best is not None and not f_new > f + 1e-12:
                break
            f, best = f_new, pick
        return f, best

    f, pick = solve(np.arange)
    f0, _ = solve(lambda n: np.array([0, n - 1]))  # all or nothing per context
    thr = {key: float(prepared[key][2][i]) for key, i in pick.items()}

    def reported(r):
        return (r["kin"] and not r["still"]) or r["llr"] >= thr.get(tuple(r[k] for k in by), math.inf)

    def counts(sel):
        tp = sum(1 for r in sel if r["kin"] and reported(r))
        fp = sum(1 for r in sel if not r["kin"] and reported(r))
        fn = sum(1 for r in sel if r["kin"] and not reported(r))
        p, rc, f1 = prf1(tp, fp, fn)
        return {"tp": tp, "fp": fp, "fn": fn, "precision": p, "recall": rc, "f1": f1}

    rej: dict = {}
    for r in rows:
        if not r["kin"] and r["age"] >= lookalike_age:
            c = rej.setdefault(r["object"], [0, 0])
            c[0] += 1
            c[1] += int(not reported(r))
    sr = [not reported(r) for r in all_rows if r.get("dont_care", False)]
    # 95 % percentile bootstrap over episodes of F1 = sum 2 TP / sum (2 TP + FP + FN), at these thresholds
    from .benchmark import _ratio_ci

    per_ep: dict = {}
    for r in rows:
        c = per_ep.setdefault(r.get("seed", 0), [0, 0])
        rep = reported(r)
        c[0] += 2 * int(r["kin"] and rep)
        c[1] += 2 * int(r["kin"] and rep) + int(not r["kin"] and rep) + int(r["kin"] and not rep)
    num, den = (np.array([c[i] for c in per_ep.values()], float) for i in (0, 1))
    ci = _ratio_ci(num, den, 2000, np.random.default_rng(0))
    return {**counts(rows), "f1_ci": ci, "kin_rows": n_pos, "moving_kin_rows": moving,
            "still_kin_rows": n_pos - moving,
            "lookalike_rows": sum(1 for r in rows if not r["kin"]),
            "by_distance": {int(b): counts([r for r in rows if r["distance_bin"] == b])
                            for b in sorted({r["distance_bin"] for r in rows})},
            "rejected": {k: (c[1] / c[0], c[0]) for k, c in sorted(rej.items())},
            "same_radius_rejected": (float(np.mean(sr)) if sr else math.nan, len(sr)),
            "thresholds": {str(k): v for k, v in thr.items()}, "f1_no_shape": f0}  # fmt: skip
