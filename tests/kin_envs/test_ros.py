"""kin_envs.ros: simulated runs recorded as ROS bags and read back through detectors.ros (round trips)."""

import math

import numpy as np
import pytest

from detectors import GeometricKinDetector
from detectors.ros import read_poses, read_scans
from kin_envs import World, scenes

pytest.importorskip("rosbags")

from kin_envs.ros import WorldRecorder, record_episode, rplidar_scan_fields  # noqa: E402

STORAGES = [("mcap", "run"), ("sqlite3", "run"), ("ros1", "run.bag")]


def _commands(n, k):
    """Deterministic wheel commands: every robot turns on the spot at its own rate, some drive."""
    return np.column_stack([0.05 * (np.arange(n) % 2), 0.3 + 0.1 * np.arange(n) + 0.05 * k])


def _record_world_run(path, storage, detector, steps=4):
    """Record a noise-free paper scene run; return the detector's results on each step's fresh scans."""
    world = World(scenes.paper_scenario(2, distance=0.5), seed=0)
    direct = []
    with WorldRecorder(path, storage=storage, detector=detector) as rec:
        for k in range(steps + 1):
            scan = world.scan()
            direct.append((scan, detector.detect_batch(scan.ranges, scan.angles), world.odometry))
            rec.record(world)
            world.step(commands=_commands(world.n_robots, k))
    return world, direct


def _same_detections(from_bag, direct):
    assert len(from_bag) == len(direct)
    for a, b in zip(from_bag, direct, strict=True):
        assert (a.first_beam, a.last_beam, a.n_beams) == (b.first_beam, b.last_beam, b.n_beams)
        # LaserScan stores angle_min / angle_increment as float32: the beams' angles agree to ~1e-7 rad
        for f in ("range", "bearing", "x", "y", "score"):
            assert getattr(a, f) == pytest.approx(getattr(b, f), abs=1e-6), f


@pytest.mark.parametrize("storage, name", STORAGES)
def test_recorded_run_read_back_gives_the_direct_detections(tmp_path, storage, name):
    det = GeometricKinDetector()
    world, direct = _record_world_run(tmp_path / name, storage, det)
    n_seen = 0
    for i in range(world.n_robots):
        scans = list(read_scans(tmp_path / name, f"/robot_{i}/scan"))
        assert len(scans) == len(direct)
        for s, (scan, results, _) in zip(scans, direct, strict=True):
            # the simulator's beam order and ranges exactly; its 12 m "no return" as inf
            sim = scan.ranges[i].astype(np.float64)
            np.testing.assert_array_equal(s.ranges, np.where(sim >= 12.0, np.inf, sim))
            np.testing.assert_allclose(np.cos(s.angles - scan.angles), 1.0, atol=1e-12)
            found = det.detect(s.ranges, s.angles).detections
            _same_detections(found, results[i].detections)
            n_seen += len(found)
        bag = tmp_path / name
        truth = read_poses(bag, f"/robot_{i}/ground_truth")
        odom, tf_odom = read_poses(bag, f"/robot_{i}/odom"), read_poses(bag, "/tf", f"robot_{i}/base_link")
        drift = read_poses(bag, "/tf", f"robot_{i}/odom")  # world -> robot_i/odom
        for s, (scan, _, odometry) in zip(scans, direct, strict=True):
            for track, want in ((truth, scan.poses[i]), (odom, odometry[i]), (tf_odom, odometry[i])):
                x, y, yaw = track.at(s.stamp_ns)
                assert (x, y) == pytest.approx(tuple(want[:2]), abs=1e-9)
                assert math.cos(yaw - want[2]) == pytest.approx(1.0, abs=1e-12)
            # REP 105: world -> odom composed with odom -> base_link is the true pose
            dx, dy, dth = drift.at(s.stamp_ns)
            ox, oy, oth = odometry[i]
            c, si = math.cos(dth), math.sin(dth)
            assert (dx + c * ox - si * oy, dy + si * ox + c * oy) == pytest.approx(
                tuple(scan.poses[i, :2]), abs=1e-9
            )
            assert math.cos(dth + oth - scan.poses[i, 2]) == pytest.approx(1.0, abs=1e-12)
    last_scan, _, last_odometry = direct[-1]
    assert np.abs(last_odometry[:, :2] - last_scan.poses[:, :2]).max() > 1e-6  # the wheel odometry drifts
    assert n_seen >= len(direct)  # the observer sees the kin (and the same-radius cylinder) each step


def test_learned_detector_round_trip(tmp_path):
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from detectors.learned import LearnedKinDetector

    det = LearnedKinDetector()
    world, direct = _record_world_run(tmp_path / "run", "mcap", det, steps=2)
    for i in range(world.n_robots):
        for s, (_, results, _) in zip(read_scans(tmp_path / "run", f"/robot_{i}/scan"), direct, strict=True):
            _same_detections(det.detect(s.ranges, s.angles).detections, results[i].detections)


