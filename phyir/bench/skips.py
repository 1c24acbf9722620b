"""What every skip saves (``phyir bench skips``): time saved and the change of the result.

:func:`phyir.predict` skips work it doesn't need.  Each variant is timed against its baseline and its
outputs compared with the baseline's (relative RMSE per layer; 0 means the skip changes nothing):

``reuse_layers``   a scene file carrying depth, normal and materials (written by a full run, read
                   back): GMNet and GSNet don't run, only LNet and the projection.  vs ``full``.
``reuse_all``      the scene file carries probes too: nothing runs.  vs ``full``.
``no_probes``      ``probes=None``: no LNet, no projection.  vs ``full``.
``geometry_only``  ``outputs=("depth", "normal")``: no GSNet, LNet or projection.  vs ``full``.
``lnet_lighting``  ``lighting="lnet"``: the probes are LNet's, not re-read from the panorama
                   (a quality trade, not a free skip).  vs ``full``.
``points``         ``probes="points"``: probes for N chosen pixels (lazy, as the viewer asks for
                   them) instead of the whole grid, on the scene file of ``reuse_layers``.  Compared
                   with the grid's probes interpolated at the same points.  vs ``reuse_layers``.

The rendering layer's own skips (emissive, mirror and rough pixels) are measured by
:func:`phyir.bench.render.bench_skips` on its procedural mixed scene against a converged reference.

The input is the deterministic HDR panorama of :func:`phyir.bench.modules.bench_image` at twice the
network's resolution (so predict upsamples, as it does for real photographs); the model is the
shipped weights when present, else a seeded random lite model (recorded in the result).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import torch

FULL = {"net_size": (256, 512), "repeats": 3, "points": 16,
        "render": {"size": (64, 128), "block": 2, "probe": (16, 32), "ref_spp": 512, "skip_spp": 64,
                   "repeats": 3}}
QUICK = {"net_size": (64, 128), "repeats": 1, "points": 8,
         "render": {"size": (32, 64), "block": 2, "probe": (16, 32), "ref_spp": 256, "skip_spp": 16,
                    "repeats": 1}}
# variant -> (baseline, what it leaves out)
VARIANTS = {
    "full": (None, "nothing: GMNet, GSNet, LNet, upsampling, projection"),
    "reuse_layers": ("full", "GMNet, GSNet, upsampling (layers read from a scene file)"),
    "reuse_all": ("full", "everything (layers and probes read from a scene file)"),
    "no_probes": ("full", "LNet, projection"),
    "geometry_only": ("full", "GSNet, LNet, projection, other layers' upsampling"),
    "lnet_lighting": ("full", "projection (LNet's probes only)"),
    "points": ("reuse_layers", "the probe grid: probes for N pixels only"),
}


def _model(device: str):
    from phyir.inference import load_cached_model
    from phyir.learn.weights import default_weights_path
    from phyir.nets.model import PhyIRModel

    path = default_weights_path()
    if path.exists():
        return load_cached_model(path, device)[0], path.name
    torch.manual_seed(0)
    return PhyIRModel("lite").to(device).eval(), "random lite (seeded; shipped weights absent)"


def _scene_file(scene, folder: str, name: str, probes: bool):
    """``scene``'s image and layers (and probes) written as a scene file and read back."""
    from phyir import io

    sc = scene.replace(probes=scene.probes if probes else None)
    path = os.path.join(folder, f"{name}.exr")
    io.save_scene(sc, path)
    return io.load_scene(path)


def _diff(out, ref, layers) -> dict[str, float]:
    from phyir.bench.render_measure import rel_rmse

    return {k: rel_rmse(getattr(out, k).float(), getattr(ref, k).float()) for k in layers
            if getattr(out, k) is not None and getattr(ref, k) is not None}


