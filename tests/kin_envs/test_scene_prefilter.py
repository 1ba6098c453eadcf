"""The overlap index's bounding-circle prefilter changes no scene: every generator gives bit-identical
scenes (and the same errors) with it and with every query answered by pymunk (the previous index)."""

import functools
import math

import numpy as np
import pytest

from kin_envs.core import scenes
from kin_envs.core.scenes import Box, Cylinder, Prism, Robot, Scene, Wall
from kin_envs.envs.kin_seek import DISTRACTORS, KinSeekEnv


def _both(monkeypatch, make):
    """``make()`` with the prefilter, then with every query given to pymunk (an infinite gap)."""
    fast = _outcome(make)
    with monkeypatch.context() as m:
        m.setattr(scenes, "_PREFILTER_GAP", math.inf)
        slow = _outcome(make)
    return fast, slow


def _outcome(make):
    try:
        return make()
    except ValueError as e:
        return ("ValueError", str(e))


@pytest.mark.parametrize("seed", range(6))
def test_random_arenas_identical(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        n_robots, n_obs = int(rng.integers(0, 12)), int(rng.integers(0, 40))
        size = float(rng.uniform(1.5, 8.0))  # small sizes: many rejections, some arenas that cannot fit
        cfg = {"clearance": float(rng.choice([0.0, 0.02, 0.05, 0.2])), "max_attempts": 50}
        s = int(rng.integers(1 << 30))
        make = functools.partial(scenes.random_arena, n_robots, n_obs, seed=s, size=size, config=cfg)
        fast, slow = _both(monkeypatch, make)
        assert fast == slow


@pytest.mark.parametrize("seed", range(3))
def test_detection_scenes_identical(monkeypatch, seed):
    for s in range(seed * 20, seed * 20 + 20):
        cfg = {"n_kin": 1 + s % 4, "n_distractors": 5 + s % 20, "clearance": [0.0, 0.03, 0.1][s % 3]}
        fast, slow = _both(monkeypatch, functools.partial(scenes.detection_scene, seed=s, config=cfg))
        assert fast == slow


def test_kin_seek_layouts_identical(monkeypatch):
    env = KinSeekEnv(detector=None, n_distractors=12, arena_size=3.0)
    for s in range(60):
        fast, slow = _both(monkeypatch, lambda s=s: env._make_scene(np.random.default_rng(s)))
        assert fast == slow
    # and the default arena, its distractor mix at the default size
    for s in range(60):
        make = functools.partial(scenes.random_arena, 2, 6, seed=s, size=4.0, config=DISTRACTORS)
        fast, slow = _both(monkeypatch, make)
        assert fast == slow


def _overlapping_scene(rng) -> Scene:
    """Objects dropped anywhere in a small arena (often overlapping, touching or outside)."""
    objs = []
    for _ in range(int(rng.integers(2, 9))):
        x, y, t = (float(v) for v in rng.uniform(-1.2, 1.2, 3))
        k = int(rng.integers(4))
        if k == 0:
            objs.append(Cylinder(x=x, y=y, radius=float(rng.uniform(0.02, 0.4))))
        elif k == 1:
            objs.append(Box(x=x, y=y, width=float(rng.uniform(0.05, 0.6)), depth=0.1, theta=t))
        elif k == 2:
            objs.append(Prism(x=x, y=y, sides=int(rng.integers(3, 7)), width=0.3, theta=t))
        else:
            objs.append(Wall(x1=x, y1=y, x2=x + math.cos(t), y2=y + math.sin(t)))
    robots = tuple(Robot(float(a), float(b)) for a, b in rng.uniform(-1.2, 1.2, (int(rng.integers(0, 3)), 2)))
    return dict(robots=robots, obstacles=tuple(objs), arena=scenes.Arena(3.0, 3.0))


def test_validation_errors_identical(monkeypatch):
    """Scene validation: the same scenes accepted, the same clash named first in the error."""
    rng = np.random.default_rng(7)
    errors = 0
    for _ in range(300):
        kw = _overlapping_scene(rng)
        fast, slow = _both(monkeypatch, lambda kw=kw: Scene(**kw))
        assert fast == slow
        errors += isinstance(fast, tuple)
    # touching exactly is allowed either way: two boxes sharing an edge, a cylinder on a face
    boxes = (Box(x=0.0, y=0.0, width=0.2, depth=0.2), Box(x=0.2, y=0.0, width=0.2, depth=0.2))
    touching = dict(obstacles=(*boxes, Cylinder(x=0.0, y=0.25, radius=0.15)))
    fast, slow = _both(monkeypatch, lambda: Scene(**touching))
    assert fast == slow and isinstance(fast, Scene)
    assert 50 < errors < 290  # both kinds of outcome were exercised


def test_placed_scenes_pass_full_validation():
    """random_arena and KinSeek's thinned layouts skip the layout check (valid by construction): the
    full check accepts every one of them, dense arenas with zero clearance included."""
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(150):
        cfg = {"clearance": float(rng.choice([0.0, 0.0, 0.01, 0.05])), "max_attempts": 200}
        try:
            scene = scenes.random_arena(int(rng.integers(0, 10)), int(rng.integers(0, 40)),
                                        seed=int(rng.integers(1 << 30)), size=float(rng.uniform(2.0, 6.0)),
                                        config=cfg)  # fmt: skip
        except ValueError:
            continue
        assert scene.replace() == scene  # replace() runs the full validation
        checked += 1
    env = KinSeekEnv(detector=None, n_distractors=20, arena_size=3.0)
    for s in range(40):
        scene = env._make_scene(np.random.default_rng(s))
        assert scene.replace() == scene
    assert checked > 100
    with pytest.raises(TypeError, match="unknown fields"):
        Scene._placed(robots=(), obstacles=(), arena=scenes.Arena(), robot=scenes.RobotSpec(),
                      lidar=scenes.LidarSpec(), name="", extra=1)  # fmt: skip
    with pytest.raises(scenes.FieldTypeError, match="scene.lidar"):
        scenes.random_arena(2, 2, lidar="not a spec")


def test_footprint_cached_copies():
    """A footprint is computed once per obstacle; every call returns a fresh array."""
    box = Box(x=0.5, y=-0.2, width=0.3, depth=0.1, theta=0.4)
    kind, a = box.footprint()
    a[:] = 0.0  # the caller's copy only
    kind2, b = box.footprint()
    assert kind == kind2 == "polygon" and np.array_equal(b, Box(x=0.5, y=-0.2, width=0.3, depth=0.1,
                                                                  theta=0.4)._footprint()[1])  # fmt: skip
    assert b is not box.footprint()[1] and not np.array_equal(a, b)
    assert box == Box(x=0.5, y=-0.2, width=0.3, depth=0.1, theta=0.4)  # the cache is not a field
