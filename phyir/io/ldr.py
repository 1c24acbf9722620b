"""Low-dynamic-range images: PNG (8/16-bit) and JPEG, sRGB-decoded to linear float32.

8-bit images go through Pillow.  Pillow truncates 16-bit RGB(A) PNGs to 8 bits, so 16-bit PNGs are
decoded and encoded here with zlib and numpy (non-interlaced only).  Alpha is dropped, grayscale is
replicated to RGB, and the pixel values are taken as sRGB-encoded (gAMA/iCCP chunks are ignored).
"""

from __future__ import annotations

import struct
import warnings
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

from phyir.color import srgb_to_linear
from phyir.errors import InputError
from phyir.io.files import input_stream, stream_size

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8\xff"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> samples per pixel
MAX_METADATA = 64 << 20  # bytes a PNG text or ICC chunk may inflate to (it is ignored, not kept)


@dataclass
class LdrInfo:
    format: str  # "PNG" or "JPEG"
    height: int
    width: int
    bits: int  # bits per sample
    mode: str  # e.g. "RGB", "RGBA", "L", "P"


def read_info(src, name: str | None = None) -> LdrInfo:
    """Size and sample format from the file header (a path or an open file), without decoding."""
    with input_stream(src, name) as (f, p):
        head = f.read(33)
        if head.startswith(PNG_MAGIC):
            return _png_info(head, p)
        from PIL import Image

        try:
            f.seek(0)
            with warnings.catch_warnings():  # the header only; the caller checks the size (sniff)
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with Image.open(f) as im:
                    return LdrInfo(im.format or "?", im.height, im.width, 8, im.mode)
        except Exception as e:
            raise InputError(p, f"not a readable image ({_one_line(e)})") from None


def _png_info(head: bytes, p: str) -> LdrInfo:
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


def _srgb_lut(bits: int) -> np.ndarray:
    """Linear value of every sample value: decoding is one table look-up, no float temporaries."""
    top = (1 << bits) - 1
    return srgb_to_linear(np.arange(top + 1, dtype=np.float32) / np.float32(top))


