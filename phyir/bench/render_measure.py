"""Measurements of the render benchmark (:mod:`phyir.bench.render`): interleaved timing, relative
RMSE against a converged :class:`Reference`, and reading sample counts and times off measured curves."""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable

import torch
from torch import Tensor

from phyir.scene import PanoScene

PREFILTERED_F32 = "prefiltered_f32"  # the prefiltered path with float32 level maps (bench row)


def level_matmul(probes: Tensor) -> str:
    """The dtype the prefiltered path's level matmul takes for ``probes [..., 3, h, w]`` when every
    level is needed (:func:`phyir.shading.prefilter.level_matmul_dtype`), as a name."""
    from phyir.shading import prefilter

    rows = prefilter.map_rows(*probes.shape[-2:])
    return str(prefilter.level_matmul_dtype(probes, rows * probes.numel())).removeprefix("torch.")


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _stats(wall: list[float], cpu: list[float]) -> dict[str, float]:
    q = statistics.quantiles(wall, n=4) if len(wall) > 1 else [wall[0]] * 3
    return {"median_s": statistics.median(wall), "q1_s": q[0], "q3_s": q[2], "min_s": min(wall),
            "max_s": max(wall), "cpu_s": statistics.median(cpu), "cpu_min_s": min(cpu), "repeats": len(wall)}


def time_interleaved(calls: dict[str, Callable[[], object]], device: str,
                     repeats: int) -> dict[str, dict[str, float]]:
    """Wall / CPU time statistics of each call, timed in turns (A B C A B C ...) after one warm-up
    each, so that a change of machine load hits every call alike.  Calls under a second are
    repeated at least 7 times."""
    t0 = time.perf_counter()
    for fn in calls.values():
        fn()
        _sync(device)
    if (time.perf_counter() - t0) / len(calls) < 1.0:
        repeats = max(repeats, 7)
    wall: dict[str, list[float]] = {k: [] for k in calls}
    cpu: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(repeats):
        for k, fn in calls.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            _sync(device)
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return {k: _stats(wall[k], cpu[k]) for k in calls}


def rel_rmse(x: Tensor, ref: Tensor, mask: Tensor | None = None) -> float:
    d2, r2 = (x - ref) ** 2, ref**2
    if mask is not None:
        d2, r2 = d2 * mask, r2 * mask
    den = float(r2.sum())
    return float("nan") if den == 0 else math.sqrt(float(d2.sum()) / den)


def diffuse_quadrature(scene: PanoScene, chunk: int = 1024) -> Tensor:
    """Noise-free diffuse layer ``[3, H, W]``: B (1-M)/pi ∫ L (n.l)+ dl by quadrature.

    L is each pixel's bilinear mix of probes, itself bilinearly interpolated: integrated on the
    prefilter's 4x4 supersampled grid of every probe texel (the same radiance Monte Carlo sees).
    """
    from phyir.shading.prefilter import fine_grid
    from phyir.shading.render import probe_weights

    H, W = scene.size
    Hp, Wp = scene.probe_grid  # type: ignore[misc]
    h, w = scene.probe_size  # type: ignore[misc]
    dev = scene.normal.device
    d, to_probe = (t.to(dev, torch.float32) for t in fine_grid(h, w))
    n = scene.normal.reshape(3, -1).T
    pidx, pw = probe_weights(H, W, Hp, Wp, dev)
    probes = scene.probes.reshape(Hp * Wp, 3, h * w)
    out = torch.empty(H * W, 3, device=dev)
    for i in range(0, H * W, chunk):
        k = (n[i:i + chunk] @ d.T).clamp(min=0) @ to_probe  # [p, h*w]: ∫ (n.l)+ L dl per texel
        x = probes[pidx[i:i + chunk]]  # [p, 4, 3, h*w]
        out[i:i + chunk] = torch.einsum("pt,pj,pjct->pc", k, pw[i:i + chunk], x)
    rho = (scene.albedo * (1 - scene.metallic)).reshape(3, -1).T
    return (rho * out / math.pi).T.reshape(3, H, W)


class Reference:
    """Converged layers: quadrature diffuse; specular as the mean of two independent importance-
    sampled halves, whose difference estimates the remaining noise (per layer, relative)."""

    def __init__(self, scene: PanoScene, spp: int, mask: Tensor, skips=True):
        from phyir.shading.render import render_scene

        a = render_scene(scene, spp=spp // 2, seed=1_000_003, skips=skips)["specular"]
        b = render_scene(scene, spp=spp // 2, seed=2_000_003, skips=skips)["specular"]
        diffuse = diffuse_quadrature(scene) * mask
        spec = (a + b) / 2
        self.layers = {"diffuse": diffuse, "specular": spec, "image": diffuse + spec}
        self.mask = mask
        noise2 = float((((a - b) / 2) ** 2 * mask).sum())  # |ref - truth|^2 ~ |a - b|^2 / 4
        self.noise = {k: (0.0 if k == "diffuse" else
                          math.sqrt(noise2 / max(float((t**2 * mask).sum()), 1e-30)))
                      for k, t in self.layers.items()}
        self.spp = spp

    def errors(self, out: dict[str, Tensor]) -> dict[str, float]:
        res = {}
        for k, ref in self.layers.items():
            raw = rel_rmse(out[k], ref, self.mask)
            noise = self.noise[k]
            res[f"err_raw_{k}"] = raw
            res[f"err_{k}"] = math.sqrt(max(raw * raw - noise * noise, 0.0)) if math.isfinite(raw) else raw
        return res


def loglog(xs: list[float], ys: list[float], y: float) -> float:
    """x where the piecewise log-log line through (xs, ys) reaches y (ys decreasing in xs).

    Extrapolates beyond the last point with the Monte Carlo rate y ~ x^-1/2 (and before the first
    with the first segment's slope clamped to that rate).
    """
    lx, ly = [math.log(v) for v in xs], [math.log(v) for v in ys]
    t = math.log(y)
    for i in range(len(xs) - 1):
        if ly[i] >= t >= ly[i + 1] and ly[i] != ly[i + 1]:
            f = (t - ly[i]) / (ly[i + 1] - ly[i])
            return math.exp(lx[i] + f * (lx[i + 1] - lx[i]))
    if t < ly[-1]:
        return math.exp(lx[-1] + 2 * (ly[-1] - t))
    return math.exp(lx[0] - 2 * (t - ly[0]))


def interp_time(spps: list[float], times: list[float], spp: float) -> float:
    """Time at ``spp``: log-log interpolation, linear in spp beyond the measured range."""
    if spp >= spps[-1]:
        return times[-1] * spp / spps[-1]
    if spp <= spps[0]:
        return times[0] * spp / spps[0]
    for i in range(len(spps) - 1):
        if spps[i] <= spp <= spps[i + 1]:
            f = (math.log(spp) - math.log(spps[i])) / (math.log(spps[i + 1]) - math.log(spps[i]))
            return math.exp(math.log(times[i]) + f * (math.log(times[i + 1]) - math.log(times[i])))
    raise AssertionError("unreachable")
