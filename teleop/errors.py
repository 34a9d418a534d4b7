"""Errors raised by the robot side: devices, the bus, settings and records.

Every message names the thing that failed and, where one exists, the next step.

:class:`ComplianceTeleopError` is the root of every error the project raises on purpose:
``teleop``'s :class:`TeleopError`, ``estimator.errors.EstimatorError`` and
``haptics.errors.HapticsError`` all derive from it, so the command-line kit
(:mod:`teleop.clikit`) catches that one type and knows no other package.
"""


class ComplianceTeleopError(Exception):
    """Root of every error the project (``teleop``, ``estimator``, ``haptics``) raises on purpose."""


class TeleopError(ComplianceTeleopError):
    """Base of every error the ``teleop`` package raises on purpose."""


class SettingsError(TeleopError, ValueError):
    """A settings file or value is missing, unknown, of the wrong type or out of range."""


class RecordError(TeleopError, ValueError):
    """A grasp record is damaged, incomplete or of an unknown version."""


class DatasetError(TeleopError, ValueError):
    """A published-dataset file cannot be imported as it stands."""


class UnsafePickleError(DatasetError):
    """A pickle asked to build something other than a plain numpy array."""


class DeviceError(TeleopError):
    """A hardware or simulated device failed."""


class DeviceNotConnectedError(DeviceError):
    """A device was used before ``connect()`` or after ``close()``."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """A device did not answer within its timeout."""


class DeviceStalledError(DeviceError):
    """A connected device has given no valid data for longer than it may (silent, or only garbage)."""


class BackendNotFoundError(DeviceError, LookupError):
    """No backend of that name is registered for the device family, or it cannot be loaded."""

    @classmethod
    def missing_library(cls, what: str, exc: ImportError, *, install: str | None = None) -> "BackendNotFoundError":
        """``what`` cannot be loaded because ``exc``'s library is missing; ``install`` says what
        provides it (None: the ``robot`` extra, which holds the hardware libraries)."""
        hint = install or "the 'robot' extra"
        return cls(f"{what} cannot be loaded: {exc} (install {hint})")


class BusError(TeleopError):
    """A bus message could not be sent, or a received one was refused."""


class SimulationError(TeleopError, ValueError):
    """An input to the simulator (height map, shear, background, press) is not what it expects."""


class InvalidCommandError(DeviceError, ValueError):
    """A device command's argument is out of range (width, speed, force, timeout)."""


class MessageRejected(BusError, ValueError):
    """A bus message broke the wire format; ``reason`` says which rule (see teleop.bus.wire)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class BusTimeoutError(BusError, TimeoutError):
    """A lossless send found no room within its timeout, or no subscriber appeared in time."""


class BusSecurityError(BusError):
    """A bus endpoint lacks the CURVE keys it needs, or the keys cannot be used."""


class BusAddressInUseError(BusError):
    """A bus endpoint cannot be bound: another process holds its address."""


class SessionLogError(TeleopError, ValueError):
    """A session log (MCAP) cannot be written, read, replayed, exported or recovered."""
