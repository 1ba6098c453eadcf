"""The native vector env's resets run with the cyclic GC paused: its state is restored however they
end, and the burst of resets gives what SyncVectorEnv gives."""

from __future__ import annotations

import gc

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

from kin_envs.envs import register_envs

register_envs()
QUICK = {"n_distractors": 5, "max_steps": 6, "detector": None}


def test_gc_state_restored_after_resets_and_autoresets():
    env = gym.make_vec("kin_envs/KinSeek-v2", num_envs=3, vectorization_mode="vector_entry_point", **QUICK)
    was = gc.isenabled()
    try:
        for enabled in (True, False):
            (gc.enable if enabled else gc.disable)()
            env.reset(seed=1)
            assert gc.isenabled() is enabled
            for _ in range(8):  # every sub-env truncates at step 6 and autoresets at step 7
                env.step(np.zeros((3, 2), np.float32))
                assert gc.isenabled() is enabled
        # a sub-env whose reset raises: the GC is still restored
        gc.enable()
        sub = env.unwrapped.envs[1]

        def broken(**kwargs):
            raise RuntimeError("broken reset")

        sub.reset = broken
        with pytest.raises(RuntimeError, match="broken reset"):
            env.reset(seed=2)
        assert gc.isenabled()
    finally:
        (gc.enable if was else gc.disable)()
        env.close()


@pytest.mark.parametrize("seed", [0, 11, 123])
def test_reset_bursts_match_sync(seed):
    """All K sub-envs truncating together (the burst) over several episodes, random seeds and actions,
    with the default distractor mix and lidar noise: the same as K separate envs, bit for bit."""
    kw = {"max_steps": 5, "detector": None, "noise_sigma": 0.01}
    native = gym.make_vec("kin_envs/KinSeek-v2", num_envs=6, vectorization_mode="vector_entry_point", **kw)
    sync = gym.make_vec("kin_envs/KinSeek-v2", num_envs=6, vectorization_mode="sync", **kw)
    assert data_equivalence(native.reset(seed=seed), sync.reset(seed=seed), exact=True)
    rng = np.random.default_rng(seed)
    for t in range(4 * 6 + 2):  # four bursts of six autoresets
        actions = rng.uniform(-1, 1, (6, 2)).astype(np.float32)
        a, b = native.step(actions), sync.step(actions)
        assert data_equivalence(a, b, exact=True), f"step {t}"
    native.close()
    sync.close()
