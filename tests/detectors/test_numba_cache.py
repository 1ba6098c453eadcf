"""The numba cache of a function goes stale when a kernel it compiles in from *another* file changes
(numba stamps a function with its own file only): :func:`detectors._numba_cache.guard_dependencies`
makes such a change recompile instead of reusing old machine code."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from detectors import _numba_cache

ROOT = Path(__file__).resolve().parents[2]

RUN = """
import sys
from detectors._numba_cache import guard_dependencies
if sys.argv[1] == "guard":
    guard_dependencies(sys.argv[2])
sys.path.insert(0, sys.argv[3])
from jitdemo.outer import outer
print(outer(1.0))
"""


def _write_inner(pkg: Path, value: float) -> None:
    (pkg / "inner.py").write_text(textwrap.dedent(f"""
        import numba

        @numba.njit(cache=True)
        def inner(x):
            return x + {value}
    """))


def _run(tmp: Path, mode: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(NUMBA_CACHE_DIR=str(tmp / f"cache-{mode}"), PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", RUN, mode, str(tmp / "jitdemo"), str(tmp)],
                         capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


def test_a_changed_kernel_in_another_file_recompiles_its_callers(tmp_path):
    pkg = tmp_path / "jitdemo"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "outer.py").write_text(textwrap.dedent("""
        import numba
        from .inner import inner

        @numba.njit(cache=True)
        def outer(x):
            return inner(x) * 10.0
    """))
    _write_inner(pkg, 1.0)
    assert _run(tmp_path, "guard") == "20.0"
    assert _run(tmp_path, "guard") == "20.0"  # from the cache
    _write_inner(pkg, 2.0)  # outer.py untouched: numba alone would load its stale machine code
    assert _run(tmp_path, "guard") == "30.0"


def test_functions_outside_the_guarded_packages_keep_numbas_locators(tmp_path):
    def f():
        return 0

    assert _numba_cache._DependencyLocator.from_function(f, str(tmp_path / "elsewhere.py")) is None
    loc = _numba_cache._DependencyLocator.from_function(f, str(ROOT / "detectors" / "features.py"))
    assert loc is not None and loc.get_source_stamp()[1] == _numba_cache._DIGESTS[(str(ROOT / "detectors"),)]
