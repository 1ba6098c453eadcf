"""The native vector envs (``gym.make_vec(id, K)``, issue 14.3): Gymnasium's vector API and
autoreset, and the same trajectories as K separate envs (Gymnasium's SyncVectorEnv) for the same
seeds, across autoresets."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from kin_envs.envs import register_envs, unpad_detections
from kin_envs.envs.vector import KinFollowVectorEnv, KinSeekVectorEnv

register_envs()
SEEK, FOLLOW = "kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"
QUICK = {"n_distractors": 4, "max_steps": 25, "kin_like_cylinders": True}


def assert_same_as_sync(env_id: str, k: int, steps: int, seed: int = 3, **kwargs) -> int:
    """Step the native vector env and a SyncVectorEnv of K envs with the same seed and actions;
    everything returned must be identical. Returns the number of episode ends."""
    native = gym.make_vec(env_id, num_envs=k, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec(env_id, num_envs=k, vectorization_mode="sync", **kwargs)
    assert isinstance(native.unwrapped, KinSeekVectorEnv | KinFollowVectorEnv)
    assert isinstance(sync.unwrapped, SyncVectorEnv)
    assert native.observation_space == sync.observation_space
    assert native.action_space == sync.action_space
    assert data_equivalence(native.reset(seed=seed), sync.reset(seed=seed), exact=True)
    native.action_space.seed(seed)
    ends = 0
    for t in range(steps):
        actions = native.action_space.sample()
        a, b = native.step(actions), sync.step(actions)
        for name, x, y in zip(("obs", "reward", "terminated", "truncated", "info"), a, b, strict=True):
            assert data_equivalence(x, y, exact=True), f"step {t}: {name} differs"
        ends += int(np.sum(a[2] | a[3]))
    native.close()
    sync.close()
    return ends


@pytest.mark.parametrize("env_id", [SEEK, FOLLOW])
def test_same_trajectories_as_separate_envs_across_autoresets(env_id):
    ends = assert_same_as_sync(env_id, 4, 70, noise_sigma=0.005, dropout_prob=0.01, **QUICK)
    assert ends >= 8  # every sub-env ended (and was autoreset) at least twice


@pytest.mark.parametrize(
    "kwargs",
    [
        {"obs_detections": "topk", "frame_stack": 2},
        {"obs_detections": "mask", "action_type": "discrete"},
        {"detector": None},
        {"detector": "learned", "obs_detections": "topk"},
        # one tracker over the K learners: the same tracks (ids included) as K envs' own trackers
        {"tracker": True, "noise_sigma": 0.02},
        {"tracker": {"kin_model": "hand"}, "obs_detections": "topk", "obs_tracks": True, "noise_sigma": 0.02},
        {"tracker": True, "obs_detections": "mask", "obs_tracks": True},
    ],
    ids=["topk-stack", "mask-discrete", "nodet", "learned", "tracker", "tracker-obs-hand",
         "tracker-obs-mask"],
)
def test_same_trajectories_variants(kwargs):
    assert_same_as_sync(SEEK, 3, 30, **{**QUICK, **kwargs})


@pytest.mark.parametrize("detector", ["geometric", "learned"])
def test_same_trajectories_at_one_percent_noise(detector):
    # (learned: at step 11, sub-env 0, the batch's cascade dropped a 2-beam detection scored 0.389 that the
    # one-scan call keeps, until the native env ran its batch as one-scan calls: _scans_alone)
    # the benchmark's noisy setting (issue 14's >= 10x at 1 % range noise): the K worlds' noise drawn in one
    # compiled call from their own Generators, detections on the noisy scans; autoresets within the run, and
    # a reset in between that replaces one sub-env's Generator (new addresses for the compiled draws)
    ends = assert_same_as_sync(SEEK, 4, 60, seed=11, detector=detector, noise_sigma=0.01, **QUICK)
    assert ends >= 8
    kw = dict(detector=detector, noise_sigma=0.01, dropout_prob=0.02, **QUICK)
    native = gym.make_vec(SEEK, num_envs=3, vectorization_mode="vector_entry_point", **kw)
    singles = [gym.make(SEEK, **kw) for _ in range(3)]
    native.reset(seed=20)
    for i, e in enumerate(singles):
        e.reset(seed=20 + i)
    rng = np.random.default_rng(0)
    done = np.zeros(3, bool)
    for t in range(40):
        if t == 7:  # sub-env 1 reseeded on its own: a new np_random, and so a new World.rng
            mask = np.array([False, True, False])
            obs, _ = native.reset(seed=[None, 99, None], options={"reset_mask": mask})
            assert np.array_equal(singles[1].reset(seed=99)[0], obs[1])
            done[1] = False
        a = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        obs, rew, term, trunc, _ = native.step(a)
        for i, e in enumerate(singles):
            if done[i]:  # NEXT_STEP autoreset: this step resets it
                o = e.reset()[0]
            else:
                o, r, te, tr, _ = e.step(a[i])
                assert (r, te, tr) == (rew[i], term[i], trunc[i])
            assert np.array_equal(o, obs[i]), (t, i)
        done = term | trunc
    native.close()


def test_vector_api_and_autoreset_mode():
    env = gym.make_vec(SEEK, num_envs=3)  # the registered vector entry point is the default
    u = env.unwrapped
    assert isinstance(u, KinSeekVectorEnv) and env.num_envs == 3
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.single_observation_space == gym.make(SEEK).observation_space
    assert env.observation_space.shape == (3, 360) and env.action_space.shape == (3, 2)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and info["kin_truth_count"].shape == (3,)
    assert info["kin_detections"]["range"].shape == (3, 16) and info["_kin_detections"].all()
    assert len(unpad_detections(info)) == 3
    # Gymnasium's vector wrappers accept it (they check the autoreset mode)
    wrapped = gym.wrappers.vector.RecordEpisodeStatistics(
        gym.wrappers.vector.NormalizeObservation(env)
    )
    wrapped.reset(seed=1)
    done_seen = False
    for _ in range(301):
        obs, rew, term, trunc, info = wrapped.step(wrapped.action_space.sample())
        assert obs.shape == (3, 360) and rew.dtype == np.float64 and term.dtype == np.bool_
        if "episode" in info:
            done_seen = True
            assert np.all(info["episode"]["l"][info["_episode"]] <= 300)
    assert done_seen
    env.close()


def test_next_step_autoreset_ignores_the_action_and_returns_the_reset():
    env = KinSeekVectorEnv(num_envs=2, max_steps=3, detector=None)
    obs0, _ = env.reset(seed=5)
    for _ in range(3):
        obs, rew, term, trunc, _ = env.step(np.zeros((2, 2), np.float32))
    assert trunc.all() and not term.any()
    obs, rew, term, trunc, info = env.step(np.full((2, 2), np.nan, np.float32))  # ignored: resets
    assert np.all(rew == 0) and not (term | trunc).any()
    assert info["reward_terms"]["progress"].tolist() == [0.0, 0.0]  # the reset info
    single = gym.make(SEEK, max_steps=3, detector=None)
    single.reset(seed=5)
    for _ in range(3):
        single.step(np.zeros(2, np.float32))
    assert np.array_equal(single.reset()[0], obs[0])  # the sub-env's next episode


def test_reset_mask_and_seeds():
    env = KinSeekVectorEnv(num_envs=3, detector=None)
    with pytest.raises(ValueError, match="first reset must reset every sub-env"):
        env.reset(options={"reset_mask": np.array([True, False, False])})
    a, _ = env.reset(seed=[7, 8, 9])
    b, _ = env.reset(seed=7)  # int: sub-env i gets seed + i
    assert np.array_equal(a, b)
    env.step(np.ones((3, 2), np.float32))
    mask = np.array([False, True, False])
    obs, info = env.reset(seed=[None, 8, None], options={"reset_mask": mask})
    assert np.array_equal(obs[1], a[1]) and not np.array_equal(obs[0], a[0])
    assert info["_kin_truth"].tolist() == mask.tolist()
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(options={"reset_mask": np.zeros(3, bool)})
    with pytest.raises(ValueError, match="list of 3 seeds"):
        env.reset(seed=[1, 2])


def test_bad_input_raises_clear_errors():
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
        KinSeekVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="render_mode"):
        KinSeekVectorEnv(num_envs=1, render_mode="human")
    with pytest.raises(TypeError, match="unknown argument"):
        KinSeekVectorEnv(num_envs=1, colour="red")
    env = KinSeekVectorEnv(num_envs=2, detector=None)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((2, 2)))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        env.step(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"actions\[1\] must be finite"):
        env.step(np.array([[0, 0], [np.nan, 0]]))
    disc = KinSeekVectorEnv(num_envs=2, detector=None, action_type="discrete")
    disc.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions\[0\] must be an integer"):
        disc.step(np.array([7, 0]))


def test_one_detector_call_and_one_detector_object_for_all_sub_envs():
    class Counting:
        def __init__(self):
            from detectors import GeometricKinDetector

            self.inner, self.batches = GeometricKinDetector(reports=False), []

        def detect(self, ranges, angles):
            return self.inner.detect(ranges, angles)

        def detect_batch(self, ranges, angles):
            self.batches.append(np.asarray(ranges).shape)
            return self.inner.detect_batch(ranges, angles)

    det = Counting()
    env = KinSeekVectorEnv(num_envs=5, detector=det)
    assert all(e.detector is det for e in env.envs)
    env.reset(seed=0)
    det.batches.clear()
    env.step(np.zeros((5, 2), np.float32))
    assert det.batches == [(5, 360)]


def test_render_rgb_array():
    pytest.importorskip("pygame")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = KinSeekVectorEnv(num_envs=2, render_mode="rgb_array", render_size=64)
        env.reset(seed=0)
        env.step(np.zeros((2, 2), np.float32))
        frames = env.render()
    assert len(frames) == 2 and frames[0].shape[2] == 3
    env.close()


def test_detection_glue_reads_a_compact_array_result():
    """``detection_arrays`` (the env's one reader of detector output) takes a ``detect_arrays``
    result as it takes ``DetectionResult`` objects."""
    import types

    from detectors import GeometricKinDetector
    from kin_envs import World, scenes
    from kin_envs.envs.common import detection_arrays

    det = GeometricKinDetector(reports=False)

    class ArrayDetector:
        def detect_arrays(self, ranges, angles):
            rows = [(b, d) for b, r in enumerate(det.detect_batch(ranges, angles)) for d in r.detections]
            col = {f: np.array([getattr(d, f) for _, d in rows])
                   for f in ("range", "bearing", "x", "y", "score", "first_beam", "last_beam", "n_beams")}
            col["n_beams_on"] = col.pop("n_beams")
            return types.SimpleNamespace(scan=np.array([b for b, _ in rows], dtype=np.int64), **col)

    class DictDetector(ArrayDetector):  # the beam detector's form: a dict with "n_beams"
        def detect_arrays(self, ranges, angles):
            cols = dict(vars(super().detect_arrays(ranges, angles)))
            cols["n_beams"] = cols.pop("n_beams_on")
            return cols

    scan = World(scenes.random_arena(16, 10, seed=1), seed=0).scan()
    row_a, tab_a = detection_arrays(det, scan.ranges, scan.angles)
    for stub in (ArrayDetector(), DictDetector()):
        row_b, tab_b = detection_arrays(stub, scan.ranges, scan.angles)
        assert len(row_a) > 5 and np.array_equal(row_a, row_b) and np.array_equal(tab_a, tab_b)


def test_same_trajectories_with_integer_reward_weights():
    # an int weight makes int reward terms in _task's info (stacked as int64 when sub-env 0's is):
    # the vector env then finishes its sub-envs one by one instead of KinSeek's _task_batch columns
    assert_same_as_sync(SEEK, 3, 40, **{**QUICK, "success_bonus": 10, "collision_penalty": 1,
                                        "success_distance": 1.0, "min_start_distance": 1.05})  # fmt: skip
