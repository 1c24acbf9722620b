"""Error of the split-sum path with its lobe-shaped look-ups against Karis' mirror look-up, on draws
of ``phyir bench render``'s glossy and metal scenes (128x256, a probe per 2x2 pixels, probes of
16x32), relative RMSE against converged Monte Carlo.

* ``mirror``: one look-up in the mirror direction with the surface's own alpha (Karis 2013);
* ``lobe-shaped``: the renderer's two look-ups around the lobe's mean direction, with the alpha of
  the lobe's width across the plane of n and v (:func:`phyir.shading.prefilter.lobe_shape_table`).

    .venv/bin/python -m benchmarks.split_sum_lookup [--seeds 0 1 2 3 4 5] [--ref-spp 1024]

Prints a Markdown table: specular error (image error in brackets) per scene.
"""

from __future__ import annotations

import argparse

import torch

from phyir.bench.render_measure import Reference
from phyir.bench.render_scenes import bench_scene, shaded_mask
from phyir.shading import render, split_sum


def _mirror_lookup(nv: torch.Tensor, rough: torch.Tensor, f0: torch.Tensor) -> torch.Tensor:
    return torch.stack((torch.ones_like(nv), torch.zeros_like(nv), (rough * rough).clamp(min=1e-4)), -1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--ref-spp", type=int, default=1024)
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.set_grad_enabled(False)
    print("| scene | mirror | lobe-shaped |")
    print("| --- | ---: | ---: |")
    shaped = split_sum.lobe_shape
    for kind in ("glossy", "metal"):
        for seed in args.seeds:
            scene = bench_scene(kind, seed=seed)
            ref = Reference(scene, args.ref_spp, shaded_mask(scene))
            cells = []
            for lookup in (_mirror_lookup, shaped):
                split_sum.lobe_shape = lookup
                try:
                    e = ref.errors(render.render_scene(scene, method="prefiltered"))
                finally:
                    split_sum.lobe_shape = shaped
                cells.append(f"{e['err_specular']:.4f} ({e['err_image']:.4f})")
            print(f"| {kind} seed {seed} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
