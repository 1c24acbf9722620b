"""Raw reading: what a file holds, before any repair (used by the loaders and ``phyir info``)."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from phyir.errors import InputError
from phyir.io import exr, files, ldr, rgbe
from phyir.io.layout import LAYER_CHANNELS, MASK_PREFIX, probe_layout
from phyir.io.sniff import check_expansion, check_panorama_size, check_size, sniff


@dataclass
class RawPart:
    """One image of a file.  ``layers``: name -> float32 [C, h, w] exactly as stored (NaN kept)."""

    name: str
    height: int
    width: int
    pixel_types: dict[str, str]  # channel -> "HALF"/"FLOAT"/"UINT"/"8-bit"/"16-bit"/"RGBE"
    layers: dict[str, np.ndarray] = field(default_factory=dict)
    layer_channels: dict[str, tuple[str, ...]] = field(default_factory=dict)
    attrs: dict[str, str] = field(default_factory=dict)  # string attributes
    ignored: list[str] = field(default_factory=list)  # channels no layer uses


@dataclass
class RawFile:
    path: str
    format: str  # "OpenEXR", "Radiance HDR", "PNG", "JPEG"
    detail: str  # e.g. "2 parts", "16-bit RGBA", "-Y 512 +X 1024"
    parts: list[RawPart]
    kind: str = "exr"  # the signature's format (:func:`sniff`): "exr", "hdr", "png" or "jpeg"

    def part(self, name: str) -> RawPart | None:
        return next((p for p in self.parts if p.name == name), None)


def read_raw(path: str | os.PathLike, panorama: bool = True,
             limit: Callable[[str, int, int], None] | None = None) -> RawFile:
    """Read every part and layer of a file as stored (no repair).

    Sizes are checked from the header before pixels are decoded; with ``panorama`` the main image
    must also pass :func:`check_panorama_size`, and ``limit(path, H, W)`` (a caller's own bound,
    e.g. what predict can hold in memory) when given.
    """
    p = os.fspath(path)
    size_rule = check_panorama_size if panorama else check_size

    def check(path: str, H: int, W: int) -> None:
        size_rule(path, H, W)
        if limit is not None:
            limit(path, H, W)

    with files.open_input(p, "image file") as f:  # opened once: sniffed, header and pixels read
        fmt, size = sniff(f, p), files.stream_size(f)
        if fmt == "exr":
            return _read_raw_exr(f, p, check)
        if fmt == "hdr":
            h = rgbe.read_header(f, p)
            check(p, h.height, h.width)
            check_expansion(p, 3 * h.height * h.width, size)
            img = rgbe.read_pixels(f, h, p)
            part = RawPart("image", h.height, h.width, dict.fromkeys("RGB", "RGBE"))
            part.layers["image"], part.layer_channels["image"] = img.transpose(2, 0, 1), ("R", "G", "B")
            return RawFile(p, "Radiance HDR", h.resolution, [part], fmt)
        info = ldr.read_info(f, p)
        check(p, info.height, info.width)
        check_expansion(p, 3 * info.height * info.width, size)
        img = ldr.read_pixels(f, info, p)
    chans = {"L": "Y", "LA": "YA", "P": "RGB", "RGB": "RGB", "RGBA": "RGBA"}.get(info.mode, info.mode)
    part = RawPart("image", info.height, info.width, dict.fromkeys(chans, f"{info.bits}-bit"))
    part.layers["image"], part.layer_channels["image"] = img.transpose(2, 0, 1), tuple(chans)
    return RawFile(p, info.format, f"{info.bits}-bit {info.mode}", [part], fmt)


def _read_raw_exr(f, p: str, check) -> RawFile:
    headers = exr.read_headers(f, p)
    names = [h.name for h in headers]
    scene_i = names.index("scene") if "scene" in names else 0
    for h in headers:
        if h.index == scene_i:
            check(p, h.height, h.width)
        else:
            check_size(p, h.height, h.width, f"part {h.name!r}")
        for c, (xs, ys) in h.sampling.items():
            if (xs, ys) != (1, 1):
                raise InputError(p, f"unsupported: channel {c!r} is subsampled ({xs}x{ys})")
    check_expansion(p, sum(h.height * h.width * len(h.channels) for h in headers), files.stream_size(f))
    probes = next((h for h in headers if h.name == "probes" and h.index != scene_i), None)
    if probes is not None:
        probe_layout(p, probes.strings, probes.height, probes.width)  # refuse before decoding
    arrays = exr.read_pixels(p, headers)  # the C++ library opens the (checked, regular) file itself
    parts = []
    for h, chans in zip(headers, arrays):
        role = "scene" if h.index == scene_i else ("probes" if h is probes else "other")
        parts.append(_exr_part(p, h, chans, role))
    return RawFile(p, "OpenEXR", f"{len(headers)} part{'s' * (len(headers) > 1)}", parts)


def _exr_part(p: str, h: exr.ExrHeader, chans: dict[str, np.ndarray], role: str) -> RawPart:
    name = h.name or ("scene" if role == "scene" else f"part{h.index}")
    part = RawPart(name, h.height, h.width, dict(h.channels), attrs=dict(h.strings))
    used: set[str] = set()

    def take(layer: str, names: tuple[str, ...]) -> None:
        for c in names:
            if h.channels[c] == "UINT":
                raise InputError(p, f"unsupported bit depth: channel {c!r} is 32-bit UINT "
                                    "(expected HALF or FLOAT)")
        part.layers[layer] = np.stack([chans[c].astype(np.float32) for c in names])
        part.layer_channels[layer] = names
        used.update(names)

    if role == "other":
        for c in h.channels:
            if h.channels[c] != "UINT":
                take(c, (c,))
        part.ignored = [c for c in h.channels if c not in used]
        return part
    layouts = {"image": ("R", "G", "B")} if role == "probes" else LAYER_CHANNELS
    for layer, names in layouts.items():
        present = [c for c in names if c in h.channels]
        if present and len(present) < len(names):
            if layer == "image" and "Y" in h.channels:
                continue
            missing = ", ".join(c for c in names if c not in h.channels)
            raise InputError(p, f"layer {layer!r} of part {name!r} is incomplete: missing {missing}")
        if present:
            take("probes" if role == "probes" else layer, names)
    if "image" not in part.layers and "probes" not in part.layers:
        if "Y" not in h.channels:
            found = ", ".join(sorted(h.channels)) or "none"
            raise InputError(p, f"part {name!r} has no R,G,B or Y channels (found: {found})")
        take("probes" if role == "probes" else "image", ("Y", "Y", "Y"))
    if role == "scene":
        for c in sorted(h.channels):
            if c.startswith(MASK_PREFIX) and len(c) > len(MASK_PREFIX):
                take(c, (c,))
    part.ignored = [c for c in h.channels if c not in used]
    return part
