"""Inputs of the second robustness corpus (tests/support/robustness/corpus.py), made by code.

``base(root)`` runs in a child interpreter that imports phyir (the corpus driver stays small, so its
children's peak memory is their own): valid panoramas and scenes, a tiny dataset and a checkpoint,
and the files whose content needs numpy/OpenEXR (NaN/Inf panoramas, NaN probes, negative depth).
The other hostile files are bytes written by the stdlib functions below (headers that lie, chunk
bombs, meshes that claim more than they hold), called by the driver.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------------------------------------
# stdlib writers (the driver uses these)


def png_chunk(typ: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + typ + body + struct.pack(">I", zlib.crc32(typ + body))


def png(W: int, H: int, bits: int = 8, ctype: int = 2, rows: bytes | None = None, extra: bytes = b"",
        interlace: int = 0, idat: bytes | None = None) -> bytes:
    """A PNG of ``rows`` (filtered scanlines; default: black, filter 0) with ``extra`` chunks."""
    chans = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}[ctype]
    if rows is None and idat is None:
        rows = (b"\0" + bytes(W * chans * bits // 8)) * H
    head = png_chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, bits, ctype, 0, 0, interlace))
    body = idat if idat is not None else png_chunk(b"IDAT", zlib.compress(rows, 9))
    return PNG_MAGIC + head + extra + body + png_chunk(b"IEND", b"")


ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def png_adam7(pixels: list[list[tuple[int, ...]]], bits: int) -> bytes:
    """An interlaced (Adam7) RGB PNG of ``pixels`` [H][W] (filter 0 on every pass row)."""
    H, W = len(pixels), len(pixels[0])
    fmt = ">HHH" if bits == 16 else "BBB"
    raw = bytearray()
    for x0, y0, dx, dy in ADAM7:
        for y in range(y0, H, dy):
            xs = range(x0, W, dx)
            if len(xs):
                raw += b"\0" + b"".join(struct.pack(fmt, *pixels[y][x]) for x in xs)
    return png(W, H, bits, 2, interlace=1, idat=png_chunk(b"IDAT", zlib.compress(bytes(raw), 9)))


def ztxt_bomb(inflated: int) -> bytes:
    """A zTXt chunk whose text inflates to ``inflated`` bytes."""
    z = zlib.compressobj(9)
    data = b"".join(z.compress(bytes(1 << 20)) for _ in range(inflated >> 20)) + z.flush()
    return png_chunk(b"zTXt", b"Comment\0\0" + data)


def iccp_bomb(inflated: int) -> bytes:
    z = zlib.compressobj(9)
    data = b"".join(z.compress(bytes(1 << 20)) for _ in range(inflated >> 20)) + z.flush()
    return png_chunk(b"iCCP", b"icc\0\0" + data)


def jpeg_sof(W: int, H: int, body: bytes = b"") -> bytes:
    """A JPEG whose SOF0 declares ``W``x``H`` (3 components) and no real image data."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, H, W, 3) + b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00" + sof + body + b"\xff\xd9"


def hdr(header: str, body: bytes = b"") -> bytes:
    return header.encode("latin-1") + body


def exr_many_attributes(count: int, W: int = 8, H: int = 4) -> bytes:
    """A valid 8x4 single-part scanline EXR (HALF R,G,B, no compression) with ``count`` extra string
    attributes in its header."""
    def attr(name: str, typ: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value
    chan = struct.pack("<iBBBBii", 1, 0, 0, 0, 0, 1, 1)  # HALF, linear, sampling 1x1
    chans = b"".join(c + b"\0" + chan for c in (b"B", b"G", b"R")) + b"\0"
    box = struct.pack("<iiii", 0, 0, W - 1, H - 1)
    head = (attr("channels", "chlist", chans) + attr("compression", "compression", b"\0")
            + attr("dataWindow", "box2i", box) + attr("displayWindow", "box2i", box)
            + attr("lineOrder", "lineOrder", b"\0") + attr("pixelAspectRatio", "float", struct.pack("<f", 1))
            + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
            + attr("screenWindowWidth", "float", struct.pack("<f", 1)))
    head += b"".join(attr(f"x{i}", "string", b"v") for i in range(count)) + b"\0"
    start = 8 + len(head) + 8 * H
    line = W * 3 * 2
    offsets = b"".join(struct.pack("<Q", start + y * (8 + line)) for y in range(H))
    half_one = struct.pack("<e", 0.5) * (W * 3)
    data = b"".join(struct.pack("<ii", y, line) + half_one for y in range(H))
    return b"\x76\x2f\x31\x01" + struct.pack("<I", 2) + head + offsets + data


def glb(json_doc: dict, bin_len_field: int | None = None, payload: bytes = b"\0" * 36) -> bytes:
    js = json.dumps(json_doc).encode()
    js += b" " * (-len(js) % 4)
    chunk_len = len(payload) if bin_len_field is None else bin_len_field
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", chunk_len, 0x004E4942) + payload
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def glb_triangle(buffer_len: int) -> bytes:
    """A GLB of one triangle whose buffer and accessor claim ``buffer_len`` bytes."""
    doc = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "scene": 0, "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "buffers": [{"byteLength": buffer_len}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": buffer_len}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": buffer_len // 12, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 1]}]}
    return glb(doc, bin_len_field=min(buffer_len, 2**32 - 4))


