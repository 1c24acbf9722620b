"""Reading and writing panoramas and scene files (format spec: docs/file-formats.md).

* ``load_panorama(path) -> Tensor[3,H,W]`` and ``load_scene(path) -> PanoScene`` read OpenEXR
  (plain or PhyIR scene files), Radiance ``.hdr`` and 8/16-bit PNG/JPEG (sRGB decoded to linear).
  The format is recognised by the file's signature, not its name.
* ``save_panorama(t, path)`` writes by extension: ``.exr``, ``.hdr``, ``.png`` (8 or 16 bit, sRGB),
  ``.jpg``; ``save_scene(scene, path)`` writes the multi-part scene ``.exr``.
* Every write is atomic (:func:`atomic_write`).
* Unusable input raises :class:`InputError` ("<file>: <problem>").  Repairable input (NaN/Inf,
  negative radiance, out-of-range layers) is repaired and reported with :class:`InputWarning`;
  a returned tensor never holds NaN or Inf.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from phyir.color import linear_to_srgb
from phyir.errors import InputError, PhyIRError
from phyir.io import exr, files, ldr, rgbe
from phyir.io.files import (
    AtomicSet,
    atomic_files,
    atomic_write,
    check_input,
    check_output,
    folder_files,
    is_temporary,
)
from phyir.io.sniff import (
    ASPECT_TOL,
    MAX_SIZE,
    MIN_SIZE,
    check_expansion,
    check_panorama_size,
    check_size,
    header_size,
    sniff,
)
from phyir.pano import directions
from phyir.scene import NORMAL_TOL, PanoScene, SceneError

__all__ = [
    "InputError", "InputWarning", "AtomicSet", "atomic_write", "atomic_files", "check_input", "check_output",
    "folder_files", "is_temporary", "load_panorama", "load_scene", "save_panorama",
    "save_scene", "read_raw", "read_scene", "check_panorama_size", "check_size", "header_size", "sniff",
    "LAYER_CHANNELS", "MIN_SIZE", "MAX_SIZE", "ASPECT_TOL",
]

META_PREFIX = "phyir."

# channel names of each layer in the scene part (docs/file-formats.md)
LAYER_CHANNELS: dict[str, tuple[str, ...]] = {
    "image": ("R", "G", "B"),
    "depth": ("depth.Z",),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "roughness": ("roughness.Y",),
    "metallic": ("metallic.Y",),
}
MASK_PREFIX = "mask."
_RANGES = {"image": (0.0, None), "probes": (0.0, None), "depth": (0.0, None), "albedo": (0.0, 1.0),
           "roughness": (0.0, 1.0), "metallic": (0.0, 1.0), "mask": (0.0, 1.0)}


class InputWarning(UserWarning):
    """Input that was usable after a repair (NaN/Inf replaced, negatives clamped, ...)."""


# ---------------------------------------------------------------------------------------------
# raw reading: what a file holds, before any repair (used by the loaders and ``phyir info``)


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
        _probe_layout(p, probes.strings, probes.height, probes.width)  # refuse before decoding
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


def _probe_layout(p: str, attrs: dict[str, str], H: int, W: int) -> tuple[int, int, int, int]:
    """(Hp, Wp, h, w) from the probes part's attributes, checked against its H x W atlas."""
    grid, size = attrs.get("probeGrid"), attrs.get("probeSize")
    try:
        Hp, Wp = (int(v) for v in grid.split("x"))  # type: ignore[union-attr]
        ph, pw = (int(v) for v in size.split("x"))  # type: ignore[union-attr]
    except (AttributeError, ValueError):
        raise InputError(p, f"probes part: probeGrid {grid!r} / probeSize {size!r} are not "
                            "strings of the form 'AxB'") from None
    if min(Hp, Wp, ph, pw) < 1 or (Hp * ph, Wp * pw) != (H, W):
        raise InputError(p, f"probes part: probeGrid {grid} x probeSize {size} does not match the "
                            f"atlas size {H}x{W}")
    return Hp, Wp, ph, pw


# ---------------------------------------------------------------------------------------------
# loading with repairs


def load_panorama(path: str | os.PathLike) -> Tensor:
    """The radiance image of a panorama or scene file, float32 [3, H, W], linear, finite, >= 0."""
    raw = read_raw(path)
    return torch.from_numpy(_repair(raw.path, "image", _main_part(raw).layers["image"]))


def load_scene(path: str | os.PathLike) -> PanoScene:
    """Every layer, probe and mask of a scene file; a plain image loads as a scene with ``image`` only.

    Repairs (each reported once per layer with :class:`InputWarning`): NaN -> 0 (normals: facing
    the camera), +-Inf -> the layer's largest/smallest finite value, values outside a layer's
    range clamped, non-unit normals renormalised.  The result passes ``PanoScene.validate``.
    """
    return read_scene(path)[0]


