"""Export learned-detector checkpoints (``.pt``) to the torch-free form the detector reads (``.npz``).

``LearnedKinDetector`` runs on the base install (no torch): it reads a checkpoint's ``.npz`` form, the
same weights bit for bit with the metadata (feature and model config, feature version, thresholds,
positioning, angular resolution, ``weights_sha256``) and the SHA-256 of the ``.pt`` it was made from.
``save_checkpoint`` (``scripts/train_classifier.py``, ``scripts/calibrate_thresholds.py``) writes it
beside every ``.pt`` it saves; this script writes it for a ``.pt`` saved before that, or after the
``.pt`` was replaced by other means (the detector then warns that the npz is stale and falls back to
torch). Needs torch (the ``train`` extra) to read the ``.pt``::

    python scripts/export_checkpoint.py outputs/train/learned.pt          # -> outputs/train/learned.npz
    python scripts/export_checkpoint.py a.pt b.pt
    python scripts/export_checkpoint.py                                   # the shipped checkpoint
    python scripts/export_checkpoint.py --check                           # is the shipped npz current?
"""

from __future__ import annotations

import argparse
from pathlib import Path

from kin_envs.cli import add_logging_args, script_logger, setup_logging

logger = script_logger(__file__)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "checkpoints", type=Path, nargs="*",
        help="learned-detector .pt checkpoints (default: the shipped one, detectors/checkpoints/"
        "learned_default.pt)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=Path, default=None,
        help="the npz to write (one checkpoint only; default: beside the .pt, <name>.npz)",
    )  # fmt: skip
    p.add_argument(
        "--check", action="store_true",
        help="write nothing: exit 1 unless every checkpoint's npz exists, reads back and was made from "
        "these exact .pt bytes",
    )  # fmt: skip
    add_logging_args(p)
    args = p.parse_args(argv)
    if args.out is not None and (len(args.checkpoints) != 1 or args.check):
        p.error("--out takes exactly one checkpoint and no --check")
    return args


def check(pt: Path) -> str | None:
    """Why the npz beside ``pt`` is not its current torch-free form, or None if it is."""
    from detectors.fileio import sha256_file
    from detectors.learned import load_npz_checkpoint, npz_path

    npz = npz_path(pt)
    try:
        ck = load_npz_checkpoint(npz)
    except (OSError, ValueError) as e:
        return str(e)
    src = (ck.get("source") or {}).get("sha256")
    if src != sha256_file(pt):
        return f"{npz} was made from other bytes than {pt} (recorded SHA-256 {src!r})"
    return None


def main(argv: list[str] | None = None) -> list[Path]:
    args = parse_args(argv)
    setup_logging(args)
    from detectors.learned import DEFAULT_CHECKPOINT

    pts = args.checkpoints or [DEFAULT_CHECKPOINT]
    if args.check:
        bad = [(pt, why) for pt in pts if (why := check(pt)) is not None]
        for pt, why in bad:
            logger.error(f"{pt}: {why}")
        if bad:
            raise SystemExit(1)
        logger.info(f"{len(pts)} npz form(s) current")
        return []
    from detectors.learned_torch import export_checkpoint

    written = []
    for pt in pts:
        out = export_checkpoint(pt, args.out)
        logger.info(f"{pt} -> {out} ({out.stat().st_size / 1e3:.0f} kB)")
        written.append(out)
    return written


if __name__ == "__main__":
    from kin_envs.cli import run_main

    run_main(main)
