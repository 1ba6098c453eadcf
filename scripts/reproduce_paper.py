"""Reproduce the paper's experiments (section 5) with the geometric detector.

Scenario I (figure 10: a kin and cylinders of radius 3, 5, 9, 11 cm) and Scenario II (figure 11:
a kin, a same-radius cylinder and 7 cm prisms and cuboid) are built in the world at 0.5, 0.8 and
1.2 m (``kin_envs.scenes.paper_scenario``, whose docstring states the layout rule), scanned from the
observer (robot 0) and run through :class:`detectors.GeometricKinDetector`. Every object is mapped
to its segment(s) through the scan's ground truth (the object a strict majority of a segment's
valid beams hit) and reported with the stage that rejected it, or "accepted" and the position
error of its detection against its true centre.

The paper's outcomes: Scenario I, only the kin accepted and every cylinder rejected by the diameter
filter (4.3.1); Scenario II, the kin accepted, every prism and the cuboid rejected by the shape
filter (4.3.2), the same-radius cylinder accepted (the paper's own false positive). "Outcome as in
the paper" means accepted vs rejected; "stage as in the paper" also requires the paper's stage.

Printed and written (``--out``; figures unless ``--no-figures``):

* the reproduction table (``reproduction.md``; all results as JSON with ``--json PATH``);
* a sensitivity table: how often each object's outcome is the paper's over ``--draws`` random
  layouts (every object, kin included, turned about the observer by a uniform offset within one
  beam step; prisms and cuboid at uniform random orientations), per distance;
* with ``--noise 0.005 0.01``: the same scenes with relative range noise over ``--repeats`` seeded
  repetitions: per object the rate of the paper's outcome and the kin's position error
  (noise 0 is always included as the reference, one run, as it is deterministic);
* figures 7, 10 and 11 (top: the scene from above with the beams that hit something and the
  detections circled; bottom: range and eq. 1 derivative vs beam number with +-d_th, detections
  marked, rejected segments shaded by stage);
* ``run.json``: command line, arguments, seeds.

Example::

    python scripts/reproduce_paper.py --noise 0.005 0.01 --repeats 50 \
        --json outputs/reproduce_paper/results.json
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import time
from pathlib import Path

import numpy as np

from detectors import GeometricKinDetector, range_derivative
from detectors.base import DetectionResult
from detectors.fileio import atomic_write, write_json, write_text
from kin_envs import World, scenes
from kin_envs.cli import (
    add_logging_args,
    check_output_dir,
    noise_level,
    script_logger,
    setup_logging,
    write_run_info,
)
from kin_envs.cli import progress as tqdm
from kin_envs.core.lidar import HitKind, LidarSpec
from kin_envs.core.scenes import Box, Cylinder, Robot, Scene
from kin_envs.detection.evaluation import describe_hits

SCENARIO_NAMES = {1: "I", 2: "II"}
FIGURE_NUMBERS = {1: 10, 2: 11}
STAGE_COLOURS = {
    "accepted": "tab:green",
    "diameter": "tab:red",
    "shape": "tab:orange",
    "too_few_points": "tab:purple",
    "not seen": "0.6",
}
_PRISM_NAMES = {3: "triangular", 4: "square", 5: "pentagonal", 6: "hexagonal", 8: "octagonal"}


# --------------------------------------------------------------------------- objects and outcomes


def object_label(scene: Scene, key: tuple[str, int]) -> str:
    """Human name of a scene object: ``("robot", i)`` or ``("obstacle", j)``."""
    kind, i = key
    if kind == "robot":
        return "kin robot"
    o = scene.obstacles[i]
    if o.kind == "cylinder":
        return f"cylinder r={100 * o.radius:g} cm"
    if o.kind == "prism":
        return f"{_PRISM_NAMES.get(o.sides, f'{o.sides}-sided')} prism {100 * o.width:g} cm"
    if o.kind == "box":
        size = f"{100 * o.width:g}" if o.width == o.depth else f"{100 * o.width:g} x {100 * o.depth:g}"
        return f"cuboid {size} cm"
    return o.kind


def paper_stage(number: int, scene: Scene, key: tuple[str, int]) -> str:
    """The paper's outcome for an object: ``"accepted"`` or the stage that rejects it."""
    kind, i = key
    if kind == "robot":
        return "accepted"
    if number == 1:
        return "diameter"
    o = scene.obstacles[i]
    if isinstance(o, Cylinder) and abs(o.radius - scene.robot.housing_radius) < 1e-9:
        return "accepted"
    return "shape"