def read_pixels(src, info: LdrInfo, name: str | None = None) -> np.ndarray:
    """Decode to linear float32 [H, W, 3] (sRGB decoded, alpha dropped, gray replicated); a view of
    a channel-first [3, H, W] array."""
    with input_stream(src, name) as (f, p):
        if info.format == "PNG" and info.bits == 16:
            samples = _read_png16(f, p, info)  # [H, W, C] uint16
            lut = _srgb_lut(16)
        else:
            samples = _read_pillow(f, p)
            lut = _srgb_lut(8)
    rgb = samples[:, :, :3] if samples.shape[2] >= 3 else samples[:, :, :1]  # alpha dropped
    H, W = rgb.shape[:2]
    planes = np.empty((3, H, W), np.float32)  # channel-first, as the loaders keep layers
    step = max(1, (1 << 20) // W)  # rows per look-up: bounded index temporaries
    for y in range(0, H, step):
        planes[:, y : y + step] = lut[rgb[y : y + step]].transpose(2, 0, 1)  # gray: broadcast
    return planes.transpose(1, 2, 0)


def _read_pillow(f: BinaryIO, p: str) -> np.ndarray:
    from PIL import Image, PngImagePlugin

    # metadata (text, ICC profiles) is ignored; Pillow's 1 MB cap on it refused valid files
    PngImagePlugin.MAX_TEXT_CHUNK = max(PngImagePlugin.MAX_TEXT_CHUNK, MAX_METADATA)
    try:
        with warnings.catch_warnings():
            # the caller has already checked the size against PhyIR's own limits
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            f.seek(0)
            with Image.open(f) as im:
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
        if "MAX_TEXT_CHUNK" in str(e):
            raise InputError(p, f"a metadata chunk (text or ICC profile) inflates to more than "
                                f"{MAX_METADATA >> 20} MB (a decompression bomb?)") from None
        raise InputError(p, f"corrupt or truncated image ({_one_line(e)})") from None
    return a[:, :, None] if a.ndim == 2 else a


def _one_line(e: BaseException) -> str:
    return (str(e).splitlines() or [type(e).__name__])[0]


# ---------------------------------------------------------------------------------------------
# 16-bit PNG


def _chunks(f: BinaryIO, p: str, size: int) -> Iterator[tuple[bytes, bytes]]:
    """(type, body) of each chunk after the signature, CRC-checked, up to IEND; a declared length
    past the end of the file is refused before anything is read."""
    f.seek(8)
    pos = 8
    while True:
        head = f.read(8)
        if len(head) < 8:
            raise InputError(p, "truncated PNG (file ends before the IEND chunk)")
        n, typ = struct.unpack(">I4s", head)
        name = typ.decode("latin-1")
        if pos + 12 + n > size:
            raise InputError(p, f"truncated PNG (inside the {name} chunk)")
        body, crc = f.read(n), f.read(4)
        if len(body) != n or len(crc) != 4:
            raise InputError(p, f"truncated PNG (inside the {name} chunk)")
        if struct.unpack(">I", crc)[0] != zlib.crc32(typ + body):
            raise InputError(p, f"corrupt PNG (CRC mismatch in the {name} chunk)")
        yield typ, body
        if typ == b"IEND":
            return
        pos += 12 + n


def _inflate_rows(f: BinaryIO, p: str, info: LdrInfo, row_bytes: int) -> np.ndarray:
    """The zlib stream of the IDAT chunks inflated into exactly H rows of ``row_bytes``: inflated
    incrementally with ``max_length``, so a stream that would inflate to more than the header's
    size (a zlib bomb) is refused as soon as it passes it, holding no more than the image."""
    need = info.height * row_bytes
    raw = np.empty(need, np.uint8)
    got = 0
    d = zlib.decompressobj()
    try:
        for typ, body in _chunks(f, p, stream_size(f)):
            if typ != b"IDAT":
                continue
            data = body
            while data:
                piece = d.decompress(data, need - got + 1)
                if got + len(piece) > need:
                    raise InputError(p, f"corrupt PNG image data (inflates to more than the {need} "
                                        f"bytes a {info.height}x{info.width} image needs)")
                raw[got : got + len(piece)] = np.frombuffer(piece, np.uint8)
                got += len(piece)
                data = d.unconsumed_tail
                if not piece:
                    break
        got += len(d.flush(1)) if got == need else 0
    except zlib.error as e:
        raise InputError(p, f"corrupt PNG image data ({e})") from None
    if got != need:
        raise InputError(p, f"corrupt or truncated PNG image data ({got} bytes, expected {need})")
    return raw.reshape(info.height, row_bytes)


def _read_png16(f: BinaryIO, p: str, info: LdrInfo) -> np.ndarray:
    """Big-endian samples [H, W, C] (a view of the inflated rows, unfiltered in place)."""
    C = _PNG_CHANNELS[{"L": 0, "RGB": 2, "LA": 4, "RGBA": 6}[info.mode]]
    bpp = 2 * C
    rows = _inflate_rows(f, p, info, info.width * bpp + 1)
    bad = np.flatnonzero(rows[:, 0] > 4)
    if bad.size:
        raise InputError(p, f"corrupt PNG (unknown filter type {rows[bad[0], 0]} in row {bad[0]})")
    unfilter(rows, bpp)
    return rows[:, 1:].view(">u2").reshape(info.height, info.width, C)


BAND = 1024  # rows unfiltered together: the skewed copy holds (band + W) x band pixels


def unfilter(rows: np.ndarray, bpp: int, band: int = BAND) -> None:
    """Undo PNG's filters in place: ``rows`` [H, 1 + W * bpp] (each row's filter type, 0-4, first),
    ``band`` rows at a time."""
    for top in range(0, rows.shape[0], band):
        _unfilter_band(rows, top, min(top + band, rows.shape[0]), bpp)


def _unfilter_band(rows: np.ndarray, top: int, end: int, bpp: int) -> None:
    """Undo PNG's per-row filters (types 0-4, checked by the caller) of rows ``top:end`` in place;
    row ``top - 1`` is already unfiltered.

    Each pixel depends on its left, upper and upper-left neighbours, so the pixels of one
    anti-diagonal (row + column = d) are independent: the band is skewed so that diagonal d is the
    contiguous slab ``skew[d]`` and decoded slab after slab (band + W steps of whole-slab numpy
    operations instead of a Python step per byte)."""
    H, W = end - top, (rows.shape[1] - 1) // bpp
    skew = np.zeros((H + W + 1, H + 1, bpp), np.uint8)  # skew[r + x, r] = pixel (top + r - 1, x)
    if top:
        skew[0:W, 0] = rows[top - 1, 1:].reshape(W, bpp)  # the row above the band, decoded
    for r in range(1, H + 1):
        skew[r : r + W, r] = rows[top + r - 1, 1:].reshape(W, bpp)
    ft = rows[top:end, 0]
    for d in range(1, H + W):
        lo, hi = max(1, d - W + 1), min(H, d) + 1  # the band's rows r with a pixel on diagonal d
        cur = skew[d, lo:hi]
        a = skew[d - 1, lo:hi].astype(np.int16)  # left
        b = skew[d - 1, lo - 1 : hi - 1].astype(np.int16)  # up
        c = skew[d - 2, lo - 1 : hi - 1].astype(np.int16)  # up-left
        t = ft[lo - 1 : hi - 1, None]
        pa, pb, pc = np.abs(b - c), np.abs(a - c), np.abs(a + b - 2 * c)
        paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
        pred = np.select([t == 1, t == 2, t == 3, t == 4], [a, b, (a + b) >> 1, paeth], 0)
        cur += pred.astype(np.uint8)  # uint8 arithmetic wraps mod 256
    for r in range(1, H + 1):
        rows[top + r - 1, 1:] = skew[r : r + W, r].reshape(-1)


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
