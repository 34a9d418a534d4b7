"""Writing calibrated values into a settings file: comments and order kept, bad values refused."""

from __future__ import annotations

import os
import shutil
import stat
import tempfile

import numpy as np
import pytest

from teleop.errors import SettingsError
from teleop.settings import default_settings_path, load_settings
from teleop.settings_edit import SettingChange, format_changes, update_settings_file


@pytest.fixture
def settings_file(tmp_path):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    return path


def _keys_in_order(text: str) -> list[str]:
    return [line.split("=")[0].strip() for line in text.splitlines() if "=" in line and not line.startswith("#")]


def test_changes_are_written_and_everything_else_is_kept(settings_file):
    before = settings_file.read_text()
    corners = ((40.5, 80.0), (430.0, 120.25), (50.0, 420.0), (440.0, 360.0))
    changes = update_settings_file(settings_file, {
        "load_cell.counts_per_n": np.float64(41873.2),
        "load_cell.tare_counts": -1234,
        "sensors.left.warp_corners_px": corners,
        "sensors.left.pixel_pitch_m": 9.1e-5,  # a key with a comment on its line
    })
    after = settings_file.read_text()
    assert changes[0] == SettingChange("load_cell.counts_per_n", 42000.0, 41873.2)
    assert changes[2].old == [[46.0, 87.0], [439.0, 121.0], [52.0, 425.0], [446.0, 368.0]]
    settings = load_settings(settings_file)
    assert settings.load_cell.counts_per_n == 41873.2 and settings.load_cell.tare_counts == -1234
    assert settings.sensor("left").warp_corners_px == corners
    # every comment line survives, keys stay where they were, the inline comment too
    assert [line for line in before.splitlines() if line.startswith("#")] == \
           [line for line in after.splitlines() if line.startswith("#")]
    assert _keys_in_order(before) == _keys_in_order(after)
    assert "# 11 px per mm, measured with calipers" in after
    changed = [a for b, a in zip(before.splitlines(), after.splitlines(), strict=True) if a != b]
    assert len(changed) == 4
    assert format_changes(changes).splitlines()[:2] == [
        "load_cell.counts_per_n: 42000.0 -> 41873.2", "load_cell.tare_counts: 0 -> -1234"]


