"""Wheel odometry as a real differential-drive robot has it: integrated wheel travel, with noise and drift.

Frames and units: metres, radians. A pose increment ``(dx, dy, dtheta)`` is expressed in the robot's frame
at the *start* of the increment (x forward, y left, dtheta CCW positive); composing increments with
:func:`compose` integrates them.

**What the encoders see.** Each physics substep, the wheel travel a robot's encoders report is computed from
the motion the robot actually achieved (its body's forward speed and yaw rate, read back from the physics
after the contact solver), not from the command: a robot stopped by a wall reports no travel, and being
pushed sideways (lateral slip) is invisible to wheel encoders, exactly as on a real robot.

**Noise model** (:class:`OdometrySpec`, per wheel):

- drift: a constant scale error per wheel, drawn once per robot when the world is built,
  ``N(0, scale_sigma)`` (a mis-calibrated wheel radius: errors grow with the distance travelled, with a
  consistent sign);
- random error: ``N(0, noise_k**2 * |travel|)`` added to each wheel's travel (variance proportional to
  the distance the wheel rolled: the classic odometry error model, Chong & Kleeman 1997).

Defaults (``scale_sigma=0.005``, ``noise_k=0.005`` m^1/2) give about 2.5 deg of heading error per metre
driven, 0.5 % of distance: a small, realistic budget for a hobby differential-drive base.
``OdometrySpec.exact()`` turns both off. Draws come from the world's own seeded RNG stream, a child spawned
from it, so enabling or changing odometry noise never changes the lidar noise of the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from kin_envs.core._validate import check_finite

__all__ = ["OdometrySpec", "Odometry", "compose", "relative"]


@dataclass(frozen=True)
class OdometrySpec:
    """Wheel-odometry error model.

    Attributes:
        scale_sigma: standard deviation of each wheel's constant relative scale error (drift), >= 0.
        noise_k: random error per wheel, m^(1/2): the travel error has variance ``noise_k**2 * |travel|``.
    """

    scale_sigma: float = 0.005
    noise_k: float = 0.005

    def __post_init__(self) -> None:
        check_finite("OdometrySpec", scale_sigma=self.scale_sigma, noise_k=self.noise_k)
        for name in ("scale_sigma", "noise_k"):
            v = getattr(self, name)
            if isinstance(v, bool) or v < 0 or v > 1:
                raise ValueError(f"OdometrySpec.{name} must be in [0, 1], got {v!r}")

    @classmethod
    def exact(cls) -> OdometrySpec:
        """No noise, no drift: odometry integrates the achieved wheel travel exactly."""
        return cls(scale_sigma=0.0, noise_k=0.0)


def compose(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``pose ⊕ delta``: apply robot-frame increments ``(n, 3)`` to poses ``(n, 3)`` (theta wrapped)."""
    pose, delta = np.asarray(pose, np.float64), np.asarray(delta, np.float64)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    out = np.empty(np.broadcast_shapes(pose.shape, delta.shape))
    out[..., 0] = pose[..., 0] + c * delta[..., 0] - s * delta[..., 1]
    out[..., 1] = pose[..., 1] + s * delta[..., 0] + c * delta[..., 1]
    th = pose[..., 2] + delta[..., 2]
    out[..., 2] = np.arctan2(np.sin(th), np.cos(th))
    return out


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a⁻¹ ⊕ b``: pose ``b`` in the frame of pose ``a`` (so ``compose(a, relative(a, b)) == b``)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    th = b[..., 2] - a[..., 2]
    out[..., 2] = np.arctan2(np.sin(th), np.cos(th))
    return out


