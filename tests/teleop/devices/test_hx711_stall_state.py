"""The stall state the HX711 reader thread writes is consistent whenever another thread reads it."""

from __future__ import annotations

import re
import threading

from teleop.devices import hx711
from teleop.devices.hx711 import SerialHx711
from teleop.settings import LoadCellSettings

RAIL = 2**23 - 1  # what a saturated HX711 reads
CHUNKS = [b"\n1000\n", b"hello\n", b"%d\n" % RAIL, b"1000\n", b"12a\n"]  # the first line is dropped: mid-line
# What the n-th skip since the last valid reading says, in the order the chunks above give them.
LAST_SKIP = {1: ["not a reading: b'hello'", "not a reading: b'12a'"], 2: [f"counts {RAIL}"]}


class Stepped(SerialHx711):
    """A cell whose reader thread, at every attribute it stores, asks why the cell is down, just before
    and just after the store: what a read in another thread would be told at that instant."""

    def __init__(self, settings: LoadCellSettings):
        self.said: list[str] = []
        self.fed = threading.Event()
        self._chunks = list(CHUNKS)
        super().__init__(settings)

    def __setattr__(self, name: str, value: object) -> None:
        reader = threading.current_thread().name.startswith("<SerialHx711")
        if reader:
            self._say()
        super().__setattr__(name, value)
        if reader:
            self._say()

    def _say(self) -> None:
        why = self._stalled()
        if why is not None:
            self.said.append(why)

    def _open_link(self) -> None:
        pass

    def _close_link(self) -> None:
        pass

    def _receive(self) -> bytes:
        if self._chunks:
            return self._chunks.pop(0)
        self.fed.set()
        self._stop.wait(0.01)
        return b""


def test_a_skip_is_never_seen_without_its_reason(monkeypatch):
    monkeypatch.setattr(hx711, "STALL_S", 0.0)  # down at once after a valid reading: every state says why
    cell = Stepped(LoadCellSettings(backend="serial", port="/dev/null", counts_per_n=1000.0, tare_counts=0))
    cell.connect()
    try:
        assert cell.fed.wait(10.0), "the reader did not take every chunk"
    finally:
        cell.close()
    skips = []
    for why in cell.said:
        if (found := re.search(r"(\d+) readings skipped \(the last: (.*)\)$", why)) is not None:
            skips.append((int(found[1]), found[2]))
        else:
            assert why.endswith("silent: nothing arrived"), why
    assert {n for n, _ in skips} == {1, 2}  # the hook saw the skips
    for n, last in skips:
        assert any(reason in last for reason in LAST_SKIP[n]), (n, last)

