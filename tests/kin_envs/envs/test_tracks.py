"""Envs with the multi-frame tracker: fixed-shape info["kin_tracks"], determinism, observation mode,
vector stacking, rendering and argument errors."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import kin_envs  # noqa: F401  (registers the ids)
from detectors.tracking import TRACK_FIELDS
from kin_envs.envs.info import unpad

IDS = ["kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"]


@pytest.mark.parametrize("env_id", IDS)
def test_info_shape_is_fixed_and_tracks_follow_the_kin(env_id):
    env = gym.make(env_id, tracker=True, max_tracks=8, noise_sigma=0.005)
    _, info = env.reset(seed=3)
    env.action_space.seed(3)
    near = 0
    for _ in range(60):
        _, _, term, trunc, info = env.step(env.action_space.sample())
        assert set(info["kin_tracks"]) == set(TRACK_FIELDS)
        assert all(v.shape == (8,) for v in info["kin_tracks"].values())
        assert 0 <= info["kin_tracks_count"] <= 8
        tracks = unpad(info, "kin_tracks")
        truth = unpad(info, "kin_truth")
        if len(truth["x"]) and len(tracks["x"]):
            d = np.hypot(tracks["x"][:, None] - truth["x"][None], tracks["y"][:, None] - truth["y"][None])
            near += int((d.min(axis=0) < 0.1).any())
        if term or trunc:
            env.reset(seed=4)
    if "Follow" in env_id:  # the kin stays near the follower (in KinSeek it may be out of range)
        assert near > 0  # the kin is tracked when it is seen


def test_checker_and_determinism_with_track_observations():
    kw = dict(tracker=True, obs_detections="topk", obs_tracks=True, noise_sigma=0.01)
    check_env(gym.make(IDS[1], **kw).unwrapped)
    runs = []
    for _ in range(2):
        env = gym.make(IDS[1], **kw)
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        seq = [obs]
        for _ in range(25):
            obs, _, _, _, info = env.step(env.action_space.sample())
            seq.append(np.r_[obs, info["kin_tracks"]["kin_prob"]])
        runs.append(np.concatenate([np.ravel(s) for s in seq]))
    np.testing.assert_array_equal(*runs)


def test_sync_vector_env_stacks_tracks_through_autoresets():
    v = gym.make_vec(IDS[0], num_envs=2, vectorization_mode="sync", tracker=True, max_steps=15)
    v.reset(seed=0)
    for _ in range(40):
        _, _, _, _, info = v.step(v.action_space.sample())
        assert info["kin_tracks"]["kin_prob"].shape == (2, 16)
    v.close()


def test_render_draws_tracks():
    env = gym.make(IDS[1], tracker=True, render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    assert env.render().shape == (512, 512, 3)


@pytest.mark.parametrize("kwargs, match", [
    (dict(tracker=True, detector=None), "needs a detector"),
    (dict(obs_tracks=True), "obs_tracks"),
    (dict(tracker="yes"), "tracker must be"),
    (dict(tracker={"bogus": 1}), "unknown key"),
])  # fmt: skip
def test_bad_tracker_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(IDS[0], **kwargs)


def test_native_vector_env_tracks_like_separate_envs_through_a_partial_reset():
    """gym.make_vec(..., "vector_entry_point", tracker=True): one KinTracker over the K learners. A sub-env
    reset by ``reset_mask`` restarts its tracks (ids from 0, adopted from its own reset frame) and leaves
    the others' untouched; afterwards every sub-env's tracks are those of a lone env with its seed and
    actions (trajectories across autoresets: tests/kin_envs/envs/test_vector_env.py)."""
    kw = dict(tracker=True, noise_sigma=0.02, max_steps=200, n_distractors=4, kin_like_cylinders=True)
    v = gym.make_vec(IDS[0], num_envs=2, vectorization_mode="vector_entry_point", **kw).unwrapped
    lone = [gym.make(IDS[0], **kw) for _ in range(2)]
    v.reset(seed=[11, 12])
    for e, s in zip(lone, [11, 12], strict=True):
        e.reset(seed=s)
    rng = np.random.default_rng(0)

    def steps(n):
        for _ in range(n):
            a = rng.uniform([0, -1], [1, 1], (2, 2))
            info = v.step(a)[4]
            for i, e in enumerate(lone):
                mine = e.step(a[i])[4]
                for f, c in mine["kin_tracks"].items():
                    np.testing.assert_array_equal(info["kin_tracks"][f][i], c, err_msg=f)
                assert info["kin_tracks_count"][i] == mine["kin_tracks_count"]
        return info

    info = steps(12)
    assert info["kin_tracks_count"].sum() > 0  # there is something to compare
    _, info = v.reset(seed=[None, 21], options={"reset_mask": np.array([False, True])})
    _, mine = lone[1].reset(seed=21)
    np.testing.assert_array_equal(info["kin_tracks"]["id"][1], mine["kin_tracks"]["id"])
    steps(12)
    v.close()


def test_swarm_env_tracks_every_agent_with_fixed_shape_info():
    """aggregation_v2 with tracker=True: one batched tracker over all robots; every agent's
    info["kin_tracks"] keeps one shape on every step; seeded runs repeat; the PettingZoo API holds."""
    from pettingzoo.test import parallel_api_test

    from kin_envs import aggregation_v2

    parallel_api_test(aggregation_v2.parallel_env(n_robots=6, tracker=True, max_cycles=30), num_cycles=30)

    def run(seed):
        env = aggregation_v2.parallel_env(n_robots=8, tracker=True, max_tracks=6, noise_sigma=0.005,
                                          max_cycles=40)  # fmt: skip
        _, infos = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        seen, out = 0, []
        for _ in range(40):
            if not env.agents:
                break
            acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
            _, _, _, _, infos = env.step(acts)
            for info in infos.values():
                assert set(info["kin_tracks"]) == set(TRACK_FIELDS)
                assert all(v.shape == (6,) and v.dtype == np.float64 for v in info["kin_tracks"].values())
                assert 0 <= info["kin_tracks_count"] <= 6
                c = info["kin_tracks_count"]
                assert np.all(info["kin_tracks"]["id"][c:] == 0)  # padded slots are empty
                seen += c
            out.append(np.stack([infos[a]["kin_tracks"]["x"] for a in sorted(infos)]))
        return seen, np.stack(out)

    seen, a = run(5)
    assert seen > 0
    np.testing.assert_array_equal(a, run(5)[1])
    env = aggregation_v2.parallel_env(n_robots=4, tracker=True, render_mode="rgb_array")
    env.reset(seed=1)
    env.step({ag: np.zeros(2, np.float32) for ag in env.agents})
    assert env.render().shape == (512, 512, 3)  # the track overlay of render_agent
    with pytest.raises(ValueError, match="obs_tracks"):
        aggregation_v2.parallel_env(tracker=True, obs_tracks=True)  # no detection channel to fill
    with pytest.raises(ValueError, match="needs a detector"):
        aggregation_v2.parallel_env(tracker=True, detector=None)


def _constant_model(path, logit: float = 5.0):
    """A track-classifier JSON whose kin log-odds is ``logit`` for every track (any age)."""
    from detectors.fileio import write_json
    from detectors.tracking import TRACK_FEATURES, TrackKinModel

    F = len(TRACK_FEATURES)
    model = TrackKinModel(np.zeros(F), np.ones(F), [(np.zeros((F, 1)), np.array([logit]))])
    write_json(path, model.to_dict())
    return str(path)


def test_tracker_kin_model_option_selects_the_track_classifier(tmp_path):
    """KinSeek-v2's tracker={"kin_model": ...}: "hand" is the hand-tuned fusion, "learned" and "geometric" the
    shipped classifiers, "auto" (default) the one fitted on the feed the tracker gets, a JSON path that model
    (its constant log-odds shows in info["kin_tracks"])."""
    from detectors.tracking import DEFAULT_KIN_MODEL, GEOMETRIC_KIN_MODEL, TrackKinModel

    shipped = {"learned": DEFAULT_KIN_MODEL, "geometric": GEOMETRIC_KIN_MODEL}
    path = _constant_model(tmp_path / "const.json")
    for opts, want in [(True, "geometric"), ({"kin_model": "hand", "p_detect": 0.7}, "hand"),
                       ({"kin_model": "learned"}, "learned"), ({"kin_model": "geometric"}, "geometric"),
                       ({"feed": "accepted"}, "learned"),
                       ({"kin_model": "auto", "feed": "permissive"}, "geometric"),
                       ({"kin_model": path}, "const")]:  # fmt: skip
        env = gym.make(IDS[0], tracker=opts, noise_sigma=0.005)
        tr = env.unwrapped.tracker
        assert (tr.kin_model is None) == (want == "hand")
        if want in shipped:
            assert tr.kin_model.to_dict() == TrackKinModel.load(shipped[want]).to_dict(), opts
        if want == "hand":
            assert tr.params.p_detect == 0.7
        env.reset(seed=4)  # an episode whose learner sees the kin and obstacles in 30 random steps
        env.action_space.seed(4)
        probs = []
        for _ in range(30):
            _, _, term, trunc, info = env.step(env.action_space.sample())
            probs.append(unpad(info, "kin_tracks")["kin_prob"])
            if term or trunc:
                env.reset(seed=104)
        probs = np.concatenate(probs)
        assert probs.size > 0  # the tracker had tracks to decide on
        if want == "const":
            np.testing.assert_allclose(probs, 1 / (1 + np.exp(-5.0)), rtol=1e-6)  # float32 info slots


@pytest.mark.parametrize("tracker, match", [
    ({"kin_model": "neural"},
     r"tracker\['kin_model'\] must be one of \['learned', 'geometric', 'hand', 'auto'\].*'neural'"),
    ({"kin_model": 3}, r"tracker\['kin_model'\] must be .* got 3"),
    ({"kin_model": "hand", "bogus": 1}, r"unknown key\(s\) \['bogus'\]"),
    ({"p_detect": 2.0}, "p_detect must be in"),
    ({"feed": "all"}, r"tracker\['feed'\] must be one of \['accepted', 'permissive', 'auto'\], got 'all'"),
])  # fmt: skip
def test_bad_tracker_kin_model_or_key_raises_naming_it(tracker, match):
    from kin_envs import aggregation_v2

    with pytest.raises(ValueError, match=match):
        gym.make(IDS[0], tracker=tracker)
    with pytest.raises(ValueError, match=match):
        aggregation_v2.parallel_env(n_robots=4, tracker=tracker)


def test_swarm_env_tracker_kin_model_option(tmp_path):
    """aggregation_v2 (PettingZoo): tracker={"kin_model": path} reaches the batched tracker: every agent's
    tracks carry the model's kin probability; "hand" selects the hand-tuned fusion."""
    from kin_envs import aggregation_v2

    env = aggregation_v2.parallel_env(n_robots=6, tracker={"kin_model": _constant_model(tmp_path / "c.json")},
                                      noise_sigma=0.005)  # fmt: skip
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    probs = []
    for _ in range(10):
        _, _, _, _, infos = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        probs += [unpad(info, "kin_tracks")["kin_prob"] for info in infos.values()]
    probs = np.concatenate(probs)
    assert probs.size > 0
    np.testing.assert_allclose(probs, 1 / (1 + np.exp(-5.0)), rtol=1e-6)
    assert aggregation_v2.parallel_env(n_robots=4, tracker={"kin_model": "hand"}).tracker.kin_model is None


