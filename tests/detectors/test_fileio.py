"""detectors.fileio: atomic writes leave either the old file or the new one, never a partial one."""

import hashlib
import json
import os
import stat

import pytest

from detectors.fileio import atomic_write, sha256_file, write_json


def test_atomic_write_replaces_and_cleans_up(tmp_path):
    p = tmp_path / "a.json"
    write_json(p, {"x": 1})
    assert p.read_text() == '{\n  "x": 1\n}\n'
    with pytest.raises(RuntimeError), atomic_write(p, "w") as f:
        f.write("partial")
        raise RuntimeError("interrupted")
    assert p.read_text() == '{\n  "x": 1\n}\n'  # the old file survives
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json"]  # no temporary left behind
    with atomic_write(p) as f:
        f.write(b"new")
    assert p.read_bytes() == b"new"
    assert sha256_file(p) == hashlib.sha256(b"new").hexdigest()
    mask = os.umask(0o022)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask  # not mkstemp's private 0600


def test_atomic_write_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"), atomic_write(tmp_path / "no" / "a"):
        pass
    with pytest.raises(ValueError, match="mode"), atomic_write(tmp_path / "a", "a"):
        pass


def test_live_log_is_readable_while_written_and_whole_after_an_error(tmp_path):
    from detectors.fileio import LiveLog

    p = tmp_path / "log.csv"
    with pytest.raises(KeyboardInterrupt), LiveLog(p) as log:
        log.write("a,b\r\n")
        log.write("1,2\r\n")
        assert p.read_bytes() == b"a,b\r\n1,2\r\n"  # flushed at once: a reader follows the run
        log.write("3,")  # a row cut short (as by a partial write)
        raise KeyboardInterrupt
    assert p.read_bytes() == b"a,b\r\n1,2\r\n"  # whole lines only, newlines as written
    assert sorted(q.name for q in tmp_path.iterdir()) == ["log.csv"]
    with pytest.raises(TypeError, match="expected str"), LiveLog(p) as log:
        log.write(b"bytes")
    assert p.read_bytes() == b""


def test_live_log_interrupted_by_ctrl_c_leaves_whole_lines(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    p = tmp_path / "metrics.jsonl"
    code = (
        "import json, itertools\n"
        "from detectors.fileio import LiveLog\n"
        f"with LiveLog({str(p)!r}) as log:\n"
        "    for i in itertools.count():\n"
        "        log.write(json.dumps({'i': i, 'pad': 'x' * 5000}) + '\\n')\n"  # lines beyond one buffer
    )
    # Ctrl-C reaches the child even when pytest runs with SIGINT ignored (a background job, nohup)
    proc = subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while (not p.exists() or p.stat().st_size < 200_000) and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    try:
        proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()  # never leave it writing (its log grows in memory)
        raise AssertionError("LiveLog writer still running 60 s after Ctrl-C") from None
    raw = p.read_bytes()
    assert raw.endswith(b"\n")
    rows = [json.loads(line) for line in raw.splitlines()]
    assert [r["i"] for r in rows] == list(range(len(rows))) and len(rows) >= 40
    assert sorted(q.name for q in tmp_path.iterdir()) == ["metrics.jsonl"]


@pytest.mark.parametrize("where", ["fdopen", "replace", "unlink"])
def test_ctrl_c_at_any_step_of_an_atomic_write_leaves_no_temporary(tmp_path, monkeypatch, where):
    """Ctrl-C right after the temporary file is created, during the rename, or (a second one) during the
    cleanup: the old file survives and no temporary is left."""
    import detectors.fileio as fileio

    p = tmp_path / "a.txt"
    p.write_text("old")
    real = {"fdopen": os.fdopen, "replace": os.replace, "unlink": os.unlink}
    calls = {"n": 0}

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 1:
            raise KeyboardInterrupt
        return real[where](*args, **kwargs)

    if where == "unlink":  # the first Ctrl-C in the rename, a second one inside the cleanup
        monkeypatch.setattr(fileio.os, "replace", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    monkeypatch.setattr(fileio.os, where, interrupted)
    with pytest.raises(KeyboardInterrupt), atomic_write(p, "w") as f:
        f.write("new")
    monkeypatch.undo()
    assert p.read_text() == "old"
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.txt"]
