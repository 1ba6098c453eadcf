"""The single-scan limit of kin vs 7 cm look-alikes: an oracle likelihood-ratio classifier.

The oracle knows what no detector can: the true noise model (Gaussian range noise of standard
deviation ``noise * true range`` per beam, independent) and which beams hit each object (the
simulator's per-beam ground truth, so segmentation is perfect). For one object's beams it compares

* **kin** (H1): the housing circle, radius :data:`HOUSING_RADIUS`, centre free;
* **look-alike** (H0): every exact candidate shape of the benchmark's ``lookalike`` split: regular
  prisms of 3-6 sides with a 7 cm circumscribed diameter and the 7 x 7 cm box, centre and
  orientation free, and (``cylinders=True``) cylinders of 2.5-6 cm radius outside the same-radius
  band (a radius grid);

by the generalised log-likelihood ratio ``LLR = (min_H0 chi2 - min_H1 chi2) / 2`` (each ``chi2`` the
sum of squared whitened range residuals at the best-fitting pose, by ``scipy.optimize.least_squares``
from several starts; a beam that the hypothesised shape does not intersect costs
:data:`MISS_COST` per metre it passes by). A higher LLR is more kin-like; thresholding it gives
every operating point an ideal single-scan classifier could reach on these objects; its best F1 is
the ceiling a learned segment classifier is compared against (:func:`best_f1`).

The ``swarm`` split's objects (``split="swarm"`` in :func:`scan_objects_llr`; :func:`object_llr_swarm`)
are every shape its generator draws (``kin_envs.core.scenes.RandomArenaConfig``), each with its size
free within the generator's range: regular prisms of 3-6 sides (circumradius 2.5-15 cm, the 7 cm ones
included), boxes and interior walls (sides 5 cm-2 m), the arena boundary (a line), and
(``llr_all``) cylinders of 2-15 cm radius outside the same-radius band. A wall or the boundary is one
object with all its visible beams (perfect segmentation, as for every object). An object whose
points lie farther apart than a housing allows (:data:`HOUSING_RADIUS` plus 8 sigma) is rejected
outright (``LLR = -inf``), so only housing-sized objects are fitted. Thresholds per beam count
(:func:`best_f1_grouped`) let the ceiling use what the range says about the prior (2-beam objects
carry no shape evidence, so whether to accept them is a matter of how many of them are kin).

No detector calls this: it is an analysis tool (``scripts/oracle_lookalike.py``, ``scripts/oracle_swarm.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..core.lidar import HitKind

__all__ = [
    "HOUSING_RADIUS",
    "LOOKALIKE_SHAPES",
    "ObjectLLR",
    "best_f1",
    "best_f1_grouped",
    "circle_ranges",
    "object_llr",
    "object_llr_swarm",
    "polygon_ranges",
    "scan_objects_llr",
]

HOUSING_RADIUS = 0.035
#: H0's exact shapes: (sides, circumradius m); the last is the 7 x 7 cm box.
LOOKALIKE_SHAPES = ((3, 0.035), (4, 0.035), (5, 0.035), (6, 0.035), (4, 0.035 * math.sqrt(2)))
#: H0's other cylinders (radius grid, m): 2.5-6 cm without the same-radius band (3.5 +- 0.2 cm).
CYLINDER_RADII = (0.025, 0.029, 0.033, 0.037, 0.041, 0.047, 0.053, 0.06)
#: whitened residual per metre by which a beam misses the hypothesised shape
MISS_COST = 1e3


def circle_ranges(angles, cx: float, cy: float, r: float):
    """Ranges along rays from the origin at ``angles`` to a circle ``(cx, cy, r)``: ``(range, hit,
    miss)``, ``miss`` the lateral distance (m) by which a ray passes by (0 on a hit)."""
    ux, uy = np.cos(angles), np.sin(angles)
    t = cx * ux + cy * uy
    p2 = np.maximum(cx * cx + cy * cy - t * t, 0.0)
    h2 = r * r - p2
    hit = (h2 >= 0) & (t > 0)
    return t - np.sqrt(np.maximum(h2, 0.0)), hit, np.where(hit, 0.0, np.maximum(np.sqrt(p2) - r, 0.0))


def _polygon(sides: int, circumradius: float, cx: float, cy: float, theta: float) -> np.ndarray:
    a = theta + 2 * np.pi * np.arange(sides) / sides  # one vertex along theta, as kin_envs' Prism
    return np.stack([cx + circumradius * np.cos(a), cy + circumradius * np.sin(a)], axis=1)


def polygon_ranges(angles, vertices):
    """Ranges along rays from the origin at ``angles`` to a convex polygon: ``(range, hit, miss)``
    (``miss``: how far, m, the ray passes by the nearest vertex's bearing; 0 on a hit)."""
    a = np.asarray(angles, dtype=np.float64)
    ux, uy = np.cos(a)[:, None], np.sin(a)[:, None]
    p0 = np.asarray(vertices, dtype=np.float64)
    e = np.roll(p0, -1, axis=0) - p0
    den = ux * e[None, :, 1] - uy * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (p0[None, :, 0] * e[None, :, 1] - p0[None, :, 1] * e[None, :, 0]) / den
        s = (p0[None, :, 0] * uy - p0[None, :, 1] * ux) / den
    ok = (np.abs(den) > 1e-12) & (s >= 0) & (s <= 1) & (t > 0)
    rng = np.where(ok, t, np.inf).min(axis=1)
    hit = np.isfinite(rng)
    if hit.all():  # the costly lateral distances only where a ray misses
        return rng, hit, np.zeros_like(rng)
    va = np.arctan2(p0[:, 1], p0[:, 0])
    dv = np.hypot(p0[:, 0], p0[:, 1])
    lateral = (np.abs(np.angle(np.exp(1j * (va[None, :] - a[:, None])))) * dv[None, :]).min(axis=1)
    return np.where(hit, rng, 0.0), hit, np.where(hit, 0.0, lateral)


def _residuals(pred, hit, miss, r_obs, sigma):
    return np.where(hit, (r_obs - pred) / sigma, MISS_COST * (miss + 1e-3))


def _fit_circle(a, r_obs, sigma, r) -> float:
    from scipy.optimize import least_squares

    best = math.inf
    for k in {int(np.argmin(r_obs)), len(a) // 2}:
        c0 = (r_obs[k] + r) * np.array([math.cos(a[k]), math.sin(a[k])])
        sol = least_squares(
            lambda p: _residuals(*circle_ranges(a, p[0], p[1], r), r_obs, sigma), c0, x_scale=0.01
        )
        best = min(best, float(np.sum(sol.fun**2)))
    return best


def _fit_polygon(a, r_obs, sigma, sides, circumradius, n_starts) -> float:
    from scipy.optimize import least_squares

    x, y = r_obs * np.cos(a), r_obs * np.sin(a)
    b = math.atan2(y.mean(), x.mean())
    c0 = (x.mean() + 0.75 * circumradius * math.cos(b), y.mean() + 0.75 * circumradius * math.sin(b))
    best = math.inf
    for th in np.linspace(0.0, 2 * np.pi / sides, n_starts, endpoint=False):
        sol = least_squares(
            lambda p: _residuals(*polygon_ranges(a, _polygon(sides, circumradius, *p)), r_obs, sigma),
            np.array([*c0, th]), x_scale=np.array([0.01, 0.01, 0.3]),
        )  # fmt: skip
        best = min(best, float(np.sum(sol.fun**2)))
    return best


#: the swarm generator's size ranges (RandomArenaConfig defaults): prism circumradius, box / wall
#: side, cylinder radius (the same-radius band cut out), m
SWARM_PRISM_R = (0.025, 0.15)
SWARM_BOX_SIDE = (0.05, 2.0)
SWARM_CYLINDER_R = ((0.02, 0.033), (0.037, 0.15))


def _box(cx, cy, theta, w, d) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    local = np.array([[-w, -d], [w, -d], [w, d], [-w, d]]) * 0.5
    return local @ np.array([[c, s], [-s, c]]) + [cx, cy]


def _centre_start(a, r_obs, depth: float) -> tuple[float, float]:
    x, y = r_obs * np.cos(a), r_obs * np.sin(a)
    b = math.atan2(y.mean(), x.mean())
    return x.mean() + depth * math.cos(b), y.mean() + depth * math.sin(b)


def _lsq(fun, x0, lo, hi, scale) -> float:
    from scipy.optimize import least_squares

    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    return float(np.sum(least_squares(fun, x0, bounds=(lo, hi), x_scale=scale).fun ** 2))


def _fit_line(a, r_obs, sigma) -> float:
    """chi2 of the best line ``n . p = c`` (the boundary, a long face): range along a ray
    ``t = c / (n . u)``."""
    x, y = r_obs * np.cos(a), r_obs * np.sin(a)
    phi0 = math.atan2(y[-1] - y[0], x[-1] - x[0]) + np.pi / 2
    c0 = float(np.mean(x * math.cos(phi0) + y * math.sin(phi0)))
    if c0 < 0:
        phi0, c0 = phi0 + np.pi, -c0

    def line(p):
        den = np.cos(a - p[0])
        hit = den * p[1] > 1e-9
        return np.where(hit, (r_obs - p[1] / np.where(hit, den, 1.0)) / sigma, MISS_COST)

    return _lsq(line, [phi0, c0], [-np.inf, -np.inf], [np.inf, np.inf], np.array([0.3, 0.01]))


def _fit_free_shapes(a, r_obs, sigma, n_starts: int, cylinders: bool, give_up: float = -math.inf) -> tuple:
    """``(min chi2 over the swarm's prisms, boxes / walls and a line; the same and its cylinders)``,
    each shape's size free within the generator's range. A line through 2 points is exact (chi2 0),
    so 2-beam objects need no other fit; and once the line's chi2 is below ``give_up`` the rest is
    skipped (the caller's LLR bound is already decisive)."""
    inf = np.inf
    best = 0.0 if a.size <= 2 else _fit_line(a, r_obs, sigma)
    if best <= give_up:
        return best, best
    for sides in (3, 4, 5, 6):
        c0 = _centre_start(a, r_obs, 0.75 * HOUSING_RADIUS)
        for th in np.linspace(0.0, 2 * np.pi / sides, n_starts, endpoint=False):
            best = min(best, _lsq(
                lambda p, n=sides: _residuals(*polygon_ranges(a, _polygon(n, p[3], p[0], p[1], p[2])),
                                              r_obs, sigma),
                [*c0, th, HOUSING_RADIUS], [-inf, -inf, -inf, SWARM_PRISM_R[0]],
                [inf, inf, inf, SWARM_PRISM_R[1]], np.array([0.01, 0.01, 0.3, 0.01]),
            ))  # fmt: skip
    lo, hi = SWARM_BOX_SIDE
    c0 = _centre_start(a, r_obs, 0.035)
    x, y = r_obs * np.cos(a), r_obs * np.sin(a)
    face = math.atan2(y[-1] - y[0], x[-1] - x[0])
    for th in np.linspace(face, face + np.pi / 2, n_starts, endpoint=False):
        best = min(best, _lsq(
            lambda p: _residuals(*polygon_ranges(a, _box(*p)), r_obs, sigma),
            [*c0, th, 0.07, 0.07], [-inf, -inf, -inf, lo, lo], [inf, inf, inf, hi, hi],
            np.array([0.01, 0.01, 0.3, 0.01, 0.01]),
        ))  # fmt: skip
    with_cyl = best
    if cylinders:
        for clo, chi in SWARM_CYLINDER_R:
            rc = chi if chi < HOUSING_RADIUS else clo  # start next to the housing's radius
            c0 = _centre_start(a, r_obs, rc)
            with_cyl = min(with_cyl, _lsq(
                lambda p: _residuals(*circle_ranges(a, p[0], p[1], p[2]), r_obs, sigma),
                [*c0, rc], [-inf, -inf, clo], [inf, inf, chi], np.array([0.01, 0.01, 0.01]),
            ))  # fmt: skip
    return best, with_cyl


def object_llr_swarm(
    angles, ranges, noise: float, *, cylinders: bool = True, n_starts: int = 2
) -> tuple[float, float]:
    """:func:`object_llr` against the ``swarm`` generator's shapes (see the module docstring):
    ``(LLR vs its prisms, boxes, walls and the boundary, LLR vs those and its other cylinders)``;
    ``-inf`` for points that no housing can have returned (farther apart than ``2 r + 8 sigma``)."""
    a = np.unwrap(np.asarray(angles, dtype=np.float64))
    r = np.asarray(ranges, dtype=np.float64)
    if a.shape != r.shape or a.size < 2:
        raise ValueError(
            f"object_llr_swarm: needs >= 2 beams with as many angles as ranges, got {a.shape}, {r.shape}"
        )
    if not (isinstance(noise, int | float) and 0 <= noise < 1):
        raise ValueError(f"object_llr_swarm: noise must be a relative sigma in [0, 1), got {noise!r}")
    sigma = np.maximum(noise * r, 1e-4)
    pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    extent = float(np.max(np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))))
    if extent > 2 * HOUSING_RADIUS + 8 * float(sigma.max()) + 1e-3:
        return -math.inf, -math.inf
    e1 = _fit_circle(a, r, sigma, HOUSING_RADIUS)
    # below LLR -25 the exact value does not matter (no kin gets there: its chi2 is ~ its beams);
    # the line's chi2 then gives an upper bound and the other fits are skipped
    e0, e0c = _fit_free_shapes(a, r, sigma, n_starts, cylinders, give_up=e1 - 50.0)
    return 0.5 * (e0 - e1), (0.5 * (e0c - e1) if cylinders else math.nan)