class Odometry:
    """Per-robot odometry state of one world (the world owns it; see the module docstring).

    Args:
        start: ``(n, 3)`` poses the odometry starts from (the robots' true start poses: the odometry frame
            coincides with the world frame at t = 0, then drifts away from it).
        wheel_base: m, distance between the wheels.
        spec: the error model.
        rng: the stream the drift and noise are drawn from.
    """

    #: Standard normals already drawn from ``rng`` (rows of ``(n, 2)``, next first, from ``ahead_pos``):
    #: :meth:`integrate` takes them before drawing again, so the stream is the same whoever drew them (the
    #: native vector env draws many steps' worth per call, :meth:`take_ahead`; a copy keeps them).
    ahead: np.ndarray | None = None
    ahead_pos: int = 0

    def __init__(self, start: np.ndarray, wheel_base: float, spec: OdometrySpec, rng: np.random.Generator):
        self.spec = spec
        self.rng = rng
        self.wheel_base = float(wheel_base)
        n = start.shape[0]
        self.pose = np.array(start, dtype=np.float64).reshape(n, 3)
        self._step_start = self.pose.copy()
        self.delta = np.zeros((n, 3))  # last World.step's increment, robot frame at its start
        # (n, 2) left/right constant scale factors: 1 + drift
        self.scale = 1.0 + (rng.normal(0.0, spec.scale_sigma, (n, 2)) if spec.scale_sigma > 0 else 0.0)
        self.scale = np.broadcast_to(self.scale, (n, 2)).copy()

    def begin_step(self) -> None:
        self._step_start = self.pose.copy()

    def integrate(self, v_forward: np.ndarray, omega: np.ndarray, dt: float) -> None:
        """Add one substep of achieved motion: forward speed (m/s, along the heading at the substep's start)
        and yaw rate (rad/s) per robot."""
        half_b = 0.5 * self.wheel_base
        ds, dth = v_forward * dt, omega * dt
        wheels = np.stack([ds - dth * half_b, ds + dth * half_b], axis=1) * self.scale  # left, right travel
        if self.spec.noise_k > 0:
            wheels += self._normals(wheels.shape) * (self.spec.noise_k * np.sqrt(np.abs(wheels)))
        ds_m = 0.5 * (wheels[:, 0] + wheels[:, 1])
        dth_m = (wheels[:, 1] - wheels[:, 0]) / self.wheel_base
        # forward along the heading at the substep's start, then turn: the physics' own (symplectic
        # Euler) integration, so exact odometry of a robot that does not slip reproduces its pose
        self.pose = compose(self.pose, np.stack([ds_m, np.zeros_like(ds_m), dth_m], axis=1))

    def integrate_state(self, state: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray, dt: float) -> None:
        """:meth:`integrate` of bodies' ``(n, 4)`` ``angle, vx, vy, omega`` rows (forward speed
        ``vx cos + vy sin`` of the heading; ``cos_h``, ``sin_h``: numpy's of ``angle``), bit for bit, in
        one compiled loop for the arithmetic (the transcendental functions stay numpy's, whose results
        a compiled ``cos`` need not match): the native vector env's 128-robot substep in ~1/4 the time."""
        z = self._normals((state.shape[0], 2)) if self.spec.noise_k > 0 else np.zeros((0, 2))
        p = self.pose
        th = p[:, 2]
        out = np.empty_like(p)
        _integrate_kernel(p, np.cos(th), np.sin(th), state, cos_h, sin_h, float(dt), 0.5 * self.wheel_base,
                          self.wheel_base, self.scale, z, float(self.spec.noise_k), out)  # fmt: skip
        th = out[:, 2]
        out[:, 2] = np.arctan2(np.sin(th), np.cos(th))  # compose's wrap
        self.pose = out

    def end_step(self) -> None:
        self.delta = relative(self._step_start, self.pose)

    def _normals(self, shape: tuple[int, ...]) -> np.ndarray:
        """``rng.normal(0, 1, shape)``: the next row drawn ahead if any, else a fresh draw."""
        a = self.ahead
        if a is not None and self.ahead_pos < a.shape[0]:
            if a.shape[1:] != tuple(shape):
                raise RuntimeError(f"Odometry: normals drawn ahead are {a.shape[1:]}, asked for {shape}")
            self.ahead_pos += 1
            return a[self.ahead_pos - 1]
        return self.rng.normal(0.0, 1.0, shape)

    def take_ahead(self, count: int, refill: int) -> np.ndarray:
        """``(count, n, 2)``: the normals of the next ``count`` calls of :meth:`integrate`, taken out of
        the stream now (whoever integrates them must use exactly these). When fewer than ``count`` are
        drawn ahead, ``max(count, refill)`` are drawn in one call (the rows left first: the same stream)."""
        a, p, n = self.ahead, self.ahead_pos, self.pose.shape[0]
        if a is None or a.shape[0] - p < count:
            left = a[p:] if a is not None else np.zeros((0, n, 2))
            fresh = self.rng.normal(0.0, 1.0, (max(count, refill) - left.shape[0], n, 2))
            a = self.ahead = np.concatenate([left, fresh]) if left.shape[0] else fresh
            p = 0
        self.ahead_pos = p + count
        return a[p : p + count]


@numba.njit(cache=True)
def _integrate_kernel(pose, c, s, state, cos_h, sin_h, dt, half_b, wheel_base, scale, z, noise_k, out):
    """:meth:`Odometry.integrate`'s arithmetic, operation for operation in numpy's order (no fast-math,
    so no fused multiply-adds: every result rounds as numpy's does); ``out[:, 2]`` gets the unwrapped
    heading."""
    for i in range(pose.shape[0]):
        v = state[i, 1] * cos_h[i] + state[i, 2] * sin_h[i]
        ds = v * dt
        dth = state[i, 3] * dt
        left = (ds - dth * half_b) * scale[i, 0]
        right = (ds + dth * half_b) * scale[i, 1]
        if noise_k > 0:
            left += z[i, 0] * (noise_k * np.sqrt(np.abs(left)))
            right += z[i, 1] * (noise_k * np.sqrt(np.abs(right)))
        ds_m = 0.5 * (left + right)
        dth_m = (right - left) / wheel_base
        # compose(pose, (ds_m, 0, dth_m)), the zero lateral term included (it decides signed zeros)
        out[i, 0] = pose[i, 0] + c[i] * ds_m - s[i] * 0.0
        out[i, 1] = pose[i, 1] + s[i] * ds_m + c[i] * 0.0
        out[i, 2] = pose[i, 2] + dth_m
