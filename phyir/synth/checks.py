"""Physical-consistency, noise and speed checks of the data generator.

Run ``python -m phyir.synth.checks [--scenes 20] [--size 128x256] [--out docs/synth_checks.json]``.

* consistency: the rendering layer (:func:`phyir.shading.render.render_scene`) applied to a scene's
  ground-truth layers and probes against its ground-truth image: relative L1
  ``sum|render - gt| / sum gt`` over non-emissive pixels, per scene and averaged; also over
  diffuse-dominated pixels (M < 0.5, R > 0.6) and glossy/metal pixels;
* noise: the same room rendered with two sampler seeds: relative L1 between the two images
  (non-emissive pixels) and between the two probe grids;
* speed: seconds (wall and CPU) and peak resident memory of one scene at the given settings.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import torch
from torch import Tensor

from phyir.scene import PanoScene
from phyir.synth.dataset import generate_scene
from phyir.synth.trace_settings import TraceSettings

PROBE_PIXELS = 4  # one probe per 4x4 pixels, as in the default 256x512 / 64x128


def rel_l1(a: Tensor, b: Tensor, mask: Tensor | None = None) -> float:
    """``sum|a - b| / sum|b|`` (over ``mask`` if given, broadcast against the tensors)."""
    diff, ref = (a - b).abs(), b.abs()
    if mask is not None:
        m = mask.to(diff.dtype).expand_as(diff)
        diff, ref = diff * m, ref * m
    return float(diff.sum() / ref.sum().clamp(min=1e-30))


def consistency(scene: PanoScene, spp: int = 128) -> dict:
    """Relative L1 of the rendering layer's re-render against the ground-truth image, overall and by
    pixel class: diffuse-dominated, glossy/metal, depth edges (a 3x3 neighbour > 10 % nearer or
    farther: where the probe grid's interpolation mixes surfaces) and the brightest 5 % (sun
    patches, lamp-lit spots); ``*_share`` is each class's share of the total absolute error."""
    import torch.nn.functional as F

    from phyir.shading.render import render_scene

    out = render_scene(scene, spp=spp)["image"]
    nonem = scene.masks["emission"] < 0.5
    diffuse = nonem & (scene.metallic < 0.5) & (scene.roughness > 0.6)
    d = F.pad(scene.depth[None], (1, 1, 1, 1), mode="replicate")
    edge = nonem & (F.max_pool2d(d, 3, 1)[0] > 1.1 * -F.max_pool2d(-d, 3, 1)[0])
    lum = scene.image.mean(0, keepdim=True)
    bright = nonem & (lum > lum[nonem].quantile(0.95))
    err = (out - scene.image).abs().sum(0, keepdim=True)
    total = float((err * nonem).sum().clamp(min=1e-30))
    res = {"all": rel_l1(out, scene.image, nonem), "glossy_share": float((nonem & ~diffuse).float().mean()),
           "brightness_ratio": float((out * nonem).sum() / (scene.image * nonem).sum())}
    for name, m in (("diffuse", diffuse), ("glossy", nonem & ~diffuse), ("edge", edge), ("bright", bright)):
        res[name] = rel_l1(out, scene.image, m)
        res[name + "_err_share"] = float((err * m).sum()) / total
    res["edge_pixels"] = float(edge.float().mean())
    res["sun"] = float(_has_sun(scene))
    return res


def _has_sun(scene: PanoScene) -> bool:
    """Whether the generator lit the room with a sun (``meta["source_radiance"]``, JSON)."""
    src = scene.meta.get("source_radiance")
    return bool(src) and float(json.loads(src).get("sun", 0.0)) > 0


def consistency_summary(per: list[dict]) -> dict:
    """Means over scenes of the main consistency figures, and of ``all`` over rooms with / without
    a sun (``all_sun``, ``all_no_sun``; absent when no room is of that kind)."""
    keys = ("all", "diffuse", "glossy", "brightness_ratio", "glossy_share", "edge", "edge_err_share",
            "bright", "bright_err_share")
    out = {k: sum(p[k] for p in per) / len(per) for k in keys}
    for name, sun in (("sun", True), ("no_sun", False)):
        rooms = [p["all"] for p in per if bool(p["sun"]) == sun]
        if rooms:
            out[f"all_{name}"], out[f"rooms_{name}"] = sum(rooms) / len(rooms), float(len(rooms))
    return out


