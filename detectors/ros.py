"""ROS bags in and out for the detectors, without ROS and without the simulator.

Reads ``sensor_msgs/LaserScan`` and odometry (``nav_msgs/Odometry`` or ``tf2_msgs/TFMessage``) from
ROS 1 bags and ROS 2 bags (sqlite3 and MCAP storage), and writes bags (detections as
``visualization_msgs/MarkerArray``), with the pure-Python `rosbags <https://pypi.org/project/rosbags/>`_
library (``pip install kin-envs[ros]``; imported only inside the functions that need it).

**Scan mapping** (:func:`laserscan_arrays`). A LaserScan's beam ``k`` points at
``angle_min + k * angle_increment`` (rad, CCW positive, in the message's ``frame_id``). The detectors
take ``(ranges, angles)`` in any one-directional sweep; this module hands them the *project's* order
so that both detectors see a real scan exactly as they see a simulated one (the learned detector's
segment features follow the sweep direction, and its checkpoint was trained on the simulator's):

* angles are computed in float64 from the message's float32 ``angle_min`` / ``angle_increment``
  and wrapped to (-pi, pi]; nothing is resampled, every beam keeps its real direction (a real
  RPLIDAR revolution of 359 or 361 beams at non-integer degrees is fed as it is);
* a positive ``angle_increment`` (counter-clockwise, what ``rplidar_ros`` publishes) is reversed
  into a clockwise sweep, as the RPLIDAR turns and as the simulator's beam ``i`` lies ``i`` steps
  clockwise of the heading;
* a full revolution (:func:`detectors.geometric.is_circular_sweep`) is rotated to start at the beam
  nearest the heading (angle 0); a partial field of view keeps its ends;
* ``msg_index[i]`` is the message index of detector beam ``i`` (``Detection.first_beam`` etc. refer to
  detector beams; :func:`detections_to_records` maps them back to message indices);
* a sweep that closes the circle (``angle_max = angle_min + 2 pi``, as some drivers publish) loses the
  beams that repeat the first directions;
* no return: ``0.0``, ``inf`` and ``NaN``, and any reading outside ``[range_min, range_max]``,
  becomes ``inf`` (both detectors treat non-finite ranges as no return).
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .base import Detection, wrap_angle
from .geometric import is_circular_sweep

__all__ = [
    "BagError",
    "BagWriter",
    "PointSets",
    "PoseTrack",
    "RosScan",
    "detection_markers",
    "detections_to_records",
    "laserscan_arrays",
    "make_msg",
    "open_reader",
    "read_pose_arrays",
    "read_poses",
    "read_scans",
    "stamp_ns",
    "to_stamp",
]

_INSTALL_HINT = "reading and writing ROS bags needs the 'ros' extra: pip install 'kin-envs[ros]'"
SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_ARRAY_TYPE = "geometry_msgs/msg/PoseArray"
STORAGES = ("mcap", "sqlite3", "ros1")
#: the housing radius drawn for a detection marker, m (the paper's RPLIDAR A1)
HOUSING_RADIUS = 0.035


class BagError(ValueError):
    """A bag that cannot be read as asked: missing, corrupt, no such topic, wrong message type."""


def _rosbags():
    try:
        import rosbags  # noqa: F401
    except ImportError as e:  # pragma: no cover - exercised only without the extra
        raise ImportError(_INSTALL_HINT) from e


# --------------------------------------------------------------------------- scan mapping


def laserscan_arrays(
    angle_min: float,
    angle_increment: float,
    ranges,
    range_min: float = 0.0,
    range_max: float = math.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A LaserScan's fields → ``(ranges, angles, msg_index)`` in the detectors' convention.

    See the module docstring for the mapping. Returns float64 ``ranges`` (no return = ``inf``),
    float64 ``angles`` (rad, robot frame, CCW positive, (-pi, pi], a clockwise sweep) and int
    ``msg_index`` (detector beam ``i`` is message beam ``msg_index[i]``). Beams that complete more than
    one revolution (a driver that repeats the first direction at the end) are left out. Raises
    ``ValueError`` for fewer than 3 beams or a zero / non-finite increment.
    """
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    n = r.shape[0]
    a0, inc = float(angle_min), float(angle_increment)
    if n < 3:
        raise ValueError(f"a LaserScan needs at least 3 ranges, got {n}")
    if not (math.isfinite(a0) and math.isfinite(inc)) or inc == 0.0:
        raise ValueError(
            f"LaserScan angle_min / angle_increment must be finite with a non-zero increment, got "
            f"angle_min = {a0}, angle_increment = {inc}"
        )
    # some drivers close the circle (angle_max = angle_min + 2 pi): beams that repeat the directions of
    # the first ones are dropped (msg_index skips them)
    n_keep = int(np.count_nonzero(np.arange(n) * abs(inc) < 2.0 * math.pi - 0.5 * abs(inc)))
    lo = float(range_min) if math.isfinite(float(range_min)) else 0.0
    hi = float(range_max) if float(range_max) > 0 else math.inf
    bad = ~np.isfinite(r) | (r <= 0.0) | (r < lo) | (r > hi)
    r = np.where(bad, np.inf, r)
    angles = wrap_angle(a0 + np.arange(n) * inc)
    idx = np.arange(n_keep)
    if inc > 0:  # counter-clockwise → the project's clockwise sweep
        idx = idx[::-1]
    if is_circular_sweep(angles[idx]):
        idx = np.roll(idx, -int(np.argmin(np.abs(angles[idx]))))
    return r[idx], angles[idx], idx


