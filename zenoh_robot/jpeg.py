"""JPEG bytes <-> uint8 arrays: the codec a JPEG ``Image`` and the image transports share.

Pillow (the [image] extra) is imported on first use, so nothing here costs an import until an
image path asks for it. ``jpeg_size`` reads a JPEG's dimensions from its frame header without
Pillow and without decoding: a receiver can refuse, in microseconds on the executor, a piece
whose JPEG does not fit the frame it claims to belong to.
"""
from __future__ import annotations

import io

import numpy as np

# Start-of-frame markers (baseline, progressive, lossless, arithmetic): the ones whose segment holds
# the dimensions. 0xC4 (DHT), 0xC8 (JPG) and 0xCC (DAC) share the range but are not frames.
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_SOS = 0xDA
_STANDALONE = frozenset([0x01, *range(0xD0, 0xD8)])   # TEM, RST0-7: markers without a length
_MAX_SEGMENTS = 64    # a real JPEG reaches its frame header within a handful; a crafted one must not loop


def encode_jpeg(arr: np.ndarray, quality: int) -> bytes:
    """One baseline JPEG of an HxW (grey) or HxWx3 (RGB) uint8 array."""
    from PIL import Image as PILImage

    buf = io.BytesIO()
    PILImage.fromarray(arr).save(buf, format="JPEG", quality=quality, optimize=False)
    return buf.getvalue()


def decode_jpeg(data: bytes, max_width: int | None = None, max_height: int | None = None) -> np.ndarray:
    """A JPEG as an array; ValueError, before decoding, if its header claims more pixels than
    ``max_width`` x ``max_height`` (a small packet must not inflate to gigabytes)."""
    from PIL import Image as PILImage

    with PILImage.open(io.BytesIO(data)) as im:
        w, h = im.size
        if (max_width is not None and w > max_width) or (max_height is not None and h > max_height):
            raise ValueError(f"JPEG of {w}x{h} does not fit {max_width}x{max_height}")
        return np.asarray(im)


def jpeg_size(data: bytes) -> tuple[int, int, int] | None:
    """(width, height, components) from the JPEG's frame header, or None if ``data`` does not
    start as a JPEG with one. Reads the markers only: nothing is decoded."""
    n = len(data)
    if n < 4 or data[0] != 0xFF or data[1] != 0xD8:
        return None
    i = 2
    for _ in range(_MAX_SEGMENTS):
        while i < n and data[i] == 0xFF and i + 1 < n and data[i + 1] == 0xFF:
            i += 1                                    # fill bytes before a marker
        if i + 4 > n or data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker in _STANDALONE:
            i += 2
            continue
        length = (data[i + 2] << 8) | data[i + 3]
        if marker in _SOF:
            if length < 8 or i + 10 > n:
                return None
            height = (data[i + 5] << 8) | data[i + 6]
            width = (data[i + 7] << 8) | data[i + 8]
            return width, height, data[i + 9]
        if marker == _SOS or length < 2:
            return None                               # image data before any frame header
        i += 2 + length
    return None
