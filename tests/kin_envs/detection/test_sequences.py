"""kin_envs.detection.sequences: seeds, episodes, the MOT bookkeeping on hand-made cases, a tiny run."""

import dataclasses

import numpy as np
import pytest

from detectors import GeometricKinDetector
from detectors.metrics import match
from kin_envs.detection import sequences as S
from kin_envs.detection.benchmark import BENCHMARK_SEEDS, SPLITS


def test_seeds_reserved_and_disjoint_from_the_single_scan_splits():
    single = set()
    for sp in SPLITS.values():
        single.update(sp.seeds(sp.n_scenes))
    seen = set()
    for spec in S.SEQUENCE_SPLITS.values():
        seeds = set(spec.seeds(spec.n_episodes))
        assert all(s in BENCHMARK_SEEDS for s in seeds)
        assert not seeds & single and not seeds & seen
        seen |= seeds


def test_episode_is_deterministic():
    spec = S.SEQUENCE_SPLITS["lookalike"]

    def run():
        ep = S.episode(spec, spec.first_seed + 3, 0.01)
        out = []
        for f in range(6):
            if f:
                ep.step(f)
            out.append((ep.world.poses.copy(), ep.scan().ranges.copy(), ep.world.odometry.copy()))
        return out

    for a, b in zip(run(), run(), strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


def _book():
    import motmetrics as mm

    return S._Observer(3, 0, mm.MOTAccumulator(auto_id=True))


def _frame(bk, kin_xy, det_xy, ids, frame):
    kin_ids = np.arange(len(kin_xy))
    m = match(det_xy, kin_xy, S.GATE)
    S._track_bookkeeping(bk, m, np.asarray(ids), kin_ids, np.ones(len(kin_xy), bool), np.asarray(kin_xy),
                         np.asarray(det_xy).reshape(-1, 2), frame)  # fmt: skip


def test_mot_perfect_tracking():
    import motmetrics as mm

    bk = _book()
    for f in range(5):
        kin = [[1.0 + 0.05 * f, 0.0], [2.0, 1.0]]
        _frame(bk, kin, kin, [7, 9], f)
    mot = S._mot_summary(mm, [bk.mot])
    assert (
        mot["mota"] == pytest.approx(1.0) and mot["idf1"] == pytest.approx(1.0) and mot["num_switches"] == 0
    )
    assert bk.confirm_frames == [1, 1] and not bk.false_ids


def test_mot_identity_switch_miss_and_false_track():
    import motmetrics as mm

    bk = _book()
    kin = [[1.0, 0.0], [2.0, 1.0]]
    _frame(bk, kin, kin, [1, 2], 0)
    _frame(bk, kin, kin, [1, 3], 1)  # kin 1 changes track: one identity switch
    _frame(bk, kin, [kin[0], [5.0, 5.0]], [1, 4], 2)  # kin 1 missed, a false track
    mot = S._mot_summary(mm, [bk.mot])
    assert mot["num_switches"] == 1
    # MOTA = 1 - (FN + FP + IDSW) / GT = 1 - (1 + 1 + 1) / 6
    assert mot["mota"] == pytest.approx(0.5)
    assert bk.false_ids == {4}


def test_tiny_run_is_well_formed():
    spec = S.SEQUENCE_SPLITS["lookalike"]
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=8))
    out = S.run_sequences(GeometricKinDetector(reports=False), spec, n_episodes=1, noise=0.0)
    assert out["frames"] == 8 and out["observer_frames"] == 8
    assert set(out["by_age"]) == {"tracker", "single"}
    for rows in out["by_age"].values():
        assert len(rows) == len(S.AGE_EDGES)
        for r in rows:
            for k in ("precision", "recall", "f1"):
                assert np.isnan(r[k]) or 0 <= r[k] <= 1
    assert out["seconds"]["tracker_per_frame"] > 0


def test_bad_arguments():
    det = GeometricKinDetector(reports=False)
    with pytest.raises(ValueError, match="unknown sequence split"):
        S.run_sequences(det, "nope")
    with pytest.raises(ValueError, match="n_episodes"):
        S.run_sequences(det, "lookalike", n_episodes=0)
    with pytest.raises(ValueError, match="noise"):
        S.run_sequences(det, "lookalike", n_episodes=1, noise=5)
    with pytest.raises(ValueError, match="frames"):
        S.SequenceConfig(frames=0)


