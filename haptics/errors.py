"""Errors raised on the operator side: mapping, HID protocol and displays."""

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
