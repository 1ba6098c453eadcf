"""Scenes as data: built-in geometry, round trips, random generation, validation errors."""

import json
import math

import numpy as np
import pytest

from kin_envs import World, scenes
from kin_envs.core.lidar import LidarSpec
from kin_envs.scenes import Arena, Box, Cylinder, Polygon, Prism, Robot, Scene, Wall


@pytest.mark.parametrize("distance", scenes.PAPER_DISTANCES)
@pytest.mark.parametrize("number", [1, 2])
def test_paper_scenarios_geometry(number, distance):
    scene = scenes.paper_scenario(number, distance=distance)
    observer, kin = scene.robots
    assert (observer.x, observer.y, observer.theta) == (0.0, 0.0, 0.0)
    assert kin.x == pytest.approx(distance) and kin.y == pytest.approx(0.0, abs=1e-12)
    # every object on the same arc, spread symmetrically, kin in the middle
    bearings = sorted(math.atan2(o.y, o.x) for o in scene.obstacles)
    for o in scene.obstacles:
        assert math.hypot(o.x, o.y) == pytest.approx(distance)
    assert sum(b < 0 for b in bearings) == sum(b > 0 for b in bearings)
    # layout rule: each distractor centred between the two beams around its nominal bearing
    # (spacing 30 deg for I, 20 deg for II), moved away from the kin: +-30.5, +-60.5 deg ...
    spacing = 30.0 if number == 1 else 20.0
    half = len(bearings) // 2
    nominal = [spacing * k for k in range(-half, 0)] + [spacing * k for k in range(1, half + 1)]
    want = [n + math.copysign(0.5, n) for n in nominal]
    np.testing.assert_allclose(np.degrees(bearings), want, atol=1e-9)
    if number == 1:
        radii = [o.radius for o in sorted(scene.obstacles, key=lambda o: math.atan2(o.y, o.x))]
        assert radii == [0.03, 0.05, 0.09, 0.11]  # right to left, as in figure 10
    else:
        # every distractor is 7 cm wide: vertices on the 3.5 cm circle, or a 7 x 7 cm cuboid
        kinds = [o.kind for o in sorted(scene.obstacles, key=lambda o: math.atan2(o.y, o.x))]
        assert kinds == ["prism", "prism", "box", "cylinder", "prism", "prism"]  # right to left
        for o in scene.obstacles:
            if o.kind == "cylinder":
                assert o.radius == scene.robot.housing_radius
                continue
            v = o.footprint()[1] - (o.x, o.y)
            if o.kind == "box":
                assert (o.width, o.depth) == (0.07, 0.07)
            else:
                np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), 0.035)
            # a flat face squarely towards the observer: the two nearest vertices are equally far
            # and their edge's midpoint lies on the line of sight
            near = np.argsort(np.hypot(v[:, 0] + o.x, v[:, 1] + o.y))[:2]
            p, q = v[near] + (o.x, o.y)
            assert np.hypot(*p) == pytest.approx(np.hypot(*q), abs=1e-12)
            m = (p + q) / 2
            assert m[0] * o.y - m[1] * o.x == pytest.approx(0.0, abs=1e-12)
        sides = [o.sides for o in sorted(scene.obstacles, key=lambda o: math.atan2(o.y, o.x))
                 if o.kind == "prism"]
        assert sides == [6, 3, 5, 6]  # right to left, as in figure 11
        # the same-radius cylinder stands just left of the kin
        left = min((o for o in scene.obstacles if o.y > 0), key=lambda o: o.y)
        assert left.kind == "cylinder"


def test_paper_scenario_between_beams_for_any_resolution():
    lidar = LidarSpec(n_beams=720)  # 0.5 deg: 20 deg -> 20.25 deg
    scene = scenes.paper_scenario(2, distance=0.8, lidar=lidar)
    deg = sorted(math.degrees(math.atan2(o.y, o.x)) for o in scene.obstacles)
    np.testing.assert_allclose(deg, [-60.25, -40.25, -20.25, 20.25, 40.25, 60.25], atol=1e-9)
    assert scene.lidar is lidar