def test_training_split_never_uses_the_reserved_seeds():
    spec = S.training_split("swarm", 1000)
    assert spec.training and not any(s in BENCHMARK_SEEDS for s in spec.seeds(5))
    assert spec.scenes == S.SEQUENCE_SPLITS["swarm"].scenes
    with pytest.raises(ValueError, match="reserved"):
        S.training_split("swarm", BENCHMARK_SEEDS.start).seeds(2)
    with pytest.raises(ValueError, match="unknown sequence split"):
        S.training_split("nope")


def test_replayed_episodes_give_the_run_and_tuning_picks_the_best():
    """record_sequences + evaluate_sequences reproduce run_sequences; the target window adds up the
    by-age-and-distance cells; tune_tracker returns the grid value with the best objective; the
    diagnosis counts every tracker miss in the window by one cause."""
    spec = S.training_split("lookalike", 77)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=15))
    det = GeometricKinDetector(reports=False)
    rec = S.record_sequences(det, spec, 1, 0.005)
    a = S.evaluate_sequences(rec, diagnose=True)
    b = S.run_sequences(det, spec, 1, 0.005)
    assert a["by_age"] == b["by_age"] and a["same_radius_rejected"] == b["same_radius_rejected"]
    tw = S.target_window(a)
    cells = [v for k, v in a["by_age_distance"]["tracker"].items()
             if int(k.split(",")[0]) >= 3 and int(k.split(",")[1]) in (1, 2)]  # fmt: skip
    assert tw["tracker"]["all"]["tp"] == sum(c["tp"] for c in cells)
    assert tw["tracker"]["all"]["fp"] == tw["tracker"]["0.3-1"]["fp"] + tw["tracker"]["1-2"]["fp"]
    d = a["diagnosis"]
    assert d.get("fn:total", 0) == sum(v for k, v in d.items() if k.startswith("fn:") and k != "fn:total")
    best, log = S.tune_tracker([rec], {"kin_threshold": (0.3, 0.9)}, passes=1)
    objs = {e["params"]["kin_threshold"]: e["objective"] for e in log}
    assert objs[best.kin_threshold] == max(objs.values())
    with pytest.raises(ValueError, match="unknown parameter"):
        S.tune_tracker([rec], {"nope": (1,)})


def test_track_samples_label_tracks_and_refuse_the_benchmark_seeds():
    """The classifier's rows: confirmed tracks within range, labelled kin when within the gate of another
    robot; fit_kin_model picks the operating point with the best objective. Benchmark episodes are refused
    (the classifier never sees the reserved seeds)."""
    spec = S.training_split("lookalike", 78)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=12))
    rec = S.record_sequences(GeometricKinDetector(reports=False), spec, 2, 0.005)
    s = S.track_samples(rec)
    from detectors.tracking import TRACK_FEATURES

    assert s["X"].shape == (s["y"].size, len(TRACK_FEATURES)) and np.isfinite(s["X"]).all()
    assert s["y"].any() and not s["y"].all()  # kin and look-alikes among the tracks
    assert (s["range"] < 5.0).all() and set(s["episode"]) <= {0, 1}
    model, rows = S.fit_kin_model([rec], thresholds=(0.3, 0.6))
    assert [r["threshold"] for r in rows] == [0.3, 0.6]
    top = max(r["objective"] for r in rows)
    best = [r["threshold"] for r in rows if r["objective"] >= top - 1e-3]
    assert model.info["threshold"] == max(best)  # the highest within tol (0.001) of the best
    assert model.min_frames == 3 and s["window"].shape == s["y"].shape
    bench = dataclasses.replace(rec, spec=S.SEQUENCE_SPLITS["lookalike"])
    with pytest.raises(ValueError, match="reserved"):
        S.track_samples(bench)


