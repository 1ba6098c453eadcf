"""The lidar's range noise and dropouts in one compiled call, drawn from each world's own NumPy ``Generator``.

``World.scan`` (and ``WorldBatch.scan_combined`` for K worlds) perturbs every finite reading with
``rng.normal(0.0, 1.0, hits)`` and, with dropouts, drops readings where ``rng.random(hits) < p``. In NumPy
that is, per scan, two ``Generator`` calls plus boolean masks, a gather, a concatenate over the worlds and a
scatter (~12 µs of a one-robot 360-beam ``World.scan``). Here the same numbers come from the same bit
generator inside one compiled call: NumPy's ``random_standard_normal`` (the 256-step ziggurat over
``next_uint64``) and ``next_double`` for the uniforms, in NumPy's order, calling the PCG64's own C functions
through the addresses its ``ctypes`` interface gives (as numba's own ``Generator`` support does, without its
per-call boxing). The ziggurat's tables are numba's copies of NumPy's (``numba.np.random._constants``). Every
value and the generator's state afterwards are NumPy's, bit for bit (tested on many seeds and lengths).

Only ``np.random.Generator`` over ``np.random.PCG64`` (what the envs and ``World(seed=int)`` make) is drawn
here; any other generator or bit generator takes the NumPy path (``handles`` returns ``None``). Like numba's
``Generator`` support, the compiled draws do not take the bit generator's ``lock``: a world's RNG must not
be drawn from another thread during its scan (the envs never do).
"""

from __future__ import annotations

import ctypes

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r

__all__ = ["apply_noise", "apply_noise_numpy", "handles", "normals", "uniforms"]

_VOID_P = ir.IntType(8).as_pointer()


@intrinsic
def _next_uint64(typingctx, fn, state):
    """``uint64_t fn(void *state)``: the bit generator's ``next_uint64``."""
    if not (isinstance(fn, types.Integer) and isinstance(state, types.Integer)):
        return None
    sig = types.uint64(fn, state)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [_VOID_P])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], _VOID_P)])

    return sig, codegen


@intrinsic
def _next_double(typingctx, fn, state):
    """``double fn(void *state)``: the bit generator's ``next_double`` (``Generator.random``'s draw)."""
    if not (isinstance(fn, types.Integer) and isinstance(state, types.Integer)):
        return None
    sig = types.float64(fn, state)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.DoubleType(), [_VOID_P])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], _VOID_P)])

    return sig, codegen


def handles(rng) -> np.ndarray | None:
    """``(3,)`` uint64: the PCG64 state's address and its ``next_uint64`` / ``next_double`` functions'
    addresses, or ``None`` if ``rng`` is not a ``Generator`` over ``PCG64`` (the caller then draws with
    NumPy). The addresses stay valid while ``rng`` lives: the caller keeps ``rng`` with them."""
    if type(rng) is not np.random.Generator or type(rng.bit_generator) is not np.random.PCG64:
        return None
    c = rng.bit_generator.ctypes
    cast = ctypes.cast
    return np.array([c.state.value, cast(c.next_uint64, ctypes.c_void_p).value,
                     cast(c.next_double, ctypes.c_void_p).value], dtype=np.uint64)  # fmt: skip


@numba.njit(cache=True, nogil=True, inline="always")
def _standard_normal(f64, f_dbl, state):
    """NumPy's ``random_standard_normal`` (``distributions.c``; numba's ``random_standard_normal``), step for
    step: the same draws from the bit generator in the same order and the same arithmetic."""
    while True:
        r = _next_uint64(f64, state)
        idx = r & 0xFF
        r >>= 8
        sign = r & 0x1
        rabs = (r >> 1) & 0x000FFFFFFFFFFFFF
        x = rabs * wi_double[idx]
        if sign & 0x1:
            x = -x
        if rabs < ki_double[idx]:
            return x  # ~99.3 % of draws
        if idx == 0:
            while True:  # the tail; 1 - U avoids log(0), as NumPy (GH 13361)
                xx = -ziggurat_nor_inv_r * np.log1p(-_next_double(f_dbl, state))
                yy = -np.log1p(-_next_double(f_dbl, state))
                if yy + yy > xx * xx:
                    if (rabs >> 8) & 0x1:
                        return -(ziggurat_nor_r + xx)
                    return ziggurat_nor_r + xx
        elif (fi_double[idx - 1] - fi_double[idx]) * _next_double(f_dbl, state) + fi_double[idx] < np.exp(
            -0.5 * x * x
        ):
            return x


