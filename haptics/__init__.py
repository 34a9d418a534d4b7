"""haptics package: the operator's softness display.

``mapping`` (E and its interval to a display-independent percept and a
command), ``protocol`` (the vendor-defined HID reports, see PROTOCOL.md),
``devices`` (the display family: simulated and USB HID backends) and
``renderer`` (estimates in, reports out, time driven by the caller).
"""
