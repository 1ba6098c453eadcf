"""detectors.ros: LaserScan → detector convention, bag reading / writing errors, odometry (no simulator)."""

import math
import subprocess
import sys

import numpy as np
import pytest

from detectors import GeometricKinDetector
from detectors.ros import (
    BagError,
    BagWriter,
    PoseTrack,
    detections_to_records,
    laserscan_arrays,
    read_poses,
    read_scans,
)

pytest.importorskip("rosbags")

KIN = (0.8 * math.cos(0.6), 0.8 * math.sin(0.6))  # a kin housing 0.8 m away, 34 deg to the left
OTHER = (-0.5, -0.9)  # a second kin behind on the right
R = 0.035


def ray_circles(angles, circles):
    """Exact ranges of rays from the origin to circles ``(cx, cy, r)``; inf where nothing is hit."""
    out = np.full(np.shape(angles), np.inf)
    dx, dy = np.cos(angles), np.sin(angles)
    for cx, cy, r in circles:
        b = dx * cx + dy * cy
        disc = b * b - (cx * cx + cy * cy - r * r)
        t = b - np.sqrt(np.maximum(disc, 0.0))
        out = np.minimum(out, np.where((disc >= 0) & (t > 0), t, np.inf))
    return out


def real_revolution(n, increment_sign, offset=0.0071):
    """A LaserScan-like revolution of ``n`` beams at non-integer degrees (float32 fields, as on the wire)."""
    span = 2 * math.pi * (359.6 / 360 if n != 360 else (n - 1) / n)
    inc = float(np.float32(increment_sign * span / (n - 1)))
    a0 = float(np.float32(-math.pi + offset if increment_sign > 0 else math.pi - offset))
    raw = a0 + np.arange(n) * inc
    ranges = ray_circles(raw, [(*KIN, R), (*OTHER, R), (1.5, -0.4, 0.2)]).astype(np.float32)
    return a0, inc, ranges


def test_rplidar_convention_is_reversed_and_rotated_to_the_heading():
    # rplidar_ros: angle_min = -pi, positive increment; message beam k at -pi + k deg
    n = 360
    inc = float(np.float32(2 * math.pi / n))
    ranges = np.arange(n, dtype=np.float32) + 1.0  # value = message index + 1
    r, a, idx = laserscan_arrays(float(np.float32(-math.pi)), inc, ranges, 0.0, 1000.0)
    # detector beam i is i degrees clockwise of the heading: message beam 180 - i
    np.testing.assert_array_equal(idx, (180 - np.arange(n)) % n)
    np.testing.assert_array_equal(r, ranges[idx])
    expected = -np.deg2rad(np.arange(n))
    np.testing.assert_allclose(np.cos(a), np.cos(expected), atol=1e-6)
    np.testing.assert_allclose(np.sin(a), np.sin(expected), atol=1e-6)
    assert abs(a[0]) < 1e-6 and np.all((a > -math.pi) & (a <= math.pi))


def test_clockwise_scan_keeps_order_and_partial_fov_keeps_its_ends():
    r, a, idx = laserscan_arrays(0.0, -math.radians(1.0), np.ones(360), 0.1, 12.0)
    np.testing.assert_array_equal(idx, np.arange(360))
    # a 270-degree lidar (CCW from -135 deg): reversed, not rotated (its ends are not neighbours)
    n = 271
    r, a, idx = laserscan_arrays(-math.radians(135), math.radians(1.0), np.ones(n), 0.1, 12.0)
    np.testing.assert_array_equal(idx, np.arange(n)[::-1])
    assert a[0] == pytest.approx(math.radians(135)) and a[-1] == pytest.approx(-math.radians(135))


def test_a_sweep_that_closes_the_circle_drops_the_repeated_beams():
    # 361 beams from -pi to +pi: the last one repeats the first direction
    inc = float(np.float32(2 * math.pi / 360))
    r, a, idx = laserscan_arrays(float(np.float32(-math.pi)), inc, np.arange(361.0) + 1.0, 0.0, 1000.0)
    assert r.shape == (360,) and sorted(idx.tolist()) == list(range(360))
    # 1.25 turns: only the first turn is kept
    r, a, idx = laserscan_arrays(0.0, -math.radians(1.0), np.ones(450), 0.0, 12.0)
    np.testing.assert_array_equal(idx, np.arange(360))


