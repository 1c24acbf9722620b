"""Benchmark of the model: size x network resolution against error and time (``phyir bench model``).

For each model size (``effnet``, ``lite``, ``full``) and network resolution (``net_sizes``), every
test scene is predicted by :func:`phyir.predict` (LNet lighting, the networks at that resolution, the outputs
brought back to the scene's own resolution) and scored against its ground truth:

* ``depth_abs_rel`` (:func:`phyir.evaluation.metrics.depth_metrics`), ``albedo_mse`` and ``albedo_si_mse``
  (:func:`phyir.evaluation.metrics.material_metrics`, emitters left out) --
  :func:`phyir.evaluation.synthetic.pixel_metrics`;
* relighting error (supplement D.3, :func:`phyir.evaluation.metrics.relight_errors`) of the Table 2 spheres at
  ``relight`` ground-truth probe cells spread over the grid, LNet's probes read at the predicted
  position of each cell (as :func:`phyir.evaluation.synthetic.evaluate_model`'s ``model/lnet``), and its mean
  over the three materials ``relight_mean``.

Weights: ``$PHYIR_BENCH_WEIGHTS`` or the shipped weights
(:func:`phyir.learn.weights.default_weights_path`, model size ``effnet``) for the size they hold;
the other sizes are timed with random weights and their errors are None (JSON null, "n/a" in the
table).

``$PHYIR_BENCH_MODELS`` (comma-separated, default ``effnet,lite,full``; quick: ``lite,full``) picks
the model sizes.

Test data: ``$PHYIR_BENCH_DATA``, a synthetic dataset folder (its ``test`` split, scenes present on
disk, at most ``scenes``); by default a few scenes generated once with :mod:`phyir.synth` into the
user cache (quick mode: two 32x64 scenes into the output folder).

Times: ``predict_s`` is the median over scenes and ``repeats`` of one whole :func:`phyir.predict`
call after a warm-up; ``network_s`` the median of the bare networks (GMNet, LNet, GSNet) at batch 1.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from phyir.scene import PanoScene

FULL = {"sizes": ("effnet", "lite", "full"), "net_sizes": ((128, 256), (256, 512)), "scenes": 4, "repeats": 1,
        "relight": 16, "relight_spp": 64, "relight_size": 16,
        "data": {"count": 10, "size": (128, 256), "probe_grid": (16, 32), "spp": 8}}
QUICK = {"sizes": ("lite", "full"), "net_sizes": ((32, 64), (64, 128)), "scenes": 2, "repeats": 1,
         "relight": 4, "relight_spp": 16, "relight_size": 8,
         "data": {"count": 2, "size": (32, 64), "probe_grid": (8, 16), "spp": 4}}
ERROR_KEYS = ("depth_abs_rel", "albedo_mse", "albedo_si_mse", "relight_diffuse", "relight_matte_silver",
              "relight_mirror_silver", "relight_mean")


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "phyir" / "bench_model"


def eval_scenes(cfg: dict, out: Path, quick: bool, log: Callable[[str], None]) -> list[Path]:
    """The scene files to evaluate on (see the module doc)."""
    from phyir.errors import InputError

    root = os.environ.get("PHYIR_BENCH_DATA")
    if root:
        from phyir.learn.datasets import read_manifest

        files = [Path(root) / f for f in read_manifest(root).get("test", [])]
        files = [f for f in files if f.is_file()][:cfg["scenes"]]
        if not files:
            raise InputError(root, "no scene of the test split is on disk")
        return files
    d = cfg["data"]
    folder = out / "model_data" if quick else _cache_dir() / "s{}x{}_{}spp".format(*d["size"], d["spp"])
    files = [folder / f"scene_{i:06d}.exr" for i in range(d["count"])]
    if not all(f.is_file() for f in files):
        from phyir.synth.dataset import DatasetConfig, generate_dataset, tiny_settings

        log(f"model bench: generating {d['count']} test scenes at {d['size'][0]}x{d['size'][1]} "
            f"into {folder}")
        ds = DatasetConfig(seed=9_000_001, count=d["count"], size=d["size"], probe_grid=d["probe_grid"],
                           probe_size=(8, 16) if quick else (16, 32), spp=d["spp"], half=not quick)
        st = tiny_settings(d["size"], d["probe_grid"], ds.probe_size, d["spp"]) if quick else None
        generate_dataset(folder, ds, settings=st, progress=False)
    # every generated scene is unseen by the model (its own dataset seed), so all of them are a test set
    return files[:cfg["scenes"]]


def lnet_relight(pred: PanoScene, gt: PanoScene, cfg: dict) -> dict[str, float]:
    """Relighting errors of LNet's probes at ``relight`` ground-truth probe cells (module doc)."""
    from phyir import pano
    from phyir.evaluation.synthetic import lighting_metrics, spread
    from phyir.inference import lnet_probes_at
    from phyir.lighting.projection import probe_positions

    Hp, Wp = gt.probe_grid
    cells = spread(Hp * Wp, cfg["relight"])[:cfg["relight"]]
    gt_p = gt.probes.reshape(Hp * Wp, 3, *gt.probe_size)[cells]
    gt_pos = probe_positions(gt.depth, gt.normal, (Hp, Wp)).reshape(-1, 3)[cells]
    pred_pos = probe_positions(pred.depth, pred.normal, (Hp, Wp)).reshape(-1, 3)[cells]
    probes = pano.resize_area(lnet_probes_at(pred.probes, pred_pos), *gt.probe_size)
    return lighting_metrics(probes, gt_p, gt_pos, relight=cfg["relight"], spp=cfg["relight_spp"],
                            size=cfg["relight_size"])