def noise(seed: int, index: int, settings: TraceSettings) -> dict:
    """Relative L1 between two renders of one room with different sampler seeds."""
    a = generate_scene(seed, index, settings, sampler_seed=1)
    b = generate_scene(seed, index, settings, sampler_seed=2)
    # compare in radiometric units: undo the (sample-dependent) exposure normalisation
    ka, kb = float(a.meta["exposure"]), float(b.meta["exposure"])
    nonem = a.masks["emission"] < 0.5
    out = {"image": rel_l1(a.image / ka, b.image / kb, nonem)}
    if a.probes is not None:
        out["probes"] = rel_l1(a.probes / ka, b.probes / kb)
    return out


def _concentration(a: Tensor, b: Tensor, mask: Tensor) -> dict:
    """How the difference of two images is spread: the share of ``sum|a-b|`` carried by the 1 % of
    pixels that differ most (fireflies), and the rel. L1 after 8x8 block means (low-frequency noise,
    e.g. of the light map, survives; per-pixel sampling noise averages out)."""
    import torch.nn.functional as F

    m = mask.to(a.dtype).expand_as(a)
    diff = ((a - b).abs() * m).sum(0).flatten()
    top = diff.topk(max(1, diff.numel() // 100)).values.sum()
    def pool(x):
        return F.avg_pool2d((x * m)[None], 8)[0]
    return {"top1_share": float(top / diff.sum().clamp(min=1e-30)),
            "lowpass8": rel_l1(pool(a), pool(b))}


def noise_breakdown(seed: int, index: int, settings: TraceSettings, device=None) -> dict:
    """Split the two-seed difference of :func:`noise` by source: the light map (built with seed 1 or
    2, camera samples fixed), the camera's own samples (light map fixed), and the probes' own rays
    (light map fixed); each with its :func:`_concentration`. Radiometric units (no exposure)."""
    import numpy as np

    from phyir.synth.paths import build_lightmap
    from phyir.synth.rooms import generate_room
    from phyir.synth.tracer import render_camera, render_probes

    sc = generate_room(np.random.default_rng([seed, index])).build(device)
    def gen(s):
        return torch.Generator(device=sc.device).manual_seed(s)
    lm1, lm2 = build_lightmap(sc, settings, gen(1)), build_lightmap(sc, settings, gen(2))
    H, W = settings.size
    def img(lm, s):
        return render_camera(sc, lm, settings, s, gen(s))
    a, g = img(lm1, 1)
    b, _ = img(lm1, 2)
    c, _ = img(lm2, 1)
    def chw(x):
        return x.reshape(H, W, 3).permute(2, 0, 1)
    a, b, c = chw(a), chw(b), chw(c)
    nonem = (g["emission"] < 0.5).reshape(1, H, W)
    kinds = sc.lights.kind.tolist()
    out = {"lights": {"area": kinds.count(0), "windows": kinds.count(1), "sun": kinds.count(2)},
           "camera": rel_l1(a, b, nonem), "camera_conc": _concentration(a, b, nonem),
           "lightmap": rel_l1(a, c, nonem), "lightmap_conc": _concentration(a, c, nonem)}
    diffuse = nonem & ((g["metallic"] < 0.5) & (g["roughness"] > 0.6)).reshape(1, H, W)
    out["camera_diffuse"] = rel_l1(a, b, diffuse)
    out["camera_glossy"] = rel_l1(a, b, nonem & ~diffuse)
    out["camera_glossy_err_share"] = float(((a - b).abs() * (nonem & ~diffuse)).sum() /
                                           ((a - b).abs() * nonem).sum().clamp(min=1e-30))
    if settings.probe_grid is not None:
        p1 = render_probes(sc, lm1, settings, gen(1))
        out["probes_own"] = rel_l1(p1, render_probes(sc, lm1, settings, gen(2)))
        out["probes_lightmap"] = rel_l1(p1, render_probes(sc, lm2, settings, gen(1)))
    return out


def check_folder(folder: str, count: int = 20, spp: int = 128) -> dict:
    """Consistency over the first ``count`` scene files of a dataset folder."""
    from pathlib import Path

    from phyir.io import load_scene

    per = []
    for p in sorted(Path(folder).glob("scene_*.exr"))[:count]:
        c = consistency(load_scene(p), spp)
        c["file"] = p.name
        per.append(c)
        print(f"{p.name}: consistency {c['all']:.4f} (diffuse {c['diffuse']:.4f}, glossy {c['glossy']:.4f}) "
              f"ratio {c['brightness_ratio']:.3f}", flush=True)
    return {"consistency_mean": consistency_summary(per), "consistency": per}


def settings_for(size: tuple[int, int], spp: int = 16) -> TraceSettings:
    H, W = size
    return TraceSettings(size=size, probe_grid=(H // PROBE_PIXELS, W // PROBE_PIXELS), spp=spp)


def run_checks(scenes: int = 20, size=(128, 256), seed: int = 1000, noise_scenes: int = 3,
               spp: int = 16, render_spp: int = 128) -> dict:
    st = settings_for(tuple(size), spp)
    per = []
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(scenes):
        s = generate_scene(seed, i, st)
        c = consistency(s, render_spp)
        c["index"] = i
        c["render_seconds"] = float(s.meta["render_seconds"])
        per.append(c)
        print(f"scene {i}: consistency {c['all']:.4f} (diffuse {c['diffuse']:.4f}, glossy {c['glossy']:.4f}) "
              f"ratio {c['brightness_ratio']:.3f}", flush=True)
    mean = consistency_summary(per)
    noi = []
    for i in range(noise_scenes):
        n = noise(seed, i, st)
        n["index"] = i
        noi.append(n)
        print(f"scene {i}: noise {n}", flush=True)
    return {"settings": {"size": list(size), "probe_grid": list(st.probe_grid),
                         "probe_size": list(st.probe_size), "spp": st.spp, "seed": seed},
            "consistency_mean": mean, "consistency": per,
            "noise_mean": ({k: sum(n[k] for n in noi) / len(noi) for k in noi[0] if k != "index"}
                           if noi else {}),
            "noise": noi,
            "wall_seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
            "threads": torch.get_num_threads()}


def speed(size=(256, 512), probe_grid=(64, 128), probe_size=(16, 32), spp: int = 16, seed: int = 0,
          index: int = 0, device=None) -> dict:
    """Time and peak memory of one scene (fresh process recommended for the memory figure)."""
    st = TraceSettings(size=tuple(size), probe_grid=None if probe_grid is None else tuple(probe_grid),
                       probe_size=tuple(probe_size), spp=spp)
    t0, c0 = time.perf_counter(), time.process_time()
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    s = generate_scene(seed, index, st, device)
    out = {"size": list(size), "probe_grid": None if probe_grid is None else list(probe_grid),
           "probe_size": list(probe_size), "spp": spp, "wall_seconds": time.perf_counter() - t0,
           "cpu_seconds": time.process_time() - c0,
           "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
           "threads": torch.get_num_threads(), "device": str(device or "cpu"),
           "load_average": list(_loadavg())}
    if device == "cuda":
        out["peak_cuda_mb"] = torch.cuda.max_memory_allocated() / 2**20
    out["render_stats"] = json.loads(s.meta["render_stats"])  # per-stage seconds (wall and CPU)
    out["room"] = s.meta["room"]
    return out


def _loadavg():
    try:
        import os

        return os.getloadavg()
    except OSError:
        return ()


def main(argv: list[str] | None = None) -> int:
    from phyir.synth.dataset import parse_size

    p = argparse.ArgumentParser(prog="python -m phyir.synth.checks", description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--noise-scenes", type=int, default=3)
    p.add_argument("--size", default="128x256")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--render-spp", type=int, default=128,
                   help="samples per pixel of the rendering layer in the consistency check")
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--speed", action="store_true",
                   help="time one scene instead (use with --size, --probe-grid)")
    p.add_argument("--probe-grid", default=None)
    p.add_argument("--device", default=None)
    p.add_argument("--dir", default=None, help="consistency of the scene files in this folder instead")
    p.add_argument("--out", default=None, help="write the results as JSON here")
    a = p.parse_args(argv)
    size = parse_size(a.size, "--size")
    if a.dir:
        res = check_folder(a.dir, a.scenes, a.render_spp)
        text = json.dumps(res, indent=1)
        print(json.dumps(res["consistency_mean"]))
        if a.out:
            with open(a.out, "w") as f:
                f.write(text)
        return 0
    if a.speed:
        grid = (size[0] // PROBE_PIXELS, size[1] // PROBE_PIXELS) if a.probe_grid is None else \
            (None if a.probe_grid == "none" else parse_size(a.probe_grid, "--probe-grid"))
        res = speed(size, grid, spp=a.spp, seed=a.seed, device=a.device)
    else:
        res = run_checks(a.scenes, size, a.seed, a.noise_scenes, a.spp, a.render_spp)
    text = json.dumps(res, indent=1)
    keys = ("consistency_mean", "noise_mean", "wall_seconds")
    print(text if a.speed else json.dumps({k: res[k] for k in keys}))
    if a.out:
        with open(a.out, "w") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