def _benchmark_feed(tracker, det, perm, scan, rows, delta, dt):
    """One frame fed as the sequence benchmark feeds its tracker (kin_envs.detection.sequences)."""
    from detectors.features import scan_noise, segment_batch
    from kin_envs.core.world import Scan
    from kin_envs.detection.sequences import _candidates

    r = scan.ranges[:rows]
    s = Scan(ranges=r, angles=scan.angles, hit_kind=None, hit_index=None, true_ranges=None, robots=None,
             poses=None, range_max=scan.range_max)  # fmt: skip
    ob, xy, sc, pts, own, acc = _candidates(perm.detect_batch(r, s.angles), s, det.detect_batch(r, s.angles))
    est, count = scan_noise(segment_batch(r, s.angles))
    est = np.where(count >= 5, est, np.nan)
    noise = np.where(np.isnan(est), tracker.params.range_noise, est)
    tracker.update_batch(ob, xy, sc, delta, dt, pts, own, noise, accepted=acc)
    return int(ob.size - acc.sum())


@pytest.mark.parametrize("detector", ["geometric", "learned"])
def test_permissive_feed_is_the_sequence_benchmarks_tracker(detector):
    """tracker={"feed": "permissive"}: info["kin_detections"] bitwise those of the default env, and the tracks
    bitwise those of a KinTracker fed as the sequence benchmark feeds it (permissive candidates, accepted
    flags, the scan's noise estimate) — what the track classifier is fitted on (v2: the classifier fitted on
    that detector's feed)."""
    from detectors.tracking import KinTracker
    from kin_envs.detection.benchmark import permissive

    kw = dict(detector=detector, noise_sigma=0.01, n_distractors=6, kin_like_cylinders=True, max_steps=200)
    a, b = gym.make(IDS[0], tracker={"feed": "permissive"}, **kw), gym.make(IDS[0], tracker=True, **kw)
    a.reset(seed=4)
    b.reset(seed=4)
    u = a.unwrapped
    assert u._feeder.one_call == (detector == "geometric")
    ref = KinTracker(kin_model="geometric" if detector == "geometric" else "learned")
    perm = permissive(u.detector)
    dt = u.world.config.control_dt
    _benchmark_feed(ref, u.detector, perm, u._last_scan, 1, np.zeros((1, 3)), dt)
    rng = np.random.default_rng(1)
    rejected = 0
    for _ in range(40):
        act = rng.uniform([0, -1], [1, 1])
        ia, ib = a.step(act)[4], b.step(act)[4]
        for f, c in ib["kin_detections"].items():
            np.testing.assert_array_equal(ia["kin_detections"][f], c, err_msg=f)
        rejected += _benchmark_feed(ref, u.detector, perm, u._last_scan, 1, u.world.odometry_delta[:1], dt)
        want = ref.track_arrays(16)["tracks"][0]
        for j, f in enumerate(TRACK_FIELDS):
            np.testing.assert_array_equal(ia["kin_tracks"][f], want[:, j].astype(np.float64), err_msg=f)
    assert rejected > 0  # candidates the detector rejects did reach the tracker


