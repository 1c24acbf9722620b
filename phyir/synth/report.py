"""Contact sheet and statistics of a generated dataset.

``python -m phyir.synth.report DIR [--sheet PNG] [--stats JSON] [--count 24]``: one row per scene
(tonemapped image, depth, normal, base colour, roughness, metalness, three probes) and a JSON
summary (light counts, sun share, metal fraction, depth range, room sizes, render time).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from phyir.color import to_srgb8
from phyir.pano import resize_area


def _gray(x: torch.Tensor, lo: float, hi: float) -> np.ndarray:
    y = ((x[0] - lo) / max(hi - lo, 1e-6)).clamp(0, 1).numpy()
    return (np.repeat(y[..., None], 3, 2) * 255).astype(np.uint8)


def scene_tiles(scene, height: int = 64) -> list[np.ndarray]:
    """One contact-sheet row's tiles: image, depth, normal, base colour, roughness, metalness and three
    probes (half height, black below)."""
    size = (height, 2 * height)
    def r(t):
        return resize_area(t, *size)
    nonem = scene.masks["emission"] < 0.5
    k = 0.5 / max(float(scene.image.mean(0)[nonem[0]].median()), 1e-6) if bool(nonem.any()) else 1.0
    tiles = [to_srgb8(r(scene.image), k), _gray(r(scene.depth), 0, float(scene.depth.max())),
             ((r(scene.normal).permute(1, 2, 0).numpy() * 0.5 + 0.5).clip(0, 1) * 255).astype(np.uint8),
             (r(scene.albedo).clamp(0, 1).permute(1, 2, 0).numpy() ** (1 / 2.2) * 255).astype(np.uint8),
             _gray(r(scene.roughness), 0, 1), _gray(r(scene.metallic), 0, 1)]
    if scene.probes is not None:
        Hp, Wp = scene.probe_grid
        for b in (Wp // 8, Wp // 2, 5 * Wp // 8):
            t = to_srgb8(resize_area(scene.probes[Hp // 2 + Hp // 8, b], height // 2, height), k)
            tiles.append(np.concatenate([t, np.zeros((height - t.shape[0], t.shape[1], 3), np.uint8)], 0))
    return tiles


def contact_sheet(paths: list[Path], out: Path, height: int = 64) -> Path:
    """One row of :func:`scene_tiles` per scene, no labels, written atomically as PNG."""
    from phyir.io import load_scene
    from phyir.sheets import BARE, save_sheet

    out.parent.mkdir(parents=True, exist_ok=True)
    save_sheet(out, [("", scene_tiles(load_scene(p), height)) for p in paths], style=BARE)
    return out


def statistics(paths: list[Path]) -> dict:
    """Dataset statistics from the scene files' metadata and layers."""
    from phyir.io import load_scene

    light_counts, suns, metal, dmin, dmax, dmed, secs, widths, heights, ratio, src = ([] for _ in range(11))
    by_kind = {"lamp": [], "sky": [], "sun": []}
    kinds = {"rect": 0, "L": 0}
    for p in paths:
        s = load_scene(p)
        lights = json.loads(s.meta["lights"])
        light_counts.append(lights["panels_and_lamps"] + lights["windows"])
        suns.append(lights["sun"])
        metal.append(float(s.meta["metal_fraction"]))
        d = s.depth[0]
        dmin.append(float(d.min()))
        dmax.append(float(d.max()))
        dmed.append(float(d.median()))
        secs.append(float(s.meta["render_seconds"]))
        room = json.loads(s.meta["room"])
        kinds[room["kind"]] += 1
        widths += [room["width"], room["depth"]]
        heights.append(room["height"])
        # dynamic range: brightest emitter pixel over the median lit non-emissive pixel
        em = s.masks["emission"][0] > 0.5
        lum = s.image.mean(0)
        med = float(lum[~em].median().clamp(min=1e-8))
        if bool(em.any()):
            ratio.append(float(lum[em].max()) / med)
        if "brightest_source" in s.meta:  # includes the sun and emitters no pixel shows
            src.append(float(s.meta["brightest_source"]) / med)
        if "source_radiance" in s.meta:  # panels/lamps, sky, sun separately (0: none)
            for name, v in json.loads(s.meta["source_radiance"]).items():
                if v > 0:
                    by_kind[name].append(v / med)
    n = len(paths)
    hist = {str(k): light_counts.count(k) for k in sorted(set(light_counts))}
    def q(v):
        return [float(np.percentile(v, x)) for x in (0, 50, 100)] if v else []
    return {"scenes": n, "light_sources_histogram": hist, "sun_share": sum(suns) / max(n, 1),
            "metal_pixel_fraction_mean": float(np.mean(metal)),
            "scenes_with_metal": sum(m > 0 for m in metal),
            "depth_min_median_max": [min(dmin), float(np.median(dmed)), max(dmax)],
            "room_side_min_median_max": q(widths), "room_height_min_median_max": q(heights),
            "room_kinds": kinds, "emitter_to_median_ratio_min_median_max": q(ratio),
            "emitter_to_median_ratio_all": sorted(round(r, 1) for r in ratio),
            "source_to_median_ratio_min_median_max": q(src),
            "source_to_median_ratio_all": sorted(round(r, 1) for r in src),
            "render_seconds_mean": float(np.mean(secs)),
            **{f"{k}_to_median_ratio_min_median_max": q(v) for k, v in by_kind.items()},
            **{f"{k}_to_median_ratio_all": sorted(round(r, 1) for r in v) for k, v in by_kind.items()},
            "lamp_ratio_in_1e2_1e4": [sum(1e2 <= r <= 1e4 for r in by_kind["lamp"]), len(by_kind["lamp"])]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m phyir.synth.report", description=__doc__.splitlines()[0])
    p.add_argument("dir")
    p.add_argument("--count", type=int, default=24)
    p.add_argument("--sheet", default=None)
    p.add_argument("--stats", default=None)
    a = p.parse_args(argv)
    paths = sorted(Path(a.dir).glob("scene_*.exr"))[: a.count]
    if a.sheet:
        print("contact sheet:", contact_sheet(paths, Path(a.sheet)))
    stats = statistics(paths)
    text = json.dumps(stats, indent=1)
    print(text)
    if a.stats:
        Path(a.stats).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
