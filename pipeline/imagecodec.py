"""Strict decoding of the PNG and JPEG frames raw logs carry, from files or from messages.

OpenCV decodes what it can: a JPEG cut short comes back as a partial image (libjpeg fills the rest
grey and only warns), a PNG whose ancillary chunk fails its CRC comes back with a warning. A frame like
that would be stored as if it were the camera's, so every image is checked for completeness before it
is decoded, and anything short of a whole file is an :class:`InputDataError` naming the file (or topic)
and the frame:

- PNG: the signature, then every chunk's length and CRC-32 (each chunk, critical or not), ``IHDR``
  first, ``IEND`` last, no bytes after it. zlib's own Adler-32 over the pixel data is checked by libpng.
- JPEG: the start-of-image marker, every marker segment's length, the entropy-coded data of every scan
  up to the end-of-image marker (a file without one is truncated). Bytes after the end-of-image marker
  are not image data and are ignored, as every decoder does. JPEG carries no checksum: a byte changed
  inside the entropy-coded data decodes to different pixels and cannot be detected by any reader.
- Anything else (BMP, TIFF, ...) is refused: the raw formats zipon reads store PNG or JPEG.
"""

from __future__ import annotations

import zlib

import cv2
import numpy as np

from pipeline.errors import InputDataError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8"


def png_problem(data: bytes) -> str | None:
    """What makes ``data`` an incomplete or corrupt PNG, or None when every chunk is whole and checks."""
    n, i = len(data), len(PNG_MAGIC)
    if not data.startswith(PNG_MAGIC):
        return "no PNG signature"
    view = memoryview(data)
    first = True
    while True:
        if i + 8 > n:
            return f"cut short at byte {n}: no IEND chunk (truncated)"
        length = int.from_bytes(data[i:i + 4], "big")
        kind = data[i + 4:i + 8]
        name = kind.decode("latin-1")
        end = i + 12 + length
        if length > 0x7FFFFFFF or end > n:
            return f"chunk {name!r} at byte {i} runs past the end of the file ({n} bytes; truncated)"
        if zlib.crc32(view[i + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            return f"chunk {name!r} at byte {i} fails its CRC"
        if first and kind != b"IHDR":
            return f"first chunk is {name!r}, not IHDR"
        first = False
        i = end
        if kind == b"IEND":
            return None if i == n else f"{n - i} bytes after the IEND chunk"


def jpeg_problem(data: bytes) -> str | None:
    """What makes ``data`` an incomplete JPEG (no end-of-image marker, a segment cut short), or None."""
    n = len(data)
    if not data.startswith(JPEG_MAGIC):
        return "no JPEG start-of-image marker"
    i = 2
    while True:
        if i >= n:
            return f"ends at byte {n} before its end-of-image marker (truncated)"
        if data[i] != 0xFF:
            return f"byte {i}: 0x{data[i]:02x} where a marker was expected"
        while i < n and data[i] == 0xFF:  # fill bytes
            i += 1
        if i >= n:
            return f"ends at byte {n} before its end-of-image marker (truncated)"
        marker = data[i]
        i += 1
        if marker == 0xD9:
            return None
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # markers without a length
            continue
        if marker == 0x00:
            return f"byte {i - 1}: a stuffed 0xff00 outside entropy-coded data"
        if i + 2 > n:
            return f"ends at byte {n} inside marker 0xff{marker:02x} (truncated)"
        length = int.from_bytes(data[i:i + 2], "big")
        if length < 2 or i + length > n:
            return f"marker 0xff{marker:02x} at byte {i - 2} has length {length}, past the end ({n} bytes; truncated)"
        i += length
        if marker == 0xDA:  # start of scan: entropy-coded data runs to the next marker that is not RSTn or a stuffed ff
            while True:
                j = data.find(b"\xff", i)
                if j < 0 or j + 1 >= n:
                    return f"ends at byte {n} inside entropy-coded data, before its end-of-image marker (truncated)"
                nxt = data[j + 1]
                if nxt == 0x00 or 0xD0 <= nxt <= 0xD7:
                    i = j + 2
                elif nxt == 0xFF:
                    i = j + 1
                else:
                    i = j
                    break


def image_problem(data: bytes) -> str | None:
    """The completeness check of the format ``data`` starts with (PNG or JPEG); other formats are a problem."""
    if data.startswith(PNG_MAGIC):
        return png_problem(data)
    if data.startswith(JPEG_MAGIC):
        return jpeg_problem(data)
    return f"not a PNG or JPEG (starts with {data[:8]!r})"


def decode_image(data: bytes, flags: int, *, what: str, **where) -> np.ndarray:
    """Decode a whole PNG/JPEG (OpenCV's channel order, as ``cv2.imdecode``); an incomplete or undecodable
    one raises :class:`InputDataError` with ``where`` (path, topic, field, frame)."""
    problem = image_problem(data)
    if problem is not None:
        raise InputDataError(f"{what} image is incomplete or corrupt: {problem}", **where,
                             expected="a whole PNG or JPEG image")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if img is None:
        raise InputDataError(f"{what} image could not be decoded", **where, expected="a PNG or JPEG image")
    return img


def read_image_file(path, flags: int, *, frame: int | None, what: str) -> np.ndarray:
    """Read and strictly decode one image file; unreadable files raise :class:`InputDataError`."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as err:
        raise InputDataError(f"{what} image could not be read ({err.strerror or err})", path=path, frame=frame,
                             expected="a readable PNG/JPEG file") from None
    return decode_image(data, flags, what=what, path=path, frame=frame)
