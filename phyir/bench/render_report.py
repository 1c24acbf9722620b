"""Summaries, tables and plots of the render benchmark's results (:mod:`phyir.bench.render`)."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

from phyir.bench.render_measure import PREFILTERED_F32, interp_time, loglog


def summarize(res: dict) -> dict:
    """Targets: samples IS needs for uniform's error; prefiltered speed-up at equal error."""
    rows = res["rows"]
    isr = [r for r in rows if r["method"] == "importance"]
    spp = [r["spp"] for r in isr]
    out = {}
    for layer in ("image", "specular"):
        err = [r[f"err_{layer}"] for r in isr]
        if not all(math.isfinite(e) and e > 0 for e in err):
            continue
        ratios = []
        for r in rows:
            if r["method"] == "uniform" and r[f"err_{layer}"] > 0:
                e_u = r[f"err_{layer}"]
                if e_u >= err[0]:  # already beaten at the smallest spp measured: a lower bound
                    ratios.append({"uniform_spp": r["spp"], "uniform_err": e_u, "is_spp_same_err": spp[0],
                                   "sample_ratio": r["spp"] / spp[0], "lower_bound": True})
                    continue
                need = loglog(spp, err, e_u)
                ratios.append({"uniform_spp": r["spp"], "uniform_err": e_u, "is_spp_same_err": need,
                               "sample_ratio": r["spp"] / need, "lower_bound": False})
        out[f"is_vs_uniform_{layer}"] = ratios
    pref = next(r for r in rows if r["method"] == "prefiltered")
    err = [r["err_image"] for r in isr]
    if pref["err_image"] > 0 and all(e > 0 for e in err):
        need = loglog(spp, err, pref["err_image"])
        cmp = {"prefiltered_err": pref["err_image"], "is_spp_same_err": need}
        for key in ("median_s", "min_s", "cpu_s"):
            t_is = interp_time(spp, [r[key] for r in isr], need)
            cmp[f"is_{key}"] = t_is
            cmp[f"prefiltered_{key}"] = pref[key]
            cmp[f"speedup_{key.split('_')[0]}"] = t_is / pref[key]
        out["prefiltered_vs_is"] = cmp
    return out


def spread_summary(rows: list[dict]) -> dict:
    """Median and minimum over the seeds of the speed-ups in wall and CPU time (one thread: CPU time
    is the fairer measure on a shared machine), and how many seeds reach 20x in each."""
    out = {}
    for key in ("median", "cpu"):
        sp = [r[f"speedup_{key}"] for r in rows]
        name = "" if key == "median" else "_cpu"
        out[f"speedup{name}_median_of_seeds"] = statistics.median(sp)
        out[f"speedup{name}_min_of_seeds"] = min(sp)
        out[f"seeds{name}_at_20x"] = sum(v >= 20 for v in sp)
    return out


