"""Where the split-sum path's error comes from, on draws of ``phyir bench render``'s scenes.

For each scene (128x256, a probe per 2x2 pixels, probes of 16x32) it prints the image error
(relative RMSE against converged Monte Carlo) of

* ``prefiltered``: the renderer's split sum (levels ``prefilter.PREFILTER_ALPHAS``, coarse maps);
* ``fine levels``: the same with 14 levels (alpha 0, 0.02, ..., 1) at the probes' full resolution:
  what finer prefiltering alone can buy;
* ``ideal split sum``: every pixel's radiance weighted by the exact prefilter kernels of the
  renderer's two look-ups (directions and alpha from :func:`phyir.shading.prefilter.lobe_shape_table`;
  quadrature of the probes' bilinear interpolant, 4x4 points per texel), times the DFG albedo: the
  split sum without any level, resolution or interpolation error, i.e. the floor of the
  approximation (two isotropic kernels standing in for the lobe, the BRDF's weight pulled out);

and, for the pixels with the largest squared error of ``prefiltered``, the brute-force value (the
pixel's bilinear probe mixture times f_s cos, summed over a 16x16-supersampled grid per texel), the
*ideal* split sum (that radiance weighted by the exact kernels of the two look-ups, times the DFG
albedo: the split sum without any level or interpolation error)
and the renderer's value.  A pixel where the ideal split sum is close to the truth but the renderer
is not errs in the levels (their alpha spacing and resolution); one where the ideal split sum is far
off errs in the split-sum approximation itself (kernels standing in for the lobe).

    .venv/bin/python -m benchmarks.split_sum_limits [--kind metal] [--seeds 0 1] [--worst 4]
"""

from __future__ import annotations

import argparse

import torch

from phyir.bench.render_measure import Reference
from phyir.bench.render_scenes import bench_scene, shaded_mask
from phyir.lighting.object_lighting import quadrature
from phyir.shading import prefilter, render, split_sum
from phyir.shading.brdf import brdf_vectors, f0_from_material
from phyir.shading.pixels import unflat

FINE_ALPHAS = (0.0, 0.02, 0.05, 0.08, 0.12, 0.16, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)
SUPER = 16


def _prefiltered(scene, alphas: tuple[float, ...], texels_per_alpha: float) -> dict:
    keep = prefilter.PREFILTER_ALPHAS, prefilter.LEVEL_TEXELS_PER_ALPHA
    prefilter.PREFILTER_ALPHAS, prefilter.LEVEL_TEXELS_PER_ALPHA = alphas, texels_per_alpha
    try:  # the operator cache is keyed by alphas, not by the level sizes: clear it both ways
        prefilter.clear_cache(operators=True)
        return render.render_scene(scene, method="prefiltered")
    finally:
        prefilter.PREFILTER_ALPHAS, prefilter.LEVEL_TEXELS_PER_ALPHA = keep
        prefilter.clear_cache(operators=True)


def _lookups(n: torch.Tensor, v: torch.Tensor, rough: torch.Tensor, f0: torch.Tensor):
    """The renderer's two look-up directions ``[p, 3]`` each and their alpha ``[p]``."""
    shape = split_sum.lobe_shape((n * v).sum(-1), rough, f0)
    return split_sum.lobe_taps(n, v, shape[:, 0], shape[:, 1]), shape[:, 2]


def _ideal_split_sum(scene, px, light, diffuse: torch.Tensor, chunk: int = 512) -> dict:
    """Layers with the ideal split sum as the specular (``px``, ``light``: the scene's
    :func:`phyir.shading.render.scene_inputs`; ``diffuse``: the renderer's)."""
    d, weights = prefilter.fine_grid(*light.probes.shape[-2:])  # directions, solid angle x taps
    d, weights = d.to(px.n.dtype), weights.to(px.n.dtype)
    nv = (px.n * px.v).sum(-1)
    f0 = f0_from_material(px.base, px.metal)
    looks, alpha = _lookups(px.n, px.v, px.rough[:, 0], f0)
    probes = light.probes.reshape(light.probes.shape[0], 3, -1)
    rad = torch.zeros_like(px.n)
    for s in range(0, len(rad), chunk):
        e = slice(s, s + chunk)
        env = (light.weight[e][:, :, None, None] * probes[light.index[e]]).sum(1)  # [p, 3, h*w]
        for look in looks:
            kernel = prefilter.lobe_kernel(look[e] @ d.T, alpha[e, None]) @ weights
            rad[e] += 0.5 * (env * (kernel / kernel.sum(-1, keepdim=True))[:, None]).sum(-1)
    spec = torch.where(px.skip[:, None], 0.0, prefilter.specular_albedo(nv, px.rough[:, 0], f0) * rad)
    H, W = scene.size
    spec = unflat(spec, 1, H, W, False)
    return {"diffuse": diffuse, "specular": spec, "image": diffuse + spec}


