"""Scoring estimators: ``estimator evaluate``, ``compare``, ``bench`` and ``card``, and their plots.

``metrics``
    How an estimate is scored against a label (with the display's own mapping, :mod:`haptics.mapping`).
``evaluate``, ``compare``, ``bench``
    Accuracy over labelled records (the ablation table), a candidate model against its base,
    latency and error of every configuration. ``evaluate`` and ``bench`` plot with matplotlib,
    imported only when drawing.
``card_cli``
    A model card's figures table from ``estimator evaluate --json`` outputs.

Imports the run time only, never :mod:`estimator.training`; nothing at run time imports it.
"""