def read_scene(path: str | os.PathLike,
               limit: Callable[[str, int, int], None] | None = None) -> tuple[PanoScene, str]:
    """:func:`load_scene` and the file's format ("exr", "hdr", "png", "jpeg"), the file sniffed once;
    ``limit(path, H, W)`` is checked from the header before decoding (see :func:`read_raw`)."""
    raw = read_raw(path) if limit is None else read_raw(path, limit=limit)
    main = _main_part(raw)
    kw: dict = {}
    for name in LAYER_CHANNELS:
        if name in main.layers:
            kw[name] = torch.from_numpy(_repair(raw.path, name, main.layers[name]))
    masks = {k[len(MASK_PREFIX):]: torch.from_numpy(_repair(raw.path, k, v))
             for k, v in main.layers.items() if k.startswith(MASK_PREFIX)}
    meta = {k[len(META_PREFIX):]: v for k, v in main.attrs.items() if k.startswith(META_PREFIX)}
    probes_part = raw.part("probes") if raw.format == "OpenEXR" else None
    if probes_part is not None and probes_part is not main:
        Hp, Wp, ph, pw = _probe_layout(raw.path, probes_part.attrs, probes_part.height,
                                       probes_part.width)
        atlas = _repair(raw.path, "probes", probes_part.layers["probes"])
        kw["probes"] = torch.from_numpy(atlas.reshape(3, Hp, ph, Wp, pw).transpose(1, 3, 0, 2, 4).copy())
    ignored = [c for part in raw.parts if part in (main, probes_part) for c in part.ignored if c != "A"]
    ignored += [f"part {q.name!r}" for q in raw.parts if q not in (main, probes_part)]
    if ignored:
        warnings.warn(f"{raw.path}: ignored {', '.join(ignored)}", InputWarning, stacklevel=2)
    scene = PanoScene(**kw, masks=masks, meta=meta)
    try:
        return scene.validate(), raw.kind
    except SceneError as e:  # pragma: no cover - _repair makes every layer valid
        raise InputError(raw.path, str(e)) from None


def _main_part(raw: RawFile) -> RawPart:
    main = raw.parts[0] if raw.format != "OpenEXR" else (raw.part("scene") or raw.parts[0])
    if "image" not in main.layers:  # pragma: no cover - _exr_part guarantees it
        raise InputError(raw.path, "no image layer")
    return main


