"""The full PhyIR model: GMNet -> LNet -> GSNet, in two sizes.

``full`` has the paper's widths; ``lite`` is narrower so it trains and runs on a CPU.
The model works on **exposure-normalised** linear images (see :mod:`phyir.learn.datasets`); use
:meth:`PhyIRModel.predict` for raw HDR or linearised LDR input: it normalises the image and scales
the predicted probes back to the input's units.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from phyir.color import exposure_scale
from phyir.nets.gmnet import GMNet
from phyir.nets.gsnet import GSNet
from phyir.nets.lnet import LNet
from phyir.pano import resize_area
from phyir.scene import PanoScene

SIZE_MULTIPLE = 32  # the GMNet encoder's total stride: H and W must be multiples of it


@dataclass(frozen=True)
class ModelConfig:
    """Architecture hyper-parameters (stored beside weights; see :mod:`phyir.learn.weights`)."""

    size: str = "lite"
    enc_width: float = 0.5
    dec_width: float = 0.25
    norm: str = "group"
    light_width: float = 0.25
    light_head_kernel: int = 1
    light_scale: int = 2  # LNet runs at H/light_scale x W/light_scale (paper: 128x256 for 256x512)
    probe_size: tuple[int, int] = (16, 32)
    probe_block: int = 16  # default probe grid = (H/probe_block) x (W/probe_block)
    gs_width: int = 16
    gs_radius: int = 2
    gs_targets: tuple[str, ...] = ("albedo", "roughness")
    gm_encoder: str = "resnet18"  # or "efficientnet-lite0" (ImageNet-pretrained; phyir.nets.gmnet)

    @staticmethod
    def named(size: str, **overrides) -> ModelConfig:
        if size not in SIZES:
            raise ValueError(f"unknown model size {size!r} (choose from {', '.join(SIZES)})")
        return dataclasses.replace(SIZES[size], **overrides)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> ModelConfig:
        d = dict(d)
        for k in ("probe_size", "gs_targets"):
            if k in d:
                d[k] = tuple(d[k])
        return ModelConfig(**d)


SIZES: dict[str, ModelConfig] = {
    "full": ModelConfig(size="full", enc_width=1.0, dec_width=1.0, light_width=1.0, light_head_kernel=3,
                        gs_width=32),
    "lite": ModelConfig(),
    # lite's LNet and GSNet (so they load from the lite weights) behind a pretrained encoder
    "effnet": ModelConfig(size="effnet", gm_encoder="efficientnet-lite0", dec_width=0.5),
}


class PhyIRModel(nn.Module):
    def __init__(self, config: ModelConfig | str = "lite"):
        super().__init__()
        cfg = ModelConfig.named(config) if isinstance(config, str) else config
        self.config = cfg
        self.gmnet = GMNet(cfg.enc_width, cfg.dec_width, cfg.norm, cfg.gm_encoder)
        self.lnet = LNet(cfg.light_width, cfg.probe_size, cfg.light_head_kernel)
        self.gsnet = GSNet(cfg.gs_width, cfg.gs_radius, cfg.gs_targets)
        # channels-last convolutions are ~1.6x faster on CPU (measured: phyir.bench.profile)
        self.to(memory_format=torch.channels_last)

    def default_grid(self, H: int, W: int) -> tuple[int, int]:
        b = self.config.probe_block
        return max(1, H // b), max(1, W // b)

    def light(self, image: Tensor, gm: dict[str, Tensor], grid: tuple[int, int]) -> Tensor:
        """LNet at 1/light_scale of the input resolution -> probes [B,Hp,Wp,3,h,w]."""
        s = self.config.light_scale
        if s > 1:
            H, W = image.shape[-2:]
            image = resize_area(image, H // s, W // s)
            gm = {k: resize_area(v, H // s, W // s) for k, v in gm.items()}
            gm["normal"] = F.normalize(gm["normal"], dim=1, eps=1e-6)
        return self.lnet(image, gm, grid)

    def forward_parts(self, image: Tensor, grid: tuple[int, int] | None = None, *, light: bool = True,
                      refine: bool = True) -> dict[str, Tensor]:
        """Everything the training losses need: ``gm`` outputs, refined ``*_gs``, ``probes``."""
        check_size(image)
        image = image.contiguous(memory_format=torch.channels_last)
        gm = self.gmnet(image)
        out = dict(gm)
        if light:
            out["probes"] = self.light(image, gm, grid or self.default_grid(*image.shape[-2:]))
        if refine:
            for k, v in self.gsnet(image, gm).items():
                out[f"{k}_gs"] = v
        return out

    def forward(self, image: Tensor, grid: tuple[int, int] | None = None) -> PanoScene:
        """Exposure-normalised image [B,3,H,W] -> batched PanoScene (GSNet-refined materials)."""
        p = {k: v.contiguous() for k, v in self.forward_parts(image, grid).items()}
        layers = {k: p.get(f"{k}_gs", p[k]) for k in ("depth", "normal", "albedo", "roughness", "metallic")}
        return PanoScene(image=image, probes=p["probes"], **layers)

    @torch.no_grad()
    def predict(self, image: Tensor, *, size: tuple[int, int] | None = None,
                grid: tuple[int, int] | None = None) -> PanoScene:
        """Raw linear image [3,H,W] or [B,3,H,W] (HDR, or LDR linearised by the loader) -> scene at the
        input's size whose probes are in the input's radiometric units (the exposure normalisation is
        undone).  The networks run at ``size`` (default: H, W rounded to multiples of 32); per-pixel
        outputs are resampled back to H x W."""
        single = image.dim() == 3
        x = image[None] if single else image
        x = torch.nan_to_num(x.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp(min=0)
        H, W = x.shape[-2:]
        rh, rw = size or (max(SIZE_MULTIPLE, round(H / SIZE_MULTIPLE) * SIZE_MULTIPLE),
                          max(SIZE_MULTIPLE, round(W / SIZE_MULTIPLE) * SIZE_MULTIPLE))
        scale = exposure_scale(x)
        s = scale.view(-1, 1, 1, 1)
        out = self(resize_area(x * s, rh, rw), grid)
        back = {k: resize_area(getattr(out, k), H, W) for k in ("depth", "normal", "albedo", "roughness",
                                                                 "metallic")}
        back["normal"] = F.normalize(back["normal"], dim=1, eps=1e-6)
        out = out.replace(image=x, probes=out.probes / s.view(-1, 1, 1, 1, 1, 1), **back)
        out.meta["exposure_scale"] = " ".join(f"{float(v):.6g}" for v in scale)
        return out[0] if single else out


def check_size(image: Tensor) -> None:
    H, W = image.shape[-2:]
    if image.dim() != 4 or image.shape[1] != 3:
        raise ValueError(f"PhyIRModel: expected an image [B,3,H,W], got {list(image.shape)}")
    if H % SIZE_MULTIPLE or W % SIZE_MULTIPLE:
        raise ValueError(f"PhyIRModel: H and W must be multiples of {SIZE_MULTIPLE}, got {H}x{W}")


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
