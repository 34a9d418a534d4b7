"""``estimator``: grasps to Young's modulus, by lifecycle.

Run time, what ships (the live service and ``estimator estimate``, ``serve``, ``reload``,
``calibrate``, ``reconstruct``): this top level (segmentation, signals, lags, contact features,
the analytical fits, measurement, streaming, the service and its model slot),
:mod:`estimator.perception` (the sensor's colour calibration and depth, with its own calibration
tooling) and :mod:`estimator.inference` (the learned model run with onnxruntime, never torch).

:mod:`estimator.training`
    datasets, training, fine-tuning, pooling, the conformal step and ONNX export; torch (the
    ``train`` extra) for the network itself.
:mod:`estimator.evaluation`
    scoring over labelled records, comparison, benchmarks, model cards and plots.

Training and evaluation import the run time, never the reverse; training also scores with
evaluation, evaluation never trains (``tests/test_import_graph.py`` checks both).
"""
