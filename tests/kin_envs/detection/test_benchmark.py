"""The detection benchmark: split configs, reserved seeds, ground truth and metrics end to end."""

import dataclasses
import math

import numpy as np
import pytest

from detectors import GeometricKinDetector, GeometricParams
from detectors.base import Detection, DetectionResult, KinDetector
from kin_envs import World, scenes
from kin_envs.detection import benchmark as B
from kin_envs.detection.beam_dataset import beam_records
from kin_envs.detection.dataset import make_scene
from kin_envs.detection.evaluation import kin_truth
from kin_envs.detection.seeds import TRAINING_SEEDS
from kin_envs.detection.sequences import SEQUENCE_SPLITS, RecordedEpisodes, track_samples

# --------------------------------------------------------------------------- configs


@pytest.mark.parametrize("name", sorted(B.SPLITS))
def test_split_round_trip(name):
    spec = B.SPLITS[name]
    assert B.split_from_dict(spec.to_dict()) == spec


@pytest.mark.parametrize(
    "make",
    [
        lambda: B.PaperConfig(distance=(0.1, 1.0)),
        lambda: B.PaperConfig(scenarios=(3,)),
        lambda: B.SwarmConfig(n_robots=(1, 4)),
        lambda: B.SwarmConfig(kin_width_prob=1.5),
        lambda: B.LookalikeConfig(weights=(1, 1, 1)),
        lambda: B.Condition(noise=-0.01),
        lambda: B.Condition(dropout=1.0),
        lambda: B.SplitSpec("swarm", B.PaperConfig(), B.BENCHMARK_SEEDS.start, 10, 2),
        lambda: B.SplitSpec("paper", B.PaperConfig(), 0, 10, 2),  # seeds outside the reserved range
        lambda: B.split_from_dict({**B.SPLITS["paper"].to_dict(), "extra": 1}),
        lambda: B.split_from_dict({**B.SPLITS["paper"].to_dict(), "config": {"distanse": [0.3, 1.5]}}),
    ],
)
def test_bad_configs_raise(make):
    with pytest.raises(ValueError):
        make()


# --------------------------------------------------------------------------- seeds


def test_benchmark_seeds_are_reserved_and_disjoint_from_training():
    blocks = [range(s.first_seed, s.first_seed + s.n_scenes) for s in B.SPLITS.values()]
    for i, a in enumerate(blocks):
        assert a.start >= B.BENCHMARK_SEEDS.start and a.stop <= B.BENCHMARK_SEEDS.stop
        for b in blocks[i + 1 :]:
            assert a.stop <= b.start or b.stop <= a.start
    # the training data's seeds (make_dataset: first_seed + i from 0; train_classifier's held-out
    # sweep and evaluate_detectors: from 1,000,000) are accepted, the benchmark's refused
    B.check_training_seeds(range(0, 10_000_000))
    B.check_training_seeds(np.arange(1_000_000, 1_100_000))
    # every generator of training data refuses every benchmark split's seeds (single scans, sequences)
    assert TRAINING_SEEDS.stop <= B.BENCHMARK_SEEDS.start
    for s in [*B.SPLITS.values(), *SEQUENCE_SPLITS.values()]:
        with pytest.raises(ValueError, match="reserved"):
            B.check_training_seeds(s.seeds(1))
        with pytest.raises(ValueError, match="reserved"):
            B.check_training_seeds(s.seeds(1), within=TRAINING_SEEDS)
        with pytest.raises(ValueError, match="reserved"):
            make_scene(s.first_seed)
        with pytest.raises(ValueError, match="reserved"):
            beam_records(s.first_seed)
    # the tracker's kin classifier fits on recorded sequence episodes: those of a benchmark split are refused
    for spec in SEQUENCE_SPLITS.values():
        with pytest.raises(ValueError, match="reserved"):
            track_samples(RecordedEpisodes(spec, 0.01, ["tracker"], [], 0.0, 0.0))
    with pytest.raises(ValueError, match="overlap"):
        B.check_training_seeds(range(B.BENCHMARK_SEEDS.start - 5, B.BENCHMARK_SEEDS.start + 5))


