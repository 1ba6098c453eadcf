"""kin_envs.detection.shape_oracle: the still-object shape bound on hand-made returns, its ROC figures,
a tiny training-seed run (refusing the benchmark's seeds), and the oracle tracker's F1 ceiling (against
a brute-force search and the sequence benchmark's own window counts)."""

import dataclasses

import numpy as np
import pytest

from detectors import GeometricKinDetector
from kin_envs.detection import sequences as S
from kin_envs.detection.shape_oracle import (
    _ray_circle,
    _ray_polygon,
    _regular,
    ceiling_records,
    f1_ceiling,
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


def _brute_f1(rows, contexts):
    """Best F1 by trying every threshold (each row's LLR, or report none) in every context."""
    import itertools

    keys = sorted({r["ctx"] for r in rows})
    options = [[np.inf, *sorted({r["llr"] for r in rows if r["still"] and r["ctx"] == k})] for k in keys]
    best = 0.0
    for thr in itertools.product(*options) if contexts else ([t] * len(keys) for t in
                                                               sorted({np.inf, *(r["llr"] for r in rows)})):
        t = dict(zip(keys, thr, strict=True))
        rep = [(r["kin"] and not r["still"]) or r["llr"] >= t[r["ctx"]] for r in rows]
        tp = sum(1 for r, x in zip(rows, rep, strict=True) if r["kin"] and x)
        fp = sum(1 for r, x in zip(rows, rep, strict=True) if not r["kin"] and x)
        fn = sum(1 for r, x in zip(rows, rep, strict=True) if r["kin"] and not x)
        best = max(best, 2 * tp / (2 * tp + fp + fn))
    return best


@pytest.mark.parametrize("seed", range(6))
def test_f1_ceiling_finds_the_best_thresholds(seed):
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(int(rng.integers(8, 18))):
        kin = bool(rng.random() < 0.6)
        still = not kin or bool(rng.random() < 0.5)
        llr = float(np.round(rng.normal(1.0 if kin else -1.0, 1.5), 1)) if still else np.inf
        rows.append({"kin": kin, "still": still, "llr": llr, "ctx": int(rng.integers(2)), "distance_bin": 1,
                     "age": 25, "object": "kin" if kin else "prism5"})  # fmt: skip
    both = f1_ceiling(rows, by=("ctx",))
    one = f1_ceiling(rows, by=())
    assert both["f1"] == pytest.approx(_brute_f1(rows, True))
    assert one["f1"] == pytest.approx(_brute_f1(rows, False))
    assert one["f1"] <= both["f1"] + 1e-12 and both["f1_no_shape"] <= both["f1"] + 1e-12
    assert both["tp"] + both["fn"] == both["kin_rows"] == sum(r["kin"] for r in rows)
    assert both["f1"] == pytest.approx(2 * both["tp"] / (2 * both["tp"] + both["fp"] + both["fn"]))
    assert np.isnan(both["f1_ci"][0])  # one episode: no interval


def test_f1_ceiling_on_a_known_case():
    """3 moving kin (always found), still kin at LLR 2 and -1, look-alikes at 1, 0.5 and -3: reporting
    LLR >= 2 gives TP 4, FP 0, FN 1 (F1 8/9); >= 1: 4 / 1 / 1 (0.8); >= -1: 5 / 2 / 0 (0.83); all: 5 / 3 / 0
    (0.77), none: 3 / 0 / 2 (0.75). The prism seen for 25 frames is rejected at the best threshold."""
    rows = [{"kin": True, "still": False, "llr": np.inf, "distance_bin": 1, "age": 12, "object": "kin"}] * 3
    rows += [{"kin": True, "still": True, "llr": v, "distance_bin": 1, "age": 12, "object": "kin"}
             for v in (2.0, -1.0)]  # fmt: skip
    rows += [{"kin": False, "still": True, "llr": v, "distance_bin": 1, "age": a, "object": k}
             for v, a, k in ((1.0, 25, "prism5"), (0.5, 12, "box"), (-3.0, 12, "box"))]  # fmt: skip
    c = f1_ceiling(rows)
    assert c["f1"] == pytest.approx(8 / 9) and (c["tp"], c["fp"], c["fn"]) == (4, 0, 1)
    assert c["rejected"] == {"prism5": (1.0, 1)} and c["f1_no_shape"] == pytest.approx(10 / 13)
    assert c["by_distance"][1]["f1"] == pytest.approx(8 / 9) and c["moving_kin_rows"] == 3
    assert c["thresholds"] == {"(1,)": 2.0}


def test_ceiling_records_count_the_benchmarks_window(monkeypatch):
    """The oracle's kin rows are exactly the kin frames the sequence benchmark counts in its target window
    (tracker TP + FN), and its same-radius rows the frames the benchmark checks for same-radius rejection,
    on the same training episodes; moving kin carry no shape evidence, still objects do."""
    monkeypatch.setattr(S, "MOVED", 0.02)  # "every kin seen has moved": reached within these short episodes
    spec = S.training_split("lookalike", 81)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=20))
    rec = S.record_sequences(GeometricKinDetector(reports=False), spec, 2, 0.01)
    res = S.evaluate_sequences(rec, mot=False, kin_model="hand")
    for distance in ((0.3, 2.0), (0.0, 5.0)):
        rows = ceiling_records(spec, 2, 0.01, step_deg=30.0, distance=distance)
        window = S.target_window(res, distance=distance)["tracker"]["all"]
        kin = [r for r in rows if r["kin"]]
        assert kin and len(kin) == window["tp"] + window["fn"]
        assert all(r["age"] >= 10 for r in rows if not r["dont_care"])
        assert all(distance[0] <= r["distance"] < distance[1] for r in rows)
        assert all(np.isinf(r["llr"]) and r["llr"] > 0 for r in kin if not r["still"])
        assert all(np.isfinite(r["llr"]) for r in rows if r["still"] and not r["dont_care"])
        c = f1_ceiling(rows)
        lo, hi = c["f1_ci"]  # NaN when every resample gives the same F1
        assert (np.isnan(lo) and np.isnan(hi)) or 0 <= lo <= hi <= 1
        assert c["kin_rows"] == len(kin) and c["lookalike_rows"] == sum(
            1 for r in rows if not r["kin"] and not r["dont_care"])
    # every distance: the same frames as the benchmark's same-radius check
    assert c["same_radius_rejected"][1] == res["same_radius_rejected"]["tracker"][1] > 0
    with pytest.raises(ValueError, match="reserved"):
        ceiling_records(S.SEQUENCE_SPLITS["lookalike"], 1)
    with pytest.raises(ValueError, match="min_age"):
        ceiling_records(spec, 1, min_age=0)
    with pytest.raises(ValueError, match="centre must be"):
        ceiling_records(spec, 1, centre="both")
    with pytest.raises(ValueError, match="still must be > 0"):
        ceiling_records(spec, 1, still=0.0)


def test_one_centre_ceiling_scores_the_same_rows():
    """``centre="one"`` (one centre over all frames so far) scores exactly the rows the per-frame variant
    does; on a still 7 cm look-alike that has been in view a while both call it a look-alike."""
    spec = S.training_split("lookalike", 90)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=14))
    per_frame = ceiling_records(spec, 1, 0.005, step_deg=30.0, min_age=8)
    one = ceiling_records(spec, 1, 0.005, step_deg=30.0, min_age=8, centre="one")
    key = [(r["observer"], r["frame"], r["object"], r["kin"], r["still"], r["distance"]) for r in per_frame]
    assert key and key == [(r["observer"], r["frame"], r["object"], r["kin"], r["still"], r["distance"])
                           for r in one]  # fmt: skip
    assert all(np.isfinite(r["llr"]) for r in one if r["still"])
    prisms = [(a["llr"], b["llr"]) for a, b in zip(per_frame, one, strict=True)
              if a["object"].startswith("prism")]  # fmt: skip
    assert prisms and all(x < 0 and y < 0 for x, y in prisms)
