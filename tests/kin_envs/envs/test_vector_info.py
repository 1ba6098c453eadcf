"""Fixed-shape info (issue 15.1): every info entry keeps one shape on every step, so Gymnasium's
vector envs (sync / async), SB3's DummyVecEnv / SubprocVecEnv and RLlib (two envs per runner)
run the envs with the detector on through autoresets; the variable-length view is unchanged."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

from kin_envs import aggregation_v0, aggregation_v2
from kin_envs.envs import register_envs, unpad_detections, unpad_kin_truth
from kin_envs.envs.info import DETECTION_FIELDS, KIN_TRUTH_FIELDS, PAD_VALUES, pad_rows, unpad

register_envs()
V1 = ["kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"]
# small and quick: short episodes so that 300 steps cross several autoresets
SMALL = {"n_distractors": 4, "max_steps": 40, "kin_like_cylinders": True, "detector": "geometric"}


def shapes(tree) -> dict:
    """``{key path: (shape, dtype)}`` of every leaf of an info."""
    out = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update({f"{k}/{kk}": vv for kk, vv in shapes(v).items()})
        else:
            a = np.asarray(v)
            out[k] = (a.shape, a.dtype)
    return out


def test_pad_and_unpad_round_trip():
    row = np.array([0, 0, 0, 2])
    cols = {"range": np.array([1.0, 2.0, 3.0, 4.0]), "kin_index": np.array([1, -1, 3, 5])}
    padded, count = pad_rows(row, cols, 3, 2)
    assert count.tolist() == [2, 0, 1]  # the farthest of row 0 does not fit
    assert padded["range"].tolist() == [[1, 2], [0, 0], [4, 0]]
    assert padded["kin_index"].tolist() == [[1, -1], [-1, -1], [5, -1]]
    one = {"kin_detections": {k: v[2] for k, v in padded.items()}, "kin_detections_count": 1}
    assert {k: v.tolist() for k, v in unpad_detections(one).items()} == {"range": [4.0], "kin_index": [5]}
    stacked = {"kin_detections": {**padded, "_range": np.ones(3, bool)}, "kin_detections_count": count}
    per_env = unpad(stacked, "kin_detections")
    assert [d["range"].tolist() for d in per_env] == [[1, 2], [], [4]] and "_range" not in per_env[0]
    assert unpad_kin_truth({}) is None
    ragged = {"kin_truth": {"index": np.array([3])}}  # v0 layout: returned as it is
    assert unpad_kin_truth(ragged) is ragged["kin_truth"]


def test_one_row_fast_paths_match_the_general_ones():
    # pad_rows with one row (KinSeek/KinFollow) against the same row inside a two-row call
    for n in (0, 1, 3, 5):
        row = np.zeros(n, dtype=np.int64)
        cols = {"range": np.arange(n, dtype=float) + 1.0, "kin_index": np.arange(n) - 1}
        one, c1 = pad_rows(row, cols, 1, 3)
        two, c2 = pad_rows(np.concatenate([row, [1]]), {k: np.append(v, 9) for k, v in cols.items()}, 2, 3)
        assert c1.tolist() == [min(n, 3)] == c2[:1].tolist()
        for k in cols:
            assert one[k].dtype == two[k].dtype and np.array_equal(one[k][0], two[k][0]), (n, k)

    # detect_rows with nothing detected: same fields, dtypes and shapes as with detections
    from kin_envs.envs.common import detect_rows

    class Fixed:
        def __init__(self, d):
            self.d = d

        def detect_arrays(self, ranges, angles):
            return {k: np.array(v, dtype=float) for k, v in self.d.items()}

    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    some = {"scan": [0], "range": [1.0], "bearing": [0.0], "x": [1.0], "y": [0.0], "score": [0.9],
            "first_beam": [3], "last_beam": [5], "n_beams": [3]}  # fmt: skip
    ranges, angles = np.ones((1, 8)), np.linspace(0, 6, 8)
    row_s, got_s = detect_rows(Fixed(some), ranges, angles, np.array([0]), poses)
    row_e, got_e = detect_rows(Fixed({k: [] for k in some}), ranges, angles, np.array([0]), poses)
    assert got_s["kin_index"].tolist() == [1] and row_s.dtype == row_e.dtype and row_e.shape == (0,)
    assert list(got_e) == list(got_s) == list(DETECTION_FIELDS)
    assert all(got_e[k].dtype == got_s[k].dtype and got_e[k].shape == (0,) for k in got_s)


@pytest.mark.filterwarnings("ignore:.*The environment kin_envs/.* is out of date")  # v0 on purpose
@pytest.mark.parametrize("env_id", V1)
def test_info_has_one_shape_and_unpads_to_v0(env_id):
    """Same seed: v1's info without its empty slots is v0's info, and v1's shapes never change."""
    kw = {**SMALL, "obs_detections": "topk"}
    new, old = gym.make(env_id, **kw), gym.make(env_id.replace("-v2", "-v0"), **kw)
    new.action_space.seed(1)
    ref = None
    out_new, out_old = new.reset(seed=4), old.reset(seed=4)
    seen = 0
    for t in range(120):
        (obs, info), (obs0, info0) = (out_new[0], out_new[-1]), (out_old[0], out_old[-1])
        assert np.array_equal(obs, obs0)
        ref = ref or shapes(info)
        assert shapes(info) == ref, t
        assert tuple(info["kin_truth"]) == KIN_TRUTH_FIELDS
        assert tuple(info["kin_detections"]) == DETECTION_FIELDS
        for key in ("kin_truth", "kin_detections"):
            assert data_equivalence(unpad(info, key), info0[key], exact=True), (t, key)
            n = info[f"{key}_count"]
            for f, v in info[key].items():  # empty slots hold the documented pad values
                assert np.all(v[n:] == PAD_VALUES.get(f, 0))
        seen += info["kin_detections_count"]
        a = new.action_space.sample()
        out_new, out_old = new.step(a), old.step(a)
        if out_new[2] or out_new[3]:
            out_new, out_old = new.reset(), old.reset()
    assert seen > 0  # the detector found something, so non-empty slots were compared too


