"""System commands: the ones that tie the robot side, the estimator and the haptics together.

Only modules here may import ``estimator`` or ``haptics``; the rest of ``teleop`` is the
shared base those packages build on, and never imports them (``tests/test_import_graph.py``).

``demo``          ``teleop demo``: the live system on simulated hardware over a scene
``demo_table``    the demo's live lines and closing table
``latency``       ``teleop bench-latency``: latency to the display report, estimate rate
``dataset``       ``teleop import-dataset``: the published dataset to grasp records
                  (raw layout) and estimator training samples (preprocessed layout)
"""