@numba.njit(cache=True, nogil=True)
def _normals_into(h, out):
    """``out[:] = rng.normal(0.0, 1.0, out.size)`` for the generator of handles ``h`` (NumPy's
    ``random_normal``: ``loc + scale * z``, kept so that a ``-0.0`` comes out as NumPy's ``0.0``)."""
    state, f64, f_dbl = h[0], h[1], h[2]
    for i in range(out.size):
        out[i] = 0.0 + 1.0 * _standard_normal(f64, f_dbl, state)


@numba.njit(cache=True, nogil=True)
def _uniforms_into(h, out):
    """``out[:] = rng.random(out.size)``: one ``next_double`` per value."""
    state, f_dbl = h[0], h[2]
    for i in range(out.size):
        out[i] = _next_double(f_dbl, state)


def normals(rng, n: int) -> np.ndarray:
    """``rng.normal(0.0, 1.0, n)`` drawn in compiled code (a PCG64 ``Generator`` only; for the tests)."""
    out = np.empty(n)
    _normals_into(handles(rng), out)
    return out


def uniforms(rng, n: int) -> np.ndarray:
    """``rng.random(n)`` drawn in compiled code (a PCG64 ``Generator`` only; for the tests)."""
    out = np.empty(n)
    _uniforms_into(handles(rng), out)
    return out


@numba.njit(cache=True, nogil=True)
def apply_noise(true, ranges, rows_per_world, h, sigma, dropout, range_min, range_max):
    """The noise of ``World.scan`` on ``(rows, beams)`` float32 ``true`` readings into ``ranges``: world ``w``
    (handles ``h[w]``) owns rows ``w * rows_per_world`` onwards. As NumPy's path, operation for operation: the
    finite readings as float64 ``d``; with ``sigma > 0`` all worlds' normals, world by world in row-major
    order, ``d += z * sigma * d``; then with ``dropout > 0`` all worlds' uniforms in the same order; ``d`` out
    of ``[range_min, range_max]`` or dropped out becomes ``range_max``; float32 into ``ranges``. Readings that
    are not finite are left as they are in ``ranges``."""
    rows, nb = true.shape
    work = np.empty(rows * nb)
    k = h.shape[0]
    flat = true.reshape(-1)
    out = ranges.reshape(-1)
    per = rows_per_world * nb
    for w in range(k):  # the normals: every world's, in the order of the concatenated NumPy draws
        state, f64, f_dbl = h[w, 0], h[w, 1], h[w, 2]
        for i in range(w * per, (w + 1) * per):
            v = flat[i]
            if np.isfinite(v):
                d = np.float64(v)
                if sigma > 0:
                    z = 0.0 + 1.0 * _standard_normal(f64, f_dbl, state)
                    d = d + z * sigma * d
                work[i] = d
    if dropout > 0:  # then the uniforms (each world's second call): a dropped reading reads range_max
        for w in range(k):
            state, f_dbl = h[w, 0], h[w, 2]
            for i in range(w * per, (w + 1) * per):
                if np.isfinite(flat[i]) and _next_double(f_dbl, state) < dropout:
                    work[i] = range_max
    for i in range(flat.size):  # (a pass of its own: no calls in it, so it vectorises)
        if np.isfinite(flat[i]):
            d = work[i]
            out[i] = range_max if (d < range_min or d > range_max) else d


def apply_noise_numpy(true, ranges, rngs, sigma, dropout, range_min, range_max) -> None:
    """:func:`apply_noise` with NumPy's own calls, for any generators (what it reproduces): the rows of
    ``true`` split evenly over ``rngs`` (world ``w``'s rows drawn from ``rngs[w]``); each world's normals
    ``rng.normal(0.0, 1.0, hits)``, then each world's uniforms ``rng.random(hits)``."""
    hit = np.isfinite(true)
    counts = hit.reshape(len(rngs), -1).sum(axis=1).tolist()
    d = true[hit].astype(np.float64)
    if sigma > 0:
        d += np.concatenate([g.normal(0.0, 1.0, c) for g, c in zip(rngs, counts, strict=True)]) * sigma * d
    invalid = (d < range_min) | (d > range_max)
    if dropout > 0:
        invalid |= np.concatenate([g.random(c) for g, c in zip(rngs, counts, strict=True)]) < dropout
    d[invalid] = range_max
    ranges[hit] = d