def test_aggregation_v2_fixed_shapes_and_v0_equivalence():
    kw = {"n_robots": 6, "max_cycles": 20, "max_kin_truth": 3, "max_detections": 4}
    new, old = aggregation_v2.parallel_env(**kw), aggregation_v0.parallel_env(**kw)
    obs, infos = new.reset(seed=2)
    _, infos0 = old.reset(seed=2)
    ref = shapes(infos["robot_0"])
    assert ref["kin_truth/index"][0] == (3,) and ref["kin_detections/range"][0] == (4,)
    rng = np.random.default_rng(0)
    for _ in range(15):
        for a in new.possible_agents:
            assert shapes(infos[a]) == ref
            for key, cap in (("kin_truth", 3), ("kin_detections", 4)):
                full = infos0[a][key]
                part = unpad(infos[a], key)
                assert infos[a][f"{key}_count"] == min(len(full["range"]), cap)
                # the nearest ``cap`` entries are kept
                assert data_equivalence(part, {f: v[:cap] for f, v in full.items()}, exact=True)
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in new.agents}
        _, _, _, _, infos = new.step(acts)
        _, _, _, _, infos0 = old.step(acts)


def run_vector(envs, steps: int = 300) -> int:
    """Step a Gymnasium vector env with random actions; every info leaf keeps its shape."""
    obs, info = envs.reset(seed=0)
    envs.action_space.seed(0)
    ref, ends = shapes(info), 0
    for _ in range(steps):
        obs, _, term, trunc, info = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(obs)
        assert shapes(info) == ref
        ends += int(np.sum(term | trunc))
    envs.close()
    return ends


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("env_id", V1)
def test_gymnasium_vector_envs_with_detector_through_autoresets(env_id, mode):
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode=mode, **SMALL)
    assert run_vector(envs) >= 2 * (300 // 40) - 2  # several autoresets per sub-env


@pytest.mark.filterwarnings("ignore:.*The environment kin_envs/.* is out of date")  # v0 on purpose
def test_the_v0_info_is_what_broke_vector_envs():
    """Why v1 exists: v0's ragged info cannot be stacked once the number of detections changes."""
    envs = gym.make_vec("kin_envs/KinSeek-v0", num_envs=2, vectorization_mode="sync", **SMALL)
    with pytest.raises(ValueError, match="could not broadcast"):
        run_vector(envs)


@pytest.mark.parametrize("vec", ["dummy", "subproc"])
def test_sb3_vec_envs_with_detector_through_autoresets(vec):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls = DummyVecEnv if vec == "dummy" else SubprocVecEnv
    # "module:id" makes gym.make import kin_envs in SubprocVecEnv's fresh worker processes
    envs = make_vec_env("kin_envs:kin_envs/KinSeek-v2", n_envs=2, seed=0, vec_env_cls=cls, env_kwargs=SMALL)
    envs.reset()
    ref, ends = None, 0
    rng = np.random.default_rng(0)
    for _ in range(300):
        _, _, dones, infos = envs.step(rng.uniform(-1, 1, (2, 2)).astype(np.float32))
        ends += int(dones.sum())
        for info in infos:
            info = {k: v for k, v in info.items() if k not in ("terminal_observation", "episode",
                                                                 "TimeLimit.truncated")}
            ref = ref or shapes(info)
            assert shapes(info) == ref
    envs.close()
    assert ends >= 2 * (300 // 40) - 2


@pytest.mark.distributed
@pytest.mark.parametrize("mode", ["sync", "vector_entry_point"])
def test_rllib_two_envs_per_env_runner_with_detector(mode):
    """RLlib vectorises each runner's envs with ``gym.make_vec`` (Gymnasium's SyncVectorEnv by
    default, or the native vector env): 320 steps across autoresets, detector on."""
    pytest.importorskip("ray", reason="ray is not installed here; run in .venv-ray")
    import ray
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        config = (
            PPOConfig()
            .environment("kin_envs/KinSeek-v2", env_config=SMALL)
            .env_runners(num_env_runners=0, num_envs_per_env_runner=2,
                         gym_env_vectorize_mode=mode)
            .training(train_batch_size_per_learner=320, minibatch_size=160, num_epochs=1)
            .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=[16]))
            .learners(num_learners=0)
            .debugging(seed=0)
        )
        algo = config.build_algo()
        result = algo.train()
        algo.stop()
    finally:
        ray.shutdown()
    runner = result[ENV_RUNNER_RESULTS]
    assert runner[NUM_ENV_STEPS_SAMPLED_LIFETIME] >= 300
    assert runner["num_episodes_lifetime"] >= 2  # episodes of 40 steps ended inside the runner