def _model(size: str, device: str, log: Callable[[str], None]):
    """(model, weights name or None) -- the trained weights when they are of this size, else random."""
    from phyir.learn.weights import default_weights_path, load_model
    from phyir.nets.model import PhyIRModel

    path = Path(os.environ.get("PHYIR_BENCH_WEIGHTS") or default_weights_path())
    if path.is_file():
        model = load_model(path, device)
        if model.config.size == size:
            return model, path.name
        log(f"model bench: {path} holds a {model.config.size} model; {size} runs with random weights")
    else:
        log(f"model bench: no weights at {path}; {size} runs with random weights (errors n/a)")
    torch.manual_seed(0)
    return PhyIRModel(size).to(device).eval(), None


def bench_config(model, weights: str | None, net_size: tuple[int, int], scenes: list[PanoScene],
                 cfg: dict, device: str) -> dict:
    """Time and (with trained weights) errors of one model at one network resolution."""
    from phyir.bench.measure import time_calls
    from phyir.evaluation.synthetic import model_input, pixel_metrics
    from phyir.inference import predict

    def run(gt: PanoScene) -> PanoScene:
        return predict(model_input(gt), model=model, device=device, lighting="lnet", net_size=net_size)

    preds = [run(gt) for gt in scenes]  # also the warm-up
    times, cpu = [], []
    for _ in range(cfg["repeats"]):
        for gt in scenes:
            t0, c0 = time.perf_counter(), time.process_time()
            run(gt)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    x = torch.rand(1, 3, *net_size, generator=torch.Generator().manual_seed(0)).to(device)

    def nets() -> None:
        with torch.inference_mode():
            model.forward_parts(x)

    net = time_calls({"nets": nets}, device, max(cfg["repeats"], 3))["nets"]
    row: dict = {"net_size": list(net_size), "weights": weights, "predict_s": statistics.median(times),
                 "predict_min_s": min(times), "predict_max_s": max(times),
                 "predict_cpu_s": statistics.median(cpu), "network_s": net["time_s"],
                 "network_q1_s": net["q1_s"], "network_q3_s": net["q3_s"], "network_cpu_s": net["cpu_s"],
                 "scenes": len(scenes)}
    if weights is None:
        return row | {k: None for k in ERROR_KEYS}
    per = []
    for pred, gt in zip(preds, scenes):
        m = pixel_metrics(pred, gt) | lnet_relight(pred, gt, cfg)
        per.append({"depth_abs_rel": m["depth.abs_rel"], "albedo_mse": m["albedo_mse"],
                    "albedo_si_mse": m["albedo_si_mse"],
                    **{k: m[k] for k in ERROR_KEYS if k.startswith("relight_") and k in m}})
        per[-1]["relight_mean"] = statistics.fmean(per[-1][k] for k in ("relight_diffuse",
                                                                       "relight_matte_silver",
                                                                       "relight_mirror_silver"))
    return row | {k: statistics.fmean(p[k] for p in per) for k in ERROR_KEYS}


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Run the model benchmark; write ``model.json`` and ``model.png``."""
    from phyir.bench.measure import torch_threads
    from phyir.bench.report import target_config

    cfg = target_config(FULL, QUICK, quick, repeats)
    if os.environ.get("PHYIR_BENCH_MODELS"):
        cfg["sizes"] = tuple(m.strip() for m in os.environ["PHYIR_BENCH_MODELS"].split(",") if m.strip())

    with torch_threads(threads):
        return _run(Path(out_dir), cfg, quick, device, log)


def _run(out: Path, cfg: dict, quick: bool, device: str, log: Callable[[str], None]) -> dict:
    from phyir.bench.report import save_target
    from phyir.io import load_scene

    out.mkdir(parents=True, exist_ok=True)
    files = eval_scenes(cfg, out, quick, log)
    scenes = [load_scene(f) for f in files]
    H, W = scenes[0].size
    result: dict = {"config": {**cfg, "device": device, "threads": torch.get_num_threads(),
                               "torch": torch.__version__, "data": str(files[0].parent),
                               "scene_size": [H, W], "loadavg_start": os.getloadavg()}, "rows": []}
    log(f"model bench: {len(scenes)} test scenes at {H}x{W} from {files[0].parent}, on {device}")
    for size in cfg["sizes"]:
        model, weights = _model(size, device, log)
        for ns in cfg["net_sizes"]:
            row = {"model": size, **bench_config(model, weights, tuple(ns), scenes, cfg, device)}
            result["rows"].append(row)
            log(f"  {size:<4} net {ns[0]}x{ns[1]}: predict {row['predict_s'] * 1e3:8.0f} ms, networks "
                f"{row['network_s'] * 1e3:8.0f} ms, depth AbsRel {_fmt(row['depth_abs_rel'])}, "
                f"relight {_fmt(row['relight_mean'])}")
        del model
    result["config"]["loadavg_end"] = os.getloadavg()
    save_target(out, "model", result, plot, format_table, log)
    return result


def key_numbers(result: dict) -> dict[str, float]:
    """Headline numbers for the report: time and (where trained weights exist) errors per row."""
    out = {}
    for r in result["rows"]:
        k = f"{r['model']}.{r['net_size'][0]}x{r['net_size'][1]}"
        out[f"{k}.predict_ms"] = r["predict_s"] * 1e3
        out[f"{k}.network_ms"] = r["network_s"] * 1e3
        out |= {f"{k}.{e}": r[e] for e in ("depth_abs_rel", "albedo_mse", "relight_mean") if r[e] is not None}
    return out


def _ms(s: float | None) -> float | None:
    return None if s is None else s * 1e3


def _fmt(v: float | None, spec: str = ".4f") -> str:
    return "n/a" if v is None else format(v, spec)


def format_table(result: dict) -> str:
    cfg = result["config"]
    H, W = cfg["scene_size"]
    lines = [f"model: device {cfg['device']}, {cfg['threads']} thread(s), {result['rows'][0]['scenes']} test "
             f"scenes at {H}x{W} ({cfg['data']}), load average {cfg['loadavg_start'][0]:.1f} -> "
             f"{cfg['loadavg_end'][0]:.1f}; errors n/a = no trained weights (timed with random weights)", "",
             "| model | weights | net size | predict ms (median) | predict CPU ms | networks ms (median) "
             "| networks CPU ms "
             "| depth AbsRel | albedo MSE | albedo si-MSE | relight diffuse | relight matte silver "
             "| relight mirror silver |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in result["rows"]:
        lines.append(f"| {r['model']} | {r['weights'] or 'random'} | {r['net_size'][0]}x{r['net_size'][1]} | "
                     f"{r['predict_s'] * 1e3:.0f} | {_fmt(_ms(r.get('predict_cpu_s')), '.0f')} | "
                     f"{r['network_s'] * 1e3:.0f} | "
                     f"{r['network_cpu_s'] * 1e3:.0f} | "
                     + " | ".join(_fmt(r[k]) for k in ERROR_KEYS if k != "relight_mean") + " |")
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    """Error against predict time, one panel per error (models with trained weights only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    keys = ("depth_abs_rel", "albedo_mse", "relight_mean")
    fig, axes = plt.subplots(1, len(keys) + 1, figsize=(4.2 * (len(keys) + 1), 3.8))
    for model in result["config"]["sizes"]:
        rows = [r for r in result["rows"] if r["model"] == model]
        t = [r["predict_s"] * 1e3 for r in rows]
        axes[-1].plot([r["net_size"][0] for r in rows], t, "o-", label=model)
        for ax, k in zip(axes, keys):
            pts = [(ti, r[k], r) for ti, r in zip(t, rows) if r[k] is not None]
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=model)
                for p in pts:
                    ax.annotate(f"{p[2]['net_size'][0]}x{p[2]['net_size'][1]}", p[:2], fontsize=7,
                                xytext=(3, 3), textcoords="offset points")
    for ax, k in zip(axes, keys):
        ax.set(xlabel="predict time (ms, median)", ylabel=k, title=k.replace("_", " "))
    axes[-1].set(xlabel="network height (px)", ylabel="predict time (ms)", yscale="log",
                 title=f"time ({result['config']['device']})")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
