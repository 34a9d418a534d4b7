"""A grasp's arrays in memory: what Samples, FrameStream, Label, reduce_image and decode_image accept and
give back, as a mutation audit found them untested."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from teleop.errors import RecordError
from teleop.grasp_data import FrameStream, Label, Samples, decode_image, reduce_image
from tests.teleop.test_record import make_record

IMAGE = np.random.default_rng(5).integers(0, 256, (24, 32, 3), dtype=np.uint8)


# --------------------------------------------------------------------------- reduce_image / decode_image


@pytest.mark.parametrize("reduce", [True, 0, -2, 2.0, 3, 5])
def test_a_reduction_that_is_not_a_whole_divisor_of_both_sides_is_refused(reduce):
    with pytest.raises(ValueError, match=f"reduce {reduce!r}: expected a whole number >= 1 dividing both sides "
                                         "of a 24 x 32 px image"):
        reduce_image(IMAGE, reduce)


def test_a_reduction_averages_blocks_and_keeps_rows_and_columns_apart():
    image = np.zeros((4, 6, 3), np.uint8)
    image[1, 1] = 8  # one pixel of the top-left 2 x 2 block
    reduced = reduce_image(image, 2)
    assert reduced.shape == (2, 3, 3) and reduced.dtype == np.uint8
    assert reduced[0, 0].tolist() == [2, 2, 2] and reduced.sum() == 6


@pytest.mark.parametrize("extension", [".jpg", ".png"])
@pytest.mark.parametrize("reduce", [1, 2, 4, 8])
def test_decoding_reduced_gives_an_image_that_many_times_smaller(extension, reduce):
    data = cv2.imencode(extension, IMAGE)[1].tobytes()
    image = decode_image(data, reduce=reduce, shape=IMAGE.shape[:2])
    assert image.shape == (24 // reduce, 32 // reduce, 3) and image.dtype == np.uint8


def test_a_png_decoded_at_half_size_is_the_block_average():
    data = cv2.imencode(".png", IMAGE)[1].tobytes()
    assert np.abs(decode_image(data, reduce=2).astype(int) - reduce_image(IMAGE, 2).astype(int)).max() <= 1


def test_an_image_declaring_the_right_width_but_another_height_is_refused():
    data = cv2.imencode(".png", IMAGE)[1].tobytes()
    with pytest.raises(ValueError, match="image declares 32x24 px, expected 32x48 px"):
        decode_image(data, shape=(48, 32))


def test_an_image_of_another_format_is_not_decoded_when_its_size_is_checked():
    """A BMP (which OpenCV decodes) has no JPEG or PNG header to check its size in: it is not decoded."""
    data = cv2.imencode(".bmp", IMAGE)[1].tobytes()
    assert decode_image(data) is not None
    assert decode_image(data, shape=IMAGE.shape[:2]) is None


def test_empty_bytes_do_not_decode():
    assert decode_image(b"") is None


# --------------------------------------------------------------------------- Samples


@pytest.mark.parametrize(("t_s", "value"), [([0.0, 1.0], [1.0]), ([[0.0], [1.0]], [[1.0], [2.0]]), (0.0, 1.0)])
def test_samples_must_be_1d_of_one_length(t_s, value):
    with pytest.raises(ValueError, match="Samples: t_s and value must be 1-D of one length"):
        Samples(t_s, value)


def test_samples_are_float64():
    samples = Samples([0, 1], np.array([1, 2], np.float32))
    assert samples.t_s.dtype == samples.value.dtype == np.float64 and len(samples) == 2


# --------------------------------------------------------------------------- FrameStream


def test_a_frame_stream_needs_one_timestamp_per_frame():
    data = cv2.imencode(".png", IMAGE)[1].tobytes()
    with pytest.raises(ValueError, match="FrameStream 'left': 1 frames but t_s has shape"):
        FrameStream("left", [0.0, 0.1], (data,))


def test_a_frame_stream_keeps_its_own_copy_of_the_frames_bytes():
    data = bytearray(cv2.imencode(".png", IMAGE)[1].tobytes())
    stream = FrameStream("left", [0.0], [data])
    data[:] = b"changed later"
    assert type(stream.encoded) is tuple and type(stream.encoded[0]) is bytes
    np.testing.assert_array_equal(stream.frame(0), IMAGE)

def test_a_frame_stream_of_an_unknown_encoding_is_refused():
    with pytest.raises(ValueError, match="FrameStream 'left': encoding 'gif' is not one of"):
        FrameStream("left", [], (), encoding="gif")
    with pytest.raises(ValueError, match="encoding 'gif' is not one of"):
        FrameStream.from_frames("left", [0.0], [IMAGE], encoding="gif")


@pytest.mark.parametrize("frame", [IMAGE.astype(np.uint16), IMAGE.astype(np.float32), IMAGE[..., :2],
                                   np.dstack([IMAGE, IMAGE[..., :1]]), IMAGE[..., 0]])
def test_only_uint8_bgr_frames_are_encoded(frame):
    with pytest.raises(ValueError, match="frame 0 of finger 'left': expected uint8 H x W x 3"):
        FrameStream.from_frames("left", [0.0], [frame])


def test_jpeg_frames_are_encoded_at_the_quality_asked_for():
    stream = FrameStream.from_frames("left", [0.0], [IMAGE], encoding="jpeg", jpeg_quality=95)
    assert stream.encoded[0] == cv2.imencode(".jpg", IMAGE, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def test_frames_decode_by_index_and_reduced():
    images = np.stack([IMAGE, IMAGE[::-1], IMAGE[:, ::-1]])
    stream = FrameStream.from_frames("left", [0.0, 0.1, 0.2], images)
    np.testing.assert_array_equal(stream.frames([2, 0]), images[[2, 0]])
    assert stream.frame(1, reduce=4).shape == (6, 8, 3) and stream.frames(reduce=2).shape == (3, 12, 16, 3)


def test_no_frames_decode_to_an_empty_array_of_the_reduced_size():
    stream = FrameStream("left", [], (), shape=(24, 32, 3))
    assert stream.frames(reduce=2).shape == (0, 12, 16, 3)


def test_a_frame_that_does_not_decode_is_a_record_error_naming_it():
    stream = FrameStream("left", [0.0], (b"not a png",))
    with pytest.raises(RecordError, match="finger 'left' frame 0: png data does not decode"):
        stream.frame(0)


# --------------------------------------------------------------------------- Label


@pytest.mark.parametrize("modulus", [0.0, -1.0, float("inf"), float("nan")])
def test_a_label_modulus_must_be_finite_and_positive(modulus):
    with pytest.raises(ValueError, match="modulus_pa must be finite and > 0"):
        Label("duck", modulus)


# --------------------------------------------------------------------------- GraspRecord


def test_a_records_sensor_and_frames_are_looked_up_by_finger():
    record = make_record("png")
    for finger in ("left", "right"):
        assert record.sensor(finger).finger == record.stream(finger).finger == finger
    with pytest.raises(KeyError, match="no frames from finger 'thumb'"):
        record.stream("thumb")
    with pytest.raises(KeyError, match="no sensor on finger 'thumb'"):
        record.sensor("thumb")
