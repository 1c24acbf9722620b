"""HDR from an 8-bit panorama with ClipNet (:mod:`phyir.nets.clipnet`): the clipped light given back.

ClipNet runs at :data:`NET_SIZE` on the area-resized panorama; its log gain is brought back to the
input's size bilinearly (wrapping in longitude) and applied where the input is clipped at full
resolution, so every unclipped pixel keeps its value. Its weights (``phyir/assets/weights/
clipnet.safetensors``, float16, with a JSON sidecar of what it was trained on) come from
:mod:`phyir.learn.train_clipnet`; where they are absent, :mod:`phyir.lighting.hdr_recovery`'s
calibrated gain per clipped region is used instead.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.nets.clipnet import ClipNet, apply_gain, clip_weight

WEIGHTS = Path(__file__).resolve().parents[1] / "assets" / "weights" / "clipnet.safetensors"
NET_SIZE = (128, 256)
_CACHE: dict[str, ClipNet] = {}
_LOCK = threading.Lock()


def save_clipnet(model: ClipNet, path: str | os.PathLike, info: dict) -> Path:
    """Float16 weights and their sidecar ``.json`` (``info``: what it was trained on), atomically."""
    from safetensors.torch import save

    from phyir.io import atomic_write

    path = Path(path)
    state = {k: v.detach().half().contiguous() for k, v in model.state_dict().items()}
    with atomic_write(path) as tmp:
        Path(tmp).write_bytes(save(state, metadata={"format": "phyir-clipnet-1"}))
    with atomic_write(path.with_suffix(".json")) as tmp:
        Path(tmp).write_text(json.dumps(info, indent=1) + "\n")
    return path


def load_clipnet(path: str | os.PathLike | None = None) -> ClipNet | None:
    """The trained ClipNet (cached), or None where there are no weights."""
    from safetensors.torch import load_file

    p = Path(path) if path is not None else WEIGHTS
    if not p.is_file():
        return None
    with _LOCK:
        if str(p) not in _CACHE:
            model = ClipNet()
            model.load_state_dict({k: v.float() for k, v in load_file(str(p)).items()})
            _CACHE[str(p)] = model.eval()
        return _CACHE[str(p)]


def upsample_wrapped(x: Tensor, H: int, W: int) -> Tensor:
    """Bilinear resampling of [B,C,h,w] to H x W, wrapping in longitude."""
    h, w = x.shape[-2:]
    padded = torch.cat((x[..., -1:], x, x[..., :1]), -1)
    scale = W / w
    y = F.interpolate(padded, size=(H, round((w + 2) * scale)), mode="bilinear", align_corners=False)
    off = round(scale)  # the padded column's width at the output's scale
    return y[..., off:off + W]


@torch.inference_mode()
def log_gain(model: ClipNet, ldr: Tensor) -> Tensor:
    """ClipNet's log gain [1,H,W] for an LDR panorama [3,H,W] (linear, clipped at 1)."""
    H, W = ldr.shape[-2:]
    small = pano.resize_area(ldr.float().clamp(0, 1), *NET_SIZE)[None]
    g = model(small)
    return (upsample_wrapped(g, H, W) if (H, W) != NET_SIZE else g)[0]


def recover(ldr: Tensor, model: ClipNet) -> tuple[Tensor, float, float]:
    """``(hdr, clipped solid angle in sr, energy after / before)`` of an LDR panorama [3,H,W]."""
    H, W = ldr.shape[-2:]
    x = ldr.float()
    out = apply_gain(x[None], log_gain(model, x)[None])[0]
    omega = pano.solid_angles(H, W, x.device, x.dtype)
    sr = float((clip_weight(x[None].clamp(0, 1))[0, 0] * omega).sum())
    before = float((x.mean(0) * omega).sum())
    return out, sr, float((out.mean(0) * omega).sum()) / max(before, 1e-30)
