"""Passwords in URLs, hidden wherever a setting is printed or stored.

A setting may be a URL with credentials (``camera_source = "http://admin:PASSWORD@pi:8080/?action=stream"``,
the stream server's login). Devices open the real value; reports, error messages, session logs and
grasp records carry it with the password replaced by ``***``, since they are shared.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["REDACTED", "redact_url", "redacted"]

REDACTED = "***"

# scheme://user:password@ with the password running to the authority's last "@" (as urllib.parse.urlsplit
# reads it); the authority ends at "/", "?", "#" or whitespace, so URLs inside longer text are found too.
_CREDENTIALS = re.compile(r"(?P<head>\b[A-Za-z][A-Za-z0-9+.-]*://[^/?#\s:]*:)[^/?#\s]*@")


def redact_url(text: str) -> str:
    """``text`` with the password of every URL in it replaced by :data:`REDACTED`.

    Parameters
    ----------
    text : str
        A URL (``http://admin:secret@pi:8080/?action=stream`` gives ``http://admin:***@pi:8080/?action=stream``)
        or text holding URLs, such as an error message. A device index (``"0"``), a path
        (``/dev/video0``) and a URL with a user but no password come back unchanged.

    Returns
    -------
    str
        The text, safe to print or store.
    """
    return _CREDENTIALS.sub(lambda m: f"{m['head']}{REDACTED}@", text)


def redacted(data: Any) -> Any:
    """``data`` (plain data: dicts, lists, tuples, strings, numbers) with :func:`redact_url` applied to
    every string in it, keys included; what is no string comes back as it is."""
    if isinstance(data, str):
        return redact_url(data)
    if isinstance(data, dict):
        return {redacted(k): redacted(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return type(data)(redacted(v) for v in data)
    return data
