"""Benchmark of the synthetic data generator: samples per pixel against noise and time
(``phyir bench synth``).

For a few seeded rooms (:func:`phyir.synth.rooms.generate_room`) the tracer's stages run separately
(:mod:`phyir.synth.tracer`: light map, camera, probes), so one light map serves every sample count:

* **noise** of the camera image at each spp, as relative L1 over non-emissive pixels,
  ``sum |x - y| / sum |y|``:

  - ``noise_total``: between two renders with different seeds (light map *and* camera samples),
    divided by sqrt(2): the seed-to-seed noise of one generated scene (independent errors add in
    quadrature; exact for Gaussian noise);
  - ``noise_camera``: against a ``ref_spp`` render sharing the light map but not the camera seed:
    the camera samples' own noise (the light map's noise is the floor ``noise_total`` levels off at);

* the same pair noise for the **probes** at several shadow-ray counts (``vis_rays``);
* **time** of each stage (median over the two seeds; one warm-up trace first) and **peak memory**
  added by one whole scene (Linux: /proc/self VmHWM; CUDA: the allocator's peak);
* **cost growth** with image resolution (probe grid = image / 4, light map sized as
  :meth:`phyir.synth.dataset.DatasetConfig.settings`) and with the probe count at a fixed image.
"""

from __future__ import annotations

import dataclasses
import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

FULL = {"size": (64, 128), "probe_grid": (16, 32), "probe_size": (16, 32), "scenes": (0, 1),
        "spp": (1, 2, 4, 8, 16, 32), "ref_spp": 128, "vis_rays": (1, 4, 8),
        "sizes": ((32, 64), (64, 128), (128, 256)), "probe_grids": ((8, 16), (16, 32), (32, 64)),
        "growth_spp": 8, "tiny": False}
QUICK = {"size": (32, 64), "probe_grid": (8, 16), "probe_size": (8, 16), "scenes": (0,),
         "spp": (1, 4), "ref_spp": 16, "vis_rays": (1, 2),
         "sizes": ((16, 32), (32, 64)), "probe_grids": ((4, 8), (8, 16)), "growth_spp": 2, "tiny": True}
SEEDS = (11, 23)  # the two independent renders of each scene
REF_SEED = 1_000_003
DATASET_SEED = 0  # rooms are drawn as scene (DATASET_SEED, index) of a dataset


def settings_for(cfg: dict, size: tuple[int, int], probe_grid: tuple[int, int] | None, spp: int):
    """Tracer settings: the dataset's (light map sized to the image) or, in quick mode, the tests'."""
    from phyir.synth.dataset import DatasetConfig, tiny_settings

    if cfg["tiny"]:  # and a coarser light map: seconds per scene
        st = tiny_settings(size, probe_grid, cfg["probe_size"], spp)
        return dataclasses.replace(st, lm_max_texels=1500)
    return DatasetConfig(size=size, probe_grid=probe_grid, probe_size=cfg["probe_size"], spp=spp).settings()


def rel_l1(x: Tensor, ref: Tensor, mask: Tensor | None = None) -> float:
    """``sum |x - ref| / sum |ref|`` (over ``mask`` > 0.5 where given)."""
    d, r = (x - ref).abs(), ref.abs()
    if mask is not None:
        d, r = d * mask, r * mask
    den = float(r.sum())
    return float("nan") if den == 0 else float(d.sum()) / den


def pair_noise(a: Tensor, b: Tensor, mask: Tensor | None = None) -> float:
    """Noise of one render from two independent ones: ``sum |a - b|`` against the pair's mean
    magnitude ``(sum |a| + sum |b|) / 2``, over sqrt(2)."""
    m = 1.0 if mask is None else mask
    den = float(((a.abs() + b.abs()) * m).sum()) / 2
    return float("nan") if den == 0 else float(((a - b).abs() * m).sum()) / den / math.sqrt(2)


def _peak_mb(fn: Callable[[], object], device: str) -> float | None:
    """Peak memory (MB) one call of ``fn`` adds (:func:`phyir.bench.measure.peak_memory`); None where
    it can't be measured."""
    from phyir.bench.measure import peak_memory

    return peak_memory(fn, device).get("extra_peak_mb")


def _mb(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.0f}"


def _timed(device: str, fn: Callable, *args, **kwargs):
    """``(fn(*args, **kwargs), wall seconds, CPU seconds)``."""
    from phyir.bench.measure import is_cuda

    sync = torch.cuda.synchronize if is_cuda(device) else (lambda: None)
    sync()
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    sync()
    return out, time.perf_counter() - t0, time.process_time() - c0


