"""Typed message bodies: one dataclass per bus type gives the checks, the typed view and the
Foxglove schema; no module outside the wire module reads a body by string key."""

from __future__ import annotations

import ast
import dataclasses
import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from teleop.bus.field_checks import FLAG, ArrayField, NumberField, Schema, TextField, array, scalar
from teleop.bus.messages import (
    BODIES,
    SCHEMAS,
    Body,
    CommandBody,
    EstimateBody,
    ForceBody,
    FrameBody,
    LabelBody,
    ModelEventBody,
)
from teleop.bus.wire import Message, decode, encode, make_message
from teleop.errors import MessageRejected
from teleop.session.foxglove import json_schema

REPO = Path(__file__).resolve().parents[3]
MAX = 16 * 1024 * 1024
WIRE_PACKAGE = REPO / "teleop" / "bus"  # the wire module and its family: they may read bodies by key
SCANNED = ("teleop", "estimator", "haptics")

ESTIMATE = {"grasp_id": "g1", "method": "auto", "E_pa": 2e5, "interval_pa": [1e5, 4e5], "state": "ok",
            "reason": "", "provisional": False, "latency_s": 0.003, "model": "default-3f2a9c1e"}


def _round_trip(message: Message) -> Message:
    return decode([bytes(f) for f in encode(message)], max_bytes=MAX)


# --------------------------------------------------------------------------- the typed view


def test_fields_read_back_what_was_sent_arrays_not_copied():
    sent = make_message("estimate", t_capture_s=2.1, **ESTIMATE)
    got = _round_trip(sent)
    assert isinstance(got.fields, EstimateBody) and got.fields.kind == "estimate"
    assert got.fields == EstimateBody(**ESTIMATE)
    assert got.fields.as_dict() == dict(got.body) == ESTIMATE  # same values, same (wire) order
    assert list(got.fields.as_dict()) == list(SCHEMAS["estimate"].fields)
    assert got.fields is got.fields  # built once per message

    force = _round_trip(make_message("force", t_capture_s=2.0, grasp_id="g1", t_s=[1.9, 2.0], value_n=[0.5, 1.5]))
    assert isinstance(force.fields, ForceBody)
    assert force.fields.value_n is force.body["value_n"]  # the read-only view over the received frame
    assert not force.fields.value_n.flags.writeable and np.array_equal(force.fields.t_s, [1.9, 2.0])


def test_the_view_is_built_only_when_read():
    got = _round_trip(make_message("heartbeat", t_capture_s=1.0, interval_s=0.5))
    assert "fields" not in vars(got)  # decoding alone builds no view (the 80 Hz force path)
    assert got.fields.interval_s == 0.5 and "fields" in vars(got)


def test_a_field_left_out_reads_as_nil():
    sent = make_message("frame", t_capture_s=1.0, finger="left", index=3, encoding="raw",
                        data=np.zeros((2, 2, 3), np.uint8))
    assert isinstance(sent.fields, FrameBody) and sent.fields.grasp_id is None
    old = encode(make_message("estimate", t_capture_s=2.1, **ESTIMATE))  # an estimate from before "model"
    body = msgpack.unpackb(bytes(old[2]))
    del body["model"]
    got = decode([bytes(old[0]), bytes(old[1]), msgpack.packb(body)], max_bytes=MAX)
    assert got.fields.model is None and got.fields.E_pa == 2e5


DISPLAY = {"grasp_id": "g1", "phase": "active", "stiffness": 0.5, "uncertainty_decades": 0.3, "rigid": False,
           "unknown": False, "provisional": False, "E_pa": 2e5, "level": 2048, "level_max": 4095}


