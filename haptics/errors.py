"""Errors raised on the operator side: mapping, HID protocol and displays."""


class HapticsError(Exception):
    """Base of every error the ``haptics`` package raises on purpose."""


class ProtocolError(HapticsError, ValueError):
    """A HID report cannot be encoded or decoded as given."""


class DisplayError(HapticsError):
    """A haptic display failed."""


class DisplayNotConnectedError(DisplayError):
    """A display was used before ``connect()``, after ``close()`` or after an unplug."""
