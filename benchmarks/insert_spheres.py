"""The GLSL object shading of the supplement's Table 2 spheres against the converged renderer.

    .venv/bin/python -m benchmarks.insert_spheres [--size 24] [--spp 4096] [--samples 128]

For each real panorama in ../shared/panos (downsampled to a 16 x 32 probe) and the tests' procedural
lamp probe, a sphere of each material is shaded by shaders/ibl.glsl (viewer.insertion
.InsertionRenderer.shade_gbuffer, ``--samples`` GGX samples) and by phyir.shading.render.shade_env
(importance sampling, ``--spp``); prints the relative L1 difference and the split-sum baseline
(shade_env method="prefiltered") for comparison.  Writes benchmarks/results/insert_spheres.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=24)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    args = ap.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import moderngl
    import torch

    from phyir import io, pano
    from phyir.evaluation.metrics import RELIGHT_MATERIALS, render_spheres, sphere_gbuffer
    from phyir.insert.objects import PRESETS
    from viewer.insertion import InsertionRenderer

    probes = {}
    try:
        from tests.support.scenes import lamp_probe

        probes["lamps (tests)"] = lamp_probe()
    except ImportError:
        pass
    for f in sorted((REPO.parent / "shared" / "panos").glob("*.hdr")):
        probes[f.stem] = pano.resize_area(io.load_panorama(f), 16, 32)
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    ins = InsertionRenderer(ctx)
    view_dir = torch.tensor([[0.3, -0.2, -1.0]])
    n, v, mask = sphere_gbuffer(view_dir, args.size)

    def rel(a, b) -> float:
        return float((a - b).abs().sum() / b.abs().sum())

    results = {}
    for name, probe in probes.items():
        row = {}
        for mat in RELIGHT_MATERIALS:
            t = time.perf_counter()
            ref = render_spheres(probe[None], view_dir, mat, size=args.size, spp=args.spp)[0]
            split = render_spheres(probe[None], view_dir, mat, size=args.size, method="prefiltered")[0]
            material = PRESETS[mat.replace("_", "-")]
            glsl = ins.shade_gbuffer(n[0], v[0], material, probe, args.samples) * mask[0]
            row[mat] = {"glsl": round(rel(glsl, ref), 4), "split_sum": round(rel(split, ref), 4),
                        "seconds": round(time.perf_counter() - t, 1)}
        results[name] = row
        print(f"{name:34s} " + "  ".join(f"{m}: glsl {r['glsl']:.4f} (split-sum {r['split_sum']:.4f})"
                                         for m, r in row.items()), flush=True)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "insert_spheres.json"), "w") as f:
        json.dump({"size": args.size, "spp": args.spp, "samples": args.samples, "results": results}, f,
                  indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