def _measured(device: str, fn: Callable, *args, **kwargs):
    """``(fn(*args, **kwargs), wall s, CPU s, peak MB or None)``."""
    got: list = []
    peak = _peak_mb(lambda: got.append(_timed(device, fn, *args, **kwargs)), device)
    return (*got[0], peak)


def _room(index: int, device: str):
    from phyir.synth.rooms import generate_room

    return generate_room(np.random.default_rng([DATASET_SEED, index])).build(device)


def bench_scene_spp(index: int, cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    """Noise and time against spp (camera) and shadow rays (probes) for one room."""
    from phyir.synth.paths import build_lightmap
    from phyir.synth.tracer import render_camera, render_probes

    sc = _room(index, device)
    st0 = settings_for(cfg, cfg["size"], cfg["probe_grid"], 1)
    lms, lm_t, lm_c, imgs, cam, probes, probe_t = [], [], [], {}, {}, {}, {}
    mask = None
    def scene() -> None:  # one whole scene per seed: light map, camera at every spp, probes
        nonlocal mask
        for s in SEEDS:
            gen = torch.Generator(device=device).manual_seed(s)
            lm, t, c = _timed(device, build_lightmap, sc, st0, gen)
            lms.append(lm)
            lm_t.append(t)
            lm_c.append(c)
            for spp in cfg["spp"]:
                st = dataclasses.replace(st0, spp=spp)
                (img, gb), t, c = _timed(device, render_camera, sc, lm, st, s, gen)
                imgs[(s, spp)] = img
                cam.setdefault(spp, []).append((t, c))
                mask = (gb["emission"] < 0.5).float()[:, None]
            for vr in cfg["vis_rays"]:
                st = dataclasses.replace(st0, vis_rays=vr)
                p, t, c = _timed(device, render_probes, sc, lm, st, gen)
                probes[(s, vr)] = p
                probe_t.setdefault(vr, []).append((t, c))

    peak = _peak_mb(scene, device)
    st_ref = dataclasses.replace(st0, spp=cfg["ref_spp"])
    gen = torch.Generator(device=device).manual_seed(REF_SEED)
    (ref, _), ref_t, _ = _timed(device, render_camera, sc, lms[0], st_ref, REF_SEED, gen)

    def med(xs, i):
        return statistics.median(x[i] for x in xs)

    lm_s, lm_cpu = statistics.median(lm_t), statistics.median(lm_c)
    # the scene's total at the generator's own probe setting (or the first measured)
    vr0 = st0.vis_rays if st0.vis_rays in cfg["vis_rays"] else cfg["vis_rays"][0]
    rows = []
    for spp in cfg["spp"]:
        a, b = imgs[(SEEDS[0], spp)], imgs[(SEEDS[1], spp)]
        rows.append({"spp": spp, "camera_s": med(cam[spp], 0), "camera_cpu_s": med(cam[spp], 1),
                     "scene_s": lm_s + med(cam[spp], 0) + med(probe_t[vr0], 0),
                     "noise_total": pair_noise(a, b, mask), "noise_camera": rel_l1(a, ref, mask)})
    prow = []
    for vr in cfg["vis_rays"]:
        a, b = probes[(SEEDS[0], vr)], probes[(SEEDS[1], vr)]
        prow.append({"vis_rays": vr, "probes_s": med(probe_t[vr], 0), "probes_cpu_s": med(probe_t[vr], 1),
                     "noise": pair_noise(a, b)})
    res = {"scene": index, "size": list(cfg["size"]), "probe_grid": list(cfg["probe_grid"]),
           "texels": lms[0].n_texels, "lightmap_s": lm_s, "lightmap_cpu_s": lm_cpu,
           "reference_spp": cfg["ref_spp"], "reference_s": ref_t, "peak_mb": peak, "scene_vis_rays": vr0,
           "camera": rows, "probes": prow}
    for r in rows:
        log(f"  scene {index} spp {r['spp']:4d}: camera {r['camera_s']:7.2f} s  noise total "
            f"{r['noise_total']:.4f}  camera {r['noise_camera']:.4f}")
    for r in prow:
        log(f"  scene {index} probes vis_rays {r['vis_rays']}: {r['probes_s']:7.2f} s  "
            f"noise {r['noise']:.4f}")
    return res


def bench_growth(cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    """Stage times against image size (probe grid = image / 4) and against the probe count."""
    from phyir.synth.paths import build_lightmap
    from phyir.synth.tracer import render_probes, trace

    sc = _room(cfg["scenes"][0], device)
    sizes = []
    for H, W in cfg["sizes"]:
        st = settings_for(cfg, (H, W), (H // 4, W // 4), cfg["growth_spp"])
        res, t, c, peak = _measured(device, trace, sc, st, seed=SEEDS[0])
        s = res.stats
        sizes.append({"size": [H, W], "probe_grid": [H // 4, W // 4], "spp": st.spp,
                      "texels": int(s["texels"]), "total_s": t, "total_cpu_s": c,
                      "lightmap_s": s["lightmap_s"], "camera_s": s["camera_s"], "probes_s": s["probes_s"],
                      "peak_mb": peak})
        log(f"  growth {H}x{W}: {t:.2f} s (light map {s['lightmap_s']:.2f}, camera {s['camera_s']:.2f}, "
            f"probes {s['probes_s']:.2f}), +{_mb(peak)} MB")
    grids = []
    st0 = settings_for(cfg, cfg["size"], cfg["probe_grid"], cfg["growth_spp"])
    gen = torch.Generator(device=device).manual_seed(SEEDS[0])
    lm = build_lightmap(sc, st0, gen)
    for g in cfg["probe_grids"]:
        st = dataclasses.replace(st0, probe_grid=tuple(g))
        _, t, c = _timed(device, render_probes, sc, lm, st, gen)
        grids.append({"probe_grid": list(g), "probes": g[0] * g[1], "probes_s": t, "probes_cpu_s": c,
                      "ms_per_probe": 1e3 * t / (g[0] * g[1])})
        log(f"  growth probes {g[0]}x{g[1]}: {t:.2f} s ({grids[-1]['ms_per_probe']:.2f} ms per probe)")
    return {"sizes": sizes, "probe_grids": grids}


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Run the data generator benchmark; write ``synth.json`` and ``synth.png``.

    ``repeats`` is unused: every measurement is one render per seed (two seeds), the generator's
    stages taking seconds each.
    """
    cfg = dict(QUICK if quick else FULL)
    from phyir.bench.measure import torch_threads

    with torch_threads(threads):
        return _run(Path(out_dir), cfg, device, log)


def _run(out: Path, cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    from phyir.bench.report import save_target

    result: dict = {"config": {**cfg, "device": device, "threads": torch.get_num_threads(),
                               "torch": torch.__version__, "seeds": list(SEEDS),
                               "loadavg_start": os.getloadavg()}}
    H, W = cfg["size"]
    log(f"synth bench: {len(cfg['scenes'])} room(s) at {H}x{W}, probes {cfg['probe_grid']} of "
        f"{cfg['probe_size']}, on {device}")
    from phyir.synth.tracer import trace  # warm-up: first-call costs stay out of the timings

    trace(_room(cfg["scenes"][0], device), settings_for(cfg, (16, 32), (4, 8), 1), seed=0)
    result["scenes"] = [bench_scene_spp(i, cfg, device, log) for i in cfg["scenes"]]
    result["growth"] = bench_growth(cfg, device, log)
    result["summary"] = summarize(result)
    result["config"]["loadavg_end"] = os.getloadavg()
    save_target(out, "synth", result, plot, format_table, log)
    return result


def summarize(result: dict) -> dict:
    """Per spp: mean over rooms of noise and times; the fitted noise rate of the camera noise."""
    spps = [r["spp"] for r in result["scenes"][0]["camera"]]

    def mean(xs):
        return sum(xs) / len(xs)

    rows = []
    for i, spp in enumerate(spps):
        rs = [s["camera"][i] for s in result["scenes"]]
        rows.append({"spp": spp, **{k: mean([r[k] for r in rs]) for k in
                                    ("camera_s", "camera_cpu_s", "scene_s", "noise_total", "noise_camera")}})
    # slope of log(noise_camera) against log(spp) (Monte Carlo: -0.5)
    xs = [math.log(r["spp"]) for r in rows]
    ys = [math.log(max(r["noise_camera"], 1e-12)) for r in rows]
    mx, my = mean(xs), mean(ys)
    den = sum((x - mx) ** 2 for x in xs)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / den if den else float("nan")
    probes = []
    for i, p in enumerate(result["scenes"][0]["probes"]):
        ps = [s["probes"][i] for s in result["scenes"]]
        probes.append({"vis_rays": p["vis_rays"], "probes_s": mean([q["probes_s"] for q in ps]),
                       "probes_cpu_s": mean([q["probes_cpu_s"] for q in ps]),
                       "noise": mean([q["noise"] for q in ps])})
    return {"camera": rows, "camera_noise_slope": slope, "probes": probes,
            "lightmap_s": mean([s["lightmap_s"] for s in result["scenes"]]),
            "lightmap_cpu_s": mean([s["lightmap_cpu_s"] for s in result["scenes"]]),
            "peak_mb": max((s["peak_mb"] for s in result["scenes"] if s["peak_mb"] is not None),
                           default=None)}


def key_numbers(result: dict) -> dict[str, float]:
    """Headline numbers for the report: noise and time per spp, light map time, growth."""
    sm = result["summary"]
    out = {"lightmap_s": sm["lightmap_s"], "camera_noise_slope": sm["camera_noise_slope"]}
    for r in sm["camera"]:
        out[f"spp{r['spp']}.noise_total"] = r["noise_total"]
        out[f"spp{r['spp']}.noise_camera"] = r["noise_camera"]
        out[f"spp{r['spp']}.scene_s"] = r["scene_s"]
    for r in result["growth"]["sizes"]:
        out["{}x{}.total_s".format(*r["size"])] = r["total_s"]
    return out


def format_table(result: dict) -> str:
    cfg, sm = result["config"], result["summary"]
    H, W = cfg["size"]
    vr = result["scenes"][0]["scene_vis_rays"]
    lines = [f"synth: device {cfg['device']}, {cfg['threads']} thread(s), {len(result['scenes'])} room(s) at "
             f"{H}x{W}, load average {cfg['loadavg_start'][0]:.1f} -> {cfg['loadavg_end'][0]:.1f}; light map "
             f"{sm['lightmap_s']:.2f} s (CPU {sm['lightmap_cpu_s']:.2f} s), peak memory "
             f"+{_mb(sm['peak_mb'])} MB per scene", "",
             f"| spp | camera s | camera CPU s | scene s (light map + camera + probes, {vr} shadow rays) "
             f"| noise total (seed to seed) | noise camera (vs {cfg['ref_spp']} spp, same light map) |",
             "| ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in sm["camera"]:
        lines.append(f"| {r['spp']} | {r['camera_s']:.2f} | {r['camera_cpu_s']:.2f} | {r['scene_s']:.2f} | "
                     f"{r['noise_total']:.4f} | {r['noise_camera']:.4f} |")
    lines += ["", f"camera noise ~ spp^{sm['camera_noise_slope']:.2f} (Monte Carlo: spp^-0.5)", "",
              "| probe shadow rays | probes s | probes CPU s | probe noise (seed to seed) |",
              "| ---: | ---: | ---: | ---: |"]
    for r in sm["probes"]:
        lines.append(f"| {r['vis_rays']} | {r['probes_s']:.2f} | {r['probes_cpu_s']:.2f} | "
                     f"{r['noise']:.4f} |")
    g = result["growth"]
    lines += ["", "| image | probe grid | light map texels | total s | total CPU s | light map s "
              f"| camera s ({g['sizes'][0]['spp']} spp) | probes s | peak MB |",
              "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in g["sizes"]:
        lines.append(f"| {r['size'][0]}x{r['size'][1]} | {r['probe_grid'][0]}x{r['probe_grid'][1]} | "
                     f"{r['texels']} | {r['total_s']:.2f} | {r['total_cpu_s']:.2f} | {r['lightmap_s']:.2f} | "
                     f"{r['camera_s']:.2f} | {r['probes_s']:.2f} | {_mb(r['peak_mb'])} |")
    lines += ["", f"| probe grid (image {H}x{W}) | probes s | probes CPU s | ms per probe |",
              "| --- | ---: | ---: | ---: |"]
    for r in g["probe_grids"]:
        lines.append(f"| {r['probe_grid'][0]}x{r['probe_grid'][1]} | {r['probes_s']:.2f} | "
                     f"{r['probes_cpu_s']:.2f} | {r['ms_per_probe']:.2f} |")
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    """Noise against time per spp (log-log) and stage times against image size."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for s in result["scenes"]:
        t = [r["camera_s"] for r in s["camera"]]
        for key, style in (("noise_total", "o-"), ("noise_camera", "s--")):
            a.plot(t, [r[key] for r in s["camera"]], style,
                   label=f"room {s['scene']}: {key.replace('_', ' ')}")
        for r in s["camera"]:
            a.annotate(str(r["spp"]), (r["camera_s"], r["noise_camera"]), fontsize=7, xytext=(3, 3),
                       textcoords="offset points")
    a.set(xscale="log", yscale="log", xlabel="camera render time (s)", ylabel="relative L1 noise",
          title=f"data generator: spp against noise ({result['config']['device']})")
    px = [r["size"][0] * r["size"][1] for r in result["growth"]["sizes"]]
    for key in ("total_s", "lightmap_s", "camera_s", "probes_s"):
        b.plot(px, [r[key] for r in result["growth"]["sizes"]], "o-", label=key[:-2].replace("_", " "))
    b.set(xscale="log", yscale="log", xlabel="pixels", ylabel="time (s)", title="cost against resolution")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