def test_training_data_from_the_benchmark_generators_refuses_benchmark_seeds():
    """The training families drawn from the benchmark's own generators (``bench_swarm_prob``,
    ``lookalike_prob``) run only on training seeds: each split's reserved seeds are refused."""
    from kin_envs.detection.dataset import DatasetConfig

    for cfg in (DatasetConfig(bench_swarm_prob=1.0), DatasetConfig(lookalike_prob=1.0)):
        for s in B.SPLITS.values():
            with pytest.raises(ValueError, match="reserved"):
                make_scene(s.first_seed, cfg)
            with pytest.raises(ValueError, match="reserved"):
                make_scene(s.first_seed + s.n_scenes - 1, cfg)
    # a training seed draws a scene of the benchmark's generator, not the benchmark's own scene
    scene, _, info = make_scene(7, DatasetConfig(lookalike_prob=1.0))
    assert info["family"] == 5
    own = B.lookalike_scene(B.SPLITS["lookalike"].first_seed)
    assert scene.obstacles != own.obstacles


def test_make_dataset_refuses_benchmark_seeds(tmp_path, capsys):
    from tests.scripts.helpers import load_script

    mod = load_script("make_dataset")
    with pytest.raises(SystemExit):
        first = str(B.BENCHMARK_SEEDS.start - 1)
        mod.main(["--out", str(tmp_path / "d"), "--scenes", "3", "--first-seed", first])
    assert "reserved" in capsys.readouterr().err


# --------------------------------------------------------------------------- scenes


def test_splits_are_seeded_and_every_robot_scans():
    for name in ("paper", "lookalike"):
        a, b = B.generate_split(name, 2), B.generate_split(name, 2)
        for x, y in zip(a, b, strict=True):
            assert x.seed == y.seed and np.array_equal(x.scan.ranges, y.scan.ranges)
            assert x.scan.ranges.shape[0] == len(x.scene.robots)


def test_swarm_robots_move_and_cluster():
    (smp,) = B.generate_split("swarm", 1)
    start = np.array([[r.x, r.y] for r in smp.scene.robots])
    moved = np.hypot(*(smp.scan.poses[:, :2] - start).T)
    assert smp.scan.ranges.shape[0] == len(smp.scene.robots) >= 8
    assert np.median(moved) > 0.3  # they drove

    # clusters: robots end up much closer to their nearest neighbour than they started
    def nn(p):
        d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
        np.fill_diagonal(d, np.inf)
        return d.min(axis=1)

    assert np.median(nn(smp.scan.poses[:, :2])) < np.median(nn(start))
    again = B.swarm_scene(np.random.default_rng(smp.seed))
    np.testing.assert_array_equal(again.poses, smp.scan.poses)


def test_conditions_add_noise_and_dropout_reproducibly():
    (smp,) = B.generate_split("lookalike", 1)
    c = B.Condition(0.01, 0.1)
    a = B.apply_condition(smp.scan, c, np.random.default_rng(1))
    b = B.apply_condition(smp.scan, c, np.random.default_rng(1))
    assert np.array_equal(a.ranges, b.ranges)
    hit = np.isfinite(smp.scan.true_ranges)
    dropped = (a.ranges == a.range_max) & hit & (smp.scan.ranges < smp.scan.range_max)
    assert 0.05 < dropped.sum() / hit.sum() < 0.15
    assert B.apply_condition(smp.scan, B.Condition(), np.random.default_rng(1)) is smp.scan


# --------------------------------------------------------------------------- scores


def _paper_scan():
    scene = scenes.paper_scenario(2, distance=0.5)
    return scene, World(scene, seed=0).scan(robots=[0])


def _kin_and_prisms(dets, scene):
    """Detections on the kin (robot 1) and on prisms / the cuboid of Scenario II."""
    kin = [d for d in dets if math.hypot(d.x - 0.5, d.y) < 0.05]
    prisms = [o for o in scene.obstacles if o.kind in ("prism", "box")]
    on_prism = [d for d in dets if any(math.hypot(d.x - o.x, d.y - o.y) < 0.05 for o in prisms)]
    return kin, on_prism


def test_geometric_score_ranks_kin_above_prisms():
    scene, scan = _paper_scan()
    shipped = GeometricKinDetector()
    res = shipped.detect(scan.ranges[0], scan.angles)
    for rep in res.reports:  # >= 0.5 exactly when the shape filter passes
        if "F" in rep.metrics:
            s = shipped.params.F_threshold / (shipped.params.F_threshold + rep.metrics["F"])
            assert (s >= 0.5) == rep.accepted
    ranked = B.permissive(shipped)
    assert ranked.params.F_threshold == B.PERMISSIVE_F_THRESHOLD
    dets = ranked.detect(scan.ranges[0], scan.angles).detections
    kin, prisms = _kin_and_prisms(dets, scene)
    assert len(kin) == 1 and len(prisms) >= 3  # the shape filter no longer removes the prisms
    assert all(kin[0].score > p.score for p in prisms)


