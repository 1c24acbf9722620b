"""Contact sheet of predictions on the real panoramas: one row per panorama with the input, depth,
normals, base colour, roughness, metalness, the re-rendering from the predicted layers and probes,
and three of the predicted probes.

    .venv/bin/python scripts/contact_sheet.py -o docs/contact_sheet.png [--weights FILE]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

PANOS = Path(__file__).resolve().parents[2] / "shared" / "panos"
TILE = (128, 256)  # rows x columns of each tile
COLUMNS = ("input", "depth", "normal", "base colour", "roughness", "metalness", "re-render",
           "probe left", "probe centre", "probe right")


def colormap(x: torch.Tensor, name: str = "turbo", lo: float | None = None,
             hi: float | None = None) -> np.ndarray:
    import matplotlib

    a = x[0].float().numpy()
    lo = float(np.percentile(a, 1)) if lo is None else lo
    hi = float(np.percentile(a, 99)) if hi is None else hi
    rgb = matplotlib.colormaps[name](np.clip((a - lo) / max(hi - lo, 1e-9), 0, 1))[..., :3]
    return (rgb * 255 + 0.5).astype(np.uint8)


def row(scene, render_spp: int) -> list[np.ndarray]:
    from phyir.color import exposure_scale, linear_to_srgb, to_srgb8
    from phyir.learn.datasets import resize_scene
    from phyir.pano import resize_area
    from phyir.shading.render import render_scene

    small = resize_scene(scene, *TILE)
    s = float(exposure_scale(small.image)) * 0.7
    def srgb(t):
        return (np.clip(linear_to_srgb(t.float().numpy()), 0, 1) * 255 + 0.5).astype(
        np.uint8).transpose(1, 2, 0)
    normal = ((small.normal * 0.5 + 0.5).clamp(0, 1).numpy().transpose(1, 2, 0) * 255 + 0.5).astype(np.uint8)
    tiles = [to_srgb8(small.image, s), colormap(torch.log(small.depth), "turbo"), normal,
             srgb(small.albedo), colormap(small.roughness, "gray", 0, 1),
             colormap(small.metallic, "gray", 0, 1),
             to_srgb8(render_scene(small, spp=render_spp)["image"], s)]
    Hp, Wp = scene.probe_grid
    for b in (Wp // 4, Wp // 2, 3 * Wp // 4):
        tiles.append(to_srgb8(resize_area(scene.probes[Hp // 2 + Hp // 4, b], *TILE), s))
    return tiles


def main() -> None:
    from phyir.inference import predict
    from phyir.sheets import LIGHT, save_sheet

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", type=Path, default=Path("docs/contact_sheet.png"))
    ap.add_argument("--weights", type=Path, default=None, help="default: the shipped weights")
    ap.add_argument("--panos", type=Path, default=PANOS)
    ap.add_argument("--spp", type=int, default=32, help="samples per pixel of the re-rendering")
    a = ap.parse_args()
    files = sorted(a.panos.glob("*.hdr"))
    if not files:
        raise SystemExit(f"no .hdr panoramas in {a.panos}")
    rows = []
    for f in files:
        t0 = time.perf_counter()
        rows.append((f.name, row(predict(f, weights=a.weights), a.spp)))
        print(f"{f.name}: {time.perf_counter() - t0:.1f} s")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    sheet = save_sheet(a.out, rows, COLUMNS, style=LIGHT)
    print(f"wrote {a.out} ({sheet.width}x{sheet.height})")

if __name__ == "__main__":
    main()