def safetensors_with(src: Path, meta_update: dict | None = None, header_edit=None) -> bytes:
    """The shipped weights ``src`` with its metadata updated / its header JSON edited (text -> text)."""
    data = src.read_bytes()
    n = struct.unpack("<Q", data[:8])[0]
    head = json.loads(data[8:8 + n])
    if meta_update:
        head["__metadata__"] = {**head.get("__metadata__", {}), **meta_update}
    text = json.dumps(head)
    if header_edit:
        text = header_edit(text)
    raw = text.encode()
    raw += b" " * (-len(raw) % 8)
    return struct.pack("<Q", len(raw)) + raw + data[8 + n:]


# ---------------------------------------------------------------------------------------------
# the base inputs (child interpreter with phyir)


def _scene(H: int, W: int, seed: int = 0):
    import torch

    from phyir.pano import directions
    from phyir.scene import PanoScene
    from phyir.synth import analytic

    g = torch.Generator().manual_seed(seed)
    depth, normal = analytic.box_room(H, W, (-2.5, -1.5, -3.0), (3.0, 1.2, 2.0))
    depth, normal = depth.float(), normal.float()
    albedo = (0.2 + 0.6 * torch.rand(3, 1, 1, generator=g)).expand(3, H, W).clone()
    image = albedo * (0.3 + 2.0 * normal[1:2].neg().clamp(min=0) + 0.5 / depth)
    d = directions(8, 16)
    probes = (0.2 + 3 * d[1:2].clamp(min=0) ** 2).expand(4, 8, 3, 8, 16).clone()
    return PanoScene(image=image, depth=depth, normal=normal, albedo=albedo,
                     roughness=torch.full((1, H, W), 0.5), metallic=torch.zeros(1, H, W),
                     probes=probes).validate()


def _exr_rgb(path: Path, rgb) -> None:
    import numpy as np

    from phyir.io import exr

    a = np.ascontiguousarray(rgb, np.float32)
    exr.write_parts(path, [("scene", {}, {"R": a[0], "G": a[1], "B": a[2]})])


def _rewrite_exr(src: Path, dst: Path, part: str, channel_prefix: str, value: float) -> None:
    import OpenEXR

    f = OpenEXR.File(str(src))
    for p in f.parts:
        if p.name() == part:
            for name, ch in p.channels.items():
                if name.startswith(channel_prefix):
                    ch.pixels[...] = value
    f.write(str(dst))


def base(root: Path) -> None:
    import numpy as np
    import torch

    from phyir import io

    root.mkdir(parents=True, exist_ok=True)
    s = _scene(64, 128)
    io.save_scene(s, root / "scene.exr")
    io.save_panorama(s.image, root / "pano.hdr")
    io.save_panorama(s.image, root / "pano.png")
    io.save_scene(_scene(256, 512, 1), root / "big_scene.exr")
    for d in ("gt", "pred"):
        (root / d).mkdir()
        io.save_scene(s, root / d / "a.exr")
    H, W = 64, 128
    nan = np.full((3, H, W), np.nan, np.float32)
    _exr_rgb(root / "nan.exr", nan)
    _exr_rgb(root / "inf.exr", np.full((3, H, W), np.inf, np.float32))
    _exr_rgb(root / "negative.exr", np.full((3, H, W), -1.0, np.float32))
    spike = np.zeros((3, H, W), np.float32)
    spike[:, 10, 10] = 1e38
    _exr_rgb(root / "spike.exr", spike)
    _exr_rgb(root / "black.exr", np.zeros((3, H, W), np.float32))
    io.save_panorama(torch.ones(3, H, W), root / "white.png")
    io.save_panorama(torch.zeros(3, H, W), root / "black16.png", bits=16)
    _rewrite_exr(root / "scene.exr", root / "nan_probes.exr", "probes", "", float("nan"))
    _rewrite_exr(root / "scene.exr", root / "neg_depth.exr", "scene", "depth", -2.0)
    _rewrite_exr(root / "scene.exr", root / "zero_depth.exr", "scene", "depth", 0.0)
    _rewrite_exr(root / "scene.exr", root / "nan_depth.exr", "scene", "depth", float("nan"))
    data = root / "data"
    data.mkdir()
    names = [f"scene_{i:06d}.exr" for i in range(5)]
    for i, n in enumerate(names):
        io.save_scene(_scene(32, 64, 10 + i), data / n)
    (data / "manifest.json").write_text(json.dumps(
        {"generator": "corpus", "splits": {"train": names[:3], "val": names[3:], "test": []}}))
    subprocess.run([sys.executable, "-m", "phyir.cli", "train", "--data", str(data), "--stage", "gm",
                    "--out", str(root / "run"), "--size", "32x64", "--probe-grid", "4x8", "--max-steps",
                    "1", "--batch-size", "2", "--workers", "0", "--no-val", "--no-progress", "--init",
                    "scratch", "--no-cache"], check=True, capture_output=True, timeout=300)


if __name__ == "__main__":
    base(Path(sys.argv[1]))
