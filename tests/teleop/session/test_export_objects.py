"""The catalogue objects an export labels grasps from (:mod:`teleop.session.export_objects`)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from teleop.errors import SessionLogError, SettingsError
from teleop.session.export_objects import catalogue_objects, label_catalogue_objects

LOG = Path("session.mcap")
GEL = '[[objects]]\nname = "lab_gel"\nshape = "box"\nmaterial = "rubber"\nmodulus_pa = 7.5e4\n'
GEL_REMEASURED = GEL.replace("7.5e4", "9.0e4")
CORK = '[[objects]]\nname = "shop_cork"\nshape = "cylinder"\nmaterial = "wood"\nmodulus_pa = 1.2e7\n'


def _log_info(attachments: dict[str, bytes], damaged: dict[str, str] | None = None) -> SimpleNamespace:
    """What a LogInfo holds of a log's attachments: intact ones' bytes, damaged ones' damage."""
    return SimpleNamespace(attachments=attachments, damaged_attachments=damaged or {})


@pytest.mark.parametrize("data", [b"garbage [[[", b""])
def test_an_attached_catalogue_that_does_not_load_is_named_as_the_logs_attachment(data):
    info = _log_info({"catalogue.toml": data})
    with pytest.raises(SettingsError, match="the log's attached catalogue.toml") as caught:
        catalogue_objects(info, None, log=LOG)
    assert "/tmp" not in str(caught.value)  # not the temporary file it was read from


def test_a_catalogue_given_is_used_instead_of_the_one_stored_in_the_log(tmp_path):
    given = tmp_path / "shop.toml"
    given.write_text(CORK, encoding="utf-8")
    info = _log_info({"catalogue.toml": GEL.encode()})
    assert set(catalogue_objects(info, given, log=LOG)) == {"shop_cork"}
    assert set(catalogue_objects(info, None, log=LOG)) == {"lab_gel"}


def test_a_damaged_label_catalogue_is_refused_not_skipped():
    info = _log_info({"label_catalogue-1.toml": GEL.encode()},
                     {"label_catalogue-2.toml": "attachment label_catalogue-2.toml failed its CRC-32"})
    with pytest.raises(SessionLogError, match="label_catalogue-2.toml"):
        label_catalogue_objects(info, log=LOG)


def test_the_later_label_catalogue_gives_an_object_named_in_two():
    # attached out of order: "later" is the catalogue's number, not its place among the attachments
    info = _log_info({"label_catalogue-2.toml": GEL_REMEASURED.encode(), "label_catalogue-1.toml": GEL.encode(),
                      "label_catalogue-3.toml": CORK.encode()})
    objects = label_catalogue_objects(info, log=LOG)
    assert set(objects) == {"lab_gel", "shop_cork"}
    assert objects["lab_gel"].modulus_pa == 9.0e4
