"""The two-host key setup that ``teleop keys --help`` prints, run as written."""

from __future__ import annotations

import contextlib
import shlex
import shutil
import subprocess

from support.bus import HEARD_WITHIN_S, delivered

from teleop.bus import Publisher, Subscriber
from teleop.bus.keys_cli import SETUP
from teleop.bus.security import BusSecurity, serving_keys
from teleop.cli import main


def _two_host_commands() -> list[list[str]]:
    section = SETUP.split("two hosts", 1)[1].split("\n\n", 1)[0]
    return [shlex.split(line.split("#", 1)[0]) for line in section.splitlines()
            if line.strip().startswith(("teleop ", "install "))]


def test_the_two_host_setup_gives_both_hosts_keys_that_bind_and_admit_each_other(tmp_path):
    robot, operator, carried = tmp_path / "R", tmp_path / "O", tmp_path / "carried"
    carried.mkdir()
    paths = {"/etc/teleop/keys": robot, "~/keys": operator, "~/keys/": operator,
             "server.key": carried / "server.key", "server.key_secret": carried / "server.key_secret",
             "r-client.key": carried / "r-client.key", "o-client.key": carried / "o-client.key"}
    commands = _two_host_commands()
    assert [c[:3] for c in commands if c[0] == "teleop"] == [["teleop", "keys", "init"]] * 2 + [["teleop", "keys", "add"]] * 2
    for command in commands:
        if command[1:3] == ["keys", "init"] and "--server-cert" not in command:  # R made the pair: carry it over
            assert main([*command[1:3], *(str(paths.get(a, a)) for a in command[3:])]) == 0
            for name in ("server.key", "server.key_secret"):
                shutil.copy2(robot / name, carried / name)
            shutil.copy2(robot / "client.key", carried / "r-client.key")
        elif command[0] == "install":
            subprocess.run([str(paths.get(a, a)) for a in command], check=True)
        else:
            if command[1:3] == ["keys", "add"] and not (carried / "o-client.key").exists():
                shutil.copy2(operator / "client.key", carried / "o-client.key")
            assert main([str(paths.get(a, a)) for a in command[1:]]) == 0
    r_keys, o_keys = BusSecurity.load(robot), BusSecurity.load(operator)
    assert serving_keys(r_keys) and serving_keys(o_keys)  # both hosts bind
    # each host's server admits the other host's client (loopback runs CURVE when keys are given)
    # (both at once: the context's one ZAP handler, restarted at once, may find its address still taken)
    with contextlib.ExitStack() as stack:
        for server, client in ((r_keys, o_keys), (o_keys, r_keys)):
            publisher = stack.enter_context(Publisher("tcp://127.0.0.1:*", lossless=False, security=server))
            subscriber = stack.enter_context(Subscriber(publisher.endpoint, ("force",), security=client))
            assert delivered(publisher, subscriber, within_s=HEARD_WITHIN_S) is not None