def scene_objects(scene: Scene) -> list[tuple[str, int]]:
    """The observer's kin and every obstacle, right to left (ascending bearing)."""
    keys = [("robot", i) for i in range(1, len(scene.robots))]
    keys += [("obstacle", j) for j in range(len(scene.obstacles))]
    return sorted(keys, key=lambda k: math.atan2(*_centre(scene, k)[::-1]))


def _centre(scene: Scene, key: tuple[str, int]) -> tuple[float, float]:
    """Centre in the observer's frame (robot 0)."""
    kind, i = key
    wx, wy = (scene.robots[i].x, scene.robots[i].y) if kind == "robot" else scene.obstacles[i].center
    ob = scene.robots[0]
    dx, dy = wx - ob.x, wy - ob.y
    c, s = math.cos(ob.theta), math.sin(ob.theta)
    return c * dx + s * dy, -s * dx + c * dy


def object_outcomes(number: int, scene: Scene, scan, result: DetectionResult, row: int = 0) -> list[dict]:
    """One row per object: its segments' stages, the outcome, the paper's, the position error.

    The outcome is "accepted" if any of the object's segments is accepted, else the stage of its
    largest segment ("not seen" without a segment).
    """
    segs: dict[tuple[str, int], list] = {}
    for rep in result.reports:
        src = describe_hits(scan, row, rep.segment.beams, scene)
        if src.kind in ("mixed", "nothing", "boundary"):
            continue
        key = ("robot", src.index) if src.kind == "kin" else ("obstacle", src.index)
        segs.setdefault(key, []).append(rep)
    det_by_beams = {(d.first_beam, d.last_beam): d for d in result.detections}
    rows = []
    for key in scene_objects(scene):
        x, y = _centre(scene, key)
        kind = HitKind.ROBOT if key[0] == "robot" else scene.obstacles[key[1]].hit_kind
        hit = (scan.hit_kind[row] == kind) & (scan.hit_index[row] == key[1])
        reps = segs.get(key, [])
        accepted = [r for r in reps if r.accepted]
        error = None
        if accepted:
            outcome = "accepted"
            dets = [det_by_beams.get((r.segment.first_beam, r.segment.last_beam)) for r in accepted]
            errs = [math.hypot(d.x - x, d.y - y) for d in dets if d is not None]
            error = min(errs) if errs else None
        elif reps:
            outcome = max(reps, key=lambda r: r.segment.n_beams).stage
        else:
            outcome = "not seen"
        paper = paper_stage(number, scene, key)
        rows.append(
            {
                "object": object_label(scene, key),
                "key": f"{key[0]} {key[1]}",
                "bearing_deg": math.degrees(math.atan2(y, x)),
                "range_m": math.hypot(x, y),
                "beams": int(np.count_nonzero(hit & (scan.ranges[row] < scan.range_max))),
                "segments": [
                    {
                        "first_beam": r.segment.first_beam,
                        "last_beam": r.segment.last_beam,
                        "n_beams": r.segment.n_beams,
                        "stage": r.stage,
                        "reason": r.reason,
                        "metrics": {k: float(v) for k, v in r.metrics.items()},
                    }
                    for r in reps
                ],
                "outcome": outcome,
                "paper": paper,
                "outcome_as_paper": (outcome == "accepted") == (paper == "accepted"),
                "stage_as_paper": outcome == paper,
                "error_m": error,
            }
        )
    return rows


