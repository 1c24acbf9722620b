"""Procedural tiny scenes for the network, loss, training and robustness tests (no files, seconds to
build), and a dataset of them on disk in ``phyir synth``'s format."""

from __future__ import annotations

import math

import torch

from phyir.pano import directions, normals_from_depth
from phyir.scene import PanoScene
from phyir.synth import analytic


def ellipsoid_depth(H: int, W: int, half: tuple[float, ...]) -> torch.Tensor:
    """Radial depth [1,H,W] of an ellipsoidal room centred on the camera (smooth everywhere)."""
    d = directions(H, W, dtype=torch.float64)
    inv = sum((d[a] / half[a]) ** 2 for a in range(3))
    return inv.rsqrt()[None].float()


def tiny_scene(seed: int, H: int = 64, W: int = 128, grid: tuple[int, int] = (4, 8),
               probe_size: tuple[int, int] = (8, 16), room: str = "box") -> PanoScene:
    """A box (or ellipsoidal) room with smooth random materials, a light-dependent image and smooth
    probes."""
    g = torch.Generator().manual_seed(seed)
    def r(*s):
        return torch.rand(*s, generator=g)
    half = (2 + 2 * float(r(())), 1.3 + 0.3 * float(r(())), 2 + 2 * float(r(())))
    centre = (0.5 * (2 * float(r(())) - 1), 0.2 * (2 * float(r(())) - 1), 0.5 * (2 * float(r(())) - 1))
    if room == "box":  # the box half-extents ``half`` around ``centre``, seen from the origin
        lo = [-h - c for h, c in zip(half, centre)]
        hi = [h - c for h, c in zip(half, centre)]
        depth = analytic.box_room(H, W, lo, hi)[0].float()
    else:
        depth = ellipsoid_depth(H, W, half)
    normal = normals_from_depth(depth)

    def smooth(ch: int) -> torch.Tensor:
        x = r(1, ch, H // 8, W // 8)
        x = torch.cat((x, x[..., :1]), -1)  # periodic in longitude
        y = torch.nn.functional.interpolate(x, size=(H, W + 1), mode="bilinear", align_corners=True)
        return y[0, :, :, :W]

    albedo = 0.1 + 0.8 * smooth(3)
    roughness = 0.2 + 0.7 * smooth(1)
    metallic = ((smooth(1) - 0.6) * 3).clamp(0, 1)  # mostly dielectric, a few metal patches
    # light from above: a simple, depth- and normal-dependent shading
    up = normal[1:2].clamp(min=0)
    light = 0.3 + 2.0 * up + 0.5 / depth
    image = (albedo * light).clamp(min=0)
    emission = torch.zeros(1, H, W)
    emission[:, : H // 16, W // 4: W // 4 + W // 16] = 1.0
    image = torch.where(emission > 0, torch.full_like(image, 30.0), image)
    Hp, Wp = grid
    h, w = probe_size
    env_dirs = directions(h, w)
    sky = 0.2 + 5.0 * env_dirs[1:2].clamp(min=0) ** 4  # bright ceiling
    pos = torch.linspace(0, 1, Hp)[:, None] + torch.linspace(0, 1, Wp)[None, :]
    gain = 1 + 0.5 * torch.sin(math.pi * pos)
    probes = (sky[None, None] * gain[:, :, None, None, None]).expand(Hp, Wp, 3, h, w).clone()
    return PanoScene(image=image, depth=depth, normal=normal, albedo=albedo, roughness=roughness,
                     metallic=metallic, probes=probes, masks={"emission": emission}).validate()


def tiny_scenes(n: int, **kw) -> list[PanoScene]:
    return [tiny_scene(1000 + i, **kw) for i in range(n)]


def write_dataset(root, n_train: int = 4, n_val: int = 2, **kw) -> None:
    """Procedural scenes as scene files + a manifest in `phyir synth`'s format."""
    import json
    from pathlib import Path

    from phyir.io import save_scene

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    splits = {"train": [], "val": [], "test": []}
    for i, s in enumerate(tiny_scenes(n_train + n_val, **kw)):
        name = f"scene_{i:06d}.exr"
        save_scene(s, root / name)
        splits["train" if i < n_train else "val"].append(name)
    (root / "manifest.json").write_text(json.dumps({"generator": "tests", "splits": splits}))