def test_recorded_topics_and_markers(tmp_path):
    from detectors.ros import open_reader

    world, direct = _record_world_run(tmp_path / "run", "mcap", GeometricKinDetector(), steps=1)
    with open_reader(tmp_path / "run") as r:
        topics = {t: (i.msgtype, i.msgcount) for t, i in r.topics.items()}
        markers = [
            len(r.deserialize(raw, c.msgtype).markers) - 1  # minus the DELETEALL
            for c, _, raw in r.messages([c for c in r.connections if c.topic == "/robot_0/kin_detections"])
        ]
        gt = [
            r.deserialize(raw, c.msgtype)
            for c, _, raw in r.messages([c for c in r.connections if c.topic == "/ground_truth/kin"])
        ]
    n = world.n_robots
    assert topics["/tf"] == ("tf2_msgs/msg/TFMessage", 2)
    assert topics["/ground_truth/kin"] == ("geometry_msgs/msg/PoseArray", 2)
    assert topics["/ground_truth/kin_markers"] == ("visualization_msgs/msg/MarkerArray", 2)
    # static obstacles: written once (markers without a lifetime persist)
    assert topics["/ground_truth/obstacles"] == ("visualization_msgs/msg/MarkerArray", 1)
    for i in range(n):
        assert topics[f"/robot_{i}/scan"] == ("sensor_msgs/msg/LaserScan", 2)
        assert topics[f"/robot_{i}/odom"] == ("nav_msgs/msg/Odometry", 2)
        assert topics[f"/robot_{i}/ground_truth"] == ("nav_msgs/msg/Odometry", 2)
    assert markers == [len(res[0].detections) for _, res, _ in direct]
    assert len(gt[0].poses) == n
    assert gt[0].poses[1].position.x == pytest.approx(direct[0][0].poses[1, 0])


def test_rplidar_fields_put_the_heading_beam_in_the_middle():
    ranges = (1.0 + 0.01 * np.arange(360)).astype(np.float32)
    ranges[3] = 12.0
    f = rplidar_scan_fields(ranges, 0.15, 12.0)
    assert f["angle_min"] == pytest.approx(-math.pi) and f["angle_increment"] == pytest.approx(
        math.radians(1)
    )
    out = f["ranges"]
    assert out[180] == ranges[0]  # message beam 180 points at 0 rad: simulator beam 0
    assert out[179] == ranges[1]  # 1 degree clockwise: simulator beam 1
    assert out[0] == ranges[180]  # -pi: simulator beam 180
    assert np.isinf(out[177])  # simulator beam 3 read range_max: no return


def _gym_rollout(env, seed, steps):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(env.action_space.sample())
        out.append(obs)
    return out


def test_record_episode_gym_does_not_change_the_episode(tmp_path):
    import gymnasium as gym

    kw = {"n_distractors": 2, "noise_sigma": 0.01}
    ref = _gym_rollout(gym.make("kin_envs/KinSeek-v2", **kw), 3, 4)

    seen = []
    env = gym.make("kin_envs/KinSeek-v2", **kw)
    info = record_episode(
        env, tmp_path / "seek", seed=3, steps=4, policy=None, detector=GeometricKinDetector()
    )
    assert info["steps"] == 4 and info["records"] == 5
    # the recorded robot-0 scans are the (noisy) scans the agent observed
    scans = list(read_scans(tmp_path / "seek", "/robot_0/scan"))
    for s, obs in zip(scans, ref, strict=True):
        seen.append(np.where(np.isinf(s.ranges), 12.0, s.ranges) / 12.0)
        np.testing.assert_allclose(seen[-1], obs[:360], atol=1e-6)


def test_record_episode_parallel(tmp_path):
    from kin_envs import aggregation_v2

    env = aggregation_v2.parallel_env(n_robots=3, detector=None)
    info = record_episode(env, tmp_path / "swarm", seed=0, steps=3, storage="sqlite3")
    assert info == {"steps": 3, "records": 4, "path": str(tmp_path / "swarm")}
    for i in range(3):
        assert len(list(read_scans(tmp_path / "swarm", f"/robot_{i}/scan"))) == 4
    with pytest.raises(TypeError, match="kin_envs env"):
        record_episode(object(), tmp_path / "x")


def test_same_seed_same_bag_contents(tmp_path):
    from detectors.ros import open_reader
    from kin_envs import aggregation_v2

    def contents(name, seed):
        env = aggregation_v2.parallel_env(n_robots=3, noise_sigma=0.01)
        record_episode(env, tmp_path / name, seed=seed, steps=3)
        with open_reader(tmp_path / name) as r:
            return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]

    a, b, c = contents("a", 5), contents("b", 5), contents("c", 6)
    assert a == b
    assert a != c