def object_llr(
    angles, ranges, noise: float, *, cylinders: bool = False, n_starts: int = 4
) -> tuple[float, float]:
    """``(LLR vs the 7 cm prisms and box, LLR vs those and the other cylinders)`` of one object's
    beams (``angles`` rad in the observer frame, ``ranges`` m, >= 2 beams); the second is NaN unless
    ``cylinders``. ``noise``: relative range noise (sigma / range, floored at 0.1 mm)."""
    a = np.unwrap(np.asarray(angles, dtype=np.float64))
    r = np.asarray(ranges, dtype=np.float64)
    if a.shape != r.shape or a.size < 2:
        raise ValueError(
            f"object_llr: needs >= 2 beams with as many angles as ranges, got {a.shape}, {r.shape}"
        )
    if not (isinstance(noise, int | float) and 0 <= noise < 1):
        raise ValueError(f"object_llr: noise must be a relative sigma in [0, 1), got {noise!r}")
    sigma = np.maximum(noise * r, 1e-4)
    e1 = _fit_circle(a, r, sigma, HOUSING_RADIUS)
    e0 = min(_fit_polygon(a, r, sigma, s, c, n_starts) for s, c in LOOKALIKE_SHAPES)
    llr_all = math.nan
    if cylinders:
        llr_all = 0.5 * (min(e0, *(_fit_circle(a, r, sigma, rc) for rc in CYLINDER_RADII)) - e1)
    return 0.5 * (e0 - e1), llr_all