def _repair(path: str, layer: str, a: np.ndarray) -> np.ndarray:
    """Make one layer finite and in range, warning once with the counts of what was changed.  Works
    in place on a contiguous float32 layer (the callers' raw arrays are theirs alone)."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    notes = []
    bad = ~np.isfinite(a)
    if layer == "normal":
        return _repair_normals(path, a)
    if bad.any():
        n_nan = int(np.isnan(a).sum())
        fin = a[~bad]
        hi, lo = (float(fin.max()), float(fin.min())) if fin.size else (0.0, 0.0)
        np.nan_to_num(a, copy=False, nan=0.0, posinf=hi, neginf=lo)
        notes.append(f"replaced {n_nan} NaN (by 0) and {int(bad.sum()) - n_nan} Inf values "
                     "(by the largest/smallest finite value)")
    lo, hi = _RANGES["mask" if layer.startswith(MASK_PREFIX) else layer]
    if lo is not None and (below := int((a < lo).sum())):
        what = "negative radiance" if layer in ("image", "probes") else f"values below {lo:g}"
        notes.append(f"clamped {below} {what} to {lo:g}")
        np.maximum(a, lo, out=a)
    if hi is not None and (above := int((a > hi).sum())):
        notes.append(f"clamped {above} values above {hi:g}")
        np.minimum(a, hi, out=a)
    if notes:
        warnings.warn(f"{path}: {layer}: {'; '.join(notes)}", InputWarning, stacklevel=3)
    return a


def _repair_normals(path: str, n: np.ndarray) -> np.ndarray:
    """Non-finite or zero normals face the camera (-d); other non-unit normals are renormalised."""
    length = np.sqrt(np.nan_to_num(n * n, nan=0.0, posinf=np.inf).sum(0))
    broken = ~np.isfinite(n).all(0) | (length < 1e-6)
    off = ~broken & (np.abs(length - 1) > NORMAL_TOL)
    notes = []
    if broken.any():
        d = directions(*n.shape[1:]).numpy()
        n = np.where(broken[None], -d, n)
        notes.append(f"{int(broken.sum())} NaN/Inf/zero normals set to face the camera")
    if off.any():
        n = np.where(off[None], n / np.where(off, length, 1.0)[None], n)
        notes.append(f"renormalised {int(off.sum())} normals that were not unit length")
    if notes:
        warnings.warn(f"{path}: normal: {'; '.join(notes)}", InputWarning, stacklevel=4)
    return n.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# writing


def save_panorama(t: Tensor, path: str | os.PathLike, *, bits: int = 8, half: bool = False,
                  quality: int = 95) -> None:
    """Write a linear radiance image [3, H, W] by extension, atomically.

    ``.exr``: float32 (``half=True``: float16) channels R,G,B in a part named ``scene``.
    ``.hdr``: RGBE, negatives written as 0.  ``.png``: sRGB-encoded, clipped to [0, 1], ``bits`` 8
    or 16.  ``.jpg``/``.jpeg``: sRGB 8-bit, ``quality``.  Non-finite values raise ValueError.
    """
    p = os.fspath(path)
    a = _as_image_array(t)
    ext = os.path.splitext(p)[1].lower()
    if ext == ".exr":
        _write_scene_exr(p, PanoScene(image=torch.from_numpy(a)), half)
        return
    hwc = a.transpose(1, 2, 0)
    if ext == ".hdr":
        data = rgbe.encode(hwc)
        with atomic_write(p) as tmp, open(tmp, "wb") as f:
            f.write(data)
    elif ext == ".png" and bits == 16:
        data = ldr.encode_png16(np.round(linear_to_srgb(hwc) * 65535).astype(np.uint16))
        with atomic_write(p) as tmp, open(tmp, "wb") as f:
            f.write(data)
    elif ext in (".png", ".jpg", ".jpeg"):
        if bits != 8:
            raise ValueError(f"save_panorama: {bits}-bit output is not supported for {ext}")
        from PIL import Image

        im = Image.fromarray(np.round(linear_to_srgb(hwc) * 255).astype(np.uint8), "RGB")
        with atomic_write(p) as tmp:
            if ext == ".png":
                im.save(tmp, format="PNG")
            else:
                im.save(tmp, format="JPEG", quality=quality)
    else:
        raise PhyIRError(f"{p}: unsupported output format {ext or '(no extension)'} "
                         "(use .exr, .hdr, .png or .jpg)")


def _as_image_array(t: Tensor) -> np.ndarray:
    if not isinstance(t, Tensor) or t.dim() != 3 or t.shape[0] != 3:
        got = list(t.shape) if isinstance(t, Tensor) else type(t).__name__
        raise ValueError(f"save_panorama: expected a tensor [3, H, W], got {got}")
    a = t.detach().to("cpu", torch.float32).numpy()
    if not np.isfinite(a).all():
        raise ValueError(f"save_panorama: image has {int((~np.isfinite(a)).sum())} NaN/Inf values")
    return a


def save_scene(scene: PanoScene, path: str | os.PathLike, *, half: bool = False) -> None:
    """Write a (validated, unbatched) scene as a multi-part OpenEXR file, atomically.

    float32 channels by default, float16 with ``half=True``; ZIP compression.  ``scene.meta``
    entries become string attributes ``phyir.<key>`` of the ``scene`` part.
    """
    p = os.fspath(path)
    if os.path.splitext(p)[1].lower() != ".exr":
        raise PhyIRError(f"{p}: scene files are OpenEXR; use a .exr file name")
    if scene.batched:
        raise ValueError("save_scene: expected an unbatched scene (index the batch first)")
    scene.validate()
    _write_scene_exr(p, scene, half)


def _write_scene_exr(p: str, scene: PanoScene, half: bool) -> None:
    dtype = np.float16 if half else np.float32

    def arr(t: Tensor) -> np.ndarray:
        return t.detach().to("cpu", torch.float32).numpy().astype(dtype)

    chans: dict[str, np.ndarray] = {}
    for name, names in LAYER_CHANNELS.items():
        t = getattr(scene, name)
        if t is not None:
            chans.update(zip(names, arr(t)))
    for k, m in scene.masks.items():
        chans[MASK_PREFIX + k] = arr(m)[0]
    attrs = {}
    for k, v in scene.meta.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise ValueError(f"save_scene: meta entries must be str -> str, got {k!r}: {type(v).__name__}")
        attrs[META_PREFIX + k] = v
    parts = [("scene", attrs, chans)]
    if scene.probes is not None:
        Hp, Wp, _, ph, pw = scene.probes.shape
        atlas = arr(scene.probes).transpose(2, 0, 3, 1, 4).reshape(3, Hp * ph, Wp * pw)
        parts.append(("probes", {"probeGrid": f"{Hp}x{Wp}", "probeSize": f"{ph}x{pw}"},
                      dict(zip("RGB", atlas))))
    with atomic_write(p) as tmp:
        exr.write_parts(tmp, parts)
