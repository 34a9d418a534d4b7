"""The learned and hybrid estimators: dataset, model, training, ONNX export and inference.

Modules and what they import:

``inputs``
    What the model reads, from a grasp record (torch-free).
``dataset``
    ``estimator build-dataset``: labelled records to training samples, split by object.
``model``, ``train``, ``export``
    The network, ``estimator train`` and ONNX export (torch; training only).
``infer``, ``hybrid``
    ONNX inference with onnxruntime and the run-time hybrid / auto estimate (never torch).

Nothing is imported here, so ``import estimator.learned.infer`` loads no torch.
"""