def test_permissive_feed_in_the_swarm_and_the_native_vector_env():
    """aggregation_v2 (all robots, one geometric call per step) and the native vector env with
    tracker={"feed": "permissive"}: the swarm's tracks are the benchmark feed's, its detections unchanged;
    the vector env's tracks those of K separate envs (across autoresets)."""
    from detectors.tracking import KinTracker
    from kin_envs import aggregation_v2
    from kin_envs.detection.benchmark import permissive

    envs = [aggregation_v2.parallel_env(n_robots=8, tracker=t, noise_sigma=0.01, max_cycles=30)
            for t in ({"feed": "permissive"}, True)]  # fmt: skip
    for e in envs:
        e.reset(seed=2)
    u = envs[0]
    ref, perm = KinTracker(n_observers=8, kin_model="geometric"), permissive(u.detector)
    dt = u.world.config.control_dt
    _benchmark_feed(ref, u.detector, perm, u._last_scan, 8, np.zeros((8, 3)), dt)
    rng = np.random.default_rng(2)
    for _ in range(12):
        acts = {ag: rng.uniform(-1, 1, 2).astype(np.float32) for ag in u.agents}
        ia, ib = envs[0].step(acts)[4], envs[1].step(acts)[4]
        _benchmark_feed(ref, u.detector, perm, u._last_scan, 8, u.world.odometry_delta, dt)
        want = ref.track_arrays(16)["tracks"]
        for i, ag in enumerate(sorted(ia, key=lambda g: int(g.split("_")[-1]))):
            for f, c in ib[ag]["kin_detections"].items():
                np.testing.assert_array_equal(ia[ag]["kin_detections"][f], c, err_msg=f)
            np.testing.assert_array_equal(ia[ag]["kin_tracks"]["x"], want[i, :, 1].astype(np.float64))
    from tests.kin_envs.envs.test_vector_env import SEEK, assert_same_as_sync

    assert_same_as_sync(SEEK, 3, 30, tracker={"feed": "permissive"}, noise_sigma=0.02, n_distractors=4,
                        max_steps=25, kin_like_cylinders=True)  # fmt: skip


