"""Per-module inference time and peak memory (``phyir bench modules``), beside the supplement's Table 1.

Parts, batch 1, at 256x512 (``--quick``: 64x128, lite only): GMNet, LNet (at half resolution, its
default probe grid), GSNet, the rendering layer at the re-rendering resolution of training
(supplement B.1: 128x256, a 16x32 probe grid; the prefiltered method training uses and importance
sampling at 16 spp) and the whole :func:`phyir.predict` (networks, upsampling and projection
lighting).  The networks carry random weights (seeded): their cost doesn't depend on the values.
Networks run in float32 under ``torch.inference_mode`` (the paper: "without quantization");
``predict`` runs as users call it (float16 autocast on CUDA).

Times: median of ``repeats`` runs after one warm-up, with min / max and quartiles (see
:mod:`phyir.bench.measure`).  Peak memory: on the CPU measured in a fresh child process whose
allocator returns freed memory (so each part's peak is its own), as the resident size above the
state before the call; on CUDA ``torch.cuda.max_memory_allocated``.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

PAPER_V100_MS = {"gmnet": 18.0, "lnet": 4.0, "render": 109.0, "gsnet": 8.0}
PAPER_GPU_MEMORY_GB = 6.0  # "less than 6G GPU memory" for the whole framework, batch 1
PARTS = ("gmnet", "lnet", "gsnet", "render_prefiltered", "render_importance", "predict")
FULL = {"size": (256, 512), "models": ("effnet", "lite", "full"), "repeats": 5, "render_size": (128, 256),
        "render_spp": 16}
QUICK = {"size": (64, 128), "models": ("lite",), "repeats": 1, "render_size": (32, 64), "render_spp": 16}
CALIBRATION_MB = 64  # a tensor of known size whose measured peak checks the memory method


def bench_image(H: int, W: int, device: str = "cpu") -> torch.Tensor:
    """A deterministic HDR panorama ``[3, H, W]``: the procedural glossy scene of
    :mod:`phyir.bench.render` rendered with the prefiltered layer (lamps up to ~10x the median)."""
    from phyir.bench.render_scenes import bench_scene
    from phyir.shading.render import render_scene

    sc = bench_scene("glossy", H, W, block=max(1, H // 16))
    return render_scene(sc, method="prefiltered")["image"].float().clamp_min(0).to(device)


def _render_scene(cfg: dict, device: str):
    from phyir.bench.render_scenes import bench_scene

    rh, rw = cfg["render_size"]
    return bench_scene("mixed", rh, rw, block=rh // 16).to(device)  # a 16x32 probe grid, as LNet's


def part_calls(size: str, cfg: dict, device: str) -> dict[str, Callable[[], object]]:
    """Callables running each part on realistic inputs (earlier stages precomputed)."""
    from phyir.bench.profile import subnet_calls
    from phyir.inference import predict
    from phyir.nets.model import PhyIRModel
    from phyir.shading.render import render_scene

    H, W = cfg["size"]
    torch.manual_seed(0)
    model = PhyIRModel(size).to(device).eval()
    image = bench_image(H, W, device)
    x = image[None].contiguous(memory_format=torch.channels_last)
    nets = subnet_calls(model, x)
    sc = _render_scene(cfg, device)

    def net(fn):
        def call():
            with torch.inference_mode():
                return fn()
        return call

    calls = {k: net(nets[k]) for k in ("gmnet", "lnet", "gsnet")}
    calls["render_prefiltered"] = lambda: render_scene(sc, method="prefiltered")
    calls["render_importance"] = lambda: render_scene(sc, spp=cfg["render_spp"], method="importance")
    image_cpu = image.cpu()  # as loaded from a file: predict moves what it needs to the device
    calls["predict"] = lambda: predict(image_cpu, model=model, device=device)
    return calls


def memory(cfg: dict, device: str) -> dict:
    """``{model size: {part: {extra_peak_mb, total_peak_mb}}}`` plus the calibration; measured here
    on CUDA, in a fresh child process on the CPU (empty where peaks can't be read)."""
    from phyir.bench import measure as bench_measure

    if bench_measure.is_cuda(device):
        return _memory_here(cfg, device)
    if not bench_measure.cpu_peak_supported():
        return {}
    return bench_measure.measure_in_child("phyir.bench.modules", {**cfg, "threads": torch.get_num_threads()})


def _memory_here(cfg: dict, device: str) -> dict:
    from phyir.bench.measure import peak_memory

    out: dict = {}
    calib = peak_memory(lambda: torch.ones(CALIBRATION_MB * 2**18, device=device).sum(), device)
    out["calibration"] = {"allocated_mb": CALIBRATION_MB, **calib}
    for size in cfg["models"]:
        calls = part_calls(size, cfg, device)
        rows = {}
        for k, fn in calls.items():
            fn()  # warm-up: one-time caches are not the part's working memory
            rows[k] = peak_memory(fn, device)
        out[size] = rows
        del calls
    return out


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Time and memory of every part; writes ``modules.json`` and ``modules.png``."""
    from phyir.bench.measure import time_calls, torch_threads
    from phyir.bench.report import save_target, target_config
    from phyir.nets.model import PhyIRModel, count_parameters

    cfg = target_config(FULL, QUICK, quick, repeats)
    with torch_threads(threads):
        H, W = cfg["size"]
        result: dict = {"config": {**cfg, "device": device, "threads": torch.get_num_threads(),
                                   "weights": "random (seeded)"},
                        "paper_v100_ms": PAPER_V100_MS, "paper_gpu_memory_gb": PAPER_GPU_MEMORY_GB,
                        "models": {}}
        for size in cfg["models"]:
            log(f"modules bench: {size} at {H}x{W}, batch 1, {device}, {cfg['repeats']} repeat(s)")
            calls = part_calls(size, cfg, device)
            times = time_calls(calls, device, cfg["repeats"])
            pred = calls["predict"]()
            model = PhyIRModel(size)
            result["models"][size] = {
                "params": {k: count_parameters(getattr(model, k)) for k in ("gmnet", "lnet", "gsnet")},
                "parts": times,
                "predict_stages_s": json.loads(pred.meta["predict.seconds"])}
            for k, t in times.items():
                log(f"  {k:<19} {t['time_s'] * 1e3:9.1f} ms  (min {t['min_s'] * 1e3:.1f}, "
                    f"max {t['max_s'] * 1e3:.1f}, CPU {t['cpu_s'] * 1e3:.1f})")
            del calls
        t0 = time.perf_counter()
        mem = memory(cfg, device)
        log(f"modules bench: peak memory measured in {time.perf_counter() - t0:.1f} s")
        result["memory_calibration"] = mem.pop("calibration", {})
        for size, rows in mem.items():
            result["models"][size]["memory"] = rows
    save_target(out_dir, "modules", result, plot, format_table, log)
    return result


def _row_name(part: str) -> str:
    return {"render_prefiltered": "rendering layer (prefiltered)",
            "render_importance": "rendering layer (importance)", "predict": "whole predict"}.get(part, part)


def format_table(result: dict) -> str:
    cfg = result["config"]
    H, W = cfg["size"]
    rh, rw = cfg["render_size"]
    sizes = list(result["models"])
    head = "| part | paper V100 ms | " + " | ".join(
        f"{s} ms (median) | {s} min-max | {s} CPU ms | {s} peak MB" for s in sizes) + " |"
    lines = [f"{H}x{W} input, batch 1, {cfg['device']}, {cfg['threads']} thread(s), "
             f"{cfg['repeats']} timed run(s) after 1 warm-up, weights {cfg['weights']}; rendering layer at "
             f"{rh}x{rw}, 16x32 probes (importance: {cfg['render_spp']} spp)", "",
             head, "| --- | ---: |" + " ---: | ---: | ---: | ---: |" * len(sizes)]
    for part in PARTS:
        paper = PAPER_V100_MS.get(part.split("_")[0])
        cells = [_row_name(part), f"{paper:.0f}" if paper else "-"]
        for s in sizes:
            t = result["models"][s]["parts"][part]
            m = result["models"][s].get("memory", {}).get(part, {})
            cells += [f"{t['time_s'] * 1e3:.1f}", f"{t['min_s'] * 1e3:.0f}-{t['max_s'] * 1e3:.0f}",
                      f"{t['cpu_s'] * 1e3:.0f}",
                      f"+{m['extra_peak_mb']:.0f}" if "extra_peak_mb" in m else "n/a"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for s in sizes:
        m = result["models"][s].get("memory", {}).get("predict")
        if m:
            lines.append(f"- {s}: whole predict peaks at {m['total_peak_mb']:.0f} MB "
                         f"{'allocated on the GPU' if 'reserved_peak_mb' in m else 'resident (process)'} "
                         f"(paper: < {PAPER_GPU_MEMORY_GB:.0f} GB GPU memory)")
    cal = result.get("memory_calibration")
    if cal:
        lines.append(f"- memory method check: a {cal['allocated_mb']} MB tensor measured "
                     f"+{cal['extra_peak_mb']:.1f} MB")
    stages = {s: result["models"][s]["predict_stages_s"] for s in sizes}
    for s, st in stages.items():
        lines.append(f"- {s} predict stages (s, last run): " +
                     ", ".join(f"{k} {v:.3f}" for k, v in st.items()))
    return "\n".join(lines)


def key_numbers(result: dict) -> dict[str, float]:
    out = {}
    for s, r in result["models"].items():
        for part, t in r["parts"].items():
            out[f"{s}.{part}.ms"] = t["time_s"] * 1e3
            m = r.get("memory", {}).get(part, {})
            if "extra_peak_mb" in m:
                out[f"{s}.{part}.peak_mb"] = m["extra_peak_mb"]
    return out


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    sizes = list(result["models"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    n = len(sizes) + 1
    xs = range(len(PARTS))
    wdt = 0.8 / n
    paper = [PAPER_V100_MS.get(p.split("_")[0], float("nan")) for p in PARTS]
    a.bar([x - 0.4 + wdt / 2 for x in xs], paper, wdt, label="paper (V100)", color="0.6")
    for i, s in enumerate(sizes, 1):
        ts = [result["models"][s]["parts"][p] for p in PARTS]
        med = [t["time_s"] * 1e3 for t in ts]
        err = [[(t["time_s"] - t["min_s"]) * 1e3 for t in ts], [(t["max_s"] - t["time_s"]) * 1e3 for t in ts]]
        if "gpu_min_s" in ts[0]:
            err = [[(t["time_s"] - t["gpu_min_s"]) * 1e3 for t in ts],
                   [(t["gpu_max_s"] - t["time_s"]) * 1e3 for t in ts]]
        a.bar([x - 0.4 + wdt * (i + 0.5) for x in xs], med, wdt, yerr=err, capsize=2, label=s)
        mem = [result["models"][s].get("memory", {}).get(p, {}).get("extra_peak_mb", float("nan"))
               for p in PARTS]
        b.bar([x - 0.4 + wdt * (i + 0.5) for x in xs], mem, wdt, label=s)
    labels = [_row_name(p).replace(" (", "\n(") for p in PARTS]
    cfg = result["config"]
    a.set(yscale="log", ylabel="ms (median, bars: min-max)",
          title=f"time per part, {cfg['size'][0]}x{cfg['size'][1]}, {cfg['device']}")
    b.set(ylabel="MB above the state before the call", title="peak memory per part")
    for ax in (a, b):
        ax.set_xticks(list(xs), labels, fontsize=7)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def _child(arg: str) -> int:
    cfg = json.loads(arg)
    torch.set_num_threads(cfg.pop("threads"))
    for k in ("size", "render_size"):
        cfg[k] = tuple(cfg[k])
    print(json.dumps(_memory_here(cfg, "cpu")))
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--memory":
        raise SystemExit(_child(sys.argv[2]))
    raise SystemExit("usage: python -m phyir.bench.modules --memory CONFIG_JSON (internal; use phyir bench)")
