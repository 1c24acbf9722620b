"""What a file is before it is decoded: its format from the signature, its size from the header, and
the size rules every reader and command applies (docs/file-formats.md)."""

from __future__ import annotations

import os
import stat

from phyir.errors import InputError
from phyir.io import exr, ldr, rgbe

# Panorama size limits (rows x columns) and the accepted aspect ratio W/H = 2 +- ASPECT_TOL.
MIN_SIZE = (4, 8)
MAX_SIZE = (8192, 16384)
ASPECT_TOL = 0.02


def sniff(path: str | os.PathLike) -> str:
    """The format of a file from its signature: "exr", "hdr", "png" or "jpeg"."""
    p = os.fspath(path)
    try:
        st = os.stat(p)
        if stat.S_ISDIR(st.st_mode):
            raise InputError(p, "is a folder, not an image file")
        with open(p, "rb") as f:
            head = f.read(8)
    except FileNotFoundError:
        raise InputError(p, "no such file") from None
    except OSError as e:
        raise InputError(p, f"cannot read: {e.strerror}") from None
    if not head:
        raise InputError(p, "empty file (0 bytes)")
    if head.startswith(exr.MAGIC):
        return "exr"
    if head.startswith(b"#?"):
        return "hdr"
    if head.startswith(ldr.PNG_MAGIC):
        return "png"
    if head.startswith(ldr.JPEG_MAGIC):
        return "jpeg"
    if p.lower().endswith(".exr"):
        raise InputError(p, "not an OpenEXR file (wrong magic number)")
    raise InputError(p, "not a supported image (expected OpenEXR, Radiance .hdr, PNG or JPEG)")


def check_size(path: str | None, H: int, W: int, what: str = "image") -> None:
    """Refuse sizes no real panorama has (before anything is allocated)."""
    if H < 1 or W < 1:
        raise InputError(path, f"empty {what} ({H}x{W})")
    if H > MAX_SIZE[0] or W > MAX_SIZE[1]:
        raise InputError(path, f"absurd size: {what} is {H}x{W} (HxW), larger than the limit "
                               f"{MAX_SIZE[0]}x{MAX_SIZE[1]}")


def check_panorama_size(path: str | None, H: int, W: int, min_size: tuple[int, int] = MIN_SIZE) -> None:
    """Size limits of :func:`check_size`, at least ``min_size``, and W/H within 2 +- ASPECT_TOL: the one
    rule of what is a panorama."""
    check_size(path, H, W, "panorama")
    if H < min_size[0] or W < min_size[1]:
        raise InputError(path, f"absurd size: {H}x{W} (HxW) is smaller than the minimum "
                               f"{min_size[0]}x{min_size[1]}")
    if abs(W / H - 2) > ASPECT_TOL:
        raise InputError(path, f"aspect ratio {W}/{H} = {W / H:.3f} is not that of an equirectangular "
                               f"panorama (width/height must be 2 +- {ASPECT_TOL})")


def header_size(path: str | os.PathLike, fmt: str | None = None) -> tuple[int, int]:
    """(H, W) of an image or scene file from its header (the main part's, for OpenEXR)."""
    fmt = fmt or sniff(path)
    if fmt == "exr":
        headers = exr.read_headers(path)
        h = next((h for h in headers if h.name == "scene"), headers[0])
    else:
        h = rgbe.read_header(path) if fmt == "hdr" else ldr.read_info(path)
    return h.height, h.width
