"""Which seeds training data may use (numpy only, so data generators can check them cheaply).

Two ranges, one check:

- :data:`BENCHMARK_SEEDS` belongs to :mod:`kin_envs.detection.benchmark` (single-scan splits and the
  sequence splits); training and validation data must never use it.
- :data:`TRAINING_SEEDS` = [0, 1,000,000) is what the swarm-trained data (the beam detector's
  :func:`kin_envs.detection.beam_dataset.beam_records`) draws from: it also stays below the detector
  evaluation sweep, which starts at 1,000,000.

:func:`check_training_seeds` refuses the benchmark's seeds always, and seeds outside ``within`` when
given (``within=TRAINING_SEEDS`` for the swarm data); :func:`kin_envs.detection.dataset.make_scene`,
``beam_records`` and the data scripts call it.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["BENCHMARK_SEEDS", "TRAINING_SEEDS", "check_training_seeds"]

#: Seeds reserved for the benchmark; training and validation data must not use them.
BENCHMARK_SEEDS = range(2_000_000_000, 2_100_000_000)

#: Seeds the swarm-trained detectors' data uses: [0, 1,000,000), below the evaluation sweep (from
#: 1,000,000) and the benchmark.
TRAINING_SEEDS = range(0, 1_000_000)


def _span(seeds: range) -> tuple[int, int]:
    return min(seeds[0], seeds[-1]), max(seeds[0], seeds[-1])


def check_training_seeds(
    seeds: Iterable[int] | range, what: str = "training data", *, within: range | None = None
) -> None:
    """Raise ``ValueError`` if any seed is not for training.

    A seed is refused if it lies in the benchmark's reserved :data:`BENCHMARK_SEEDS`, or, when
    ``within`` is given (e.g. :data:`TRAINING_SEEDS`), outside ``within``. ``what`` names the caller's
    input in the message. A ``range`` is checked by its ends (no array is built).
    """
    lo, hi = BENCHMARK_SEEDS.start, BENCHMARK_SEEDS.stop
    if isinstance(seeds, range):
        if not len(seeds):
            return
        first, last = _span(seeds)
        if first < hi and last >= lo:
            raise ValueError(
                f"{what}: seeds {seeds.start}..{seeds.stop - 1} overlap the benchmark's reserved seeds "
                f"[{lo}, {hi}); use seeds outside that range"
            )
        if within is not None and not (first >= within.start and last < within.stop):
            bad = first if first < within.start else last
            raise ValueError(_outside(what, bad, within))
        return
    s = np.asarray(list(seeds) if not isinstance(seeds, np.ndarray) else seeds, dtype=np.int64).reshape(-1)
    bad = s[(s >= lo) & (s < hi)]
    if bad.size:
        raise ValueError(
            f"{what}: seed {int(bad[0])} is reserved for the benchmark (seeds [{lo}, {hi})); "
            "use seeds outside that range"
        )
    if within is not None:
        bad = s[(s < within.start) | (s >= within.stop)]
        if bad.size:
            raise ValueError(_outside(what, int(bad[0]), within))


def _outside(what: str, seed: int, within: range) -> str:
    return (
        f"{what}: training seed {seed} is outside the training range [{within.start}, {within.stop}); "
        "seeds outside it are reserved for evaluation"
    )
