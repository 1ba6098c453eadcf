"""Simulated runs out as ROS bags: any World run or env episode → ROS 2 (MCAP / sqlite3) or ROS 1 bag.

Per recorded step (stamp = ``world.time`` + ``start_ns``), for every robot ``i``:

* ``/robot_i/scan`` ``sensor_msgs/LaserScan`` in frame ``robot_i/base_link`` (the lidar sits at the
  robot's centre), in the convention of the RPLIDAR's ROS driver (``rplidar_ros``): ``angle_min`` =
  -pi (for an even beam count), ``angle_increment`` = +2 pi / n (counter-clockwise), ``angle_max`` =
  pi - 2 pi / n; ``range_min`` / ``range_max`` from the lidar spec; **no return is ``inf``** (the
  simulator's ``range_max`` readings: nothing hit, or a surface closer than ``range_min``);
* ``/robot_i/odom`` ``nav_msgs/Odometry``: the robot's **wheel odometry** (``World.odometry``, which
  drifts; frame ``robot_i/odom`` = the world frame at t = 0, child ``robot_i/base_link``);
* ``/robot_i/ground_truth`` ``nav_msgs/Odometry``: the true pose (frame ``world``; twists in the child
  frame);
* ``/robot_i/kin_detections`` ``visualization_msgs/MarkerArray`` (frame ``robot_i/base_link``) when a
  detector is given;

and once per step: ``/tf`` (REP 105: ``world`` → ``robot_i/odom``, the odometry's drift, and
``robot_i/odom`` → ``robot_i/base_link``, the odometry), ``/ground_truth/kin``
``geometry_msgs/PoseArray`` (every robot's pose, frame ``world``) and ``/ground_truth/kin_markers``
(the robots' housings as cylinders, a MarkerArray); ``/ground_truth/obstacles`` (a MarkerArray: cylinders
and polygon edges, frame ``world``) is written at the first step and again only when an obstacle moved.

Reading such a bag back with :func:`detectors.ros.read_scans` gives the simulator's beam order and
ranges exactly (angles to float32 precision; tested). The bag-writing machinery is simulator-free and
lives in :mod:`detectors.ros`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from detectors.ros import HOUSING_RADIUS, ODOM_TYPE, SCAN_TYPE, BagWriter, detection_markers
from kin_envs.core.world import Scan, World

__all__ = ["WorldRecorder", "record_episode", "rplidar_scan_fields"]

WORLD_FRAME = "world"
_MARKERS = "visualization_msgs/msg/MarkerArray"


def rplidar_scan_fields(ranges, range_min: float, range_max: float) -> dict[str, Any]:
    """One robot's simulated scan (simulator beam order: beam ``i`` at ``i`` steps clockwise of the
    heading) → LaserScan fields in ``rplidar_ros``' convention (see the module docstring)."""
    r = np.asarray(ranges, dtype=np.float32)
    n = r.shape[0]
    res = 2.0 * math.pi / n
    h = n // 2
    # message beam k points at -(h - k) * res, the simulator's beam (h - k) mod n
    out = r[(h - np.arange(n)) % n]
    out = np.where(out >= np.float32(range_max), np.float32(np.inf), out)
    return {
        "angle_min": -h * res,
        "angle_increment": res,
        "ranges": out,
        "range_min": range_min,
        "range_max": range_max,
    }


