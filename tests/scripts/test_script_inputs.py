"""Issue 16 (point 9): the scripts refuse bad options up front with a message naming the option:
noise levels past a sane range, distances past the lidar's range, and an output directory that
cannot be written is refused *before* any computation (each test makes the computation fail loudly
if it is reached)."""

from __future__ import annotations

import pytest

from tests.scripts.helpers import load_script


def _computing(*_a, **_k):
    raise AssertionError("the script computed before checking its output directory")


@pytest.fixture
def blocked(tmp_path):
    """An output path that cannot be created (its parent is a file), whatever the user's rights:
    the tests run as root in CI, where permission bits do not stop a write."""
    f = tmp_path / "a_file"
    f.write_text("x")
    return f / "out"


@pytest.mark.parametrize("script, argv", [
    ("evaluate_detectors", ["--noise", "5"]),
    ("evaluate_detectors", ["--noise", "-0.01"]),
    ("evaluate_detectors", ["--noise", "nan"]),
    ("reproduce_paper", ["--noise", "5", "--draws", "0", "--no-figures"]),
    ("reproduce_paper", ["--noise", "0.01", "inf", "--draws", "0", "--no-figures"]),
    ("reproduce_paper", ["--distances", "1000", "--draws", "0", "--no-figures"]),
    ("reproduce_paper", ["--distances", "0.5", "12", "--draws", "0", "--no-figures"]),
])  # fmt: skip
def test_noise_and_distance_out_of_range_are_argparse_errors(script, argv, tmp_path, capsys, monkeypatch):
    mod = load_script(script)
    monkeypatch.setattr(mod, "run_scene" if script == "reproduce_paper" else "map_seeds", _computing)
    with pytest.raises(SystemExit) as e:
        mod.main([*argv, "--out", str(tmp_path)])
    assert e.value.code == 2
    err = capsys.readouterr().err
    opt = argv[0]
    assert opt in err and ("lidar's range" in err if opt == "--distances" else "[0, 0.5]" in err), err


def test_train_classifier_noise_edges_out_of_range(tmp_path, capsys):
    pytest.importorskip("torch")
    mod = load_script("train_classifier")
    with pytest.raises(SystemExit):
        mod.main(["--data", str(tmp_path), "--out", str(tmp_path), "--calib-noise-edges", "0.01", "5"])
    assert "--calib-noise-edges" in capsys.readouterr().err


@pytest.mark.parametrize("windows, message", [
    ('{"bogus": 1}', "unknown key(s) ['bogus']"),
    ('{"anchor": "everywhere"}', "WindowConfig.anchor"),
    ('{"sag": -1}', "WindowConfig.sag"),
    ("[1, 2]", "--windows"),
])  # fmt: skip
def test_make_dataset_bad_windows_config(windows, message, tmp_path, capsys, monkeypatch):
    mod = load_script("make_dataset")
    monkeypatch.setattr(mod, "imap_seeds", _computing)
    with pytest.raises(SystemExit) as e:
        mod.main(["--out", str(tmp_path / "o"), "--scenes", "2", "--no-progress", "--windows", windows])
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_train_classifier_window_kin_weight_must_be_positive(tmp_path, capsys):
    pytest.importorskip("torch")
    mod = load_script("train_classifier")
    for bad in ("0", "-1", "nan"):
        with pytest.raises(SystemExit):
            mod.main(["--data", str(tmp_path), "--out", str(tmp_path / "o"), "--window-kin-weight", bad])
        assert "--window-kin-weight" in capsys.readouterr().err


def test_sane_noise_levels_are_accepted():
    from kin_envs.cli import MAX_NOISE, noise_level

    assert noise_level("0") == 0.0 and noise_level("0.01") == 0.01
    assert noise_level(str(MAX_NOISE)) == MAX_NOISE


def _assert_refused(call, capsys, blocked):
    with pytest.raises((SystemExit, ValueError)) as e:
        call()
    text = str(e.value) if isinstance(e.value, ValueError) else capsys.readouterr().err
    assert str(blocked) in text and "cannot be created" in text, text


