"""Specular bias of the split-sum path against converged Monte Carlo with and without the
look-up direction's shift toward the normal (``phyir.render.DOMINANT_SHIFT``), on several draws of
``phyir bench render``'s glossy and metal scenes (128x256, a probe per 2x2 pixels).

    .venv/bin/python benchmarks/split_sum_shift.py [--seeds 0 1 2 3 4 5] [--shifts 0 0.3]

Prints a Markdown table of relative RMSE (specular layer; the image in brackets) per scene.
"""

from __future__ import annotations

import argparse

import torch

from phyir import render
from phyir.bench_render import Reference, _shaded_mask, bench_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--shifts", type=float, nargs="+", default=[0.0, 0.3])
    ap.add_argument("--ref-spp", type=int, default=512)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | " + " | ".join(f"shift {s:g}" for s in args.shifts) + " |")
    print("| --- |" + " ---: |" * len(args.shifts))
    keep = render.DOMINANT_SHIFT
    try:
        for seed in args.seeds:
            for kind in ("glossy", "metal"):
                scene = bench_scene(kind, seed=seed)
                ref = Reference(scene, args.ref_spp, _shaded_mask(scene))
                cells = []
                for shift in args.shifts:
                    render.DOMINANT_SHIFT = shift
                    e = ref.errors(render.render_scene(scene, method="prefiltered"))
                    cells.append(f"{100 * e['err_specular']:.2f} % ({100 * e['err_image']:.2f} %)")
                print(f"| {kind}, seed {seed} | " + " | ".join(cells) + " |", flush=True)
    finally:
        render.DOMINANT_SHIFT = keep


if __name__ == "__main__":
    main()