def test_no_return_readings_become_inf():
    ranges = np.array([0.0, np.inf, np.nan, 0.1, 0.2, 5.0, 12.5, -np.inf, 1.0], dtype=np.float32)
    r, _, idx = laserscan_arrays(0.0, -0.1, ranges, range_min=0.15, range_max=12.0)
    back = np.empty_like(r)
    back[idx] = r
    np.testing.assert_array_equal(
        back, np.float32([np.inf, np.inf, np.inf, np.inf, 0.2, 5.0, np.inf, np.inf, 1.0])
    )


@pytest.mark.parametrize(
    "args, match",
    [
        ((0.0, 0.1, [1.0, 1.0]), "at least 3"),
        ((0.0, 0.0, [1.0] * 5), "non-zero increment"),
        ((float("nan"), 0.1, [1.0] * 5), "finite"),
    ],
)
def test_bad_scan_fields_raise(args, match):
    with pytest.raises(ValueError, match=match):
        laserscan_arrays(*args)


@pytest.mark.parametrize("n", [359, 360, 361])
@pytest.mark.parametrize("sign", [1, -1])
def test_real_revolutions_are_detected_where_the_kin_is(n, sign):
    """359 / 361 beams at non-integer degrees, either sweep direction: both detectors find both kin."""
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from detectors.learned import LearnedKinDetector

    a0, inc, ranges = real_revolution(n, sign)
    ranges[[5, 6, 7]] = [0.0, np.nan, np.inf]  # RPLIDAR no-returns in the background
    r, a, idx = laserscan_arrays(a0, inc, ranges, 0.15, 12.0)
    for det, tol in ((GeometricKinDetector(), 1e-4), (LearnedKinDetector(), 0.01)):
        found = det.detect(r, a).detections
        assert len(found) == 2, (type(det).__name__, found)
        for cx, cy in (KIN, OTHER):
            assert min(math.hypot(d.x - cx, d.y - cy) for d in found) < tol, (type(det).__name__, found)
        recs = detections_to_records(found, idx)
        for d, rec in zip(found, recs, strict=True):
            # the message's beams of the segment hit the kin
            beams = [rec["first_beam"], rec["last_beam"]]
            assert all(np.isfinite(ranges[b]) and ranges[b] < 1.1 for b in beams)
            assert rec["n_beams"] == d.n_beams


def test_learned_detector_refuses_another_lidar_resolution():
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from detectors.learned import LearnedKinDetector

    a0, inc, ranges = real_revolution(720, 1)
    r, a, _ = laserscan_arrays(a0, inc, ranges, 0.15, 12.0)
    assert len(GeometricKinDetector().detect(r, a).detections) == 2  # the geometric one takes any layout
    with pytest.raises(ValueError, match=r"0\.50\d deg apart.*trained on 1\.000 deg"):
        LearnedKinDetector().detect(r, a)


def _write_scan_bag(path, storage, n_scans=3, odom=True):
    """A small bag with /scan (CCW, rplidar_ros style), /odom and /tf, written with BagWriter."""
    a0, inc, ranges = real_revolution(360, 1)
    with BagWriter(path, storage) as w:
        for k in range(n_scans):
            t = 1_000_000_000 + k * 100_000_000
            w.write(
                "/scan",
                "sensor_msgs/msg/LaserScan",
                t,
                w.laserscan(w.header("laser", t), a0, inc, ranges, 0.15, 12),
            )
            if odom:
                q = w.msg("geometry_msgs/msg/Quaternion", z=math.sin(0.1 * k), w=math.cos(0.1 * k))
                pose = w.msg(
                    "geometry_msgs/msg/Pose",
                    position=w.msg("geometry_msgs/msg/Point", x=0.5 * k),
                    orientation=q,
                )
                od = w.msg(
                    "nav_msgs/msg/Odometry",
                    header=w.header("odom", t),
                    child_frame_id="base_link",
                    pose=w.msg("geometry_msgs/msg/PoseWithCovariance", pose=pose),
                )
                w.write("/odom", "nav_msgs/msg/Odometry", t, od)
                tr = w.msg(
                    "geometry_msgs/msg/TransformStamped",
                    header=w.header("odom", t),
                    child_frame_id="laser",
                    transform=w.msg(
                        "geometry_msgs/msg/Transform",
                        translation=w.msg("geometry_msgs/msg/Vector3", x=0.5 * k),
                        rotation=q,
                    ),
                )
                w.write("/tf", "tf2_msgs/msg/TFMessage", t, w.msg("tf2_msgs/msg/TFMessage", transforms=[tr]))
    return ranges


