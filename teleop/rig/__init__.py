"""Bringing up a real rig: ``teleop calibrate`` (load cell, gripper, camera) and what they share."""
