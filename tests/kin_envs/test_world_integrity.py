"""Issue 16 at the world level: copies of a world in a pile-up, no native memory growth over resets,
robot-robot penetration in 64-robot jams, huge commands, seeds and scan indices."""

from __future__ import annotations

import copy
import os
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from kin_envs import World, WorldConfig, scenes
from kin_envs.core._validate import FieldTypeError


def _to_centre(poses: np.ndarray) -> np.ndarray:
    """Top-speed commands steering every robot at the arena centre (a pile-up)."""
    err = np.arctan2(-poses[:, 1], -poses[:, 0]) - poses[:, 2]
    return np.c_[np.full(len(poses), 1.0), 4.0 * np.arctan2(np.sin(err), np.cos(err))]


def test_world_copy_is_exact_in_a_jam():
    """The contact solver's warm start matters in a pile-up; a copy must still agree bit for bit."""
    world = World(scenes.random_arena(64, 0, seed=1, size=3.5), seed=0)
    for _ in range(30):
        world.step(commands=_to_centre(world.poses))
    assert (world.contacts != 0).sum() > 10  # really a jam
    for twin in (copy.deepcopy(world), pickle.loads(pickle.dumps(world))):
        assert twin.time == world.time and twin.rng is not world.rng
        for _ in range(10):
            twin.step(commands=_to_centre(twin.poses))
        np.testing.assert_array_equal(twin.contacts, (ref := copy.deepcopy(world), [ref.step(
            commands=_to_centre(ref.poses)) for _ in range(10)])[0].contacts)
        np.testing.assert_array_equal(twin.poses, ref.poses)
        np.testing.assert_array_equal(twin.scan().ranges, ref.scan().ranges)


def test_copy_of_a_copy_is_exact():
    """The replay log is rebuilt in the copy, so a copy can be copied again (before, the copy's log was
    empty and its own copies restarted from the scene)."""
    world = World(scenes.random_arena(8, 5, seed=1, size=4.0), seed=0)
    rng = np.random.default_rng(0)
    for t in range(30):
        world.step(commands=rng.uniform(-1, 1, (8, 2)) if t % 5 == 0 else np.tile([0.3, 0.5], (8, 1)))
    twice = pickle.loads(pickle.dumps(copy.deepcopy(world)))
    for w in (world, twice):
        for _ in range(5):
            w.step(commands=np.tile([0.2, -0.4], (8, 1)))
    np.testing.assert_array_equal(twice.poses, world.poses)
    np.testing.assert_array_equal(twice.scan().ranges, world.scan().ranges)


def test_copy_log_stores_each_held_command_once():
    """Issue 16 (point 5): the log grows with changes of the commands, not with steps."""
    world = World(scenes.random_arena(16, 5, seed=2, size=4.0), seed=0)
    held = np.tile([0.3, 0.2], (16, 1))
    for t in range(300):
        world.step(commands=held if t < 200 else -held)
    state = world.__getstate__()
    assert state["history"].shape == (2, 16, 2) and state["history_counts"].tolist() == [200, 100]
    assert len(pickle.dumps(world)) < 20_000  # 300 steps x 16 robots x 16 B unencoded: 77 kB of log alone
    twin = pickle.loads(pickle.dumps(world))
    np.testing.assert_array_equal(twin.poses, world.poses)
    # -0.0 and 0.0 compare equal but are different bits: runs are split on bits, so a replay is exact
    w = World(scenes.random_arena(2, 0, seed=0, size=2.0))
    w._record(np.zeros((2, 2)))
    w._record(np.array([[-0.0, 0.0], [0.0, 0.0]]))
    assert w.__getstate__()["history_counts"].tolist() == [1, 1]


SOAK = """
import gc, resource, numpy as np
from kin_envs import World, scenes
scene = scenes.random_arena(64, 20, seed=0)
cmd = np.tile([0.3, 0.5], (64, 1))
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()
def reset(i):  # what an env's reset does natively: build a world, step it, scan
    w = World(scene, seed=i)
    w.step(commands=cmd)
    w.scan()
for i in range(50):
    reset(i)
gc.collect()  # pending cyclic garbage (old worlds) is not a leak
points = []
for b in range({blocks}):
    for i in range({per_block}):
        reset(i)
    gc.collect()
    points.append(rss())
# the allocator makes RSS jitter by ~1 MB either way: fit the growth per reset over all blocks
x = np.arange(1, len(points) + 1) * {per_block}
print(np.polyfit(x, np.array(points, float), 1)[0])
"""