@pytest.mark.parametrize("storage, name", [("mcap", "b"), ("sqlite3", "b"), ("ros1", "b.bag")])
def test_bag_scans_and_poses_read_back(tmp_path, storage, name):
    path = tmp_path / name
    ranges = _write_scan_bag(path, storage)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind
    scans = list(read_scans(path, "/scan"))
    assert [s.stamp_ns for s in scans] == [1_000_000_000, 1_100_000_000, 1_200_000_000]
    assert scans[0].frame_id == "laser" and scans[0].range_max == pytest.approx(12.0)
    np.testing.assert_array_equal(
        scans[1].ranges, np.where(np.isfinite(ranges), ranges, np.inf)[scans[1].msg_index]
    )
    for track in (read_poses(path, "/odom"), read_poses(path, "/tf", "laser")):
        assert track.at(1_100_000_000) == pytest.approx((0.5, 0.0, 0.2))
        assert track.at(1_050_000_000) == pytest.approx((0.25, 0.0, 0.1))  # interpolated
        assert track.at(999_999_999) is None and track.at(1_300_000_000) is None  # no extrapolation


def test_pose_track_interpolates_yaw_across_pi():
    tr = PoseTrack(np.array([0, 10]), np.zeros((2, 2)), np.array([math.pi - 0.1, -math.pi + 0.1]))
    assert abs(tr.at(5)[2]) == pytest.approx(math.pi)


def test_bag_errors_name_the_problem(tmp_path):
    path = tmp_path / "b"
    _write_scan_bag(path, "mcap", n_scans=1)
    with pytest.raises(BagError, match=r"no topic '/lidar'.*/scan \(sensor_msgs/msg/LaserScan\)"):
        list(read_scans(path, "/lidar"))
    with pytest.raises(
        BagError, match=r"'/odom' has message type nav_msgs/msg/Odometry, expected sensor_msgs"
    ):
        list(read_scans(path, "/odom"))
    with pytest.raises(BagError, match="TF topic; name the robot's frame"):
        read_poses(path, "/tf")
    with pytest.raises(BagError, match="no pose of frame 'base_link'; its child frames: laser"):
        read_poses(path, "/tf", "base_link")
    with pytest.raises(BagError, match="no such bag"):
        list(read_scans(tmp_path / "missing", "/scan"))
    bad = tmp_path / "corrupt.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(BagError, match="not a readable ROS bag"):
        list(read_scans(bad, "/scan"))
    mcap = next(path.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:200])  # truncated
    with pytest.raises(BagError, match="(not a readable ROS bag|corrupt)"):
        list(read_scans(path, "/scan"))
    with pytest.raises(FileExistsError):
        BagWriter(path)
    with pytest.raises(ValueError, match="storage must be one of"):
        BagWriter(tmp_path / "x", "ros3")


def test_a_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), BagWriter(tmp_path / "b") as w:
        w.write(
            "/scan", "sensor_msgs/msg/LaserScan", 1, w.laserscan(w.header("l", 1), 0, 0.1, [1.0] * 3, 0, 5)
        )
        raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_missing_rosbags_gives_an_install_hint():
    code = (
        "import sys, importlib.abc\n"
        "class F(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, n, p=None, t=None):\n"
        "        if n.split('.')[0] == 'rosbags': raise ImportError(n)\n"
        "sys.meta_path.insert(0, F())\n"
        "import detectors.ros as r\n"
        "try:\n    list(r.read_scans('x', '/scan'))\nexcept ImportError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "pip install 'kin-envs[ros]'" in out.stdout, out.stderr
