"""Making models: datasets, training, fine-tuning, pooling, the conformal step and ONNX export.

``samples``, ``dataset``
    Training samples and ``estimator build-dataset`` (labelled records to samples, split by
    object); torch-free.
``splits``, ``recipe``
    A dataset's encoded splits and how a model's answers on them are scored; the training
    recipes' settings (torch-free).
``model``, ``train``, ``export``
    The network, ``estimator train`` and ONNX export (torch: the ``train`` extra).
``conformal``
    The conformal step: temperature, rigid probability and interval scale fitted on the
    validation objects (torch-free).
``finetune``, ``pool``
    ``estimator fine-tune`` and ``pool`` (torch).
``recalibrate``
    ``estimator recalibrate``: refits a model's calibration through onnxruntime (torch-free).

The ``*_cli`` modules import no torch at their top, so every command's ``--help`` works without
the ``train`` extra.

Imports the run time (:mod:`estimator.inference` and the top level) and
:mod:`estimator.evaluation` (a model's scores, a fine-tune's comparison); nothing at run time
imports it. Nothing is imported here, so ``import estimator.training.samples`` loads no torch.
"""
