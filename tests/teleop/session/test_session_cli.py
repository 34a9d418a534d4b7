"""The replay, export and recover commands: JSON summaries, files written, one-line errors."""

from __future__ import annotations

import json
import socket

import teleop.cli
from teleop.bus import Subscriber
from teleop.record import read_record


def _json_tail(capsys) -> dict:
    captured = capsys.readouterr()
    return json.loads(captured.out.strip().splitlines()[-1])


def test_export_command_writes_the_records(recorded, tmp_path, capsys):
    out = tmp_path / "records"
    assert teleop.cli.main(["export", str(recorded.path), "--out", str(out), "--json"]) == 0
    summary = _json_tail(capsys)
    assert summary["exported"] == 2 and [s["grasp_id"] for s in summary["skipped"]] == ["g2"]
    session = summary["session_id"]  # the log's start time: two sessions never share a name
    assert sorted(p.name for p in out.glob("*.grasp")) == [f"session_{session}_g0.grasp", f"session_{session}_g1.grasp"]
    assert read_record(summary["records"][0]).label.object_name == "stress_ball"


def test_recover_command_reports_what_it_salvaged(recorded, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.path.read_bytes()[: recorded.path.stat().st_size // 2])
    assert (
        teleop.cli.main(["recover", str(cut), "--out", str(tmp_path / "fixed.mcap"), "--json"]) == 0
    )
    report = _json_tail(capsys)
    assert not report["complete"] and 0 < report["messages"] < len(recorded.sent)
    assert report["damage"] and report["salvaged_bytes"] <= report["source_bytes"]


def test_replay_command_sends_every_message(recorded, capsys):
    frames = sum(m.type == "frame" for m in recorded.sent)
    with socket.socket() as probe:  # a free port for the command to bind
        probe.bind(("127.0.0.1", 0))
        endpoint = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    with Subscriber(endpoint, ["frame"]) as sub:
        code = teleop.cli.main(
            [
                "replay",
                str(recorded.path),
                "--endpoint",
                endpoint,
                "--as-fast-as-possible",
                "--topics",
                "frame",
                "--linger-s",
                "0.3",
                "--json",
            ]
        )
        got = []
        while len(got) < frames and (message := sub.recv(timeout_s=1.0)) is not None:
            got.append(message)
    assert code == 0
    summary = _json_tail(capsys)
    assert summary["sent"] == frames == len(got) and summary["endpoint"] == endpoint


def test_a_replay_that_matches_nothing_fails_and_names_the_logs_publishers(recorded, capsys):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        endpoint = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    code = teleop.cli.main(["replay", str(recorded.path), "--endpoint", endpoint, "--as-fast-as-possible",
                            "--recorded-from", "robto", "--linger-s", "0", "--wait-subscriber-s", "0"])  # robot, mistyped
    err = capsys.readouterr().err
    assert code == 1 and "nothing replayed" in err and " from robot)" in err, err
    assert teleop.cli.main(["replay", str(recorded.path), "--wait-subscriber-s", "nan"]) == 2
    assert "--wait-subscriber-s nan: expected a number >= 0" in capsys.readouterr().err


def test_user_mistakes_are_one_line_errors(recorded, tmp_path, capsys):
    assert teleop.cli.main(["recover", str(recorded.path), "--out", str(recorded.path)]) == 2
    assert "is the log being recovered" in capsys.readouterr().err
    assert teleop.cli.main(["export", str(tmp_path / "absent.mcap"), "--out", str(tmp_path)]) == 2
    assert "cannot read session log" in capsys.readouterr().err
    assert teleop.cli.main(["replay", str(recorded.path), "--speed", "-1"]) == 2
    assert "--speed -1" in capsys.readouterr().err


def test_record_refuses_a_catalogue_that_does_not_load_before_recording(tmp_path, capsys):
    # It recorded with rc 0; only `teleop export` failed later, naming a temporary file.
    catalogue = tmp_path / "objects.toml"
    catalogue.write_text("[[objects]\nname = ", encoding="utf-8")
    out = tmp_path / "session.mcap"
    code = teleop.cli.main(["record", "--out", str(out), "--duration-s", "0.2", "--objects", str(catalogue),
                            "--endpoint", "tcp://127.0.0.1:1"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert f"teleop record: error: --objects: {catalogue}: not valid TOML" in err


def _free_endpoint() -> str:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{probe.getsockname()[1]}"


def test_a_replay_nobody_listens_to_names_wait_subscriber_s_and_how_to_replay_anyway(recorded, capsys):
    endpoint = _free_endpoint()
    code = teleop.cli.main(["replay", str(recorded.path), "--endpoint", endpoint, "--wait-subscriber-s", "0.2",
                            "--linger-s", "0", "--json"])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err == (f"teleop replay: error: --wait-subscriber-s 0.2: no subscriber connected to {endpoint} within "
                   "0.2 s; start one, or pass --wait-subscriber-s 0 to replay to nobody\n")


def test_replay_help_says_no_subscriber_is_an_error_and_an_endpoint_in_use_names_endpoint(recorded, capsys):
    import argparse

    from teleop.session.replay_cli import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    helptext = " ".join(parser.format_help().split())
    assert "none within S seconds is an error" in helptext
    endpoint = _free_endpoint()
    with socket.socket() as holder:  # the port is taken by another process's socket
        holder.bind(("127.0.0.1", int(endpoint.rsplit(":", 1)[1])))
        holder.listen()
        code = teleop.cli.main(["replay", str(recorded.path), "--endpoint", endpoint, "--wait-subscriber-s", "0",
                                "--linger-s", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "Address already in use" in err and "--endpoint" in err, err