def test_unwritable_out_reproduce_paper(blocked, capsys, monkeypatch):
    mod = load_script("reproduce_paper")
    monkeypatch.setattr(mod, "run_scene", _computing)
    _assert_refused(lambda: mod.main(["--out", str(blocked), "--draws", "0"]), capsys, blocked)


def test_unwritable_json_reproduce_paper(blocked, tmp_path, capsys, monkeypatch):
    mod = load_script("reproduce_paper")
    monkeypatch.setattr(mod, "run_scene", _computing)
    _assert_refused(lambda: mod.main(["--out", str(tmp_path), "--json", str(blocked / "r.json")]), capsys,
                    blocked)  # fmt: skip


def test_unwritable_out_evaluate_detectors(blocked, capsys, monkeypatch):
    mod = load_script("evaluate_detectors")
    monkeypatch.setattr(mod, "map_seeds", _computing)
    argv = ["--scenes", "2", "--out", str(blocked), "--no-progress"]
    _assert_refused(lambda: mod.main(argv), capsys, blocked)


def test_unwritable_out_benchmark(blocked, capsys, monkeypatch):
    mod = load_script("benchmark")
    monkeypatch.setitem(mod.SECTIONS, "lidar", _computing)
    _assert_refused(lambda: mod.main(["--sections", "lidar", "--out", str(blocked)]), capsys, blocked)


def test_unwritable_out_make_dataset(blocked, capsys, monkeypatch):
    mod = load_script("make_dataset")
    monkeypatch.setattr(mod, "imap_seeds", _computing)
    argv = ["--out", str(blocked), "--scenes", "2", "--no-progress"]
    _assert_refused(lambda: mod.main(argv), capsys, blocked)


def test_unwritable_out_train_classifier(blocked, tmp_path, capsys, monkeypatch):
    pytest.importorskip("torch")
    mod = load_script("train_classifier")
    monkeypatch.setattr(mod, "load_dataset", _computing)
    _assert_refused(lambda: mod.main(["--data", str(tmp_path), "--out", str(blocked)]), capsys, blocked)
    _assert_refused(lambda: mod.main(["--data", str(tmp_path), "--out", str(tmp_path / "o"),
                                      "--checkpoint", str(blocked / "m.pt")]), capsys, blocked)  # fmt: skip


def test_unwritable_out_evaluate_policies(blocked, capsys, monkeypatch):
    mod = load_script("evaluate_policies")
    monkeypatch.setattr(mod, "make_env", _computing)
    _assert_refused(lambda: mod.main(["--episodes", "1", "--out", str(blocked), "--no-progress"]), capsys,
                    blocked)  # fmt: skip


def test_benchmark_detectors_noise_and_out(blocked, tmp_path, capsys, monkeypatch):
    mod = load_script("benchmark_detectors")
    monkeypatch.setattr(mod, "run_benchmark", _computing)
    with pytest.raises(SystemExit):
        mod.main(["--noise", "5", "--out", str(tmp_path)])
    assert "--noise" in capsys.readouterr().err
    _assert_refused(lambda: mod.main(["--out", str(blocked)]), capsys, blocked)


def test_unwritable_out_benchmark_tracking(blocked, capsys, monkeypatch):
    mod = load_script("benchmark_tracking")
    monkeypatch.setattr(mod, "run_sequences", _computing)
    _assert_refused(lambda: mod.main(["--out", str(blocked)]), capsys, blocked)


def test_unwritable_out_train_beam_detector(blocked, capsys, monkeypatch):
    pytest.importorskip("torch")
    mod = load_script("train_beam_detector")
    monkeypatch.setattr(mod, "make_data", _computing)
    _assert_refused(lambda: mod.main(["--out", str(blocked)]), capsys, blocked)


def test_reproduce_paper_distance_too_near_is_an_argparse_error(tmp_path, capsys, monkeypatch):
    # at 0.3 m the paper's arc of objects overlaps: refused up front naming the option, not by the scene
    # validation in the middle of the run
    mod = load_script("reproduce_paper")
    monkeypatch.setattr(mod, "run_scene", _computing)
    with pytest.raises(SystemExit) as e:
        mod.main(["--distances", "0.5", "0.3", "--draws", "0", "--no-figures", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--distances 0.3: Scenario I's objects do not fit" in err
    assert "overlaps" in err