@dataclass(frozen=True)
class ObjectLLR:
    """One object seen by one scan row: ``label`` (``"kin"``, ``"7 cm prism <n>"``, ``"7 cm box"``,
    ``"other cylinder"``), its valid beams, centre distance (m) and the two LLRs of :func:`object_llr`."""

    frame: int
    hit_kind: int
    index: int
    label: str
    n_beams: int
    distance: float
    llr: float
    llr_all: float
    beams: tuple[int, ...] = ()

    @property
    def kin(self) -> bool:
        return self.label == "kin"


def _label(scene, kind: int, idx: int, same_radius_tol: float) -> str | None:
    if kind == HitKind.ROBOT:
        return "kin"
    if kind not in (HitKind.PRISM, HitKind.BOX, HitKind.CYLINDER) or idx < 0:
        return None
    o = scene.obstacles[idx]
    if o.kind == "cylinder":
        return None if abs(o.radius - HOUSING_RADIUS) <= same_radius_tol else "other cylinder"
    if o.kind == "prism" and abs(o.width - 2 * HOUSING_RADIUS) < 1e-4:
        return f"7 cm prism {o.sides}"
    if o.kind == "box" and max(abs(o.width - 0.07), abs(o.depth - 0.07)) < 1e-4:
        return "7 cm box"
    return None