def predict_variants(cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    from phyir import predict
    from phyir.bench.measure import time_calls
    from phyir.bench.modules import bench_image
    from phyir.inference import OUTPUTS, lnet_probes_at
    from phyir.lighting.projection import surface_points

    Hn, Wn = cfg["net_size"]
    image = bench_image(2 * Hn, 2 * Wn)
    model, weights = _model(device)
    kw = {"model": model, "device": device, "net_size": (Hn, Wn)}
    full = predict(image, **kw, lighting="projection")
    g = torch.Generator().manual_seed(0)
    H, W = image.shape[-2:]
    n = cfg["points"]
    u, v = torch.rand(n, generator=g) * W, (0.1 + 0.8 * torch.rand(n, generator=g)) * H
    pts = surface_points(full, u, v)
    with tempfile.TemporaryDirectory() as tmp:
        layers = _scene_file(full, tmp, "layers", probes=False)
        everything = _scene_file(full, tmp, "all", probes=True)
    proj = dict(kw, lighting="projection")  # the most work: every skip is measured against it
    calls = {
        "full": lambda: predict(image, **proj),
        "reuse_layers": lambda: predict(layers, **proj),
        "reuse_all": lambda: predict(everything, **proj),
        "no_probes": lambda: predict(image, probes=None, **proj),
        "geometry_only": lambda: predict(image, outputs=("depth", "normal"), **proj),
        "lnet_lighting": lambda: predict(image, **dict(kw, lighting="lnet")),
        "points": lambda: predict(layers, probes="points", points=pts, **proj),
    }
    log(f"skips bench: predict variants, input {H}x{W}, network {Hn}x{Wn}, {weights}, "
        f"{cfg['repeats']} repeat(s)")
    times = time_calls(calls, device, cfg["repeats"])
    outs = {k: fn() for k, fn in calls.items()}
    rows = {}
    for name, (base, skipped) in VARIANTS.items():
        out = outs[name]
        row = {"skips": skipped, "baseline": base, **times[name],
               "computed": out.meta.get("predict.computed", ""), "reused": out.meta.get("predict.reused", "")}
        if base is not None:
            t0 = times[base]["time_s"]
            row["time_saved_s"] = t0 - row["time_s"]
            row["time_saved_frac"] = 1 - row["time_s"] / t0
            row["cpu_saved_frac"] = 1 - row["cpu_s"] / max(times[base]["cpu_s"], 1e-9)
        if name == "points":
            grid = lnet_probes_at(outs[base].probes, pts)  # what the grid gives at those points
            row["diff"] = {"probes": _diff_t(out.probes[:, 0], grid)}
        elif base is not None:
            row["diff"] = _diff(out, outs[base], OUTPUTS)
        row["max_diff"] = max(row.get("diff", {}).values(), default=0.0)
        rows[name] = row
        log(f"  {name:<14} {row['time_s'] * 1e3:9.1f} ms  saved "
            f"{100 * row.get('time_saved_frac', 0.0):5.1f}%  max rel. diff {row['max_diff']:.2e}")
    return {"input_size": [H, W], "weights": weights, "points": n, "rows": rows}


def _diff_t(a: torch.Tensor, b: torch.Tensor) -> float:
    from phyir.bench.render_measure import rel_rmse

    return rel_rmse(a.float(), b.float())


def render_skips(cfg: dict, device: str, log: Callable[[str], None]) -> list[dict]:
    from phyir.bench.render import bench_scene, bench_skips

    H, W = cfg["size"]
    log(f"skips bench: rendering layer skips, mixed scene {H}x{W}, importance {cfg['skip_spp']} spp, "
        f"reference {cfg['ref_spp']} spp")
    sc = bench_scene("mixed", H, W, cfg["block"], cfg["probe"]).to(device)
    return bench_skips(sc, cfg, device, log)[-1]["summary"]


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Time and change of every skip; writes ``skips.json`` and ``skips.png``."""
    cfg = {**(QUICK if quick else FULL)}
    cfg["render"] = dict(cfg["render"])
    if repeats is not None:
        cfg["repeats"] = cfg["render"]["repeats"] = repeats
    from phyir.bench.measure import torch_threads
    from phyir.bench.report import save_target

    with torch_threads(threads):
        result = {"config": {**cfg, "device": device, "threads": torch.get_num_threads()},
                  "predict": predict_variants(cfg, device, log),
                  "render": render_skips(cfg["render"], device, log)}
    save_target(out_dir, "skips", result, plot, format_table, log)
    return result


def format_table(result: dict) -> str:
    p = result["predict"]
    cfg = result["config"]
    H, W = p["input_size"]
    Hn, Wn = cfg["net_size"]
    lines = [f"predict on a {H}x{W} panorama (network {Hn}x{Wn}), {p['weights']}, {cfg['device']}, "
             f"{cfg['threads']} thread(s), {cfg['repeats']} timed run(s) after 1 warm-up; "
             f"points: {p['points']} pixels", "",
             "| variant | leaves out | computed | time ms (median) | min-max ms | CPU ms | saved vs baseline "
             "(wall; CPU) | max rel. diff vs baseline |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in p["rows"].items():
        saved = (f"{r['time_saved_s'] * 1e3:.0f} ms ({100 * r['time_saved_frac']:.0f}%; CPU "
                 f"{100 * r['cpu_saved_frac']:.0f}%) vs {r['baseline']}" if r["baseline"] else "-")
        nonzero = {k: v for k, v in r.get("diff", {}).items() if v != 0}
        diff = ", ".join(f"{k} {v:.1e}" for k, v in nonzero.items()) + (" (others 0)" if len(nonzero) < len(
            r.get("diff", {})) else "") if nonzero else "0"
        lines.append(f"| {name} | {r['skips']} | {r['computed'] or '-'} | {r['time_s'] * 1e3:.1f} | "
                     f"{r['min_s'] * 1e3:.0f}-{r['max_s'] * 1e3:.0f} | {r['cpu_s'] * 1e3:.0f} | {saved} | "
                     f"{diff} |")
    rc = cfg["render"]
    lines += ["", f"rendering layer skips (mixed scene {rc['size'][0]}x{rc['size'][1]}, importance "
              f"{rc['skip_spp']} spp, error vs a {rc['ref_spp']} spp reference)", "",
              "| skip | pixels | samples saved | wall time saved (median) | CPU time saved (min) "
              "| err image with / without | err on its pixels with / without |",
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for e in result["render"]:
        own = (f"{e['err_pixels']:.4f} / {e['err_pixels_without']:.4f}" if "err_pixels" in e
               else "n/a (image value by definition)")
        lines.append(f"| {e['skip']} | {100 * e['fraction']:.1f}% | {100 * e['samples_saved_frac']:.1f}% | "
                     f"{e['time_saved_s'] * 1e3:.0f} ms ({100 * e['time_saved_frac']:.0f}%) | "
                     f"{e['cpu_saved_s'] * 1e3:.0f} ms ({100 * e['cpu_saved_frac']:.0f}%) | "
                     f"{e['err_image']:.4f} / {e['err_image_without']:.4f} | {own} |")
    return "\n".join(lines)


def key_numbers(result: dict) -> dict[str, float]:
    out = {}
    for name, r in result["predict"]["rows"].items():
        out[f"predict.{name}.ms"] = r["time_s"] * 1e3
        if r["baseline"]:
            out[f"predict.{name}.time_saved_frac"] = r["time_saved_frac"]
            out[f"predict.{name}.cpu_saved_frac"] = r["cpu_saved_frac"]
            out[f"predict.{name}.max_diff"] = r["max_diff"]
    for e in result["render"]:
        out[f"render.{e['skip']}.time_saved_frac"] = e["time_saved_frac"]
        out[f"render.{e['skip']}.cpu_saved_frac"] = e["cpu_saved_frac"]
        out[f"render.{e['skip']}.err_image"] = e["err_image"]
    return out


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    rows = result["predict"]["rows"]
    names = list(rows)
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    t = [rows[k]["time_s"] * 1e3 for k in names]
    err = [[(rows[k]["time_s"] - rows[k]["min_s"]) * 1e3 for k in names],
           [(rows[k]["max_s"] - rows[k]["time_s"]) * 1e3 for k in names]]
    a.barh(names, t, xerr=err, capsize=2)
    for i, k in enumerate(names):
        if rows[k]["baseline"]:
            a.annotate(f"diff {rows[k]['max_diff']:.1e}", (t[i], i), fontsize=7, xytext=(4, -3),
                       textcoords="offset points")
    a.set(xscale="log", xlabel="ms per predict (median, bars: min-max)", title="predict: time of each skip")
    a.invert_yaxis()
    r = result["render"]
    b.scatter([100 * e["time_saved_frac"] for e in r], [e.get("err_pixels", e["err_image"]) for e in r],
              label="with the skip")
    b.scatter([0] * len(r), [e.get("err_pixels_without", e["err_image_without"]) for e in r], marker="x",
              label="without")
    for e in r:
        b.annotate(e["skip"], (100 * e["time_saved_frac"], e.get("err_pixels", e["err_image"])), fontsize=7,
                   xytext=(3, 3), textcoords="offset points")
    b.set(xlabel="time saved (%)", ylabel="relative RMSE on the pixels it changes",
          title="rendering layer skips")
    for ax in (a, b):
        ax.grid(True, alpha=0.3)
    b.legend()
    fig.tight_layout()
    save_figure(fig, path)
