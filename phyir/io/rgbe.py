"""Radiance RGBE (.hdr) files in numpy: header, RLE and flat scanlines, all eight orientations.

A channel byte m with exponent byte e stands for m * 2**(e - 136) (e == 0: black), as in the
widely used readers (Walter's rgbe.c, stb_image, OpenCV); Radiance's own reader adds 0.5 to m.
The writer rounds mantissas to nearest, so a round trip errs by at most 2**-8 of a pixel's
brightest channel, and values RGBE represents exactly (0.25, 1, 3.5, ...) come back exact.
``EXPOSURE=`` lines (a multiplier already applied to the pixels) are divided out, so the returned
values are the radiance the writer meant.  Writing produces ``-Y H +X W`` (top row first) with
new-style RLE scanlines.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from phyir.errors import InputError
from phyir.io.files import input_stream

_MAX_HEADER = 64 * 1024
_RES = re.compile(rb"^([-+])([XY]) +(\d+) +([-+])([XY]) +(\d+)$")


@dataclass
class HdrHeader:
    height: int
    width: int
    resolution: str  # the resolution line as written, e.g. "-Y 512 +X 1024"
    exposure: float
    format: str
    data_offset: int

    @property
    def n_scanlines(self) -> int:
        return self.height if self.resolution.split()[0][1] == "Y" else self.width


def read_header(src, name: str | None = None) -> HdrHeader:
    """Parse the text header and the resolution line of a path or an open file (no pixel data is
    read)."""
    with input_stream(src, name) as (f, p):
        head = f.read(_MAX_HEADER)
    if not head.startswith(b"#?"):
        raise InputError(p, "not a Radiance HDR file (missing '#?' signature)")
    end = head.find(b"\n\n")
    if end < 0:
        raise InputError(p, "corrupt or truncated Radiance HDR header (no blank line ending it)")
    exposure, fmt = 1.0, "32-bit_rle_rgbe"
    for line in head[:end].split(b"\n")[1:]:
        key, _, value = line.partition(b"=")
        try:
            if key.strip() == b"EXPOSURE":
                exposure *= float(value)
            elif key.strip() == b"FORMAT":
                fmt = value.strip().decode("ascii", "replace")
        except ValueError:
            raise InputError(p, f"corrupt Radiance HDR header line {line[:60]!r}") from None
    if fmt != "32-bit_rle_rgbe":
        raise InputError(p, f"unsupported Radiance HDR FORMAT={fmt} (only 32-bit_rle_rgbe)")
    # [issue 22, class 5] dividing out an absurd EXPOSURE (1e300, 1e-40) under- or overflows float32
    # to an all-black or infinite image: refuse anything beyond 2^+-64 (64 stops either way)
    if not (np.isfinite(exposure) and 2.0 ** -64 <= exposure <= 2.0 ** 64):
        raise InputError(p, f"EXPOSURE={exposure:g} in the Radiance HDR header is not a plausible "
                            f"multiplier (expected 2^-64..2^64)")
    # [end issue 22, class 5]
    res_end = head.find(b"\n", end + 2)
    m = _RES.match(head[end + 2 : res_end].strip()) if res_end > 0 else None
    if m is None or m[2] == m[5]:
        raise InputError(p, "corrupt or truncated Radiance HDR resolution line")
    slow, fast = int(m[3]), int(m[6])
    H, W = (slow, fast) if m[2] == b"Y" else (fast, slow)
    return HdrHeader(H, W, head[end + 2 : res_end].strip().decode(), exposure, fmt, res_end + 1)


def read_pixels(src, header: HdrHeader, name: str | None = None) -> np.ndarray:
    """Decode the pixels of a Radiance file (a path or an open file) into float32 [H, W, 3], top row
    first (a view of a channel-first [3, H, W] array).  At most the bytes the largest encoding of
    H x W pixels takes are read."""
    with input_stream(src, name) as (f, p):
        f.seek(header.data_offset)
        n = header.n_scanlines
        m = header.height * header.width // n
        data = f.read(n * (4 + 4 * (m + m // 128 + 1)))  # RLE's worst case; flat: 4 m per line
    sign_slow, axis_slow, _, sign_fast, _, _ = _RES.match(header.resolution.encode()).groups()
    n, m = (header.height, header.width) if axis_slow == b"Y" else (header.width, header.height)
    rgbe = _decode_scanlines(data, n, m, p)  # [n, m, 4] uint8
    del data
    out = np.empty((3, header.height, header.width), np.float32).transpose(1, 2, 0)  # channel-first
    # slow axis Y: '-Y' = top to bottom; slow axis X: transpose, then the same sign rules apply
    if axis_slow == b"Y":
        flip_rows, flip_cols = sign_slow == b"+", sign_fast == b"-"
    else:
        flip_rows, flip_cols = sign_fast == b"+", sign_slow == b"-"
    lines = out[::-1] if flip_rows else out
    lines = lines[:, ::-1] if flip_cols else lines
    lines = lines if axis_slow == b"Y" else lines.transpose(1, 0, 2)  # lines[k]: scanline k
    step = max(1, (1 << 20) // m)  # scanlines per conversion: bounded float temporaries
    for k in range(0, n, step):
        rgb = rgbe_to_float(rgbe[k : k + step])
        lines[k : k + step] = rgb if header.exposure == 1.0 else rgb / np.float32(header.exposure)
    return out


def _decode_scanlines(data: bytes, n: int, m: int, path: str) -> np.ndarray:
    out = np.empty((n, m, 4), np.uint8)
    pos = 0
    for k in range(n):
        head = data[pos : pos + 4]
        if (8 <= m < 32768 and len(head) == 4 and head[0] == 2 and head[1] == 2
                and not head[2] & 0x80 and (head[2] << 8 | head[3]) == m):
            pos += 4
            for c in range(4):
                pos = _rle_channel(data, pos, m, out[k, :, c], path, k)
        else:
            pos = _flat_scanline(data, pos, m, out, k, path)
    return out


def _truncated(path: str, k: int) -> InputError:
    return InputError(path, f"truncated Radiance HDR pixel data (ends in scanline {k})")


def _rle_channel(data: bytes, pos: int, m: int, dst: np.ndarray, path: str, k: int) -> int:
    """Decode one channel of a new-style RLE scanline into ``dst`` (m bytes); returns the new pos."""
    buf = bytearray()
    end = len(data)
    while len(buf) < m:
        if pos >= end:
            raise _truncated(path, k)
        code = data[pos]
        if code > 128:
            if pos + 1 >= end:
                raise _truncated(path, k)
            buf += data[pos + 1 : pos + 2] * (code - 128)
            pos += 2
        elif code == 0:
            raise InputError(path, f"corrupt Radiance HDR RLE data in scanline {k} (zero-length run)")
        else:
            if pos + 1 + code > end:
                raise _truncated(path, k)
            buf += data[pos + 1 : pos + 1 + code]
            pos += 1 + code
    if len(buf) != m:
        raise InputError(path, f"corrupt Radiance HDR RLE data in scanline {k} (run overflows the line)")
    dst[:] = np.frombuffer(bytes(buf), np.uint8)
    return pos


def _flat_scanline(data: bytes, pos: int, m: int, out: np.ndarray, k: int, path: str) -> int:
    """A flat scanline, with old-style runs (pixel 1,1,1,n repeats the previous pixel) if present."""
    chunk = np.frombuffer(data, np.uint8, count=min(4 * m, (len(data) - pos) // 4 * 4), offset=pos)
    px = chunk.reshape(-1, 4)
    if len(px) == m and not ((px[:, 0] == 1) & (px[:, 1] == 1) & (px[:, 2] == 1)).any():
        out[k] = px
        return pos + 4 * m
    # old-style run-length encoding, pixel by pixel
    i, shift = 0, 0
    while i < m:
        if pos + 4 > len(data):
            raise _truncated(path, k)
        r, g, b, e = data[pos : pos + 4]
        pos += 4
        if r == g == b == 1:
            if i == 0:
                raise InputError(path, f"corrupt Radiance HDR data in scanline {k} (run before any pixel)")
            count = e << shift
            if i + count > m:
                raise InputError(path, f"corrupt Radiance HDR data in scanline {k} (run overflows the line)")
            out[k, i : i + count] = out[k, i - 1]
            i += count
            shift += 8
        else:
            out[k, i] = (r, g, b, e)
            i += 1
            shift = 0
    return pos


def rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """[..., 4] uint8 RGBE to [..., 3] float32: m * 2**(e - 136), black when e == 0."""
    e = rgbe[..., 3:4].astype(np.int32)
    scale = np.ldexp(np.float32(1.0), e - 136).astype(np.float32)
    return np.where(e > 0, rgbe[..., :3].astype(np.float32) * scale, np.float32(0))


def float_to_rgbe(rgb: np.ndarray) -> np.ndarray:
    """[..., 3] float to [..., 4] uint8 RGBE, mantissas rounded to nearest.

    The shared exponent is chosen so the brightest channel's mantissa lands in [128, 255]; the
    error is then at most 2**-8 of the brightest channel.  Negative values are written as 0,
    values below 2**-128 as black, values above the format's range (about 1.7e38) saturate.
    """
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    mx = rgb.max(axis=-1, keepdims=True)
    mant, ex = np.frexp(mx)  # mx = mant * 2**ex, mant in [0.5, 1)
    ex = np.minimum(ex + (np.round(mant * 256) >= 256), 127)  # rounding up to 256: next exponent
    m = np.clip(np.round(rgb * np.ldexp(1.0, 8 - ex)), 0, 255)  # saturates above the range
    black = (mx <= 0) | (ex < -127)
    out = np.empty((*rgb.shape[:-1], 4), np.uint8)
    out[..., :3] = np.where(black, 0, m)
    out[..., 3:] = np.where(black, 0, ex + 128)
    return out


def encode(rgb: np.ndarray) -> bytes:
    """The bytes of a ``-Y H +X W`` RGBE file for float [H, W, 3] (RLE when 8 <= W < 32768)."""
    H, W = rgb.shape[:2]
    px = float_to_rgbe(rgb)
    parts = [f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {H} +X {W}\n".encode()]
    if not 8 <= W < 32768:
        parts.append(px.tobytes())
        return b"".join(parts)
    marker = bytes((2, 2, W >> 8, W & 0xFF))
    for i in range(H):
        parts.append(marker)
        for c in range(4):
            parts.append(_rle_encode(px[i, :, c]))
    return b"".join(parts)


def _rle_encode(row: np.ndarray) -> bytes:
    """New-style RLE of one channel: runs of >= 4 equal bytes as (128 + n, value), rest literal."""
    W = len(row)
    starts = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
    lengths = np.diff(np.r_[starts, W])
    out = bytearray()
    lit = 0  # start of the pending literal stretch
    raw = row.tobytes()
    long = lengths >= 4
    for s, n in zip(starts[long].tolist(), lengths[long].tolist()):
        _literal(out, raw, lit, s)
        lit = s + n
        while n > 0:
            k = min(n, 127)
            out += bytes((128 + k, raw[s]))
            n -= k
    _literal(out, raw, lit, W)
    return bytes(out)


def _literal(out: bytearray, raw: bytes, a: int, b: int) -> None:
    while a < b:
        k = min(b - a, 128)
        out.append(k)
        out += raw[a : a + k]
        a += k