def test_a_display_message_says_what_the_device_reported_and_older_ones_read_as_nil():
    said = _round_trip(make_message("display", t_capture_s=1.0, **DISPLAY, device_state="fault",
                                    device_faults="over_temperature,bad_report"))
    assert said.fields.device_state == "fault" and said.fields.device_faults == "over_temperature,bad_report"
    assert make_message("display", t_capture_s=1.0, **DISPLAY, device_state="rendering",
                        device_faults="").fields.device_faults == ""
    old = encode(make_message("display", t_capture_s=1.0, **DISPLAY))  # a session log from before the fields
    body = msgpack.unpackb(bytes(old[2]))
    del body["device_state"], body["device_faults"]
    got = decode([bytes(old[0]), bytes(old[1]), msgpack.packb(body)], max_bytes=MAX)
    assert got.fields.device_state is None and got.fields.device_faults is None and got.fields.level == 2048
    schema = json_schema("display")["properties"]
    assert schema["device_state"]["enum"] == ["free", "rendering", "fault", "watchdog"]
    for bad, match in [({"device_state": "melted", "device_faults": ""}, "device_state = 'melted'"),
                       ({"device_state": "fault", "device_faults": "fire"}, r"device_faults names \['fire'\]"),
                       ({"device_state": "fault"}, "both given or both nil"),
                       ({"device_faults": ""}, "both given or both nil")]:
        with pytest.raises(MessageRejected, match=match):
            make_message("display", t_capture_s=1.0, **DISPLAY, **bad)


def test_unknown_types_and_hand_built_bodies_are_refused_by_name():
    with pytest.raises(MessageRejected, match="unknown_type"):
        make_message("telemetry", t_capture_s=0.0, x=1)
    with pytest.raises(MessageRejected, match=r"unknown_type: 'telemetry'"):
        _ = Message("telemetry", {}, 0.0).fields
    with pytest.raises(MessageRejected, match=r"missing_field: label body lacks detail, object_name, source"):
        _ = Message("label", {"grasp_id": "g"}, 0.0).fields
    with pytest.raises(MessageRejected, match=r"extra_field: follow body has unexpected field\(s\) colour"):
        _ = Message("follow", {"target_width_m": 0.04, "enable": True, "colour": "red"}, 0.0).fields


def test_a_json_report_of_a_body_is_its_fields():
    event = make_message("model_event", t_capture_s=5.1, event="refused", request="r2", reason="no metadata.json")
    assert isinstance(event.fields, ModelEventBody)
    assert json.loads(json.dumps(event.fields.as_dict())) == {
        "event": "refused", "request": "r2", "model": None, "path": None, "reason": "no metadata.json"}
    assert LabelBody(**make_message("label", t_capture_s=0.0, grasp_id="g", object_name="ball", source="catalogue",
                                    detail="").fields.as_dict()).object_name == "ball"


# --------------------------------------------------------------------------- one definition per type


def test_every_type_is_one_body_class_and_its_schema_is_derived_from_it():
    assert list(BODIES) == list(SCHEMAS)
    for kind, body in BODIES.items():
        assert issubclass(body, Body) and body.kind == kind and body.__doc__, kind
        assert dataclasses.is_dataclass(body) and body.__dataclass_params__.frozen, kind
        assert SCHEMAS[kind] == Schema.of(body), kind
        schema, names = SCHEMAS[kind], [f.name for f in dataclasses.fields(body)]
        assert set(names) == set(schema.fields) | set(schema.arrays), kind
        assert [n for n in names if n in schema.fields] == list(schema.fields), kind  # the wire's order
        assert schema.nullable == {f.name for f in dataclasses.fields(body) if f.default is None}, kind
        assert schema.optional <= schema.nullable, kind


def test_the_derived_checks_keep_the_old_rules():
    schema = SCHEMAS["estimate"]
    assert schema.nullable == schema.optional == {"model"}  # E_pa is nullable, but a sender must say it
    with pytest.raises(MessageRejected, match="missing_field: estimate body lacks E_pa"):
        make_message("estimate", t_capture_s=0.0, **{k: v for k, v in ESTIMATE.items() if k != "E_pa"})
    with pytest.raises(MessageRejected, match="state 'ok' has no E_pa"):  # the class's cross_check
        make_message("estimate", t_capture_s=0.0, **{**ESTIMATE, "E_pa": None})
    with pytest.raises(MessageRejected, match=r"t_s \(2,\) and value_n \(1,\)"):
        make_message("force", t_capture_s=0.0, t_s=[1.0, 2.0], value_n=[1.0])
    assert SCHEMAS["display"].nullable == {"grasp_id", "E_pa", "level", "level_max", "device_state",
                                           "device_faults"}
    assert SCHEMAS["display"].optional == {"device_state", "device_faults"}  # older logs lack them
    assert SCHEMAS["command"].rule is None and SCHEMAS["frame"].rule is not None
    assert make_message("command", t_capture_s=0.0, action="stop", params={}).fields == CommandBody(
        action="stop", params={})  # the grasp left out: nil


