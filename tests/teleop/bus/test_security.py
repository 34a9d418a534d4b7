"""CURVE on the bus (real sockets on loopback), key management, and the receive-size limits."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import socket
import stat
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq
from support.bus import HEARD_WITHIN_S, delivered, force

import teleop.cli
from teleop.bus import Publisher, Subscriber
from teleop.bus.pubsub import CONTROL_FRAME_BYTES
from teleop.bus.security import (
    CURVE_FRAME_OVERHEAD_BYTES,
    ZAP_HANDLERS,
    BusSecurity,
    apply_security,
    authorize_key,
    check_endpoints,
    init_keys,
    is_loopback,
    list_keys,
    revoke_key,
    security_from_settings,
)
from teleop.bus.wire import encode, make_message
from teleop.errors import BusError, BusSecurityError, BusTimeoutError
from teleop.settings import BusSettings

LOOPBACK = "tcp://127.0.0.1:*"
SILENCE_S = 0.4  # how long a refused peer is watched for traffic that must not come


def _nothing_arrives(pub: Publisher, *subs: Subscriber) -> bool:
    return delivered(pub, *subs, within_s=SILENCE_S) is None


# --------------------------------------------------------------------------- endpoints


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp://127.0.0.1:5550",
        "tcp://127.8.9.10:*",
        "tcp://[::1]:5550",
        "tcp://localhost:5550",
        "inproc://bus",
        "ipc:///tmp/bus.sock",
        "tcp://127.0.0.1;127.0.0.1:5550",
    ],
)
def test_loopback_endpoints(endpoint):
    assert is_loopback(endpoint)


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp://*:5550",
        "tcp://0.0.0.0:5550",
        "tcp://192.168.1.20:5550",
        "tcp://[::]:5550",
        "tcp://eth0:5550",
        "tcp://robot.lab:5550",
        "tcp://127.0.0.1;10.0.0.2:5550",
        "ws://10.0.0.2:80/bus",
        "epgm://eth0;239.192.1.1:5555",
    ],
)
def test_endpoints_other_hosts_can_reach(endpoint):
    assert not is_loopback(endpoint)


@pytest.mark.parametrize("endpoint", ["tipc://{5560,0,0}", "vmci://1:5555"])
def test_fabric_transports_reach_other_hosts_and_need_keys(endpoint):
    # tipc and vmci name no host, yet reach other machines and VMs
    assert not is_loopback(endpoint)
    with pytest.raises(BusSecurityError, match="reachable from other hosts"):
        check_endpoints([endpoint], None)


def test_a_non_loopback_endpoint_without_keys_refuses_to_start(keys):
    for make in (
        lambda: Publisher("tcp://0.0.0.0:*", lossless=True),
        lambda: Subscriber(["tcp://127.0.0.1:5550", "tcp://192.168.1.20:5550"]),
        lambda: security_from_settings(BusSettings(estimate_pub="tcp://*:5551")),
    ):
        with pytest.raises(BusSecurityError) as info:
            make()
        message = str(info.value)
        assert "teleop keys init" in message and "bus.keys_dir" in message
        assert ("0.0.0.0" in message) or ("192.168.1.20" in message) or ("*:5551" in message)
    check_endpoints(["tcp://0.0.0.0:5550"], keys)  # with keys it is allowed
    assert security_from_settings(BusSettings()) is None  # all loopback: plain
    with pytest.raises(BusError, match="not a ZeroMQ endpoint"):
        is_loopback("tpc://127.0.0.1:5550")
    with pytest.raises(BusError, match="port '99999': expected an integer in 1..65535"):
        is_loopback("tcp://127.0.0.1:99999")  # read as the settings read it: ZeroMQ would bind 34463


def test_settings_keys_dir_turns_curve_on(keys):
    bus = BusSettings(robot_pub="tcp://10.0.0.2:5550", keys_dir=str(keys.keys_dir))
    assert security_from_settings(bus) == keys
    with pytest.raises(BusSecurityError, match="does not exist"):
        security_from_settings(BusSettings(keys_dir=str(keys.keys_dir / "absent")))


# --------------------------------------------------------------------------- CURVE on the bus


def test_only_an_authorised_client_can_subscribe(keys, stranger):
    wrong_server = dataclasses.replace(keys, server_public_key=stranger.client_public_key)
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub,
        contextlib.ExitStack() as stack,
    ):
        outsiders = [
            stack.enter_context(
                Subscriber(pub.endpoint, ["force"], security=stranger)
            ),  # not authorised
            stack.enter_context(Subscriber(pub.endpoint, ["force"])),  # no CURVE at all
            stack.enter_context(Subscriber(pub.endpoint, ["force"], security=wrong_server)),
        ]
        with pytest.raises(BusTimeoutError):  # no subscription gets through the handshake
            pub.wait_for_subscriber("force", timeout_s=SILENCE_S)
        with Subscriber(pub.endpoint, ["force"], security=keys) as insider:
            pub.wait_for_subscriber("force", timeout_s=2.0)
            force(pub, 7)
            got = insider.recv(timeout_s=2.0)
            assert got is not None and got.body["value_n"][0] == 7.0 and got.source == "robot"
            assert _nothing_arrives(pub, *outsiders)


def test_only_an_authorised_client_can_publish(keys, stranger):
    with Subscriber(LOOPBACK, ["force"], bind=True, security=keys) as sub:
        with Publisher(
            sub.endpoints[0], lossless=False, bind=False, source="mallory", security=stranger
        ) as pub:
            assert _nothing_arrives(pub, sub)
            with pytest.raises(BusTimeoutError):  # nor did the subscription reach it
                pub.wait_for_subscriber("force", timeout_s=0.05)
        with Publisher(
            sub.endpoints[0], lossless=False, bind=False, source="robot", security=keys
        ) as pub:
            got = delivered(pub, sub, within_s=HEARD_WITHIN_S)
            pub.wait_for_subscriber("force", timeout_s=0.05)
    assert got is not None and got.source == "robot"
    assert sub.stats.received >= 1 and "mallory" not in sub.heartbeat.peers()


def test_an_impostor_server_cannot_publish_to_clients(keys, stranger):
    # It binds with a server key pair of its own; clients trust only the bus's server key.
    impostor = dataclasses.replace(
        stranger, server_public_key=BusSecurity.load(stranger.keys_dir).server_public_key
    )
    with (
        Publisher(LOOPBACK, lossless=False, source="mallory", security=impostor) as pub,
        Subscriber(pub.endpoint, ["force"], security=keys) as sub,
    ):
        assert _nothing_arrives(pub, sub)


def test_a_revoked_key_is_refused_after_restart(tmp_path, keys, stranger):
    authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name="operator")
    pub = Publisher(LOOPBACK, lossless=False, source="robot", security=keys)
    endpoint = pub.endpoint
    with (
        Subscriber(endpoint, ["force"], security=stranger) as operator,
        Subscriber(endpoint, ["force"], security=keys) as robot_side,
    ):
        assert delivered(pub, operator, within_s=HEARD_WITHIN_S) is not None  # authorised: it works
        received_before = operator.stats.received

        revoke_key(keys.keys_dir, "operator")
        pub.close()
        pub = _rebind(endpoint, keys)  # the restart; both subscribers reconnect by themselves
        try:
            assert delivered(pub, robot_side, within_s=HEARD_WITHIN_S) is not None
            assert _nothing_arrives(pub, operator)
            assert operator.stats.received == received_before
        finally:
            pub.close()


def _rebind(endpoint: str, security: BusSecurity) -> Publisher:
    # libzmq closes the old listener in its I/O thread: retry briefly while the port frees.
    deadline = time.monotonic() + 2.0
    while True:
        try:
            return Publisher(endpoint, lossless=False, source="robot", security=security)
        except BusError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_one_zap_handler_per_context_released_with_the_last_server(keys):
    context = zmq.Context()
    try:
        first = Publisher(LOOPBACK, lossless=False, security=keys, context=context)
        second = Subscriber(LOOPBACK, bind=True, security=keys, context=context)
        assert ZAP_HANDLERS.running(context)
        first.close()
        first.close()  # idempotent: the lease is given back once
        assert ZAP_HANDLERS.running(context)
        second.close()
        assert not ZAP_HANDLERS.running(context)
    finally:
        context.term()


def test_a_failed_setup_gives_the_zap_handler_back(keys):
    context = zmq.Context()
    try:
        with Publisher(LOOPBACK, lossless=False, context=context) as taken:
            with pytest.raises(BusError, match="cannot bind publisher") as info:
                Publisher(taken.endpoint, lossless=False, security=keys, context=context)
            assert taken.endpoint in str(info.value)
        assert not ZAP_HANDLERS.running(context)
    finally:
        context.term()


def test_a_curve_server_without_its_zap_handler_admits_no_one(keys):
    # Without ZAP_ENFORCE_DOMAIN libzmq would admit any client that knows the server key.
    context = zmq.Context()
    raw = context.socket(zmq.PUB)
    try:
        apply_security(raw, keys, server=True)()  # the lease given back at once: no handler
        port = raw.bind_to_random_port("tcp://127.0.0.1")
        with Subscriber(
            f"tcp://127.0.0.1:{port}", ["force"], security=keys, context=context
        ) as sub:
            frames = [
                bytes(f)
                for f in encode(make_message("force", t_capture_s=0.0, t_s=[0.0], value_n=[1.0]))
            ]
            deadline = time.monotonic() + SILENCE_S
            while time.monotonic() < deadline:
                raw.send_multipart(frames)
                assert sub.recv(timeout_s=0.02) is None
    finally:
        raw.close(linger=0)
        context.term()


def test_from_settings_takes_the_limit_and_the_keys(keys):
    bus = BusSettings(keys_dir=str(keys.keys_dir), max_message_bytes=2048, heartbeat_s=0.25)
    with (
        Publisher.from_settings(bus, LOOPBACK, lossless=False, source="robot") as pub,
        Subscriber.from_settings(bus, pub.endpoint, ["force"]) as sub,
        Subscriber(pub.endpoint, ["force"]) as plain,
    ):
        assert (pub.max_bytes, pub.heartbeat_s, sub.max_bytes) == (2048, 0.25, 2048)
        assert sub._live().getsockopt(zmq.MAXMSGSIZE) == 2048 + CURVE_FRAME_OVERHEAD_BYTES
        assert delivered(pub, sub, within_s=HEARD_WITHIN_S) is not None
        assert _nothing_arrives(pub, plain)  # CURVE is on: a client without keys gets nothing
    with pytest.raises(BusSecurityError, match="10.0.0.2"):
        Subscriber.from_settings(BusSettings(command="tcp://10.0.0.2:5552"), "tcp://127.0.0.1:5550")


def test_a_connect_only_node_joins_an_existing_bus(tmp_path, keys):
    """The documented two-host setup: the operator host trusts the robot's server key,
    the robot host authorises the operator's client key."""
    listing = init_keys(tmp_path / "operator", server_cert=keys.keys_dir / "server.key")
    assert not listing.can_serve and listing.server_public_key == keys.server_public_key.decode()
    operator = BusSecurity.load(tmp_path / "operator")
    with pytest.raises(BusSecurityError, match="can connect but not bind"):
        Publisher(LOOPBACK, lossless=False, security=operator)
    authorize_key(keys.keys_dir, tmp_path / "operator" / "client.key", name="operator")
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub,
        Subscriber(pub.endpoint, ["force"], security=operator) as sub,
    ):
        pub.wait_for_subscriber("force", timeout_s=2.0)
        force(pub, 5)
        assert sub.recv(timeout_s=2.0).body["value_n"][0] == 5.0


