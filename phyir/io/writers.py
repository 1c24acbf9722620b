"""Writing panoramas and scene files, atomically (:func:`phyir.io.files.atomic_write`)."""

from __future__ import annotations

import os

import numpy as np
import torch
from torch import Tensor

from phyir.color import linear_to_srgb
from phyir.errors import PhyIRError
from phyir.io import exr, ldr, rgbe
from phyir.io.files import atomic_write
from phyir.io.layout import LAYER_CHANNELS, MASK_PREFIX, META_PREFIX
from phyir.scene import PanoScene


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

    float32 channels by default, float16 with ``half=True``; PIZ compression (lossless, and about
    twice as fast as ZIP on float32 layers).  ``scene.meta`` entries become string attributes
    ``phyir.<key>`` of the ``scene`` part.
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

    def arr(t: Tensor) -> np.ndarray:  # (no copy of a float32 layer written as float32)
        return t.detach().to("cpu", torch.float32).numpy().astype(dtype, copy=False)

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
