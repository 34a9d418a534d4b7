"""The model slot on fake models: what it refuses and keeps, in which order it serves requests, when it
looks at the served files, and what its events carry. The loader runs in the caller's thread here, so
each poll's effect is known without waiting."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from estimator import model_slot
from estimator.errors import ModelError
from estimator.inference import infer, reference
from estimator.model_slot import ModelEvent, ModelSlot
from teleop.bus.wire import MAX_STR_CHARS


def fake_id(folder: Path) -> str:
    """A model id over the fake model's files (ModelError when one is missing)."""
    folder = Path(folder)
    try:
        data = (folder / "metadata.json").read_bytes() + (folder / "model.onnx").read_bytes()
    except OSError as exc:
        raise ModelError(f"{folder}: no model ({exc})") from exc
    return f"{folder.name}-{hashlib.sha256(data).hexdigest()[:8]}"


class FakePredictor:
    """Loads a fake model: its metadata says how it fails ("refuse": a ModelError, "crash": another error,
    "nan": its inference)."""

    def __init__(self, folder: Path):
        self.model_dir = Path(folder)
        self.model_id = fake_id(self.model_dir)
        self.kind = (self.model_dir / "metadata.json").read_text()
        if self.kind == "refuse":
            raise ModelError(f"{folder}: metadata refused")
        if self.kind == "crash":
            raise RuntimeError("the loader broke")
        self.variant = SimpleNamespace(name="depth", input_shapes={"frames": (3, 1, 4, 5)})
        self.batches: list = []

    def predict_logits(self, batch):
        self.batches.append(batch)
        if self.kind == "nan":
            raise ModelError("logits not finite")
        return np.zeros((1, 4), np.float32)


class SyncThread:
    def __init__(self, target, args=(), **_):
        self.target, self.args = target, args

    def start(self):
        self.target(*self.args)


@pytest.fixture
def fakes(monkeypatch):
    monkeypatch.setattr(infer, "CompliancePredictor", FakePredictor)
    monkeypatch.setattr(infer, "model_id", fake_id)
    monkeypatch.setattr("estimator.inference.hybrid.HybridEstimator",
                        lambda predictor, settings, calibration: SimpleNamespace(predictor=predictor))
    monkeypatch.setattr(model_slot, "threading", SimpleNamespace(Thread=SyncThread, Event=threading.Event))


def fake_model(folder: Path, kind: str = "good", weights: bytes = b"w1") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "metadata.json").write_text(kind)
    (folder / "model.onnx").write_bytes(weights)
    return folder


def slot_on(folder: Path | None, now: list[float], **options) -> ModelSlot:
    options = {"check_reference": False, **options}
    return ModelSlot(folder, settings=None, calibration=None, check_interval_s=1.0, clock=lambda: now[0], **options)


def looks(slot: ModelSlot, now: list[float], times: list[float]) -> list[ModelEvent]:
    """Poll once at each time of ``times`` (the slot's own loading settled at each), then twice more:
    what the slot said."""
    events = []
    for t in times:
        now[0] = t
        events += [slot.poll(idle=True), slot.poll(idle=True)]
    return [e for e in events if e is not None]


def test_a_model_that_breaks_the_loader_in_another_way_is_refused_and_the_served_one_stays(fakes, tmp_path):
    slot = slot_on(fake_model(tmp_path / "a"), [0.0])
    served, served_id = slot.estimator, slot.model_id
    slot.request_load(fake_model(tmp_path / "b", "crash"), "r1")
    assert slot.poll(idle=False) is None and slot.busy and not slot.switch_pending  # checked: nothing to switch to
    event = slot.poll(idle=False)  # a refusal waits for no grasp's end
    assert (event.event, event.request, event.model) == ("refused", "r1", served_id)
    assert "loading failed (RuntimeError: the loader broke)" in event.reason
    assert slot.estimator is served and slot.estimator is not None and slot.failures == 1


def test_a_model_that_fails_at_start_is_an_error_not_a_slot_serving_nothing(fakes, tmp_path):
    with pytest.raises(ModelError, match="metadata refused"):
        slot_on(fake_model(tmp_path / "a", "refuse"), [0.0])
    with pytest.raises(ModelError, match="loading failed"):
        slot_on(fake_model(tmp_path / "b", "crash"), [0.0])


def test_an_unknown_mode_is_refused(fakes, tmp_path):
    with pytest.raises(ModelError, match="model mode 'best'"):
        slot_on(fake_model(tmp_path / "a"), [0.0], mode="best")


def test_requests_are_served_in_the_order_they_came(fakes, tmp_path):
    slot = slot_on(fake_model(tmp_path / "a"), [0.0])
    slot.request_load(fake_model(tmp_path / "b", weights=b"w2"), "first")
    slot.request_load(fake_model(tmp_path / "c", weights=b"w3"), "second")
    events = looks(slot, [0.0], [0.0, 0.0])
    assert [(e.request, Path(e.path).name) for e in events] == [("first", "b"), ("second", "c")]
    assert Path(slot.model_dir).name == "c" and slot.loads == 3


