"""What a file is before it is decoded: its format from the signature, its size from the header, and
the size rules every reader and command applies (docs/file-formats.md)."""

from __future__ import annotations

from fractions import Fraction

from phyir.errors import InputError
from phyir.io import exr, ldr, rgbe
from phyir.io.files import input_stream

# Panorama size limits (rows x columns) and the accepted aspect ratio W/H = 2 +- ASPECT_TOL.
MIN_SIZE = (4, 8)
MAX_SIZE = (8192, 16384)
ASPECT_TOL = 0.02
# Decompression bombs (check_expansion): pixels over 384 MiB as float32 (4096x8192 RGB) must come
# from a file at least 1/96 of that size (one byte per 8 RGB pixels).
FREE_DECODE_BYTES = 384 << 20
MAX_EXPANSION = 96


def sniff(src, name: str | None = None) -> str:
    """The format of a file (a path or an open file) from its signature: "exr", "hdr", "png" or
    "jpeg".  A path must be a regular file (:func:`phyir.io.files.check_input`)."""
    with input_stream(src, name) as (f, p):
        try:
            head = f.read(8)
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


def check_expansion(path: str | None, samples: int, file_bytes: int) -> None:
    """Refuse a decompression bomb: a file whose ``samples`` (pixels x channels, over every part)
    would take more than :data:`FREE_DECODE_BYTES` as float32 *and* more than :data:`MAX_EXPANSION`
    times the file's size.  Real panoramas that large are far bigger files; this bounds what a small
    file can make a reader allocate (a 5 MB file: at most ~480 MB of pixels)."""
    decoded = 4 * samples
    if decoded > FREE_DECODE_BYTES and decoded > MAX_EXPANSION * file_bytes:
        raise InputError(path, f"refused as a decompression bomb: its pixels would take "
                               f"{decoded / 2**20:,.0f} MiB from a file of {file_bytes / 2**20:.2f} MiB "
                               f"(above {FREE_DECODE_BYTES >> 20} MiB, at most {MAX_EXPANSION}x the "
                               "file's size)")


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
    if abs(Fraction(W, H) - 2) > Fraction(str(ASPECT_TOL)):  # exact: 101/50 is 2 + 0.02, not more
        raise InputError(path, f"aspect ratio {W}/{H} = {W / H:.3f} is not that of an equirectangular "
                               f"panorama (width/height must be 2 +- {ASPECT_TOL})")


def header_size(src, fmt: str | None = None) -> tuple[int, int]:
    """(H, W) of an image or scene file (a path or an open file) from its header (the main part's,
    for OpenEXR); the file is opened once."""
    with input_stream(src) as (f, p):
        fmt = fmt or sniff(f, p)
        if fmt == "exr":
            headers = exr.read_headers(f, p)
            h = next((h for h in headers if h.name == "scene"), headers[0])
        else:
            h = rgbe.read_header(f, p) if fmt == "hdr" else ldr.read_info(f, p)
    return h.height, h.width
