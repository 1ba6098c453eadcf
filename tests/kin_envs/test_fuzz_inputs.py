"""Issue 16 (done-when): hypothesis drives the public entry points with arbitrary inputs; each is
either handled or refused with a ValueError / TypeError that names the field."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kin_envs import LidarSpec, RobotSpec, Scene, World, WorldConfig, scenes

ANY = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5), st.lists(st.floats(-5, 5), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _refused_naming(cls, field: str, value) -> None:
    try:
        cls(**{field: value})
    except (ValueError, TypeError) as e:
        assert field in str(e), f"{cls.__name__}({field}={value!r}): message does not name it: {e}"


@FUZZ
@given(cls=st.sampled_from([LidarSpec, WorldConfig, RobotSpec]), data=st.data(), value=ANY)
def test_config_fields(cls, data, value):
    import dataclasses

    field = data.draw(st.sampled_from([f.name for f in dataclasses.fields(cls)]))
    _refused_naming(cls, field, value)


@FUZZ
@given(key=st.sampled_from(["x", "y", "theta", "radius", "kind", "movable", "mass"]), value=ANY,
       where=st.sampled_from(["robots", "obstacles", "arena", "lidar", "robot"]))
def test_scene_dicts(key, value, where):
    d = scenes.paper_scenario(1).to_dict()
    target = d[where][0] if isinstance(d[where], list) else d[where]
    target[key] = value
    try:
        Scene.from_dict(d)
    except (ValueError, TypeError) as e:
        assert str(e), "empty message"
        assert key in str(e) or "unknown key" in str(e) or "overlaps" in str(e) or "outside" in str(e) \
            or "obstacle kind" in str(e) or "'kind'" in str(e), str(e)


_WORLD = World(scenes.random_arena(3, 4, seed=0, size=3.0), seed=0)


@FUZZ
@given(cmd=st.one_of(ANY, st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2,
                                            max_size=2), min_size=3, max_size=3)),
       wheels=st.booleans())
def test_commands(cmd, wheels):
    try:
        _WORLD.step(**{"wheel_speeds" if wheels else "commands": cmd})
    except (ValueError, TypeError) as e:
        assert ("wheel_speeds" if wheels else "commands") in str(e) or "give exactly one" in str(e)
    assert np.isfinite(_WORLD.poses).all()


@FUZZ
@given(robots=st.one_of(ANY, st.lists(st.one_of(st.integers(-5, 5), st.floats(-5, 5)), max_size=4)))
def test_scan_indices(robots):
    try:
        scan = _WORLD.scan(robots=robots)
    except (ValueError, TypeError) as e:
        assert "robot" in str(e)
    else:
        assert np.isfinite(scan.ranges).all()


@FUZZ
@given(seed=ANY)
def test_seeds(seed):
    try:
        World(scenes.random_arena(2, 0, seed=0, size=2.0), seed=seed)
    except (ValueError, TypeError) as e:
        assert "seed" in str(e)