class WorldRecorder:
    """Record World states to a bag (see the module docstring for topics and conventions).

    Args:
        path: the bag to create (a ROS 2 bag directory, or a ``.bag`` file for ``storage="ros1"``);
            written atomically, must not exist.
        storage: ``"mcap"`` (default), ``"sqlite3"`` or ``"ros1"``.
        detector: a :class:`detectors.KinDetector` whose detections are recorded as markers, or None.
        start_ns: ROS time of ``world.time == 0`` (default 1 s, so no stamp is zero).

    Use as a context manager; call :meth:`record` once per step. Recording never changes the run:
    robots the caller did not scan are scanned without noise, which draws nothing from the world's RNG.
    """

    def __init__(self, path, storage: str = "mcap", detector=None, start_ns: int = 1_000_000_000) -> None:
        self.writer = BagWriter(path, storage)
        self.detector = detector
        self.start_ns = int(start_ns)
        self.n_records = 0
        self._obstacles = None  # the obstacle geometry last written

    def __enter__(self) -> WorldRecorder:
        self.writer.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.__exit__(*exc)

    def record(self, world: World, scan: Scan | None = None) -> list:
        """Write one step: ``scan``'s rows as they are, every other robot scanned noise-free.

        Returns the detector's results per robot (empty list without a detector).
        """
        w = self.writer
        t = self.start_ns + round(world.time * 1e9)
        full = _all_rows(world, scan)
        poses = full.poses
        spec = world.scene.lidar
        results = []
        if self.detector is not None:
            results = self.detector.detect_batch(full.ranges, full.angles)
        vel = world.velocities
        odo, odo_delta = world.odometry, world.odometry_delta
        dt = world.config.control_dt
        transforms = []
        for i in range(world.n_robots):
            base, odom_frame = f"robot_{i}/base_link", f"robot_{i}/odom"
            fields = rplidar_scan_fields(full.ranges[i], spec.range_min, spec.range_max)
            scan_msg = w.laserscan(w.header(base, t), scan_time=dt, **fields)
            w.write(f"/robot_{i}/scan", SCAN_TYPE, t, scan_msg)
            x, y, th = (float(v) for v in poses[i])
            c, s = math.cos(th), math.sin(th)
            vx, vy, om = (float(v) for v in vel[i])
            # ground truth (Gazebo's p3d style): world frame, twist in the robot frame
            truth = _odometry(w, WORLD_FRAME, base, t, (x, y, th), (c * vx + s * vy, -s * vx + c * vy, om))
            w.write(f"/robot_{i}/ground_truth", ODOM_TYPE, t, truth)
            # wheel odometry (drifts): the odom frame is the world frame at t = 0
            ox, oy, oth = (float(v) for v in odo[i])
            wheel = _odometry(
                w, odom_frame, base, t, (ox, oy, oth), tuple(float(v) / dt for v in odo_delta[i])
            )
            w.write(f"/robot_{i}/odom", ODOM_TYPE, t, wheel)
            # REP 105: world -> odom (the drift: true pose composed with the inverse odometry) -> base_link
            dth = th - oth
            cd, sd = math.cos(dth), math.sin(dth)
            transforms.append(
                _transform(
                    w, WORLD_FRAME, odom_frame, t, x - (cd * ox - sd * oy), y - (sd * ox + cd * oy), dth
                )
            )
            transforms.append(_transform(w, odom_frame, base, t, ox, oy, oth))
            if self.detector is not None:
                pts = [(d.x, d.y) for d in results[i].detections]
                w.write(f"/robot_{i}/kin_detections", _MARKERS, t, detection_markers(w, base, t, pts))
        w.write("/tf", "tf2_msgs/msg/TFMessage", t, w.msg("tf2_msgs/msg/TFMessage", transforms=transforms))
        kin = w.msg(
            "geometry_msgs/msg/PoseArray",
            header=w.header(WORLD_FRAME, t),
            poses=[_pose(w, float(p[0]), float(p[1]), float(p[2])) for p in poses],
        )
        w.write("/ground_truth/kin", "geometry_msgs/msg/PoseArray", t, kin)
        w.write("/ground_truth/kin_markers", _MARKERS, t, _kin_markers(w, poses, t))
        # static obstacles are written once: markers without a lifetime stay until replaced
        geom = (world._circles[world.n_robots :].copy(), world._segments.copy())
        old = self._obstacles
        if old is None or not all(np.array_equal(a, b) for a, b in zip(geom, old, strict=True)):
            w.write("/ground_truth/obstacles", _MARKERS, t, _obstacle_markers(w, world, t))
            self._obstacles = geom
        self.n_records += 1
        return results


def _all_rows(world: World, scan: Scan | None) -> Scan:
    """A Scan of every robot: ``scan``'s rows where given, noise-free scans (no RNG draw) for the rest."""
    if (
        scan is not None
        and scan.robots.shape[0] == world.n_robots
        and np.array_equal(scan.robots, np.arange(world.n_robots))
    ):
        return scan
    full = world.scan(noise=False)
    if scan is None:
        return full
    ranges = full.ranges.copy()
    ranges[scan.robots] = scan.ranges
    return Scan(
        ranges=ranges,
        angles=full.angles,
        hit_kind=full.hit_kind,
        hit_index=full.hit_index,
        true_ranges=full.true_ranges,
        robots=full.robots,
        poses=full.poses,
        range_max=full.range_max,
    )


def _odometry(w: BagWriter, frame: str, child: str, t: int, pose, twist):
    """``nav_msgs/Odometry``: ``pose`` (x, y, yaw) in ``frame``, ``twist`` (vx, vy, omega) in ``child``."""
    vx, vy, om = twist
    tw = w.msg(
        "geometry_msgs/msg/Twist",
        linear=w.msg("geometry_msgs/msg/Vector3", x=vx, y=vy),
        angular=w.msg("geometry_msgs/msg/Vector3", z=om),
    )
    return w.msg(
        ODOM_TYPE,
        header=w.header(frame, t),
        child_frame_id=child,
        pose=w.msg("geometry_msgs/msg/PoseWithCovariance", pose=_pose(w, *pose)),
        twist=w.msg("geometry_msgs/msg/TwistWithCovariance", twist=tw),
    )


def _transform(w: BagWriter, parent: str, child: str, t: int, x: float, y: float, yaw: float):
    return w.msg(
        "geometry_msgs/msg/TransformStamped",
        header=w.header(parent, t),
        child_frame_id=child,
        transform=w.msg(
            "geometry_msgs/msg/Transform",
            translation=w.msg("geometry_msgs/msg/Vector3", x=x, y=y),
            rotation=_quat(w, yaw),
        ),
    )