def _expected_topk(info, top_k, range_max, threshold=0.5):
    """An agent's top-k detection channel rebuilt from its own info["kin_tracks"] (confirmed kin tracks,
    nearest first): [1, range / range_max, sin(bearing), cos(bearing)] per slot, zeros after."""
    t, c = info["kin_tracks"], info["kin_tracks_count"]
    keep = (t["confirmed"][:c] > 0) & (t["kin_prob"][:c] >= threshold)
    x, y = t["x"][:c][keep], t["y"][:c][keep]
    rng = np.hypot(x, y)
    order = np.argsort(rng, kind="stable")[:top_k]
    out = np.zeros(4 * top_k)
    for j, i in enumerate(order):
        b = np.arctan2(y[i], x[i])
        out[4 * j: 4 * j + 4] = 1.0, min(rng[i] / range_max, 1.0), np.sin(b), np.cos(b)
    return out


def test_swarm_env_observes_its_tracks():
    """aggregation_v2 with obs_tracks=True: every agent's detection channel holds its own confirmed kin
    tracks (rebuilt here from its info["kin_tracks"]), not its raw detections; the scan part is the same as
    without; the PettingZoo API holds and seeded runs repeat."""
    from pettingzoo.test import parallel_api_test

    from kin_envs import aggregation_v2

    kw = dict(n_robots=10, tracker=True, obs_detections="topk", obs_top_k=3, noise_sigma=0.005, max_cycles=40)
    parallel_api_test(aggregation_v2.parallel_env(**kw, obs_tracks=True), num_cycles=20)

    def run(obs_tracks):
        env = aggregation_v2.parallel_env(**kw, obs_tracks=obs_tracks)
        obs, _ = env.reset(seed=9)
        rng = np.random.default_rng(9)
        seq = []
        for _ in range(25):
            acts = {a: rng.uniform([0.2, -1], [1, 1]).astype(np.float32) for a in env.agents}
            obs, _, _, _, infos = env.step(acts)
            seq.append((obs, infos))
        return seq, env.unwrapped._obs.layout.range_max

    with_tracks, range_max = run(True)
    without, _ = run(False)
    filled = differs = 0
    for (obs, infos), (obs0, _) in zip(with_tracks, without, strict=True):
        for a, o in obs.items():
            np.testing.assert_array_equal(o[:360], obs0[a][:360])  # the same world, scans and tracks
            want = _expected_topk(infos[a], 3, range_max)
            np.testing.assert_allclose(o[360:], want, rtol=1e-5, atol=1e-6, err_msg=a)
            filled += int(want[0] == 1.0)
            differs += int(not np.array_equal(o[360:], obs0[a][360:]))
    assert filled > 20 and differs > 0  # tracks were observed, and they are not the raw detections
    again, _ = run(True)
    for (obs, _), (obs2, _) in zip(with_tracks, again, strict=True):
        for a in obs:
            np.testing.assert_array_equal(obs[a], obs2[a])