def test_missing_keys_and_tables_are_created(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text("# a minimal rig\n[load_cell]\nbackend = \"sim\"\n")
    changes = update_settings_file(path, {"gripper.finger_stiffness_n_per_m": 1.5e5, "load_cell.tare_counts": 7})
    assert [c.old for c in changes] == [None, None]
    assert format_changes(changes).startswith("gripper.finger_stiffness_n_per_m: (unset) -> 150000.0")
    settings = load_settings(path)
    assert settings.gripper.finger_stiffness_n_per_m == 1.5e5 and settings.load_cell.tare_counts == 7
    assert path.read_text().startswith("# a minimal rig\n[load_cell]\n")


@pytest.mark.parametrize("changes, match", [
    ({"load_cell.counts_per_n": -5.0}, "counts_per_n"),
    ({"gripper.no_such_key": 1.0}, "unknown key 'no_such_key'"),
    ({"sensors.left.warp_corners_px": [[1.0, 2.0]]}, "warp_corners_px"),
    ({"counts_per_n": 1.0}, "dotted path"),
    ({"load_cell..counts_per_n": 1.0}, "dotted path"),  # a part left empty, or blank
    ({"load_cell. .counts_per_n": 1.0}, "dotted path"),
    ({".load_cell.counts_per_n": 1.0}, "dotted path"),
    ({"gripper.max_width_m.inner": 1.0}, "is a value, not a table"),
    # The packages' tables are checked by their owners too, as `teleop settings` checks them.
    ({"estimator.n_frames": 0}, r"\[estimator\].*n_frames"),
    ({"display.e_soft_pa": 1e11}, r"\[display\].*e_soft_pa"),
])
def test_an_invalid_result_is_refused_and_the_file_left_untouched(settings_file, changes, match):
    before = settings_file.read_bytes()
    stamp = os.stat(settings_file).st_mtime_ns
    with pytest.raises(SettingsError, match=match):
        update_settings_file(settings_file, {"load_cell.tare_counts": 5, **changes})
    assert settings_file.read_bytes() == before and os.stat(settings_file).st_mtime_ns == stamp
    assert [p.name for p in settings_file.parent.iterdir()] == ["rig.toml"]  # no temporary left behind


def test_a_file_that_is_not_toml_is_named(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[load_cell\n")
    with pytest.raises(SettingsError, match="broken.toml: not valid TOML"):
        update_settings_file(path, {"load_cell.tare_counts": 1})
    with pytest.raises(SettingsError, match="cannot read settings file"):
        update_settings_file(tmp_path / "absent.toml", {"load_cell.tare_counts": 1})


def test_a_linked_settings_file_is_written_through_the_link(settings_file, tmp_path):
    link = tmp_path / "current.toml"
    link.symlink_to(settings_file)
    update_settings_file(link, {"load_cell.tare_counts": 9})
    assert link.is_symlink() and link.resolve() == settings_file.resolve()
    assert load_settings(settings_file).load_cell.tare_counts == 9


def test_crlf_line_ends_are_kept_and_only_the_changed_key_differs(settings_file):
    before = settings_file.read_bytes().replace(b"\r\n", b"\n").replace(b"\n", b"\r\n")
    settings_file.write_bytes(before)
    update_settings_file(settings_file, {"gripper.finger_stiffness_n_per_m": 123456.0})
    after = settings_file.read_bytes()
    changed = [(a, b) for a, b in zip(before.split(b"\r\n"), after.split(b"\r\n"), strict=True) if a != b]
    assert changed == [(b"finger_stiffness_n_per_m = 200000.0", b"finger_stiffness_n_per_m = 123456.0")]
    # a table the file lacks is added with the file's line ends too
    update_settings_file(settings_file, {"sensors.third.camera_latency_s": 0.01})
    text = settings_file.read_bytes()
    assert b"[sensors.third]\r\ncamera_latency_s = 0.01\r\n" in text and text.count(b"\n") == text.count(b"\r\n")


def test_a_byte_order_mark_is_read_and_kept(settings_file):
    before = b"\xef\xbb\xbf" + settings_file.read_bytes()
    settings_file.write_bytes(before)
    changes = update_settings_file(settings_file, {"gripper.finger_stiffness_n_per_m": 123456.0})
    assert changes == [SettingChange("gripper.finger_stiffness_n_per_m", 200000.0, 123456.0)]
    after = settings_file.read_bytes()
    assert after.startswith(b"\xef\xbb\xbf#") and after.count(b"\xef\xbb\xbf") == 1
    assert after == before.replace(b"finger_stiffness_n_per_m = 200000.0", b"finger_stiffness_n_per_m = 123456.0")
    assert load_settings(settings_file).gripper.finger_stiffness_n_per_m == 123456.0


def test_a_file_that_is_not_utf8_is_a_settings_error_not_a_traceback(tmp_path):
    path = tmp_path / "rig.toml"
    data = default_settings_path().read_bytes() + "# 20 \xb0C lab\n".encode("latin-1")  # an editor's Latin-1
    path.write_bytes(data)
    with pytest.raises(SettingsError, match=r"cannot read settings file .*rig.toml: .*utf-8"):
        update_settings_file(path, {"load_cell.counts_per_n": 41873.2})
    assert path.read_bytes() == data


def test_the_files_mode_is_kept_when_it_is_rewritten(settings_file):
    # the new version is a new file (mkstemp makes it 0600): a shared 0664 rig file stays 0664
    settings_file.chmod(0o664)
    update_settings_file(settings_file, {"load_cell.counts_per_n": 41873.2})
    assert stat.S_IMODE(settings_file.stat().st_mode) == 0o664
    assert load_settings(settings_file).load_cell.counts_per_n == 41873.2


def test_a_read_only_file_is_refused_and_left_untouched(settings_file):
    # It was rewritten (os.replace does not ask the file's mode); refused by its mode bits, so for root too.
    settings_file.chmod(0o444)
    before = settings_file.read_bytes()
    with pytest.raises(SettingsError, match=r"rig.toml is read-only \(mode 444\).*; values not written: "
                                            r"load_cell.tare_counts = 5$"):
        update_settings_file(settings_file, {"load_cell.tare_counts": 5})
    assert settings_file.read_bytes() == before and stat.S_IMODE(settings_file.stat().st_mode) == 0o444
    assert [p.name for p in settings_file.parent.iterdir()] == ["rig.toml"]


def test_a_temporary_file_that_cannot_be_made_is_a_settings_error_with_the_values(settings_file, monkeypatch):
    # A folder the user cannot write: mkstemp's PermissionError escaped as a traceback (root is let in, so faked).
    def refuse(**_kwargs):
        raise PermissionError(13, "Permission denied", str(settings_file.parent / ".rig.toml.x.tmp"))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    before = settings_file.read_bytes()
    with pytest.raises(SettingsError, match=r"cannot write settings file .*rig.toml: Permission denied; "
                                            r"values not written: load_cell.counts_per_n = 41873.2$"):
        update_settings_file(settings_file, {"load_cell.counts_per_n": 41873.2})
    assert settings_file.read_bytes() == before


def test_a_failed_replace_leaves_no_temporary_file_behind(settings_file, monkeypatch):
    def refuse(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", refuse)
    before = settings_file.read_bytes()
    with pytest.raises(SettingsError, match="No space left on device; values not written"):
        update_settings_file(settings_file, {"load_cell.counts_per_n": 41873.2})
    assert settings_file.read_bytes() == before
    assert [p.name for p in settings_file.parent.iterdir()] == ["rig.toml"]  # no .rig.toml.*.tmp


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into any folder: nothing to refuse")
def test_a_folder_that_cannot_be_written_is_refused(settings_file):
    settings_file.parent.chmod(0o555)
    before = settings_file.read_bytes()
    try:
        with pytest.raises(SettingsError, match="rig.toml: permission denied to its folder"):
            update_settings_file(settings_file, {"load_cell.tare_counts": 5})
    finally:
        settings_file.parent.chmod(0o755)
    assert settings_file.read_bytes() == before


def test_a_folder_the_user_may_not_write_is_refused_with_the_values(settings_file, monkeypatch):
    # as above, for root too: the folder's permission as os.access answers it for a user without it
    import teleop.settings_edit as settings_edit

    folder = settings_file.resolve().parent
    access = os.access

    def refused_for_the_folder(path, mode, *args, **kwargs):
        return os.fspath(path) != os.fspath(folder) and access(path, mode, *args, **kwargs)

    monkeypatch.setattr(settings_edit.os, "access", refused_for_the_folder)
    before = settings_file.read_bytes()
    with pytest.raises(SettingsError, match=r"permission denied to its folder .*; values not written: "
                                            r"load_cell.counts_per_n = 41873.2$"):
        update_settings_file(settings_file, {"load_cell.counts_per_n": 41873.2})
    assert settings_file.read_bytes() == before


def test_a_linked_file_is_checked_against_the_folder_loading_resolves_it_from(tmp_path, monkeypatch):
    """Relative paths in a file reached through a link resolve against its target's folder on loading:
    the edit checks its result against that folder too, not the link's."""
    import teleop.settings_edit as settings_edit

    target, here = tmp_path / "rigs" / "settings.toml", tmp_path / "session" / "settings.toml"
    target.parent.mkdir()
    here.parent.mkdir()
    shutil.copy(default_settings_path(), target)
    here.symlink_to(target)
    checked = []
    build = settings_edit.settings_from_mapping

    def spy(data, *, source=None):
        settings = build(data, source=source)
        checked.append(settings)
        return settings

    monkeypatch.setattr(settings_edit, "settings_from_mapping", spy)
    update_settings_file(here, {"load_cell.tare_counts": 9})
    loaded = load_settings(here)
    assert [s.folder for s in checked] == [loaded.folder] == [target.parent]
    assert checked[0].sensor("left").calibration == loaded.sensor("left").calibration


def test_a_refused_edit_names_the_file_and_the_keys_changed(settings_file):
    with pytest.raises(SettingsError) as info:
        update_settings_file(settings_file, {"load_cell.counts_per_n": -5.0})
    assert str(settings_file) in str(info.value) and "load_cell.counts_per_n changed" in str(info.value)
