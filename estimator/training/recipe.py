"""The training recipes' settings: :class:`TrainConfig` and fine-tuning's defaults.

Torch-free, so that the commands' ``--help`` states the defaults without the ``train`` extra.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimator.errors import EstimatorError

__all__ = ["FINE_TUNE_CONFIG", "REPLAY_RATIO", "TrainConfig"]


@dataclass(frozen=True)
class TrainConfig:
    """The training recipe (:mod:`estimator.training.train`'s notes); stored in the model's metadata."""

    epochs: int = 60
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 10
    label_sd_decades: float = 0.15
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        # Named as the commands' options (``--epochs`` for ``epochs``, ...): every field is one.
        if not (math.isfinite(self.label_sd_decades) and self.label_sd_decades >= 0):
            raise EstimatorError(f"--label-sd {self.label_sd_decades!r}: expected a finite value >= 0")
        for option, value in (("--epochs", self.epochs), ("--batch-size", self.batch_size),
                              ("--patience", self.patience), ("--threads", self.threads)):
            if value < 1:
                raise EstimatorError(f"{option} {value!r}: expected a whole number >= 1")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise EstimatorError(f"--lr {self.lr!r}: expected a finite value > 0")
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0):
            raise EstimatorError(f"--weight-decay {self.weight_decay!r}: expected a finite value >= 0")


#: Fine-tuning's recipe (:mod:`estimator.training.finetune`, whose notes say why).
FINE_TUNE_CONFIG = TrainConfig(epochs=20, batch_size=16, lr=3e-4)
#: Replayed base-training samples per new sample in every epoch (:mod:`estimator.training.finetune`).
REPLAY_RATIO = 1