def test_housing_beams_are_the_beams_whose_rays_hit_the_housing():
    """housing_beams against the ray-circle condition, beam by beam: a ray at angle theta from the origin
    meets a circle of radius r centred at range rho, bearing beta iff |rho sin(theta - beta)| <= r and
    cos(theta - beta) > 0; at least the nearest beam when no ray meets it; either turning direction."""
    from kin_envs.core.lidar import LidarSpec
    from kin_envs.envs.tracks import housing_beams

    rng = np.random.default_rng(0)
    cw = np.asarray(LidarSpec().angles)  # beam i is i steps clockwise
    ccw = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    for angles in (cw, ccw):
        n = angles.size
        bearing = rng.uniform(-np.pi, np.pi, 400)
        rho = np.r_[rng.uniform(0.036, 0.2, 50), rng.uniform(0.2, 12.0, 350)]
        first, last, count = housing_beams(angles, bearing, rho, 0.035)
        for b, p, f, la, c in zip(bearing, rho, first, last, count, strict=True):
            d = angles - b
            hit = (np.abs(p * np.sin(d)) <= 0.035) & (np.cos(d) > 0)
            got = np.zeros(n, bool)
            got[(f + np.arange(c)) % n] = True
            assert (f + c - 1) % n == la
            if hit.any():
                np.testing.assert_array_equal(got, hit, err_msg=f"bearing {b}, range {p}")
            else:
                assert c == 1 and f == np.argmin(np.abs(np.arctan2(np.sin(d), np.cos(d))))
    with pytest.raises(ValueError, match="evenly spaced"):
        housing_beams(np.array([0.0, 0.1, 0.3]), np.zeros(1), np.ones(1), 0.035)


