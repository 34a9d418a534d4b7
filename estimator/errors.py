"""Errors raised by the estimator: perception, calibration, fits and models."""

from teleop.errors import ComplianceTeleopError


class EstimatorError(ComplianceTeleopError):
    """Base of every error the ``estimator`` package raises on purpose."""


class CalibrationError(EstimatorError, ValueError):
    """Calibration input or a calibration file is unusable."""


class PerceptionError(EstimatorError, ValueError):
    """A frame or stream cannot be turned into measurements as given."""


class ModelError(EstimatorError):
    """A learned model cannot be loaded, or its inputs do not fit it."""


class FitError(EstimatorError, ValueError):
    """A fit's input series are malformed, or an estimate would break its invariants."""


class SampleError(EstimatorError, ValueError):
    """A training sample, or a sample file, is malformed."""