def _quat(w: BagWriter, yaw: float):
    return w.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _pose(w: BagWriter, x: float, y: float, yaw: float):
    return w.msg(
        "geometry_msgs/msg/Pose",
        position=w.msg("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
        orientation=_quat(w, yaw),
    )


def _kin_markers(w: BagWriter, poses: np.ndarray, t: int):
    """Every robot's lidar housing (what a kin detector looks for) as a blue cylinder, frame ``world``."""
    mt = "visualization_msgs/msg/Marker"
    hdr = w.header(WORLD_FRAME, t)
    blue = w.msg("std_msgs/msg/ColorRGBA", r=0.2, g=0.4, b=1.0, a=1.0)
    d = 2 * HOUSING_RADIUS
    scale = w.msg("geometry_msgs/msg/Vector3", x=d, y=d, z=0.1)
    markers = [w.msg(mt, header=hdr, ns="kin", id=0, action=3)]
    for i, (x, y, th) in enumerate(poses.tolist()):
        markers.append(
            w.msg(
                mt, header=hdr, ns="kin", id=i + 1, type=3, pose=_pose(w, x, y, th), scale=scale, color=blue
            )
        )
    return w.msg(_MARKERS, markers=markers)


def _obstacle_markers(w: BagWriter, world: World, t: int):
    """Obstacles as grey cylinders (circles) and one line list of polygon and wall edges, frame ``world``."""
    mt = "visualization_msgs/msg/Marker"
    hdr = w.header(WORLD_FRAME, t)
    # the lidar geometry the last scan used (kept current by World.scan): circles (x, y, r), segments
    circles, segments = world._circles[world.n_robots :], world._segments
    grey = w.msg("std_msgs/msg/ColorRGBA", r=0.6, g=0.6, b=0.6, a=1.0)
    markers = [w.msg(mt, header=hdr, ns="obstacles", id=0, action=3)]
    for k, (x, y, r) in enumerate(circles.tolist()):
        scale = w.msg("geometry_msgs/msg/Vector3", x=2 * r, y=2 * r, z=0.1)
        markers.append(
            w.msg(
                mt,
                header=hdr,
                ns="obstacles",
                id=k + 1,
                type=3,
                pose=_pose(w, x, y, 0.0),
                scale=scale,
                color=grey,
            )
        )
    if segments.shape[0]:
        pts = [w.msg("geometry_msgs/msg/Point", x=a, y=b, z=0.0) for a, b in segments.reshape(-1, 2).tolist()]
        markers.append(
            w.msg(
                mt,
                header=hdr,
                ns="obstacles",
                id=len(circles) + 1,
                type=5,
                pose=_pose(w, 0.0, 0.0, 0.0),
                scale=w.msg("geometry_msgs/msg/Vector3", x=0.02),
                color=grey,
                points=pts,
            )
        )
    return w.msg(_MARKERS, markers=markers)


def record_episode(
    env,
    path,
    *,
    seed: int = 0,
    steps: int | None = None,
    policy: Callable[[Any], Any] | None = None,
    storage: str = "mcap",
    detector=None,
    progress: bool = False,
) -> dict:
    """Run one episode of a Gymnasium env or a PettingZoo parallel env of kin_envs and record it.

    Args:
        env: ``gymnasium.make("kin_envs/...")`` or ``aggregation_v2.parallel_env(...)``.
        path: the bag to create (see :class:`WorldRecorder`).
        seed: reset seed; the random actions (without ``policy``) are seeded with it too.
        steps: stop after this many steps (default: the episode's end).
        policy: ``policy(observation) -> action`` (Gymnasium) or ``policy(observations) -> actions``
            (PettingZoo, dicts by agent); default: seeded random actions.
        detector: recorded as markers (default: none; the env's own detector channel is untouched).

    Returns ``{"steps": n, "records": n + 1, "path": str}``. The scans the env computed are recorded
    as they are (with its noise); robots it did not scan are recorded noise-free.
    """
    parallel = hasattr(env, "possible_agents")
    base = env if parallel else getattr(env, "unwrapped", env)
    if not hasattr(base, "world"):
        raise TypeError(f"record_episode: expected a kin_envs env with a .world, got {type(base).__name__}")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 0):
        raise ValueError(f"record_episode: steps must be an integer >= 0 or None, got {steps!r}")
    if parallel:
        obs, _ = env.reset(seed=seed)
        for k, a in enumerate(env.possible_agents):
            env.action_space(a).seed(seed + k)
    else:
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc="record", unit="step")
    n = 0
    with WorldRecorder(path, storage=storage, detector=detector) as rec:
        rec.record(base.world, base._last_scan)
        while steps is None or n < steps:
            if parallel:
                if not env.agents:
                    break
                act = policy(obs) if policy else {a: env.action_space(a).sample() for a in env.agents}
                obs, _, term, trunc, _ = env.step(act)
                done = not env.agents or all(term.values()) or all(trunc.values())
            else:
                act = policy(obs) if policy else env.action_space.sample()
                obs, _, term, trunc, _ = env.step(act)
                done = term or trunc
            n += 1
            rec.record(base.world, base._last_scan)
            if bar is not None:
                bar.update(1)
            if done:
                break
    if bar is not None:
        bar.close()
    return {"steps": n, "records": n + 1, "path": str(Path(path))}