def test_a_reload_asked_for_is_busy_until_done_and_a_slot_with_nothing_loading_waits_for_nothing(fakes, tmp_path):
    slot = slot_on(fake_model(tmp_path / "a"), [0.0])
    assert not slot.busy and slot.wait(0.0)
    slot.request_reload()
    assert slot.busy
    (event,) = looks(slot, [0.0], [0.0])
    assert event.event == "loaded" and "reloaded (the same files)" in event.reason and not slot.busy


def test_a_load_of_the_served_folder_answers_a_reload_asked_for_before_it(fakes, tmp_path):
    folder = fake_model(tmp_path / "a")
    slot = slot_on(folder, [0.0])
    slot.request_load(folder, "r1")
    slot.request_reload()
    slot.poll(idle=True)  # the request starts first and reads the files after the reload was asked for
    assert slot.poll(idle=True).request == "r1"
    assert not slot.busy and slot.poll(idle=True) is None and slot.loads == 2


def test_the_served_files_touched_without_a_change_are_not_loaded_again(fakes, tmp_path):
    now = [0.0]
    folder = fake_model(tmp_path / "a")
    slot = slot_on(folder, now)
    os.utime(folder / "metadata.json", (1_000_000_000, 1_000_000_000))
    assert looks(slot, now, [1.0, 2.0, 3.0, 4.0]) == [] and slot.loads == 1 and not slot.busy


def test_the_served_files_are_not_looked_at_before_a_check_interval_has_passed(fakes, tmp_path):
    now = [0.0]
    folder = fake_model(tmp_path / "a")
    slot = slot_on(folder, now)
    fake_model(folder, weights=b"w2")
    assert looks(slot, now, [0.5, 0.9]) == [] and slot.loads == 1
    now[0] = 1.6
    slot.poll(idle=True)  # the first look sees them changed: wait for them to stay the same
    assert not slot.busy and slot.loads == 1
    assert [e.event for e in looks(slot, now, [2.6])] == ["loaded"] and slot.loads == 2


def test_files_refused_once_are_tried_again_after_the_slot_switched_to_others(fakes, tmp_path):
    now = [0.0]
    folder = fake_model(tmp_path / "a")
    slot = slot_on(folder, now)
    fake_model(folder, "refuse", b"bad")
    assert [e.event for e in looks(slot, now, [1.0, 2.0, 3.0])] == ["refused"]
    fake_model(folder, weights=b"w2")
    assert [e.event for e in looks(slot, now, [4.0, 5.0])] == ["loaded"]
    fake_model(folder, "refuse", b"bad")  # the refused files again, now over another model
    assert [e.event for e in looks(slot, now, [6.0, 7.0])] == ["refused"] and slot.failures == 2


def test_a_model_whose_reference_inference_fails_is_refused_naming_the_model_not_onnxruntime(fakes, tmp_path,
                                                                                              monkeypatch):
    monkeypatch.setattr(reference, "reference_inputs", lambda variant, settings: {"frames": np.ones((1, 3))})
    slot = slot_on(fake_model(tmp_path / "a"), [0.0], check_reference=True)
    slot.request_load(fake_model(tmp_path / "b", "nan"), "r1")
    (event,) = looks(slot, [0.0], [0.0])
    assert event.event == "refused" and "fails on the reference grasp" in event.reason
    assert "logits not finite" in event.reason and "onnxruntime" not in event.reason


@pytest.mark.parametrize("error", [ValueError("no sample"), OSError("unreadable reference")])
def test_a_reference_that_these_settings_cannot_measure_checks_the_model_on_zero_inputs(fakes, tmp_path, monkeypatch,
                                                                                      error):
    def unmeasurable(variant, settings):
        raise error

    monkeypatch.setattr(reference, "reference_inputs", unmeasurable)
    slot = slot_on(fake_model(tmp_path / "a"), [0.0], check_reference=True)
    (batch,) = slot.estimator.predictor.batches
    assert batch["frames"].shape == (1, 3, 1, 4, 5) and not batch["frames"].any()


def test_an_event_carries_a_reason_and_path_cut_to_what_the_bus_carries(tmp_path):
    fits = "r" * MAX_STR_CHARS
    assert ModelEvent("refused", None, None, fits, fits).body()["reason"] == fits
    body = ModelEvent("refused", "r1", "m", "p" * (MAX_STR_CHARS + 5), "r" * (MAX_STR_CHARS + 5)).body()
    for key, char in (("reason", "r"), ("path", "p")):
        assert len(body[key]) == MAX_STR_CHARS and body[key] == char * (MAX_STR_CHARS - 1) + "…"
    assert ModelEvent("loaded", None, "m", None, "ok").body()["path"] is None
