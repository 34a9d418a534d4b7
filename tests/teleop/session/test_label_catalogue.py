"""Labels from a catalogue other than the log's keep that catalogue's material and shape on export."""

from __future__ import annotations

import shutil
import time

import teleop.cli
from teleop.session import LogReader, session_grasps
from teleop.session.label import label_catalogues, label_session

LAB = '[[objects]]\nname = "lab_gel"\nshape = "box"\nmaterial = "rubber"\nmodulus_pa = 7.5e4\n'
SHOP = '[[objects]]\nname = "shop_cork"\nshape = "cylinder"\nmaterial = "wood"\nmodulus_pa = 1.2e7\n'


def _labels_of(log):
    return {g.grasp_id: g.record.label for g in session_grasps(log) if g.record is not None}


def test_an_object_only_in_the_label_catalogue_exports_with_its_material_and_shape(recorded, tmp_path):
    log = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, log)
    (tmp_path / "lab.toml").write_text(LAB, encoding="utf-8")
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng1,lab_gel\n", encoding="utf-8")

    assert teleop.cli.main(["label", str(log), "--csv", str(tmp_path / "labels.csv"),
                            "--catalogue", str(tmp_path / "lab.toml")]) == 0

    label = _labels_of(log)["g1"]
    assert (label.object_name, label.modulus_pa, label.material, label.shape, label.source) == (
        "lab_gel", 7.5e4, "rubber", "box", "catalogue")


def test_each_label_catalogue_is_attached_once_and_every_one_is_used(recorded, tmp_path):
    log = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, log)
    before = LogReader(log).info().attachments
    for name, text in (("lab.toml", LAB), ("shop.toml", SHOP), ("g0.csv", "grasp_id,object\ng0,lab_gel\n"),
                       ("g1.csv", "grasp_id,object\ng1,shop_cork\n"), ("ball.csv", "grasp_id,object\ng0,stress_ball\n")):
        (tmp_path / name).write_text(text, encoding="utf-8")

    label_session(log, tmp_path / "g0.csv", catalogue=tmp_path / "lab.toml")
    label_session(log, tmp_path / "g1.csv", catalogue=tmp_path / "shop.toml")
    label_session(log, tmp_path / "g0.csv", catalogue=tmp_path / "lab.toml")  # attached already
    label_session(log, tmp_path / "ball.csv")  # the log's own catalogue: nothing to attach

    added = {k: v for k, v in LogReader(log).info().attachments.items() if k not in before}
    assert added == {"label_catalogue-1.toml": LAB.encode(), "label_catalogue-2.toml": SHOP.encode()}
    labels = _labels_of(log)
    assert (labels["g0"].material, labels["g0"].shape) == ("foam", "sphere")  # relabelled: stress_ball, the log's
    assert (labels["g1"].material, labels["g1"].shape) == ("wood", "cylinder")


def test_a_catalogue_recorded_before_the_simulators_checks_still_reads_for_export_and_label(tmp_path):
    """A log's catalogue was accepted when it was recorded: export and label take its names, materials
    and shapes, though it names a material the simulator has no model for, or holds another key."""
    from types import SimpleNamespace

    from teleop.session.export_objects import catalogue_objects
    from teleop.session.label import _catalogue_objects

    old = (b'title = "lab objects"\n[[objects]]\nname = "gel_pad"\nshape = "sphere"\nmaterial = "Silicone "\n'
           b'modulus_pa = 2e4\nsize_m = [0.02, 0.03, 0.02]\n')
    info = SimpleNamespace(attachments={"catalogue.toml": old}, damaged_attachments={})
    (gel,) = catalogue_objects(info, None, log=tmp_path / "session.mcap").values()
    assert (gel.name, gel.material, gel.shape, gel.modulus_pa) == ("gel_pad", "silicone", "sphere", 2e4)
    objects, where, attach = _catalogue_objects(None, {"catalogue.toml": old})
    assert [o.name for o in objects] == ["gel_pad"] and attach is None


def test_an_attached_label_catalogue_is_stamped_with_the_log_s_own_time_base(recorded, tmp_path):
    from mcap.reader import make_reader

    log = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, log)
    (tmp_path / "lab.toml").write_text(LAB, encoding="utf-8")
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng1,lab_gel\n", encoding="utf-8")
    before_ns = time.time_ns()
    label_session(log, tmp_path / "labels.csv", catalogue=tmp_path / "lab.toml")
    with open(log, "rb") as f:
        reader = make_reader(f)
        attached = [a for a in reader.iter_attachments() if a.name == "label_catalogue-1.toml"]
        last_message_ns = max(m.log_time for _, _, m in reader.iter_messages())
    assert len(attached) == 1
    # the time it was attached, in the log's time base: after the recording, not decades ahead
    assert last_message_ns <= attached[0].log_time and before_ns <= attached[0].log_time <= time.time_ns()


def test_a_label_without_a_modulus_takes_the_logs_catalogue_object_before_a_label_catalogues(tmp_path):
    """Both catalogues name the object: the log's (or --objects) has it first, as the grasps were run with it."""
    from pathlib import Path
    from types import SimpleNamespace

    from teleop.bus.messages import LabelBody
    from teleop.session.export import _Assembler
    from teleop.session.export_notes import LogNotes
    from teleop.session.export_objects import catalogue_objects, label_catalogue_objects

    own = LAB.replace('"box"', '"sphere"').replace('"rubber"', '"silicone"').replace("7.5e4", "2e4")
    objects = catalogue_objects(SimpleNamespace(attachments={"catalogue.toml": own.encode()}, damaged_attachments={}),
                                None, log=tmp_path / "session.mcap")
    label_objects = label_catalogue_objects(
        SimpleNamespace(attachments={"label_catalogue-1.toml": LAB.encode()}, damaged_attachments={}),
        log=tmp_path / "session.mcap")
    labels = {"g1": LabelBody(grasp_id="g1", object_name="lab_gel", modulus_pa=None, source="catalogue", detail="")}
    assembler = _Assembler(path=Path("session.mcap"), settings=None, objects=objects, source="simulated",
                           session_version="0", session="s", notes=LogNotes(labels=labels), calibration_files={},
                           label_objects=label_objects)
    label, unlabelled = assembler.label("g1", None)
    assert unlabelled == ""
    assert (label.modulus_pa, label.material, label.shape) == (2e4, "silicone", "sphere")


def test_the_catalogues_labelling_attached_are_listed_oldest_first_past_nine():
    names = {f"label_catalogue-{n}.toml": b"" for n in (10, 2, 1, 11)}
    assert label_catalogues(names) == [f"label_catalogue-{n}.toml" for n in (1, 2, 10, 11)]