def test_paper_scenario_seen_by_observer():
    """Every object of Scenario II is hit by the observer's lidar at 1.2 m."""
    world = World(scenes.paper_scenario(2, distance=1.2))
    scan = world.scan()
    hit = set(scan.hit_index[0][scan.hit_kind[0] >= scenes.Cylinder.hit_kind].tolist())
    assert hit == set(range(6))
    assert scan.visible_robots(0).keys() == {1}


def test_paper_scenario_errors():
    with pytest.raises(ValueError, match="number must be 1 or 2"):
        scenes.paper_scenario(3)
    with pytest.raises(ValueError, match="overlaps"):
        scenes.paper_scenario(1, distance=0.2)
    with pytest.raises(ValueError, match="distance"):
        scenes.paper_scenario(1, distance=-1)


def _all_kinds_scene():
    return Scene(
        robots=(Robot(0, 0, 0.3), Robot(1, 1, -1.0)),
        obstacles=(
            Cylinder(-1, 0, 0.1),
            Box(0, 1.2, 0.2, 0.1, theta=0.4, movable=True, mass=2.0),
            Prism(1, -1, sides=5, width=0.07, theta=0.2),
            Polygon(-1, -1, vertices=((0, 0), (0.2, 0), (0.1, 0.15))),
            Wall(-1.8, 1.5, -0.5, 1.5, thickness=0.05),
        ),
        arena=Arena(4, 4),
        name="all kinds",
    )


def test_round_trip_dict_and_json():
    scene = _all_kinds_scene()
    d = scene.to_dict()
    assert Scene.from_dict(d) == scene
    assert Scene.from_json(scene.to_json()) == scene
    assert json.loads(json.dumps(d)) == d  # plain data only
    r = scenes.random_arena(5, 12, seed=2, size=5.0)
    assert Scene.from_dict(json.loads(json.dumps(r.to_dict()))) == r


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d.update(colour="red"), r"unknown key\(s\) \['colour'\]"),
        (lambda d: d["arena"].update(depth=3), r"scene.arena: unknown key\(s\) \['depth'\]"),
        (lambda d: d["robots"][0].update(z=1), r"scene.robots\[0\]: unknown key"),
        (lambda d: d["obstacles"][0].update(height=1), r"scene.obstacles\[0\] \(cylinder\): unknown key"),
        (lambda d: d["obstacles"][0].update(kind="sphere"), "unknown obstacle kind 'sphere'"),
        (lambda d: d["obstacles"][0].update(radius=-0.1), "radius must be > 0"),
        (lambda d: d["obstacles"][2].update(sides=2), "sides must be an integer >= 3"),
        (lambda d: d["robots"][0].update(x=5.0), r"robots\[0\].*outside the arena"),
        (lambda d: d["robots"][1].update(x=0.1, y=0.1), r"robots\[1\].*overlaps robots\[0\]"),
        (lambda d: d["obstacles"][0].update(x=-0.1), r"obstacles\[0\].*overlaps robots\[0\]"),
        (lambda d: d["obstacles"][3].update(vertices=[[0, 0], [1, 0], [0.5, 0.1], [0.5, 1]]), "convex"),
        (lambda d: d["lidar"].update(range_max=-1), "range_max"),
        (lambda d: d["robot"].update(body_radius=0.01), "housing_radius"),
        (lambda d: d["robots"][0].update(theta=float("nan")), "theta must be a finite number"),
    ],
)
def test_invalid_scenes_raise_clear_errors(mutate, match):
    d = json.loads(_all_kinds_scene().to_json())
    mutate(d)
    with pytest.raises(ValueError, match=match):
        Scene.from_dict(d)


def test_random_arena_is_seeded_and_valid():
    a = scenes.random_arena(8, 20, seed=4)
    assert a == scenes.random_arena(8, 20, seed=4)
    assert a != scenes.random_arena(8, 20, seed=5)
    assert len(a.robots) == 8 and len(a.obstacles) == 20
    Scene.from_dict(a.to_dict())  # validates: inside the arena, no overlaps


