"""The ``kin-envs`` console script (kin_envs.commands): record a bag, detect on it, errors."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from detectors import GeometricKinDetector
from kin_envs.commands import main

pytest.importorskip("rosbags")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def swarm_bag(tmp_path_factory):
    """A 3-robot aggregation episode (4 steps) recorded by the CLI, with direct detections per robot."""
    d = tmp_path_factory.mktemp("cli")
    bag = d / "swarm"
    argv = [
        "record",
        str(bag),
        "--env",
        "aggregation_v2",
        "--env-kwargs",
        '{"n_robots": 3, "arena_size": 2.0}',
    ]
    assert main([*argv, "--steps", "4", "--seed", "1", "--quiet"]) == 0
    return bag


def test_entry_point_is_declared():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["scripts"]["kin-envs"] == "kin_envs.commands:main"
    assert any(r.startswith("rosbags") for r in meta["project"]["optional-dependencies"]["ros"])
    assert "ros" in meta["project"]["optional-dependencies"]["all"][0]
    assert not any("rosbags" in r for r in meta["project"]["dependencies"])  # optional, not core


def test_record_writes_the_bag_and_its_run_record(swarm_bag):
    run = json.loads(Path(str(swarm_bag) + ".run.json").read_text())
    assert run["env"] == "aggregation_v2" and run["seed"] == 1 and run["steps"] == 4
    assert run["command"].startswith("kin-envs record")
    assert (swarm_bag / "metadata.yaml").is_file() and list(swarm_bag.glob("*.mcap"))


def test_detect_jsonl_matches_the_detector_on_the_bag(swarm_bag, tmp_path):
    from detectors.ros import read_scans

    out = tmp_path / "d.jsonl"
    argv = ["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--odom", "/robot_1/ground_truth"]
    assert main([*argv, "--out", str(out), "--truth", "/ground_truth/kin", "--quiet"]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    scans = list(read_scans(swarm_bag, "/robot_1/scan"))
    assert len(rows) == len(scans) == 5
    det = GeometricKinDetector()
    for row, s in zip(rows, scans, strict=True):
        assert row["stamp_ns"] == s.stamp_ns and row["frame_id"] == "robot_1/base_link"
        assert row["pose"] is not None
        direct = det.detect(s.ranges, s.angles).detections
        # the command batches scans (detect_batch): equal to detect's results up to rounding
        assert [d["n_beams"] for d in row["detections"]] == [d.n_beams for d in direct]
        got = [v for d in row["detections"] for v in (d["x"], d["y"])]
        assert got == pytest.approx([v for d in direct for v in (d.x, d.y)], abs=1e-12)
        for d in row["detections"]:  # world coordinates from the odometry pose
            p = row["pose"]
            c, si = np.cos(p["yaw"]), np.sin(p["yaw"])
            assert d["wx"] == pytest.approx(p["x"] + c * d["x"] - si * d["y"])
            assert d["wy"] == pytest.approx(p["y"] + si * d["x"] + c * d["y"])
            # no obstacles, no noise: every detection is a robot's housing, found to the micrometre
            assert d["truth_error"] < 1e-5
    assert sum(len(r["detections"]) for r in rows) >= 1  # robots 0 and 2 are in view in this arena
    # the run record beside the output, as `kin-envs record` writes one beside its bag
    run = json.loads(Path(str(out) + ".run.json").read_text())
    assert run["command"].startswith("kin-envs detect") and run["topic"] == "/robot_1/scan"
    assert run["detector"] == "geometric" and run["scans"] == 5
    assert run["detections"] == sum(len(r["detections"]) for r in rows)
    assert run["within_truth_gate"] == run["detections"] and run["truth_gate"] == 0.05


def test_detect_csv_tf_and_markers(swarm_bag, tmp_path):
    from detectors.ros import open_reader

    out, markers = tmp_path / "d.csv", tmp_path / "markers.bag"
    argv = ["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--odom", "/tf", "--out", str(out)]
    assert main([*argv, "--markers", str(markers), "--quiet"]) == 0
    jl = tmp_path / "d.jsonl"
    assert main(["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--out", str(jl), "--quiet"]) == 0
    per_scan = [len(json.loads(line)["detections"]) for line in jl.read_text().splitlines()]
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == sum(per_scan)
    assert all(r["wx"] != "" and r["pose_yaw"] != "" for r in rows)
    with open_reader(markers) as r:  # a ROS 1 bag: the scans and one MarkerArray per scan
        topics = {t: (i.msgtype, i.msgcount) for t, i in r.topics.items()}
        counts = [
            len(r.deserialize(raw, c.msgtype).markers) - 1
            for c, _, raw in r.messages([c for c in r.connections if c.topic.endswith("kin_detections")])
        ]
    assert topics["/robot_1/scan"] == ("sensor_msgs/msg/LaserScan", 5)
    assert topics["/robot_1/scan/kin_detections"] == ("visualization_msgs/msg/MarkerArray", 5)
    assert counts == per_scan


def test_detect_learned_runs(swarm_bag, tmp_path):
    pytest.importorskip("torch")
    out = tmp_path / "l.jsonl"
    assert (
        main(
            [
                "detect",
                str(swarm_bag),
                "--topic",
                "/robot_0/scan",
                "--detector",
                "learned",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    assert len(out.read_text().splitlines()) == 5


def _odometry_steps(scans, poses):
    """Each scan with the odometry increment since the previous one (robot frame there) and the time step,
    as `kin-envs detect --track` computes them (the first scan: zero, 0.1 s)."""
    prev = None
    for s in scans:
        p = poses.at(s.stamp_ns)
        if prev is None:
            delta, dt = np.zeros(3), 0.1
        else:
            c, si = np.cos(prev[1][2]), np.sin(prev[1][2])
            dx, dy = p[0] - prev[1][0], p[1] - prev[1][1]
            delta = np.array([c * dx + si * dy, -si * dx + c * dy, p[2] - prev[1][2]])
            dt = (s.stamp_ns - prev[0]) / 1e9
        prev = (s.stamp_ns, p)
        yield s, delta, dt


def test_detect_track_follows_the_detections_through_the_wheel_odometry(swarm_bag, tmp_path):
    """--track: every scan carries the KinTracker's tracks, fed with the bag's wheel odometry; they are
    the tracks of a KinTracker run directly on the same scans and odometry increments, and each sits on
    that scan's detection (robot and odometry frames); the CSV holds them as record=track rows."""
    from detectors.ros import read_poses, read_scans
    from detectors.tracking import KinTracker

    out = tmp_path / "t.jsonl"
    argv = ["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--odom", "/robot_1/odom", "--track",
            "--track-feed", "accepted"]  # fmt: skip
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    scans, poses = list(read_scans(swarm_bag, "/robot_1/scan")), read_poses(swarm_bag, "/robot_1/odom")
    direct, det = KinTracker(), GeometricKinDetector()
    for row, (s, delta, dt) in zip(rows, _odometry_steps(scans, poses), strict=True):
        direct.update_from_result(det.detect(s.ranges, s.angles), s.ranges, s.angles, delta, dt)
        assert [t["id"] for t in row["tracks"]] == [t.id for t in direct.tracks()]
        for t in row["tracks"]:
            d = min(row["detections"], key=lambda d: np.hypot(d["x"] - t["x"], d["y"] - t["y"]))
            assert np.hypot(d["x"] - t["x"], d["y"] - t["y"]) < 0.03
            assert np.hypot(d["wx"] - t["wx"], d["wy"] - t["wy"]) < 0.03
    assert sum(len(r["tracks"]) for r in rows) >= 1
    assert any(len(r["tracks"]) and r["tracks"][0]["frames_seen"] > 1 for r in rows)  # followed over scans
    csv_out = tmp_path / "t.csv"
    assert main([*argv, "--out", str(csv_out), "--quiet"]) == 0
    recs = list(csv.DictReader(csv_out.open()))
    assert {r["record"] for r in recs} == {"detection", "track"}
    assert sum(r["record"] == "track" for r in recs) == sum(len(r["tracks"]) for r in rows)


