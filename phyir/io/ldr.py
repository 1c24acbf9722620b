"""Low-dynamic-range images: PNG (8/16-bit) and JPEG, sRGB-decoded to linear float32.

8-bit images go through Pillow.  Pillow truncates 16-bit RGB(A) PNGs to 8 bits, so 16-bit PNGs are
decoded and encoded here with zlib and numpy (non-interlaced only).  Alpha is dropped, grayscale is
replicated to RGB, and the pixel values are taken as sRGB-encoded (gAMA/iCCP chunks are ignored).
"""

from __future__ import annotations

import os
import struct
import warnings
import zlib
from dataclasses import dataclass

import numpy as np

from phyir.color import srgb_to_linear
from phyir.errors import InputError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8\xff"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> samples per pixel


@dataclass
class LdrInfo:
    format: str  # "PNG" or "JPEG"
    height: int
    width: int
    bits: int  # bits per sample
    mode: str  # e.g. "RGB", "RGBA", "L", "P"


def read_info(path: str | os.PathLike) -> LdrInfo:
    """Size and sample format from the file header, without decoding the pixels."""
    p = os.fspath(path)
    with open(p, "rb") as f:
        head = f.read(33)
    if head.startswith(PNG_MAGIC):
        if len(head) < 33 or head[12:16] != b"IHDR":
            raise InputError(p, "corrupt or truncated PNG (no IHDR chunk)")
        W, H, bits, ctype, _comp, _filt, interlace = struct.unpack(">IIBBBBB", head[16:29])
        if ctype not in _PNG_CHANNELS:
            raise InputError(p, f"corrupt PNG (unknown colour type {ctype})")
        if bits not in (8, 16):
            raise InputError(p, f"unsupported bit depth: {bits}-bit PNG (8 or 16 bits per sample)")
        if bits == 16 and ctype == 3:
            raise InputError(p, "corrupt PNG (16-bit palette images don't exist)")
        if bits == 16 and interlace:
            raise InputError(p, "unsupported: interlaced 16-bit PNG (re-save without interlacing)")
        mode = {0: "L", 2: "RGB", 3: "P", 4: "LA", 6: "RGBA"}[ctype]
        return LdrInfo("PNG", H, W, bits, mode)
    from PIL import Image

    try:
        with Image.open(p) as im:
            return LdrInfo(im.format or "?", im.height, im.width, 8, im.mode)
    except Exception as e:
        raise InputError(p, f"not a readable image ({_one_line(e)})") from None


def read_pixels(path: str | os.PathLike, info: LdrInfo) -> np.ndarray:
    """Decode to linear float32 [H, W, 3] (sRGB decoded, alpha dropped, gray replicated)."""
    p = os.fspath(path)
    if info.format == "PNG" and info.bits == 16:
        samples = _read_png16(p, info)  # [H, W, C] uint16
        x = samples.astype(np.float32) / 65535.0
    else:
        x = _read_pillow(p).astype(np.float32) / 255.0
    if x.shape[2] in (2, 4):  # drop alpha
        x = x[:, :, :-1]
    if x.shape[2] == 1:
        x = np.repeat(x, 3, axis=2)
    return srgb_to_linear(x)


def _read_pillow(p: str) -> np.ndarray:
    from PIL import Image

    try:
        with warnings.catch_warnings():
            # the caller has already checked the size against PhyIR's own limits
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as im:
                if im.mode in ("P", "PA"):
                    im = im.convert("RGBA" if "transparency" in im.info or im.mode == "PA" else "RGB")
                elif im.mode == "CMYK" or im.mode == "YCbCr":
                    im = im.convert("RGB")
                elif im.mode == "1":
                    raise InputError(p, "unsupported bit depth: 1-bit image")
                elif im.mode not in ("L", "LA", "RGB", "RGBA"):
                    raise InputError(p, f"unsupported bit depth or pixel format: Pillow mode {im.mode}")
                a = np.asarray(im)
    except InputError:
        raise
    except Exception as e:  # Pillow raises OSError/SyntaxError/ValueError/... for damaged files
        raise InputError(p, f"corrupt or truncated image ({_one_line(e)})") from None
    return a[:, :, None] if a.ndim == 2 else a


def _one_line(e: BaseException) -> str:
    return (str(e).splitlines() or [type(e).__name__])[0]