def test_random_arena_mixes_kinds_including_kin_width():
    scene = scenes.random_arena(4, 200, seed=0, size=20.0)
    kinds = {o.kind for o in scene.obstacles}
    assert kinds == {"cylinder", "box", "prism", "wall"}
    kin_wide = [
        o
        for o in scene.obstacles
        if (o.kind == "cylinder" and o.radius == 0.035)
        or (o.kind == "prism" and o.width == 0.07)
        or (o.kind == "box" and (o.width, o.depth) == (0.07, 0.07))
    ]
    assert len(kin_wide) > 20
    assert {o.sides for o in scene.obstacles if o.kind == "prism" and o.width == 0.07} == {3, 4, 5, 6}
    other_radii = [o.radius for o in scene.obstacles if o.kind == "cylinder" and o.radius != 0.035]
    assert min(other_radii) < 0.05 and max(other_radii) > 0.1


def test_random_arena_keeps_clearance():
    cfg = scenes.RandomArenaConfig(clearance=0.1)
    scene = scenes.random_arena(10, 30, seed=9, size=6.0, config=cfg)
    # every robot keeps 0.1 m from every obstacle and the boundary
    hx = scene.arena.width / 2
    for r in scene.robots:
        assert abs(r.x) <= hx - 0.09 - 0.1 + 1e-9 and abs(r.y) <= hx - 0.09 - 0.1 + 1e-9
        for o in scene.obstacles:
            kind, geom = o.footprint()
            if kind == "circle":
                assert math.hypot(r.x - geom[0], r.y - geom[1]) >= 0.09 + geom[2] + 0.1 - 1e-9


def test_random_arena_too_crowded():
    with pytest.raises(ValueError, match="do not fit in a 1.0 x 1.0 m arena"):
        scenes.random_arena(30, 10, seed=0, size=1.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [({"n_robots": -1}, "n_robots"), ({"n_obstacles": 2.5}, "n_obstacles")],
)
def test_random_arena_bad_counts(kwargs, match):
    with pytest.raises(ValueError, match=match):
        scenes.random_arena(**kwargs)


def test_random_arena_config_validation():
    with pytest.raises(ValueError, match="kind_weights"):
        scenes.RandomArenaConfig(kind_weights=(1, 0, 0))
    with pytest.raises(ValueError, match="cylinder_radius"):
        scenes.RandomArenaConfig(cylinder_radius=(0.2, 0.1))