def test_mask_channel_of_track_observations_covers_the_kin():
    """KinFollow-v2 with obs_detections="mask" and obs_tracks=True: the mask marks the beams whose rays meet
    a housing at a reported kin track's centre (it was all zeros before: tracks have no segment beams);
    when that track sits on the kin, they are most of the beams that hit the kin's housing."""
    from kin_envs.core.lidar import HitKind

    env = gym.make(IDS[1], tracker=True, obs_detections="mask", obs_tracks=True)
    obs, _ = env.reset(seed=3)
    env.action_space.seed(3)
    angles = env.unwrapped.world.scene.lidar.angles
    on_target = reported = 0
    for _ in range(80):
        obs, _, term, trunc, info = env.step(env.action_space.sample())
        mask = obs[360:] > 0
        t, c = info["kin_tracks"], info["kin_tracks_count"]
        kin = (t["confirmed"][:c] > 0) & (t["kin_prob"][:c] >= 0.5)
        x, y = t["x"][:c][kin], t["y"][:c][kin]
        # rays from the origin meeting a 3.5 cm circle at (x, y): |rho sin(theta - beta)| <= r, in front
        d = angles[None] - np.arctan2(y, x)[:, None]
        want = ((np.abs(np.hypot(x, y)[:, None] * np.sin(d)) <= 0.035) & (np.cos(d) > 0)).any(axis=0)
        assert np.count_nonzero(mask != want) <= 1  # float32 info: a beam at the edge may flip
        reported += int(mask.any())
        scan = env.unwrapped._last_scan
        on_kin = (scan.hit_kind[0] == HitKind.ROBOT.value) & (scan.ranges[0] < scan.range_max)
        truth = unpad(info, "kin_truth")
        if kin.sum() == 1 and len(truth["x"]) and np.hypot(x - truth["x"], y - truth["y"]).min() < 0.02:
            on_target += 1
            assert (mask & on_kin).sum() >= 0.5 * on_kin.sum()
        if term or trunc:
            break
    assert reported >= 10 and on_target >= 5