def test_a_file_in_authorized_that_is_no_certificate_stops_the_server_naming_it(keys):
    # pyzmq's own loader only logs such a file, then its server admits no one
    junk = keys.authorized_dir / "junk.key"
    junk.write_text("garbage\n")
    for serve in (
        lambda: Publisher(LOOPBACK, lossless=False, security=keys),
        lambda: Subscriber(LOOPBACK, bind=True, security=keys),
    ):
        with pytest.raises(BusSecurityError) as info:
            serve()
        assert f"cannot read CURVE certificate {junk}" in str(info.value)
        assert "teleop keys add" in str(info.value)
    assert not ZAP_HANDLERS.running(zmq.Context.instance())
    with pytest.raises(BusSecurityError, match="junk.key"):  # `teleop keys list` says the same
        list_keys(keys.keys_dir)
    junk.unlink()
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub,
        Subscriber(pub.endpoint, ["force"], security=keys) as sub,
    ):
        assert delivered(pub, sub, within_s=HEARD_WITHIN_S) is not None


# --------------------------------------------------------------------------- key files


def _secrets(*dirs: Path) -> list[str]:
    return [
        line.split("=", 1)[1].strip().strip('"')
        for d in dirs
        for f in d.glob("*.key_secret")
        for line in f.read_text().splitlines()
        if line.strip().startswith("secret-key")
    ]