def _label_swarm(scene, kind: int, idx: int, same_radius_tol: float) -> str | None:
    if kind == HitKind.BOUNDARY:
        return "boundary"
    if kind == HitKind.WALL:
        return "wall"
    label = _label(scene, kind, idx, same_radius_tol)
    if label is not None or kind not in (HitKind.PRISM, HitKind.BOX, HitKind.CYLINDER):
        return label
    o = scene.obstacles[idx]
    return None if o.kind == "cylinder" else o.kind  # same-radius cylinders: apart


def scan_objects_llr(
    scan, scene, row: int, noise: float, distance: tuple[float, float], *, frame: int = 0,
    cylinders: bool = True, n_starts: int = 4, same_radius_tol: float = 0.002, split: str = "lookalike",
) -> list[ObjectLLR]:  # fmt: skip
    """:func:`object_llr` of every kin, 7 cm prism / box and (non-same-radius) cylinder that scan row
    ``row`` sees with >= 2 valid beams, centred within ``distance`` (m) of the observer.

    ``split="swarm"``: every object the ``swarm`` generator draws (also other prisms and boxes, walls
    and the boundary, whose distance is that of its nearest point) scored by :func:`object_llr_swarm`."""
    if split not in ("lookalike", "swarm"):
        raise ValueError(f"scan_objects_llr: split must be 'lookalike' or 'swarm', got {split!r}")
    swarm = split == "swarm"
    valid = scan.ranges[row] < scan.range_max
    hk, hi = scan.hit_kind[row], scan.hit_index[row]
    robots = np.asarray(scan.robots).tolist()
    ox, oy, oth = (float(v) for v in scan.poses[row])
    c, s = math.cos(oth), math.sin(oth)
    out = []
    for kind, idx in sorted(set(zip(hk[valid].tolist(), hi[valid].tolist(), strict=True))):
        label = (_label_swarm if swarm else _label)(scene, kind, idx, same_radius_tol)
        if label is None:
            continue
        beams = np.flatnonzero(valid & (hk == kind) & (hi == idx))
        for b in [beams]:  # perfect segmentation: every visible beam of the object
            if b.size < 2:
                continue
            if label in ("wall", "boundary"):
                d = float(scan.ranges[row, b].min())
            else:
                if label == "kin":
                    # a scanning robot's pose at scan time (a swarm has moved); else its scene pose
                    rb = scene.robots[idx]
                    x, y = scan.poses[robots.index(idx)][:2] if idx in robots else (rb.x, rb.y)
                else:
                    x, y = scene.obstacles[idx].center
                dx, dy = float(x) - ox, float(y) - oy
                d = math.hypot(c * dx + s * dy, -s * dx + c * dy)
            if not distance[0] <= d < distance[1]:
                continue
            a, r = scan.angles[b], scan.ranges[row, b]
            if swarm:
                llr, llr_all = object_llr_swarm(a, r, noise, cylinders=cylinders, n_starts=n_starts)
            else:
                llr, llr_all = object_llr(a, r, noise, cylinders=cylinders, n_starts=n_starts)
            out.append(ObjectLLR(frame, int(kind), int(idx), label, int(b.size), d, llr, llr_all,
                                 tuple(b.tolist())))  # fmt: skip
    return out


