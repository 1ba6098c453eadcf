"""Training of the beam kin detector (:mod:`detectors.beam_detector`) from per-beam samples (torch).

Reads samples (:func:`detectors.beam_detector.load_beam_dataset` records), never a world. The loss is
DROW's: binary cross-entropy on ``p(beam hits a kin)`` plus a smooth-L1 regression of the kin centre
(offset from the beam's return, beam frame) on kin beams. Beams on same-radius cylinders are left out
(identical to a kin in one scan). Negatives far from any kin-like structure are subsampled and
re-weighted by the inverse keep probability, so ``p`` stays calibrated.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .beam_detector import _OFFSET_SCALE, BeamConfig, BeamModel, beam_inputs
from .samples import category_code

__all__ = ["BeamTrainConfig", "beam_training_set", "train_beam_model"]


@dataclass(frozen=True)
class BeamTrainConfig:
    """Optimisation of :func:`train_beam_model` (seeded).

    Attributes:
        epochs, batch_size, lr, weight_decay: Adam with cosine decay.
        offset_weight: weight of the centre regression loss.
        easy_keep: keep probability of "easy" negatives (not on a kin-width object, not within the
            cut-out of a kin beam); kept ones are weighted ``1 / easy_keep``.
        max_minutes: stop early after this wall time.
    """

    epochs: int = 8
    batch_size: int = 2048
    lr: float = 3e-3
    weight_decay: float = 1e-5
    offset_weight: float = 1.0
    easy_keep: float = 0.1
    max_minutes: float = 12.0

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1 or not self.lr > 0 or not 0 < self.easy_keep <= 1:
            raise ValueError(f"BeamTrainConfig: invalid values in {self}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d) -> BeamTrainConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict) or set(d) - names:
            raise ValueError(
                f"BeamTrainConfig: unknown key(s) {sorted(set(d) - names)}; expected {sorted(names)}"
            )
        return cls(**d)


def beam_training_set(records: dict, config: BeamConfig, easy_keep: float, rng: np.random.Generator):
    """``(x, y, offset target (m, beam frame), weight)`` from per-beam records (see the module docstring)."""
    ranges = records["ranges"]
    x, row, beam = beam_inputs(ranges, records["angles"], config)
    label = records["label"][row, beam].astype(np.float32)
    cat = records["category"][row, beam]
    keep = cat != category_code("same_radius_cylinder")
    # hard negatives: kin-width look-alikes, and every beam within the cut-out of a kin beam
    near = np.zeros(ranges.shape, bool)
    lab = records["label"].astype(bool)
    for j in range(-config.half_window, config.half_window + 1):
        near |= np.roll(lab, j, axis=1)
    hard = near[row, beam] | np.isin(cat, [category_code("kin_width_prism"), category_code("kin_width_box")])
    easy = (label == 0) & ~hard
    draw = rng.random(easy.shape[0]) < easy_keep
    keep &= ~easy | draw
    w = np.where(easy, 1.0 / easy_keep, 1.0).astype(np.float32)
    # target: kin centre minus the beam's return, in the beam frame (u along, v across, CCW)
    centre = records["centre"][row, beam].astype(np.float64)
    ang = records["angles"][beam]
    ca, sa = np.cos(ang), np.sin(ang)
    r = ranges[row, beam].astype(np.float64)
    dx, dy = centre[:, 0] - r * ca, centre[:, 1] - r * sa
    t = np.stack([dx * ca + dy * sa, -dx * sa + dy * ca], axis=1)
    t[label == 0] = 0.0
    return x[keep], label[keep], t[keep].astype(np.float32), w[keep]


class _Net(nn.Module):
    def __init__(self, config: BeamConfig, x_mean, x_std) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        d = config.n_inputs
        for h in config.hidden:
            layers += [nn.Linear(d, h), nn.ReLU()]
            d = h
        layers.append(nn.Linear(d, 3))
        self.net = nn.Sequential(*layers)
        self.register_buffer("m", torch.as_tensor(x_mean))
        self.register_buffer("s", torch.as_tensor(x_std))

    def forward(self, x):
        return self.net((x - self.m) / self.s)


def train_beam_model(
    x, y, t, w, config: BeamConfig, train: BeamTrainConfig | None = None, *, seed: int = 0, log=None
) -> tuple[BeamModel, list[dict]]:
    """Train the per-beam MLP on ``beam_training_set`` arrays → ``(BeamModel, per-epoch log)``."""
    tc = train or BeamTrainConfig()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    x_mean = x.mean(axis=0).astype(np.float32)
    x_std = np.maximum(x.std(axis=0), 1e-3).astype(np.float32)
    net = _Net(config, x_mean, x_std)
    opt = torch.optim.Adam(net.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    steps = tc.epochs * math.ceil(len(x) / tc.batch_size)
    # OneCycleLR divides by pct_start * total_steps - 1: 0.1 x 10 steps is a ZeroDivisionError
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=tc.lr, total_steps=steps, pct_start=0.1 if steps != 10 else 0.2
    )
    X, Y, T, W = (torch.as_tensor(v) for v in (x, y, t / _OFFSET_SCALE, w))
    bce = nn.BCEWithLogitsLoss(reduction="none")
    history = []
    t0 = time.perf_counter()
    for epoch in range(tc.epochs):
        perm = torch.as_tensor(rng.permutation(len(x)))
        total = 0.0
        for k in range(0, len(x), tc.batch_size):
            idx = perm[k : k + tc.batch_size]
            out = net(X[idx])
            yb, wb = Y[idx], W[idx]
            loss_c = (bce(out[:, 0], yb) * wb).sum() / wb.sum()
            pos = yb > 0.5
            loss_r = nn.functional.smooth_l1_loss(out[pos, 1:], T[idx][pos]) if pos.any() else out.sum() * 0
            loss = loss_c + tc.offset_weight * loss_r
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        history.append({"epoch": epoch, "loss": total / len(x), "seconds": time.perf_counter() - t0})
        if log:
            log(history[-1])
        if time.perf_counter() - t0 > 60 * tc.max_minutes:
            break
    layers = [m for m in net.net if isinstance(m, nn.Linear)]
    weights = [(m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy()) for m in layers]
    return BeamModel(config, weights, x_mean, x_std), history