@pytest.mark.parametrize("cls, kwargs, exc, match", [
    (scenes.RandomArenaConfig, {"kind_weights": "abcd"}, TypeError, "kind_weights must be a list or tuple"),
    (scenes.RandomArenaConfig, {"kind_weights": (1, -1, 0, 0)}, ValueError, r"kind_weights\[1\]"),
    (scenes.RandomArenaConfig, {"kind_weights": (0, 0, 0, 0)}, ValueError, "kind_weights must not all be 0"),
    (scenes.RandomArenaConfig, {"kin_width_prob": "0.5"}, TypeError, "kin_width_prob"),
    (scenes.RandomArenaConfig, {"box_size": (0.1, float("nan"))}, ValueError, r"box_size\[1\]"),
    (scenes.RandomArenaConfig, {"wall_length": None}, TypeError, "wall_length"),
    (scenes.RandomArenaConfig, {"prism_sides": (3, 4.5)}, TypeError, r"prism_sides\[1\] must be an integer"),
    (scenes.RandomArenaConfig, {"prism_sides": ()}, ValueError, "prism_sides must hold at least 1"),
    (scenes.RandomArenaConfig, {"prism_sides": (10**9,)}, ValueError, r"prism_sides\[0\]"),
    (scenes.RandomArenaConfig, {"clearance": -0.1}, ValueError, "clearance"),
    (scenes.RandomArenaConfig, {"max_attempts": 2.5}, TypeError, "max_attempts must be an integer"),
    (scenes.DetectionSceneConfig, {"n_kin": 1.5}, TypeError, "n_kin must be an integer"),
    (scenes.DetectionSceneConfig, {"n_distractors": True}, TypeError, "n_distractors"),
    (scenes.DetectionSceneConfig, {"n_kin": 10**9}, ValueError, "n_kin"),
    (scenes.DetectionSceneConfig, {"distance": 2.0}, TypeError, "distance must be a list or tuple"),
    (scenes.DetectionSceneConfig, {"distance": (0.0, 1.0)}, ValueError, r"distance\[0\]"),
    (scenes.DetectionSceneConfig, {"distance": (0.5, float("inf"))}, ValueError, r"distance\[1\]"),
    (scenes.DetectionSceneConfig, {"distractor_weights": (1, 1, 1, 1, 1, "x")}, TypeError,
     r"distractor_weights\[5\]"),
    (scenes.DetectionSceneConfig, {"arena_margin": None}, TypeError, "arena_margin"),
    (scenes.DetectionSceneConfig, {"max_attempts": 0}, ValueError, "max_attempts"),
])  # fmt: skip
def test_scene_generator_configs_name_the_bad_field(cls, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        cls(**kwargs)
    with pytest.raises(exc, match=match):  # the same from a dict (JSON), lists for tuples
        cls.from_dict({k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items()})


def test_scene_generator_configs_store_tuples_and_refuse_unknown_keys():
    cfg = scenes.RandomArenaConfig.from_dict({"box_size": [0.1, 0.2], "prism_sides": [3, 5]})
    assert cfg.box_size == (0.1, 0.2) and cfg.prism_sides == (3, 5) and hash(cfg)
    assert scenes.DetectionSceneConfig.from_dict({"distance": [0.5, 1.0]}).distance == (0.5, 1.0)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['size'\]"):
        scenes.RandomArenaConfig.from_dict({"size": 3})
    with pytest.raises(TypeError, match="expected a dict"):
        scenes.RandomArenaConfig.from_dict([("clearance", 0.1)])


def test_detection_scene_layout():
    cfg = scenes.DetectionSceneConfig(n_kin=3, n_distractors=15, distance=(0.3, 3.0))
    a = scenes.detection_scene(3, cfg)
    assert a == scenes.detection_scene(3, cfg)
    assert a.robots[0].x == 0.0 and a.robots[0].y == 0.0
    assert len(a.robots) == 4
    for r in a.robots[1:]:
        assert 0.3 - 1e-9 <= math.hypot(r.x, r.y) <= 3.0 + 1e-9
    Scene.from_dict(a.to_dict())  # valid: no overlaps, inside the arena
    # over many seeds every distractor kind shows up, corners as two walls meeting
    kinds = set()
    for seed in range(30):
        for o in scenes.detection_scene(seed, cfg).obstacles:
            if o.kind == "prism":
                kinds.add(("prism", o.sides, o.width))
            elif o.kind == "cylinder":
                kinds.add("same_radius_cylinder" if o.radius == 0.035 else "other_cylinder")
            else:
                kinds.add(o.kind)
    assert {("prism", n, 0.07) for n in (3, 4, 5, 6)} <= kinds
    assert {"same_radius_cylinder", "other_cylinder", "box", "wall"} <= kinds


def test_detection_scene_config_errors():
    with pytest.raises(ValueError, match="distance"):
        scenes.DetectionSceneConfig(distance=(2.0, 1.0))
    with pytest.raises(ValueError, match="distractor_weights"):
        scenes.DetectionSceneConfig(distractor_weights=(1, 1))
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['n_robots'\]"):
        scenes.DetectionSceneConfig.from_dict({"n_robots": 3})
    with pytest.raises(ValueError, match="could not place"):
        scenes.detection_scene(0, scenes.DetectionSceneConfig(n_kin=40, distance=(0.3, 0.4)))


@pytest.mark.parametrize(
    "make", [lambda s: scenes.random_arena(4, 3, seed=s), lambda s: scenes.detection_scene(s)]
)
@pytest.mark.parametrize("seed, exc, match", [(-1, ValueError, "seed must be >= 0, got -1"),
                                              (1.5, TypeError, "seed must be None, an integer >= 0"),
                                              ("0", TypeError, "got str '0'")])  # fmt: skip
def test_scene_generators_name_a_bad_seed(make, seed, exc, match):
    # numpy's own message ("expected non-negative integer") names neither the generator nor the value
    with pytest.raises(exc, match=rf"(random_arena|detection_scene): .*{match}"):
        make(seed)
    # every seed form the World takes still works, with the same scenes as before
    assert make(np.int64(3)) == make(3) == make(np.random.default_rng(3)) == make(np.random.SeedSequence(3))
    make(None)