# ---------------------------------------------------------------------------------------------
# 16-bit PNG


def _read_png16(p: str, info: LdrInfo) -> np.ndarray:
    with open(p, "rb") as f:
        data = f.read()
    pos, idat = 8, []
    ctype = {"L": 0, "RGB": 2, "LA": 4, "RGBA": 6}[info.mode]
    while True:
        if pos + 8 > len(data):
            raise InputError(p, "truncated PNG (file ends before the IEND chunk)")
        n, typ = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        crc = data[pos + 8 + n : pos + 12 + n]
        if len(body) != n or len(crc) != 4:
            raise InputError(p, f"truncated PNG (inside the {typ.decode('latin-1')} chunk)")
        if struct.unpack(">I", crc)[0] != zlib.crc32(typ + body):
            raise InputError(p, f"corrupt PNG (CRC mismatch in the {typ.decode('latin-1')} chunk)")
        if typ == b"IDAT":
            idat.append(body)
        elif typ == b"IEND":
            break
        pos += 12 + n
    C = _PNG_CHANNELS[ctype]
    bpp = 2 * C
    stride = info.width * bpp
    try:
        raw = zlib.decompress(b"".join(idat))
    except zlib.error as e:
        raise InputError(p, f"corrupt PNG image data ({e})") from None
    if len(raw) != info.height * (stride + 1):
        raise InputError(p, f"corrupt or truncated PNG image data ({len(raw)} bytes, "
                            f"expected {info.height * (stride + 1)})")
    rows = np.frombuffer(raw, np.uint8).reshape(info.height, stride + 1)
    out = _unfilter(rows, bpp, p)
    return out.view(">u2").reshape(info.height, info.width, C).astype(np.uint16)


def _unfilter(rows: np.ndarray, bpp: int, p: str) -> np.ndarray:
    """Undo PNG's per-row filters.  None/Sub/Up are vectorised; Average/Paeth loop in Python."""
    H, stride = rows.shape[0], rows.shape[1] - 1
    out = np.zeros((H, stride), np.uint8)
    prev = np.zeros(stride, np.uint8)
    for i in range(H):
        ft, line = rows[i, 0], rows[i, 1:]
        if ft == 0:
            cur = line.copy()
        elif ft == 1:
            cur = (line.reshape(-1, bpp).cumsum(axis=0, dtype=np.uint64) & 0xFF).astype(np.uint8)
            cur = cur.reshape(-1)
        elif ft == 2:
            cur = line + prev  # uint8 arithmetic wraps mod 256
        elif ft in (3, 4):
            cur = np.frombuffer(_unfilter_slow(bytes(line), bytes(prev), bpp, ft), np.uint8)
        else:
            raise InputError(p, f"corrupt PNG (unknown filter type {ft} in row {i})")
        out[i] = cur
        prev = out[i]
    return out


def _unfilter_slow(line: bytes, prev: bytes, bpp: int, ft: int) -> bytes:
    cur = bytearray(line)
    for x in range(len(cur)):
        a = cur[x - bpp] if x >= bpp else 0
        b = prev[x]
        if ft == 3:
            cur[x] = (cur[x] + ((a + b) >> 1)) & 0xFF
        else:
            c = prev[x - bpp] if x >= bpp else 0
            pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
            pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (cur[x] + pred) & 0xFF
    return bytes(cur)


def encode_png16(rgb16: np.ndarray) -> bytes:
    """Bytes of a 16-bit RGB PNG for uint16 [H, W, 3] (rows filtered with 'Up')."""
    H, W, C = rgb16.shape
    assert C == 3 and rgb16.dtype == np.uint16
    raw = np.ascontiguousarray(rgb16, dtype=">u2").view(np.uint8).reshape(H, W * 6)
    filtered = np.empty((H, W * 6 + 1), np.uint8)
    filtered[:, 0] = 2
    filtered[:, 1:] = raw - np.vstack((np.zeros((1, W * 6), np.uint8), raw[:-1]))

    def chunk(typ: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + typ + body + struct.pack(">I", zlib.crc32(typ + body))

    return (PNG_MAGIC + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 16, 2, 0, 0, 0))
            + chunk(b"sRGB", b"\x00") + chunk(b"IDAT", zlib.compress(filtered.tobytes(), 6))
            + chunk(b"IEND", b""))
