"""A service's JSON-lines report on a full disk: the reporting stops, the service does not."""

from __future__ import annotations

import errno
import json
import logging

from teleop.live import JsonLines


def _full() -> OSError:
    return OSError(errno.ENOSPC, "No space left on device")


class _FillingDisk:
    """The report file as the disk fills: half a line gets written, then the disk is full."""

    def __init__(self, file):
        self.file = file
        self.writes = 0

    def write(self, text):
        self.writes += 1
        self.file.write(text[: len(text) // 2])
        self.file.flush()
        raise _full()

    def flush(self):
        raise _full()

    def close(self):
        self.file.close()
        raise _full()


def test_a_report_on_a_full_disk_stops_reporting_with_one_error_and_the_service_carries_on(tmp_path, caplog):
    path = tmp_path / "estimator.jsonl"
    report = JsonLines(path)
    report.write({"grasp_id": "g1"})  # before the disk filled
    disk = report._file = _FillingDisk(report._file)
    with caplog.at_level(logging.ERROR, logger="teleop.live"):
        report.write({"grasp_id": "g2"})
        report.write({"grasp_id": "g3"})
        report.close()
        report.close()
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1, errors
    assert str(path) in errors[0] and "No space left on device" in errors[0] and "carries on" in errors[0]
    assert disk.writes == 1  # g3 was not tried: the file was dropped after g2
    # g1 is kept whole, and a later run's appended record starts on a line of its own, after g2's half
    # (not cut back: another writer may have appended meanwhile).
    lines = path.read_text().splitlines()
    assert json.loads(lines[0]) == {"grasp_id": "g1"} and len(lines) == 2
    with JsonLines(path) as later:
        later.write({"grasp_id": "g4"})
    assert path.read_text().splitlines() == [*lines, '{"grasp_id": "g4"}']


def test_another_writers_records_are_never_cut(tmp_path):
    path = tmp_path / "shared.jsonl"
    ours = JsonLines(path)
    ours.write({"grasp_id": "g1"})
    with JsonLines(path) as theirs:  # a second service given the same report
        theirs.write({"grasp_id": "t1"})
    ours._file = _FillingDisk(ours._file)
    ours.write({"grasp_id": "g2"})
    assert path.read_text().startswith('{"grasp_id": "g1"}\n{"grasp_id": "t1"}\n')


def test_a_report_to_a_pipe_is_written_though_a_pipe_cannot_tell_its_position(tmp_path):
    # A pipe cannot tell its position: writing to one must not fail on that.
    report = JsonLines(None)
    written = []

    class _Pipe:
        def seekable(self):
            return False

        def tell(self):
            raise OSError(errno.ESPIPE, "Illegal seek")

        def write(self, text):
            written.append(text)

        def flush(self):
            pass

        def close(self):
            pass

    report._file = _Pipe()
    report.write({"grasp_id": "g1"})
    report.close()
    assert written == ['{"grasp_id": "g1"}\n']
