"""Bus messages in the forms Foxglove decodes (:mod:`teleop.session.foxglove`): the topics, times and
JSON Schemas the session log and the live view share. That a log's Foxglove channels decode is in
test_foxglove_log.py, what the live view advertises in test_foxglove_live.py."""

from __future__ import annotations

import json

import jsonschema
import pytest

from teleop.bus.wire import SCHEMAS, make_message
from teleop.errors import MessageRejected
from teleop.session.foxglove import (
    EVENTS_TOPIC,
    MAX_SAMPLE_MESSAGES,
    foxglove_messages,
    json_schema,
    known_channels,
)

OFFSET_NS = 1_700_000_000 * 10**9  # a log's: monotonic seconds to ns since the Unix epoch


def _stamp_ns(item) -> int:
    stamp = json.loads(item.data)["timestamp"]
    return stamp["sec"] * 10**9 + stamp["nsec"]


def _force(t_s: list[float], **options):
    return make_message("force", t_capture_s=t_s[-1], t_s=t_s, value_n=[float(i) for i in range(len(t_s))],
                        **options)


def test_each_sample_is_stamped_at_its_own_time_not_the_batch_capture_time():
    message = make_message("force", t_capture_s=300.05, t_s=[300.0, 300.01, 300.02], value_n=[1.0, 2.0, 3.0])
    converted = foxglove_messages(message, OFFSET_NS)
    assert [_stamp_ns(item) for item in converted] == [round(t * 1e9) + OFFSET_NS for t in (300.0, 300.01, 300.02)]
    assert {json.loads(item.data)["t_capture_s"] for item in converted} == {300.05}  # as sent


@pytest.mark.parametrize("size", [MAX_SAMPLE_MESSAGES, MAX_SAMPLE_MESSAGES + 1, MAX_SAMPLE_MESSAGES + 2])
def test_no_batch_gives_more_than_the_most_sample_messages_and_its_first_and_last_are_kept(size):
    t_s = [1.0 + i * 1e-3 for i in range(size)]
    converted = foxglove_messages(_force(t_s))
    assert len(converted) == min(size, MAX_SAMPLE_MESSAGES)
    samples = [json.loads(item.data)["t_s"] for item in converted]
    assert (samples[0], samples[-1]) == (t_s[0], t_s[-1])


def test_a_suffixed_bus_topic_keeps_its_own_foxglove_topic():
    assert [item.topic for item in foxglove_messages(_force([1.0]))] == ["/force"]
    assert [item.topic for item in foxglove_messages(_force([1.0], topic="force/extra"))] == ["/force/extra"]


def test_known_channels_are_the_fingers_images_the_events_and_each_json_types_default_topic():
    topics = [channel.topic for channel in known_channels(["left", "right"])]
    assert len(topics) == len(set(topics))
    json_topics = {f"/{kind}" for kind in SCHEMAS} - {"/frame", "/grasp_event", "/heartbeat"}
    # frames and grasp events have their own topics; heartbeats none
    assert set(topics) == {"/tactile/left", "/tactile/right", EVENTS_TOPIC} | json_topics


def test_json_schemas_refuse_the_integers_the_wire_refuses():
    display = dict(grasp_id="g0", phase="active", stiffness=0.4, uncertainty_decades=0.3, rigid=False,
                   unknown=False, provisional=True, E_pa=2e5, level=0, level_max=1)
    make_message("display", t_capture_s=1.0, **display)  # the smallest level and level_max the wire takes
    with pytest.raises(MessageRejected):
        make_message("display", t_capture_s=1.0, **{**display, "level_max": 0})
    properties = json_schema("display")["properties"]
    jsonschema.validate(0, properties["level"])
    jsonschema.validate(1, properties["level_max"])
    for value, schema in ((-1, properties["level"]), (0, properties["level_max"])):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(value, schema)