def run_scene(number: int, scene: Scene, detector: GeometricKinDetector, seed=None):
    """Scan ``scene`` from robot 0 and detect: ``(scan, result, object rows)``."""
    scan = World(scene, seed=seed).scan(robots=[0])
    result = detector.detect(scan.ranges[0], scan.angles)
    return scan, result, object_outcomes(number, scene, scan, result)


# --------------------------------------------------------------------------- sensitivity


def perturbed_scene(scene: Scene, rng: np.random.Generator) -> Scene:
    """``scene`` with every object (kin included) turned about the observer by a uniform offset
    within one beam step, and prisms / cuboids at uniform random orientations."""
    res = scene.lidar.resolution

    def turn(x: float, y: float) -> tuple[float, float, float]:
        b = math.atan2(y, x) + float(rng.uniform(-0.5, 0.5)) * res
        r = math.hypot(x, y)
        return r * math.cos(b), r * math.sin(b), b

    robots = [scene.robots[0]]
    for kin in scene.robots[1:]:
        x, y, _ = turn(kin.x, kin.y)
        robots.append(Robot(x, y, kin.theta))
    obstacles = []
    for o in scene.obstacles:
        x, y, _ = turn(*o.center)
        change = {"x": x, "y": y}
        if o.kind in ("prism", "box"):
            change["theta"] = float(rng.uniform(0.0, 2.0 * math.pi))
        obstacles.append(dataclasses.replace(o, **change))
    return scene.replace(robots=tuple(robots), obstacles=tuple(obstacles))


def sensitivity(number: int, distance: float, draws: int, rng, detector, lidar=None) -> list[dict]:
    """Per object: how often its outcome (and its stage) is the paper's over random layouts."""
    base = scenes.paper_scenario(number, distance=distance, lidar=lidar)
    keys = scene_objects(base)
    tally = {k: {"outcome": 0, "stage": 0, "stages": {}} for k in keys}
    for _ in range(draws):
        scene = perturbed_scene(base, rng)
        _, _, rows = run_scene(number, scene, detector)
        for k, r in zip(keys, rows, strict=True):
            t = tally[k]
            t["outcome"] += r["outcome_as_paper"]
            t["stage"] += r["stage_as_paper"]
            t["stages"][r["outcome"]] = t["stages"].get(r["outcome"], 0) + 1
    out = []
    for k in keys:
        x, y = _centre(base, k)
        out.append(
            {
                "scenario": SCENARIO_NAMES[number],
                "distance": distance,
                "object": object_label(base, k),
                "bearing_deg": math.degrees(math.atan2(y, x)),
                "paper": paper_stage(number, base, k),
                "draws": draws,
                "outcome_rate": tally[k]["outcome"] / draws,
                "stage_rate": tally[k]["stage"] / draws,
                "outcomes": dict(sorted(tally[k]["stages"].items())),
            }
        )
    return out


# --------------------------------------------------------------------------- noise


def noise_study(number: int, distance: float, noise: float, repeats: int, rng, detector) -> list[dict]:
    """Per object over ``repeats`` noisy scans: rate of the paper's outcome and of its stage; for
    the kin the position error (m) of its detections."""
    scene = scenes.paper_scenario(number, distance=distance, lidar=LidarSpec(noise_sigma=noise))
    keys = scene_objects(scene)
    runs = 1 if noise == 0 else repeats  # noise-free scans are identical
    hits = {k: [0, 0] for k in keys}
    stages: dict = {k: {} for k in keys}
    errors: dict = {k: [] for k in keys}
    for _ in range(runs):
        _, _, rows = run_scene(number, scene, detector, seed=rng)
        for k, r in zip(keys, rows, strict=True):
            hits[k][0] += r["outcome_as_paper"]
            hits[k][1] += r["stage_as_paper"]
            stages[k][r["outcome"]] = stages[k].get(r["outcome"], 0) + 1
            if r["error_m"] is not None:
                errors[k].append(r["error_m"])
    out = []
    for k in keys:
        e = np.asarray(errors[k])
        x, y = _centre(scene, k)
        out.append(
            {
                "scenario": SCENARIO_NAMES[number],
                "distance": distance,
                "noise": noise,
                "object": object_label(scene, k),
                "bearing_deg": math.degrees(math.atan2(y, x)),
                "paper": paper_stage(number, scene, k),
                "runs": runs,
                "outcome_rate": hits[k][0] / runs,
                "stage_rate": hits[k][1] / runs,
                "outcomes": dict(sorted(stages[k].items())),
                "error_mean_m": float(e.mean()) if e.size else None,
                "error_p95_m": float(np.percentile(e, 95)) if e.size else None,
            }
        )
    return out