def test_init_writes_private_secret_files(tmp_path, keys):
    mode = lambda p: stat.S_IMODE(p.stat().st_mode)  # noqa: E731
    assert mode(keys.keys_dir) == 0o700
    assert mode(keys.keys_dir / "server.key_secret") == 0o600
    assert mode(keys.keys_dir / "client.key_secret") == 0o600
    assert sorted(p.name for p in keys.keys_dir.iterdir()) == [
        "authorized",
        "client.key",
        "client.key_secret",
        "server.key",
        "server.key_secret",
    ]
    assert [k.name for k in list_keys(keys.keys_dir).authorized] == ["client"]
    assert keys.client_secret_key.decode() not in repr(keys)
    with pytest.raises(BusSecurityError, match="already holds CURVE keys"):
        init_keys(keys.keys_dir)


def test_init_refuses_a_folder_holding_only_an_authorised_keys_folder_and_writes_nothing(tmp_path):
    keys_dir = tmp_path / "keys"
    (keys_dir / "authorized").mkdir(parents=True)
    with pytest.raises(BusSecurityError, match=r"already holds CURVE keys \(authorized\)"):
        init_keys(keys_dir)
    assert [p.name for p in keys_dir.iterdir()] == ["authorized"]  # no half-made pair left behind


def test_unsafe_or_damaged_keys_are_refused(tmp_path, keys, stranger):
    secret = keys.keys_dir / "client.key_secret"
    secret.chmod(0o644)
    with pytest.raises(BusSecurityError, match="chmod 600"):
        BusSecurity.load(keys.keys_dir)
    secret.chmod(0o600)
    (keys.keys_dir / "client.key").write_bytes((stranger.keys_dir / "client.key").read_bytes())
    with pytest.raises(BusSecurityError, match="does not belong"):
        BusSecurity.load(keys.keys_dir)
    with pytest.raises(BusSecurityError, match="holds a secret key"):
        authorize_key(keys.keys_dir, stranger.keys_dir / "client.key_secret")
    garbled = tmp_path / "garbled.key"
    garbled.write_text('curve\n    public-key = "not a key"\n')
    with pytest.raises(BusSecurityError, match="Z85"):
        authorize_key(stranger.keys_dir, garbled)


