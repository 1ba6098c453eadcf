"""Several independent worlds advanced and scanned together (the native vector env's core).

:class:`WorldBatch` ``.step`` and ``.scan`` do exactly what ``World.step`` and ``World.scan`` do
for each of its worlds (same arithmetic, same RNG draws in the same order, so results are bit-identical),
but pay Python's per-call overhead once per batch instead of once per world: the drive update of
all worlds is one set of numpy operations per physics substep, Chipmunk is called from compiled
loops over all worlds' bodies and spaces (:mod:`kin_envs.core._chipmunk_calls`), the odometry's
arithmetic is compiled, contacts are resolved for all worlds at once, and every robot of every world
is scanned in one call of the raycasting kernel (each robot against its own world's primitives only).

Worlds stay independent objects: any of them can be reset (replaced) between calls.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

from kin_envs.core._chipmunk_calls import ChipmunkCalls, address, drive
from kin_envs.core._noise import apply_noise, apply_noise_numpy
from kin_envs.core.interrupts import atomic
from kin_envs.core.lidar import (
    _cast_one,
    _columns,
    _work,
    _write_row,
    beam_tables,
    cast_prepared,
    wrap_headings,
)
from kin_envs.core.odometry import Odometry
from kin_envs.core.world import _COMMAND_CAP, Contact, Scan, World

__all__ = ["WorldBatch"]


def _key(w: World) -> tuple:
    return (w.n_robots, w.scene.robot, w.scene.lidar, w.config.physics_dt, w.config.substeps,
            w.config.odometry)


#: Odometry normals each world draws ahead at a time (Odometry.take_ahead): one RNG call per world every
#: 40 steps instead of every step (a call costs ~3 µs whatever its size).
_ODOMETRY_AHEAD = 200


def _stacked_odometry(first: Odometry, pose: np.ndarray, scale: np.ndarray) -> Odometry:
    """One :class:`Odometry` of several worlds' robots (``pose``, ``scale``: theirs, stacked; the spec
    and wheel base of ``first``, the same for all). ``begin_step`` sets its step start and ``end_step``
    its delta."""
    o = Odometry.__new__(Odometry)
    o.spec, o.wheel_base, o.rng = first.spec, first.wheel_base, None
    o.pose, o.scale = pose, scale
    return o


class WorldBatch:
    """``K`` independent worlds, stepped and scanned together.

    All worlds must have the same number of robots, robot spec, lidar spec and timestep (the
    scenes, obstacles and RNGs are each world's own). Replace a world (a new episode) with
    ``batch[k] = World(...)``.

    Example::

        batch = WorldBatch([World(scenes.random_arena(2, 6, seed=s), seed=s) for s in range(64)])
        batch.step(np.zeros((64, 2, 2)))      # wheel speeds, rad/s
        scans, poses = batch.scan([0])        # robot 0 of every world, one kernel call
    """

    def __init__(self, worlds: Sequence[World]) -> None:
        self._worlds = list(worlds)
        if not self._worlds:
            raise ValueError("WorldBatch: needs at least one world")
        self._layout_ok = False
        self._phys: dict | None = None
        self._noise_rngs: list | None = None
        self._noise_ids: list[int] | None = None
        self._noise_h: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self._worlds)

    def __getitem__(self, k: int) -> World:
        return self._worlds[k]

    def __setitem__(self, k: int, world: World) -> None:
        if not isinstance(world, World):
            raise TypeError(f"WorldBatch: expected a World, got {type(world).__name__}")
        self._worlds[k] = world
        self._layout_ok = False
        self._replace_physics(k, world)

    @property
    def worlds(self) -> tuple[World, ...]:
        return tuple(self._worlds)

    def _layout(self) -> None:
        """Per-batch tables, rebuilt whenever a world was replaced."""
        if self._layout_ok:
            return
        ws = self._worlds
        k0 = _key(ws[0])
        for j, w in enumerate(ws):
            if _key(w) != k0:
                raise ValueError(
                    f"WorldBatch: world {j} differs from world 0 in robot count, robot spec, lidar "
                    "spec or timestep; a batch needs them equal"
                )
        self.n_robots = ws[0].n_robots
        n = self.n_robots
        # contacts: one owner table of all worlds (pymunk body ids are unique across spaces)
        ids = np.concatenate([w._owner_ids for w in ws])
        flags = np.concatenate([w._owner_flag for w in ws])
        robots = np.concatenate([np.where(w._owner_robot >= 0, w._owner_robot + j * n, -1)
                                 for j, w in enumerate(ws)])
        order = np.argsort(ids, kind="stable")
        self._ids, self._flags, self._owner_robots = ids[order], flags[order], robots[order]
        # lidar: every world's primitives in one array, each robot casting against its own slice
        self._movable = any(w._movable for w in ws)
        self._any_grid = any(w._lidar_grid is not None for w in ws)
        c_len = np.array([len(w._circles) for w in ws])
        s_len = np.array([len(w._segments) for w in ws])
        p_len = np.array([len(w._prim_kind) for w in ws])
        self._c_off = np.concatenate([[0], np.cumsum(c_len)[:-1]])
        self._s_off = np.concatenate([[0], np.cumsum(s_len)[:-1]])
        self._p_off = np.concatenate([[0], np.cumsum(p_len)[:-1]])
        self._c_len, self._s_len = c_len, s_len
        self._circles = np.concatenate([w._circles for w in ws]).reshape(-1, 3)
        self._segments = np.concatenate([w._segments for w in ws]).reshape(-1, 4)
        self._prim_kind = np.concatenate([w._prim_kind for w in ws]).astype(np.int8)
        self._prim_index = np.concatenate([w._prim_index for w in ws]).astype(np.int32)
        # robot i of world j is circle i of that world's slice
        self._robot_circle = (self._c_off[:, None] + np.arange(n)[None, :]).reshape(-1)
        self._scan_cache: tuple | None = None
        self._layout_ok = True

    # -- physics ----------------------------------------------------------------------------------
    def step(self, wheel_speeds: np.ndarray, active: np.ndarray | None = None) -> None:
        """``worlds[k].step(wheel_speeds=wheel_speeds[k])`` for every ``k``, batched.

        Args:
            wheel_speeds: ``(K, n_robots, 2)`` left/right wheel speeds, rad/s.
            active: ``(K,)`` bools, the worlds to step (default all); rows of the others are ignored.
        """
        self._layout()
        ws, k, n = self._worlds, len(self._worlds), self.n_robots
        sel = self._select(active)
        wheels = np.asarray(wheel_speeds, dtype=np.float64)
        if wheels.shape != (k, n, 2):
            raise ValueError(f"WorldBatch.step: wheel_speeds must have shape ({k}, {n}, 2), got "
                             f"{wheels.shape}")
        if sel is not None:
            wheels = np.where(sel[:, None, None], wheels, 0.0)
        w0 = ws[0]
        spec = w0.scene.robot
        # World.step's elementwise arithmetic on all worlds' rows at once, in one compiled pass
        commands = np.empty((k * n, 2))
        if not _limit_wheels(wheels.reshape(k * n, 2), _COMMAND_CAP, float(spec.max_wheel_speed),
                             float(spec.wheel_radius), float(spec.wheel_base), commands):  # fmt: skip
            bad = np.argwhere(~np.isfinite(wheels))[0]
            raise ValueError(f"WorldBatch.step: wheel_speeds{bad.tolist()} is "
                             f"{wheels[tuple(bad)]}; expected finite numbers")
        on = range(k) if sel is None else np.flatnonzero(sel).tolist()
        with atomic():  # as World.step: Ctrl-C takes effect between steps, never inside one
            self._advance(commands, on, sel)

    def _physics(self) -> dict:
        """The addresses of every world's bodies and spaces for the compiled Chipmunk loops (rebuilt
        when a world was replaced)."""
        if self._phys is None:
            ws = self._worlds
            self._phys = {
                "bodies": np.array([address(b._body) for w in ws for b in w.robot_bodies], np.uintp),
                "controls": np.array([address(c._body) for w in ws for c in w._controls], np.uintp),
                "spaces": np.array([address(w.space._space) for w in ws], np.uintp),
                # fixed for a world's life (drawn when it is built)
                "odometry_scale": np.concatenate([w._odometry.scale for w in ws]),
            }
        return self._phys

    def _replace_physics(self, k: int, world: World) -> None:
        """World ``k``'s rows of :meth:`_physics`' tables, in place (a vector env replaces a world at
        every autoreset; rebuilding the tables of 64 worlds costs ~0.25 ms)."""
        phys = self._phys
        if phys is None:
            return
        k = range(len(self._worlds))[k]
        n = phys["bodies"].size // len(self._worlds)
        if world.n_robots != n:  # _layout refuses the batch; rebuild from scratch after a fix
            self._phys = None
            return
        rows = slice(k * n, (k + 1) * n)
        phys["bodies"][rows] = [address(b._body) for b in world.robot_bodies]
        phys["controls"][rows] = [address(c._body) for c in world._controls]
        phys["spaces"][k] = address(world.space._space)
        phys["odometry_scale"][rows] = world._odometry.scale

    def _advance(self, commands: np.ndarray, on, sel) -> None:
        """World._advance of the worlds ``on`` with their ``(K * n, 2)`` rows of ``commands``."""
        ws, n, w0 = self._worlds, self.n_robots, self._worlds[0]
        dt, substeps = w0.config.physics_dt, w0.config.substeps
        noisy = w0.config.odometry.noise_k > 0
        per_world = commands.reshape(len(ws), n, 2)  # a fresh array, never written: views are safe
        # one pass over the worlds before the physics: commands recorded, odometry gathered (World._record
        # and Odometry.take_ahead inlined: this loop runs 64 times a step in the vector env, and a method
        # call costs more than its work here)
        odos, odo_poses, noise, stepped = [], [], [], []
        for j, applied in zip(on, per_world if sel is None else per_world[sel], strict=True):
            w = ws[j]
            stepped.append(w)
            w._commands = applied
            hist = w._history
            # World._record: bit-identical repeats extend the last run (bytes: -0.0 and 0.0 stay apart)
            if hist and applied.tobytes() == hist[-1].tobytes():
                w._history_counts[-1] += 1
            else:
                hist.append(applied)
                w._history_counts.append(1)
            o = w._odometry
            odos.append(o)
            odo_poses.append(o.pose)
            if noisy:  # Odometry.integrate draws normal(0, 1, (robots, 2)) per substep
                ahead, pos = o.ahead, o.ahead_pos
                if ahead is not None and ahead.shape[0] - pos >= substeps:
                    o.ahead_pos = pos + substeps  # take_ahead when enough are drawn ahead
                    noise.append(ahead[pos : pos + substeps])
                else:
                    noise.append(o.take_ahead(substeps, _ODOMETRY_AHEAD))
        phys, calls = self._physics(), ChipmunkCalls.here()
        bodies, controls, spaces = phys["bodies"], phys["controls"], phys["spaces"]
        if sel is not None:
            rows = np.repeat(sel, n)
            commands, bodies, controls, spaces = commands[rows], bodies[rows], controls[rows], spaces[sel]
        # wheel odometry of every world's robots in one Odometry (World.step: begin, integrate the
        # achieved motion each substep before the drive update, end)
        scale = phys["odometry_scale"] if sel is None else phys["odometry_scale"][rows]
        odo = _stacked_odometry(odos[0], np.concatenate(odo_poses), scale)
        if noisy:
            odo.ahead = np.concatenate(noise, axis=1)
        odo.begin_step()
        drive(calls, bodies, controls, spaces, commands, odo, substeps, dt)
        odo.end_step()
        if odo.ahead is not None and odo.ahead_pos != substeps:
            raise RuntimeError("WorldBatch: odometry noise draws out of step with Odometry.integrate")
        contacts = self._contacts(spaces)
        # the last step's contacts of the stepped worlds, in order (the vector env's task reads them)
        self.stepped_contacts = contacts if sel is None else contacts[sel]
        elapsed = substeps * dt
        # each world's rows as views (Odometry replaces its arrays, never writes into them); iterating
        # an array yields its rows as views at C speed
        for o, w, p, s, d, c in zip(odos, stepped, odo.pose.reshape(-1, n, 3),
                                    odo._step_start.reshape(-1, n, 3), odo.delta.reshape(-1, n, 3),
                                    self.stepped_contacts, strict=True):  # fmt: skip
            o.pose, o._step_start, o.delta = p, s, d
            w.time += elapsed
            w.contacts = c

    def _select(self, active) -> np.ndarray | None:
        if active is None:
            return None
        sel = np.asarray(active, dtype=bool).reshape(-1)
        if sel.shape != (len(self._worlds),):
            raise ValueError(f"WorldBatch: active must have shape ({len(self._worlds)},), got {sel.shape}")
        return None if sel.all() else sel

    def _contacts(self, spaces: np.ndarray) -> np.ndarray:
        """``(K, n_robots)``: ``World._update_contacts``' result for the worlds of ``spaces`` (rows of the
        others zero), their arbiters read in one compiled loop and resolved at once (a fresh array: rows
        can be handed out as views)."""
        pairs_a, _ = ChipmunkCalls.here().arbiter_pairs(spaces)
        n = self.n_robots
        contacts = np.zeros(len(self._worlds) * n, dtype=np.int8)
        if len(pairs_a):
            ids = self._ids
            k = np.minimum(np.searchsorted(ids, pairs_a), len(ids) - 1)
            known = ids[k] == pairs_a
            flag = np.where(known, self._flags[k], Contact.WALL).astype(np.int8)
            robot = np.where(known, self._owner_robots[k], -1)
            for me, other in ((0, 1), (1, 0)):
                m = robot[:, me] >= 0
                np.bitwise_or.at(contacts, robot[m, me], flag[m, other])
        return contacts.reshape(-1, n)

    # -- state ------------------------------------------------------------------------------------
    def poses(self) -> np.ndarray:
        """``(K, n_robots, 3)``: ``worlds[k].poses`` for every ``k`` (theta wrapped), read at once."""
        self._layout()
        bodies = self._physics()["bodies"]
        out = ChipmunkCalls.here().read_poses(bodies, np.empty((bodies.size, 3)))
        wrap_headings(out)  # World.poses' wrap, bit for bit
        return out.reshape(len(self._worlds), self.n_robots, 3)

    # -- sensing ----------------------------------------------------------------------------------
    def scan(self, robots: Sequence[int] | None = None, noise: bool = True,
             active: np.ndarray | None = None) -> tuple[list[Scan | None], np.ndarray]:
        """``[w.scan(robots, noise) for w in worlds]`` in one call of the raycasting kernel.

        Args:
            robots: robot indices to scan in every world (``None``: all).
            noise: apply each world's lidar noise and dropouts, drawn from that world's RNG in the
                order ``World.scan`` draws them.
            active: ``(K,)`` bools, the worlds to scan (default all; others give ``None``).

        Returns:
            ``(scans, poses)``: one :class:`Scan` per world (views into shared buffers) and the
            ``(K, n_robots, 3)`` poses of every robot at the time of the scan.
        """
        combined, poses, on = self.scan_combined(robots, noise, active)
        m = combined.robots.size // max(len(on), 1)
        scans: list[Scan | None] = [None] * len(self._worlds)
        for r, j in enumerate(on):
            sl = slice(r * m, (r + 1) * m)
            scans[j] = Scan(ranges=combined.ranges[sl], angles=combined.angles,
                            hit_kind=combined.hit_kind[sl], hit_index=combined.hit_index[sl],
                            true_ranges=combined.true_ranges[sl], robots=combined.robots[sl],
                            poses=combined.poses[sl], range_max=combined.range_max)
        return scans, poses

    def _noise_handles(self) -> np.ndarray | None:
        """``(K, 3)`` noise handles of the worlds' RNGs (``World._noise_handles``; rebuilt when a world or
        its ``rng`` is another object), ``None`` if one of them is not a PCG64 ``Generator``."""
        # identity, by id: the objects are kept in _noise_rngs (their addresses stay valid, ids not reused)
        ids = [id(w.rng) for w in self._worlds]
        if ids != self._noise_ids:
            hs = [w._noise_handles() for w in self._worlds]
            self._noise_h = None if any(h is None for h in hs) else np.concatenate(hs)
            self._noise_rngs, self._noise_ids = [w.rng for w in self._worlds], ids
        return self._noise_h

    def scan_combined(self, robots: Sequence[int] | None = None, noise: bool = True,
                      active: np.ndarray | None = None) -> tuple[Scan, np.ndarray, list[int]]:
        """:meth:`scan` as one :class:`Scan` whose rows are the scanned robots of the active worlds
        in order (``robots`` per world; ``hit_index`` and ``robots`` are indices within each
        world), the ``(K, n_robots, 3)`` poses and the list of active worlds."""
        self._layout()
        ws, n, k = self._worlds, self.n_robots, len(self._worlds)
        sel = self._select(active)
        on = list(range(k)) if sel is None else np.flatnonzero(sel).tolist()
        spec = ws[0].scene.lidar
        ix = np.arange(n) if robots is None else np.asarray(robots, dtype=np.int64).reshape(-1)
        key = tuple(ix.tolist())
        if self._scan_cache is None or self._scan_cache[0] != key:  # (checked once per robot list)
            if ix.size and (ix.min() < 0 or ix.max() >= n):
                raise ValueError(f"WorldBatch.scan: robot indices must be in [0, {n}), got {ix.tolist()}")
        poses = self.poses()
        if self._movable:  # rare: moved obstacles change their world's primitives
            for w, p in zip(ws, poses, strict=True):
                w._update_lidar_geometry(p)  # (inactive worlds too: it draws no random numbers)
            self._circles = np.concatenate([w._circles for w in ws]).reshape(-1, 3)
            self._segments = np.concatenate([w._segments for w in ws]).reshape(-1, 4)
        else:
            self._circles[self._robot_circle, :2] = poses.reshape(-1, 3)[:, :2]
        if self._scan_cache is None or self._scan_cache[0] != key:
            m = ix.size
            world = np.repeat(np.arange(k), m)
            self._scan_cache = (
                key, world, np.tile(ix, k), self._c_off[world], self._c_off[world] + self._c_len[world],
                self._s_off[world], self._s_off[world] + self._s_len[world], self._p_off[world],
            )
        _, world, skip, c_lo, c_hi, s_lo, s_hi, p_lo = self._scan_cache
        origin = poses[:, ix].reshape(-1, 3)
        if sel is not None:
            rows_on = np.repeat(sel, ix.size)
            skip, c_lo, c_hi, s_lo, s_hi, p_lo, origin = (
                a[rows_on] for a in (skip, c_lo, c_hi, s_lo, s_hi, p_lo, origin)
            )
        rows, nb = origin.shape[0], spec.n_beams
        ranges = np.empty((rows, nb), np.float32)
        true = np.empty((rows, nb), np.float32)
        kind = np.empty((rows, nb), np.int8)
        index = np.empty((rows, nb), np.int32)
        m = ix.size
        # the same kernel choice as World.scan: worlds with a lidar grid (large arenas) are cast through
        # it, one call per such world; all the others together in one call of the brute-force kernel
        gridded = [r for r, j in enumerate(on) if ws[j]._lidar_grid is not None] if self._any_grid else []
        brute = np.ones(rows, dtype=bool)
        for r in gridded:
            brute[r * m : (r + 1) * m] = False
        sub = slice(None) if not gridded else np.flatnonzero(brute)
        if not gridded or sub.size:
            outs = (ranges, true, kind, index) if not gridded else (
                np.empty((sub.size, nb), np.float32), np.empty((sub.size, nb), np.float32),
                np.empty((sub.size, nb), np.int8), np.empty((sub.size, nb), np.int32))  # fmt: skip
            _multi_kernel(
                np.ascontiguousarray(origin[sub, 0]), np.ascontiguousarray(origin[sub, 1]),
                np.ascontiguousarray(origin[sub, 2]), beam_tables(nb), float(spec.range_min),
                float(spec.range_max), self._circles, c_lo[sub], c_hi[sub], skip[sub], self._segments,
                s_lo[sub], s_hi[sub], self._prim_kind, self._prim_index, p_lo[sub], *outs,
            )  # fmt: skip
            if gridded:
                for a, b in zip((ranges, true, kind, index), outs, strict=True):
                    a[sub] = b
        for r in gridded:
            j, rs = on[r], slice(r * m, (r + 1) * m)
            w, c0, s0 = ws[j], self._c_off[j], self._s_off[j]
            # through the world's own kernel arguments and work arrays (World.scan's path)
            static = (w._lidar_static[:3] + (self._circles[c0 : c0 + self._c_len[j]],
                      self._segments[s0 : s0 + self._s_len[j]]) + w._lidar_static[5:])  # fmt: skip
            x, y, theta = origin[rs].T.copy()
            out = cast_prepared(x, y, theta, ix, static, w._lidar_grid_args)
            for a, b in zip((ranges, true, kind, index), out, strict=True):
                a[rs] = b
        if noise and (spec.noise_sigma > 0 or spec.dropout_prob > 0):
            # World.scan's noise, each world drawing from its own RNG in the same order: one compiled call
            # over all worlds (kin_envs.core._noise, bitwise NumPy's draws), or NumPy's calls
            h = self._noise_handles()
            if h is not None:
                apply_noise(true, ranges, m, h if sel is None else h[on], float(spec.noise_sigma),
                            float(spec.dropout_prob), float(spec.range_min), float(spec.range_max))
            else:
                apply_noise_numpy(true, ranges, [ws[j].rng for j in on], float(spec.noise_sigma),
                                  float(spec.dropout_prob), float(spec.range_min), float(spec.range_max))
        combined = Scan(ranges=ranges, angles=spec.angles, hit_kind=kind, hit_index=index,
                        true_ranges=true, robots=np.tile(ix, len(on)), poses=origin,
                        range_max=spec.range_max)
        return combined, poses, on


@numba.njit(cache=True, nogil=True, error_model="numpy")  # cap / 0.0 is inf, as numpy's
def _limit_wheels(flat, cap, limit, radius, base, out):
    """``(k * n, 2)`` wheel speeds -> ``(v, omega)`` commands in ``out``, as ``World.step`` computes them
    (``WorldBatch.step``'s former numpy expressions, operation for operation: no fast-math, so every
    result rounds as numpy's does); False (``out`` unset) if a value is not finite.

    Rows beyond ``cap`` (any of them: then every row is scaled by ``min(1, cap / peak)``, 1 for the
    others) as ``World._check_commands``; the wheel limit ``min(1, limit / max(peak, 1e-12))``; then
    ``v = radius (l + r) / 2``, ``omega = radius (r - l) / base`` (``World.wheel_speeds_to_unicycle``)."""
    rows = flat.shape[0]
    over = False
    for i in range(rows):
        a, b = flat[i, 0], flat[i, 1]
        if not (np.isfinite(a) and np.isfinite(b)):
            return False
        if max(abs(a), abs(b)) > cap:
            over = True
    for i in range(rows):
        a, b = flat[i, 0], flat[i, 1]
        if over:
            m = min(1.0, cap / max(abs(a), abs(b)))
            a, b = a * m, b * m
        m = min(1.0, limit / max(max(abs(a), abs(b)), 1e-12))
        a, b = a * m, b * m
        out[i, 0] = radius * (a + b) / 2
        out[i, 1] = radius * (b - a) / base
    return True


@numba.njit(cache=True, nogil=True)
def _multi_kernel(ox, oy, heading, tabs, range_min, range_max, circles, c_lo, c_hi, skip,
                  segments, s_lo, s_hi, prim_kind, prim_index, p_lo, out_ranges, out_true,
                  out_kind, out_index):  # fmt: skip
    """``_scan_kernel`` with per-origin primitive ranges: origin ``n`` sees circles
    ``c_lo[n]:c_hi[n]`` and segments ``s_lo[n]:s_hi[n]`` (its own world's), and its owner table
    starts at ``p_lo[n]``."""
    n_beams = tabs.shape[1]
    cos_tab = tabs[0]
    sin_tab = tabs[1]
    best_d = np.empty(n_beams)
    best_p = np.empty(n_beams, dtype=np.int32)
    ws = _work(max(circles.shape[0], segments.shape[0]))
    (cx, cy, cr, fx, fy, fr), (sx1, sy1, sx2, sy2) = _columns(circles, segments)
    for n in range(ox.shape[0]):
        c0, c1, s0, s1 = c_lo[n], c_hi[n], s_lo[n], s_hi[n]
        circ = (cx[c0:c1], cy[c0:c1], cr[c0:c1], fx[c0:c1], fy[c0:c1], fr[c0:c1])
        _cast_one(ox[n], oy[n], heading[n], skip[n], range_max, circ,
                  (sx1[s0:s1], sy1[s0:s1], sx2[s0:s1], sy2[s0:s1]), cos_tab, sin_tab, best_d, best_p, ws)
        _write_row(n, best_d, best_p, p_lo[n], prim_kind, prim_index, range_min, range_max, out_ranges,
                   out_true, out_kind, out_index)
