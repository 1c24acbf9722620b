"""Scanned rooms with ground-truth depth, in the file layouts 360° depth benchmarks use.

A scan is a panorama (``rgb.png``/``.jpg``/``.exr``/``.hdr``) and its radial depth in metres, in the
project's equirect mapping (docs/conventions.md):

- ``depth.npy``: float, metres;
- ``depth.exr``: a float channel (``Y``, ``Z``, ``depth`` or ``R``), metres;
- ``depth.png``: 16-bit, ``value * scale`` metres, ``scale`` :data:`PNG_SCALE` (Matterport3D's and
  Replica's 1/4000 m) unless a ``scan.json`` beside it says ``{"depth_scale": 0.001953125}``
  (Stanford2D3D's 1/512 m).

A folder is one scan (those files in it), a folder of scan folders, or a folder of pairs
``NAME_rgb.*`` / ``NAME_depth.*``. Invalid depth (0, negative, not finite, or past :data:`MAX_DEPTH`:
the 65535 of a 16-bit hole) is masked out.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from phyir.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".hdr")
DEPTH_SUFFIXES = (".npy", ".exr", ".png")
PNG_SCALE = 1 / 4000  # metres per unit of a 16-bit depth PNG (Matterport3D, Replica)
MIN_DEPTH = 0.05  # metres: nearer is a hole, not a surface
MAX_DEPTH = 100.0  # metres: farther is a hole (the 16-bit maximum) or the sky through a window
EXR_CHANNELS = ("Y", "Z", "depth", "R")


@dataclass(frozen=True)
class Scan:
    """One scanned room: its name, image file and depth file (and the PNG depth scale)."""

    name: str
    image: Path
    depth: Path
    png_scale: float = PNG_SCALE


def _first(folder: Path, stem: str, suffixes: tuple[str, ...]) -> Path | None:
    for s in suffixes:
        for p in (folder / f"{stem}{s}", folder / f"{stem}{s.upper()}"):
            if p.is_file():
                return p
    return None


def _png_scale(folder: Path) -> float:
    meta = folder / "scan.json"
    if not meta.is_file():
        return PNG_SCALE
    try:
        scale = float(json.loads(meta.read_text())["depth_scale"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(meta, f"expected {{\"depth_scale\": metres per unit}} ({e})") from None
    if not 0 < scale < 1e3:
        raise InputError(meta, f"depth_scale {scale} is not a positive number of metres per unit")
    return scale


def _scan_in(folder: Path) -> Scan | None:
    image, depth = _first(folder, "rgb", IMAGE_SUFFIXES), _first(folder, "depth", DEPTH_SUFFIXES)
    if image is None or depth is None:
        return None
    return Scan(folder.name, image, depth, _png_scale(folder))


def find_scans(folder: str | os.PathLike) -> list[Scan]:
    """The scans in ``folder`` (one scan, scan folders, or ``NAME_rgb``/``NAME_depth`` pairs), by name."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "not a folder of scans (rgb.* + depth.* per room)")
    one = _scan_in(root)
    if one is not None:
        return [one]
    scans = [s for d in sorted(root.iterdir()) if d.is_dir() and (s := _scan_in(d)) is not None]
    for img in sorted(root.iterdir()):
        stem = img.stem.removesuffix("_rgb")
        if img.suffix.lower() in IMAGE_SUFFIXES and img.stem.endswith("_rgb"):
            depth = _first(root, f"{stem}_depth", DEPTH_SUFFIXES)
            if depth is not None:
                scans.append(Scan(stem, img, depth, _png_scale(root)))
    if not scans:
        raise InputError(root, "holds no scan: expected rgb.* and depth.{npy,exr,png} (in it or in its "
                               "subfolders) or NAME_rgb.* / NAME_depth.* pairs")
    return sorted(scans, key=lambda s: s.name)


def write_scan(folder: str | os.PathLike, rgb: np.ndarray, depth: Tensor | np.ndarray) -> Scan:
    """Write a scan in the layout :func:`find_scans` reads: ``rgb.png`` (``rgb``: [H,W,3] uint8 sRGB)
    and ``depth.npy`` (radial metres, [H,W] or [1,H,W]), as one set: both land in a new ``folder``
    together or not at all."""
    import shutil
    import tempfile

    from PIL import Image

    root = Path(folder)
    if root.exists():
        raise InputError(root, "already exists: a scan is written into a new folder")
    d = np.asarray(depth, dtype=np.float32).squeeze()
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3 or d.shape != rgb.shape[:2]:
        raise ValueError(f"write_scan: expected rgb [H,W,3] uint8 and depth [H,W], got {rgb.shape} "
                         f"{rgb.dtype} and {list(d.shape)}")
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        Image.fromarray(np.ascontiguousarray(rgb)).save(tmp / "rgb.png")
        np.save(tmp / "depth.npy", d)
        os.replace(tmp, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return Scan(root.name, root / "rgb.png", root / "depth.npy")


def _read_exr_depth(path: Path) -> np.ndarray:
    from phyir.io import exr

    headers = exr.read_headers(path)
    chans = exr.read_pixels(path, headers[:1])[0]
    for c in EXR_CHANNELS:
        if c in chans:
            return chans[c]
    raise InputError(path, f"no depth channel (looked for {', '.join(EXR_CHANNELS)}; has {', '.join(chans)})")


def _read_png_depth(path: Path, scale: float) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        if im.mode not in ("I;16", "I;16B", "I"):
            raise InputError(path, f"expected a 16-bit single-channel depth PNG, got mode {im.mode}")
        raw = np.array(im).astype(np.float64)
    return np.where(raw >= 65535, np.inf, raw * scale)  # the maximum marks a hole


def read_depth(scan: Scan) -> Tensor:
    """Ground-truth radial depth ``[1,H,W]`` float32 in metres; invalid pixels are 0."""
    p = scan.depth
    suffix = p.suffix.lower()
    try:
        if suffix == ".npy":
            d = np.load(p, allow_pickle=False)
        elif suffix == ".exr":
            d = _read_exr_depth(p)
        else:
            d = _read_png_depth(p, scan.png_scale)
    except (OSError, ValueError) as e:
        raise InputError(p, f"unreadable depth ({e})") from None
    d = np.squeeze(np.asarray(d, dtype=np.float64))
    if d.ndim != 2 or d.shape[1] != 2 * d.shape[0]:
        raise InputError(p, f"expected an H x 2H depth map, got shape {list(d.shape)}")
    valid = np.isfinite(d) & (d > MIN_DEPTH) & (d < MAX_DEPTH)
    return torch.from_numpy(np.where(valid, d, 0.0).astype(np.float32))[None]
