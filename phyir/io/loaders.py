"""Loading panoramas and scene files, with repairs (:mod:`phyir.io.repairs`)."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable

import torch
from torch import Tensor

from phyir.errors import InputError
from phyir.io.layout import LAYER_CHANNELS, MASK_PREFIX, META_PREFIX, probe_layout
from phyir.io.raw import RawFile, RawPart, read_raw
from phyir.io.repairs import InputWarning, repair
from phyir.scene import PanoScene, SceneError


def load_panorama(path: str | os.PathLike) -> Tensor:
    """The radiance image of a panorama or scene file, float32 [3, H, W], linear, finite, >= 0."""
    raw = read_raw(path)
    return torch.from_numpy(repair(raw.path, "image", _main_part(raw).layers["image"]))


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
            kw[name] = torch.from_numpy(repair(raw.path, name, main.layers[name]))
    masks = {k[len(MASK_PREFIX):]: torch.from_numpy(repair(raw.path, k, v))
             for k, v in main.layers.items() if k.startswith(MASK_PREFIX)}
    meta = {k[len(META_PREFIX):]: v for k, v in main.attrs.items() if k.startswith(META_PREFIX)}
    probes_part = raw.part("probes") if raw.format == "OpenEXR" else None
    if probes_part is not None and probes_part is not main:
        Hp, Wp, ph, pw = probe_layout(raw.path, probes_part.attrs, probes_part.height,
                                       probes_part.width)
        atlas = repair(raw.path, "probes", probes_part.layers["probes"])
        kw["probes"] = torch.from_numpy(atlas.reshape(3, Hp, ph, Wp, pw).transpose(1, 3, 0, 2, 4).copy())
    ignored = [c for part in raw.parts if part in (main, probes_part) for c in part.ignored if c != "A"]
    ignored += [f"part {q.name!r}" for q in raw.parts if q not in (main, probes_part)]
    if ignored:
        warnings.warn(f"{raw.path}: ignored {', '.join(ignored)}", InputWarning, stacklevel=2)
    scene = PanoScene(**kw, masks=masks, meta=meta)
    try:
        return scene.validate(), raw.kind
    except SceneError as e:  # pragma: no cover - repair makes every layer valid
        raise InputError(raw.path, str(e)) from None


def _main_part(raw: RawFile) -> RawPart:
    main = raw.parts[0] if raw.format != "OpenEXR" else (raw.part("scene") or raw.parts[0])
    if "image" not in main.layers:  # pragma: no cover - raw.py guarantees it
        raise InputError(raw.path, "no image layer")
    return main
