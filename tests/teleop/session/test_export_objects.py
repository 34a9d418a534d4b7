"""The catalogue objects an export labels grasps from (:mod:`teleop.session.export_objects`)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from teleop.errors import SettingsError
from teleop.session.export_objects import catalogue_objects


@pytest.mark.parametrize("data", [b"garbage [[[", b""])
def test_an_attached_catalogue_that_does_not_load_is_named_as_the_logs_attachment(data):
    info = SimpleNamespace(attachments={"catalogue.toml": data}, damaged_attachments={})
    with pytest.raises(SettingsError, match="the log's attached catalogue.toml") as caught:
        catalogue_objects(info, None, log=Path("session.mcap"))
    assert "/tmp" not in str(caught.value)  # not the temporary file it was read from
