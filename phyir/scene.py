"""``PanoScene``: the one data type that flows through PhyIR (I/O, synthesis, networks, viewer)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import torch
from torch import Tensor

from phyir.errors import PhyIRError

# metres along the normal from the surface point seen through a block's centre to its probe
# (docs/conventions.md): the generator, projection lighting and the viewer all place probes so
PROBE_OFFSET = 0.05

# name -> channel count of the per-pixel layers, in file/display order
PIXEL_LAYERS: dict[str, int] = {
    "image": 3,
    "depth": 1,
    "normal": 3,
    "albedo": 3,
    "roughness": 1,
    "metallic": 1,
}
# value ranges checked by validate(); None = unbounded on that side
_RANGES: dict[str, tuple[float | None, float | None]] = {
    "image": (0.0, None),
    "depth": (0.0, None),
    "albedo": (0.0, 1.0),
    "roughness": (0.0, 1.0),
    "metallic": (0.0, 1.0),
    "probes": (0.0, None),
}
NORMAL_TOL = 1e-2  # |‖n‖ - 1| allowed for normals


class SceneError(PhyIRError, ValueError):
    """A PanoScene whose fields are inconsistent or out of range; the message names the field."""


@dataclass
class PanoScene:
    """An indoor panorama and its layers, torch float32, channels first.

    Unbatched shapes: ``image [3,H,W]``, ``depth [1,H,W]``, ``normal [3,H,W]``, ``albedo [3,H,W]``,
    ``roughness [1,H,W]``, ``metallic [1,H,W]``, ``probes [Hp,Wp,3,h,w]``, ``masks[name] [1,H,W]``.
    A batch of scenes carries one extra leading dimension on every tensor (see :meth:`stack`).
    Every field but ``image`` may be ``None``.  ``meta`` holds string attributes (source file,
    exposure scale, ...), carried through files as EXR header attributes.
    """

    image: Tensor
    depth: Tensor | None = None
    normal: Tensor | None = None
    albedo: Tensor | None = None
    roughness: Tensor | None = None
    metallic: Tensor | None = None
    probes: Tensor | None = None
    masks: dict[str, Tensor] = field(default_factory=dict)
    meta: dict[str, str] = field(default_factory=dict)

    # -- shape helpers -------------------------------------------------------------------------
    @property
    def batched(self) -> bool:
        return self.image.dim() == 4

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) of the panorama."""
        return tuple(self.image.shape[-2:])  # type: ignore[return-value]

    @property
    def probe_grid(self) -> tuple[int, int] | None:
        """(Hp, Wp) of the probe grid, or None."""
        return None if self.probes is None else tuple(self.probes.shape[-5:-3])  # type: ignore

    @property
    def probe_size(self) -> tuple[int, int] | None:
        """(h, w) of each probe, or None."""
        return None if self.probes is None else tuple(self.probes.shape[-2:])  # type: ignore

    def layers(self) -> Iterator[tuple[str, Tensor]]:
        """The per-pixel layers present, in canonical order (image first), then masks as ``mask.<n>``."""
        for name in PIXEL_LAYERS:
            t = getattr(self, name)
            if t is not None:
                yield name, t
        for name, t in self.masks.items():
            yield f"mask.{name}", t

    def has(self, *names: str) -> bool:
        return all(getattr(self, n) is not None for n in names)

    # -- transforms ----------------------------------------------------------------------------
    def replace(self, **changes) -> PanoScene:
        return dataclasses.replace(self, **changes)

    def map(self, fn) -> PanoScene:
        """Apply ``fn`` to every tensor (including probes and masks)."""
        kw = {n: (None if getattr(self, n) is None else fn(getattr(self, n)))
              for n in (*PIXEL_LAYERS, "probes")}
        return PanoScene(**kw, masks={k: fn(v) for k, v in self.masks.items()}, meta=dict(self.meta))

    def to(self, device=None, dtype=None) -> PanoScene:
        return self.map(lambda t: t.to(device=device, dtype=dtype if t.is_floating_point() else None))

    def detach(self) -> PanoScene:
        return self.map(lambda t: t.detach())

    @staticmethod
    def stack(scenes: list[PanoScene]) -> PanoScene:
        """Batch unbatched scenes; a field is kept only if every scene has it."""
        if not scenes:
            raise SceneError("PanoScene.stack: empty list")
        kw = {}
        for n in (*PIXEL_LAYERS, "probes"):
            vals = [getattr(s, n) for s in scenes]
            kw[n] = torch.stack(vals) if all(v is not None for v in vals) else None
        common = set.intersection(*(set(s.masks) for s in scenes))
        masks = {k: torch.stack([s.masks[k] for s in scenes]) for k in sorted(common)}
        return PanoScene(**kw, masks=masks, meta=dict(scenes[0].meta))

    def __getitem__(self, i: int) -> PanoScene:
        """The i-th scene of a batch."""
        if not self.batched:
            raise SceneError("PanoScene: indexing needs a batched scene")
        return self.map(lambda t: t[i])

    # -- validation ----------------------------------------------------------------------------
    def validate(self) -> PanoScene:
        """Check shapes, ranges and finiteness; raise :class:`SceneError` naming the field."""
        img = self.image
        if not isinstance(img, Tensor):
            raise SceneError(f"image: expected a torch.Tensor, got {type(img).__name__}")
        if img.dim() not in (3, 4) or img.shape[-3] != 3:
            raise SceneError(f"image: expected shape [3,H,W] or [B,3,H,W], got {list(img.shape)}")
        lead = img.shape[:-3]
        H, W = img.shape[-2:]
        for name, ch in PIXEL_LAYERS.items():
            t = getattr(self, name)
            if t is None:
                continue
            want = (*lead, ch, H, W)
            if not isinstance(t, Tensor) or tuple(t.shape) != want:
                got = list(t.shape) if isinstance(t, Tensor) else type(t).__name__
                raise SceneError(f"{name}: expected shape {list(want)}, got {got}")
            self._check_values(name, t)
        for name, t in self.masks.items():
            want = (*lead, 1, H, W)
            if tuple(t.shape) != want:
                raise SceneError(f"mask.{name}: expected shape {list(want)}, got {list(t.shape)}")
        if self.normal is not None:
            n = self.normal.float()
            norm = torch.sqrt((n * n).sum(-3))  # (vector_norm over the channel axis is ~20x slower on CPU)
            bad = (norm - 1).abs() > NORMAL_TOL
            if bad.any():
                raise SceneError(f"normal: {int(bad.sum())} pixels are not unit length "
                                 f"(|n| in [{norm.min():.3g}, {norm.max():.3g}])")
        if self.probes is not None:
            p = self.probes
            if p.dim() != len(lead) + 5 or tuple(p.shape[:len(lead)]) != tuple(lead) or p.shape[-3] != 3:
                want = f"[{'B,' * len(lead)}Hp,Wp,3,h,w]"
                raise SceneError(f"probes: expected shape {want}, got {list(p.shape)}")
            self._check_values("probes", p)
        return self

    @staticmethod
    def _check_values(name: str, t: Tensor) -> None:
        if not t.is_floating_point():
            raise SceneError(f"{name}: expected a floating-point tensor, got {t.dtype}")
        if not t.numel():
            return
        t_min, t_max = (float(v) for v in torch.aminmax(t))  # one pass: NaN or inf show in these
        if not (math.isfinite(t_min) and math.isfinite(t_max)):
            raise SceneError(f"{name}: {int((~torch.isfinite(t)).sum())} non-finite values (NaN/Inf)")
        lo, hi = _RANGES.get(name, (None, None))
        if lo is not None and t_min < lo:
            raise SceneError(f"{name}: values below {lo} (min {t_min:.4g})")
        if hi is not None and t_max > hi + 1e-6:
            raise SceneError(f"{name}: values above {hi} (max {t_max:.4g})")
