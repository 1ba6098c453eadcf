"""scripts/fit_track_classifier.py: a tiny fit writes a loadable model, its table and run record; bad
arguments exit."""

import json

import pytest

from tests.scripts.helpers import load_script


def test_tiny_fit_writes_a_loadable_model(tmp_path):
    from detectors.tracking import KinTracker, TrackKinModel

    mod = load_script("fit_track_classifier")
    out = tmp_path / "fit"
    argv = ["--detector", "geometric", "--swarm-episodes", "1", "--lookalike-episodes", "2", "--frames", "12",
            "--noise", "0.005", "--out", str(out)]  # fmt: skip
    res = mod.main(argv)
    model = TrackKinModel.load(out / "tracker_kin.json")
    top = max(r["objective"] for r in res["thresholds"])
    # the operating point: the highest threshold within --tol (0.001) of the best objective
    near = [r["threshold"] for r in res["thresholds"] if r["objective"] >= top - 1e-3]
    assert model.info["threshold"] == max(near) and model.hit_only
    assert model.info["sets"][0].startswith("swarm@1000") and model.min_frames == 3
    assert KinTracker(kin_model=out / "tracker_kin.json").kin_model.info == model.info
    md = (out / "fit.md").read_text()
    assert "| hand-tuned fusion |" in md and "(chosen)" in md
    assert json.loads((out / "run.json").read_text())["seed"] == 1000


@pytest.mark.parametrize(
    "argv", [["--swarm-episodes", "0"], ["--noise", "5"], ["--frames", "1"], ["--l2", "-1"],
            ["--outside-weight", "0"], ["--detector", "beam", "--ship"]]
)
def test_bad_arguments(argv, tmp_path):
    mod = load_script("fit_track_classifier")
    with pytest.raises(SystemExit):
        mod.main([*argv, "--out", str(tmp_path / "x")])
