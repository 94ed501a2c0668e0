"""Strict PNG/JPEG decoding (pipeline.imagecodec) on images OpenCV itself wrote: whole images decode exactly as
OpenCV decodes them; every cut, a chunk whose CRC fails, a file that is not PNG/JPEG are named problems."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from pipeline.errors import InputDataError
from pipeline.imagecodec import decode_image, image_problem, jpeg_problem, png_problem, read_image_file

RNG = np.random.default_rng(7)
COLOUR = cv2.resize(RNG.integers(0, 256, (12, 16, 3), dtype=np.uint8), (64, 48), interpolation=cv2.INTER_LINEAR)
DEPTH = RNG.integers(0, 9000, (48, 64), dtype=np.uint16)


def encode(ext: str, img: np.ndarray, params=()) -> bytes:
    ok, buf = cv2.imencode(ext, img, list(params))
    assert ok
    return buf.tobytes()


IMAGES = {
    "png-colour": encode(".png", COLOUR),
    "png-depth16": encode(".png", DEPTH),
    "jpeg-baseline": encode(".jpg", COLOUR, [cv2.IMWRITE_JPEG_QUALITY, 90]),
    "jpeg-progressive": encode(".jpg", COLOUR, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
    "jpeg-restart-markers": encode(".jpg", COLOUR, [cv2.IMWRITE_JPEG_RST_INTERVAL, 1]),
}


@pytest.mark.parametrize("name", list(IMAGES))
def test_whole_images_pass_and_decode_as_opencv_does(name):
    data = IMAGES[name]
    assert image_problem(data) is None
    got = decode_image(data, cv2.IMREAD_UNCHANGED, what="colour", frame=0)
    assert np.array_equal(got, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED))


@pytest.mark.parametrize("name", list(IMAGES))
def test_every_cut_is_a_problem(name):
    """Cut at every byte (PNG) or every 7th (JPEG): each is named; OpenCV's imread would return some of them
    as partial images."""
    data = IMAGES[name]
    step = 1 if name.startswith("png") else 7
    for n in range(0, len(data) - 1, step):
        assert image_problem(data[:n]) is not None, n
    assert image_problem(data[:-1]) is not None


def test_png_crc_of_every_chunk_is_checked():
    data = bytearray(IMAGES["png-colour"])
    for at in (20, len(data) // 2, len(data) - 6):  # IHDR, IDAT, IEND
        bad = bytearray(data)
        bad[at] ^= 0x10
        assert "fails its CRC" in png_problem(bytes(bad)), at


def test_png_ancillary_chunk_with_a_bad_crc_is_refused():
    """libpng only warns about an ancillary chunk's CRC and decodes the image; zipon refuses the file."""
    data = IMAGES["png-colour"]
    body = b"tEXt" + b"Comment\x00hello"
    good = struct.pack(">I", 13) + body + struct.pack(">I", zlib.crc32(body))
    bad = good[:-1] + bytes([good[-1] ^ 1])
    assert png_problem(data[:33] + good + data[33:]) is None
    assert "'tEXt'" in png_problem(data[:33] + bad + data[33:])
    assert cv2.imdecode(np.frombuffer(data[:33] + bad + data[33:], np.uint8), cv2.IMREAD_UNCHANGED) is not None


def test_png_trailing_bytes_and_jpeg_trailing_bytes():
    """Bytes after PNG's IEND are refused (nothing writes them); bytes after JPEG's end-of-image marker are not
    image data (cameras append some) and the image decodes the same."""
    assert "after the IEND" in png_problem(IMAGES["png-colour"] + b"\x00")
    jpg = IMAGES["jpeg-baseline"]
    assert jpeg_problem(jpg + b"\x00\x00trailer") is None
    a = decode_image(jpg + b"\x00\x00trailer", cv2.IMREAD_COLOR, what="colour")
    assert np.array_equal(a, decode_image(jpg, cv2.IMREAD_COLOR, what="colour"))


def test_other_formats_are_refused():
    assert "not a PNG or JPEG" in image_problem(encode(".bmp", COLOUR))
    assert "not a PNG or JPEG" in image_problem(b"")


def test_read_image_file_names_file_and_frame(tmp_path):
    f = tmp_path / "frame-000004.color.jpg"
    f.write_bytes(IMAGES["jpeg-baseline"][: len(IMAGES["jpeg-baseline"]) * 4 // 10])
    with pytest.raises(InputDataError) as e:
        read_image_file(f, cv2.IMREAD_COLOR, frame=4, what="colour")
    assert str(e.value).startswith(f"file {f}; frame 4: colour image is incomplete or corrupt")
    assert "truncated" in str(e.value)
    assert cv2.imread(str(f), cv2.IMREAD_COLOR) is not None  # what the readers used to store: a partial image
    with pytest.raises(InputDataError, match="could not be read"):
        read_image_file(tmp_path / "absent.png", cv2.IMREAD_COLOR, frame=0, what="colour")


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def test_structural_problems_are_named():
    png = IMAGES["png-colour"]
    assert png_problem(b"\x89PNG\r\n\x1a\n" + _chunk(b"tEXt", b"a\x00b") + png[8:]) == "first chunk is 'tEXt', not IHDR"
    assert png_problem(png[:8] + struct.pack(">I", 0x80000000) + png[12:]).startswith("chunk 'IHDR' at byte 8 runs past")
    jpg = IMAGES["jpeg-baseline"]
    assert jpeg_problem(jpg[:2] + b"\x00" + jpg[3:]) == "byte 2: 0x00 where a marker was expected"
    assert jpeg_problem(jpg[:2] + b"\xff\x00" + jpg[2:]) == "byte 3: a stuffed 0xff00 outside entropy-coded data"
    assert "length 1" in jpeg_problem(jpg[:2] + b"\xff\xe0\x00\x01" + jpg[2:])
    assert jpeg_problem(jpg[:3]).startswith("ends at byte 3")


def test_a_whole_png_whose_pixels_do_not_decode_is_refused():
    """Every CRC right, the compressed pixel data garbage: libpng fails, and the error names the file."""
    png = IMAGES["png-colour"]
    ihdr_end = 8 + 12 + 13
    forged = png[:ihdr_end] + _chunk(b"IDAT", b"not zlib data at all") + _chunk(b"IEND", b"")
    assert png_problem(forged) is None
    with pytest.raises(InputDataError, match="could not be decoded") as e:
        decode_image(forged, cv2.IMREAD_UNCHANGED, what="depth", path="d.png", frame=3)
    assert str(e.value).startswith("file d.png; frame 3: depth image")