def test_key_names_cannot_leave_the_authorised_directory(keys, stranger):
    for name in ("../server", "..", "a/b", ".hidden", ""):
        with pytest.raises(BusSecurityError, match="key name"):
            revoke_key(keys.keys_dir, name)
        with pytest.raises(BusSecurityError, match="key name"):
            authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name=name)
    assert (keys.keys_dir / "server.key").exists()


def test_add_refuses_duplicates_and_revoke_names_the_known_keys(keys, stranger):
    with pytest.raises(BusSecurityError, match="already authorised"):  # name "client" is taken
        authorize_key(keys.keys_dir, stranger.keys_dir / "client.key")
    authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name="operator")
    with pytest.raises(BusSecurityError, match="already authorised .* as 'operator'"):
        authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name="operator2")
    with pytest.raises(BusSecurityError, match=r"authorised: client, operator"):
        revoke_key(keys.keys_dir, "nobody")


# --------------------------------------------------------------------------- the command


def _keys(capsys, *argv: str) -> tuple[int, str, str]:
    code = teleop.cli.main(["keys", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_keys_command_end_to_end(tmp_path, capsys):
    robot, operator = tmp_path / "robot", tmp_path / "operator"
    code, out, _ = _keys(capsys, "init", str(robot))
    assert code == 0 and "bus.keys_dir" in out
    code, out, _ = _keys(
        capsys, "init", str(operator), "--server-cert", str(robot / "server.key"), "--json"
    )
    assert code == 0 and json.loads(out.splitlines()[-1])["can_serve"] is False
    outputs = [out]
    for argv in (
        ("add", str(robot), str(operator / "client.key"), "--name", "operator"),
        ("list", str(robot)),
        ("list", str(robot), "--json"),
        ("revoke", str(robot), "operator", "--json"),
    ):
        code, out, err = _keys(capsys, *argv)
        assert code == 0 and "warning" not in err, err
        outputs.append(out)
    assert "authorised operator" in outputs[1] and "restart" in outputs[1]
    assert "operator" in outputs[2]
    listed = json.loads(outputs[3].splitlines()[-1])
    assert [k["name"] for k in listed["authorized"]] == ["client", "operator"]
    assert json.loads(outputs[4].splitlines()[-1])["name"] == "operator"
    assert [k.name for k in list_keys(robot).authorized] == ["client"]
    code, _, err = _keys(capsys, "revoke", str(robot), "client")
    assert code == 0 and "warning: 'client' is this directory's own client key" in err
    secrets = _secrets(robot, operator)
    assert len(secrets) == 3  # robot server + client, operator client
    assert not any(s in out for s in secrets for out in outputs)


def test_keys_json_names_the_action_and_list_says_whether_the_host_can_bind(tmp_path, capsys):
    server, laptop = tmp_path / "server", tmp_path / "laptop"
    code, out, _ = _keys(capsys, "init", str(server), "--json")
    assert code == 0 and json.loads(out.splitlines()[-1])["action"] == "init"
    assert _keys(capsys, "init", str(laptop), "--server-cert", str(server / "server.key"))[0] == 0
    assert "(bind and connect)" in _keys(capsys, "list", str(server))[1]
    assert "(connect only (no server secret key))" in _keys(capsys, "list", str(laptop))[1]
    listing = json.loads(_keys(capsys, "list", str(laptop), "--json")[1].splitlines()[-1])
    assert listing["action"] == "list" and listing["can_serve"] is False


def test_keys_without_an_action_is_a_usage_error_not_a_traceback(capsys):
    with pytest.raises(SystemExit) as exited:
        teleop.cli.main(["keys"])
    assert exited.value.code == 2 and "ACTION" in capsys.readouterr().err


def test_keys_command_errors_are_one_line(tmp_path):
    result = subprocess.run(
        [
            str(Path(sys.executable).parent / "teleop"),
            "keys",
            "revoke",
            str(tmp_path / "absent"),
            "x",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "does not exist" in lines[0] and "teleop keys init" in lines[0]


def test_a_keys_dir_that_is_a_file_is_called_a_file(tmp_path):
    (tmp_path / "settings.toml").write_text("")
    with pytest.raises(BusSecurityError, match="settings.toml is a file, not a directory: set bus.keys_dir"):
        BusSecurity.load(tmp_path / "settings.toml")


# --------------------------------------------------------------------------- size limits


def _zmtp_peer_greeting(socket_type: bytes) -> bytes:
    """ZMTP 3.0 greeting (NULL mechanism) and READY command, as a raw peer sends them."""
    greeting = (
        b"\xff" + b"\x00" * 8 + b"\x7f" + b"\x03\x00" + b"NULL".ljust(20, b"\x00") + b"\x00" * 32
    )
    ready = b"\x05READY" + b"\x0bSocket-Type" + struct.pack(">I", len(socket_type)) + socket_type
    return greeting + b"\x04" + bytes([len(ready)]) + ready


def _dropped_after_header(conn: socket.socket, claimed_bytes: int, *, within_s: float) -> bool:
    """Send only the length prefix of a ``claimed_bytes`` frame; True if the peer hangs up."""
    conn.sendall(b"\x02" + struct.pack(">Q", claimed_bytes))  # long, last frame
    conn.settimeout(0.05)
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            if not conn.recv(65536):
                return True
        except TimeoutError:
            continue
        except ConnectionResetError:
            return True
    return False


def test_an_oversize_frame_is_cut_off_before_allocation_and_the_subscriber_carries_on():
    max_bytes = 64 * 1024
    with (
        socket.create_server(("127.0.0.1", 0)) as listener,
        Publisher(LOOPBACK, lossless=True, source="robot") as good,
    ):
        port = listener.getsockname()[1]
        with Subscriber(
            [good.endpoint, f"tcp://127.0.0.1:{port}"], ["force"], max_bytes=max_bytes
        ) as sub:
            listener.settimeout(2.0)
            conn, _ = listener.accept()
            with conn:
                conn.sendall(_zmtp_peer_greeting(b"PUB"))
                # 1 GiB announced: ZMQ_MAXMSGSIZE drops the connection on the length prefix,
                # so the subscriber never allocates or waits for the body.
                assert _dropped_after_header(conn, 2**30, within_s=2.0)
            good.wait_for_subscriber("force", timeout_s=2.0)
            force(good, 9)
            got = sub.recv(timeout_s=2.0)
    assert got is not None and got.body["value_n"][0] == 9.0
    assert not sub.stats.refused  # it never reached the decoder


def test_without_the_limit_the_same_frame_would_be_awaited():
    """Control for the test above: a SUB socket without ZMQ_MAXMSGSIZE keeps the connection
    open waiting for the announced body, so the test above can fail."""
    context = zmq.Context.instance()
    with socket.create_server(("127.0.0.1", 0)) as listener, context.socket(zmq.SUB) as raw:
        raw.setsockopt(zmq.LINGER, 0)
        raw.connect(f"tcp://127.0.0.1:{listener.getsockname()[1]}")
        listener.settimeout(2.0)
        conn, _ = listener.accept()
        with conn:
            conn.sendall(_zmtp_peer_greeting(b"PUB"))
            assert not _dropped_after_header(conn, 64 * 1024 * 1024, within_s=0.5)


def test_a_publisher_cuts_off_an_oversize_frame_from_a_subscriber():
    with Publisher(LOOPBACK, lossless=False, source="robot") as pub:
        port = int(pub.endpoint.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=2.0) as conn:
            conn.sendall(_zmtp_peer_greeting(b"SUB"))
            assert _dropped_after_header(conn, CONTROL_FRAME_BYTES + 1, within_s=2.0)
        with Subscriber(pub.endpoint, ["force"]) as sub:
            pub.wait_for_subscriber("force", timeout_s=2.0)
            force(pub, 4)
            assert sub.recv(timeout_s=2.0) is not None


def test_curve_frames_up_to_the_limit_reach_the_decoder(keys):
    """ZMQ_MAXMSGSIZE counts CURVE's per-frame overhead: a frame of exactly max_bytes
    still reaches the decoder (refused there as a one-frame message, not cut off), one
    byte more is cut off by the transport and never reaches it."""
    max_bytes = 4096
    with contextlib.ExitStack() as stack:
        raw = zmq.Context.instance().socket(zmq.PUB)
        stack.callback(apply_security(raw, keys, server=True))
        stack.callback(raw.close, linger=0)  # runs first: the socket closes before the lease
        port = raw.bind_to_random_port("tcp://127.0.0.1")
        sub = stack.enter_context(
            Subscriber(f"tcp://127.0.0.1:{port}", ["f"], max_bytes=max_bytes, security=keys)
        )
        deadline = time.monotonic() + 3.0
        while not sub.stats.refused and time.monotonic() < deadline:  # until subscribed
            raw.send(b"f" * max_bytes)
            assert sub.recv(timeout_s=0.05) is None
        at_limit = dict(sub.stats.refused)
        raw.send(b"f" * (max_bytes + 1))
        assert sub.recv(timeout_s=0.3) is None
    assert set(at_limit) == {"frame_count"}
    assert dict(sub.stats.refused) == at_limit