@dataclass(frozen=True, eq=False)
class RosScan:
    """One LaserScan mapped onto the detectors' convention (see :func:`laserscan_arrays`).

    ``stamp_ns``: the header stamp (ns; the bag's log time if the header stamp is zero);
    ``log_ns``: when the bag logged it; ``ranges`` / ``angles`` / ``msg_index``: detector beams.
    """

    index: int
    stamp_ns: int
    log_ns: int
    frame_id: str
    ranges: np.ndarray
    angles: np.ndarray
    msg_index: np.ndarray
    range_min: float
    range_max: float
    msg: object = None  #: the deserialised message (to copy it into another bag)


def stamp_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (``sec``, ``nanosec``) as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


# --------------------------------------------------------------------------- reading


@contextlib.contextmanager
def open_reader(bag):
    """Open a ROS 1 bag file or a ROS 2 bag directory (sqlite3 or MCAP) with ``rosbags``' AnyReader.

    Raises :class:`BagError` naming the path if it does not exist or is not a readable bag.
    """
    _rosbags()
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(bag)
    if not path.exists():
        raise BagError(f"{path}: no such bag (expected a ROS 1 .bag file or a ROS 2 bag directory)")
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except Exception as e:  # rosbags raises its own error types per format
        raise BagError(f"{path}: not a readable ROS bag ({type(e).__name__}: {e})") from e
    try:
        yield reader
    finally:
        reader.close()


def _connections(reader, bag, topic: str, types: Sequence[str]):
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(reader.topics.items())) or "none"
        raise BagError(f"{bag}: no topic {topic!r} in the bag; topics: {have}")
    wrong = [c.msgtype for c in conns if c.msgtype not in types]
    if wrong:
        raise BagError(f"{bag}: topic {topic!r} has message type {wrong[0]}, expected {' or '.join(types)}")
    return conns


def _messages(reader, bag, conns):
    try:
        for con, t, raw in reader.messages(connections=conns):
            yield con, t, reader.deserialize(raw, con.msgtype)
    except BagError:
        raise
    except Exception as e:
        raise BagError(f"{bag}: corrupt or unreadable message ({type(e).__name__}: {e})") from e


def count_messages(bag, topic: str) -> int:
    """Number of messages on ``topic`` (for progress bars); :class:`BagError` if there is none."""
    with open_reader(bag) as reader:
        return sum(c.msgcount for c in _connections(reader, bag, topic, (SCAN_TYPE, ODOM_TYPE, TF_TYPE)))


def read_scans(bag, topic: str) -> Iterator[RosScan]:
    """Every ``sensor_msgs/LaserScan`` on ``topic``, in log-time order, mapped by :func:`laserscan_arrays`.

    Raises :class:`BagError` for a missing bag or topic, another message type, or a corrupt message.
    """
    with open_reader(bag) as reader:
        conns = _connections(reader, bag, topic, (SCAN_TYPE,))
        for k, (_, t, msg) in enumerate(_messages(reader, bag, conns)):
            try:
                r, a, idx = laserscan_arrays(
                    msg.angle_min, msg.angle_increment, msg.ranges, msg.range_min, msg.range_max
                )
            except ValueError as e:
                raise BagError(f"{bag}: {topic} message {k}: {e}") from None
            st = stamp_ns(msg.header.stamp)
            yield RosScan(
                k,
                st if st else int(t),
                int(t),
                str(msg.header.frame_id),
                r,
                a,
                idx,
                float(msg.range_min),
                float(msg.range_max),
                msg,
            )


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


