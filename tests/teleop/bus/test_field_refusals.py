"""Field by field, what a sender is refused and a receiver refuses (teleop.bus.field_checks): flags
are no numbers, strings no arrays, bounds are where the checks say; the wire's framing and refusal
reasons are tests/teleop/bus/test_wire.py's."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from teleop.bus.field_checks import MAX_TIME_S, NumberField
from teleop.bus.wire import REJECT_REASONS, decode, encode, make_message
from teleop.errors import MessageRejected

MAX = 16 * 1024 * 1024
ESTIMATE = dict(t_capture_s=2.1, grasp_id="g1", method="hertz", E_pa=None, state="insufficient_data",
                reason="too short", provisional=False, latency_s=0.001, interval_pa=[None, None])
COMMAND = dict(t_capture_s=0.0, action="start_grasp", grasp_id="g2")
FORCE = dict(t_capture_s=2.0, grasp_id="g1", t_s=[2.0, 3.0], value_n=[1.0, 2.0])


def _made_refused(type_: str, **fields) -> MessageRejected:
    """The refusal of ``make_message(type_, **fields)``: what a sender is told."""
    with pytest.raises(MessageRejected) as refused:
        make_message(type_, **fields)
    return refused.value


def _received_refused(message, **body_changes) -> str:
    """The reason a receiver refuses ``message`` with its body's fields changed on the wire."""
    frames = [bytes(f) for f in encode(message, max_bytes=MAX)]
    body = msgpack.unpackb(frames[2])
    body.update(body_changes)
    with pytest.raises(MessageRejected) as refused:
        decode([frames[0], frames[1], msgpack.packb(body), *frames[3:]], max_bytes=MAX)
    assert refused.value.reason in REJECT_REASONS
    return refused.value.reason


# --------------------------------------------------------------------------- flags and strings


@pytest.mark.parametrize("flag", [True, False])
def test_a_flag_is_no_number(flag):
    # latency_s=True would be stored as 1.0 s
    refused = _made_refused("estimate", **{**ESTIMATE, "latency_s": flag})
    assert refused.reason == "mistyped_field" and "must be a number" in str(refused)
    assert _received_refused(make_message("estimate", **ESTIMATE), latency_s=flag) == "mistyped_field"


@pytest.mark.parametrize(("name", "value"), [
    ("t_s", [True, 3.0]),
    ("value_n", [True, False]),
    ("t_s", [np.bool_(True), 3.0]),
    ("value_n", True),
])
def test_a_flag_is_no_sample(name, value):
    # t_s=[True, 3.0] would be sent as the sample times [1.0, 3.0]
    refused = _made_refused("force", **{**FORCE, name: value})
    said = f"mistyped_field: force.{name} must be an array of numbers, not of flags: holds "
    assert str(refused).startswith(said) and "True" in str(refused)


def test_an_array_of_flags_is_refused_for_its_dtype():
    refused = _made_refused("force", **{**FORCE, "value_n": np.array([True, False])})
    assert refused.reason == "mistyped_field" and "force.value_n has dtype bool" in str(refused)


def test_a_string_is_no_array_of_numbers():
    # "2.0" must not pass as the sample time 2.0 (nor "12" as 12 samples' worth of anything)
    refused = _made_refused("force", **{**FORCE, "t_s": "2.0", "value_n": [1.0]})
    assert refused.reason == "mistyped_field" and "t_s must be an array of numbers" in str(refused)


def test_a_numpy_integer_is_sent_as_a_plain_integer():
    # a frame index counted with numpy must encode (msgpack cannot pack numpy.int64)
    message = make_message("frame", t_capture_s=1.5, finger="left", grasp_id="g1", index=np.int64(3),
                           encoding="jpeg", data=b"\xff\xd8\xff\xd9")
    assert decode(encode(message, max_bytes=MAX), max_bytes=MAX).fields.index == 3


# --------------------------------------------------------------------------- bounds


def test_a_number_at_its_magnitude_bound_passes():
    # "at most max_abs in magnitude": the bound itself is allowed
    assert NumberField(max_abs=MAX_TIME_S)(MAX_TIME_S, "t") == MAX_TIME_S
    assert NumberField(max_abs=MAX_TIME_S)(-MAX_TIME_S, "t") == -MAX_TIME_S
    with pytest.raises(MessageRejected, match="in magnitude"):
        NumberField(max_abs=MAX_TIME_S)(MAX_TIME_S * (1 + 1e-15), "t")


def test_an_interval_side_of_zero_pa_is_refused():
    # "each > 0 or nil": a modulus of 0 Pa is no bound
    refused = _made_refused("estimate", **{**ESTIMATE, "interval_pa": [0.0, 1e5]})
    assert refused.reason == "mistyped_field" and "interval_pa[0]" in str(refused)


# --------------------------------------------------------------------------- command params


@pytest.mark.parametrize("value", ["5.0", None, [5.0], math.nan, math.inf])
def test_command_params_map_names_to_finite_numbers_only(value):
    refused = _made_refused("command", params={"target_force_n": value}, **COMMAND)
    expected = "not_finite" if isinstance(value, float) else "mistyped_field"
    assert refused.reason == expected and "params.target_force_n" in str(refused)


@pytest.mark.parametrize("key", ["p" * 65, 7])
def test_command_param_names_are_short_strings(key):
    refused = _made_refused("command", params={key: 1.0}, **COMMAND)
    assert refused.reason == "mistyped_field" and "params key" in str(refused)
    if isinstance(key, str):  # msgpack itself refuses a non-string map key on receipt ("corrupt")
        sent = make_message("command", params={"ok": 1.0}, **COMMAND)
        assert _received_refused(sent, params={key: 1.0}) == "mistyped_field"
