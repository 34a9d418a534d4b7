"""The learned and hybrid estimators at run time: a trained model run with onnxruntime, never torch.

``window``, ``inputs``
    The model's input window and what it reads from a grasp (variants, scales, encoding).
``sampling``
    One grasp's frames sampled and measured as the model reads them.
``distribution``
    The model's answer as a distribution over log10 E, and what it says.
``infer``
    A model folder (``metadata.json``, ``model.onnx``) loaded and run with onnxruntime.
``hybrid``
    The learned estimate of a grasp record (``hybrid``, ``cnn``) and the ``auto`` mode.
``reference``
    A model's inputs on one fixed grasp, checked before a model is served.
``provenance``
    What a model was trained on: its dataset's split, read by training and evaluation.

Nothing is imported here, so ``import estimator.inference.inputs`` loads no onnxruntime.
"""
