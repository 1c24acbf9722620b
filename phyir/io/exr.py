"""OpenEXR files: a pure-Python header reader and thin wrappers around the official bindings.

The header is parsed here, in Python, before the C++ library sees the file: that is how corrupt or
hostile headers (wrong magic, truncated attributes, absurd data windows) are refused with a clear
message *before* anything is allocated.  Pixel data is then read and written with ``OpenEXR.File``.
Errors are raised as :class:`~phyir.errors.InputError` naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from phyir.errors import InputError
from phyir.io.files import input_stream, stream_size

MAGIC = b"\x76\x2f\x31\x01"
PIXEL_TYPES = {0: "UINT", 1: "HALF", 2: "FLOAT"}
_FLAG_TILED, _FLAG_LONG_NAMES, _FLAG_DEEP, _FLAG_MULTIPART = 0x200, 0x400, 0x800, 0x1000
_MAX_ATTRS = 4096  # more attributes than this in one header is corruption, not a real file
_MAX_PARTS = 256


@dataclass
class ExrHeader:
    """What PhyIR needs from one part's header."""

    index: int
    name: str | None
    data_window: tuple[int, int, int, int]  # xMin, yMin, xMax, yMax (inclusive)
    display_window: tuple[int, int, int, int] | None
    channels: dict[str, str] = field(default_factory=dict)  # name -> UINT/HALF/FLOAT
    sampling: dict[str, tuple[int, int]] = field(default_factory=dict)
    strings: dict[str, str] = field(default_factory=dict)  # string-typed attributes
    compression: int | None = None
    storage: str = "scanlineimage"  # from the 'type' attribute or the version flags

    @property
    def height(self) -> int:
        return self.data_window[3] - self.data_window[1] + 1

    @property
    def width(self) -> int:
        return self.data_window[2] - self.data_window[0] + 1


def read_headers(src, name: str | None = None) -> list[ExrHeader]:
    """Parse every part's header of an OpenEXR file (a path or an open file) without the C++ library.

    Raises :class:`InputError` for a wrong magic number, a truncated or malformed header, deep data
    and empty or inverted data windows.  Sizes are *not* limited here (see phyir.io).
    """
    with input_stream(src, name) as (f, p):
        return _Parser(f, stream_size(f), p).headers()


class _Parser:
    def __init__(self, f: io.BufferedReader, size: int, path: str):
        self.f, self.size, self.path = f, size, path

    def fail(self, problem: str) -> InputError:
        return InputError(self.path, f"corrupt or truncated OpenEXR header: {problem}")

    def read(self, n: int) -> bytes:
        b = self.f.read(n)
        if len(b) != n:
            raise self.fail("file ends inside the header")
        return b

    def cstr(self, limit: int) -> bytes:
        out = bytearray()
        while True:
            c = self.read(1)
            if c == b"\0":
                return bytes(out)
            out += c
            if len(out) > limit:
                raise self.fail("name longer than allowed")

    def headers(self) -> list[ExrHeader]:
        if self.f.read(4) != MAGIC:
            raise InputError(self.path, "not an OpenEXR file (wrong magic number)")
        (version,) = struct.unpack("<I", self.read(4))
        if version & 0xFF != 2:
            raise self.fail(f"unsupported format version {version & 0xFF}")
        if version & _FLAG_DEEP:
            raise InputError(self.path, "deep OpenEXR data is not supported")
        self.name_limit = 255 if version & _FLAG_LONG_NAMES else 31
        multipart = bool(version & _FLAG_MULTIPART)
        headers = []
        while True:
            h = self.header(len(headers), tiled=bool(version & _FLAG_TILED))
            if h is None:  # empty header: end of the multi-part header list
                break
            headers.append(h)
            if not multipart:
                break
            if len(headers) > _MAX_PARTS:
                raise self.fail(f"more than {_MAX_PARTS} parts")
        if not headers:
            raise self.fail("no parts")
        return headers

    def header(self, index: int, tiled: bool) -> ExrHeader | None:
        attrs: dict[str, tuple[str, bytes]] = {}
        strings: dict[str, str] = {}
        for _ in range(_MAX_ATTRS):
            name = self.cstr(self.name_limit)
            if not name:
                break
            typ = self.cstr(self.name_limit).decode("latin-1")
            (n,) = struct.unpack("<i", self.read(4))
            if n < 0 or n > self.size - self.f.tell():
                raise self.fail(f"attribute {name.decode('latin-1')!r} has an impossible size {n}")
            key = name.decode("latin-1")
            if typ in ("box2i", "chlist", "compression", "string"):
                attrs[key] = (typ, self.read(n))
                if typ == "string":
                    strings[key] = attrs[key][1].decode("utf-8", "replace")
            else:
                self.f.seek(n, os.SEEK_CUR)
        else:
            raise self.fail("too many attributes")
        if not attrs and index > 0:
            return None
        if "dataWindow" not in attrs or "channels" not in attrs:
            raise self.fail("missing dataWindow or channels attribute")
        dw = self.box(attrs["dataWindow"])
        if dw[2] < dw[0] or dw[3] < dw[1]:
            raise InputError(self.path, f"empty image (data window {dw})")
        disp = self.box(attrs["displayWindow"]) if "displayWindow" in attrs else None
        channels, sampling = self.chlist(attrs["channels"][1])
        comp = attrs["compression"][1][0] if "compression" in attrs else None
        storage = strings.get("type", "tiledimage" if tiled else "scanlineimage")
        if storage.startswith("deep"):
            raise InputError(self.path, "deep OpenEXR data is not supported")
        return ExrHeader(index, strings.get("name"), dw, disp, channels, sampling,
                         {k: v for k, v in strings.items() if k not in ("name", "type")}, comp, storage)

    def box(self, attr: tuple[str, bytes]) -> tuple[int, int, int, int]:
        typ, data = attr
        if typ != "box2i" or len(data) != 16:
            raise self.fail("window attribute is not a box2i")
        return struct.unpack("<4i", data)  # type: ignore[return-value]

    def chlist(self, data: bytes) -> tuple[dict[str, str], dict[str, tuple[int, int]]]:
        channels, sampling, pos = {}, {}, 0
        while pos < len(data) and data[pos] != 0:
            end = data.find(b"\0", pos)
            if end < 0 or end + 17 > len(data):
                raise self.fail("malformed channel list")
            name = data[pos:end].decode("latin-1")
            ptype, _linear, xs, ys = struct.unpack("<iB3xii", data[end + 1 : end + 17])
            if ptype not in PIXEL_TYPES:
                raise self.fail(f"channel {name!r} has unknown pixel type {ptype}")
            channels[name], sampling[name] = PIXEL_TYPES[ptype], (xs, ys)
            pos = end + 17
        if not channels:
            raise InputError(self.path, "OpenEXR file has no channels")
        return channels, sampling


