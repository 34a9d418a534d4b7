"""A recorded live session replays to the same estimates (issue 6).

The live system (robot node, estimator service, renderer, recorder as separate processes) runs the
quick scene (``teleop demo --operator script``) and records ``session.mcap``. The robot's recorded
messages are then fed, in recorded order, into a fresh in-process :class:`~estimator.service.EstimatorService` set up as ``estimator
serve`` sets itself up in the demo (same settings, calibration, methods and shipped default model);
each grasp's final estimate must equal the one the live service published and the log recorded.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from estimator.analytical import METHODS
from estimator.measurements import resolve_calibration
from estimator.model_slot import ModelSlot
from estimator.service import INPUT_TOPICS, EstimatorService, resolve_model_dir
from estimator.settings import estimator_settings
from estimator.stream import DEFAULT_METHODS
from teleop.bus.wire import Message, make_message
from teleop.session import replay_messages
from teleop.settings import default_settings_path, load_settings
from teleop.system.demo import scene_plan


class CollectingPublisher:
    """Keeps what the service sends, built and checked as a real publisher would build it."""

    def __init__(self) -> None:
        self.sent: list[Message] = []

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> Message:
        message = make_message(kind, t_capture_s=t_capture_s, topic=topic, **body)
        self.sent.append(message)
        return message


def finals(messages) -> dict[str, dict[str, Any]]:
    """The final estimate of each grasp: {grasp_id: body}."""
    found: dict[str, dict[str, Any]] = {}
    for m in messages:
        if m.type == "estimate" and not m.body["provisional"]:
            assert m.body["grasp_id"] not in found, f"two final estimates for {m.body['grasp_id']}"
            found[m.body["grasp_id"]] = dict(m.body)
    return found


def same_value(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return a == b or (math.isnan(a) and math.isnan(b))


@pytest.mark.slow
def test_the_recorded_session_replays_to_the_same_final_estimates(quick_demo_script):
    assert quick_demo_script.code == 0, quick_demo_script.err
    session = Path(quick_demo_script.result["session_log"])
    assert session.is_file()
    plan = scene_plan("quick")
    recorded = finals(replay_messages(session, topics=("estimate",)))
    assert len(recorded) == len(quick_demo_script.result["grasps"]) == len(plan)

    # The estimator as `estimator serve` builds it in the demo (see estimator.service.run), with the
    # calibration the settings name (the demo's, as they name one).
    settings = load_settings(default_settings_path())
    methods = tuple([m for m in estimator_settings(settings).methods if m in METHODS] or DEFAULT_METHODS)
    calibration = resolve_calibration(settings.sensor(settings.sensing.finger), None)
    model_dir = resolve_model_dir(None, settings)
    assert model_dir is not None, "the demo serves the shipped default model; it is missing"
    model = ModelSlot(model_dir, settings=settings, calibration=calibration, mode="auto")
    publisher = CollectingPublisher()
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=publisher,
                               methods=methods, model=model)
    # Only the robot's messages: the log also holds the estimator's own forwarded grasp ends.
    for message in replay_messages(session, topics=INPUT_TOPICS):
        if message.source == "robot":
            service.handle(message, received_s=0.0)
    assert service.stats.bad_messages == 0 and service.stats.grasps == len(plan)

    replayed = finals(publisher.sent)
    assert set(replayed) == set(recorded)
    for grasp_id, was in recorded.items():
        now = replayed[grasp_id]
        # Same inputs in the same order through the same deterministic code (no clock is read on
        # the estimate's path; latency_s is the only timing field): the replay must be exact.
        assert (now["state"], now["method"], now["reason"]) == (was["state"], was["method"], was["reason"]), grasp_id
        assert now["model"] == was["model"] == model.model_id, grasp_id  # the log names the model that answered
        assert same_value(now["E_pa"], was["E_pa"]), (grasp_id, now["E_pa"], was["E_pa"])
        assert all((a is None and b is None) or (a is not None and b is not None and same_value(float(a), float(b)))
                   for a, b in zip(now["interval_pa"], was["interval_pa"], strict=True)), grasp_id  # None: open
