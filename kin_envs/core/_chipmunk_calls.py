"""Chipmunk called from compiled numba loops: the native vector env's physics over all worlds at once.

A Python call into pymunk costs ~0.1-0.2 µs of interpreter overhead plus the list or tuple it builds;
:class:`~kin_envs.core.multi.WorldBatch` made ~600 of them per physics substep for 64 worlds (read the
robots' angle and velocity, write the control bodies' velocity, step the spaces). Here the same C
functions are called from one compiled loop per phase, through their addresses (taken from pymunk's
cffi module at run time and passed in as integers, so the compiled code stays cacheable).

Only functions whose arguments are pointers and doubles are called this way (no struct passed or
returned by value, which would need platform ABI knowledge); a body's velocity is read and written
through pymunk's own batch iterator functions, which take ``(cpBody *, pmBatchedData *)``. The values
read and written are exactly those of ``pymunk.batch`` and of ``Body`` attribute access.
"""

from __future__ import annotations

import threading

import numba
import numpy as np
import pymunk.batch as pmbatch
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from pymunk._chipmunk import ffi, lib

__all__ = ["ChipmunkCalls", "address", "drive"]


def address(cdata) -> int:
    """A cffi pointer as an integer (a pymunk body or space: ``body._body``)."""
    return int(ffi.cast("uintptr_t", cdata))


# -- intrinsics: raw pointers and C calls from integers ----------------------------------------------
def _ptr_intrinsic(dtype):
    @intrinsic
    def as_ptr(typingctx, addr):
        if not isinstance(addr, types.Integer):
            return None
        sig = types.CPointer(dtype)(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(types.CPointer(dtype)))

        return sig, codegen

    return as_ptr


_f64_ptr = _ptr_intrinsic(types.float64)
_i32_ptr = _ptr_intrinsic(types.int32)
_uptr_ptr = _ptr_intrinsic(types.uintp)
_VOID_P = ir.IntType(8).as_pointer()


@intrinsic
def _call_pp(typingctx, fn, a, b):
    """``void fn(void *a, void *b)``."""
    if not all(isinstance(t, types.Integer) for t in (fn, a, b)):
        return None
    sig = types.void(fn, a, b)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.VoidType(), [_VOID_P, _VOID_P])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(args[1], _VOID_P), builder.inttoptr(args[2], _VOID_P)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call_ppp(typingctx, fn, a, b, c):
    """``void fn(void *a, void *b, void *c)``."""
    if not all(isinstance(t, types.Integer) for t in (fn, a, b, c)):
        return None
    sig = types.void(fn, a, b, c)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.VoidType(), [_VOID_P, _VOID_P, _VOID_P])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(a, _VOID_P) for a in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call_pd(typingctx, fn, a, x):
    """``void fn(void *a, double x)``."""
    if not (isinstance(fn, types.Integer) and isinstance(a, types.Integer) and isinstance(x, types.Float)):
        return None
    sig = types.void(fn, a, x)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.VoidType(), [_VOID_P, ir.DoubleType()])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(args[1], _VOID_P), args[2]])
        return context.get_dummy_value()

    return sig, codegen


# -- the compiled loops -----------------------------------------------------------------------------
@numba.njit(cache=True)
def _read_bodies(get_fn, data, float_array, arr_field, bodies, out):
    """``out[i]``: the values pymunk's batch get gives for ``bodies[i]`` (the fields of ``data``, in
    pymunk's order), body by body."""
    num = numba.carray(_i32_ptr(float_array), 1)
    width = out.shape[1]
    for i in range(bodies.shape[0]):
        num[0] = 0
        _call_pp(get_fn, bodies[i], data)
        # the array may have been reallocated by the push: read its pointer after each call
        arr = numba.carray(_f64_ptr(numba.carray(_uptr_ptr(arr_field), 1)[0]), width)
        for c in range(width):
            out[i, c] = arr[c]


