"""decode_image against images whose header declares another size than expected."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

import teleop.grasp_data
from teleop.grasp_data import decode_image

SHAPE = (48, 64)  # rows, cols


def _image() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 255, (*SHAPE, 3), dtype=np.uint8)


def _jpeg_declaring(cols: int, rows: int) -> bytes:
    data = bytearray(cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5:sof + 9] = rows.to_bytes(2, "big") + cols.to_bytes(2, "big")
    return bytes(data)


def _png_declaring(cols: int, rows: int) -> bytes:
    data = bytearray(cv2.imencode(".png", np.zeros((16, 16, 3), np.uint8))[1].tobytes())
    ihdr = data.find(b"IHDR")  # its length before it, its CRC after its 13 bytes
    data[ihdr + 4:ihdr + 12] = struct.pack(">II", cols, rows)
    data[ihdr + 17:ihdr + 21] = struct.pack(">I", zlib.crc32(bytes(data[ihdr:ihdr + 17])))
    return bytes(data)


@pytest.fixture
def no_decoding(monkeypatch):
    def refuse(*_args):
        raise AssertionError("decoded")

    monkeypatch.setattr(teleop.grasp_data.cv2, "imdecode", refuse)


@pytest.mark.parametrize("make", [_jpeg_declaring, _png_declaring])
def test_an_image_declaring_another_size_is_refused_before_decoding(make, no_decoding):
    with pytest.raises(ValueError, match="image declares 9000x8000 px, expected 64x48 px: refused before decoding"):
        decode_image(make(9000, 8000), reduce=2, shape=SHAPE)


@pytest.mark.parametrize("make", [_jpeg_declaring, _png_declaring])
def test_an_image_declaring_gigapixels_is_refused_before_decoding(make, no_decoding):
    with pytest.raises(ValueError, match=r"refused before decoding, expected 64x48 px: Image size \(900000000 pixels\)"):
        decode_image(make(30000, 30000), reduce=2, shape=SHAPE)


@pytest.mark.parametrize("extension", [".jpg", ".png"])
@pytest.mark.parametrize("reduce", [1, 2, 16])
def test_an_image_of_the_expected_size_decodes_as_without_the_check(extension, reduce):
    data = cv2.imencode(extension, _image())[1]
    np.testing.assert_array_equal(decode_image(data, reduce=reduce, shape=SHAPE), decode_image(data, reduce=reduce))


def test_bytes_without_an_image_header_do_not_decode():
    assert decode_image(b"not an image", shape=SHAPE) is None
    assert decode_image(cv2.imencode(".jpg", _image())[1].tobytes()[:20], shape=SHAPE) is None
