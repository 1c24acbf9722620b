"""A random camera pipeline: what users' LDR panoramas went through before the loader linearised them.

Exposure, white balance (a colour cast the camera did not remove), one of several tone curves
(filmic ACES, Reinhard, plain clipping with a contrast gamma), sRGB encoding, 8 bits and, often,
JPEG compression; then the loader's sRGB decode. The network learns that clipped, compressed and
tinted inputs are the same room as the HDR ground truth.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from phyir.color import aces, linear_to_srgb, srgb_to_linear


@dataclass(frozen=True)
class CameraPipeline:
    white_balance_stops: float = 0.3  # R and B gains 2^U(-a, a) against G
    curves: tuple[str, ...] = ("aces", "reinhard", "clip")
    clip_gamma: tuple[float, float] = (0.8, 1.25)  # contrast of the "clip" curve
    p_jpeg: float = 0.5
    jpeg_quality: tuple[int, int] = (60, 95)


def tone_curve(x: Tensor, curve: str, gamma: float = 1.0) -> Tensor:
    """Display-referred [0, 1] from scene-linear radiance."""
    if curve == "aces":
        return aces(x)
    if curve == "reinhard":
        return x * (1 + x / 16) / (1 + x)  # white point 4
    if curve == "clip":
        return x.clamp(0, 1) ** gamma
    raise ValueError(f"unknown tone curve {curve!r}")


def jpeg_round_trip(srgb8: np.ndarray, quality: int) -> np.ndarray:
    """8-bit sRGB [H,W,3] through a JPEG encoder and decoder (Pillow)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(srgb8).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert("RGB"))


def encode_srgb8(shown: Tensor) -> np.ndarray:
    """Display-referred values (any shape) as 8-bit sRGB codes."""
    return np.round(linear_to_srgb(shown.detach().cpu().numpy()) * 255).astype(np.uint8)


def decode_srgb8(codes: np.ndarray) -> Tensor:
    """8-bit sRGB codes back to linear values, as the LDR loader decodes them."""
    return torch.from_numpy(np.ascontiguousarray(srgb_to_linear(codes.astype(np.float32) / 255.0)))


def jpeg_linear(ldr: Tensor, quality: int) -> Tensor:
    """A linear 8-bit image [3,H,W] (values in [0, 1]) through a JPEG encoder at ``quality`` and the
    loader's sRGB decode."""
    codes = jpeg_round_trip(encode_srgb8(ldr.permute(1, 2, 0)), quality)
    return decode_srgb8(codes).permute(2, 0, 1).to(ldr)


def hdr_to_ldr_linear(image: Tensor, exposure: float = 1.0) -> Tensor:
    """The fixed camera: ACES at ``exposure``, sRGB, 8 bits, the loader's decode (no white balance or
    JPEG; :func:`simulate_ldr` draws those)."""
    return decode_srgb8(encode_srgb8(aces(image * exposure)))


AUTO_EXPOSURE_KEY = 0.18  # a camera's auto-exposure: the median luminance of the copy


def ldr_copy(hdr: Tensor, exposure: float = 1.0) -> tuple[Tensor, float]:
    """The auto-exposed 8-bit sRGB copy of a linear image [3,H,W], decoded back to linear, and the
    exposure factor: ``clip(hdr × s, 0, 1)`` sRGB-encoded, rounded to 8 bits, decoded, with
    s = ``exposure`` × :data:`AUTO_EXPOSURE_KEY` / median luminance (what a camera's JPEG of the room
    holds; the evaluation's camera, :mod:`phyir.evaluation.real` and ``ldr_light``, and ClipNet's
    validation, at ``exposure`` 1)."""
    from phyir.color import luminance

    x = torch.nan_to_num(hdr.float(), nan=0.0, posinf=0.0).clamp_min(0)
    med = float(luminance(x).median())
    s = exposure * (AUTO_EXPOSURE_KEY / med if med > 0 else 1.0)
    return decode_srgb8(encode_srgb8(x * s)), s


def simulate_ldr(image: Tensor, exposure: float, gen: torch.Generator,
                 camera: CameraPipeline = CameraPipeline()) -> Tensor:
    """Linear radiance ``[3,H,W]`` as the loader would read the photograph a random camera made of it
    at ``exposure`` (the returned image is in the exposed units; divide by ``exposure`` to undo it)."""
    def u() -> float:
        return float(torch.rand((), generator=gen))
    a = camera.white_balance_stops
    gains = torch.tensor([2.0 ** (a * (2 * u() - 1)), 1.0, 2.0 ** (a * (2 * u() - 1))])
    curve = camera.curves[int(u() * len(camera.curves)) % len(camera.curves)]
    g0, g1 = camera.clip_gamma
    shown = tone_curve(image * exposure * gains[:, None, None].to(image), curve, g0 + (g1 - g0) * u())
    codes = encode_srgb8(shown.permute(1, 2, 0))  # (linear_to_srgb clips to [0, 1])
    if u() < camera.p_jpeg:
        q0, q1 = camera.jpeg_quality
        codes = jpeg_round_trip(codes, round(q0 + (q1 - q0) * u()))
    return decode_srgb8(codes).permute(2, 0, 1).to(image)
