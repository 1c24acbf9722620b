"""LDR/HDR training pairs for ClipNet (:mod:`phyir.nets.clipnet`) from HDR panoramas.

Every HDR panorama is an exact pair once a camera is simulated on it: auto-exposure (the median
luminance brought to :data:`phyir.learn.camera.AUTO_EXPOSURE_KEY` times 2^U(-a, a)), a white-balance
cast, a tone curve, 8-bit sRGB codes, often JPEG, then the loader's decode; yaw and mirror at
random. The target is what a linear sensor would have recorded of the same scene under the same
exposure and cast (no clipping): the panorama ClipNet must return where the photograph clipped.

Sources: real HDR photographs (``../shared/hdri-indoor``, its fixed validation split never among
them: :data:`HDRI_VALIDATION`) and path-traced rooms (``phyir synth`` folders, their image layer).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.learn.camera import (
    AUTO_EXPOSURE_KEY,
    decode_srgb8,
    encode_srgb8,
    jpeg_round_trip,
    ldr_copy,
    tone_curve,
)

# ../shared/hdri-indoor/README.md: the fixed validation split (never trained on)
HDRI_VALIDATION = ("colorful_studio_1k", "lythwood_room_1k", "thatch_chapel_1k", "parking_garage_1k",
                   "brown_photostudio_06_1k", "brown_photostudio_07_1k", "peppermint_powerplant_1k")
HDR_SUFFIXES = (".hdr", ".exr")


@dataclass(frozen=True)
class Camera:
    exposure_stops: float = 1.5  # around auto-exposure, 2^U(-a, a)
    white_balance_stops: float = 0.3
    curves: tuple[str, ...] = ("clip", "clip", "clip", "aces", "reinhard")  # plain clipping weighs most
    clip_gamma: tuple[float, float] = (0.9, 1.1)
    p_jpeg: float = 0.5
    jpeg_quality: tuple[int, int] = (70, 95)


def is_validation(path: str | os.PathLike) -> bool:
    return Path(path).stem in HDRI_VALIDATION


def hdr_files(folder: str | os.PathLike, split: str) -> list[Path]:
    """The HDR panoramas of ``folder`` in ``split`` ("train": all but :data:`HDRI_VALIDATION`, "val")."""
    from phyir.io import folder_files

    files = [Path(f) for f in folder_files(folder, HDR_SUFFIXES)]
    return [p for p in files if is_validation(p) == (split == "val")]


def load_panoramas(paths: list[Path], size: tuple[int, int]) -> list[Tensor]:
    """HDR panoramas area-resized to ``size`` (H, W), float32, finite and >= 0."""
    from phyir.io import load_panorama

    out = []
    for p in paths:
        x = torch.nan_to_num(load_panorama(p).float(), nan=0.0, posinf=0.0).clamp_min(0)
        out.append(pano.resize_area(x, *size) if tuple(x.shape[-2:]) != size else x)
    return out


def synthetic_images(folder: str | os.PathLike, size: tuple[int, int],
                     limit: int | None = None) -> list[Tensor]:
    """The image layers of a ``phyir synth`` folder's training split, resized to ``size``."""
    from phyir.io import load_scene
    from phyir.learn.datasets import split_files

    out = []
    for f in split_files(folder, "train", limit):
        x = torch.nan_to_num(load_scene(f).image.float(), nan=0.0, posinf=0.0).clamp_min(0)
        out.append(pano.resize_area(x, *size) if tuple(x.shape[-2:]) != size else x)
    return out


def photograph(hdr: Tensor, gen: torch.Generator, camera: Camera = Camera()) -> tuple[Tensor, Tensor]:
    """``(ldr, target)``: the decoded 8-bit photograph of ``hdr [3,H,W]`` by a random camera, and
    the linear exposure of the same scene with the same cast (unclipped)."""
    def u() -> float:
        return float(torch.rand((), generator=gen))
    med = max(float(luminance(hdr).median()), 1e-8)
    exposure = AUTO_EXPOSURE_KEY / med * 2.0 ** (camera.exposure_stops * (2 * u() - 1))
    a = camera.white_balance_stops
    gains = torch.tensor([2.0 ** (a * (2 * u() - 1)), 1.0, 2.0 ** (a * (2 * u() - 1))])[:, None, None]
    target = hdr * exposure * gains.to(hdr)
    curve = camera.curves[int(u() * len(camera.curves)) % len(camera.curves)]
    g0, g1 = camera.clip_gamma
    codes = encode_srgb8(tone_curve(target, curve, g0 + (g1 - g0) * u()).permute(1, 2, 0))
    if u() < camera.p_jpeg:
        q0, q1 = camera.jpeg_quality
        codes = jpeg_round_trip(codes, round(q0 + (q1 - q0) * u()))
    return decode_srgb8(codes).permute(2, 0, 1).to(hdr), target


def fixed_photograph(hdr: Tensor) -> tuple[Tensor, Tensor]:
    """``(ldr, target)`` through the evaluation's camera (:func:`phyir.learn.camera.ldr_copy`:
    auto-exposed, clipped, 8-bit sRGB, no cast, no JPEG)."""
    ldr, exposure = ldr_copy(hdr)
    return ldr.to(hdr), hdr * exposure


def random_view(x: Tensor, gen: torch.Generator) -> Tensor:
    """A random yaw (whole columns) and, half the time, the mirror image."""
    x = torch.roll(x, int(torch.randint(x.shape[-1], (), generator=gen)), -1)
    return x.flip(-1) if float(torch.rand((), generator=gen)) < 0.5 else x


def batch(images: list[Tensor], count: int, gen: torch.Generator, size: tuple[int, int],
          camera: Camera = Camera()) -> tuple[Tensor, Tensor]:
    """``count`` random pairs ``(ldr, target)`` [B,3,H,W] at ``size``: each photographed at its
    stored size (cameras clip at full resolution), then both area-resized."""
    ldrs, targets = [], []
    for i in np.asarray(torch.randint(len(images), (count,), generator=gen)):
        ldr, target = photograph(random_view(images[int(i)], gen), gen, camera)
        ldrs.append(pano.resize_area(ldr, *size))
        targets.append(pano.resize_area(target, *size))
    return torch.stack(ldrs), torch.stack(targets)
