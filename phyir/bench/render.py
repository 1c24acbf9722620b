"""Benchmark of the rendering layer: time against error (``phyir bench render``).

Scenes are procedural: smooth random G-buffers (normals facing the camera, base colour, roughness,
metalness) and a probe grid (one probe per ``block x block`` pixels) lit by an ambient gradient plus
a few bright sources at fixed 3D positions, so probes vary smoothly across the grid.

Errors are relative RMSE, sqrt(sum (x - ref)^2 / sum ref^2) over shaded pixels, against a converged
reference: the mean of two importance-sampled renders at ``ref_spp / 2`` each, with seeds no method
uses.  The reference's own noise is estimated from the difference of its halves and removed in
quadrature (``err`` columns; ``err_raw`` keeps the plain value).  Times are the median of
``repeats`` runs after one warm-up, with the interquartile range; the load average is recorded
because the machine may be shared.

The scenes are :mod:`phyir.bench.render_scenes`, timing, errors and the reference
:mod:`phyir.bench.render_measure`, summaries, tables and plots :mod:`phyir.bench.render_report`.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.bench.render_measure import (
    PREFILTERED_F32,
    Reference,
    level_matmul,
    loglog,
    rel_rmse,
    time_interleaved,
)
from phyir.bench.render_report import format_table, plot, plot_energy, spread_summary, summarize
from phyir.bench.render_scenes import bench_scene, shaded_mask
from phyir.scene import PanoScene

PAPER_MS = 109.0  # rendering layer, 128x256, V100 (supplement Table 1)
FULL = {"size": (128, 256), "block": 2, "probe": (16, 32), "ref_spp": 1024, "repeats": 3, "memory": True,
        "is_spp": (1, 2, 4, 8, 16, 32, 64, 128, 256), "uniform_spp": (16, 64, 256), "skip_spp": 64,
        "seeds": 6}
QUICK = {"size": (64, 128), "block": 2, "probe": (16, 32), "ref_spp": 512, "repeats": 2,
         "is_spp": (1, 2, 4, 16, 64), "uniform_spp": (16, 64), "skip_spp": 16, "seeds": 2}


def bench_methods(scene: PanoScene, cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    """Time and error of uniform / importance sampling at several spp and of the prefiltered path."""
    from phyir.shading import prefilter
    from phyir.shading.render import render_scene

    mask = shaded_mask(scene)
    t0 = time.perf_counter()
    ref = Reference(scene, cfg["ref_spp"], mask)
    log(f"  reference: quadrature diffuse + {cfg['ref_spp']} spp specular in "
        f"{time.perf_counter() - t0:.1f} s, noise {ref.noise['image']:.1e} (image)")
    configs = [("prefiltered", 1)] + [("uniform", n) for n in cfg["uniform_spp"]] + \
        [("importance", n) for n in cfg["is_spp"]]
    if level_matmul(scene.probes) != "float32":  # what the low-precision levels cost and save
        configs.insert(1, (PREFILTERED_F32, 1))

    def make(method: str, spp: int) -> Callable[[], dict[str, Tensor]]:
        def call() -> dict[str, Tensor]:
            if method.startswith("prefiltered"):
                prefilter.clear_cache()  # time the prefiltering too, every call
            if method == PREFILTERED_F32:
                old, prefilter.LEVEL_PRECISION = prefilter.LEVEL_PRECISION, "float32"
                try:
                    return render_scene(scene, method="prefiltered")
                finally:
                    prefilter.LEVEL_PRECISION = old
            return render_scene(scene, spp=spp, method=method, seed=7)
        return call

    calls = {c: make(*c) for c in configs}
    errors, first, breakdown = {}, {}, []
    for c, fn in calls.items():  # errors, and the cost of one call to group the timings
        t0 = time.perf_counter()
        out = fn()
        first[c] = time.perf_counter() - t0
        errors[c] = ref.errors(out)
        if c[0] == "prefiltered":
            breakdown = prefiltered_breakdown(scene, out, ref)
    times = {}
    for fast in (True, False):  # interleaved timing; short calls get more repeats
        group = {c: fn for c, fn in calls.items() if (first[c] < 1.0) == fast}
        if group:
            times.update(time_interleaved(group, device, cfg["repeats"]))
    rows = []
    for c in configs:
        method, spp = c
        row = {"method": method, "spp": spp if not method.startswith("prefiltered") else 0, **times[c],
               **errors[c]}
        rows.append(row)
        log(f"  {method:<15} spp {row['spp']:>4}  {row['median_s'] * 1e3:9.1f} ms  "
            f"err image {row['err_image']:.4f} specular {row['err_specular']:.4f}")
    return {"reference_spp": cfg["ref_spp"], "reference_noise": ref.noise, "rows": rows,
            "prefiltered_breakdown": breakdown}


def prefiltered_breakdown(scene: PanoScene, out: dict[str, Tensor], ref: Reference) -> list[dict]:
    """Where the split sum errs: specular error and bias of the prefiltered render by n.v and R."""
    from phyir.shading.render import view_dirs

    H, W = scene.size
    nv = (scene.normal * view_dirs(H, W, scene.normal.device, scene.normal.dtype)).sum(0, keepdim=True)
    rough = scene.roughness
    rows = []
    bins = (("n.v", nv, (0.0, 0.3, 0.5, 0.7, 1.01)), ("R", rough, (0.0, 0.2, 0.4, 0.6, 0.8, 1.01)))
    for name, t, edges in bins:
        for lo, hi in zip(edges, edges[1:]):
            m = ref.mask * ((t >= lo) & (t < hi))
            if float(m.sum()) == 0:
                continue
            e = (out["specular"] - ref.layers["specular"]) * m
            r = ref.layers["specular"] * m
            rows.append({"by": name, "lo": lo, "hi": min(hi, 1.0), "pixels": float(m.mean()),
                         "err_specular": rel_rmse(out["specular"], ref.layers["specular"], m),
                         "bias_specular": float(e.sum() / r.sum().clamp(min=1e-30)),
                         "share_of_err2": float((e**2).sum() / (((out["specular"] - ref.layers["specular"])
                                                                  * ref.mask) ** 2).sum().clamp(min=1e-30))})
    return rows


def seed_spread(kind: str, cfg: dict, device: str, base: dict, log: Callable[[str], None]) -> dict:
    """The prefiltered path against importance sampling on ``cfg["seeds"]`` scenes of ``kind``.

    Seed 0 is ``base`` (:func:`bench_methods` with its summary); every further seed gets its own
    reference and errors of both paths.  Per seed, the spp at which importance sampling matches the
    prefiltered error is read off its error curve (log-log), and the two are then timed **head to
    head**: importance sampling at that spp (rounded; beyond the largest spp measured, at that spp
    and scaled linearly) interleaved with the prefiltered call, so that this machine's changes of
    speed between the benchmark's phases can't bias the ratio.
    """
    from phyir.shading import prefilter
    from phyir.shading.render import render_scene

    isr = [r for r in base["rows"] if r["method"] == "importance"]
    spp = [r["spp"] for r in isr]
    H, W = cfg["size"]
    rows = []
    for seed in range(cfg.get("seeds", 1)):
        sc = bench_scene(kind, H, W, cfg["block"], cfg["probe"], seed=seed).to(device)

        def pf(scene: PanoScene = sc) -> dict[str, Tensor]:
            prefilter.clear_cache()  # time the prefiltering too, every call
            return render_scene(scene, method="prefiltered")

        if seed == 0:
            err_pf = next(r for r in base["rows"] if r["method"] == "prefiltered")["err_image"]
            err_is = [r["err_image"] for r in isr]
        else:
            ref = Reference(sc, cfg["ref_spp"], shaded_mask(sc))
            err_pf = ref.errors(pf())["err_image"]
            err_is = [ref.errors(render_scene(sc, spp=n, method="importance", seed=7))["err_image"]
                      for n in spp]
        need = loglog(spp, err_is, err_pf)
        timed = min(max(1, round(need)), spp[-1])
        scale = need / timed if need > spp[-1] else 1.0

        def is_call(scene: PanoScene = sc, n: int = timed) -> dict[str, Tensor]:
            return render_scene(scene, spp=n, method="importance", seed=7)

        t = time_interleaved({"pf": pf, "is": is_call}, device, cfg["repeats"])
        row = {"seed": seed, "prefiltered_err": err_pf, "is_spp_same_err": need,
               "is_errors": dict(zip(spp, err_is)), "is_spp_timed": timed,
               "prefiltered_median_s": t["pf"]["median_s"], "prefiltered_cpu_s": t["pf"]["cpu_s"],
               "is_median_s": t["is"]["median_s"] * scale, "is_cpu_s": t["is"]["cpu_s"] * scale}
        for key in ("median_s", "cpu_s"):
            row[f"speedup_{key.split('_')[0]}"] = row[f"is_{key}"] / row[f"prefiltered_{key}"]
        rows.append(row)
        log(f"  {kind} seed {seed}: prefiltered err {err_pf:.4f} ({t['pf']['median_s'] * 1e3:.1f} ms) = "
            f"importance {need:.0f} spp ({row['is_median_s'] * 1e3:.0f} ms, timed at {timed} spp): "
            f"{row['speedup_median']:.1f}x (median wall), {row['speedup_cpu']:.1f}x (CPU)")
    return {"rows": rows, **spread_summary(rows)}


def _sample_count(classes: dict[str, Tensor], spp: int, rough_all: bool = False) -> int:
    """Direction samples (and reflected look-ups) a frame takes with these pixel classes."""
    half = (spp + 1) // 2
    return (spp * (len(classes["std"]) + len(classes["spec"]))
            + (spp if rough_all else half) * len(classes["rough"])
            + half * len(classes["mirror_d"]) + len(classes["mirror"]))


def bench_skips(scene: PanoScene, cfg: dict, device: str, log: Callable[[str], None]) -> list[dict]:
    """Time saved and error introduced by each skip (importance sampling at ``skip_spp``).

    The reference shades every valid non-emissive pixel with full Monte Carlo (no approximation).
    """
    from phyir.shading.render import pixel_classes, render_scene

    mask = shaded_mask(scene)
    spp = cfg["skip_spp"]
    ref = Reference(scene, cfg["ref_spp"], mask, skips={"emissive"})
    variants = {"none": set(), "emissive": {"emissive"}, "mirror": {"emissive", "mirror"},
                "rough": {"emissive", "rough"}, "all": {"emissive", "mirror", "rough"}}
    classes = pixel_classes(scene)
    affected = {}
    for name in ("mirror", "rough"):
        m = torch.zeros(scene.size[0] * scene.size[1], device=mask.device)
        m[classes[name]] = 1
        affected[name] = m.reshape(1, *scene.size) * mask
    from phyir.shading import render

    out = {}
    variants["rough_all_cosine"] = {"emissive", "rough"}

    def make(name: str, sk: set[str]) -> Callable[[], dict[str, Tensor]]:
        def call() -> dict[str, Tensor]:
            old, render.ROUGH_ALL_COSINE = render.ROUGH_ALL_COSINE, name == "rough_all_cosine"
            try:
                return render_scene(scene, spp=spp, seed=7, skips=sk)
            finally:
                render.ROUGH_ALL_COSINE = old
        return call

    calls = {name: make(name, sk) for name, sk in variants.items()}
    times = time_interleaved(calls, device, max(cfg["repeats"], 7))
    for name, sk in variants.items():
        r = calls[name]()
        row = {**times[name], **ref.errors(r),
               "samples": _sample_count(pixel_classes(scene, sk), spp, name == "rough_all_cosine")}
        for a, m in affected.items():
            row[f"err_{a}_pixels"] = rel_rmse(r["image"], ref.layers["image"], m)
            row[f"err_specular_{a}_pixels"] = rel_rmse(r["specular"], ref.layers["specular"], m)
        row["err_rough_all_cosine_pixels"] = row["err_rough_pixels"]
        row["err_specular_rough_all_cosine_pixels"] = row["err_specular_rough_pixels"]
        out[name] = row
        log(f"  skips {name:<16} {row['median_s'] * 1e3:9.1f} ms  CPU min {row['cpu_min_s'] * 1e3:9.1f} ms  "
            f"err image {row['err_image']:.4f}")
    total = scene.size[0] * scene.size[1]
    em = scene.masks.get("emission")
    frac = {"emissive": float((em > 0.5).float().mean()) if em is not None else 0.0,
            "mirror": len(classes["mirror"]) / total, "rough": len(classes["rough"]) / total}
    table = []
    frac["rough_all_cosine"] = frac["rough"]
    for name in ("emissive", "mirror", "rough", "rough_all_cosine"):
        r = out[name]
        # emissive: compared with no skips; the others: on top of the emissive skip
        prev = out["none"] if name == "emissive" else out["emissive"]
        entry = {"skip": name, "fraction": frac[name],
                 "samples_saved_frac": 1 - r["samples"] / prev["samples"],
                 "time_saved_s": prev["median_s"] - r["median_s"],
                 "time_saved_frac": 1 - r["median_s"] / prev["median_s"],
                 "cpu_saved_s": prev["cpu_min_s"] - r["cpu_min_s"],
                 "cpu_saved_frac": 1 - r["cpu_min_s"] / prev["cpu_min_s"],
                 "err_image": r["err_image"], "err_image_without": prev["err_image"]}
        if f"err_{name}_pixels" in r:  # error on the pixels the skip changes, with / without it
            entry["err_pixels"] = r[f"err_{name}_pixels"]
            entry["err_pixels_without"] = prev[f"err_{name}_pixels"]
        if f"err_specular_{name}_pixels" in r:
            entry["err_specular_pixels"] = r[f"err_specular_{name}_pixels"]
            entry["err_specular_pixels_without"] = prev[f"err_specular_{name}_pixels"]
        table.append(entry)
    return [{"variant": k, **v} for k, v in out.items()] + [{"summary": table}]


MEMORY_CASES = (("importance", False), ("importance", True), ("prefiltered", False), ("prefiltered", True))


def memory_use(H: int = 256, W: int = 512, spp: int = 64, log: Callable[[str], None] = print) -> list[dict]:
    """Peak resident memory added by one render at ``H x W`` (probe per 2x2 pixels), forward and
    forward + backward, each in a fresh child process with :data:`phyir.bench.measure.MALLOC_ENV`
    (in this process, earlier targets' freed memory stays resident and hides the peaks); Linux only
    (empty elsewhere)."""
    from phyir.bench import measure as bench_measure

    if not bench_measure.cpu_peak_supported():
        return []
    rows = []
    for method, grad in MEMORY_CASES:
        rows.append(bench_measure.measure_in_child("phyir.bench.render", {
            "method": method, "grad": grad, "H": H, "W": W, "spp": spp, "threads": torch.get_num_threads()}))
        log(f"  memory {method:<11} {'forward+backward' if grad else 'forward':<16} "
            f"+{rows[-1]['extra_peak_mb']:.0f} MB (probes {rows[-1]['probes_mb']:.0f} MB)")
    return rows


def _memory_child(method: str, grad: bool, H: int, W: int, spp: int) -> dict:
    """One case of :func:`memory_use`, measured in this (fresh) process."""
    from phyir.bench.measure import peak_memory
    from phyir.shading.render import render_scene

    sc = bench_scene("mixed", H, W)
    if grad:
        sc = sc.replace(normal=sc.normal.requires_grad_(True), albedo=sc.albedo.requires_grad_(True),
                        probes=sc.probes.requires_grad_(True))

    def call() -> None:
        out = render_scene(sc, spp=spp, method=method)
        if grad:
            out["image"].sum().backward()

    call()  # warm-up: one-time tables (DFG, operators, Sobol points) are not the render's working memory
    for t in (sc.normal, sc.albedo, sc.probes):
        t.grad = None
    peak = peak_memory(call, "cpu")
    probes_mb = sc.probes.numel() * sc.probes.element_size() / 2**20
    return {"method": method, "grad": grad, "size": [H, W], "spp": spp,
            "extra_peak_mb": peak["extra_peak_mb"], "probes_mb": probes_mb}


def energy_curves(path: Path | None = None) -> dict:
    """White-furnace energy of the model from the DFG table (validated against quadrature in the tests):
    the diffuse excess of a white dielectric (B = 1, M = 0 reflects 1 + F0 A + B) and the energy lost
    by the single-scattering specular lobe of a white metal (1 - A - B), against n.v per roughness.
    Also checks the rendering layer itself: diffuse of B = 1, M = 0 under a unit environment."""
    from phyir.shading import prefilter
    from phyir.shading.render import shade_env

    nv = torch.linspace(0.02, 1.0, 50)
    roughs = (0.1, 0.3, 0.5, 0.7, 1.0)
    curves = {"n_dot_v": nv.tolist(), "dielectric_total": {}, "metal_loss": {}}
    for r in roughs:
        e_d = prefilter.specular_albedo(nv, torch.full_like(nv, r), torch.tensor([0.04]))[:, 0]
        e_m = prefilter.specular_albedo(nv, torch.full_like(nv, r), torch.tensor([1.0]))[:, 0]
        curves["dielectric_total"][str(r)] = (1 + e_d).tolist()
        curves["metal_loss"][str(r)] = (1 - e_m).tolist()
    # furnace check through the layer: 16 x 32 pixels over all directions, view 60 deg off the normal
    n = pano.directions(16, 32)
    v = F.normalize(n + 1.7 * F.normalize(torch.cross(n, torch.tensor([0.3, 0.9, 0.1])[:, None, None]
                                                      .expand_as(n), dim=0), dim=0), dim=0)
    mats = (torch.ones(3, 16, 32), torch.full((1, 16, 32), 0.5), torch.zeros(1, 16, 32))
    env = torch.ones(3, 8, 16)
    furnace = {}
    for method in ("importance", "uniform", "prefiltered"):
        d, s = shade_env(n, v, *mats, env, spp=1024, method=method, parts=True)
        furnace[method] = {"diffuse_mean": float(d.mean()), "diffuse_max_dev": float((d - 1).abs().max()),
                           "specular_mean": float(s.mean())}
    curves["furnace"] = furnace
    if path is not None:
        plot_energy(curves, roughs, path)
    return curves


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Run the render benchmark; write ``render.json``, ``render.png`` and ``render_energy.png``.

    ``threads`` sets torch's CPU threads for the run (on a shared machine one thread makes CPU time
    a fair measure of work: no thread waits on a descheduled sibling).
    """
    from phyir.bench.measure import torch_threads
    from phyir.bench.report import target_config

    with torch_threads(threads):
        return _run(out_dir, target_config(FULL, QUICK, quick, repeats), device, log)


def _run(out_dir: str | os.PathLike, cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    H, W = cfg["size"]
    result: dict = {"config": {**cfg, "device": device, "threads": torch.get_num_threads(),
                               "torch": torch.__version__, "loadavg_start": os.getloadavg()},
                    "scenes": {}}
    for kind in ("glossy", "metal"):
        b, (ph, pw) = cfg["block"], cfg["probe"]
        log(f"render bench: scene {kind} {H}x{W}, probe per {b}x{b} pixels "
            f"({H // b}x{W // b} probes of {ph}x{pw}) on {device}")
        sc = bench_scene(kind, H, W, cfg["block"], cfg["probe"]).to(device)
        result["config"]["level_matmul"] = level_matmul(sc.probes)
        res = bench_methods(sc, cfg, device, log)
        res["summary"] = summarize(res)
        if cfg.get("seeds", 1) > 1:
            log(f"render bench: prefiltered against importance sampling on {cfg['seeds']} {kind} scenes")
            res["seeds"] = seed_spread(kind, cfg, device, res, log)
        result["scenes"][kind] = res
    log(f"render bench: skips on the mixed scene {H}x{W}")
    sc = bench_scene("mixed", H, W, cfg["block"], cfg["probe"]).to(device)
    result["skips"] = bench_skips(sc, cfg, device, log)
    if cfg.get("memory"):
        log("render bench: memory at 256x512, 64 spp")
        result["memory"] = memory_use(log=log)
    result["config"]["loadavg_end"] = os.getloadavg()
    from phyir.bench.report import save_target

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result["energy"] = energy_curves(out / "render_energy.png")
    save_target(out, "render", result, plot, format_table, log)
    return result


def sample_ratios(kind: str = "glossy", cfg: dict | None = None, log: Callable[[str], None] = print) -> dict:
    """Errors only (no timing): uniform against importance sampling at the benchmark's sample counts
    on one scene, and the importance-sampled spp that reaches each uniform error (layers image,
    diffuse, specular) and the prefiltered path's image error (its bias: the first row).
    Independent of machine load, so usable where the full benchmark can't run."""
    from phyir.shading.render import render_scene

    cfg = dict(FULL if cfg is None else cfg)
    H, W = cfg["size"]
    sc = bench_scene(kind, H, W, cfg["block"], cfg["probe"])
    mask = shaded_mask(sc)
    ref = Reference(sc, cfg["ref_spp"], mask)
    rows = []
    methods = (("prefiltered", (0,)), ("uniform", cfg["uniform_spp"]), ("importance", cfg["is_spp"]))
    for method, spps in methods:
        for spp in spps:
            rows.append({"method": method, "spp": spp, **ref.errors(render_scene(sc, spp=max(spp, 1),
                                                                                   method=method, seed=7))})
            log(f"  {kind} {method:<11} spp {spp:>4}  err image {rows[-1]['err_image']:.4f} "
                f"diffuse {rows[-1]['err_diffuse']:.4f} specular {rows[-1]['err_specular']:.4f}")
    isr = [r for r in rows if r["method"] == "importance"]
    ratios = []
    pref = rows[0]["err_image"]
    if math.isfinite(pref) and pref > 0:
        need = loglog([r["spp"] for r in isr], [r["err_image"] for r in isr], pref)
        ratios.append({"layer": "image", "prefiltered_err": pref, "is_spp_same_err": need})
        log(f"  prefiltered image error {pref:.4f} = importance {need:.1f} spp")
    for layer in ("image", "diffuse", "specular"):
        err = [r[f"err_{layer}"] for r in isr]
        if not all(math.isfinite(e) and e > 0 for e in err):
            continue
        for r in rows:
            if r["method"] == "uniform":
                need = loglog([r_["spp"] for r_ in isr], err, r[f"err_{layer}"])
                if r[f"err_{layer}"] >= err[0]:  # beaten at the smallest spp measured: a lower bound
                    need = float(isr[0]["spp"])
                ratios.append({"layer": layer, "uniform_spp": r["spp"], "uniform_err": r[f"err_{layer}"],
                               "is_spp_same_err": need, "sample_ratio": r["spp"] / need,
                               "lower_bound": r[f"err_{layer}"] >= err[0]})
                bound = " (lower bound)" if ratios[-1]["lower_bound"] else ""
                log(f"  {layer}: uniform {r['spp']} spp = importance {need:.1f} spp: "
                    f"{r['spp'] / need:.1f}x fewer samples{bound}")
    return {"kind": kind, "config": cfg, "reference_noise": ref.noise, "rows": rows, "ratios": ratios}


def prefiltered_cpu(kind: str = "metal", spps: tuple[int, ...] = (64, 128), repeats: int = 5,
                    log: Callable[[str], None] = print) -> dict:
    """CPU time (median, min of ``repeats`` interleaved calls after a warm-up) of the prefiltered path
    (prefiltering included) and of importance sampling at ``spps`` on a 128x256 bench scene."""
    from phyir.shading import prefilter
    from phyir.shading.render import render_scene

    sc = bench_scene(kind)

    def make(method: str, spp: int) -> Callable[[], object]:
        def call() -> object:
            prefilter.clear_cache()
            return render_scene(sc, spp=max(spp, 1), method=method, seed=7)
        return call

    calls = {("prefiltered", 0): make("prefiltered", 0), **{("importance", n): make("importance", n)
                                                           for n in spps}}
    cpu: dict = {k: [] for k in calls}
    wall: dict = {k: [] for k in calls}
    for fn in calls.values():
        fn()
    for _ in range(repeats):
        for k, fn in calls.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            cpu[k].append(time.process_time() - c0)
            wall[k].append(time.perf_counter() - t0)
    rows = [{"method": m, "spp": n, "cpu_median_s": statistics.median(v), "cpu_min_s": min(v),
             "wall_median_s": statistics.median(wall[(m, n)])} for (m, n), v in cpu.items()]
    for r in rows:
        log(f"  {kind} {r['method']:<11} spp {r['spp']:>4}  CPU median {r['cpu_median_s'] * 1e3:.1f} ms, "
            f"min {r['cpu_min_s'] * 1e3:.1f} ms, wall median {r['wall_median_s'] * 1e3:.1f} ms "
            f"({torch.get_num_threads()} thread(s))")
    return {"kind": kind, "threads": torch.get_num_threads(), "rows": rows}


def resummarize(out_dir: str | os.PathLike) -> dict:
    """Recompute the summaries of ``out_dir/render.json`` from its measured rows (after a change to
    :func:`~phyir.bench.render_report.summarize` or :func:`~phyir.bench.render_report.spread_summary`;
    nothing is re-measured) and rewrite it, its table in ``report.md``/``report.json`` and its plot."""
    import json

    from phyir.bench import report as bench_report

    out = Path(out_dir)
    result = json.loads((out / "render.json").read_text())
    for res in result["scenes"].values():
        res["summary"] = summarize(res)
        if "seeds" in res:
            res["seeds"].update(spread_summary(res["seeds"]["rows"]))
    bench_report.save_target(out, "render", result, plot, format_table, lambda s: None)
    report_path = out / "report.json"
    if report_path.exists():
        import sys

        report = json.loads(report_path.read_text())
        old = report["targets"].get("render", {})
        entry = bench_report.target_entry("render", sys.modules[__name__], result, old.get("seconds", 0.0),
                                          out, [])
        entry.update(date=old.get("date", entry["date"]), command=old.get("command", ""))
        report["targets"]["render"] = entry
        bench_report.write_report(out, report)
    return result


if __name__ == "__main__":
    # python -m phyir.bench.render OUT.json [glossy|metal ...]: errors only (sample_ratios)
    # python -m phyir.bench.render OUT.json --prefiltered-cpu [kind [threads [spp ...]]]: prefiltered_cpu
    import sys

    torch.set_num_threads(1)
    if sys.argv[1:2] == ["--memory"]:  # a child of memory_use
        import json

        case = json.loads(sys.argv[2])
        torch.set_num_threads(case.pop("threads"))
        print(json.dumps(_memory_child(**case)))
        raise SystemExit(0)
    if sys.argv[1:2] == ["--resummarize"]:  # python -m phyir.bench.render --resummarize DIR
        print(format_table(resummarize(sys.argv[2])))
        raise SystemExit(0)
    if sys.argv[2:3] == ["--prefiltered-cpu"]:
        args = sys.argv[3:]
        torch.set_num_threads(int(args[1]) if len(args) > 1 else 1)
        spps = tuple(int(a) for a in args[2:]) or (64, 128)
        res = prefiltered_cpu(*args[:1], spps=spps)
    else:
        res = {k: sample_ratios(k) for k in (sys.argv[2:] or ["glossy"])}
    from phyir.bench.report import write_json

    write_json(Path(sys.argv[1]), res)