def _hand_frame(kin_beams, cand_at):
    """A hand-made recorded frame: observer 0 at the origin, robot 1 at (1, 0), robot 2 at (0, 1); robots
    with beams are in view, candidates (score 0.9, accepted) at the robots in ``cand_at``."""
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    ids = np.array([k for k, b in kin_beams.items() if b > 0], np.int64)
    xy = poses[cand_at, :2].reshape(-1, 2)
    k = xy.shape[0]
    cand = (np.zeros(k, np.int64), xy, np.full(k, 0.9), None, None, np.ones(k, bool))
    truth = (ids, np.array([kin_beams[i] for i in ids], np.int64), poses[ids, :2], np.zeros(ids.size),
             np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, bool))  # fmt: skip
    return S._Frame(np.zeros((1, 3)), cand, np.array([np.nan]), {"single": [xy]}, [truth], np.zeros(3), poses,
                    np.zeros(4))  # fmt: skip


def test_track_samples_label_as_the_benchmark_scores_a_report():
    """Labels follow the per-frame metric: a track on a kin in view (>= 2 beams) is kin; one coasting on a
    kin hidden this frame is not (a report there is a false positive); one on a kin with a single beam is
    left out ("don't care"); the target window is the benchmark's (in view >= 10 frames, 0.3-2 m)."""
    frames = [_hand_frame({1: 3, 2: 3}, [1, 2]) for _ in range(11)]
    frames += [_hand_frame({1: 3, 2: 0}, [1]), _hand_frame({1: 3, 2: 1}, [1])]
    spec = S.training_split("swarm", 0)
    rec = S.RecordedEpisodes(spec, 0.01, ["tracker", "single"], [(1, 3, 0, [], np.zeros(3, bool), frames)],
                             0.0, 0.0)  # fmt: skip
    s = S.track_samples(rec)
    n = s["y"].size
    assert n == 2 * 11 + 2 + 1  # both tracks while both are in view, both when 2 hides, only 1's after
    assert s["y"][:22].all() and s["y"][22] and not s["y"][23] and s["y"][24]
    assert s["window"].tolist() == [False] * 18 + [True] * 7  # from the 10th frame in view on


def test_diagnosis_against_the_single_scan_adds_up():
    """The diagnosis splits the window's kin frames by who got them right, and every tracker miss where the
    single scan was right has one cause: the counts add up to the target window's own."""
    spec = S.training_split("swarm", 81)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=16))
    rec = S.record_sequences(GeometricKinDetector(reports=False), spec, 1, 0.01)
    r = S.evaluate_sequences(rec, mot=False, diagnose=True, kin_model="hand")
    d, tw = r["diagnosis"], S.target_window(r)
    v = {k: d.get(f"vs_single:{k}", 0) for k in ("both_tp", "both_fn", "tracker_only", "single_only")}
    assert v["both_tp"] + v["tracker_only"] == d["tp"] == tw["tracker"]["all"]["tp"]
    assert v["both_tp"] + v["single_only"] == tw["single"]["all"]["tp"]
    assert v["both_fn"] + v["single_only"] == d.get("fn:total", 0) == tw["tracker"]["all"]["fn"]
    lost = sum(n for k, n in d.items() if k.startswith("lost:"))
    causes = sum(n for k, n in d.items() if k.startswith("fn:") and k != "fn:total")
    assert lost == v["single_only"] and causes == d.get("fn:total", 0)
    assert sum(n for k, n in d.items() if k.startswith("fp:")) == tw["tracker"]["all"]["fp"]


def test_lookalikes_rejected_by_kind_after_20_frames():
    """Look-alikes in view >= 20 frames at 0.3-2 m are checked in the same frames for every method; the
    share not reported is a rate per kind."""
    spec = S.training_split("lookalike", 79)
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, frames=24))
    rec = S.record_sequences(GeometricKinDetector(reports=False), spec, 2, 0.0)
    r = S.evaluate_sequences(rec, mot=False, kin_model="hand")
    lr = r["lookalikes_rejected"]
    assert set(lr) == {"tracker", "single"} and lr["tracker"]
    assert {k: n for k, (_, n) in lr["tracker"].items()} == {k: n for k, (_, n) in lr["single"].items()}
    assert all(0 <= rate <= 1 and n > 0 for d in lr.values() for rate, n in d.values())
    assert sum(n for _, n in lr["tracker"].values()) <= 2 * (24 - 19) * max(len(e[3]) for e in rec.episodes)