@dataclass(frozen=True, eq=False)
class PoseTrack:
    """Planar poses over time: ``stamps_ns`` (m,) sorted, ``xy`` (m, 2) m, ``yaw`` (m,) rad."""

    stamps_ns: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    frame_id: str = ""

    def at(self, t_ns: int) -> tuple[float, float, float] | None:
        """The pose at ``t_ns``, linearly interpolated (yaw along the shorter arc); ``None`` outside the
        track's time span (no extrapolation)."""
        s = self.stamps_ns
        if s.size == 0 or t_ns < s[0] or t_ns > s[-1]:
            return None
        j = int(np.searchsorted(s, t_ns, side="left"))
        if s[j] == t_ns:
            return float(self.xy[j, 0]), float(self.xy[j, 1]), float(self.yaw[j])
        i = j - 1
        w = (t_ns - s[i]) / (s[j] - s[i])
        xy = self.xy[i] + w * (self.xy[j] - self.xy[i])
        yaw = wrap_angle(float(self.yaw[i] + w * wrap_angle(float(self.yaw[j] - self.yaw[i]))))
        return float(xy[0]), float(xy[1]), float(yaw)


def read_poses(bag, topic: str, child_frame: str | None = None) -> PoseTrack:
    """The robot's planar pose over time from ``nav_msgs/Odometry`` or ``tf2_msgs/TFMessage`` on ``topic``.

    Odometry: ``pose.pose`` at each header stamp (in the message's ``header.frame_id``). TF: the
    transforms whose ``child_frame_id`` is ``child_frame`` (required for TF; leading ``/`` ignored).
    Raises :class:`BagError` if the topic is missing, of another type, or holds no such pose.
    """
    with open_reader(bag) as reader:
        conns = _connections(reader, bag, topic, (ODOM_TYPE, TF_TYPE))
        is_tf = conns[0].msgtype == TF_TYPE
        if is_tf and not child_frame:
            raise BagError(f"{bag}: {topic} is a TF topic; name the robot's frame (child_frame_id) to follow")
        want = (child_frame or "").lstrip("/")
        rows, frame, seen = [], "", set()
        for _, _, msg in _messages(reader, bag, conns):
            if is_tf:
                for tr in msg.transforms:
                    seen.add(tr.child_frame_id)
                    if tr.child_frame_id.lstrip("/") == want:
                        v, q = tr.transform.translation, tr.transform.rotation
                        rows.append((stamp_ns(tr.header.stamp), v.x, v.y, _yaw(q)))
                        frame = tr.header.frame_id
            else:
                p = msg.pose.pose
                rows.append((stamp_ns(msg.header.stamp), p.position.x, p.position.y, _yaw(p.orientation)))
                frame = msg.header.frame_id
    if not rows:
        if not is_tf:
            raise BagError(f"{bag}: {topic} is empty")
        frames = ", ".join(sorted(seen)) or "none"
        raise BagError(
            f"{bag}: {topic} has no pose of frame {want!r}; its child frames: {frames} "
            "(kin-envs detect: choose one with --base-frame)"
        )
    rows.sort(key=lambda r: r[0])
    a = np.asarray(rows, dtype=np.float64)
    stamps = np.asarray([r[0] for r in rows], dtype=np.int64)
    return PoseTrack(stamps, a[:, 1:3], a[:, 3], str(frame))


@dataclass(frozen=True, eq=False)
class PointSets:
    """Sets of world points over time (e.g. every kin's true position): ``stamps_ns`` (m,) sorted and
    ``points[j]`` (k_j, 2) at ``stamps_ns[j]``."""

    stamps_ns: np.ndarray
    points: list

    def nearest(self, t_ns: int) -> np.ndarray:
        """The point set with the stamp nearest to ``t_ns``."""
        j = int(np.argmin(np.abs(self.stamps_ns - np.int64(t_ns))))
        return self.points[j]