def test_a_body_class_declares_every_field_with_a_check():
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Fine:
        name: str = scalar(TextField())
        note: str | None = scalar(TextField(nullable=True))
        level: float | None = scalar(NumberField(nullable=True), required=True)
        added: str | None = scalar(TextField(nullable=True), added_later=True)
        samples: np.ndarray = array(ArrayField(("<f8",), (1,)))

    schema = Schema.of(Fine)
    assert list(schema.fields) == ["name", "note", "level", "added"] and list(schema.arrays) == ["samples"]
    assert schema.nullable == {"note", "added"} and schema.optional == {"added"} and schema.rule is None

    @dataclasses.dataclass(frozen=True)
    class Unchecked:
        name: str

    with pytest.raises(TypeError, match=r"Unchecked.name is declared without scalar\(\) or array\(\)"):
        Schema.of(Unchecked)
    with pytest.raises(TypeError, match="not a dataclass"):
        Schema.of(dict)
    with pytest.raises(TypeError, match="only a nullable field can be required"):
        scalar(FLAG, required=True)
    with pytest.raises(TypeError, match="added later must be nullable"):
        scalar(NumberField(), added_later=True)


def test_the_foxglove_schema_comes_from_the_same_definition():
    for kind, body in BODIES.items():
        derived = json_schema(kind)
        scalars = [f for f in dataclasses.fields(body) if f.name in SCHEMAS[kind].fields]
        assert {f.name for f in scalars} <= set(derived["properties"]), kind
        for f in scalars:  # nil is left out of a JSON message: a nullable field is never required
            assert (f.name in derived["required"]) == (not SCHEMAS[kind].fields[f.name].nullable), (kind, f.name)


# --------------------------------------------------------------------------- no string keys outside the wire


def _is_body(node: ast.AST, bound: set[str]) -> bool:
    """An expression ending in ``.body`` (not a call of a ``body()`` method), or a name bound from one."""
    return (isinstance(node, ast.Attribute) and node.attr == "body") or (isinstance(node, ast.Name) and node.id in bound)


def _bound_from_body(scope: ast.AST) -> set[str]:
    """Names assigned from a ``.body`` expression in ``scope`` (``b = m.body``, ``a, b = x, m.body``)."""
    names = set()
    for node in ast.walk(scope):
        pairs = []
        if isinstance(node, ast.Assign):
            for target in node.targets:
                if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                    pairs += zip(target.elts, node.value.elts, strict=False)
                else:
                    pairs.append((target, node.value))
        elif isinstance(node, ast.AnnAssign | ast.NamedExpr) and node.value is not None:
            pairs.append((node.target, node.value))
        names |= {t.id for t, v in pairs if isinstance(t, ast.Name) and _is_body(v, set())}
    return names


def _string(node: ast.AST | None) -> bool:
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def body_reads(source: str, where: str) -> list[str]:
    """Each place in ``source`` that reads a message body by string key, or copies or spreads it
    into a dict to be read so elsewhere: ``where:line``."""
    tree = ast.parse(source)
    found = set()
    for scope in [tree, *(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef))]:
        bound = _bound_from_body(scope)
        for node in ast.walk(scope):
            if isinstance(node, ast.Subscript) and _is_body(node.value, bound) and _string(node.slice):
                found.add(node.lineno)
            elif isinstance(node, ast.Call):
                func, first = node.func, node.args[0] if node.args else None
                get = (isinstance(func, ast.Attribute) and func.attr == "get" and _is_body(func.value, bound)
                       and _string(first))
                copy = isinstance(func, ast.Name) and func.id == "dict" and first is not None and _is_body(first, bound)
                spread = any(k.arg is None and _is_body(k.value, bound) for k in node.keywords)
                if get or copy or spread:
                    found.add(node.lineno)
            elif isinstance(node, ast.Dict) and any(
                    k is None and _is_body(v, bound) for k, v in zip(node.keys, node.values, strict=True)):
                found.add(node.lineno)
    return [f"{where}:{line}" for line in sorted(found)]


