"""``import kin_envs`` (and making the envs without rendering) must not import torch or pygame."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import sys
import kin_envs
import kin_envs.aggregation_v2
from kin_envs.envs import register_envs
register_envs()
heavy = sorted(m for m in ("torch", "pygame") if m in sys.modules)
assert not heavy, f"import kin_envs imported {heavy}"

import gymnasium
for env_id in ("kin_envs/KinSeek-v2", "kin_envs/KinFollow-v2"):
    env = gymnasium.make(env_id)  # default detector="geometric"
    env.reset(seed=0)
    env.step(env.action_space.sample())
par = kin_envs.aggregation_v2.parallel_env(n_robots=2)
par.reset(seed=0)
heavy = sorted(m for m in ("torch", "pygame") if m in sys.modules)
assert not heavy, f"making the envs imported {heavy}"
"""


def test_import_is_light():
    r = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_register_is_idempotent():
    import gymnasium

    from kin_envs.envs import ENV_IDS, register_envs

    register_envs()
    register_envs()
    for env_id, entry_point in ENV_IDS.items():
        assert gymnasium.spec(env_id).entry_point == entry_point