def format_table(result: dict) -> str:
    """The printed / documented tables (markdown)."""
    cfg = result["config"]
    lines = [f"device {cfg['device']}, {cfg['threads']} thread(s), {cfg['size'][0]}x{cfg['size'][1]}, "
             f"prefiltered level matmul in {cfg.get('level_matmul', 'float32')}, "
             f"load average {cfg['loadavg_start'][0]:.1f} -> {cfg['loadavg_end'][0]:.1f}", ""]
    for kind, res in result["scenes"].items():
        lines += [f"scene {kind} (reference {res['reference_spp']} spp, noise "
                  f"{res['reference_noise']['image']:.1e} removed)", "",
                  "| method | spp | time ms (median) | IQR ms | min ms | CPU ms | err image | err diffuse "
                  "| err specular |",
                  "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for r in res["rows"]:
            lines.append(f"| {r['method']} | {r['spp'] or '-'} | {r['median_s'] * 1e3:.1f} | "
                         f"{r['q1_s'] * 1e3:.0f}-{r['q3_s'] * 1e3:.0f} | {r['min_s'] * 1e3:.0f} | "
                         f"{r['cpu_s'] * 1e3:.0f} | "
                         f"{r['err_image']:.4f} | "
                         f"{r['err_diffuse']:.4f} | {r['err_specular']:.4f} |")
        sm = res["summary"]
        for layer in ("image", "specular"):
            for q in sm.get(f"is_vs_uniform_{layer}", []):
                if q["lower_bound"]:
                    lines.append(f"- uniform {q['uniform_spp']} spp ({layer} err {q['uniform_err']:.4f}) is "
                                 f"worse than importance at {q['is_spp_same_err']} spp: "
                                 f">= {q['sample_ratio']:.0f}x fewer samples")
                else:
                    lines.append(f"- uniform {q['uniform_spp']} spp ({layer} err {q['uniform_err']:.4f}) = "
                                 f"importance {q['is_spp_same_err']:.1f} spp: "
                                 f"{q['sample_ratio']:.1f}x fewer samples")
        for b in res.get("prefiltered_breakdown", []):
            lines.append(f"- prefiltered specular, {b['by']} in [{b['lo']:.1f}, {b['hi']:.1f}) "
                         f"({100 * b['pixels']:.0f}% of pixels): error {b['err_specular']:.3f}, "
                         f"bias {b['bias_specular']:+.3f}, "
                         f"share of the squared error {b['share_of_err2']:.2f}")
        p = sm.get("prefiltered_vs_is")
        if p:
            lines.append(f"- prefiltered (err {p['prefiltered_err']:.4f}, "
                         f"{p['prefiltered_median_s'] * 1e3:.1f} ms) "
                         f"= importance {p['is_spp_same_err']:.0f} spp ({p['is_median_s'] * 1e3:.0f} ms): "
                         f"{p['speedup_median']:.1f}x faster (median wall), "
                         f"{p['speedup_min']:.1f}x (min wall), {p['speedup_cpu']:.1f}x (CPU time)")
        sd = res.get("seeds")
        if sd:
            lines += ["", f"prefiltered against importance sampling on {len(sd['rows'])} {kind} scenes "
                      "(seeds; each timed head to head with importance sampling at the matching spp)", "",
                      "| seed | prefiltered err image | ms (median) | = importance spp "
                      "| speed-up (median wall) | speed-up (CPU) |",
                      "| ---: | ---: | ---: | ---: | ---: | ---: |"]
            for r in sd["rows"]:
                lines.append(f"| {r['seed']} | {r['prefiltered_err']:.4f} | "
                             f"{r['prefiltered_median_s'] * 1e3:.1f} | {r['is_spp_same_err']:.0f} | "
                             f"{r['speedup_median']:.1f}x | {r['speedup_cpu']:.1f}x |")
            lines.append("- speed-up over the seeds, median wall time: median "
                         f"{sd['speedup_median_of_seeds']:.1f}x, "
                         f"min {sd['speedup_min_of_seeds']:.1f}x, {sd['seeds_at_20x']} of {len(sd['rows'])} "
                         f"scenes at >= 20x; CPU time: median {sd['speedup_cpu_median_of_seeds']:.1f}x, "
                         f"min {sd['speedup_cpu_min_of_seeds']:.1f}x, {sd['seeds_cpu_at_20x']} of "
                         f"{len(sd['rows'])} scenes at >= 20x")
        lines.append("")
    for m in result.get("memory", []):
        lines.append(f"- memory, {m['size'][0]}x{m['size'][1]} {m['method']} {m['spp']} spp "
                     f"{'forward+backward' if m['grad'] else 'forward'}: +{m['extra_peak_mb']:.0f} MB peak "
                     f"(probes {m['probes_mb']:.0f} MB)")
    if result.get("memory"):
        lines.append("")
    sk = result["skips"][-1]["summary"]
    lines += [f"skips (mixed scene, importance {cfg['skip_spp']} spp)", "",
              "| skip | pixels | samples saved | wall time saved (median) | CPU time saved (min) "
              "| err image with / without | err on its pixels with / without "
              "| specular err on its pixels with / without |",
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for e in sk:
        lines.append(f"| {e['skip']} | {100 * e['fraction']:.1f}% | {100 * e['samples_saved_frac']:.1f}% | "
                     f"{e['time_saved_s'] * 1e3:.0f} ms ({100 * e['time_saved_frac']:.0f}%) | "
                     f"{e['cpu_saved_s'] * 1e3:.0f} ms ({100 * e['cpu_saved_frac']:.0f}%) | "
                     f"{e['err_image']:.4f} / {e['err_image_without']:.4f} | "
                     + (f"{e['err_pixels']:.4f} / {e['err_pixels_without']:.4f} | "
                        f"{e['err_specular_pixels']:.4f} / {e['err_specular_pixels_without']:.4f} |"
                        if "err_pixels" in e else "n/a (image value by definition) | n/a |"))
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    """Time against error (log-log): one column per scene, rows for the image and specular layers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    scenes = result["scenes"]
    cfg = result["config"]
    fig, axes = plt.subplots(2, len(scenes), figsize=(5.5 * len(scenes), 8), squeeze=False)
    for col, (kind, res) in enumerate(scenes.items()):
        for row, layer in enumerate(("image", "specular")):
            ax = axes[row, col]
            key = f"err_{layer}"
            for method, style in (("uniform", "o--"), ("importance", "s-")):
                rs = [r for r in res["rows"] if r["method"] == method]
                ax.errorbar([r["median_s"] * 1e3 for r in rs], [r[key] for r in rs],
                            xerr=[[(r["median_s"] - r["q1_s"]) * 1e3 for r in rs],
                                  [(r["q3_s"] - r["median_s"]) * 1e3 for r in rs]], fmt=style, label=method)
                for r in rs:
                    ax.annotate(str(r["spp"]), (r["median_s"] * 1e3, r[key]), fontsize=7,
                                xytext=(3, 3), textcoords="offset points")
            p = next(r for r in res["rows"] if r["method"] == "prefiltered")
            ax.plot([p["median_s"] * 1e3], [p[key]], "r*", ms=12, label="prefiltered")
            for q in (r for r in res["rows"] if r["method"] == PREFILTERED_F32):
                ax.plot([q["median_s"] * 1e3], [q[key]], "kx", ms=9, label="prefiltered, float32 levels")
            ax.set(xscale="log", yscale="log", xlabel="time per image (ms, median)",
                   ylabel=f"relative RMSE ({layer})",
                   title=f"{kind}: {layer} ({cfg['size'][0]}x{cfg['size'][1]}, {cfg['device']})")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def plot_energy(curves: dict, roughs: tuple[float, ...], path: Path) -> None:
    """Plot :func:`phyir.bench.render.energy_curves`' white-furnace curves per roughness to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for r in roughs:
        a.plot(curves["n_dot_v"], curves["dielectric_total"][str(r)], label=f"R = {r}")
        b.plot(curves["n_dot_v"], curves["metal_loss"][str(r)], label=f"R = {r}")
    a.axhline(1.0, color="k", lw=0.8, ls=":")
    a.set(xlabel="n.v", ylabel="albedo (diffuse + specular)",
          title="white dielectric (B=1, M=0): reflects more than it receives")
    b.set(xlabel="n.v", ylabel="1 - specular albedo",
          title="white metal (B=1, M=1): energy the specular lobe loses")
    for ax in (a, b):
        ax.grid(True, alpha=0.3)
        ax.legend()
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
