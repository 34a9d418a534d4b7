"""``estimator reload``: switch a running estimator service to another model, without a restart.

It sends one ``load_model`` message (the folder, and a request id of its own) on ``bus.control``
and waits for the service's ``model_event`` answering that request on ``bus.estimate_pub``
(:mod:`estimator.model_slot`): the service loads and checks the model while it serves,
switches to it between grasps and says "loaded" with the new model's id, or keeps the model it
has and says "refused" with the reason. Exit status 0 when loaded, 1 when refused, 2 when no
service answered within ``--timeout-s`` (or the folder or the endpoints are unusable).

The service listens for commands on ``bus.command`` (the operator's: a console or ``teleop
demo`` holds it) and on ``bus.control``, which this command binds while it runs, so it works while
an operator operates. Every estimator service subscribed to ``bus.control`` takes the request and
switches (or refuses) on its own, but only the one on ``bus.estimate_pub`` is heard answering: the
answer says how many took it (``services``, counted by their subscriptions to ``load_model``), so a
second service (one serving another model for a side-by-side comparison) is never switched
unawares; give each service its own ``--control`` to switch one alone. Copying new files into the folder the service serves works too: it switches
once both files have stopped changing.

Until the service's subscription to the control endpoint has connected, a message sent there is
lost; so the first request waits for the service's subscription to ``load_model`` (a recorder's, to
every topic, does not count), and :data:`JOIN_S` more for the other peers (a recorder), then is
sent again every :data:`RESEND_S` until answered: the
service loads a request once and answers a repeat with the answer it gave.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import uuid

from estimator.errors import ModelError
from teleop.bus.messages import ModelEventBody
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.clikit import positive_number
from teleop.errors import BusAddressInUseError, BusError, TeleopError
from teleop.live import add_endpoint_arguments, bus_from_args
from teleop.settings import BusSettings, default_settings_path, load_settings

__all__ = ["JOIN_S", "RESEND_S", "reload_model", "services_reached"]

RESEND_S = 0.5
# Peers reconnect to a freshly bound endpoint every 0.1 s (ZeroMQ's default): once the service has
# subscribed, this long lets a recorder subscribe too, so the request itself is on the record.
JOIN_S = 0.3
DEFAULT_TIMEOUT_S = 30.0
# A reload that just ended lets go of the control port a moment after its socket closed.
BIND_WAIT_S = 2.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Switch a running estimator service (estimator serve, or the one teleop demo starts) to another "
        "model: it loads and checks the model while it serves, switches between grasps and answers; the "
        "model in use stays when the new one fails. Exit status 0 when loaded, 1 when refused (the reason "
        "is printed), 2 when no service answered. Sends on the control endpoint, so an operator console "
        "may hold the command endpoint meanwhile. Every estimator service on the control endpoint switches "
        "(the answer counts them: services); give each service its own --control to switch one alone."
    )
    parser.add_argument("--model", metavar="DIR", required=True,
                        help="the model folder (model.onnx and metadata.json) on the service's host; a "
                             "relative path is taken from this directory")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML whose [bus] endpoints the service uses")
    add_endpoint_arguments(parser, "control", "estimate_pub")
    parser.add_argument("--timeout-s", type=positive_number, default=DEFAULT_TIMEOUT_S, metavar="S",
                        help="how long to wait for the service's answer; it answers after the grasp open "
                             "now, if any, has ended")
    parser.add_argument("--json", action="store_true",
                        help="print the answer as one JSON object (event, request, model, path, reason, and "
                             "services: how many estimator services took the request) as the last stdout line")


def reload_model(path: str, *, command: Publisher, answers: Subscriber, timeout_s: float = DEFAULT_TIMEOUT_S,
                 request: str | None = None) -> ModelEventBody:
    """Send ``load_model`` for ``path`` on ``command`` until the ``model_event`` answering it
    arrives on ``answers`` (a subscriber of the service's estimate endpoint, topic ``model_event``);
    its body.

    Raises
    ------
    TeleopError
        No answer within ``timeout_s``.
    """
    request = request or f"reload-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    deadline = time.monotonic() + timeout_s
    next_send = None  # first when a subscriber to load_model is heard, and JOIN_S later
    while True:
        now = time.monotonic()
        if now >= deadline:
            if next_send is None:
                why = (f"nothing subscribed to load_model on {command.endpoint}: is the estimator service running, "
                       f"with that --control endpoint (and --estimate-pub {answers.endpoint_text})?")
            elif answers.heartbeat.is_alive("estimator"):
                why = (f"the estimator service on {answers.endpoint_text} is running: it switches models between "
                       "grasps, so a grasp still open holds its answer back (wait, or raise --timeout-s)")
            else:
                why = (f"this did not hear the estimator service on {answers.endpoint_text}; is that its "
                       "--estimate-pub endpoint, and is it running?")
            raise TeleopError(f"no answer to load_model {path} (request {request}) within {timeout_s:g} s: {why}")
        if next_send is None and command.subscriptions("load_model"):  # the service's (a recorder's is "")
            next_send = now + JOIN_S
        if next_send is not None and now >= next_send:
            command.send("load_model", t_capture_s=now, path=path, request=request)
            next_send = now + RESEND_S
        message = answers.recv(timeout_s=min(0.05, max(0.0, deadline - now)))
        if message is not None and message.type == "model_event" and message.fields.request == request:
            return message.fields


def services_reached(command: Publisher) -> int:
    """How many estimator services subscribe to ``load_model`` on ``command`` now: each takes a request
    sent there (a recorder, subscribed to every topic, is not counted)."""
    return command.subscriptions("load_model")


def _control_publisher(bus: BusSettings) -> Publisher:
    """Bind the control endpoint, waiting up to :data:`BIND_WAIT_S` for a reload that just ended.

    Only the endpoint in use is waited for and blamed on another reload; any other error (the keys,
    the endpoint's text) is raised as it is, at once.
    """
    deadline = time.monotonic() + BIND_WAIT_S
    while True:
        try:
            return Publisher.from_settings(bus, bus.control, lossless=False,
                                           source=f"reload-{os.getpid()}")  # its own: seq from 0
        except BusAddressInUseError as exc:
            if time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            raise TeleopError(f"cannot send on the control endpoint {bus.control} ({exc}): another estimator "
                              "reload runs, or copy the model's files into the folder the service "
                              "serves") from exc


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    bus = bus_from_args(settings, args)
    if not args.model.strip():
        raise ModelError("--model: expected a model folder, got an empty path")
    path = os.path.abspath(args.model)  # the service's working directory is not this one
    try:
        answers = Subscriber.from_settings(bus, bus.estimate_pub, ("model_event",))
    except BusError as exc:
        raise TeleopError(f"cannot listen to the estimator service on {bus.estimate_pub}: {exc}") from exc
    with answers, _control_publisher(bus) as command:
        answer = reload_model(path, command=command, answers=answers, timeout_s=args.timeout_s)
        services = max(1, services_reached(command))  # the one that answered, gone since, still took it
    loaded = answer.event == "loaded"
    if loaded:
        print(f"estimator reload: the service serves {answer.model} ({answer.path}) from its next grasp on",
              file=sys.stderr)
    else:
        print(f"estimator reload: refused {answer.path}: {answer.reason}; the service keeps "
              f"{answer.model or 'no model'}", file=sys.stderr)
    if services > 1:
        print(f"estimator reload: {services} estimator services subscribe to {bus.control}: every one took this "
              f"load_model and switches (or refuses) on its own; only the one on {bus.estimate_pub} answered here "
              "(see the others' logs); give each service its own --control to switch one alone", file=sys.stderr)
    if args.json:
        print(json.dumps({**answer.as_dict(), "services": services}))
    return 0 if loaded else 1
