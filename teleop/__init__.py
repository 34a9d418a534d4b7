"""teleop package."""