# ---------------------------------------------------------------------------------------------
# pixel data through the official bindings


@contextlib.contextmanager
def _capture_native_stderr() -> Iterator[io.StringIO]:
    """Capture what the C++ library prints on file descriptor 2 (its error reports).

    The library reports decode errors there and then returns partial data; we turn them into the
    text of one InputError instead of letting them spill onto the terminal.  This redirects fd 2
    process-wide for the duration of one read.
    """
    out = io.StringIO()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all: nothing to capture
        yield out
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield out
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out.write(tmp.read().decode("utf-8", "replace"))


def read_pixels(path: str | os.PathLike, headers: list[ExrHeader]) -> list[dict[str, np.ndarray]]:
    """Read every part's channels as 2D numpy arrays (HALF/FLOAT/UINT as stored).

    ``headers`` are the parsed headers of the same file (used to verify that the library returned
    every part and channel at its full size: it silently drops parts whose pixel data is corrupt).
    """
    import OpenEXR

    p = os.fspath(path)
    py_out = io.StringIO()
    try:
        with _capture_native_stderr() as native, contextlib.redirect_stdout(py_out):
            f = OpenEXR.File(p, separate_channels=True)
            parts = [{k: c.pixels for k, c in part.channels.items()} for part in f.parts]
    except Exception as e:  # the bindings raise RuntimeError/IndexError/... for bad data
        detail = _first_line(str(e)).replace(f"'{p}' ", "")
        raise InputError(p, f"corrupt or truncated OpenEXR data ({detail})") from None
    detail = _first_line(native.getvalue() + py_out.getvalue()).removeprefix(f"{p}: ")
    if len(parts) != len(headers):
        raise InputError(p, f"corrupt or truncated OpenEXR pixel data ({detail or 'parts missing'})")
    for h, chans in zip(headers, parts):
        for name in h.channels:
            a = chans.get(name)
            xs, ys = h.sampling.get(name, (1, 1))
            want = (-(-h.height // ys), -(-h.width // xs))
            if a is None or a.shape[:2] != want:
                raise InputError(p, f"corrupt or truncated OpenEXR pixel data in channel {name!r}"
                                    f"{' (' + detail + ')' if detail else ''}")
    return parts


def _first_line(text: str) -> str:
    for line in text.splitlines():
        line = line.strip()
        if line:
            return line.removeprefix("Warning: ")
    return ""


def _use_all_cores(openexr) -> None:
    """Let the library compress and decompress on every core (its default is one thread: a 360
    camera's scene file, 12 float32 channels of 16.6 M pixels, takes twice as long to write)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if openexr.global_thread_count() != n:
        openexr.set_global_thread_count(n)


def write_parts(path: str | os.PathLike, parts: list[tuple[str, dict, dict[str, np.ndarray]]],
                compression: str = "PIZ") -> None:
    """Write a (multi-part) scanline OpenEXR file.

    ``parts``: (name, extra header attributes, channel name -> 2D float16/float32 array).  Every
    part gets the first part's display window (OpenEXR requires it to be shared) and its own data
    window from its arrays.  With one part the library writes a single-part file that still
    carries the part's ``name`` attribute.
    """
    import OpenEXR

    _use_all_cores(OpenEXR)
    comp = getattr(OpenEXR, f"{compression}_COMPRESSION")
    H, W = next(iter(parts[0][2].values())).shape
    display = ((0, 0), (W - 1, H - 1))
    out = []
    for name, attrs, chans in parts:
        header = {"compression": comp, "type": OpenEXR.scanlineimage, "displayWindow": display,
                  **attrs}
        out.append(OpenEXR.Part(header, {k: np.ascontiguousarray(v) for k, v in chans.items()}, name))
    try:
        OpenEXR.File(out).write(os.fspath(path))
    except RuntimeError as e:  # the library wraps the OS's refusal (a full disk, ...) in its text
        code = next((c for c in _OS_ERRNOS if os.strerror(c) in str(e)), None)
        if code is None:
            raise
        raise OSError(code, os.strerror(code), os.fspath(path)) from None


_OS_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO,
              errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG)
