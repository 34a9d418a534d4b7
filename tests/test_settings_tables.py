"""The packages' settings tables, as they register themselves with the shared base."""

from __future__ import annotations

import importlib.metadata

import pytest

from teleop.errors import SettingsError
from teleop.settings import TABLES_GROUP, Section, load_settings, package_tables


def test_every_registered_table_is_built_by_a_section_of_that_name():
    entries = importlib.metadata.entry_points(group=TABLES_GROUP)
    assert sorted(e.name for e in entries) == list(package_tables()) == ["display", "estimator", "operator"]
    for entry in entries:
        section = entry.load()
        assert issubclass(section, Section) and entry.name == section.TABLE, entry.value


def test_a_table_no_package_registered_is_refused_naming_the_registered_ones(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text("[estimatr]\nn_frames = 3\n")
    with pytest.raises(SettingsError, match="estimatr") as raised:
        load_settings(path)
    assert str(path) in str(raised.value)


def test_the_shared_base_names_no_package_table_in_its_source():
    import inspect

    import teleop.settings

    source = inspect.getsource(teleop.settings)
    assert '"estimator"' not in source and '"display"' not in source and '"operator"' not in source