@numba.njit(cache=True)
def _set_velocities(set_fn, data, float_array, arr_field, bodies, vx, vy):
    """``bodies[i].velocity = (vx[i], vy[i])`` (pymunk's batch set, ``cpBodySetVelocity``)."""
    num = numba.carray(_i32_ptr(float_array), 1)
    arr = numba.carray(_f64_ptr(numba.carray(_uptr_ptr(arr_field), 1)[0]), 2)
    for i in range(bodies.shape[0]):
        arr[0] = vx[i]
        arr[1] = vy[i]
        num[0] = 0
        _call_pp(set_fn, bodies[i], data)


@numba.njit(cache=True)
def _set_angular_velocities(fn, bodies, omega):
    for i in range(bodies.shape[0]):
        _call_pd(fn, bodies[i], omega[i])


@numba.njit(cache=True)
def _step_spaces(fn, spaces, dt):
    for j in range(spaces.shape[0]):
        _call_pd(fn, spaces[j], dt)


@numba.njit(cache=True)
def _set_and_step(set_fn, data, float_array, arr_field, bodies, vx, vy, step_fn, spaces, dt):
    _set_velocities(set_fn, data, float_array, arr_field, bodies, vx, vy)
    _step_spaces(step_fn, spaces, dt)


@numba.njit(cache=True)
def _arbiter_pairs(each_fn, arb_fn, data, int_array, arr_field, spaces, counts):
    """Every space's cached arbiters' ``(body a, body b)`` ids appended to the int array, in pymunk's
    order; ``counts[j]``: how many ids space ``j`` added. Returns the array's address (it may move)."""
    num = numba.carray(_i32_ptr(int_array), 1)
    num[0] = 0
    for j in range(spaces.shape[0]):
        before = num[0]
        _call_ppp(each_fn, spaces[j], arb_fn, data)
        counts[j] = num[0] - before
    return numba.carray(_uptr_ptr(arr_field), 1)[0]