def read_pose_arrays(bag, topic: str) -> PointSets:
    """The positions of every ``geometry_msgs/PoseArray`` on ``topic`` (e.g. ground-truth kin poses).

    Raises :class:`BagError` if the topic is missing, of another type, or empty.
    """
    with open_reader(bag) as reader:
        conns = _connections(reader, bag, topic, (POSE_ARRAY_TYPE,))
        rows = [
            (
                stamp_ns(m.header.stamp),
                np.array([[p.position.x, p.position.y] for p in m.poses]).reshape(-1, 2),
            )
            for _, _, m in _messages(reader, bag, conns)
        ]
    if not rows:
        raise BagError(f"{bag}: {topic} is empty")
    rows.sort(key=lambda r: r[0])
    return PointSets(np.array([r[0] for r in rows], dtype=np.int64), [r[1] for r in rows])


def detections_to_records(
    detections: Sequence[Detection], msg_index: np.ndarray, pose: tuple[float, float, float] | None = None
) -> list[dict]:
    """Plain dicts for output: the detection's fields, beams as *message* indices, and world ``wx, wy``
    when the robot's ``pose`` (x, y, yaw) is known."""
    out = []
    for d in detections:
        rec = {
            "range": d.range,
            "bearing": d.bearing,
            "x": d.x,
            "y": d.y,
            "score": d.score,
            "first_beam": int(msg_index[d.first_beam]),
            "last_beam": int(msg_index[d.last_beam]),
            "n_beams": d.n_beams,
        }
        if pose is not None:
            px, py, yaw = pose
            c, s = math.cos(yaw), math.sin(yaw)
            rec["wx"] = px + c * d.x - s * d.y
            rec["wy"] = py + s * d.x + c * d.y
        out.append(rec)
    return out


# --------------------------------------------------------------------------- writing


@functools.cache
def _typestore(storage: str):
    """One typestore per ROS version and process: rosbags compiles (de)serialisers per typestore."""
    _rosbags()
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if storage != "ros1":
        return get_typestore(Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.ROS1_NOETIC)
    if TF_TYPE not in ts.types:  # rosbags' Noetic store lacks tf2_msgs; its definition is one line
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_TYPE))
    return ts


_NP = {
    "float32": np.float32,
    "float64": np.float64,
    "int8": np.int8,
    "uint8": np.uint8,
    "byte": np.uint8,
    "char": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "bool": np.bool_,
}


def _default(ts, desc):
    kind, arg = desc
    k = int(kind)
    if k == 1:  # base type
        name = arg[0]
        return "" if name == "string" else False if name == "bool" else 0.0 if name.startswith("float") else 0
    if k == 2:  # nested message
        return make_msg(ts, arg)
    sub, size = arg
    if int(sub[0]) == 1 and sub[1][0] in _NP:
        return np.zeros(size if k == 3 else 0, dtype=_NP[sub[1][0]])
    return [_default(ts, sub) for _ in range(size)] if k == 3 else []


def make_msg(ts, msgtype: str, **fields):
    """A message of ``msgtype`` from typestore ``ts``: the given fields, every other field at its zero
    default (so one call works across ROS distributions whose messages differ in extra fields).

    Defaults are built once per type and shared between messages (they are only serialised, never
    modified)."""
    _, cls, defaults = _defaults(ts, msgtype)
    if not fields.keys() <= defaults.keys():
        raise TypeError(f"{msgtype} has no field(s) {sorted(set(fields) - set(defaults))}")
    return cls(**{**defaults, **fields})


# keyed by id(ts); the entry holds ts itself, so that id cannot be reused by another typestore
_DEFAULTS: dict[tuple[int, str], tuple[object, type, dict]] = {}


def _defaults(ts, msgtype: str):
    key = (id(ts), msgtype)
    hit = _DEFAULTS.get(key)
    if hit is None:
        _, defs = ts.fielddefs[msgtype]
        hit = _DEFAULTS[key] = (ts, ts.types[msgtype], {n: _default(ts, d) for n, d in defs})
    return hit


def to_stamp(ts, t_ns: int):
    """Integer nanoseconds → ``builtin_interfaces/Time``."""
    t_ns = int(t_ns)
    return make_msg(
        ts, "builtin_interfaces/msg/Time", sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000
    )