def _grid(h: int, w: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Directions ``[F, 3]``, solid angles and bilinear taps of a SUPER x SUPER grid per probe texel."""
    d, omega, idx, wgt = quadrature(h, w, SUPER)
    return d.T, omega, idx, wgt


def _pixel_terms(px, light, p: int, grid) -> tuple[float, float, float, float]:
    """(n.v, brute force, ideal split sum, R) of flat pixel ``p``, red channel."""
    d, omega, idx, wgt = grid
    env = sum(light.weight[p, k].double() * light.probes[light.index[p, k]].double() for k in range(4))
    radiance = (env.reshape(3, -1)[:, idx] * wgt).sum(-1).T  # [F, 3]
    n, v, rough, base = (t[p].double() for t in (px.n, px.v, px.rough, px.base))
    metal = px.metal[p].double()
    _, fs = brdf_vectors(n[:, None].expand(3, len(d)), v[:, None].expand(3, len(d)), d.T, base[:, None],
                         rough[:, None], metal[:, None], dim=0)
    cos = (d @ n).clamp(min=0)
    truth = float((fs[0] * cos * radiance[:, 0] * omega).sum())
    nv = float(n @ v)
    f0 = f0_from_material(base, metal)
    looks, alpha = _lookups(n[None], v[None], rough, f0[None])
    k = sum(prefilter.lobe_kernel(d @ look[0], alpha) * omega for look in looks)
    albedo = prefilter.specular_albedo(torch.tensor([nv], dtype=torch.float64), rough, f0[None])[0]
    ideal = float((k * radiance[:, 0]).sum() / k.sum() * albedo[0])
    return nv, truth, ideal, float(rough[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", default="metal", choices=("glossy", "metal"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--worst", type=int, default=4)
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.set_grad_enabled(False)
    for seed in args.seeds:
        scene = bench_scene(args.kind, seed=seed)
        ref = Reference(scene, args.ref_spp, shaded_mask(scene))
        out = _prefiltered(scene, prefilter.PREFILTER_ALPHAS, prefilter.LEVEL_TEXELS_PER_ALPHA)
        fine = _prefiltered(scene, FINE_ALPHAS, 1e-9)  # 1e-9: levels never halved
        px, light, _, _ = render.scene_inputs(scene)
        ideal = _ideal_split_sum(scene, px, light, out["diffuse"])
        print(f"{args.kind} seed {seed}: image error prefiltered {ref.errors(out)['err_image']:.4f}, "
              f"fine levels {ref.errors(fine)['err_image']:.4f}, "
              f"ideal split sum {ref.errors(ideal)['err_image']:.4f}")
        err2 = ((out["specular"] - ref.layers["specular"]) ** 2 * ref.mask).sum(0).reshape(-1)
        share = err2 / err2.sum()
        grid = _grid(*light.probes.shape[-2:])
        W = scene.size[1]
        for p in err2.topk(args.worst).indices.tolist():
            nv, truth, ideal, rough = _pixel_terms(px, light, p, grid)
            y, x = divmod(p, W)
            got, mc = float(out["specular"][0, y, x]), float(ref.layers["specular"][0, y, x])
            print(f"  pixel ({y},{x}) n.v {nv:.2f} R {rough:.2f} ({100 * float(share[p]):.1f}% of the "
                  f"squared error), red: truth {truth:.3f} (reference {mc:.3f}), "
                  f"ideal split sum {ideal:.3f} ({100 * (ideal / truth - 1):+.0f}%), "
                  f"prefiltered {got:.3f} ({100 * (got / truth - 1):+.0f}%)")


if __name__ == "__main__":
    main()