def test_the_scan_finds_every_form_of_a_body_read_by_key():
    source = """
def handle(message, logged):
    a = message.body["E_pa"]
    b = logged.message.body.get("model")
    body = message.body
    c = body["state"]
    kind, other = message.type, message.body
    d = other.get("grasp_id")
    e = dict(message.body)
    f = {**message.body, "t_s": 1.0}
    g = update(**message.body)
    fine = message.fields.E_pa, label.body("g1")["grasp_id"], message.body[name], body.get(name)
    return a, b, c, d, e, f, g, fine
"""
    assert body_reads(source, "x.py") == [f"x.py:{line}" for line in (3, 4, 6, 8, 9, 10, 11)]


def test_no_module_outside_the_wire_module_reads_a_body_by_string_key():
    reads = []
    for package in SCANNED:
        for path in sorted((REPO / package).rglob("*.py")):
            if WIRE_PACKAGE in path.parents:
                continue
            where = str(path.relative_to(REPO))
            reads += body_reads(path.read_text(encoding="utf-8"), where)
    assert not reads, ("bus bodies read by string key (read message.fields.<name> instead; a JSON "
                       f"report takes message.fields.as_dict()): {', '.join(reads)}")


# --------------------------------------------------------------------------- an estimate's interval

_TOL = 1e-9  # the renderer's relative tolerance (haptics.mapping.EstimateUpdate)


@pytest.mark.parametrize(("state", "interval"), [
    ("lower_bound", [None, None]), ("lower_bound", [None, 3e5]), ("upper_bound", [3e5, None]),
])
def test_a_bound_state_without_its_bound_is_refused_on_the_wire_as_the_renderer_would(state, interval):
    from haptics.errors import MappingError
    from haptics.mapping import EstimateUpdate

    with pytest.raises(MappingError):
        EstimateUpdate(None, tuple(interval), state)
    with pytest.raises(MessageRejected, match=rf"mistyped_field: estimate with state '{state}' has neither E_pa"):
        make_message("estimate", t_capture_s=1.0, **{**ESTIMATE, "state": state, "E_pa": None,
                                                    "interval_pa": interval})


@pytest.mark.parametrize(("state", "e_pa", "interval", "ok"), [
    ("ok", 2e5, [1e5, 4e5], True),
    ("ok", 1e5 * (1 - _TOL / 2), [1e5, 4e5], True),  # a bound rounded differently from the value
    ("ok", 4e5 * (1 + _TOL / 2), [1e5, 4e5], True),
    ("ok", 5e5, [1e3, 2e3], False),  # above its interval
    ("ok", 1e5 * (1 - 1e-6), [1e5, 4e5], False),  # below it
    ("ok", 1e300, [1e-300, None], True),  # one side open
    ("lower_bound", 3e5, [3e5, None], True),  # a bound: E is the interval's closed side
    ("lower_bound", 1e5, [3e5, None], False),
    ("upper_bound", 3e5, [None, 3e5], True),
    ("upper_bound", 4e5, [None, 3e5], False),
    ("lower_bound", None, [3e5, None], True),  # the bound read from the interval
    ("insufficient_data", None, [None, None], True),
])
def test_an_estimate_outside_its_own_interval_is_refused_on_the_wire_as_the_renderer_would(state, e_pa, interval,
                                                                                            ok):
    from haptics.errors import MappingError
    from haptics.mapping import EstimateUpdate

    body = {**ESTIMATE, "state": state, "E_pa": e_pa, "interval_pa": interval}
    try:
        EstimateUpdate(e_pa, tuple(interval), state)
        rendered = True
    except MappingError:
        rendered = False
    assert rendered == ok  # the wire's rule is the renderer's
    if ok:
        assert _round_trip(make_message("estimate", t_capture_s=1.0, **body)).fields.E_pa == e_pa
        return
    with pytest.raises(MessageRejected, match=r"mistyped_field: .*lies outside its interval_pa"):
        make_message("estimate", t_capture_s=1.0, **body)
    # ... and so is one a sender put on the wire by hand: the receiver refuses it.
    topic, header, _, *rest = encode(make_message("estimate", t_capture_s=1.0, **ESTIMATE))
    with pytest.raises(MessageRejected, match=r"mistyped_field: .*lies outside its interval_pa"):
        decode([bytes(topic), bytes(header), msgpack.packb(body), *map(bytes, rest)], max_bytes=MAX)
