"""Grasp simulator: contact mechanics, grasp dynamics, sensor models and tactile optics.

``shapes`` (object surfaces and poses) -> ``contact`` (BEM on a bonded gel layer, Hertz where
exact) -> ``grasp`` (gripper motion, bulk and finger compliance, one labelled GraspRecord) with
``sensors`` (load cell, gripper width, camera clocks) and ``optics`` (frames); ``simulate`` is the
``teleop simulate`` command, ``preview`` its PNG contact sheets.
"""
