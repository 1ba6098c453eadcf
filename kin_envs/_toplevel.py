"""Are the top-level packages ``detectors`` and ``agents`` ours?

kin-envs installs three top-level packages: ``kin_envs``, ``detectors`` and ``agents``. The last two are
also the names of unrelated distributions on the public package index. Installing one of those into the
same environment either shadows ours (an earlier entry of ``sys.path``) or silently merges its files into
our folder (pip writes both into ``site-packages/detectors/``, the later ``__init__.py`` wins). Either
way imports break later in confusing ways, so ``import kin_envs`` checks first, without importing them:

* the package Python would import must be ours: its ``__init__.py`` carries the marker
  ``__kin_envs_package__ = True`` (a foreign ``__init__`` that replaced ours in a merged folder does not);
* no distribution other than kin-envs is installed under that very name (a merged folder whose
  ``__init__`` is still ours).

Otherwise an ``ImportError`` names the conflicting distribution(s) and the way out.
"""

from __future__ import annotations

import importlib.util
from importlib import metadata
from pathlib import Path

#: the line every package of kin-envs carries in its ``__init__.py``
MARKER = "__kin_envs_package__ = True"
OURS = frozenset({"kin-envs", "kin_envs"})
CHECKED = ("detectors", "agents")


def _providers(name: str) -> list[str]:
    """Installed distributions other than kin-envs that provide the top-level package ``name``."""
    found = set(metadata.packages_distributions().get(name, []))
    try:
        found.add(metadata.distribution(name).metadata["Name"])
    except metadata.PackageNotFoundError:
        pass
    return sorted(d for d in found if d and d.lower().replace("_", "-") not in OURS)


def _conflict(name: str, why: str) -> ImportError:
    dists = _providers(name)
    named = (f"the distribution(s) {', '.join(repr(d) for d in dists)}" if dists
             else "another package of that name (no installed distribution claims it)")
    uninstall = f"`pip uninstall {' '.join(dists)}`" if dists else "remove it from the path"
    return ImportError(
        f"kin-envs: the top-level package {name!r} is not kin-envs' own: {why}; it comes from {named}. "
        f"kin-envs ships its own {name!r} package, and an unrelated package of the same name cannot live in "
        f"the same environment: {uninstall}, then reinstall kin-envs (`pip install --force-reinstall "
        f"--no-deps -e .` from the clone), or use separate virtual environments."
    )


def check_toplevel(name: str) -> None:
    """Raise ``ImportError`` naming the conflicting distribution if ``name`` is not kin-envs' package."""
    spec = importlib.util.find_spec(name)
    if spec is None:  # not importable at all: a broken install, reported at import as usual
        return
    origin = spec.origin
    if origin is None or not origin.endswith("__init__.py"):
        raise _conflict(name, f"Python would import it from {origin or spec.submodule_search_locations}")
    try:
        text = Path(origin).read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise _conflict(name, f"its {origin} cannot be read ({e})") from e
    if MARKER not in text:
        raise _conflict(name, f"{origin} lacks kin-envs' marker")
    try:
        other = metadata.distribution(name).metadata["Name"]
    except metadata.PackageNotFoundError:
        return
    if other and other.lower().replace("_", "-") not in OURS:
        raise _conflict(name, f"a distribution named {other!r} is installed beside it (merged folders)")


def check_all() -> None:
    for name in CHECKED:
        check_toplevel(name)
