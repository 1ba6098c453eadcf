"""kin_envs.detection.shape_oracle: the still-object shape bound on hand-made returns, its ROC figures,
and a tiny training-seed run (refusing the benchmark's seeds)."""

import dataclasses

import numpy as np
import pytest

from detectors import GeometricKinDetector
from kin_envs.detection import sequences as S
from kin_envs.detection.shape_oracle import (
    _ray_circle,
    _ray_polygon,
    _regular,
    lookalike_family,
    oracle_samples,
    roc_summary,
    shape_llr,
)


def _returns(shape, dist, noise, rng, frames=8):
    """Returns of a circle of the housing radius or a 7 cm hexagon at the origin, seen from a sensor
    sliding past at ``dist`` (1 degree beams, a random beam phase per frame), and the beams beside them."""
    O, U, R, F, NO, NU, NF = [], [], [], [], [], [], []
    outline = {"hexagon": _regular(6, 0.07, 0.3)[None], "box": _regular(4, 0.099, 0.2)[None]}
    for f in range(frames):
        o = np.array([-dist, 0.03 * f])
        ang = np.arctan2(-o[1], -o[0]) + np.deg2rad(np.arange(-8.0, 8.0) + rng.uniform(0, 1))
        u = np.c_[np.cos(ang), np.sin(ang)]
        oo = np.repeat(o[None], len(u), 0)
        t = (_ray_circle(oo, u, np.zeros((1, 2)), np.array([0.035])) if shape == "circle"
             else _ray_polygon(oo, u, outline[shape]))[0]  # fmt: skip
        hit = np.isfinite(t)
        beside = (np.roll(hit, 1) | np.roll(hit, -1)) & ~hit
        O.append(oo[hit]), U.append(u[hit]), F.append(np.full(hit.sum(), f))
        R.append(t[hit] * (1 + noise * rng.normal(size=hit.sum())))
        NO.append(oo[beside]), NU.append(u[beside]), NF.append(np.full(beside.sum(), f))
    cat = np.concatenate
    return cat(O), cat(U), cat(R), (cat(NO), cat(NU), cat(NF)), cat(F)


@pytest.mark.parametrize("per_frame", [False, True])
def test_circle_and_hexagon_told_apart_and_the_bad_input_refused(per_frame):
    rng = np.random.default_rng(0)
    family = lookalike_family(step_deg=20.0)
    llr = {}
    for shape in ("circle", "hexagon"):
        o, u, r, nb, f = _returns(shape, 0.5, 0.002, rng)
        llr[shape] = shape_llr(o, u, r, 0.002, family, neighbours=nb, frame=f if per_frame else None)["llr"]
    # millimetre noise at 0.5 m: the outline is resolved, the hexagon is in the family
    assert llr["circle"] > 5 and llr["hexagon"] < -20
    with pytest.raises(ValueError, match="ranges must be finite"):
        shape_llr(o, u, np.where(np.arange(len(r)) == 0, np.inf, r), 0.01, family)
    with pytest.raises(ValueError, match=">= 2 returns"):
        shape_llr(o[:1], u[:1], r[:1], 0.01, family)
    with pytest.raises(ValueError, match="one id per return"):
        shape_llr(o, u, r, 0.01, family, frame=f[:-1])


def test_roc_summary_on_known_values():
    assert roc_summary([2, 3, 4], [0, 1]) == {"auc": 1.0, "tpr_at_fpr05": 1.0, "fpr_at_tpr95": 0.0}
    assert roc_summary([1, 1], [1, 1])["auc"] == 0.5  # ties count half
    r = roc_summary(np.arange(100), np.arange(100) - 50.0)  # half the look-alikes above every kin's 5 %
    assert r["auc"] == pytest.approx(0.875) and np.isnan(roc_summary([], [1.0])["auc"])


def test_oracle_samples_on_training_episodes_only():
    spec = S.training_split("lookalike", 78)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=10))
    rec = S.record_sequences(GeometricKinDetector(reports=False), spec, 1, 0.01)
    out = oracle_samples(rec, frames=(10,), kin_model="hand", step_deg=30.0)
    assert out and all(s["frames"] == 10 and 0.3 <= s["distance"] < 2.0 for s in out)
    assert all(np.isfinite(s["llr"]) and 0 <= s["track_prob"] <= 1 for s in out)
    kinds = {"kin", "box", "cylinder", "prism3", "prism4", "prism5", "prism6"}
    assert {s["object"] for s in out} <= kinds
    with pytest.raises(ValueError, match="reserved"):
        oracle_samples(dataclasses.replace(rec, spec=S.SEQUENCE_SPLITS["lookalike"]))


def test_the_silhouette_carries_what_the_noisy_ranges_do_not():
    """A 7 x 7 cm box at 1.5 m, 1 % range noise: its ranges barely differ from a circle's, but which beams
    hit it (directions are exact) does: the silhouette terms reject it, range residuals alone cannot."""
    rng = np.random.default_rng(1)
    family = lookalike_family(step_deg=20.0)
    o, u, r, nb, f = _returns("box", 1.5, 0.01, rng)
    with_silhouette = shape_llr(o, u, r, 0.01, family, neighbours=nb, frame=f)["llr"]
    ranges_only = shape_llr(o, u, r, 0.01, family, neighbours=nb, frame=f, angle_sigma=0.0)["llr"]
    assert with_silhouette < -20 < ranges_only