def test_learned_score_ranks_kin_above_prisms():
    pytest.importorskip("torch")
    from detectors.learned import LearnedKinDetector

    scene, scan = _paper_scan()
    ranked = B.permissive(LearnedKinDetector(reports=False))
    assert ranked.threshold == 0.0
    dets = ranked.detect(scan.ranges[0], scan.angles).detections
    kin, prisms = _kin_and_prisms(dets, scene)
    assert len(kin) == 1 and len(prisms) >= 3
    assert all(kin[0].score > p.score for p in prisms)


# --------------------------------------------------------------------------- end to end


class OracleDetector(KinDetector):
    """Reports exactly the kin each (noise-free) benchmark scan sees, from the ground truth."""

    def __init__(self, samples, extra=None):
        self.truth = {}
        for smp in samples:
            for r in range(smp.scan.ranges.shape[0]):
                ks = kin_truth(smp.scan, r, smp.scene)
                dets = [Detection(k.range, k.bearing, k.x, k.y, 0.9, 0, 0, k.n_beams) for k in ks]
                if extra is not None:
                    dets.append(dataclasses.replace(extra, score=0.95))
                self.truth[smp.scan.ranges[r].astype(np.float64).tobytes()] = dets

    def detect(self, ranges, angles):
        return DetectionResult(list(self.truth[np.asarray(ranges, np.float64).tobytes()]), [])


def test_oracle_scores_one_and_a_ranked_false_positive_costs_ap():
    samples = {"lookalike": B.generate_split("lookalike", 3)}
    oracle = OracleDetector(samples["lookalike"])
    # far from everything, on beam 0: a false positive ranked above every kin
    fp = Detection(9.0, 0.0, 9.0, 0.0, 0.95, 0, 0, 3)
    noisy = OracleDetector(samples["lookalike"], extra=fp)
    res = B.run_benchmark(
        {"oracle": oracle, "noisy": noisy}, "lookalike", 3, [B.Condition()], n_resamples=50, samples=samples,
        permissive_detectors={"oracle": oracle, "noisy": noisy},
    )  # fmt: skip
    (a,) = res.select(detector="oracle", bin="all")
    assert a["n_kin"] > 0
    assert a["precision"] == a["recall"] == a["f1"] == a["ap"] == 1.0
    assert a["error_p95"] < 1e-9
    for r in res.select(detector="oracle"):
        if r["n_kin"]:
            assert r["ap"] == 1.0 and r["f1"] == 1.0
    ex = res.extras[("oracle", "lookalike", "noise 0 %")]
    assert ex["same_radius"] == 0 < ex["same_radius_seen"]
    assert sum(ex["misses"].values()) == 0
    (b,) = res.select(detector="noisy", bin="all")
    n_scans = res.extras[("noisy", "lookalike", "noise 0 %")]["n_scans"]
    assert b["fp"] == n_scans and b["recall"] == 1.0
    # every scan's false positive comes first: the curve starts at precision 0
    assert 0 < b["ap"] < 1
    lo, hi = b["f1_ci"]
    assert 0.0 <= lo <= b["f1"] <= hi <= 1.0
    lo, hi = b["ap_ci"]
    assert 0.0 <= lo <= hi <= 1.0


def test_run_benchmark_rejects_bad_input():
    with pytest.raises(ValueError, match="split"):
        B.run_benchmark({"g": GeometricKinDetector()}, "nope", 1)
    with pytest.raises(ValueError, match="size"):
        B.run_benchmark({"g": GeometricKinDetector()}, "paper", 0)
    with pytest.raises(ValueError, match="detect_batch"):
        B.run_benchmark({"g": object()}, "paper", 1)
    assert GeometricParams().F_threshold < B.PERMISSIVE_F_THRESHOLD


def test_bootstrap_ap_interval_brackets_the_point_estimate():
    rng = np.random.default_rng(0)
    n_scenes, n = 40, 400
    scene = rng.integers(0, n_scenes, n)
    dtp = (rng.random(n) < 0.4).astype(int)
    dfp = 1 - dtp
    score = rng.random(n) + 0.5 * dtp  # true positives tend to score higher
    n_gt = np.bincount(scene[dtp == 1], minlength=n_scenes).astype(float) + 1  # one miss per scene
    ap, (lo, hi), curve = B._ap_with_ci(score, dtp, dfp, scene, n_gt, n_scenes, 300, rng)
    assert 0.0 <= lo <= ap <= hi <= 1.0 and hi - lo < 0.3
    assert ap == pytest.approx(curve.ap)
