"""The lidar's range noise drawn in compiled code (``kin_envs.core._noise``) against NumPy's own calls:
the same normals and uniforms as ``Generator.normal(0, 1, n)`` / ``Generator.random(n)`` and the same
generator state after them, bit for bit; ``World.scan`` and ``WorldBatch.scan_combined`` give what NumPy's
path gives (the previous code, kept as the fallback for other generators) on random scenes."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from kin_envs import LidarSpec, World, scenes
from kin_envs.core import _noise
from kin_envs.core.multi import WorldBatch


def _arena(n_robots, n_obstacles, seed, size=6.0, lidar=None, walls=True):
    scene = scenes.random_arena(n_robots, n_obstacles, seed=seed, size=size, lidar=lidar)
    # without walls the beams that reach nothing read range_max (not finite ground truth, no noise)
    return scene if walls else dataclasses.replace(scene, arena=dataclasses.replace(scene.arena, walls=False))


def _state(g: np.random.Generator):
    """A generator's state, comparable with == (MT19937's holds an array)."""
    def plain(v):
        return {k: plain(x) for k, x in v.items()} if isinstance(v, dict) else np.asarray(v).tolist()
    return plain(g.bit_generator.state)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint8)


@pytest.mark.parametrize("n", [0, 1, 2, 7, 255, 360, 1000, 20_000])
def test_normals_and_uniforms_are_numpys_stream(n):
    for seed in range(40):
        ours, ref = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(2):  # twice: the state after the first call is NumPy's
            assert np.array_equal(_bits(_noise.normals(ours, n)), _bits(ref.normal(0.0, 1.0, n)))
            assert np.array_equal(_bits(_noise.uniforms(ours, n)), _bits(ref.random(n)))
        assert _state(ours) == _state(ref)
        assert ours.integers(1 << 62, size=3).tolist() == ref.integers(1 << 62, size=3).tolist()


def test_ziggurat_tail_and_wedges_are_exercised():
    # 2M normals: the tail branch (|z| > r = 3.654, ~1 in 3,800 draws) and the wedges (~0.7 %, each one
    # more next_double) run many times; the values still match bit for bit
    ours, ref = np.random.default_rng(123), np.random.default_rng(123)
    a, b = _noise.normals(ours, 2_000_000), ref.normal(0.0, 1.0, 2_000_000)
    assert np.array_equal(_bits(a), _bits(b))
    assert np.count_nonzero(np.abs(a) > 3.6541528853610087) > 300
    assert _state(ours) == _state(ref)


def test_only_pcg64_generators_are_drawn_in_compiled_code():
    assert _noise.handles(np.random.default_rng(0)) is not None
    for rng in (np.random.Generator(np.random.MT19937(0)), np.random.Generator(np.random.Philox(0)),
                np.random.Generator(np.random.PCG64DXSM(0)), np.random.Generator(np.random.SFC64(0)),
                np.random.RandomState(0), None):  # fmt: skip
        assert _noise.handles(rng) is None

    class MyPCG64(np.random.PCG64):
        pass

    assert _noise.handles(np.random.Generator(MyPCG64(0))) is None


def _numpy_noise(spec: LidarSpec, true: np.ndarray, clean: np.ndarray, rngs: list) -> np.ndarray:
    """The oracle: World.scan's noise as NumPy expressions, rows split evenly among ``rngs`` in order (all
    normals world by world, then all uniforms)."""
    out = clean.copy()
    hit = np.isfinite(true)
    per = hit.reshape(len(rngs), -1).sum(axis=1)
    d = true[hit].astype(np.float64)
    if spec.noise_sigma > 0:
        z = np.concatenate([g.normal(0.0, 1.0, c) for g, c in zip(rngs, per, strict=True)])
        d += z * spec.noise_sigma * d
    invalid = (d < spec.range_min) | (d > spec.range_max)
    if spec.dropout_prob > 0:
        invalid |= np.concatenate([g.random(c) for g, c in zip(rngs, per, strict=True)]) < spec.dropout_prob
    d[invalid] = spec.range_max
    out[hit] = d
    return out


SPECS = [
    LidarSpec(noise_sigma=0.01),
    LidarSpec(noise_sigma=0.03, dropout_prob=0.05),
    LidarSpec(noise_sigma=0.0, dropout_prob=0.1),
    LidarSpec(noise_sigma=0.2, range_min=0.5, range_max=3.0, n_beams=90),  # many readings pushed out of range
]


@pytest.mark.parametrize("spec", SPECS, ids=range(len(SPECS)))
def test_world_scan_noise_is_numpys(spec):
    # open and closed random arenas (readings that miss stay as they are), all robots and subsets
    for seed in range(12):
        scene = _arena(4, 10, seed, 3.0 + seed, spec, walls=seed % 2 == 0)
        w = World(scene, seed=seed)
        for t in range(4):
            w.step(wheel_speeds=np.full((4, 2), 5.0) * np.array([1, 1 - t % 2]))
            robots = None if t % 2 else [3, 1]
            before = copy.deepcopy(w.rng)
            clean = w.scan(robots, noise=False)
            noisy = w.scan(robots)
            expect = _numpy_noise(spec, clean.true_ranges, clean.ranges, [before])
            assert np.array_equal(_bits(noisy.ranges), _bits(expect))
            assert _state(w.rng) == _state(before)
            assert np.array_equal(noisy.true_ranges, clean.true_ranges)
        if not scene.arena.walls:
            assert not np.isfinite(clean.true_ranges).all()


def test_world_scan_follows_a_replaced_rng_and_other_bit_generators():
    spec = LidarSpec(noise_sigma=0.02, dropout_prob=0.05)
    w = World(scenes.random_arena(3, 6, seed=1, lidar=spec), seed=1)
    w.scan()
    for rng in (np.random.default_rng(7), np.random.Generator(np.random.MT19937(7)),
                np.random.default_rng(8)):  # fmt: skip
        w.rng = rng  # a new object: the cached addresses must not be used for it
        before = copy.deepcopy(rng)
        clean, noisy = w.scan(noise=False), w.scan()
        assert np.array_equal(_bits(noisy.ranges), _bits(_numpy_noise(spec, clean.true_ranges, clean.ranges,
                                                                      [before])))  # fmt: skip
        assert _state(rng) == _state(before)


@pytest.mark.parametrize("shared", [False, True])
def test_batch_noise_is_numpys(shared):
    # K worlds in one compiled call against NumPy's calls world by world; with ``shared`` two worlds draw
    # from one Generator object (the order of the draws across worlds matters then)
    spec = LidarSpec(noise_sigma=0.02, dropout_prob=0.03)
    k = 5
    ws = [World(_arena(3, 8, s, 4.0, spec, walls=s != 2), seed=s) for s in range(k)]
    if shared:
        ws[3].rng = ws[1].rng
    batch = WorldBatch(ws)
    for t in range(6):
        batch.step(np.full((k, 3, 2), 6.0) * (1 + t % 2))
        active = None if t < 3 else np.array([True, False, True, True, t == 5])
        on = range(k) if active is None else np.flatnonzero(active)
        robots = [0, 2] if t % 2 else None
        before = copy.deepcopy([ws[j].rng for j in on])  # (one deepcopy: shared objects stay shared)
        clean, _, _ = batch.scan_combined(robots, noise=False, active=active)
        noisy, _, _ = batch.scan_combined(robots, active=active)
        assert np.array_equal(_bits(noisy.ranges), _bits(_numpy_noise(spec, clean.true_ranges, clean.ranges,
                                                                      before)))  # fmt: skip
        for j, b in zip(on, before, strict=True):
            assert _state(ws[j].rng) == _state(b)


def test_batch_falls_back_to_numpy_for_other_generators():
    spec = LidarSpec(noise_sigma=0.02, dropout_prob=0.03)
    ws = [World(scenes.random_arena(2, 5, seed=s, lidar=spec), seed=s) for s in range(3)]
    batch = WorldBatch(ws)
    batch.scan_combined()
    assert batch._noise_handles() is not None
    ws[1].rng = np.random.Generator(np.random.Philox(5))
    assert batch._noise_handles() is None
    before = copy.deepcopy([w.rng for w in ws])
    clean, _, _ = batch.scan_combined(noise=False)
    noisy, _, _ = batch.scan_combined()
    expect = _numpy_noise(spec, clean.true_ranges, clean.ranges, before)
    assert np.array_equal(_bits(noisy.ranges), _bits(expect))
    ws[1].rng = np.random.default_rng(5)  # back to PCG64: compiled again, with the new generator's addresses
    before = copy.deepcopy([w.rng for w in ws])
    noisy, _, _ = batch.scan_combined()
    assert batch._noise_handles() is not None
    expect = _numpy_noise(spec, clean.true_ranges, clean.ranges, before)
    assert np.array_equal(_bits(noisy.ranges), _bits(expect))
