"""Issue 16 (done-when): hypothesis drives the public entry points with arbitrary inputs; each is
either handled or refused with a ValueError / TypeError that names the field (or, for checkpoints,
the file).

The number of examples comes from the hypothesis profile (tests/conftest.py): a few per test in CI,
``KIN_HYPOTHESIS_PROFILE=full`` for the thorough run."""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kin_envs import LidarSpec, RobotSpec, Scene, World, WorldConfig, scenes
from kin_envs.core.scenes import DetectionSceneConfig, RandomArenaConfig

ANY = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5), st.lists(st.floats(-5, 5), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
# examples per test: the loaded profile's (tests/conftest.py)
FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _refused_naming(cls, field: str, value) -> None:
    try:
        cls(**{field: value})
    except (ValueError, TypeError) as e:
        assert field in str(e), f"{cls.__name__}({field}={value!r}): message does not name it: {e}"


CONFIGS = [LidarSpec, WorldConfig, RobotSpec, RandomArenaConfig, DetectionSceneConfig]
# the (min, max) / weights / sides fields of the scene-generator configs take sequences
NUMBERS = st.one_of(st.integers(-10, 2000), st.floats(allow_nan=True, allow_infinity=True), st.none(),
                    st.text(max_size=2), st.booleans())  # fmt: skip
SEQUENCES = st.lists(NUMBERS, max_size=7).flatmap(lambda v: st.sampled_from([v, tuple(v), np.asarray(v)]))


@FUZZ
@given(cls=st.sampled_from(CONFIGS), data=st.data(), value=st.one_of(ANY, SEQUENCES))
def test_config_fields(cls, data, value):
    field = data.draw(st.sampled_from([f.name for f in dataclasses.fields(cls)]))
    _refused_naming(cls, field, value)


@FUZZ
@given(cls=st.sampled_from([RandomArenaConfig, DetectionSceneConfig]), data=st.data())
def test_scene_generator_configs_from_dicts(cls, data):
    """A JSON-like dict of plausible and implausible values: refused naming a field, or it builds a
    config whose scene generator either places everything validly or says it could not."""
    names = [f.name for f in dataclasses.fields(cls)]
    keys = data.draw(st.lists(st.sampled_from([*names, "colour"]), max_size=3, unique=True))
    d = {k: data.draw(st.one_of(ANY, SEQUENCES.map(list))) for k in keys}
    try:
        cfg = cls.from_dict(d)
    except (ValueError, TypeError) as e:
        assert any(k in str(e) for k in keys), f"{cls.__name__}.from_dict({d!r}): {e}"
        return
    assert dataclasses.replace(cfg) == cfg and hash(cfg) is not None  # frozen, tuples stored
    make = scenes.random_arena if cls is RandomArenaConfig else scenes.detection_scene
    try:
        scene = make(seed=0, config=cfg) if cls is DetectionSceneConfig else make(2, 3, 0, 4.0, cfg)
    except ValueError as e:
        assert "could not place" in str(e), str(e)
    else:
        Scene.from_dict(scene.to_dict())  # valid: inside the arena, nothing overlapping


def test_scene_generators_take_dict_configs_and_refuse_other_types():
    d = {"distance": [0.5, 1.0], "n_distractors": 2}
    assert scenes.detection_scene(1, d) == scenes.detection_scene(1, DetectionSceneConfig(**d))
    assert scenes.random_arena(2, 2, 0, 4.0, {"clearance": 0.1}) == scenes.random_arena(
        2, 2, 0, 4.0, RandomArenaConfig(clearance=0.1))
    for make in (lambda c: scenes.detection_scene(0, c), lambda c: scenes.random_arena(2, 2, 0, 4.0, c)):
        with pytest.raises(TypeError, match="expected a dict"):
            make("wide")
        with pytest.raises(ValueError, match=r"unknown key\(s\) \['colour'\]"):
            make({"colour": 1})


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


# --- checkpoints: random bytes, truncated files, wrong-shape or missing weights -----------------

_CKPT_DIR = Path(tempfile.mkdtemp(prefix="kin_fuzz_ckpt_"))


def _valid_checkpoint() -> tuple[Path, bytes]:
    torch = pytest.importorskip("torch")
    from detectors.features import FeatureConfig, feature_names
    from detectors.learned import ModelConfig, SegmentNet, save_checkpoint

    n = len(feature_names())
    torch.manual_seed(0)
    m = SegmentNet(ModelConfig(n, (8,)))
    m.set_normalisation(np.zeros(n), np.ones(n), [0.03, 0.0], [0.01, 0.01])
    path = save_checkpoint(_CKPT_DIR / "valid.pt", m, FeatureConfig())
    return path, path.read_bytes()


def _load_refused_naming_the_file(path: Path) -> bool:
    """True if it loaded, False if refused with a ValueError naming ``path``."""
    from detectors.learned import load_checkpoint

    try:
        load_checkpoint(path)
    except ValueError as e:
        assert str(path) in str(e), str(e)
        return False
    return True


@FUZZ
@given(raw=st.binary(max_size=4096), prefix=st.sampled_from([b"", b"PK\x03\x04", b"\x80\x02"]))
def test_checkpoint_random_bytes(raw, prefix):
    _valid_checkpoint()
    path = _CKPT_DIR / "random.pt"
    path.write_bytes(prefix + raw)
    assert not _load_refused_naming_the_file(path)


@FUZZ
@given(frac=st.floats(0.0, 1.0, exclude_max=True))
def test_checkpoint_truncated(frac):
    _, raw = _valid_checkpoint()
    path = _CKPT_DIR / "truncated.pt"
    path.write_bytes(raw[: int(frac * len(raw))])
    assert not _load_refused_naming_the_file(path)


@FUZZ
@given(data=st.data(), keep_checksum=st.booleans())
def test_checkpoint_wrong_shape_state_dicts(data, keep_checksum):
    import torch

    valid, _ = _valid_checkpoint()
    ck = torch.load(valid, weights_only=True)
    state = ck["state_dict"]
    key = data.draw(st.sampled_from(sorted(state)))
    action = data.draw(st.sampled_from(["reshape", "drop", "extra", "dtype"]))
    if action == "reshape":
        shape = tuple(data.draw(st.lists(st.integers(0, 9), max_size=3)))
        if shape == tuple(state[key].shape):
            shape = (*shape, 2)
        state[key] = torch.zeros(shape)
    elif action == "drop":
        del state[key]
    elif action == "extra":
        state[key + "_extra"] = torch.zeros(3)
    else:
        state[key] = state[key].to(torch.float64)
    if not keep_checksum:
        ck.pop("weights_sha256", None)
    path = _CKPT_DIR / "edited.pt"
    torch.save(ck, path)
    loaded = _load_refused_naming_the_file(path)
    assert not loaded or action == "dtype", f"{action} {key} loaded"