def best_f1(scores: Sequence[float], positive: Sequence[bool]) -> dict:
    """The best F1 over every threshold of ``scores`` (accept ``score >= threshold``), with its
    precision, recall and threshold."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    if s.shape != y.shape or s.size == 0 or not y.any():
        raise ValueError(f"best_f1: needs equal-length scores and labels with >= 1 positive, got {s.shape}")
    order = np.argsort(-s, kind="stable")
    ss, yy = s[order], y[order]
    last = np.r_[ss[1:] != ss[:-1], True]  # a threshold accepts every tied score
    tp = np.cumsum(yy)[last]
    fp = np.cumsum(~yy)[last]
    f1 = 2 * tp / (tp + fp + y.sum())
    j = int(np.argmax(f1))
    return {
        "f1": float(f1[j]), "precision": float(tp[j] / (tp[j] + fp[j])), "recall": float(tp[j] / y.sum()),
        "threshold": float(ss[last][j]), "positives": int(y.sum()), "negatives": int((~y).sum()),
    }  # fmt: skip


def best_f1_grouped(scores: Sequence[float], positive: Sequence[bool], groups: Sequence[int],
                    sweeps: int = 3) -> dict:  # fmt: skip
    """:func:`best_f1` with one threshold per group (e.g. beam count: what a Bayes rule does with a
    prior that depends on it), chosen by coordinate ascent on the pooled F1 from the best common
    threshold. -> ``f1``, ``precision``, ``recall``, ``thresholds`` (per group, ``inf`` = reject all)."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    g = np.asarray(groups)
    if s.shape != y.shape or s.shape != g.shape or s.size == 0 or not y.any():
        raise ValueError(f"best_f1_grouped: needs equal-length scores, labels, groups with >= 1 positive, "
                         f"got {s.shape}, {y.shape}, {g.shape}")  # fmt: skip
    keys = np.unique(g).tolist()
    col = np.searchsorted(keys, g)
    cands = [np.r_[np.unique(s[col == j]), np.inf] for j in range(len(keys))]

    def f1(t):
        acc = s >= t[col]
        tp = int((acc & y).sum())
        return 2 * tp / (acc.sum() + y.sum()), acc

    t = np.full(len(keys), best_f1(s, y)["threshold"])
    best = f1(t)[0]
    for _ in range(sweeps):
        changed = False
        for j in range(len(keys)):
            for v in cands[j]:
                trial = t.copy()
                trial[j] = v
                val = f1(trial)[0]
                if val > best + 1e-12:
                    best, t, changed = val, trial, True
        if not changed:
            break
    acc = f1(t)[1]
    tp = int((acc & y).sum())
    return {
        "f1": float(best), "precision": tp / max(int(acc.sum()), 1), "recall": tp / int(y.sum()),
        "thresholds": dict(zip(keys, t.tolist(), strict=True)), "positives": int(y.sum()),
        "negatives": int((~y).sum()),
    }  # fmt: skip
