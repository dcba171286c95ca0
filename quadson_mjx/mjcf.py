"""Text helpers shared by the robots' MJCF generators: deterministic number formatting and a
deterministic PNG encoder, so that regenerated model files are byte-identical to the committed ones."""

from __future__ import annotations

import struct
import zlib

import numpy as np


def num(x: float) -> str:
    """Deterministic short float formatting for the MJCF (9 significant digits, no "-0")."""
    s = f"{float(x):.9g}"
    return "0" if s == "-0" else s


def vec(xs) -> str:
    """Space-separated `num` of every element of xs (flattened), as MJCF attribute text."""
    return " ".join(num(x) for x in np.ravel(xs))


def png_gray8(img: np.ndarray) -> bytes:
    """Minimal deterministic 8-bit grayscale PNG encoder (no timestamps, fixed zlib level).

    img: (rows, cols) uint8 -> the PNG file's bytes."""

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    h, w = img.shape
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(raw, 9))
        + chunk(b"IEND", b"")
    )
