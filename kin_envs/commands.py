"""The ``kin-envs`` console script: kin detection on ROS bags, and simulated episodes recorded as bags.

``kin-envs detect BAG --topic /scan [--detector geometric|learned|beam] [--odom /odom] [--track
[--track-feed auto|accepted|permissive]] [--out FILE.jsonl|.csv] [--markers OUT_BAG]`` runs a detector on
every ``sensor_msgs/LaserScan`` of a ROS 1 or ROS 2 bag and writes the detections per scan with their
stamps (with ``--track``, also the multi-frame ``detectors.KinTracker``'s tracks, fed with the odometry
between scans and the detector's permissive candidates (``--track-feed auto``, the geometric detector's
default) or its detections) and beside them the run record ``FILE.run.json``;
``kin-envs record OUT --env ID`` records one env episode to a bag (:func:`kin_envs.ros.record_episode`).
Run ``kin-envs COMMAND --help`` for the options. Also runnable as ``python -m kin_envs.commands``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import shlex
import sys
from pathlib import Path

import numpy as np

from detectors.fileio import atomic_write, write_json
from kin_envs.cli import detector_from_name

__all__ = ["main"]

# one CSV row per detection (scans without detections have no row; the JSON Lines output has one line
# per scan); pose_* / wx, wy with --odom, truth_error with --truth
_CSV_FIELDS = (
    *("scan", "stamp_ns", "stamp", "frame_id", "detection", "range", "bearing", "x", "y", "score"),
    *("first_beam", "last_beam", "n_beams", "pose_x", "pose_y", "pose_yaw", "wx", "wy", "truth_error"),
)
# with --track: a "record" column (detection / track) and the track's columns; a track row's x, y are in the
# robot frame at the scan, wx, wy in the --odom frame
_CSV_TRACK_FIELDS = (
    *("record", "track_id", "vx", "vy", "existence", "kin_prob", "frames_seen", "confirmed", "is_kin"),
)


def _make_detector(name: str, checkpoint: str | None):
    if checkpoint and name not in ("learned", "beam"):
        raise ValueError("--checkpoint applies to --detector learned or beam only")
    if name == "learned":
        with contextlib.suppress(ImportError):  # no torch: detector_from_name says so
            import torch

            torch.set_num_threads(1)  # a tiny network: more threads only add contention
    # per-segment reports are not written out: skip building them
    return detector_from_name(name, checkpoint=checkpoint, reports=False)


def _output_format(out: str | None) -> str:
    if out is None:
        return "jsonl"
    suffix = Path(out).suffix.lower()
    if suffix in (".jsonl", ".ndjson"):
        return "jsonl"
    if suffix == ".csv":
        return "csv"
    raise ValueError(f"--out must end in .jsonl or .csv, got {out!r}")


def _markers_storage(path: str) -> str:
    return "ros1" if path.lower().endswith(".bag") else "mcap"


def detect(args: argparse.Namespace) -> int:
    from detectors import ros

    fmt = _output_format(args.out)
    if not (math.isfinite(args.truth_gate) and args.truth_gate > 0):
        raise ValueError(f"--truth-gate must be a distance > 0 m, got {args.truth_gate}")
    detector = _make_detector(args.detector, args.checkpoint)
    bag = Path(args.bag)
    for out in (args.out, args.markers):
        if out:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
    n_msgs = ros.count_messages(bag, args.topic)
    scans = ros.read_scans(bag, args.topic)
    first = next(scans, None)  # checks the type (BagError) before anything is written
    track = None
    if args.odom:
        child = args.base_frame or (first.frame_id if first is not None else None)
        track = ros.read_poses(bag, args.odom, child)
    if args.track and not args.odom:
        raise ValueError("--track needs --odom: the tracker follows objects through the robot's motion "
                         "between scans (a nav_msgs/Odometry or TF topic)")  # fmt: skip
    tracker = None
    if args.track:
        from detectors.tracking import KinTracker
        from kin_envs.envs.tracks import auto_kin_model, make_feeder

        # the track classifier fitted on what feeds it, as the v2 envs' tracker=True
        kt = KinTracker(kin_model=auto_kin_model(args.track_feed, detector))
        tracker = _ScanTracker(kt, make_feeder(args.track_feed, detector, kt.params.range_noise))
    truth = None
    if args.truth:
        if not args.odom:
            raise ValueError("--truth needs --odom (detections are compared in the odometry frame)")
        truth = ros.read_pose_arrays(bag, args.truth)

    out_cm = atomic_write(args.out, "w") if args.out else contextlib.nullcontext(sys.stdout)
    markers_cm = (
        ros.BagWriter(args.markers, _markers_storage(args.markers))
        if args.markers
        else contextlib.nullcontext()
    )
    from tqdm import tqdm

    n_scans = n_dets = n_true = n_tracks = 0
    with out_cm as f, markers_cm as mw:
        fields = (*_CSV_FIELDS, *_CSV_TRACK_FIELDS) if tracker is not None else _CSV_FIELDS
        writer = csv.DictWriter(f, fieldnames=fields) if fmt == "csv" else None
        if writer is not None:
            writer.writeheader()
        bar = tqdm(total=n_msgs, desc=f"detect {args.topic}", unit="scan", disable=args.quiet)
        for s, result in _detect_chunks(detector, _chain(first, scans)):
            pose = track.at(s.stamp_ns) if track is not None else None
            recs = ros.detections_to_records(result.detections, s.msg_index, pose)
            if truth is not None and pose is not None:
                pts = truth.nearest(s.stamp_ns)
                for d in recs:
                    # the observer's own pose is in the set but never within range_min of a detection
                    d["truth_error"] = float(np.hypot(pts[:, 0] - d["wx"], pts[:, 1] - d["wy"]).min())
                    n_true += d["truth_error"] <= args.truth_gate
            row = {
                "scan": s.index,
                "stamp_ns": s.stamp_ns,
                "stamp": s.stamp_ns / 1e9,
                "frame_id": s.frame_id,
                "n_beams": int(s.ranges.shape[0]),
                "pose": None if pose is None else {"x": pose[0], "y": pose[1], "yaw": pose[2]},
                "detections": recs,
            }
            tracks = None
            if tracker is not None:
                tracks = tracker.step(s, result, pose)
                row["tracks"] = tracks
                n_tracks += 0 if tracks is None else sum(t["is_kin"] for t in tracks)
            if writer is None:
                f.write(json.dumps(row) + "\n")
            else:
                for k, d in enumerate(recs):
                    pose_cols = (
                        {} if pose is None else dict(zip(("pose_x", "pose_y", "pose_yaw"), pose, strict=True))
                    )
                    writer.writerow(
                        {
                            **{c: row[c] for c in ("scan", "stamp_ns", "stamp", "frame_id")},
                            "detection": k,
                            **d,
                            **pose_cols,
                            **({"record": "detection"} if tracker is not None else {}),
                        }
                    )
                for t in tracks or []:
                    writer.writerow({**{c: row[c] for c in ("scan", "stamp_ns", "stamp", "frame_id")},
                                     "record": "track", "track_id": t["id"],
                                     **{c: v for c, v in t.items() if c != "id"}})  # fmt: skip
            if mw is not None:
                _write_marker_scan(mw, args.topic, s, result.detections)
            n_scans += 1
            n_dets += len(recs)
            bar.update(1)
        bar.close()
    record_path = args.out or args.markers  # the run record beside the output (none for stdout alone)
    if record_path:
        run = {
            "command": shlex.join(["kin-envs", *args.argv]),
            **{k: getattr(args, k) for k in ("bag", "topic", "detector", "checkpoint", "odom", "base_frame")},
            **{k: getattr(args, k) for k in ("truth", "truth_gate", "track", "track_feed", "out", "markers")},
            "scans": n_scans,
            "detections": n_dets,
            **({"within_truth_gate": n_true} if truth is not None else {}),
            **({"kin_tracks": n_tracks} if tracker is not None else {}),
        }
        write_json(str(record_path).rstrip("/") + ".run.json", run)
    if truth is not None:
        print(f"{n_true} of {n_dets} detections within {args.truth_gate} m of a true kin", file=sys.stderr)
    print(
        f"{n_scans} scans, {n_dets} detections ({args.detector})"
        + (f" -> {args.out}" if args.out else "")
        + (f"; markers -> {args.markers}" if args.markers else "")
        + (f"; {n_tracks} kin tracks over all scans (KinTracker)" if tracker is not None else ""),
        file=sys.stderr,
    )
    return 0


class _ScanTracker:
    """Feeds a :class:`detectors.KinTracker` scan by scan: the odometry increment between scans comes from
    the bag's poses (``--odom``), in the robot frame at the previous scan; the tracks are reported in the
    robot frame at the scan (``x, y``, ``vx, vy``) and in the odometry frame (``wx, wy``)."""

    def __init__(self, tracker, feeder=None) -> None:
        self.tracker = tracker
        self.feeder = feeder  # kin_envs.envs.tracks.PermissiveFeed, or None: the detections alone
        self.prev = None  # (stamp_ns, pose) of the last tracked scan
        self.origin = None  # the odometry pose at the first tracked scan (the tracker's frame origin)

    def step(self, s, result, pose) -> list[dict] | None:
        if pose is None:  # outside the odometry's time span: no motion known, no tracking
            return None
        import math

        from detectors.base import wrap_angle

        if self.prev is None:
            delta, dt, self.origin = np.zeros(3), 0.1, pose
        else:
            t0, (x0, y0, th0) = self.prev
            c, sn = math.cos(th0), math.sin(th0)
            dx, dy = pose[0] - x0, pose[1] - y0
            delta = np.array([c * dx + sn * dy, -sn * dx + c * dy, wrap_angle(pose[2] - th0)])
            dt = max((s.stamp_ns - t0) / 1e9, 1e-3)  # equal stamps: still a (tiny) step forward
        self.prev = (s.stamp_ns, pose)
        if self.feeder is None:
            self.tracker.update_from_result(result, s.ranges, s.angles, delta, dt)
        else:  # the detector's permissive candidates (its own call on this scan), their points and the noise
            from detectors.tracking import segment_points

            ranges = s.ranges[None]
            _, (row, x, y, scores, accepted, first, last, noise) = self.feeder.detect(
                ranges, s.angles, np.zeros(1, np.int64), np.zeros((1, 3)), range_max=s.range_max
            )
            # a recording's scans: the public, checked path (the envs' own scans take the trusted one)
            pts, own = segment_points(ranges, s.angles, row, first, last, s.range_max)
            obs = np.zeros(len(x), np.int64)
            self.tracker.update_batch(obs, np.c_[x, y], scores, delta[None], dt, pts, own, noise,
                                      accepted=accepted)  # fmt: skip
        thr = self.tracker.params.kin_threshold
        out = []
        ox, oy, oth = self.origin
        co, so = math.cos(oth), math.sin(oth)
        local = self.tracker.in_robot_frame(0)
        pth = self.tracker.pose[2]
        cp, sp = math.cos(pth), math.sin(pth)
        for t, (lx, ly) in zip(self.tracker.tracks(0), local, strict=True):
            out.append({
                "id": t.id, "x": float(lx), "y": float(ly), "wx": ox + co * t.x - so * t.y,
                "wy": oy + so * t.x + co * t.y, "vx": cp * t.vx + sp * t.vy, "vy": -sp * t.vx + cp * t.vy,
                "existence": t.existence, "kin_prob": t.kin_prob, "frames_seen": t.frames_seen,
                "confirmed": t.confirmed, "is_kin": bool(t.confirmed and t.kin_prob >= thr),
            })  # fmt: skip
        return out


def _chain(first, rest):
    if first is not None:
        yield first
        yield from rest


def _detect_chunks(detector, scans, size: int = 64):
    """``(scan, DetectionResult)`` in order; consecutive scans with the same beam layout go through
    ``detect_batch`` together (4x faster for the learned detector; results equal to ``detect``'s to
    rounding)."""
    chunk: list = []
    for s in scans:
        if chunk and (len(chunk) == size or not np.array_equal(chunk[0].angles, s.angles)):
            yield from _run(detector, chunk)
            chunk = []
        chunk.append(s)
    yield from _run(detector, chunk)


def _run(detector, chunk):
    if chunk:
        results = detector.detect_batch(np.stack([s.ranges for s in chunk]), chunk[0].angles)
        yield from zip(chunk, results, strict=True)


def _write_marker_scan(mw, topic: str, s, detections) -> None:
    """The scan (copied into the output bag's ROS version) and its detections as a MarkerArray."""
    m = s.msg
    hdr = mw.header(s.frame_id, s.stamp_ns)
    scan = mw.laserscan(
        hdr,
        m.angle_min,
        m.angle_increment,
        m.ranges,
        m.range_min,
        m.range_max,
        angle_max=float(m.angle_max),
        time_increment=float(m.time_increment),
        scan_time=float(m.scan_time),
        intensities=m.intensities.astype("float32"),
    )
    mw.write(topic, "sensor_msgs/msg/LaserScan", s.log_ns, scan)
    from detectors.ros import detection_markers

    arr = detection_markers(mw, s.frame_id, s.stamp_ns, [(d.x, d.y) for d in detections])
    mw.write(topic.rstrip("/") + "/kin_detections", "visualization_msgs/msg/MarkerArray", s.log_ns, arr)


def record(args: argparse.Namespace) -> int:
    from kin_envs.cli import parse_json_object
    from kin_envs.ros import record_episode

    kwargs = parse_json_object(args.env_kwargs, "--env-kwargs") or {}
    from kin_envs import aggregation_v0, aggregation_v1, aggregation_v2

    swarms = {"aggregation_v2": aggregation_v2, "aggregation_v1": aggregation_v1,
              "aggregation_v0": aggregation_v0}  # fmt: skip
    swarm = swarms.get(args.env.removeprefix("kin_envs."))
    if swarm is not None:
        env = swarm.parallel_env(**kwargs)
    else:
        import gymnasium as gym

        import kin_envs  # noqa: F401  (registers the ids)

        try:
            env = gym.make(args.env, **kwargs)
        except gym.error.Error as e:  # unknown / misspelt id: say which ids there are
            ids = sorted(k for k in gym.registry if k.startswith("kin_envs/"))
            raise ValueError(f"--env {args.env!r}: {e} Expected one of {', '.join(ids)}, "
                             f"{', '.join(swarms)}") from e  # fmt: skip
    detector = None if args.detector == "none" else _make_detector(args.detector, args.checkpoint)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    storage = args.storage or ("ros1" if args.out.lower().endswith(".bag") else "mcap")
    try:
        info = record_episode(
            env,
            args.out,
            seed=args.seed,
            steps=args.steps,
            storage=storage,
            detector=detector,
            progress=not args.quiet,
        )
    finally:
        env.close()
    run = {
        "command": shlex.join(["kin-envs", *args.argv]),
        "env": args.env,
        "env_kwargs": kwargs,
        "seed": args.seed,
        "steps": info["steps"],
        "storage": storage,
        "detector": args.detector,
        "bag": str(args.out),
    }
    write_json(str(args.out).rstrip("/") + ".run.json", run)
    print(f"recorded {info['steps']} steps of {args.env} -> {args.out} ({storage})", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="kin-envs", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("detect", help="detect kin in every LaserScan of a ROS 1 / ROS 2 bag")
    d.add_argument("bag", help="ROS 1 .bag file or ROS 2 bag directory (sqlite3 or MCAP)")
    d.add_argument("--topic", required=True, help="sensor_msgs/LaserScan topic, e.g. /scan")
    d.add_argument(
        "--detector",
        default="geometric",
        choices=("geometric", "learned", "beam"),
        help="detector to run (beam: the per-beam DROW-style detector, numpy only)",
    )
    d.add_argument(
        "--checkpoint", default=None, help="learned or beam detector checkpoint (default: the shipped one)"
    )
    d.add_argument(
        "--odom",
        default=None,
        help="nav_msgs/Odometry or tf2_msgs/TFMessage topic: adds the "
        "robot's pose and world coordinates (wx, wy) of each detection",
    )
    d.add_argument(
        "--base-frame",
        default=None,
        help="with a TF --odom: the robot's child_frame_id to follow (default: the scan's frame_id)",
    )
    d.add_argument(
        "--out",
        default=None,
        help="output FILE.jsonl (one line per scan) or FILE.csv (one row per "
        "detection), with its run record FILE.run.json (command, options, counts) beside it; "
        "default: JSON Lines on stdout",
    )
    d.add_argument(
        "--markers",
        default=None,
        help="also write a bag with the scans and the detections as "
        "visualization_msgs/MarkerArray on TOPIC/kin_detections (OUT.bag: ROS 1, else ROS 2 MCAP; "
        "without --out, the run record is OUT.run.json)",
    )
    d.add_argument(
        "--truth",
        default=None,
        help="geometry_msgs/PoseArray topic of the true kin positions in the --odom frame (recorded bags: "
        "/ground_truth/kin): adds truth_error (m) to each detection and prints how many are real",
    )
    d.add_argument(
        "--truth-gate",
        type=float,
        default=0.05,
        help="with --truth: a detection within this distance (m) of a true kin counts as real",
    )
    d.add_argument(
        "--track",
        action="store_true",
        help="also run the multi-frame detectors.KinTracker (needs --odom): each scan's tracks (id, x, y, "
        "vx, vy in the robot frame, wx, wy in the odometry frame, existence, kin_prob, is_kin) as 'tracks' "
        "in the JSON Lines output, or as rows with record=track in the CSV",
    )
    d.add_argument(
        "--track-feed",
        choices=("auto", "accepted", "permissive"),
        default="auto",
        help="what feeds the tracker: the detector's accepted detections, or its permissive candidates with "
        "their scores and accepted flags (what the track classifier is fitted on); auto: permissive where it "
        "costs no second detector call (the geometric detector), else accepted (README, 'What feeds the "
        "tracker')",
    )
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=detect)

    r = sub.add_parser("record", help="record one simulated episode to a ROS bag")
    r.add_argument("out", help="bag to create: a ROS 2 bag directory, or OUT.bag for ROS 1")
    r.add_argument(
        "--env",
        default="kin_envs/KinSeek-v2",
        help="Gymnasium id, or aggregation_v2 / aggregation_v1 / aggregation_v0 (PettingZoo)",
    )
    r.add_argument("--env-kwargs", default=None, help="env keyword arguments: a JSON object or a JSON file")
    r.add_argument(
        "--steps", type=int, default=None, help="stop after this many steps (default: episode end)"
    )
    r.add_argument("--seed", type=int, default=0, help="reset seed (random actions are seeded with it too)")
    r.add_argument(
        "--storage",
        default=None,
        choices=("mcap", "sqlite3", "ros1"),
        help="bag format (default: ros1 for OUT.bag, else mcap)",
    )
    r.add_argument(
        "--detector",
        default="geometric",
        choices=("geometric", "learned", "beam", "none"),
        help="detector whose output is recorded as markers",
    )
    r.add_argument(
        "--checkpoint", default=None, help="learned or beam detector checkpoint (default: the shipped one)"
    )
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=record)
    return p


def main(argv=None) -> int:
    """Entry point of the ``kin-envs`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    from detectors.ros import BagError

    try:
        return args.func(args)
    except (BagError, ValueError, TypeError, FileExistsError, FileNotFoundError, ImportError) as e:
        print(f"kin-envs {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