class BagWriter:
    """Write a bag atomically: ROS 2 with MCAP (default) or sqlite3 storage, or a ROS 1 ``.bag``.

    Everything is written under a temporary name beside ``path`` and renamed to ``path`` when the
    ``with`` block succeeds (a failed run leaves no half-written bag); ``path`` must not exist.
    ``header(frame_id, t_ns)`` builds a header for this bag's ROS version; ``write(topic, msgtype,
    t_ns, msg)`` adds the topic on first use.
    """

    def __init__(self, path, storage: str = "mcap") -> None:
        if storage not in STORAGES:
            raise ValueError(f"storage must be one of {STORAGES}, got {storage!r}")
        self.path = Path(path)
        self.storage = storage
        self.ts = _typestore(storage)
        if self.path.exists():
            raise FileExistsError(f"{self.path} already exists; remove it or choose another output path")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"{self.path.parent}: output directory does not exist")
        self._writer = None
        self._conns: dict[str, object] = {}
        self._tmpdir: str | None = None
        self._seq = 0

    def __enter__(self) -> BagWriter:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin, Writer

        self._tmpdir = tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        tmp = Path(self._tmpdir) / self.path.name
        try:
            if self.storage == "ros1":
                self._writer = Writer1(tmp)
            else:
                plugin = StoragePlugin.MCAP if self.storage == "mcap" else StoragePlugin.SQLITE3
                self._writer = Writer(tmp, version=9, storage_plugin=plugin)
            self._writer.open()
        except BaseException:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self._writer.close()
            if exc_type is None:
                os.replace(Path(self._tmpdir) / self.path.name, self.path)
        finally:
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    def header(self, frame_id: str, t_ns: int):
        kw = {"stamp": to_stamp(self.ts, t_ns), "frame_id": frame_id}
        if self.storage == "ros1":
            self._seq += 1
            kw["seq"] = self._seq
        return make_msg(self.ts, "std_msgs/msg/Header", **kw)

    def msg(self, msgtype: str, **fields):
        return make_msg(self.ts, msgtype, **fields)

    def write(self, topic: str, msgtype: str, t_ns: int, msg) -> None:
        con = self._conns.get(topic)
        if con is None:
            con = self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self.ts)
        if self.storage == "ros1":
            data = self.ts.serialize_ros1(msg, msgtype)
        else:
            data = self.ts.serialize_cdr(msg, msgtype)
        self._writer.write(con, int(t_ns), data)

    def laserscan(self, header, angle_min, angle_increment, ranges, range_min, range_max, **fields):
        """A ``sensor_msgs/LaserScan`` (``angle_max`` from the others unless given; ranges as float32)."""
        r = np.asarray(ranges, dtype=np.float32)
        fields.setdefault(
            "angle_max", float(np.float32(angle_min) + np.float32(angle_increment) * (r.shape[0] - 1))
        )
        return self.msg(
            SCAN_TYPE,
            header=header,
            angle_min=float(angle_min),
            angle_increment=float(angle_increment),
            range_min=float(range_min),
            range_max=float(range_max),
            ranges=r,
            **fields,
        )


def _color(w: BagWriter, r: float, g: float, b: float, a: float = 1.0):
    return w.msg("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a)


def _pose(w: BagWriter, x: float, y: float, yaw: float = 0.0, z: float = 0.0):
    q = w.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    return w.msg(
        "geometry_msgs/msg/Pose", position=w.msg("geometry_msgs/msg/Point", x=x, y=y, z=z), orientation=q
    )


def detection_markers(w: BagWriter, frame_id: str, t_ns: int, points, ns: str = "kin_detections", color=None):
    """A ``visualization_msgs/MarkerArray``: DELETEALL, then one cylinder of the housing's radius per
    ``(x, y)`` in ``points`` (frame ``frame_id``), so each array replaces the previous one in RViz /
    Foxglove."""
    mt = "visualization_msgs/msg/Marker"
    hdr = w.header(frame_id, t_ns)
    markers = [w.msg(mt, header=hdr, ns=ns, id=0, action=3)]
    rgba = _color(w, *(color or (0.1, 0.9, 0.2, 0.8)))
    scale = w.msg("geometry_msgs/msg/Vector3", x=2 * HOUSING_RADIUS, y=2 * HOUSING_RADIUS, z=0.05)
    for k, (x, y) in enumerate(points):
        markers.append(
            w.msg(
                mt,
                header=hdr,
                ns=ns,
                id=k + 1,
                type=3,
                action=0,
                pose=_pose(w, float(x), float(y)),
                scale=scale,
                color=rgba,
            )
        )
    return w.msg("visualization_msgs/msg/MarkerArray", markers=markers)
