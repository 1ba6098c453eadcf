"""The benchmark's reserved seeds (numpy only, so data generators can check them cheaply).

:data:`BENCHMARK_SEEDS` belongs to :mod:`kin_envs.detection.benchmark`; training and validation data
must never use it (:func:`check_training_seeds`; :func:`kin_envs.detection.dataset.make_scene` refuses it).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["BENCHMARK_SEEDS", "check_training_seeds"]

#: Seeds reserved for the benchmark; training and validation data must not use them.
BENCHMARK_SEEDS = range(2_000_000_000, 2_100_000_000)


def check_training_seeds(seeds: Iterable[int] | range, what: str = "training data") -> None:
    """Raise ``ValueError`` if any seed lies in the benchmark's reserved range :data:`BENCHMARK_SEEDS`."""
    lo, hi = BENCHMARK_SEEDS.start, BENCHMARK_SEEDS.stop
    if isinstance(seeds, range):
        if len(seeds) and min(seeds[0], seeds[-1]) < hi and max(seeds[0], seeds[-1]) >= lo:
            raise ValueError(
                f"{what}: seeds {seeds.start}..{seeds.stop - 1} overlap the benchmark's reserved seeds "
                f"[{lo}, {hi}); use seeds outside that range"
            )
        return
    s = np.asarray(list(seeds) if not isinstance(seeds, np.ndarray) else seeds, dtype=np.int64).reshape(-1)
    bad = s[(s >= lo) & (s < hi)]
    if bad.size:
        raise ValueError(
            f"{what}: seed {int(bad[0])} is reserved for the benchmark (seeds [{lo}, {hi})); "
            "use seeds outside that range"
        )
