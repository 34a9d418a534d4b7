"""Switching the estimator service's model: model ids, the model slot, load_model on the bus and
``estimator reload``."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from support.live import Rig, expected_final, in_capture_order

from estimator.model_slot import ModelSlot
from estimator.settings import estimator_settings
from teleop.bus.pubsub import Publisher
from teleop.errors import BusError
from teleop.settings import load_settings


def write_tiny_model(model_dir: Path, log10_e: float, *, data: dict | None = None, note: str = "",
                     broken: bool = False) -> float:
    """A model that ignores its input and puts all its mass in the bin of ``log10_e``; returns the
    median it answers (the bin's centre, Pa). ``data`` goes into the metadata's ``data`` (e.g. another
    ``depth_binning``), ``note`` into its ``training`` (metadata that differs, for a model's id);
    ``broken``: it answers NaN (it loads, and fails its first inference)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from estimator.inference.distribution import BIN_DECADES, EDGES_LOG10, N_BINS, bin_index
    from estimator.inference.infer import MODEL_FORMAT, MODEL_VERSION, OUTPUT_NAME, current_scales

    shape = [3, 1, 16, 22]
    index = int(bin_index(log10_e))
    logits = np.full(N_BINS, -60.0, np.float32)
    logits[index] = 0.0
    if broken:
        logits[0] = np.nan
    nodes = [helper.make_node("ReduceMean", ["frames"], ["mean"], axes=[2, 3, 4], keepdims=0),
             helper.make_node("Mul", ["mean", "zero"], ["nothing"]),  # (batch, frames) of zeros
             helper.make_node("ReduceMean", ["nothing"], ["column"], axes=[1], keepdims=1),
             helper.make_node("Add", ["column", "logits"], [OUTPUT_NAME])]
    graph = helper.make_graph(
        nodes, "tiny", [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["batch", *shape])],
        [helper.make_tensor_value_info(OUTPUT_NAME, TensorProto.FLOAT, ["batch", N_BINS])],
        [helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
         helper.make_tensor("logits", TensorProto.FLOAT, [N_BINS], logits.tolist())])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    model_dir.mkdir(parents=True, exist_ok=True)
    onnx.save(model, model_dir / "model.onnx")
    (model_dir / "metadata.json").write_text(json.dumps({
        "format": MODEL_FORMAT, "version": MODEL_VERSION,
        "variant": {"name": "depth", "n_frames": 3, "size_px": [16, 22]},
        "inputs": {"frames": [None, *shape]}, "output": OUTPUT_NAME, "scales": current_scales(),
        "calibration": {"temperature": 1.0, "p_rigids": [0.5], "level": 0.9, "force_band_edges_n": [],
                        "interval_scales": [1.645], "soft_pa": 5e3},
        "data": {"depth_binning": estimator_settings(load_settings()).depth_binning, **(data or {})},
        "training": {"note": note},
    }))
    return float(10.0 ** (EDGES_LOG10[index] + BIN_DECADES / 2))


def test_model_id_names_the_folder_and_the_contents_of_its_files(tmp_path):
    from estimator.errors import ModelError
    from estimator.inference.infer import CompliancePredictor, model_id

    folder = tmp_path / "soft-v1"
    write_tiny_model(folder, 5.55)
    ident = model_id(folder)
    assert re.fullmatch(r"soft-v1-[0-9a-f]{8}", ident) and model_id(folder) == ident  # stable
    assert CompliancePredictor(folder).model_id == ident  # the id of the bytes it loaded
    copy = tmp_path / "elsewhere" / "soft-v1"
    shutil.copytree(folder, copy)
    assert model_id(copy) == ident  # a copy is the same model
    (folder / "notes.txt").write_text("not part of the model")
    assert model_id(folder) == ident
    (folder / "old.onnx").mkdir()  # not a file (nor would a named pipe be): not read, not hashed
    assert model_id(folder) == ident
    (folder / "old.onnx").rmdir()
    metadata = (folder / "metadata.json").read_text()
    (folder / "metadata.json").write_text(metadata.replace('"temperature": 1.0', '"temperature": 1.5'))
    assert model_id(folder) not in (ident, model_id(copy))  # the metadata changed
    (folder / "metadata.json").write_text(metadata)
    assert model_id(folder) == ident
    write_tiny_model(folder, 4.25)  # the same metadata, another network
    assert model_id(folder) != ident
    long = tmp_path / ("a-very-long-model-folder-name-" * 4)
    write_tiny_model(long, 5.55)
    assert len(model_id(long)) == 64 and model_id(long).startswith("a-very-long")
    (copy / "model.onnx").unlink()
    with pytest.raises(ModelError, match=r"soft-v1 is not a model folder: it has no model\.onnx"):
        model_id(copy)
    with pytest.raises(ModelError, match="does not exist"):
        model_id(tmp_path / "nowhere")


@pytest.mark.slow
def test_model_reload_swaps_between_grasps_without_dropping_one(settings, calibration, records, tmp_path):
    model_dir = tmp_path / "model"
    first_e = write_tiny_model(model_dir, 5.55)
    # Only the reload asked for below, not the files' change (check_interval_s): one reload.
    slot = ModelSlot(model_dir, settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    first_id = slot.model_id
    rig = Rig(settings, calibration, model=slot)
    try:
        record = records["stress_ball"]
        messages = in_capture_order(record)
        half = slice(0, len(messages) // 2)
        rig.send_grasp(record, "g-a", end=False, part=half)
        deadline = time.monotonic() + 20
        while not rig.service.stats.provisional and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rig.service.stats.provisional > 0  # grasp A is loading now
        second_e = write_tiny_model(model_dir, 4.25)  # the files change mid-grasp...
        slot.request_reload()  # ...and a reload is asked for
        rig.send_grasp(record, "g-a", start=False, part=slice(len(messages) // 2, None))
        got_a = rig.collect("g-a")
        rig.send_grasp(record, "g-b")
        got_b = rig.collect("g-b")
    finally:
        rig.close()
    final_a = [m.body for m in got_a if m.type == "estimate" and not m.body["provisional"]]
    final_b = [m.body for m in got_b if m.type == "estimate" and not m.body["provisional"]]
    _, provisional = expected_final(settings, calibration, record)
    assert sum(m.type == "estimate" and m.body["provisional"] for m in got_a) == provisional  # none dropped
    assert len(final_a) == len(final_b) == 1
    assert final_a[0]["method"] == "cnn" and final_a[0]["E_pa"] == pytest.approx(first_e, rel=1e-5)
    assert final_b[0]["E_pa"] == pytest.approx(second_e, rel=1e-5)
    assert final_a[0]["model"] == first_id and final_b[0]["model"] == slot.model_id != first_id
    assert slot.loads == 2 and rig.service.stats.reloads == 1


def settled(slot: ModelSlot, *, idle: bool = True):
    """Let the candidate the slot is loading be checked, then poll: what the slot did."""
    assert slot.wait(30.0)
    return slot.poll(idle=idle)


def test_model_slot_switches_to_new_files_once_they_stay_the_same_and_keeps_a_good_model_over_a_bad_one(
        settings, calibration, tmp_path, caplog):
    from estimator.inference.infer import model_id

    served, new = tmp_path / "served", tmp_path / "new"
    write_tiny_model(served, 5.55)
    write_tiny_model(new, 4.75, note="fine-tuned")  # another network and another metadata
    now = [0.0]
    slot = ModelSlot(served, settings=settings, calibration=calibration, check_interval_s=1.0,
                     clock=lambda: now[0])
    first, first_id = slot.estimator, slot.model_id
    assert first_id == model_id(served) and slot.loads == 1
    now[0] = 1.0
    assert slot.poll(idle=True) is None and not slot.busy  # nothing changed
    # The new model is copied over the served one, the metadata first: a mismatched pair for a while.
    shutil.copy(new / "metadata.json", served / "metadata.json")
    now[0] = 1.5
    assert slot.poll(idle=True) is None  # not looked at before check_interval_s
    now[0] = 2.0
    assert slot.poll(idle=True) is None and not slot.busy  # changed: wait for it to stay the same
    shutil.copy(new / "model.onnx", served / "model.onnx")
    now[0] = 3.0
    assert slot.poll(idle=True) is None and not slot.busy  # changed again: the half-copied pair was never loaded
    now[0] = 4.0
    with caplog.at_level(logging.INFO, logger="estimator.service.model"):
        assert slot.poll(idle=False) is None and slot.busy  # the same twice: loading while a grasp goes on
        assert slot.wait(30.0) and slot.switch_pending
        assert slot.poll(idle=False) is None and slot.estimator is first  # never swapped mid-grasp
        event = slot.poll(idle=True)
    assert event.event == "loaded" and event.request is None and event.model == model_id(served) == slot.model_id
    assert event.model.startswith("served-") and event.model[-8:] == model_id(new)[-8:]  # new's files, in served/
    assert event.path == str(served) and slot.estimator is not first and slot.loads == 2 and slot.failures == 0
    assert f"model {slot.model_id} ({served}) serves from the next grasp on, in place of {first_id}" in caplog.text
    good, good_id = slot.estimator, slot.model_id

    # Broken files that stay broken: tried once, refused, the good model stays.
    (served / "metadata.json").write_text("{ not json")
    for t in (5.0, 6.0):
        now[0] = t
        assert slot.poll(idle=True) is None
    with caplog.at_level(logging.WARNING, logger="estimator.service.model"):
        event = settled(slot)
    assert event.event == "refused" and event.model == good_id and "not a readable model metadata" in event.reason
    assert slot.estimator is good and slot.failures == 1
    assert f"model {served} refused, still serving {good_id}" in caplog.text
    for t in (7.0, 8.0, 9.0):
        now[0] = t
        assert slot.poll(idle=True) is None and not slot.busy  # not tried again until they change
    assert slot.failures == 1

    # Asked for by path: a folder that is not there, and a model that does not fit the settings.
    slot.request_load(tmp_path / "nowhere", "r1")
    assert slot.poll(idle=True) is None
    event = settled(slot)
    assert (event.event, event.request, event.model) == ("refused", "r1", good_id)
    assert "does not exist" in event.reason
    other_binning = tmp_path / "other-binning"
    write_tiny_model(other_binning, 4.25, data={"depth_binning": 7})
    slot.request_load(other_binning / "model.onnx", "r2")  # its model.onnx names the folder
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "refused" and event.path == str(other_binning) and "depth_binning" in event.reason
    assert slot.estimator is good and slot.failures == 3
    write_tiny_model(tmp_path / "broken", 4.25, broken=True)
    slot.request_load(tmp_path / "broken", "r-nan")
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "refused" and "fails on the reference grasp" in event.reason and "not finite" in event.reason
    slot.request_load(new, "r3")
    slot.poll(idle=True)
    event = settled(slot)
    assert (event.event, event.request, event.model, event.path) == ("loaded", "r3", model_id(new), str(new))
    assert slot.model_dir == new and slot.estimator is not good


def test_model_slot_does_not_try_again_refused_files_copied_over_unchanged(settings, calibration, tmp_path):
    # Files with a model id that fail their check: copied again (new mtimes, the same id), they are not
    # loaded and refused again at every look.
    served, broken = tmp_path / "served", tmp_path / "broken"
    write_tiny_model(served, 5.55)
    write_tiny_model(broken, 4.25, broken=True)
    now = [0.0]
    slot = ModelSlot(served, settings=settings, calibration=calibration, check_interval_s=1.0, clock=lambda: now[0])
    good = slot.estimator
    events = []
    for t in range(1, 12):
        if t in (1, 6):  # copied in, then copied over again
            for name in ("metadata.json", "model.onnx"):
                (served / name).unlink()
                shutil.copy(broken / name, served / name)
        now[0] = float(t)
        event = slot.poll(idle=True)
        if slot.busy:  # loading them: let their check finish
            event = settled(slot)
        if event is not None:
            events.append(event.event)
    assert events == ["refused"] and slot.failures == 1 and slot.estimator is good


def shipped_copy_slot(settings, tmp_path: Path, now: list[float]) -> tuple[ModelSlot, Path]:
    """A slot serving a copy of the shipped model (onnxruntime only: no onnx needed to write one), on the
    clock ``now``; no reference check, so no calibration."""
    from estimator.inference.infer import default_model_dir

    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    slot = ModelSlot(folder, settings=settings, calibration=None, check_reference=False, clock=lambda: now[0])
    return slot, folder


def watch(slot: ModelSlot, now: list[float], looks: int) -> list:
    """What ``looks`` looks at the folder, each a check interval apart, did (a load let finish each time)."""
    events = []
    for _ in range(looks):
        now[0] += 2.0
        events.append(slot.poll(idle=True))
        slot.wait(30.0)
        events.append(slot.poll(idle=True))
    return [e for e in events if e is not None]


def test_model_slot_does_not_try_again_a_damaged_model_it_refused_when_only_its_time_changes(settings, tmp_path):
    now = [0.0]
    slot, folder = shipped_copy_slot(settings, tmp_path, now)
    served = slot.model_id
    meta = json.loads((folder / "metadata.json").read_text())
    (folder / "metadata.json").write_text(json.dumps({**meta, "version": 1}))
    assert [e.event for e in watch(slot, now, 3)] == ["refused"]
    assert slot.failures == 1 and slot.model_id == served
    stamp = 1_000_000_000
    os.utime(folder / "metadata.json", (stamp, stamp))  # the same bytes, a new time
    assert watch(slot, now, 4) == [] and slot.failures == 1 and slot.model_id == served


def test_model_slot_does_not_switch_to_files_that_changed_again_while_loading(settings, tmp_path, monkeypatch):
    from estimator.inference import infer

    now = [0.0]
    slot, folder = shipped_copy_slot(settings, tmp_path, now)
    served, loads = slot.model_id, slot.loads
    monkeypatch.setattr(infer, "model_id", lambda _folder: "model-0badc0de")  # what the watch saw, not what loads
    stamp = 1_000_000_000
    os.utime(folder / "metadata.json", (stamp, stamp))
    assert watch(slot, now, 3) == [] and slot.loads == loads and slot.model_id == served


def test_model_slot_without_a_model_serves_the_first_one_it_is_given(settings, calibration, tmp_path):
    write_tiny_model(tmp_path / "m", 5.55)
    slot = ModelSlot(None, settings=settings, calibration=calibration)
    assert slot.estimator is None and slot.model_id is None
    slot.request_reload()  # nothing to reload: said, nothing done
    assert slot.poll(idle=True) is None and not slot.busy
    slot.request_load(tmp_path / "m", "r1")
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "loaded" and slot.model_id == event.model and "was no model" in event.reason


def test_service_switches_models_on_load_model_between_grasps_and_every_estimate_names_its_model(
        settings, calibration, records, tmp_path):
    from estimator.inference.infer import model_id

    first_e, second_e = write_tiny_model(tmp_path / "a", 5.55), write_tiny_model(tmp_path / "b", 4.25)
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    rig = Rig(settings, calibration, model=slot, commands=operator.endpoint, report=tmp_path / "estimator.jsonl")
    try:
        operator.wait_for_subscriber("load_model", timeout_s=5.0)
        record = records["steel_ball_bearing"]
        half = len(in_capture_order(record)) // 2
        rig.send_grasp(record, "g-a", end=False, part=slice(0, half))
        operator.send("load_model", t_capture_s=0.0, path=str(tmp_path / "b"), request="r1")
        deadline = time.monotonic() + 30
        while not slot.switch_pending and time.monotonic() < deadline:
            time.sleep(0.02)
        assert slot.switch_pending and slot.model_id == model_id(tmp_path / "a")  # checked; g-a still open
        rig.send_grasp(record, "g-a", start=False, part=slice(half, None))
        got_a = rig.collect("g-a")
        assert not rig.model_events  # nothing said before g-a's end went out
        loaded = rig.model_event("r1")
        rig.send_grasp(record, "g-b")
        got_b = rig.collect("g-b")
    finally:
        rig.close()
        operator.close()
    ids = model_id(tmp_path / "a"), model_id(tmp_path / "b")
    assert loaded.body == {"event": "loaded", "request": "r1", "model": ids[1], "path": str(tmp_path / "b"),
                           "reason": f"switched; was {ids[0]}"}
    for got, ident, e_pa in ((got_a, ids[0], first_e), (got_b, ids[1], second_e)):
        estimates = [m.body for m in got if m.type == "estimate"]
        final = estimates[-1]
        assert not final["provisional"] and final["method"] == "cnn" and final["E_pa"] == pytest.approx(e_pa, rel=1e-5)
        assert final["model"] == ident
        assert all(e["model"] is None for e in estimates[:-1])  # provisional: analytical, no model made them
    reports = [json.loads(line) for line in (tmp_path / "estimator.jsonl").read_text().splitlines()]
    assert [(r["grasp_id"], r["model"], r["model_path"]) for r in reports] == [
        ("g-a", ids[0], str(tmp_path / "a")), ("g-b", ids[1], str(tmp_path / "b"))]
    assert rig.service.stats.reloads == 1 and rig.service.stats.load_requests == 1


def test_a_follow_grasp_served_by_a_model_has_its_estimates_provisional_until_its_one_final(settings, calibration,
                                                                                            records, tmp_path):
    # The display follows the model's answer while the operator loads; only the end makes it final.
    write_tiny_model(tmp_path / "a", 5.55)
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    rig = Rig(settings, calibration, model=slot)
    try:
        rig.robot.send("robot_state", t_capture_s=0.0, mode="following", grasp_id="g-f", target_width_m=0.08,
                       enable=True)
        rig.send_grasp(records["stress_ball"], "g-f")
        estimates = [m.body for m in rig.collect("g-f") if m.type == "estimate"]
    finally:
        rig.close()
    assert len(estimates) >= 2 and [e["provisional"] for e in estimates] == [True] * (len(estimates) - 1) + [False]
    assert any(e["model"] == slot.model_id for e in estimates[:-1])  # the model made the provisional ones


def test_service_refuses_a_model_that_does_not_check_out_and_keeps_its_own(settings, calibration, records,
                                                                           tmp_path, caplog):
    write_tiny_model(tmp_path / "a", 5.55)
    (tmp_path / "empty").mkdir()
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    rig = Rig(settings, calibration, model=slot, commands=operator.endpoint)
    try:
        operator.wait_for_subscriber("load_model", timeout_s=5.0)
        with caplog.at_level(logging.WARNING, logger="estimator.service.model"):
            answers = {}
            for request, path in (("r-missing", tmp_path / "nowhere"), ("r-empty", tmp_path / "empty")):
                operator.send("load_model", t_capture_s=0.0, path=str(path), request=request)
                answers[request] = rig.model_event(request).body
            operator.send("load_model", t_capture_s=0.0, path=str(tmp_path / "nowhere"), request="r-missing")
            again = rig.model_event("r-missing").body  # a repeat is answered again, not loaded again
        rig.send_grasp(records["steel_ball_bearing"], "g-c")
        got = rig.collect("g-c")
    finally:
        rig.close()
        operator.close()
    assert {a["event"] for a in answers.values()} == {"refused"}
    assert {a["model"] for a in answers.values()} == {slot.model_id}
    assert "does not exist" in answers["r-missing"]["reason"] and again == answers["r-missing"]
    assert "no model.onnx and no metadata.json" in answers["r-empty"]["reason"]
    assert "refused, still serving" in caplog.text and "does not exist" in caplog.text
    final = [m.body for m in got if m.type == "estimate" and not m.body["provisional"]]
    assert final[-1]["model"] == slot.model_id and slot.model_dir == tmp_path / "a"
    stats = rig.service.stats
    assert (stats.load_requests, stats.model_refusals, stats.reloads) == (2, 2, 0)


@pytest.mark.slow
def test_estimator_reload_switches_a_running_service_and_says_why_it_refuses(settings, calibration, records,
                                                                              tmp_path, capsys):
    import estimator.cli
    from estimator.inference.infer import model_id
    from teleop.system.live_system import free_ports

    write_tiny_model(tmp_path / "a", 5.55)
    second_e = write_tiny_model(tmp_path / "b", 4.25)
    command, nobody = (f"tcp://127.0.0.1:{port}" for port in free_ports(2))
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    rig = Rig(settings, calibration, model=slot, commands=command)

    def reload(model: Path, *options: str) -> tuple[int, str, str]:
        code = estimator.cli.main(["reload", "--model", str(model), "--control", command, "--estimate-pub",
                                   rig.service.publisher.endpoint, *options])
        out, err = capsys.readouterr()
        return code, out, err

    try:
        code, out, err = reload(tmp_path / "b", "--json")
        assert code == 0, err
        answer = json.loads(out.splitlines()[-1])
        assert answer["event"] == "loaded" and answer["model"] == model_id(tmp_path / "b") == slot.model_id
        assert f"serves {answer['model']}" in err
        code, out, err = reload(tmp_path / "nowhere", "--timeout-s", "20")
        assert code == 1 and "does not exist" in err and f"keeps {slot.model_id}" in err and out == ""
        rig.send_grasp(records["steel_ball_bearing"], "g-after")
        final = [m.body for m in rig.collect("g-after") if m.type == "estimate"][-1]
    finally:
        rig.close()
    assert final["model"] == slot.model_id and final["E_pa"] == pytest.approx(second_e, rel=1e-5)
    # No service there: it says so, without a traceback.
    code = estimator.cli.main(["reload", "--model", str(tmp_path / "b"), "--control", command, "--estimate-pub",
                               nobody, "--timeout-s", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "no answer to load_model" in err and nobody in err and "Traceback" not in err
    deadline = time.monotonic() + 5.0
    while True:  # the last reload's socket lets go of the port a moment after it closed
        try:
            console = Publisher(command, lossless=True, source="operator")
            break
        except BusError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    with console:  # another reload holds the control endpoint
        code = estimator.cli.main(["reload", "--model", str(tmp_path / "b"), "--control", command, "--estimate-pub",
                                   nobody, "--timeout-s", "1"])
    err = capsys.readouterr().err
    assert code == 2 and f"cannot send on the control endpoint {command}" in err and "another" in err


def test_estimator_serve_names_the_missing_file_of_a_folder_that_is_not_a_model(tmp_path, capsys):
    import estimator.cli

    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "model.onnx").write_bytes(b"")
    code = estimator.cli.main(["serve", "--model", str(tmp_path / "half"), "--duration-s", "0.1"])
    err = capsys.readouterr().err
    assert code == 2 and f"{tmp_path / 'half'} is not a model folder: it has no metadata.json" in err
    assert "Traceback" not in err
