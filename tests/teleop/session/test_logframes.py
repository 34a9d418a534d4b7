"""The log's frame container (:mod:`teleop.session.logframes`): a corrupt or hostile stored message is
refused as MessageRejected, which the reader counts and skips, never misread (an unknown flag taken for
"elided") nor a crash with another exception. The round trip and the short containers are in
test_recorder.py."""

from __future__ import annotations

import struct

import pytest

from teleop.errors import MessageRejected
from teleop.session.logframes import ELIDED, MAX_FRAMES, MIN_FRAMES, pack_frames, unpack_frames

FRAMES = [b"force", b"header-bytes", b"body", b"buffer-1"]


def _refused(data: bytes, **options) -> str:
    """The reason ``unpack_frames`` refuses ``data``."""
    with pytest.raises(MessageRejected) as caught:
        unpack_frames(data, **options)
    return caught.value.reason


def test_a_message_with_the_most_frames_allowed_reads_back_and_one_more_is_refused():
    frames = [b"topic", b"header", b"body", *(bytes([i]) * (i + 1) for i in range(MAX_FRAMES - MIN_FRAMES))]
    assert len(frames) == MAX_FRAMES
    assert [bytes(f) for f in unpack_frames(pack_frames(frames))] == frames
    assert _refused(pack_frames([*frames, b"one too many"])) == "frame_count"


@pytest.mark.parametrize("flag", [1 << 17, 1 << 31, (1 << 17) | ELIDED])
def test_an_unknown_flag_is_refused_not_read_as_elided(flag):
    # laid out as an elided container (its last frame's bytes left out), but flagged with another bit
    data = bytearray(pack_frames(FRAMES, elide_last=True))
    struct.pack_into("<I", data, 0, len(FRAMES) | flag)
    assert _refused(bytes(data), elided=FRAMES[-1]) == "corrupt"


@pytest.mark.parametrize("kept_bytes", [4, 8, 12])
def test_a_container_cut_inside_its_frame_lengths_is_refused_as_corrupt(kept_bytes):
    # the count says 4 frames; fewer than 4 lengths follow
    assert _refused(pack_frames(FRAMES)[:kept_bytes]) == "corrupt"


def test_bytes_after_the_last_frame_are_refused_as_corrupt():
    assert _refused(pack_frames(FRAMES) + b"\x00junk") == "corrupt"
    elided = pack_frames(FRAMES, elide_last=True)
    assert [bytes(f) for f in unpack_frames(elided, elided=FRAMES[-1])] == FRAMES
    assert _refused(elided + FRAMES[-1], elided=FRAMES[-1]) == "corrupt"  # the image bytes stored twice


@pytest.mark.parametrize("image", [FRAMES[-1][:-1], FRAMES[-1] + b"!", b""], ids=["shorter", "longer", "empty"])
def test_an_image_of_another_length_than_the_elided_frame_is_refused(image):
    assert _refused(pack_frames(FRAMES, elide_last=True), elided=image) == "corrupt"
