"""Errors raised on the operator side: mapping, HID protocol, displays and operator input devices."""

from teleop.errors import ComplianceTeleopError


class HapticsError(ComplianceTeleopError):
    """Base of every error the ``haptics`` package raises on purpose."""


class ProtocolError(HapticsError, ValueError):
    """A HID report cannot be encoded or decoded as given."""


class DisplayError(HapticsError):
    """A haptic display failed."""


class DisplayNotConnectedError(DisplayError):
    """A display was used before ``connect()``, after ``close()`` or after an unplug."""


class MappingError(HapticsError, ValueError):
    """An estimate, an interval or a time cannot be mapped to a display command."""


class DisplayBackendNotFoundError(DisplayError, LookupError):
    """No display backend of that name is registered."""


class InputDeviceError(HapticsError):
    """An operator input device (keyboard, gamepad, the display's grip, the simulated operator)
    failed: not found, unplugged, or a device that has no grip."""


class InputNotConnectedError(InputDeviceError):
    """An operator input device was used before ``connect()``, after ``close()`` or after a failure."""


class InputBackendNotFoundError(InputDeviceError, LookupError):
    """No operator input backend of that name is registered."""


class OperatorInputError(HapticsError, ValueError):
    """An operator input reading, or an argument given to an input device, is out of range."""