def test_resets_do_not_grow_native_memory():
    """Issue 16: 10.7 MB per 1,000 resets at 64 robots (pymunk never frees a batch Buffer). Budget:
    5 MB per 2,000 resets. CI runs 400 resets in 10 blocks and fits RSS's growth per reset (RSS itself
    jitters by ~1 MB); KIN_SOAK_RESETS=2000 for the full soak."""
    n = int(os.environ.get("KIN_SOAK_RESETS", "400"))
    blocks = 10
    code = textwrap.dedent(SOAK.format(blocks=blocks, per_block=max(1, n // blocks)))
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=900, check=True
    )
    per_reset = float(out.stdout.split()[-1])
    # the fitted slope of 400 resets scatters from 0.9 to 2.9 kB per reset between runs (one ~1 MB
    # jump of the allocator moves it), so the reduced run's budget is 5 kB: still less than half the
    # old leak (11.5 kB); the full soak keeps the 2.5 kB (5 MB per 2,000 resets)
    budget = 2.5e3 if n >= 2000 else 5e3
    assert per_reset < budget, f"RSS grows {per_reset / 1e3:.2f} kB per reset (budget {budget / 1e3} kB)"


@pytest.mark.parametrize("huge", [1e308, -1e308, 1.7e308, 1e20])
def test_huge_finite_commands_never_make_nan_poses(huge):
    world = World(scenes.random_arena(4, 5, seed=0, size=3.0), seed=0)
    for cmd in ([[huge, 0.0]] * 4, [[0.0, huge]] * 4, [[huge, -huge]] * 4, [[huge, 1.0]] * 4):
        world.step(commands=cmd)
        assert np.isfinite(world.poses).all() and np.isfinite(world.commands).all()
        assert np.all(np.abs(world.unicycle_to_wheel_speeds(world.commands)) <= 10.0 + 1e-9)
        world.step(wheel_speeds=cmd)
        assert np.isfinite(world.poses).all()
    assert np.isfinite(world.scan().ranges).all()
    # the same direction as a merely large command: the ratio v : omega is kept
    a = World(scenes.random_arena(4, 5, seed=0, size=3.0))
    a.step(commands=[[huge, huge / 4]] * 4)
    np.testing.assert_allclose(a.commands[:, 1] / a.commands[:, 0], 0.25)


@pytest.mark.parametrize("commands, match", [
    ([["a", 0.0]] * 2, "commands must be an"),
    ([[1j, 0.0]] * 2, "commands"),
    ([[None, 0.0]] * 2, "commands"),
])
def test_bad_commands_name_the_argument(commands, match):
    world = World(scenes.random_arena(2, 0, seed=0, size=2.0))
    with pytest.raises(ValueError, match=match):
        world.step(commands=commands)


@pytest.mark.parametrize("seed", ["abc", 1.5, True, -1, [1, 2]])
def test_bad_seed_is_refused_naming_it(seed):
    with pytest.raises(ValueError, match="seed"):
        World(scenes.random_arena(2, 0, seed=0, size=2.0), seed=seed)


def test_scan_refuses_non_integer_robot_indices():
    world = World(scenes.random_arena(3, 0, seed=0, size=2.0))
    with pytest.raises(FieldTypeError, match="integer robot indices"):
        world.scan(robots=[1.7])
    with pytest.raises(TypeError):
        world.scan(robots=[True])
    assert world.scan(robots=[]).ranges.shape == (0, 360)


@pytest.mark.parametrize("kwargs, match", [
    ({"iterations": 2.5}, "iterations must be an integer"),
    ({"iterations": 0}, "iterations"),
    ({"control_dt": "0.1"}, "control_dt must be a finite number"),
    ({"physics_dt": None}, "physics_dt"),
    ({"floor_friction": True}, "floor_friction"),
    ({"control_dt": 1e6}, "control_dt"),
])
def test_world_config_names_the_bad_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        WorldConfig(**kwargs)


def _max_penetration(world: World) -> float:
    p = world.poses[:, :2]
    d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return float(2 * world.scene.robot.body_radius - d.min())


@pytest.mark.parametrize("seed", [0, 1])
def test_robots_never_overlap_a_centimetre_in_a_64_robot_jam(seed):
    """Issue 16: up to 1.28 cm robot-robot penetration in 64-robot jams at top speed. Measured over
    8 jams x 500 steps: max 0.63 cm with physics_dt=0.01 (tested here, reduced to 2 x 120 steps);
    the default physics_dt=0.02 reaches 1.03-1.23 cm in 1-2 of 4,000 steps (README, World)."""
    world = World(scenes.random_arena(64, 0, seed=seed, size=3.5), seed=seed,
                  config=WorldConfig(physics_dt=0.01))
    worst = 0.0
    for _ in range(120):
        world.step(commands=_to_centre(world.poses))
        worst = max(worst, _max_penetration(world))
    assert worst < 0.01, f"robots overlap by {worst * 100:.2f} cm"