def test_detect_track_feeds_the_permissive_candidates_by_default(swarm_bag, tmp_path):
    """--track (--track-feed auto) with the geometric detector: the tracks are those of a KinTracker with the
    geometric track classifier fed each scan's permissive candidates (kin_envs.envs.tracks.PermissiveFeed, as
    the v2 envs' tracker=True) and the same odometry increments; the run record names the feed; a bad feed is
    refused."""
    from detectors.ros import read_poses, read_scans
    from detectors.tracking import KinTracker, segment_points
    from kin_envs.envs.tracks import PermissiveFeed

    out = tmp_path / "t.jsonl"
    argv = ["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--odom", "/robot_1/odom", "--track"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    scans, poses = list(read_scans(swarm_bag, "/robot_1/scan")), read_poses(swarm_bag, "/robot_1/odom")
    direct = KinTracker(kin_model="geometric")  # the classifier fitted on that feed
    feed = PermissiveFeed(GeometricKinDetector(), direct.params.range_noise)
    for row, (s, delta, dt) in zip(rows, _odometry_steps(scans, poses), strict=True):
        one = np.zeros(1, np.int64)
        _, (r, x, y, sc, acc, first, last, noise) = feed.detect(s.ranges[None], s.angles, one,
                                                                np.zeros((1, 3)), range_max=s.range_max)
        pts, own = segment_points(s.ranges[None], s.angles, r, first, last, s.range_max)
        direct.update_batch(one.repeat(len(x)), np.c_[x, y], sc, delta[None], dt, pts, own, noise,
                            accepted=acc)  # fmt: skip
        got = [(t["id"], t["kin_prob"]) for t in row["tracks"]]
        assert got == [(t.id, t.kin_prob) for t in direct.tracks()]
    assert sum(len(r["tracks"]) for r in rows) >= 1
    assert json.loads((tmp_path / "t.jsonl.run.json").read_text())["track_feed"] == "auto"
    with pytest.raises(SystemExit):
        main([*argv, "--track-feed", "all", "--out", str(out), "--quiet"])


def test_detect_beam_has_the_same_fields_and_matches_the_detector(swarm_bag, tmp_path):
    from detectors.beam_detector import BeamKinDetector
    from detectors.ros import read_scans

    argv = ["detect", str(swarm_bag), "--topic", "/robot_1/scan", "--odom", "/robot_1/ground_truth"]
    argv.append("--quiet")
    rows = {}
    for name in ("geometric", "beam"):
        out = tmp_path / f"{name}.jsonl"
        assert main([*argv, "--detector", name, "--out", str(out)]) == 0
        rows[name] = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r.keys() for r in rows["beam"]] == [r.keys() for r in rows["geometric"]]
    scans = list(read_scans(swarm_bag, "/robot_1/scan"))
    direct = BeamKinDetector().detect_batch(np.stack([s.ranges for s in scans]), scans[0].angles)
    n = 0
    for row, res in zip(rows["beam"], direct, strict=True):
        assert [d["n_beams"] for d in row["detections"]] == [d.n_beams for d in res.detections]
        got = [v for d in row["detections"] for v in (d["x"], d["y"], d["score"])]
        assert got == pytest.approx([v for d in res.detections for v in (d.x, d.y, d.score)], abs=1e-9)
        for d in row["detections"]:
            assert set(d) == {*"range bearing x y score first_beam last_beam n_beams wx wy".split()}
            n += 1
    assert n >= 1  # robots 0 and 2 are in view: the beam detector finds at least one of them
    csv_out = tmp_path / "beam.csv"
    assert main([*argv, "--detector", "beam", "--out", str(csv_out)]) == 0
    with csv_out.open() as f:
        assert len(list(csv.DictReader(f))) == n


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--topic", "/nope"], "no topic '/nope' in the bag; topics: /ground_truth/kin"),
        (
            ["--topic", "/robot_0/odom"],
            "has message type nav_msgs/msg/Odometry, expected sensor_msgs/msg/LaserScan",
        ),
        (
            ["--topic", "/robot_0/scan", "--odom", "/robot_0/scan"],
            "expected nav_msgs/msg/Odometry or tf2_msgs",
        ),
        (["--topic", "/robot_0/scan", "--out", "x.txt"], "--out must end in .jsonl or .csv"),
        (
            ["--topic", "/robot_0/scan", "--checkpoint", "x.pt"],
            "--checkpoint applies to --detector learned or beam",
        ),
        (["--topic", "/robot_0/scan", "--truth", "/ground_truth/kin"], "--truth needs --odom"),
        (["--topic", "/robot_0/scan", "--truth-gate", "-0.05"], "--truth-gate must be a distance > 0 m"),
        (["--topic", "/robot_0/scan", "--truth-gate", "nan"], "must be a distance > 0 m, got nan"),
        (["--topic", "/robot_0/scan", "--track"], "--track needs --odom"),
        (
            ["--topic", "/robot_0/scan", "--odom", "/tf", "--truth", "/tf"],
            "expected geometry_msgs/msg/PoseArray",
        ),
    ],
)
def test_detect_errors(swarm_bag, tmp_path, capsys, extra, message):
    assert main(["detect", str(swarm_bag), *extra, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "kin-envs detect: error:" in err and message in err
    assert not list(tmp_path.iterdir())  # nothing written


def test_detect_corrupt_and_missing_bags(tmp_path, capsys):
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"not a bag at all")
    assert main(["detect", str(bad), "--topic", "/scan"]) == 2
    assert "not a readable ROS bag" in capsys.readouterr().err
    assert main(["detect", str(tmp_path / "none"), "--topic", "/scan"]) == 2
    assert "no such bag" in capsys.readouterr().err


def test_record_errors(tmp_path, capsys, swarm_bag):
    assert main(["record", str(swarm_bag), "--env", "aggregation_v2", "--quiet"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["record", str(tmp_path / "x"), "--env", "kin_envs/Nope-v0", "--quiet"]) == 2
    assert "--env 'kin_envs/Nope-v0'" in capsys.readouterr().err
    # the id without its namespace (as the README's table spells the names): the message lists the ids
    assert main(["record", str(tmp_path / "x"), "--env", "KinSeek-v2", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--env 'KinSeek-v2'" in err and "Expected one of kin_envs/KinFollow-v0" in err
    assert "kin_envs/KinSeek-v2" in err and "aggregation_v2" in err
    assert not list(tmp_path.iterdir())


def test_module_runs_as_a_script(swarm_bag):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "kin_envs.commands",
            "detect",
            str(swarm_bag),
            "--topic",
            "/robot_2/scan",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert len(out.stdout.splitlines()) == 5 and "5 scans" in out.stderr