# --------------------------------------------------------------------------- tables


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def _cm(x) -> str:
    return "–" if x is None else f"{100 * x:.2f}"


def reproduction_markdown(reproduction: list[dict]) -> str:
    lines = []
    for block in reproduction:
        lines += [
            f"**Scenario {block['scenario']} at {block['distance']:g} m**",
            "",
            "| object | bearing | beams | outcome | paper | as paper | position error (cm) |",
            "|---|---:|---:|---|---|---|---:|",
        ]
        for r in block["objects"]:
            mark = "yes" if r["stage_as_paper"] else ("outcome only" if r["outcome_as_paper"] else "**no**")
            lines.append(
                f"| {r['object']} | {r['bearing_deg']:+.1f}° | {r['beams']} | {r['outcome']} | {r['paper']} "
                f"| {mark} | {_cm(r['error_m'])} |"
            )
        lines.append("")
    return "\n".join(lines)


def sensitivity_markdown(rows: list[dict], distances) -> str:
    head = " | ".join(f"{d:g} m" for d in distances)
    lines = [
        "Fraction of random layouts (uniform sub-beam offset of every object, random prism / cuboid "
        "orientation) in which the object's outcome is the paper's (in brackets: also at the paper's "
        "stage).",
        "",
        f"| scenario | object | paper | {head} |",
        "|---|---|---|" + "---:|" * len(distances),
    ]
    by_obj: dict = {}
    for r in rows:
        by_obj.setdefault((r["scenario"], round(r["bearing_deg"], 1), r["object"], r["paper"]), {})[
            r["distance"]
        ] = r
    for (sc, bearing, obj, paper), per_d in by_obj.items():
        cells = []
        for d in distances:
            r = per_d.get(d)
            cells.append("–" if r is None else f"{_pct(r['outcome_rate'])} ({_pct(r['stage_rate'])})")
        lines.append(
            f"| {sc} | {_side(obj, bearing)} at {bearing:+.1f}° | {paper} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def _side(name: str, bearing_deg: float) -> str:
    """``name`` with the side of the observer it stands on (the two hexagons share a name)."""
    return name if abs(bearing_deg) < 1e-9 else f"{name} ({'right' if bearing_deg < 0 else 'left'})"


def noise_markdown(rows: list[dict]) -> str:
    """One table per scenario: rows distance x noise, columns objects (rate of the paper's outcome)
    and the kin's position error."""
    out = []
    for sc in ("I", "II"):
        sub = [r for r in rows if r["scenario"] == sc]
        if not sub:
            continue
        out += [
            f"**Scenario {sc}**: rate of the paper's outcome (kin detected; "
            + (
                "cylinders rejected"
                if sc == "I"
                else "prisms and cuboid rejected, same-radius cylinder accepted"
            )
            + ") and kin position error (cm, mean / 95th percentile over detections)",
            "",
        ]
        cols = []
        for r in sub:
            if r["distance"] == sub[0]["distance"] and r["noise"] == sub[0]["noise"]:
                cols.append(_side(r["object"], r["bearing_deg"]))
        out.append("| distance | noise | " + " | ".join(cols) + " | kin error mean | kin error p95 |")
        out.append("|---:|---:|" + "---:|" * (len(cols) + 2))
        groups: dict = {}
        for r in sub:
            groups.setdefault((r["distance"], r["noise"]), []).append(r)
        for (d, nz), rs in sorted(groups.items()):
            kin = next(r for r in rs if r["object"] == "kin robot")
            cells = [_pct(r["outcome_rate"]) for r in rs]
            runs = f" (n={kin['runs']})"
            out.append(
                f"| {d:g} m | {100 * nz:g} %{runs} | "
                + " | ".join(cells)
                + f" | {_cm(kin['error_mean_m'])} | {_cm(kin['error_p95_m'])} |"
            )
        out.append("")
    return "\n".join(out)


# --------------------------------------------------------------------------- figures


def _draw_scene(ax, scene: Scene, scan, result: DetectionResult, rows: list[dict], title: str) -> None:
    import matplotlib.patches as mpatches

    spec = scene.robot
    outcome = {r["key"]: r["outcome"] for r in rows}
    ox, oy, oth = (float(v) for v in scan.poses[0])
    # beams that hit something (valid returns only: what the detector saw)
    valid = scan.ranges[0] < scan.range_max
    a = scan.angles[valid] + oth
    r = scan.ranges[0][valid].astype(float)
    hx, hy = ox + r * np.cos(a), oy + r * np.sin(a)
    for x, y in zip(hx, hy, strict=True):
        ax.plot([ox, x], [oy, y], color="tab:blue", lw=0.3, alpha=0.5, zorder=1)
    ax.plot(hx, hy, ".", color="tab:blue", ms=2, zorder=4)
    for i, rob in enumerate(scene.robots):
        ax.add_patch(mpatches.Circle((rob.x, rob.y), spec.body_radius, fc="0.9", ec="0.5", lw=0.8, zorder=2))
        c = "0.2" if i == 0 else STAGE_COLOURS[outcome.get(f"robot {i}", "not seen")]
        ax.add_patch(mpatches.Circle((rob.x, rob.y), spec.housing_radius, fc=c, ec="k", lw=0.8, zorder=3))
    for j, o in enumerate(scene.obstacles):
        kind, geom = o.footprint()
        c = STAGE_COLOURS[outcome.get(f"obstacle {j}", "not seen")]
        if kind == "circle":
            patch = mpatches.Circle(geom[:2], geom[2], fc=c, ec="k", lw=0.8, alpha=0.8, zorder=3)
        else:
            patch = mpatches.Polygon(geom, closed=True, fc=c, ec="k", lw=0.8, alpha=0.8, zorder=3)
        ax.add_patch(patch)
    c, s = math.cos(oth), math.sin(oth)
    for d in result.detections:
        wx, wy = ox + c * d.x - s * d.y, oy + s * d.x + c * d.y
        ring = mpatches.Circle(
            (wx, wy), 2.2 * spec.housing_radius, fill=False, ec="tab:green", lw=2, zorder=5
        )
        ax.add_patch(ring)
    for row in rows:
        kind, i = row["key"].split()
        cx, cy = (
            (scene.robots[int(i)].x, scene.robots[int(i)].y)
            if kind == "robot"
            else scene.obstacles[int(i)].center
        )
        ax.annotate(
            f"{row['object']}\n{row['outcome']}",
            (cx, cy),
            xytext=(cx * 1.25 + 0.05, cy * 1.25),
            fontsize=6,
            ha="center",
            va="center",
        )
    pts = np.array(
        [[o.center[0], o.center[1]] for o in scene.obstacles] + [[rb.x, rb.y] for rb in scene.robots]
    )
    lo, hi = pts.min(axis=0) - 0.25, pts.max(axis=0) + 0.35
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    handles = [mpatches.Patch(color=v, label=k) for k, v in STAGE_COLOURS.items() if k != "not seen"]
    handles.append(mpatches.Patch(fill=False, ec="tab:green", lw=2, label="detection"))
    ax.legend(handles=handles, fontsize=6, loc="lower left")


def _draw_scan(ax_r, ax_d, scan, result: DetectionResult, d_th: float, y_top: float) -> None:
    import matplotlib.patches as mpatches

    n = scan.ranges.shape[1]
    # beams re-centred on the heading so that the objects in front are in the middle: beam 359
    # (1° left of the heading) is drawn at -1; the ticks still show beam numbers
    pos = (np.arange(n) + n // 2) % n - n // 2
    order = np.argsort(pos)
    d = np.minimum(scan.ranges[0].astype(float), scan.range_max)
    deriv = range_derivative(d, d_th)
    for rep in result.reports:
        if rep.accepted:
            continue
        colour = STAGE_COLOURS.get(rep.stage, "0.6")
        p = pos[rep.segment.beams]
        for run in np.split(p, np.flatnonzero(np.diff(p) != 1) + 1):
            for ax in (ax_r, ax_d):
                ax.axvspan(run.min() - 0.5, run.max() + 0.5, color=colour, alpha=0.25, lw=0)
    ax_r.plot(
        pos[order],
        np.minimum(d, y_top)[order],
        color="tab:blue",
        lw=1,
        label="range $d_i$ (no return at top)",
    )
    ax_d.plot(pos[order], deriv[order], color="tab:green", lw=1, label=r"$\partial_i$ (eq. 1)")
    for det in result.detections:
        i = int(np.argmin(np.abs(np.angle(np.exp(1j * (scan.angles - det.bearing))))))
        ax_r.plot(pos[i], det.range, "o", ms=10, mfc="none", mec="tab:green", mew=2)
        ax_d.plot(pos[i], 0.0, "o", ms=10, mfc="none", mec="tab:green", mew=2)
    for sgn in (1, -1):
        ax_d.axhline(sgn * d_th, color="k", ls="--", lw=0.8)
    seen = pos[d < scan.range_max]
    lo, hi = (seen.min() - 8, seen.max() + 8) if seen.size else (-n // 2, n // 2)
    ticks = np.arange(10 * math.floor(lo / 10), hi + 1, 10 if hi - lo <= 200 else 30)
    for ax in (ax_r, ax_d):
        ax.set_xlim(lo, hi)
        ax.set_xticks(ticks, [str(int(t) % n) for t in ticks])
    ax_r.set_ylim(0, y_top)
    ax_r.set_ylabel("range (m)")
    ax_d.set_ylim(-1.0, 1.0)
    ax_d.set_ylabel(r"$\partial_i$ (m, clipped)")
    ax_d.set_xlabel("beam number (beam i points i° clockwise; objects on the observer's left on the left)")
    shade = [
        mpatches.Patch(color=STAGE_COLOURS[k], alpha=0.25, label=f"rejected: {k}")
        for k in ("diameter", "shape", "too_few_points")
    ]
    ring = ax_r.plot([], [], "o", ms=8, mfc="none", mec="tab:green", mew=2, label="detection")
    ax_r.legend(handles=[*ax_r.get_lines()[:1], *ring, *shade], fontsize=6, loc="lower right")
    ax_d.legend(fontsize=6, loc="lower right", title=f"±d_th = ±{d_th:g} m", title_fontsize=6)


def save_figure(path: Path, scene: Scene, scan, result, rows, title: str, d_th: float, y_top: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(8, 10))
    gs = fig.add_gridspec(3, 1, height_ratios=[2.2, 1, 0.8])
    _draw_scene(fig.add_subplot(gs[0]), scene, scan, result, rows, title)
    ax_r = fig.add_subplot(gs[1])
    ax_d = fig.add_subplot(gs[2], sharex=ax_r)
    _draw_scan(ax_r, ax_d, scan, result, d_th, y_top)
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


def figure7_scene() -> Scene:
    """Figure 7's illustration: a cuboid at the left and a cylinder at the right of the observer."""
    d, b = 0.6, math.radians(25.5)
    return Scene(
        robots=(Robot(0.0, 0.0, 0.0),),
        obstacles=(
            Box(x=d * math.cos(b), y=d * math.sin(b), width=0.1, depth=0.1, theta=b),
            Cylinder(x=d * math.cos(b), y=-d * math.sin(b), radius=0.05),
        ),
        arena=scenes.Arena(3.0, 3.0, walls=False),
        name="figure 7: cuboid (left) and cylinder (right)",
    )


# --------------------------------------------------------------------------- main


def _print_reproduction(reproduction: list[dict]) -> None:
    for block in reproduction:
        print(f"\nScenario {block['scenario']} at {block['distance']:g} m")
        print(
            f"  {'object':<24}{'bearing':>9}{'beams':>7}  {'outcome':<16}{'paper':<10}{'as paper':<14}"
            f"{'err (cm)':>8}"
        )
        for r in block["objects"]:
            mark = "yes" if r["stage_as_paper"] else ("outcome only" if r["outcome_as_paper"] else "NO")
            print(
                f"  {r['object']:<24}{r['bearing_deg']:>+8.1f}°{r['beams']:>7}  {r['outcome']:<16}"
                f"{r['paper']:<10}{mark:<14}{_cm(r['error_m']):>8}"
            )


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=Path("outputs/reproduce_paper"), help="output directory")
    ap.add_argument("--json", type=Path, default=None, help="also write all results to this JSON file")
    ap.add_argument(
        "--distances", type=float, nargs="+", default=list(scenes.PAPER_DISTANCES),
        help=f"observer-object distances, m, within the lidar's range (< {LidarSpec().range_max:g} m)",
    )  # fmt: skip
    ap.add_argument(
        "--noise",
        type=noise_level,
        nargs="*",
        default=[],
        help="relative range noise levels for the noise study, e.g. 0.005 0.01 (0 is always added)",
    )
    ap.add_argument(
        "--repeats", type=int, default=50, help="noisy scans per scenario, distance and noise level"
    )
    ap.add_argument(
        "--draws",
        type=int,
        default=200,
        help="random layouts per scenario and distance for the sensitivity table (0: skip)",
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensitivity draws and the noise")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    add_logging_args(ap)
    args = ap.parse_args(argv)
    setup_logging(args)
    if not args.no_figures and importlib.util.find_spec("matplotlib") is None:
        # the viz extra draws the figures; the tables and JSON do not need it
        script_logger(__file__).warning("no figures: matplotlib is not installed (pip install kin-envs[viz])")
        args.no_figures = True
    if any(not (math.isfinite(d) and d > 0) for d in args.distances):
        ap.error(f"--distances must be > 0 m, got {args.distances}")
    # the object's centre past range_max: its face may still return, but nothing the paper measured
    range_max = LidarSpec().range_max
    if any(d >= range_max for d in args.distances):
        ap.error(f"--distances must be within the lidar's range (< {range_max:g} m), got {args.distances}")
    for d in args.distances:  # too near, the paper's arc of objects overlaps: say so before any work
        for number in (1, 2):
            try:
                scenes.paper_scenario(number, distance=d)
            except ValueError as e:
                ap.error(f"--distances {d:g}: Scenario {'I' * number}'s objects do not fit on an arc of that "
                         f"radius ({e}); use a larger distance (the paper: 0.5 m)")  # fmt: skip
    if args.repeats < 1 or args.draws < 0 or args.seed < 0:
        ap.error("--repeats must be >= 1, --draws >= 0 and --seed >= 0")
    try:  # before any computation: an unwritable --out must not cost a whole run
        out: Path = check_output_dir(args.out)
        if args.json is not None:
            check_output_dir(args.json.parent, "--json's directory")
    except ValueError as e:
        ap.error(str(e))
    t0 = time.perf_counter()
    detector = GeometricKinDetector()
    sens_seed, noise_seed = np.random.SeedSequence(args.seed).spawn(2)
    distances = list(args.distances)

    reproduction, figures = [], []
    for number in (1, 2):
        for d in distances:
            scene = scenes.paper_scenario(number, distance=d)
            scan, result, rows = run_scene(number, scene, detector)
            reproduction.append(
                {
                    "scenario": SCENARIO_NAMES[number],
                    "distance": d,
                    "objects": rows,
                    "detections": [dataclasses.asdict(x) for x in result.detections],
                }
            )
            if not args.no_figures:
                name = f"figure{FIGURE_NUMBERS[number]}_scenario_{SCENARIO_NAMES[number]}_{d:g}m.png"
                title = (
                    f"Figure {FIGURE_NUMBERS[number]}: Scenario {SCENARIO_NAMES[number]} at {d:g} m "
                    f"(colour = outcome, green ring = detection)"
                )
                save_figure(out / name, scene, scan, result, rows, title, detector.params.d_th, d + 0.6)
                figures.append(str(out / name))
    if not args.no_figures:
        scene = figure7_scene()
        scan = World(scene).scan(robots=[0])
        result = detector.detect(scan.ranges[0], scan.angles)
        rows = object_outcomes(1, scene, scan, result)
        for r in rows:  # figure 7 only illustrates segmentation: no paper outcome
            r["paper"] = r["outcome_as_paper"] = r["stage_as_paper"] = None
        save_figure(
            out / "figure7_segmentation.png",
            scene,
            scan,
            result,
            rows,
            "Figure 7: cuboid (left) and cylinder (right) at 0.6 m",
            detector.params.d_th,
            1.2,
        )
        figures.append(str(out / "figure7_segmentation.png"))
    _print_reproduction(reproduction)

    sens_rows: list[dict] = []
    if args.draws:
        rng = np.random.default_rng(sens_seed)
        jobs = [(k, d) for k in (1, 2) for d in distances]
        for k, d in tqdm(jobs, desc="sensitivity", unit="scene"):
            sens_rows += sensitivity(k, d, args.draws, rng, detector)
        print("\n" + sensitivity_markdown(sens_rows, distances))

    noise_rows: list[dict] = []
    levels = sorted({0.0, *args.noise})
    if args.noise:
        rng = np.random.default_rng(noise_seed)
        jobs = [(k, d, nz) for k in (1, 2) for d in distances for nz in levels]
        for k, d, nz in tqdm(jobs, desc="noise", unit="setting"):
            noise_rows += noise_study(k, d, nz, args.repeats, rng, detector)
        print(noise_markdown(noise_rows))

    md = [
        "# Reproduction of the paper's experiments (geometric detector)",
        "",
        "Layout rule (kin_envs.scenes.paper_scenario): " + LAYOUT_RULE,
        "",
        reproduction_markdown(reproduction),
    ]
    if sens_rows:
        md += ["## Sensitivity to the layout", "", sensitivity_markdown(sens_rows, distances)]
    if noise_rows:
        md += [
            f"## Range noise ({args.repeats} seeded repetitions per noisy setting)",
            "",
            noise_markdown(noise_rows),
        ]
    write_text(out / "reproduction.md", "\n".join(md))
    results = {
        "layout_rule": LAYOUT_RULE,
        "detector": {"class": type(detector).__name__, "params": dataclasses.asdict(detector.params)},
        "reproduction": reproduction,
        "sensitivity": {"draws": args.draws, "rows": sens_rows},
        "noise": {"levels": levels if args.noise else [], "repeats": args.repeats, "rows": noise_rows},
        "figures": figures,
    }
    run = write_run_info(
        out, args, config={"detector": results["detector"], "layout_rule": LAYOUT_RULE}, seed=args.seed,
        argv=argv, script=__file__,
        seeds={"sensitivity": "SeedSequence(seed).spawn(2)[0]", "noise": "SeedSequence(seed).spawn(2)[1]"},
        seconds=time.perf_counter() - t0,
    )
    if args.json is not None:
        write_json(args.json, {**results, "run": run}, default=_json_default)
    script_logger(__file__).info(
        f"wrote {out}/reproduction.md, run.json"
        + (f", {len(figures)} figures" if figures else "")
        + (f" and {args.json}" if args.json else "")
        + f" in {run['seconds']:.1f} s"
    )
    return {**results, "run": run}


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


LAYOUT_RULE = (
    "every distractor centred between two beams (nominal bearing moved away from the kin to the "
    "midpoint of the two beams around it: 30° -> 30.5°); the kin straight ahead on beam 0; every prism "
    "and the cuboid turned so that a flat face squarely faces the observer."
)


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