def test_aggregation_v2_passes_pettingzoo_api_tests():
    from pettingzoo.test import api_test, parallel_api_test

    par = aggregation_v2.parallel_env(n_robots=4, max_cycles=30)
    assert par.metadata["name"] == "aggregation_v2"
    parallel_api_test(par, num_cycles=40)
    api_test(aggregation_v2.env(n_robots=4, max_cycles=30), num_cycles=40)
    with pytest.raises(RuntimeError, match="aggregation_v2: call reset"):
        aggregation_v2.parallel_env(n_robots=3).step({})
    with pytest.raises(RuntimeError, match="aggregation_v0: call reset"):
        aggregation_v0.parallel_env(n_robots=3).step({})


def test_kinseek_one_row_detect_rows_equals_the_general_path():
    pytest.importorskip("torch")
    from kin_envs.envs.common import detect_rows

    env = gym.make("kin_envs/KinSeek-v2", detector="learned")
    env.reset(seed=1)
    u, n_det = env.unwrapped, 0
    env.action_space.seed(1)
    for _ in range(80):
        *_, te, tr, _ = env.step(env.action_space.sample())
        if te or tr:
            env.reset()
        s, poses = u._last_scan, u.world.poses
        args = (u.detector, s.ranges[:1], s.angles, s.robots[:1], poses)
        r1, c1 = detect_rows(*args, trusted=True)  # the one-row fast path, trusted detector entry
        r2, c2 = detect_rows(*args, robot_world=np.zeros(len(poses), int))  # the general path
        assert np.array_equal(r1, r2) and list(c1) == list(c2)
        assert all(c1[k].dtype == c2[k].dtype and np.array_equal(c1[k], c2[k]) for k in c1)
        n_det += len(r1)
    assert n_det > 0
    env.close()