class ChipmunkCalls:
    """This thread's batch buffers and the C functions' addresses (one set per thread, like
    :func:`kin_envs.core.world._buffer`: pymunk never frees a buffer's native arrays)."""

    _local = threading.local()

    def __init__(self) -> None:
        # the compiled loops write an array's count (an int at the struct's start) and read its pointer
        if ffi.offsetof("pmFloatArray", "num") != 0 or ffi.offsetof("pmIntArray", "num") != 0:
            raise RuntimeError("pymunk's batch arrays changed layout: the native vector env needs num first")
        fn = {name: address(ffi.addressof(lib, name)) for name in (
            "pmSpaceBodyGetIteratorFuncBatched", "pmSpaceBodySetIteratorFuncBatched",
            "pmSpaceArbiterIteratorFuncBatched", "cpSpaceEachCachedArbiter", "cpSpaceStep",
            "cpBodySetAngularVelocity")}  # fmt: skip
        self._bufs = [pmbatch.Buffer() for _ in range(3)]
        self._bufs.append(self._bufs[0])  # the pose read shares the drive read's array
        self._data = []
        body = pmbatch.BodyFields
        for buf, fields in zip(self._bufs, (
            body.ANGLE | body.VELOCITY | body.ANGULAR_VELOCITY,  # angle, vx, vy, omega
            body.VELOCITY,
            pmbatch.ArbiterFields.BODY_A_ID | pmbatch.ArbiterFields.BODY_B_ID,
            body.POSITION | body.ANGLE,  # x, y, angle
        ), strict=True):  # fmt: skip
            d = ffi.new("pmBatchedData *")
            d.fields = fields.value
            d.floatArray, d.intArray = buf._float_arr, buf._int_arr
            self._data.append(d)
        # room for one body's values (the set reads two), so that no push reallocates in the loops
        self._bufs[1].set_float_buf(np.zeros(2))
        get, put, arb, _ = self._bufs
        def arrays(a):  # the array struct and its ``arr`` field
            return address(a), address(a) + ffi.offsetof(ffi.typeof(a).item, "arr")

        self.get = (fn["pmSpaceBodyGetIteratorFuncBatched"], address(self._data[0]), *arrays(get._float_arr))
        self.get_pose = (self.get[0], address(self._data[3]), *self.get[2:])
        self.set = (fn["pmSpaceBodySetIteratorFuncBatched"], address(self._data[1]), *arrays(put._float_arr))
        self.arbiters = (fn["cpSpaceEachCachedArbiter"], fn["pmSpaceArbiterIteratorFuncBatched"],
                         address(self._data[2]), *arrays(arb._int_arr))  # fmt: skip
        self.step_fn = fn["cpSpaceStep"]
        self.set_avel_fn = fn["cpBodySetAngularVelocity"]

    @classmethod
    def here(cls) -> ChipmunkCalls:
        calls = getattr(cls._local, "calls", None)
        if calls is None:
            calls = cls._local.calls = cls()
        return calls

    def read_bodies(self, bodies: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``(n, 4)`` angle, vx, vy, omega of the bodies (``uintp`` addresses)."""
        _read_bodies(*self.get, bodies, out)
        return out

    def read_poses(self, bodies: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``(n, 3)`` raw x, y, angle of the bodies (``World._robot_rows``' values)."""
        _read_bodies(*self.get_pose, bodies, out)
        return out

    def set_angular_velocities(self, bodies: np.ndarray, omega: np.ndarray) -> None:
        _set_angular_velocities(self.set_avel_fn, bodies, omega)

    def set_velocities(self, bodies: np.ndarray, vx: np.ndarray, vy: np.ndarray) -> None:
        _set_velocities(*self.set, bodies, vx, vy)

    def set_and_step(self, bodies, vx, vy, spaces: np.ndarray, dt: float) -> None:
        """Set the bodies' velocities, then ``cpSpaceStep(space, dt)`` for every space."""
        _set_and_step(*self.set, bodies, vx, vy, self.step_fn, spaces, float(dt))

    def arbiter_pairs(self, spaces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(pairs, counts)``: ``(m, 2)`` body ids of all spaces' arbiters (as
        ``pymunk.batch.get_space_arbiters``, space after space) and how many pairs each space has."""
        counts = np.zeros(spaces.shape[0], np.int32)
        arr = _arbiter_pairs(*self.arbiters, spaces, counts)
        total = int(counts.sum())
        if total == 0:
            return np.zeros((0, 2), np.uintp), counts // 2
        pairs = np.frombuffer(ffi.buffer(ffi.cast("uintptr_t *", arr), total * ffi.sizeof("uintptr_t")),
                              dtype=np.uintp).reshape(-1, 2).copy()  # fmt: skip
        return pairs, counts // 2


def drive(calls: ChipmunkCalls, bodies, controls, spaces, commands: np.ndarray, odometry, substeps: int,
          dt: float) -> None:
    """``World.step``'s physics for the robots ``bodies`` (driven through their kinematic ``controls``,
    ``uintp`` addresses, row for row) of ``spaces``: ``substeps`` Chipmunk steps of ``dt`` s with the
    ``(n, 2)`` ``(v, omega)`` ``commands`` (m/s, rad/s CCW) held, and each substep's achieved motion
    integrated by ``odometry`` (an :class:`~kin_envs.core.odometry.Odometry` of these ``n`` robots,
    between its ``begin_step`` and ``end_step``), read before the drive update."""
    v, omega = commands[:, 0], commands[:, 1]
    # The yaw rate is constant over a control step: set it once (a kinematic body keeps it; setting it
    # again every substep is a no-op). A robot commanded to stand still (v = 0) gets its zero once too.
    calls.set_angular_velocities(controls, np.ascontiguousarray(omega))
    moving = v != 0.0
    still = controls[~moving]
    if still.size:
        zero = np.zeros(still.size)
        calls.set_velocities(still, zero, zero)
    m_controls, m_v = controls[moving], v[moving]
    state = np.empty((len(bodies), 4))  # angle, vx, vy, omega
    for _ in range(substeps):
        calls.read_bodies(bodies, state)
        heading = state[:, 0]
        cos_h, sin_h = np.cos(heading), np.sin(heading)
        # pymunk moves bodies with the velocity they have now (positions are integrated first in a
        # step), so this is the motion the wheel encoders are about to measure
        odometry.integrate_state(state, cos_h, sin_h, dt)
        calls.set_and_step(m_controls, m_v * cos_h[moving], m_v * sin_h[moving], spaces, dt)
