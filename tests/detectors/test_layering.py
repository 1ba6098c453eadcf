"""The layering rule: ``detectors`` runs on any 2D scan without the simulator.

Every module of ``detectors`` is imported, and both detectors run on a stored scan, in a subprocess in
which importing ``kin_envs`` or ``pymunk`` raises (and ``rosbags``: the optional ROS extra is imported
only when a bag is read or written). The scan (``tests/fixtures``) is the paper's
Scenario II at 0.8 m seen by robot 0: the kin (robot 1) shows 5 beams among 7 cm prisms.
"""

import json
import subprocess
import sys
from pathlib import Path

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "paper_scenario2_0.8m_scan.npz"

_CODE = r"""
import importlib, importlib.abc, json, pkgutil, sys
import numpy as np

class Forbid(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("kin_envs", "pymunk", "rosbags"):
            raise ImportError(f"detectors imported {name!r}: the layering rule forbids it")
        return None

sys.meta_path.insert(0, Forbid())
import torch
torch.set_num_threads(1)
import detectors

for m in pkgutil.walk_packages(detectors.__path__, "detectors."):
    importlib.import_module(m.name)

z = np.load(sys.argv[1])
ranges, angles, kind, index = z["ranges"], z["angles"], z["hit_kind"], z["hit_index"]
for det in (detectors.GeometricKinDetector(), detectors.LearnedKinDetector()):
    batch = det.detect_batch(ranges, angles)
    single = det.detect(ranges[0], angles)
    assert len(batch) == ranges.shape[0]
    xy = [(d.x, d.y) for d in single.detections]
    print(type(det).__name__, len(xy), json.dumps(xy))
print("imported:", sorted(k for k in sys.modules if k.split(".")[0] in ("kin_envs", "pymunk", "rosbags")))
"""


def test_detectors_import_and_run_without_the_simulator():
    out = subprocess.run(
        [sys.executable, "-c", _CODE, str(FIXTURE)], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[-1] == "imported: []"
    # the kin sits 0.8 m straight ahead of the observer (observer frame: x forward, y left)
    for line in lines[:2]:
        name, n, xy = line.split(" ", 2)
        assert int(n) >= 1, line
        pts = json.loads(xy)
        assert any(abs(x - 0.8) < 0.05 and abs(y) < 0.05 for x, y in pts), line
