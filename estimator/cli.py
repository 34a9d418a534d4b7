"""``estimator``: turn grasps into Young's modulus: calibration, perception, fits, models."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from teleop.cli_start import start

if TYPE_CHECKING:
    from collections.abc import Sequence

    from teleop.clikit import Command

# Nothing else is imported here: the console script imports this module before main() runs, and a
# Ctrl-C meanwhile would end in a traceback. teleop.clikit is imported by start(), under its guard.


def commands() -> dict[str, Command]:
    """The ``estimator`` subcommands, by name (each one's module imported only when it runs)."""
    from teleop.clikit import Command

    return {
        "estimate": Command("estimator.estimate_cli", "estimate Young's modulus from each grasp record or folder of records"),
        "evaluate": Command("estimator.evaluation.evaluate_cli", "score the analytical and learned estimators over labelled grasp records (ablation table)"),
        "card": Command("estimator.evaluation.card_cli", "write a model card's figures table from estimator evaluate --json outputs, or check it"),
        "compare": Command("estimator.evaluation.compare_cli", "score a base and a candidate model on labelled records neither trained on: which is better, with its uncertainty"),
        "build-dataset": Command("estimator.training.dataset_cli", "labelled grasp records to training samples, split by object"),
        "train": Command("estimator.training.train_cli", "train the learned / hybrid model and export it to ONNX", extra="train"),
        "fine-tune": Command("estimator.training.finetune_cli", "adapt a trained model to a new rig from a few labelled grasps", extra="train"),
        "pool": Command("estimator.training.pool_cli", "pool models of one variant trained with other seeds into one", extra="train"),
        "recalibrate": Command("estimator.training.recalibrate_cli", "refit a trained model's interval calibration on its validation objects, without retraining"),
        "bench": Command("estimator.evaluation.bench_cli", "latency and error of every estimator configuration, with the Pareto frontier"),
        "calibrate": Command("estimator.perception.calibrate_cli", "fit a sensor's colour-to-gradient calibration from ball presses"),
        "reconstruct": Command("estimator.perception.reconstruct_cli", "check a calibration: reconstruct held-out ball presses and fit spheres"),
        "serve": Command("estimator.service_cli", "serve live estimates of the grasps on the bus"),
        "reload": Command("estimator.reload_cli", "switch a running estimator service to another model, checked before it serves"),
    }


def main(argv: Sequence[str] | None = None) -> int:
    return start("estimator", __doc__, commands, argv)


if __name__ == "__main__":  # `python -m estimator.cli`, as the console script runs main()
    sys.exit(main())
